//! `submap-match`: the submap matcher (`mapper::matching`) on two point-cloud files.
//!
//! Exit codes: 0 match found, 1 no match, 2 usage or input error. `--help` for the options.

mod args;
mod frames;
mod output;

use std::process::ExitCode;
use std::sync::Arc;
use std::time::Instant;

use mapper::VoxelCloud;
use mapper::cloud_file::{CloudFile, read_cloud};
use mapper::matching::{MatchReport, PreparedCloud, RelativePrior, match_clouds};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use args::{Args, USAGE, UsageError};
use frames::UpAlignment;

/// What one run measured, for the output.
#[derive(Debug)]
pub struct Run {
    pub report: MatchReport,
    pub alignment: UpAlignment,
    /// Points after the voxel filter.
    pub source_points: usize,
    pub target_points: usize,
    pub prepare_s: f64,
    /// Voxel filter, preparation and matching.
    pub total_s: f64,
}

/// A file's points, voxel-filtered unless `voxel_m` is 0, in the aligned frame.
fn cloud(file: CloudFile, voxel_m: f64, alignment: &UpAlignment) -> VoxelCloud {
    let mut points = file.points;
    alignment.align_points(&mut points);
    if voxel_m > 0.0 { VoxelCloud::filtered(voxel_m, &points) } else { VoxelCloud { leaf_m: 0.0, points } }
}

fn run(args: &Args) -> Result<Run, UsageError> {
    let read = |path| read_cloud(path).map_err(|e| UsageError(e.to_string()));
    let (source_file, target_file) = (read(&args.source)?, read(&args.target)?);
    let alignment = UpAlignment::new(&args.up);
    let prior = args.prior.map(|p| {
        let t_input = Isometry3::from_parts(
            Translation3::from(p.translation_m),
            UnitQuaternion::from_rotation_matrix(&alignment.yaw_about_up(p.yaw_rad)),
        );
        RelativePrior {
            t_target_source: alignment.aligned_from_input(&t_input),
            delta_sigma_m: Vector3::repeat(p.sigma_m),
        }
    });

    let start = Instant::now();
    let source = Arc::new(cloud(source_file, args.voxel_m, &alignment));
    let target = Arc::new(cloud(target_file, args.voxel_m, &alignment));
    let (source_points, target_points) = (source.len(), target.len());
    let prepare_start = Instant::now();
    let source = PreparedCloud::new(source, &args.params);
    let target = PreparedCloud::new(target, &args.params);
    let prepare_s = prepare_start.elapsed().as_secs_f64();
    let report = match_clouds(&source, &target, prior.as_ref(), &args.params);
    let total_s = start.elapsed().as_secs_f64();
    Ok(Run { report, alignment, source_points, target_points, prepare_s, total_s })
}

fn main() -> ExitCode {
    let parsed = args::parse(std::env::args_os().skip(1));
    let args = match parsed {
        Ok(Some(args)) => args,
        Ok(None) => {
            println!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Err(UsageError(message)) => {
            eprintln!("submap-match: {message}\n\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    match run(&args) {
        Ok(result) => {
            if args.json {
                println!("{}", output::json(&args, &result));
            } else {
                print!("{}", output::summary(&args, &result));
            }
            if result.report.outcome.is_ok() { ExitCode::SUCCESS } else { ExitCode::from(1) }
        }
        Err(UsageError(message)) => {
            eprintln!("submap-match: {message}");
            ExitCode::from(2)
        }
    }
}
