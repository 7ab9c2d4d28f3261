//! The acceptance criterion of the core's accuracy: on each Middlebury scene (bad-pixel rate,
//! non-occluded pixels, 1 px) exactly what the CLI outputs by default is no worse than OpenCV's
//! StereoSGBM at its best of the documented settings for that scene. OpenCV runs in this test
//! (`scripts/opencv_sgbm.py` in the project venv) on the same PNGs, and both are scored by the
//! same `fpga_model::eval` code. (`middlebury.rs` holds the regression thresholds.)
//!
//! Run with `--nocapture` to see the table (BENCHMARKS.md quotes it).

#![allow(clippy::unwrap_used, reason = "test helpers: a panic is a failed test with its message")]

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use common::{ours_percent, scenes};
use fpga_model::eval::{DEFAULT_THRESHOLD_PX, Scene};
use fpga_model::io;

/// The project venv's python (created by `scripts/test` from the project-level
/// `scripts/requirements.txt`).
fn venv_python() -> PathBuf {
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    assert!(
        python.exists(),
        "{} is missing: run scripts/test (it creates the venv with OpenCV) before this test",
        python.display()
    );
    python
}

/// Runs `opencv_sgbm.py accuracy` on the scenes; returns the output directory.
fn run_opencv_grid(scenes: &[Scene]) -> PathBuf {
    let out = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("opencv_sgbm_accuracy");
    if out.exists() {
        std::fs::remove_dir_all(&out).unwrap();
    }
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/opencv_sgbm.py");
    let mut command = Command::new(venv_python());
    command.arg(&script).arg("accuracy").arg("--out").arg(&out);
    for scene in scenes {
        command
            .arg("--scene")
            .arg(&scene.name)
            .arg(&scene.left_path)
            .arg(&scene.right_path)
            .arg(scene.disparities.to_string());
    }
    let output = command.output().unwrap();
    assert!(
        output.status.success(),
        "opencv_sgbm.py failed ({}); if OpenCV is missing run scripts/test:\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    out
}

fn settings_text(settings: &serde_json::Value) -> String {
    let keys =
        ["mode", "blockSize", "P1", "P2", "uniquenessRatio", "speckleWindowSize", "speckleRange", "disp12MaxDiff"];
    keys.iter().map(|k| format!("{k}={}", settings[*k])).collect::<Vec<_>>().join(" ").replace('"', "")
}

#[test]
fn ours_beats_opencv_best_setting() {
    let scenes = scenes();
    let out = run_opencv_grid(&scenes);
    let index: serde_json::Value = serde_json::from_slice(&std::fs::read(out.join("index.json")).unwrap()).unwrap();

    // Same pixels on both sides: OpenCV's gray conversion in the script must equal ours.
    for scene in &scenes {
        let info = &index["scenes"][&scene.name];
        let sum = |pixels: &[u8]| pixels.iter().map(|&p| u64::from(p)).sum::<u64>();
        assert_eq!(info["left_pixel_sum"].as_u64(), Some(sum(&scene.left.pixels)), "{} left gray", scene.name);
        assert_eq!(info["right_pixel_sum"].as_u64(), Some(sum(&scene.right.pixels)), "{} right gray", scene.name);
    }

    // Score every OpenCV result with the same eval code; keep the best per scene.
    let results = index["results"].as_array().unwrap();
    let mut best: BTreeMap<String, (f64, serde_json::Value, PathBuf)> = BTreeMap::new();
    for result in results {
        let name = result["scene"].as_str().unwrap();
        let scene = scenes.iter().find(|s| s.name == name).unwrap();
        let file = out.join(result["file"].as_str().unwrap());
        let pfm = io::read_pfm(&file).unwrap();
        assert_eq!((pfm.width, pfm.height), (scene.left.width, scene.left.height));
        let percent = 100.0 * scene.bad_pixel_rate(&pfm.values, DEFAULT_THRESHOLD_PX).unwrap();
        if best.get(name).is_none_or(|(b, _, _)| percent < *b) {
            best.insert(name.to_owned(), (percent, result["settings"].clone(), file.clone()));
        }
    }
    // The grid writes ~0.9 GB of PFMs: keep only each scene's best.
    for result in results {
        let file = out.join(result["file"].as_str().unwrap());
        if !best.values().any(|(_, _, kept)| *kept == file) {
            std::fs::remove_file(&file).unwrap();
        }
    }

    println!(
        "\nOpenCV {} StereoSGBM, {} settings per scene; bad pixels nonocc > {DEFAULT_THRESHOLD_PX} px:",
        index["opencv"].as_str().unwrap_or("?"),
        results.len() / scenes.len()
    );
    println!("| scene | D | ours % | OpenCV best % | OpenCV best setting |");
    println!("|---|---:|---:|---:|---|");
    let mut losses = Vec::new();
    for scene in &scenes {
        let ours = ours_percent(scene);
        let (theirs, settings, _) = &best[&scene.name];
        println!("| {} | {} | {ours:.2} | {theirs:.2} | {} |", scene.name, scene.disparities, settings_text(settings));
        if ours > *theirs {
            losses.push(format!(
                "{}: ours {ours:.2} % > OpenCV {theirs:.2} % ({})",
                scene.name,
                settings_text(settings)
            ));
        }
    }
    assert!(losses.is_empty(), "OpenCV's best setting beats our default on: {losses:?}");
}
