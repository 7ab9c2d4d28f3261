//! Agreement with evo 1.38.1 on real trajectories: every ATE and RPE statistic computed here
//! equals evo's to 1e-6 relative. evo runs in this same test (eval/scripts/evo_reference.py, with
//! evo's own readers, association, alignment and metrics), so nothing is hard-coded.
//!
//! Cases, for (a) EuRoC V1_02: evo's `V102.txt` estimate vs the official ground-truth CSV and
//! (b) V1_01: an OpenVINS estimate vs evo's TUM ground truth:
//! - ATE without alignment, `--align` (SE(3)), `--align --correct_scale` (Sim(3)) and
//!   `--correct_scale` alone (scale only), translation and angle in degrees; angle in radians,
//!   full transformation and rotation part without alignment and with SE(3);
//! - RPE with delta 1 frame and delta 1 m (`--delta_unit m`), translation and angle in degrees,
//!   without alignment, with SE(3) and with Sim(3).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::path::Path;
use std::process::{Child, Command, Stdio};

use eval::align::Alignment;
use eval::associate::{DEFAULT_MAX_DIFF_S, associate};
use eval::io;
use eval::metrics::{self, Delta, PoseRelation, Stats};
use serde_json::Value;

const PYTHON: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../.venv/bin/python");
const SCRIPT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/scripts/evo_reference.py");
const V102_GT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/trajectories/V102_groundtruth.csv");
const V102_EST: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/trajectories/V102.txt");
const V101_GT: &str =
    concat!(env!("CARGO_MANIFEST_DIR"), "/../data/euroc/v1_01_excerpt/groundtruth_from_evo/V101_gt_tum.txt");
const V101_EST: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../data/euroc/v1_01_excerpt/groundtruth_from_evo/V101_openvins_estimate_tum.txt"
);

const MAX_RELATIVE_DIFFERENCE: f64 = 1e-6;

fn spawn_evo(gt_format: &str, gt: &str, est: &str) -> Child {
    assert!(Path::new(PYTHON).exists(), "no Python venv at {PYTHON}: run scripts/test first");
    Command::new(PYTHON)
        .args([SCRIPT, gt_format, gt, est])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start evo_reference.py")
}

fn evo_results(child: Child) -> BTreeMap<String, Value> {
    let output = child.wait_with_output().unwrap();
    assert!(
        output.status.success(),
        "evo_reference.py failed (run scripts/test first if evo is missing):\n{}",
        String::from_utf8_lossy(&output.stderr)
    );
    serde_json::from_slice(&output.stdout).unwrap()
}

fn relation(name: &str) -> PoseRelation {
    match name {
        "trans" => PoseRelation::Translation,
        "angle_deg" => PoseRelation::RotationAngleDeg,
        "angle_rad" => PoseRelation::RotationAngleRad,
        "full" => PoseRelation::Full,
        "rot_part" => PoseRelation::RotationPart,
        other => panic!("unknown relation {other}"),
    }
}

fn alignment(name: &str) -> Alignment {
    name.parse().unwrap()
}

fn relative_difference(ours: f64, theirs: f64) -> f64 {
    if ours == theirs { 0.0 } else { (ours - theirs).abs() / theirs.abs().max(f64::MIN_POSITIVE) }
}

/// Compares one case; returns the largest relative difference over its statistics.
fn compare(case: &str, ours: &Stats, evo: &Value) -> f64 {
    assert_eq!(ours.count as u64, evo["pairs"].as_u64().unwrap(), "{case}: pair count");
    let stats = &evo["stats"];
    let mut worst = 0.0_f64;
    for (name, value) in ours.named() {
        let theirs = stats[name].as_f64().unwrap();
        let difference = relative_difference(value, theirs);
        assert!(
            difference <= MAX_RELATIVE_DIFFERENCE,
            "{case} {name}: ours {value:.12e}, evo {theirs:.12e}, relative difference {difference:.2e}"
        );
        worst = worst.max(difference);
    }
    worst
}

/// Computes every case evo computed and compares them; prints ours vs evo for the report.
fn check_dataset(label: &str, gt_text: &str, est_text: &str, evo: &BTreeMap<String, Value>) {
    let (_, gt) = io::parse(gt_text, None).unwrap();
    let (_, est) = io::parse(est_text, None).unwrap();
    let association = associate(&gt, &est, DEFAULT_MAX_DIFF_S, 0.0).unwrap();
    let mut worst = 0.0_f64;
    assert!(evo.len() >= 26, "{label}: evo returned only {} cases", evo.len());
    for (case, reference) in evo {
        let parts: Vec<&str> = case.split('/').collect();
        let stats = match parts.as_slice() {
            ["ape", align, rel] => metrics::ate(&association, &alignment(align), relation(rel)).unwrap().stats,
            ["rpe", align, delta, rel] => {
                let delta = match *delta {
                    "1frames" => Delta::Frames(1),
                    "1m" => Delta::Metres(1.0),
                    other => panic!("unknown delta {other}"),
                };
                metrics::rpe(&association, &alignment(align), delta, relation(rel)).unwrap().stats
            }
            _ => panic!("unknown case {case}"),
        };
        let difference = compare(case, &stats, reference);
        if parts[1] != "scale" && (parts.last() == Some(&"trans") || parts.last() == Some(&"angle_deg")) {
            println!(
                "{label} {case:<26} rmse ours {:.12} evo {:.12} (max rel. diff over stats {difference:.1e})",
                stats.rmse,
                reference["stats"]["rmse"].as_f64().unwrap()
            );
        }
        worst = worst.max(difference);
    }
    println!("{label}: {} cases, largest relative difference {worst:.2e}", evo.len());
}

#[test]
fn ate_and_rpe_agree_with_evo_on_real_trajectories() {
    // Both evo runs start first, so their ~2 s of Python start-up overlap with each other and
    // with our side.
    let v102_child = spawn_evo("euroc", V102_GT, V102_EST);
    let v101_child = spawn_evo("tum", V101_GT, V101_EST);
    let read = |path: &str| std::fs::read_to_string(path).unwrap();
    let (v102_gt, v102_est, v101_gt, v101_est) = (read(V102_GT), read(V102_EST), read(V101_GT), read(V101_EST));
    check_dataset("V102", &v102_gt, &v102_est, &evo_results(v102_child));
    check_dataset("V101", &v101_gt, &v101_est, &evo_results(v101_child));
}

/// The command line prints the library's numbers (checked against evo above), so its JSON
/// agrees with evo too. Compared with the library rather than with a third evo run, which would
/// add seconds of Python for no new information.
#[test]
fn cli_json_matches_the_library() {
    let run = |args: &[&str]| -> Value {
        let output = Command::new(env!("CARGO_BIN_EXE_eval")).args(args).output().unwrap();
        assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
        serde_json::from_slice(&output.stdout).unwrap()
    };
    let ate = run(&["ate", "--gt", V102_GT, "--est", V102_EST, "--align", "se3", "--json"]);
    let rpe = run(&["rpe", "--gt", V102_GT, "--est", V102_EST, "--delta", "1", "--unit", "m", "--json"]);

    let (_, gt) = io::parse(&std::fs::read_to_string(V102_GT).unwrap(), None).unwrap();
    let (_, est) = io::parse(&std::fs::read_to_string(V102_EST).unwrap(), None).unwrap();
    let association = associate(&gt, &est, DEFAULT_MAX_DIFF_S, 0.0).unwrap();
    let ate_report = metrics::ate(&association, &Alignment::Se3, PoseRelation::Translation).unwrap();
    let rpe_stats =
        metrics::rpe(&association, &Alignment::None, Delta::Metres(1.0), PoseRelation::Translation).unwrap().stats;
    for (json, stats) in [(&ate, &ate_report.stats), (&rpe, &rpe_stats)] {
        assert_eq!(json["pairs"].as_u64(), Some(stats.count as u64));
        for (name, value) in [
            ("rmse", stats.rmse),
            ("mean", stats.mean),
            ("median", stats.median),
            ("std", stats.std),
            ("min", stats.min),
            ("max", stats.max),
            ("sse", stats.sse),
        ] {
            // serde_json's default float parser is not correctly rounded (that needs its
            // `float_roundtrip` feature): allow the last bit.
            let printed = json[name].as_f64().unwrap();
            assert!(relative_difference(printed, value) <= 1e-15, "{name}: {printed} vs {value}");
        }
    }
    let final_error_m = ate["final_error_m"].as_f64().unwrap();
    assert!(relative_difference(final_error_m, ate_report.final_error.error_m) <= 1e-15);
    let percent = ate["final_error_percent"].as_f64().unwrap();
    assert!(relative_difference(percent, ate_report.final_error.percent.unwrap()) <= 1e-15);
}
