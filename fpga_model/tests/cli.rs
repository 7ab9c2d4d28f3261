//! The `sgm` binary end to end on tsukuba: its PFM equals the library's output for the default
//! configuration, its JSON has the documented fields, and its errors have the documented exit
//! codes (2 usage, 1 runtime) and name what went wrong.

#![allow(clippy::unwrap_used, reason = "test helpers: a panic is a failed test with its message")]

use std::path::PathBuf;
use std::process::{Command, Output};

use fpga_model::eval::default_data_root;
use fpga_model::{SgmConfig, fast, io, reference};

fn sgm(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_sgm")).args(args).output().unwrap()
}

fn tsukuba(file: &str) -> String {
    default_data_root().join("middlebury_v2/tsukuba").join(file).display().to_string()
}

fn out_path(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("cli_tests");
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

fn stderr(output: &Output) -> String {
    String::from_utf8_lossy(&output.stderr).into_owned()
}

/// The library's default output for tsukuba, as PFM values.
fn expected_tsukuba() -> Vec<f32> {
    let left = io::read_gray_png(tsukuba("imL.png")).unwrap();
    let right = io::read_gray_png(tsukuba("imR.png")).unwrap();
    let config = SgmConfig { disparities: 16, ..Default::default() };
    let mut matcher = fast::Matcher::new(config, left.width, left.height, 1).unwrap();
    io::disparity_to_pfm_values(&matcher.compute(&left, &right).unwrap())
}

#[test]
fn json_run_on_tsukuba() {
    let out = out_path("tsukuba_json.pfm");
    let out_str = out.display().to_string();
    let output = sgm(&[
        "--left",
        &tsukuba("imL.png"),
        "--right",
        &tsukuba("imR.png"),
        "--disparities",
        "16",
        "--out",
        &out_str,
        "--json",
        "--threads",
        "2",
    ]);
    assert!(output.status.success(), "{}", stderr(&output));
    let stdout = String::from_utf8(output.stdout).unwrap();
    assert_eq!(stdout.trim().lines().count(), 1, "exactly one JSON object: {stdout}");
    let report: serde_json::Value = serde_json::from_str(stdout.trim()).unwrap();
    assert_eq!(report["width"], 384);
    assert_eq!(report["height"], 288);
    assert_eq!(report["disparities"], 16);
    assert_eq!(report["paths"], 8);
    assert_eq!(report["threads"], 2);
    assert_eq!(report["implementation"], "fast");
    let time_ms = report["time_ms"].as_f64().unwrap();
    assert!(time_ms > 0.0 && time_ms < 10_000.0, "time {time_ms}");
    assert!(report["working_memory_bytes"].as_u64().unwrap() > 0);

    let pfm = io::read_pfm(&out).unwrap();
    assert_eq!((pfm.width, pfm.height), (384, 288));
    assert!(pfm.values.iter().all(|&v| v == f32::INFINITY || (0.0..=15.0).contains(&v)));
    let invalid = pfm.values.iter().filter(|v| v.is_infinite()).count() as f64 / pfm.values.len() as f64;
    let reported = report["invalid_fraction"].as_f64().unwrap();
    assert!((invalid - reported).abs() < 1e-12, "PFM {invalid} vs JSON {reported}");
    assert!(reported < 0.5, "invalid fraction {reported}");
    // The CLI's default is exactly the library's default configuration.
    assert!(pfm.values == expected_tsukuba(), "CLI output differs from fast::compute with the default config");
}

#[test]
fn human_summary_and_reference() {
    let out = out_path("tsukuba_reference.pfm");
    let out_str = out.display().to_string();
    let output = sgm(&[
        "--left",
        &tsukuba("imL.png"),
        "--right",
        &tsukuba("imR.png"),
        "--disparities",
        "16",
        "--out",
        &out_str,
        "--reference",
    ]);
    assert!(output.status.success(), "{}", stderr(&output));
    let stdout = String::from_utf8(output.stdout).unwrap();
    assert!(stdout.contains("time per frame:") && stdout.contains(" ms"), "{stdout}");
    assert!(stdout.contains("reference matcher"), "{stdout}");
    assert!(stdout.contains("invalid pixels:"), "{stdout}");
    // `--reference` runs the reference with the default configuration...
    let written = io::read_pfm(&out).unwrap().values;
    let direct = reference::compute(
        &io::read_gray_png(tsukuba("imL.png")).unwrap(),
        &io::read_gray_png(tsukuba("imR.png")).unwrap(),
        &SgmConfig { disparities: 16, ..Default::default() },
    )
    .unwrap();
    assert!(written == io::disparity_to_pfm_values(&direct), "--reference differs from reference::compute");
    // ...and so gives the same file as the default fast matcher (their contract: bit-identical).
    let fast = expected_tsukuba();
    let differing = written.iter().zip(&fast).filter(|(a, b)| a.to_bits() != b.to_bits()).count();
    assert_eq!(differing, 0, "sgm --reference and sgm (fast) differ in {differing} pixels");
}

#[test]
fn four_paths() {
    let out = out_path("tsukuba_four.pfm");
    let out_str = out.display().to_string();
    let l = tsukuba("imL.png");
    let r = tsukuba("imR.png");
    let output =
        sgm(&["--left", &l, "--right", &r, "--disparities", "16", "--out", &out_str, "--paths", "4", "--json"]);
    assert!(output.status.success(), "{}", stderr(&output));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["paths"], 4);
    assert!(io::read_pfm(&out).unwrap().values != expected_tsukuba(), "4 paths should differ from 8");
}

#[test]
fn usage_errors_exit_2() {
    let l = tsukuba("imL.png");
    let r = tsukuba("imR.png");
    let out = out_path("never_written.pfm").display().to_string();
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (vec!["--left", &l, "--right", &r, "--disparities", "17", "--out", &out], "disparities 17"),
        (vec!["--left", &l, "--right", &r, "--disparities", "0", "--out", &out], "disparities 0"),
        (vec!["--left", &l, "--right", &r, "--disparities", "512", "--out", &out], "disparities 512"),
        (vec!["--left", &l, "--right", &r, "--disparities", "many", "--out", &out], "'many'"),
        (vec!["--left", &l, "--right", &r, "--out", &out], "missing --disparities"),
        (vec!["--left", &l, "--right", &r, "--disparities", "16"], "missing --out"),
        (vec!["--right", &r, "--disparities", "16", "--out", &out], "missing --left"),
        (vec!["--left", &l, "--right", &r, "--disparities", "16", "--out", &out, "--paths", "6"], "4 or 8"),
        (vec!["--left", &l, "--right", &r, "--disparities", "16", "--out", &out, "--threads", "0"], "--threads"),
        (vec!["--left", &l, "--right", &r, "--disparities", "16", "--out", &out, "--bogus"], "--bogus"),
        (vec!["--left"], "--left"),
    ];
    for (args, needle) in cases {
        let output = sgm(&args);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {}", stderr(&output));
        let message = stderr(&output);
        assert!(message.contains(needle), "{args:?}: stderr lacks {needle:?}: {message}");
        assert!(message.contains("usage: sgm"), "{message}");
    }
    let help = sgm(&["--help"]);
    assert_eq!(help.status.code(), Some(0));
    assert!(String::from_utf8_lossy(&help.stdout).contains("usage: sgm"));
}

#[test]
fn runtime_errors_exit_1() {
    let l = tsukuba("imL.png");
    let out = out_path("runtime_error.pfm").display().to_string();
    let missing = tsukuba("no_such_image.png");
    let output = sgm(&["--left", &l, "--right", &missing, "--disparities", "16", "--out", &out]);
    assert_eq!(output.status.code(), Some(1), "{}", stderr(&output));
    assert!(stderr(&output).contains("no_such_image.png"), "{}", stderr(&output));

    // tsukuba's left with teddy's right: 384x288 vs 450x375.
    let teddy = default_data_root().join("middlebury_v2/teddy/imR.png").display().to_string();
    let output = sgm(&["--left", &l, "--right", &teddy, "--disparities", "16", "--out", &out]);
    assert_eq!(output.status.code(), Some(1), "{}", stderr(&output));
    let message = stderr(&output);
    assert!(message.contains("384") && message.contains("450"), "{message}");

    // A text file is no PNG.
    let info = tsukuba("info.txt");
    let output = sgm(&["--left", &l, "--right", &info, "--disparities", "16", "--out", &out]);
    assert_eq!(output.status.code(), Some(1), "{}", stderr(&output));
    assert!(stderr(&output).contains("info.txt"), "{}", stderr(&output));

    // An output in a directory that does not exist.
    let bad_out = out_path("no_dir").join("x").join("d.pfm").display().to_string();
    let r = tsukuba("imR.png");
    let output = sgm(&["--left", &l, "--right", &r, "--disparities", "16", "--out", &bad_out]);
    assert_eq!(output.status.code(), Some(1), "{}", stderr(&output));
    assert!(stderr(&output).contains("d.pfm"), "{}", stderr(&output));
}
