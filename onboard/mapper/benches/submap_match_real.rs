//! `submap-match` against Open3D (FPFH + RANSAC + point-to-point ICP,
//! `scripts/open3d_register.py` in the project venv) on the real pairs of `data/pointcloud/`: the
//! bunny, the lidar pair, and the lidar pair with the source turned by a further 30° of yaw.
//!
//! `cargo bench -p mapper --features cli --bench submap_match_real` prints the table the mapper
//! README quotes: per pair and tool, success as the tool reports it, rotation and translation
//! error against the pair's reference, wall time (median of 3 runs; both without file reading),
//! and the ratio of our time to Open3D's. Both run on one thread (`OMP_NUM_THREADS=1` for
//! Open3D; our matcher is single-threaded) at the same resolution (`RealPair::voxel_m`).
//! Without `--bench` (as `cargo test --all-targets` runs it): one run of the bunny only.

#![allow(clippy::unwrap_used, reason = "benchmark: a panic is a failed run with its message")]

#[path = "../tests/common/real_pairs.rs"]
mod real_pairs;

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};

use real_pairs::{RealPair, bunny, errors, json_transform, lidar, lidar_yawed, run_ours};

const EXE: &str = env!("CARGO_BIN_EXE_submap-match");

/// One tool's result on one pair.
#[derive(Debug)]
struct Outcome {
    success: bool,
    /// Rotation (deg) and translation (m) error of the reported transform, when there is one.
    errors: Option<(f64, f64)>,
    /// Median over the runs.
    time_ms: f64,
    note: String,
}

fn median(mut values: Vec<f64>) -> f64 {
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn ours(pair: &RealPair, runs: usize) -> Outcome {
    let results: Vec<_> = (0..runs).map(|_| run_ours(EXE, pair)).collect();
    let (_, first) = &results[0];
    let success = first["found"].as_bool().unwrap();
    let note = if success {
        format!("{} inliers, rmse {:.1} mm", first["inliers"], first["rmse_m"].as_f64().unwrap() * 1e3)
    } else {
        format!("rejection: {}", first["rejection"].as_str().unwrap_or("?"))
    };
    Outcome {
        success,
        errors: json_transform(first).map(|t| errors(&t, &pair.t_target_source)),
        time_ms: median(results.iter().map(|(_, j)| j["time_ms"].as_f64().unwrap()).collect()),
        note,
    }
}

fn open3d(python: &Path, pair: &RealPair, runs: usize) -> Result<Outcome, String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/open3d_register.py");
    let mut results = Vec::new();
    for _ in 0..runs {
        let output = Command::new(python)
            .env("OMP_NUM_THREADS", "1")
            .arg(&script)
            .arg(&pair.source)
            .arg(&pair.target)
            .arg("--voxel-m")
            .arg(pair.voxel_m.to_string())
            .output()
            .map_err(|e| format!("{}: {e}", python.display()))?;
        if !output.status.success() {
            return Err(format!("open3d_register.py on {}: {}", pair.name, String::from_utf8_lossy(&output.stderr)));
        }
        let json: serde_json::Value = serde_json::from_slice(&output.stdout).map_err(|e| e.to_string())?;
        results.push(json);
    }
    let first = &results[0];
    Ok(Outcome {
        success: first["success"].as_bool().unwrap_or(false),
        errors: json_transform(first).map(|t| errors(&t, &pair.t_target_source)),
        time_ms: median(results.iter().map(|j| j["time_ms"].as_f64().unwrap_or(f64::NAN)).collect()),
        note: format!(
            "fitness {:.2}, rmse {:.1} mm",
            first["fitness"].as_f64().unwrap_or(f64::NAN),
            first["inlier_rmse_m"].as_f64().unwrap_or(f64::NAN) * 1e3
        ),
    })
}

fn error_cells(outcome: &Outcome) -> (String, String) {
    match outcome.errors {
        Some((rotation_deg, translation_m)) => (format!("{rotation_deg:.3}"), format!("{:.1}", translation_m * 1e3)),
        None => ("–".to_owned(), "–".to_owned()),
    }
}

fn run(full: bool) -> Result<(), String> {
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    if !python.exists() {
        return Err(format!("{} is missing: run scripts/test (it creates the venv with open3d)", python.display()));
    }
    let tmp = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("submap_match_real");
    let (pairs, runs) = if full { (vec![bunny(), lidar(), lidar_yawed(&tmp)], 3) } else { (vec![bunny()], 1) };
    println!("| pair | tool | success | rotation error (°) | translation error (mm) | time (ms) | ours / Open3D | |");
    println!("|---|---|---|---:|---:|---:|---:|---|");
    for pair in &pairs {
        let ours = ours(pair, runs);
        let reference = open3d(&python, pair, runs)?;
        for (tool, outcome) in [("submap-match", &ours), ("Open3D 0.20", &reference)] {
            let (rotation, translation) = error_cells(outcome);
            let ratio =
                if tool == "submap-match" { format!("{:.2}", ours.time_ms / reference.time_ms) } else { String::new() };
            println!(
                "| {} | {tool} | {} | {rotation} | {translation} | {:.0} | {ratio} | {} |",
                pair.name,
                if outcome.success { "yes" } else { "no" },
                outcome.time_ms,
                outcome.note
            );
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    // `cargo bench` passes `--bench`; `cargo test --all-targets` does not: then a smoke run only.
    let full = std::env::args().any(|a| a == "--bench");
    match run(full) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("submap_match_real: {message}");
            ExitCode::FAILURE
        }
    }
}
