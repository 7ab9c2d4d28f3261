//! Accuracy on the Middlebury scenes (bad-pixel rate, non-occluded pixels, 1 px), of exactly
//! what the CLI outputs by default, against regression thresholds. (`middlebury_vs_opencv.rs`
//! compares the same numbers with OpenCV StereoSGBM.)
//!
//! Run with `--nocapture` to see the tables (BENCHMARKS.md quotes them).

#![allow(clippy::unwrap_used, reason = "test helpers: a panic is a failed test with its message")]

mod common;

use common::{ours_percent, scenes};
use fpga_model::eval::DEFAULT_THRESHOLD_PX;

/// Regression thresholds in percent: measured with the default configuration plus 0.5
/// percentage points (so a real loss of accuracy fails, noise-free as the core is integer).
/// Measured: tsukuba 3.61, teddy 6.80, cones 4.44, Reindeer 6.47.
const THRESHOLDS_PERCENT: [(&str, f64); 4] = [("tsukuba", 4.1), ("teddy", 7.3), ("cones", 4.9), ("Reindeer", 7.0)];

#[test]
fn default_config_regression() {
    println!("\nours (default config, fast::Matcher), bad pixels nonocc > {DEFAULT_THRESHOLD_PX} px:");
    println!("| scene | D | evaluated px | bad % | threshold % |");
    println!("|---|---:|---:|---:|---:|");
    let mut failures = Vec::new();
    for scene in scenes() {
        let ours = ours_percent(&scene);
        let (_, threshold) = THRESHOLDS_PERCENT.iter().find(|(name, _)| *name == scene.name).copied().unwrap();
        println!(
            "| {} | {} | {} | {ours:.2} | {threshold:.1} |",
            scene.name,
            scene.disparities,
            scene.evaluated_pixels()
        );
        if ours > threshold {
            failures.push(format!("{}: {ours:.2} % > {threshold} %", scene.name));
        }
    }
    assert!(failures.is_empty(), "accuracy regressed: {failures:?}");
}
