//! Multi-robot SLAM front-end on simulated 2-robot Moon runs (issue 9): the thesis's
//! local-reference topology against the sequential-odometry topology on the same data (thesis
//! Table 8.6), and the multi-robot estimate against single-robot SLAM per robot (Table 8.9);
//! errors of the online estimates (what each robot had at each moment).
//!
//! LOOP CLOSURES FROM GROUND TRUTH: detections and submap matches come from the test-only
//! `sim::truth_constraints` source (the thesis's noise models), not from a matcher or a marker
//! detector. The filter data is real: VIO on rendered stereo, IMU and wheels.
//!
//! `cargo run --release -p sil --example sim_team_slam -- [--seeds 10] [--first-seed 1]
//!  [--duration 300] [--downscale 2] [--cache runs/team_slam]`
//! (with `--cache`, each seed's filter record is written once and read back on later runs).

use std::path::PathBuf;

use mapper::slam::Topology;
use sil::slam_eval::{self, ExchangeOptions, RobotResult, Variant};
use sil::team_record::{self, TeamRecordOptions};

const VARIANTS: [Variant; 5] = [
    Variant::Multi(Topology::LocalReference),
    Variant::Multi(Topology::SequentialOdometry),
    Variant::Single(Topology::LocalReference),
    Variant::Single(Topology::SequentialOdometry),
    Variant::FilterOnly,
];

struct Args {
    seeds: u64,
    first_seed: u64,
    duration_s: f64,
    downscale: u32,
    cache: Option<PathBuf>,
}

fn parse_args() -> Result<Args, lexopt::Error> {
    use lexopt::prelude::*;
    let mut args = Args { seeds: 10, first_seed: 1, duration_s: 300.0, downscale: 2, cache: None };
    let mut parser = lexopt::Parser::from_env();
    while let Some(arg) = parser.next()? {
        match arg {
            Long("seeds") => args.seeds = parser.value()?.parse()?,
            Long("first-seed") => args.first_seed = parser.value()?.parse()?,
            Long("duration") => args.duration_s = parser.value()?.parse()?,
            Long("downscale") => args.downscale = parser.value()?.parse()?,
            Long("cache") => args.cache = Some(parser.value()?.parse()?),
            _ => return Err(arg.unexpected()),
        }
    }
    Ok(args)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args = parse_args()?;
    println!("LOOP CLOSURES FROM GROUND TRUTH (sim::truth_constraints, test-only): detections and matches");
    println!("are drawn from the simulator's truth with the thesis's noise models; the filter data is real VIO.\n");
    let mut all: Vec<(u64, RobotResult)> = Vec::new();
    for seed in args.first_seed..args.first_seed + args.seeds {
        let options = TeamRecordOptions {
            robots: 2,
            duration_s: args.duration_s,
            seed,
            downscale: args.downscale,
            ..TeamRecordOptions::default()
        };
        let world = team_record::moon_team_world(&options)?;
        let dir = args.cache.as_ref().map(|c| c.join(format!("seed{seed}")));
        let records = match &dir {
            Some(dir) if dir.exists() => team_record::read_team(dir)?,
            _ => {
                let records = team_record::record_team(&world, &options)?;
                if let Some(dir) = &dir {
                    team_record::write_team(dir, &records)?;
                }
                records
            }
        };
        let exchange = ExchangeOptions {
            truth: sim::truth_constraints::TruthConstraintConfig { seed, ..Default::default() },
            ..ExchangeOptions::default()
        };
        let log = slam_eval::exchange(&world, &records, &exchange)?;
        println!(
            "seed {seed}: {} detections, {} match attempts, {} matches ({} inter-robot, {} outliers)",
            log.detections, log.match_attempts, log.matches, log.inter_robot_matches, log.outlier_matches
        );
        for record in &records {
            for variant in VARIANTS {
                let Some(result) =
                    slam_eval::evaluate(&world, record, &log.received[record.robot], variant, exchange.truth)?
                else {
                    continue;
                };
                let (nodes, factors) = result.size.thesis_formula();
                println!(
                    "  robot {} {:<28} driven {:6.1} m  mean {:6.3} m  max {:6.3} m  final {:6.3} m  yaw {:5.2}°  \
                     graph {:3} nodes {:3} factors{}  connected {:?}",
                    record.robot,
                    variant.name(),
                    result.distance_m,
                    result.position.mean,
                    result.position.max,
                    result.final_error_m,
                    result.yaw.mean.to_degrees(),
                    result.size.nodes,
                    result.size.factors,
                    if (nodes, factors) == (result.size.nodes, result.size.factors) {
                        ""
                    } else {
                        " (FORMULA MISMATCH)"
                    },
                    result.connected,
                );
                all.push((seed, result));
            }
        }
    }
    summarize(&all);
    Ok(())
}

fn mean_of(all: &[(u64, RobotResult)], variant: Variant) -> Vec<f64> {
    all.iter().filter(|(_, r)| r.variant == variant).map(|(_, r)| r.position.mean).collect()
}

fn summarize(all: &[(u64, RobotResult)]) {
    println!("\nMean over seeds and robots of each run's mean online 3D error (ground-truth loop closures):");
    for variant in VARIANTS {
        let v = mean_of(all, variant);
        let yaw: Vec<f64> =
            all.iter().filter(|(_, r)| r.variant == variant).map(|(_, r)| r.yaw.mean.to_degrees()).collect();
        if v.is_empty() {
            continue;
        }
        println!(
            "  {:<28} {:6.3} m   yaw {:5.2}°   ({} runs)",
            variant.name(),
            v.iter().sum::<f64>() / v.len() as f64,
            yaw.iter().sum::<f64>() / yaw.len() as f64,
            v.len()
        );
    }
    // Thesis style: the mean of the per-run relative improvements.
    let improvement = |better: Variant, worse: Variant| {
        let (b, w) = (mean_of(all, better), mean_of(all, worse));
        let ratios: Vec<f64> = b.iter().zip(&w).map(|(b, w)| 1.0 - b / w).collect();
        100.0 * ratios.iter().sum::<f64>() / ratios.len().max(1) as f64
    };
    println!(
        "  local reference vs sequential odometry (multi): {:+.1} % lower error (thesis: 15 %)",
        improvement(Variant::Multi(Topology::LocalReference), Variant::Multi(Topology::SequentialOdometry))
    );
    println!(
        "  multi-robot vs single-robot (local reference):  {:+.1} % lower error (thesis Exp. #2: 82 %/75 %)",
        improvement(Variant::Multi(Topology::LocalReference), Variant::Single(Topology::LocalReference))
    );
    println!(
        "  multi-robot vs filter only:                      {:+.1} % lower error",
        improvement(Variant::Multi(Topology::LocalReference), Variant::FilterOnly)
    );
}
