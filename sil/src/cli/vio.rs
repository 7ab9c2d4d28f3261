//! `sil vio --dataset DIR --gt GT [--out EST.tum] [--json] [onboard vio options]`
//!
//! `onboard vio` (the firmware's nodes on the dataset, [`onboard::vio`]) followed by the score of
//! its estimate against the dataset's ground truth ([`crate::vio_score`]: ATE after SE(3)
//! alignment, final drift in % of the ground-truth path). Exit codes: 0 success, 1 runtime error
//! (unreadable dataset or ground truth, ...), 2 usage error.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;

use onboard::cli::vio::{self as firmware, Options};
use onboard::vio::DatasetReport;

use crate::vio_score::{Score, load_ground_truth, score};

const USAGE: &str = "usage: sil vio --dataset DIR --gt GT [--out EST.tum] [--json] [options]

  --gt FILE              ground truth (TUM, KITTI poses.txt or EuRoC CSV): the estimate is scored
                         (ATE after SE(3) alignment, final drift in % of the ground-truth path)

Every other option is `onboard vio`'s:";

/// `--gt FILE` taken out of the arguments; the rest is `onboard vio`'s.
fn split_gt(args: Vec<OsString>) -> Result<(Option<PathBuf>, Vec<OsString>), String> {
    let mut gt = None;
    let mut rest = Vec::new();
    let mut args = args.into_iter();
    while let Some(arg) = args.next() {
        if arg == "--gt" {
            gt = Some(PathBuf::from(args.next().ok_or("--gt: a file is required")?));
        } else if let Some(value) = arg.to_str().and_then(|a| a.strip_prefix("--gt=")) {
            gt = Some(PathBuf::from(value));
        } else {
            rest.push(arg);
        }
    }
    Ok((gt, rest))
}

fn parse_args(args: Vec<OsString>) -> Result<Option<(Options, Option<PathBuf>)>, String> {
    let (gt, rest) = split_gt(args)?;
    Ok(firmware::parse_args(rest)?.map(|options| (options, gt)))
}

fn run((options, gt): &(Options, Option<PathBuf>)) -> Result<(DatasetReport, Option<Score>), String> {
    let report = firmware::run(options)?;
    let score = match gt {
        Some(path) => {
            let dataset = onboard::sensors::open_replay(&options.config).map_err(|e| e.to_string())?;
            let gt =
                load_ground_truth(path, dataset.kind, &dataset.image_stamps_ns, &dataset.calibration.left.t_body_cam)
                    .map_err(|e| e.to_string())?;
            Some(score(&report.estimate_in_dataset_time(), &gt).map_err(|e| e.to_string())?)
        }
        None => None,
    };
    Ok((report, score))
}

pub fn main(args: Vec<OsString>) -> ExitCode {
    let usage = format!("{USAGE}\n\n{}", firmware::USAGE);
    let ((options, _), (report, score)) = match onboard::cli::parse_and_run("sil", "vio", &usage, args, parse_args, run)
    {
        Ok(done) => done,
        Err(code) => return code,
    };
    if options.json {
        let mut object = firmware::json(&options, &report);
        if let Some(score) = &score {
            for (key, value) in score.json_fields() {
                object[key] = value;
            }
        }
        println!("{object}");
    } else {
        firmware::print_text(&options, &report);
        if let Some(score) = &score {
            score.print();
        }
    }
    ExitCode::SUCCESS
}
