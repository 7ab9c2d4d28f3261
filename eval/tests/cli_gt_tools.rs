//! `eval sync`, `eval fuse` and `eval plot` end to end with the real binary on real trajectories.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use std::process::Command;

fn data(path: &str) -> String {
    format!("{}/../data/{path}", env!("CARGO_MANIFEST_DIR"))
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("eval-cli-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn eval(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_eval")).args(args).output().unwrap()
}

/// A copy of a real ground truth on a clock shifted by 0.25 s: `sync` must find the shift.
#[test]
fn sync_recovers_a_clock_offset_and_writes_the_synced_estimate() {
    let dir = temp_dir("sync");
    let gt_path = data("euroc/v1_01_excerpt/groundtruth_from_evo/V101_gt_tum.txt");
    let gt = std::fs::read_to_string(&gt_path).unwrap();
    let shifted: String = gt
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let (t, rest) = l.split_once(' ').unwrap();
            format!("{:.9} {rest}\n", t.parse::<f64>().unwrap() - 0.25)
        })
        .collect();
    let est = dir.join("shifted.tum");
    std::fs::write(&est, shifted).unwrap();
    let out = dir.join("synced.tum");
    let output =
        eval(&["sync", "--gt", &gt_path, "--est", est.to_str().unwrap(), "--out", out.to_str().unwrap(), "--json"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let offset = report["offset_s"].as_f64().unwrap();
    let drift = report["drift"].as_f64().unwrap();
    println!("recovered offset {offset} s, drift {drift}");
    assert!((offset - 0.25).abs() < 2e-3, "offset {offset}");
    assert!((drift - 1.0).abs() < 1e-4, "drift {drift}");
    // The synced estimate evaluates like the ground truth itself.
    let ate = eval(&["ate", "--gt", &gt_path, "--est", out.to_str().unwrap(), "--json"]);
    let ate: serde_json::Value = serde_json::from_slice(&ate.stdout).unwrap();
    assert!(ate["rmse"].as_f64().unwrap() < 0.01, "{ate}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn fuse_and_plot_write_their_outputs() {
    let dir = temp_dir("fuse");
    let root = "euroc/v1_01_excerpt/groundtruth_from_evo";
    let (gt, odom) =
        (data(&format!("{root}/V101_gt_tum.txt")), data(&format!("{root}/V101_openvins_estimate_tum.txt")));
    let fused = dir.join("fused.tum");
    let stream = format!("laser:{gt}:0.016:1.56");
    let output = eval(&["fuse", "--odom", &odom, "--stream", &stream, "--out", fused.to_str().unwrap(), "--json"]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert!(report["streams"][0]["used"].as_u64().unwrap() > 2000, "{report}");
    assert!(std::fs::read_to_string(&fused).unwrap().lines().count() > 10_000);

    let (png, err_png) = (dir.join("t.png"), dir.join("e.png"));
    let output = eval(&[
        "plot",
        "--gt",
        &data("trajectories/V102_groundtruth.csv"),
        "--est",
        &data("trajectories/V102.txt"),
        "--out",
        png.to_str().unwrap(),
        "--error-out",
        err_png.to_str().unwrap(),
    ]);
    assert!(output.status.success(), "{}", String::from_utf8_lossy(&output.stderr));
    assert!(String::from_utf8_lossy(&output.stdout).contains("ATE RMSE 0.0917 m over 798 pairs"));
    for path in [&png, &err_png] {
        let bytes = std::fs::read(path).unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
    }

    let bad = eval(&["fuse", "--odom", &odom, "--stream", "laser:only-two", "--out", "/tmp/x"]);
    assert_eq!(bad.status.code(), Some(2));
    std::fs::remove_dir_all(&dir).unwrap();
}
