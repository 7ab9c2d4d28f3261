//! Navigation's metric for obstacle classification (`sil::obstacles::traverse`): the rover drives
//! at every rock taller than h_max and every negative-edge section (≥ 0.3 m drop) of simulated
//! worlds, and each counts as found when it is in the rolling local obstacle map before the
//! rover is within stopping distance.
//!
//! Run: `cargo run --release -p sil --example hazard_traverse -- [--scenarios moon,mars]
//! [--seeds N] [--first-seed K] [--gaze on|off] [--true-depth] [--bridge PX] [--hidden-drop M] [--release-unseen] [--frame-every S] [--only rocks|edges]
//! [--max-targets K] [--max-edges K] [--size M] [--profiles] [--json FILE]`. `--profiles` prints every drive with the
//! true ground along its path (misses are always printed).

use std::io::Write;

use sil::obstacles::traverse::{CLEAR_EXCESS_M, Traverse, TraverseOptions, TraverseTally, traverse_paths};
use sil::obstacles::{Aim, Truth, preset_world};
use vision::obstacles::ObstacleConfig;

struct Args {
    scenarios: Vec<String>,
    seeds: u64,
    /// Seeds `first_seed ..= first_seed + seeds - 1`.
    first_seed: u64,
    options: TraverseOptions,
    config: ObstacleConfig,
    max_targets: Option<usize>,
    /// Every rock, and at most this many edge targets per world (in the order along the rims).
    max_edges: Option<usize>,
    /// Drive at rocks only or edges only (both: `None`).
    only: Option<Aim>,
    size_m: f64,
    json: Option<String>,
    /// Print every drive's line, not only the misses.
    profiles: bool,
}

fn parse() -> Result<Args, String> {
    let mut args = Args {
        scenarios: vec!["moon".into(), "mars".into()],
        seeds: 5,
        first_seed: 1,
        options: TraverseOptions::default(),
        config: ObstacleConfig::default(),
        max_targets: None,
        max_edges: None,
        only: None,
        size_m: 60.0,
        json: None,
        profiles: false,
    };
    let mut it = std::env::args().skip(1);
    while let Some(flag) = it.next() {
        let mut value = || it.next().ok_or_else(|| format!("{flag} needs a value"));
        let number = |v: String| v.parse::<f64>().map_err(|e| format!("{v}: {e}"));
        match flag.as_str() {
            "--scenarios" => args.scenarios = value()?.split(',').map(str::to_owned).collect(),
            "--seeds" => args.seeds = number(value()?)? as u64,
            "--first-seed" => args.first_seed = number(value()?)? as u64,
            "--gaze" => {
                args.options.gaze = match value()?.as_str() {
                    "on" => Some(onboard::nodes::gaze::GazeOptions::lru()),
                    "off" => None,
                    other => return Err(format!("--gaze: expected on or off, got {other:?}")),
                }
            }
            "--true-depth" => args.options.true_depth = true,
            "--bridge" => args.config.bridge_invalid_px = number(value()?)? as usize,
            "--hidden-drop" => args.config.hidden_drop_m = number(value()?)?,
            "--release-unseen" => args.config.release_unseen_edges = true,
            "--frame-every" => args.options.frame_every_s = number(value()?)?,
            "--start" => args.options.start_m = number(value()?)?,
            "--only" => {
                args.only = match value()?.as_str() {
                    "rocks" => Some(Aim::Rock),
                    "edges" => Some(Aim::Edge),
                    other => return Err(format!("--only: expected rocks or edges, got {other:?}")),
                }
            }
            "--max-targets" => args.max_targets = Some(number(value()?)? as usize),
            "--max-edges" => args.max_edges = Some(number(value()?)? as usize),
            "--size" => args.size_m = number(value()?)?,
            "--json" => args.json = Some(value()?),
            "--profiles" => args.profiles = true,
            other => return Err(format!("unknown argument {other:?}")),
        }
    }
    Ok(args)
}

fn pct(found: usize, of: usize) -> String {
    if of == 0 { "-".into() } else { format!("{:.1} % ({found}/{of})", 100.0 * found as f64 / of as f64) }
}

fn row(name: &str, t: &TraverseTally) -> String {
    format!(
        "{name:<9} rocks ≥ h_max+{CLEAR_EXCESS_M}: {:<17} rocks > h_max: {:<17} edges: {:<17} steep edges: {:<17} precision: {:<20} false cells beside {} / falling {} / open {}, frames {}",
        pct(t.rocks_clear.1, t.rocks_clear.0),
        pct(t.rocks.1, t.rocks.0),
        pct(t.edges.1, t.edges.0),
        pct(t.edges_steep.1, t.edges_steep.0),
        pct(t.cells_true, t.hazard_cells),
        t.cells_beside,
        t.cells_falling,
        t.hazard_cells - t.cells_true - t.cells_beside - t.cells_falling,
        t.frames
    )
}

fn main() -> Result<(), String> {
    let args = parse()?;
    let o = args.options;
    println!(
        "drive {} m/s, stopping distance {:.2} m (reaction {} s, {} m/s²), pairs every {} s from {} m, gaze {}, depth {}, bridge {} px, hidden drop {} m, unseen edges {}",
        o.drive.speed_mps,
        o.drive.stopping_distance_m(),
        o.drive.reaction_s,
        o.drive.deceleration_mps2,
        o.frame_every_s,
        o.start_m,
        if o.gaze.is_some() { "on" } else { "off" },
        if o.true_depth { "exact" } else { "SGM" },
        args.config.bridge_invalid_px,
        args.config.hidden_drop_m,
        if args.config.release_unseen_edges { "released" } else { "held" }
    );
    let mut total = TraverseTally::default();
    let mut per_world = Vec::new();
    let mut misses = Vec::new();
    for scenario in &args.scenarios {
        let mut scenario_total = TraverseTally::default();
        for seed in args.first_seed..args.first_seed + args.seeds {
            let started = std::time::Instant::now();
            let world = preset_world(scenario, seed, args.size_m).map_err(|e| e.to_string())?;
            let all = Truth::of(&world, args.config.max_step_m);
            let mut targets = all.clone();
            targets.keep_drops(&world, o.edge_drop_m);
            let mut paths = traverse_paths(&world, &targets, &args.config, &o, seed);
            if let Some(aim) = args.only {
                paths.retain(|p| p.aim == aim);
            }
            if let Some(k) = args.max_edges {
                let mut edges = 0;
                paths.retain(|p| {
                    edges += usize::from(p.aim == Aim::Edge);
                    p.aim == Aim::Rock || edges <= k
                });
            }
            if let Some(k) = args.max_targets {
                // Rocks first: they are few; then edges up to the cap.
                paths.sort_by_key(|p| p.aim != Aim::Rock);
                paths.truncate(k);
            }
            let mut traverse = Traverse::new(&world, &all, args.config, o).map_err(|e| e.to_string())?;
            let mut tally = TraverseTally::default();
            for (k, path) in paths.iter().enumerate() {
                let outcome = traverse.drive(path, seed * 1_000_000 + k as u64 * 1000).map_err(|e| e.to_string())?;
                let profile = path.profile_m(&world, args.config.max_slope_rad);
                if args.profiles || !outcome.found_at_stop {
                    misses.push(format!(
                        "{} {scenario} seed {seed} {:?} at ({:.1}, {:.1}) yaw {:.2} rise {:.2} m drop ahead {:.2} m (steep {:.2} m) excess {:.2} m: first marked at {}",
                        if outcome.found_at_stop { "found" } else { "missed" },
                        outcome.aim,
                        path.target_m.x,
                        path.target_m.y,
                        path.yaw_rad,
                        profile.rise_m,
                        profile.drop_m,
                        profile.steep_drop_m,
                        outcome.excess_height_m,
                        outcome.first_found_m.map_or("never".into(), |d| format!("{d:.2} m"))
                    ));
                }
                tally.add(&outcome);
            }
            println!(
                "{}   ({} drives, {:.0} s)",
                row(&format!("{scenario} {seed}"), &tally),
                paths.len(),
                started.elapsed().as_secs_f64()
            );
            let _ = std::io::stdout().flush();
            scenario_total.merge(&tally);
            per_world.push((scenario.clone(), seed, tally));
        }
        println!("{}", row(scenario, &scenario_total));
        total.merge(&scenario_total);
    }
    println!("{}", row("all", &total));
    println!("found at any frame before the stop: rocks {}, edges {}", total.rocks_any, total.edges_any);
    for m in &misses {
        println!("{m}");
    }
    if let Some(path) = args.json {
        let worlds: Vec<serde_json::Value> = per_world
            .iter()
            .map(|(s, seed, t)| {
                serde_json::json!({
                    "scenario": s, "seed": seed,
                    "rocks_clear": [t.rocks_clear.0, t.rocks_clear.1], "rocks": [t.rocks.0, t.rocks.1],
                    "edges": [t.edges.0, t.edges.1], "edges_steep": [t.edges_steep.0, t.edges_steep.1],
                    "hazard_cells": t.hazard_cells, "cells_true": t.cells_true, "cells_listed": t.cells_listed,
                    "cells_beside": t.cells_beside, "cells_falling": t.cells_falling, "frames": t.frames,
                })
            })
            .collect();
        std::fs::write(&path, serde_json::to_string_pretty(&worlds).map_err(|e| e.to_string())?)
            .map_err(|e| format!("{path}: {e}"))?;
    }
    Ok(())
}
