#![allow(clippy::unwrap_used, clippy::expect_used)]
//! `onboard vio` end to end on the real datasets, scored by the harness (`sil vio --gt`, the
//! binary as a user runs it): the dataset replayed through the rover's own nodes.

use std::path::PathBuf;
use std::process::{Command, Output};

fn data(path: &str) -> String {
    format!("{}/../data/{path}", env!("CARGO_MANIFEST_DIR"))
}

fn onboard(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sil")).args(args).output().unwrap()
}

fn json_of(output: &Output) -> serde_json::Value {
    assert!(output.status.success(), "stderr: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).unwrap()
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("onboard-vio-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn number(report: &serde_json::Value, key: &str) -> f64 {
    report[key].as_f64().unwrap_or_else(|| panic!("{key} missing in {report}"))
}

#[test]
fn kitti_straight_drive_drifts_less_than_two_percent() {
    let dir = temp_dir("kitti");
    let out = dir.join("est.tum");
    let report = json_of(&onboard(&[
        "vio",
        "--dataset",
        &data("stereo_sequences/kitti_straight"),
        "--gt",
        &data("stereo_sequences/kitti_straight/poses.txt"),
        "--out",
        out.to_str().unwrap(),
        "--json",
    ]));
    eprintln!("{report}");
    assert_eq!(report["layout"], "kitti");
    assert_eq!(report["mode"], "vo");
    assert_eq!(report["frames"], 51);
    assert_eq!(report["gt_pairs"], 51);
    // The written trajectory is the one scored: one TUM row per frame.
    let text = std::fs::read_to_string(&out).unwrap();
    assert_eq!(text.lines().count(), 51);
    let gt_length = number(&report, "gt_path_length_m");
    assert!((gt_length - 59.9).abs() < 0.5, "{gt_length}");
    // A good stereo odometry stays near 1 % on KITTI (issue 7); this excerpt is one straight.
    assert!(number(&report, "final_drift_percent") < 2.0, "{report}");
    assert!(number(&report, "ate_rmse_m") < KITTI_ATE_BOUND_M, "{report}");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// 1.5 × the measured ATE (0.102 m, BENCHMARKS.md): the pipeline is deterministic, so the margin
/// only has to absorb later tuning, not run-to-run noise.
const KITTI_ATE_BOUND_M: f64 = 0.155;
/// MH_01 hand-held: the pipeline is deterministic, but the odometry was retuned while these were
/// measured (ATE 4.7–5.2 mm, final drift 0.42–0.77 % over three versions; 8.5 mm ATE after the
/// faster KLT's early exit, BENCHMARKS.md), so the bounds are 1.5 × the worst version, rounded up.
/// A lost or scale-wrong track is centimetres off.
const MH01_ATE_BOUND_M: f64 = 0.013;
const MH01_DRIFT_BOUND_PERCENT: f64 = 1.1;

#[test]
fn euroc_mh01_hand_held_raw_images_are_rectified_and_tracked() {
    let report = json_of(&onboard(&[
        "vio",
        "--dataset",
        &data("euroc/mh_01_handheld"),
        "--gt",
        &data("euroc/mh_01_handheld/groundtruth_openvins_MH_01_easy_tum_crop.txt"),
        "--json",
    ]));
    eprintln!("{report}");
    assert_eq!(report["layout"], "asl");
    // No IMU samples in this excerpt: stereo odometry alone.
    assert_eq!(report["mode"], "vo");
    assert_eq!(report["frames"], 85);
    assert!(number(&report, "vision_ms_per_frame") > 0.0);
    assert!(number(&report, "ate_rmse_m") < MH01_ATE_BOUND_M, "{report}");
    assert!(number(&report, "final_drift_percent") < MH01_DRIFT_BOUND_PERCENT, "{report}");
}

#[test]
fn euroc_v1_01_static_with_real_imu_stays_put() {
    let report = json_of(&onboard(&["vio", "--dataset", &data("euroc/v1_01_excerpt"), "--json"]));
    eprintln!("{report}");
    assert_eq!(report["mode"], "vio");
    assert_eq!(report["frames"], 20);
    assert!(number(&report, "vo_updates_applied") > 0.0, "{report}");
    assert!(number(&report, "max_displacement_m") < 0.05, "{report}");
    // The filter ran on the real IMU up to the last image's result (0.95 s of images + 0.25 s),
    // not over the 144 s of IMU in the excerpt.
    assert_eq!(report["imu_samples"], 241);
    assert_eq!(report["frames_before_init"], 10);
    // Biases settle: the VO-corrected filter keeps the gyro bias it levelled at rest (EuRoC's
    // ADIS: about [-0.002, 0.025, 0.08] rad/s) and finds an accelerometer bias of a few cm/s².
    let vector =
        |key: &str| -> Vec<f64> { report[key].as_array().unwrap().iter().map(|v| v.as_f64().unwrap()).collect() };
    let (gyro_0, gyro_1) = (vector("initial_gyro_bias_radps"), vector("final_gyro_bias_radps"));
    for (a, b) in gyro_0.iter().zip(&gyro_1) {
        assert!((a - b).abs() < 0.01, "{gyro_0:?} -> {gyro_1:?}");
    }
    assert!((gyro_1[2] - 0.08).abs() < 0.01, "{gyro_1:?}");
    let accel = vector("final_accel_bias_mps2");
    assert!(accel.iter().all(|a| a.abs() < 0.1), "{accel:?}");
}

#[test]
fn bad_inputs_give_exit_code_one_and_usage_errors_two() {
    let missing = onboard(&["vio", "--dataset", "/nonexistent/dataset"]);
    assert_eq!(missing.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&missing.stderr);
    assert!(stderr.contains("/nonexistent/dataset") && stderr.contains("no such dataset directory"), "{stderr}");

    // A KITTI layout with a garbled calibration.
    let dir = temp_dir("garbled");
    std::fs::create_dir_all(dir.join("image_0")).unwrap();
    std::fs::create_dir_all(dir.join("image_1")).unwrap();
    std::fs::write(dir.join("calib.txt"), "P0: 707 0 601 zero\n").unwrap();
    let garbled = onboard(&["vio", "--dataset", dir.to_str().unwrap()]);
    assert_eq!(garbled.status.code(), Some(1));
    let stderr = String::from_utf8_lossy(&garbled.stderr);
    assert!(stderr.contains("calib.txt:1") && stderr.contains("`zero` is not a number"), "{stderr}");
    std::fs::remove_dir_all(&dir).unwrap();

    // Ground truth that is not a trajectory.
    let kitti = data("stereo_sequences/kitti_straight");
    let bad_gt = onboard(&["vio", "--dataset", &kitti, "--gt", &data("stereo_sequences/kitti_straight/calib.txt")]);
    assert_eq!(bad_gt.status.code(), Some(1), "{}", String::from_utf8_lossy(&bad_gt.stderr));

    for args in
        [&["vio"][..], &["vio", "--dataset"], &["vio", "--dataset", &kitti, "--latency-ms", "-3"], &["vio", "--bogus"]]
    {
        let output = onboard(args);
        assert_eq!(output.status.code(), Some(2), "{args:?}");
        assert!(String::from_utf8_lossy(&output.stderr).contains("usage: onboard vio"));
    }
    let help = onboard(&["vio", "--help"]);
    assert!(help.status.success());
    assert!(String::from_utf8_lossy(&help.stdout).contains("--switch-distance"));
}
