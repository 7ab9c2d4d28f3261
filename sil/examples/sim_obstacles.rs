#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Obstacle classification against the simulator's ground truth (thesis §5.1.1), the command
//! line of [`sil::obstacles`] (what is evaluated, the truth and the matching are described
//! there): deliberate viewpoints 2.5–4.5 m from each true obstacle of a Moon world plus random
//! open viewpoints, or with `--approach` straight approach runs towards each target.
//!
//! Experiments: `--true-depth` classifies the renderer's exact depth instead of SGM's (the
//! classifier's own ceiling); `--steep-edges` keeps only the edge discs where the true ground
//! drops by more than `h_max` at more than the slope limit (the sim's crater-edge list also holds
//! rims one may drive down); `--tilt RAD` tilts the head down by another angle than mounted;
//! `--approach-to M` ends the approach runs at M m instead of 2.5 m.
//!
//! Run: `cargo run --release -p sil --example sim_obstacles -- [--seeds N] [--per-target K]
//! [--open M] [--dump]`; the stereo defaults are the on-board ones (`vision::depth_sgm_config`,
//! `SpeckleFilter::for_image`), changed with `[--uniqueness PCT] [--lr-diff PX] [--lr-strict]
//! [--speckle PX (0 = off)] [--speckle-step PX]`; the classifier's with `[--pixel-error PX]
//! [--support K] [--min-cluster N] [--window N]`; the worlds' side with `[--size M]` (60 m). `--diagnose` prints where SGM fails on
//! negative edges (every 20th viewpoint, or each missed edge run) and writes the marked left
//! image to the temp directory.

use nalgebra::Point2;
use sil::obstacles::report::{
    approach_lines, classify_line, disparity_summary, false_cluster_line, false_cluster_summary, range_lines,
    rock_height_lines, tally_row,
};
use sil::obstacles::{
    APPROACH_M, Aim, DISTANCES_M, Evaluator, RunOutcome, Tally, Truth, approaches, moon_world, viewpoints,
};
use vision::obstacles::ObstacleConfig;
use vision::{SpeckleFilter, depth_sgm_config};

/// Prints what [`Evaluator::diagnose`] found and writes the marked image as the `dumps`-th view
/// into the temp directory.
fn diagnose(evaluator: &Evaluator<'_>, dumps: &mut usize) {
    *dumps += 1;
    let diagnosis = evaluator.diagnose();
    for e in &diagnosis.edge_samples {
        println!("   edge px ({},{}) sgm {:.2} true {:.2} disp {}", e.x, e.y, e.depth_m, e.true_depth_m, e.disparity);
    }
    let path = std::env::temp_dir().join(format!("sim_obstacles_view_{dumps}.png"));
    std::fs::write(path, diagnosis.image.to_png().unwrap()).unwrap();
    println!("  too-near SGM pixels by quarter (rows top→bottom, cols left→right): {:?}", diagnosis.near_bins);
    println!(
        "  negative-edge pixels {}, {} with SGM off by > 0.2 m: {:?}",
        diagnosis.edge_total, diagnosis.edge_wrong, diagnosis.edge_bins
    );
}

fn main() {
    let mut seeds = 3u64;
    let mut per_target = 3usize;
    let mut open = 20usize;
    let mut size_m = 60.0;
    let mut dump = false;
    let mut diagnose_views = false;
    let mut true_depth = false;
    let mut approach = false;
    let mut approach_m = APPROACH_M;
    let mut tilt_rad: Option<f64> = None;
    let mut steep_edges = false;
    let mut config = ObstacleConfig::default();
    let mut sgm = depth_sgm_config();
    let mut speckle_px: Option<usize> = None;
    let mut speckle_step_px = 1.0f32;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().and_then(|v| v.parse::<f64>().ok()).expect("a number");
        match arg.as_str() {
            "--seeds" => seeds = value() as u64,
            "--per-target" => per_target = value() as usize,
            "--open" => open = value() as usize,
            "--size" => size_m = value(),
            "--pixel-error" => config.pixel_error_px = value(),
            "--support" => config.step_support_cells = value() as usize,
            "--min-cluster" => config.min_step_cluster_cells = value() as usize,
            "--window" => config.window_cells = value() as usize,
            "--uniqueness" => sgm.uniqueness_percent = value() as u8,
            "--lr-diff" => sgm.lr_max_diff = value() as u8,
            "--lr-strict" => sgm.lr_lenient = false,
            "--speckle" => speckle_px = Some(value() as usize),
            "--speckle-step" => speckle_step_px = value() as f32,
            "--dump" => dump = true,
            "--diagnose" => diagnose_views = true,
            "--true-depth" => true_depth = true,
            "--approach" => approach = true,
            "--approach-to" => approach_m.1 = value(),
            "--tilt" => tilt_rad = Some(value()),
            "--steep-edges" => steep_edges = true,
            other => panic!("unknown argument {other}"),
        }
    }
    config.validate().expect("a valid configuration");
    println!(
        "SGM: uniqueness {} %, LR max diff {} px, lenient {}; speckle filter {} px within {speckle_step_px} px (0 = off)",
        sgm.uniqueness_percent,
        sgm.lr_max_diff,
        sgm.lr_lenient,
        speckle_px.map_or_else(|| "400 (at 1024x508, scaled)".to_string(), |px| px.to_string())
    );
    println!(
        "obstacles, Moon preset {size_m} m worlds: h_max {:.2} m, slope {:.0}°, window {} cells, support {}, min cluster {}, Δp {} px; {per_target} viewpoints per target at {DISTANCES_M:?} m, {open} open viewpoints per seed",
        config.max_step_m,
        config.max_slope_rad.to_degrees(),
        config.window_cells,
        config.step_support_cells,
        config.min_step_cluster_cells,
        config.pixel_error_px
    );
    let mut totals = [Tally::default(), Tally::default(), Tally::default()];
    let mut false_clusters = Vec::new();
    let mut outcomes: Vec<RunOutcome> = Vec::new();
    for seed in 1..=seeds {
        let world = moon_world(seed, size_m).expect("the Moon world");
        let mut truth = Truth::of(&world, config.max_step_m);
        if steep_edges {
            truth.keep_steep_edges(&world, config.max_step_m, config.max_slope_rad);
        }
        let tilt_rad = tilt_rad.unwrap_or(world.robots[0].setup.tilt_rad);
        let mut views = viewpoints(&world, &truth, per_target, open, seed);
        for view in &mut views {
            view.tilt_rad = tilt_rad;
        }
        let camera = world.robots[0].model().camera;
        let speckle = match speckle_px {
            None => Some(SpeckleFilter::for_image(camera.width_px as usize, camera.height_px as usize)),
            Some(0) => None,
            Some(px) => Some(SpeckleFilter::new(px, speckle_step_px)),
        };
        let mut evaluator = Evaluator::with_stereo(&world, &truth, config, sgm, speckle).expect("an evaluator");
        evaluator.true_depth = true_depth;
        // Diagnosis images are numbered per world: a later seed's overwrite an earlier one's.
        let mut dumps = 0;
        let mut tallies = [Tally::default(), Tally::default(), Tally::default()];
        if approach {
            let runs = approaches(&world, &truth, config.max_step_m, approach_m, tilt_rad, seed);
            for (r, run) in runs.iter().enumerate() {
                let outcome = evaluator
                    .drive(run, seed * 1_000_003 + (r * 64) as u64, &mut tallies[run.aim as usize])
                    .expect("an evaluated run");
                if diagnose_views && run.aim == Aim::Edge && outcome.found_at_m.is_none() {
                    let t = run.truth.first().map_or(Point2::origin(), |o| o.centre_m);
                    println!("edge run {r} missed, target ({:.2}, {:.2}), last frame:", t.x, t.y);
                    diagnose(&evaluator, &mut dumps);
                }
                outcomes.push(outcome);
            }
            println!("seed {seed}: {} approach runs", runs.len());
        } else {
            for (i, view) in views.iter().enumerate() {
                let slot = view.aim as usize;
                evaluator.evaluate(view, seed * 1_000_003 + i as u64, &mut tallies[slot]).expect("an evaluated view");
                if diagnose_views && i % 20 == 0 {
                    println!("viewpoint {i} {:?}", view.aim);
                    diagnose(&evaluator, &mut dumps);
                }
            }
            println!("seed {seed}: {} viewpoints", views.len());
        }
        println!("seed {seed}: {} rocks > h_max, {} edge targets", truth.rocks.len(), truth.edge_targets.len());
        for (name, t) in ["rock", "edge", "open"].iter().zip(&tallies) {
            println!("{}", tally_row(name, t));
        }
        for (total, t) in totals.iter_mut().zip(&tallies) {
            total.add(t);
        }
        false_clusters.extend(evaluator.false_clusters.drain(..).map(|c| (seed, c)));
    }
    println!("all seeds:");
    let mut all = Tally::default();
    for (name, t) in ["rock", "edge", "open"].iter().zip(&totals) {
        println!("{}", tally_row(name, t));
        all.add(t);
    }
    println!("{}", tally_row("all", &all));
    for line in rock_height_lines(&all).iter().chain(&range_lines(&all)) {
        println!("{line}");
    }
    if approach {
        for line in approach_lines(&outcomes, approach_m, tilt_rad) {
            println!("{line}");
        }
    }
    println!("{}", false_cluster_summary(&false_clusters, config.max_step_m));
    if dump {
        for (seed, c) in &false_clusters {
            println!("{}", false_cluster_line(*seed, c));
        }
    }
    println!("{}", disparity_summary(&all));
    if let Some(line) = classify_line(&all) {
        println!("{line}");
    }
}
