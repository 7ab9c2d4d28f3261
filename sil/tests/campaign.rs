//! `sil campaign` on the beginning of one experiment in all three variants: each variant's
//! mission runs with its own back-end and the report puts them side by side, with pictures.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use sil::campaign::{self, CampaignOptions, Variant};
use sim::scenario::experiments;

#[test]
fn a_campaign_runs_every_variant_and_reports_them_side_by_side() {
    let out = std::env::temp_dir().join(format!("sil-campaign-{}", std::process::id()));
    let options = CampaignOptions {
        out: out.clone(),
        experiments: vec![experiments::find("lab-rocks").unwrap()],
        variants: Variant::ALL.to_vec(),
        downscale: 4,
        duration_s: Some(15.0),
        step_threads: 2,
        progress: false,
    };
    let result = campaign::run(&options).unwrap();
    assert_eq!(result.runs.len(), 3);
    for run in &result.runs {
        let dir = out.join("lab-rocks").join(run.variant.name());
        assert!(dir.join("report.json").exists(), "{} has no report", dir.display());
        assert_eq!(run.report.scenario, "lab-rocks");
        assert_eq!(run.report.duration_s, 15.0);
        for robot in &run.report.robots {
            // Alone, a robot's frame holds only itself; with the radio the two meet at the start.
            let expected = if run.variant == Variant::Solo { vec![robot.robot] } else { vec![1, 2] };
            assert_eq!(robot.connected, expected, "{:?} robot {}", run.variant, robot.robot);
        }
    }
    // The team run's graph inputs replayed into the thesis's variants: the multi-robot local-
    // reference replay rebuilds the live graph exactly; alone or as a bare filter chain, the
    // robot's graph loses the other robot and its detections.
    let team = result.runs.iter().find(|r| r.variant == Variant::Team).unwrap();
    for robot in &team.report.robots {
        let names: Vec<&str> = robot.replays.iter().map(|v| v.variant).collect();
        assert_eq!(
            names,
            ["multi, local reference", "multi, sequential odometry", "single, local reference", "filter only"]
        );
        let live = &robot.replays[0];
        assert_eq!((live.nodes, live.factors), (robot.graph_nodes, robot.graph_factors), "robot {}", robot.robot);
        for v in &robot.replays {
            assert!(v.score.is_some(), "robot {} {}: {:?}", robot.robot, v.variant, v.error);
        }
        let filter = &robot.replays[3];
        assert!(
            filter.factors < live.factors,
            "robot {}: filter {} vs live {}",
            robot.robot,
            filter.factors,
            live.factors
        );
    }
    for other in result.runs.iter().filter(|r| r.variant != Variant::Team) {
        assert!(other.report.robots.iter().all(|r| r.replays.is_empty()));
    }
    assert!(result.runs.iter().any(|r| r.variant == Variant::Truth && r.report.truth_loop_closures));
    assert!(result.runs.iter().any(|r| r.variant == Variant::Solo && r.report.solo));

    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("## lab-rocks (moon site, seed 11, 15 s; after Tab. 8.8 #1"), "{md}");
    for column in ["team robot 1", "team robot 2", "solo robot 1", "solo robot 2", "truth robot 1", "truth robot 2"] {
        assert!(md.contains(column), "no column {column}: {md}");
    }
    for row in ["| mean 3D error [m] |", "| map matches inter-robot |", "| robot detections made |"] {
        let line = md.lines().find(|l| l.starts_with(row)).unwrap_or_else(|| panic!("no row {row}: {md}"));
        assert_eq!(line.matches('|').count(), 8, "{line}");
    }
    assert!(md.contains("The team run's graph inputs replayed"), "{md}");
    for row in ["| sent, all links [KB/s] |", "| of it submaps [KB/s] |", "| matcher attempts / accepted |"] {
        let line = md.lines().find(|l| l.starts_with(row)).unwrap_or_else(|| panic!("no row {row}: {md}"));
        assert_eq!(line.matches('|').count(), 8, "{line}");
    }
    // The team's robots talk (markers, poses, telemetry): some bytes per second on their links;
    // the solo robots have no team link but still the ground's.
    let sent = md.lines().find(|l| l.starts_with("| sent, all links [KB/s] |")).unwrap();
    let rates: Vec<f64> = sent.split('|').filter_map(|c| c.trim().parse().ok()).collect();
    assert!(rates.len() == 6 && rates.iter().all(|&r| r > 0.0), "{sent}");
    let runtime = md.lines().skip_while(|l| !l.starts_with("Team run, time in each process")).nth(2).unwrap();
    assert!(runtime.contains("vision") && runtime.contains("mapper"), "{runtime}");
    for variant in ["| team | 2 |", "| solo | 2 |", "| truth | 2 |", "| replayed: filter only | 2 |"] {
        assert!(md.contains(variant), "summary lacks {variant}: {md}");
    }
    // The thesis's runtime table: every robot updated its graph and integrated its images.
    for row in ["| graph update (iSAM2) | 1.7 / 162 |", "| submap integration of one depth image | 10 / 40 |"] {
        let line = md.lines().find(|l| l.starts_with(row)).unwrap_or_else(|| panic!("no row {row}: {md}"));
        assert_eq!(line.matches("×)").count(), 2, "{line}");
    }
    // Pictures: each run's trajectories, the experiment's error over time with the team's loop
    // closures (the robots detect each other at the start) marked, all embedded in the report.
    for robot in &team.report.robots {
        assert!(
            robot.closure_events.iter().any(|e| e.kind == sil::mission::events::ClosureKind::Detection),
            "robot {}: {:?}",
            robot.robot,
            robot.closure_events
        );
    }
    let error = std::fs::read_to_string(out.join("lab-rocks/error.svg")).unwrap();
    assert_eq!(error.matches("<path").count(), 6, "three variants per robot");
    assert!(error.contains(">detection<"), "no detection in the legend");
    assert!(md.contains("![error over time](lab-rocks/error.svg)"), "{md}");
    for variant in ["team", "solo", "truth"] {
        let svg = std::fs::read_to_string(out.join("lab-rocks").join(variant).join("trajectories.svg")).unwrap();
        assert_eq!(svg.matches("<path").count(), 4, "{variant}: truth and estimate per robot");
        assert!(md.contains(&format!("![{variant} trajectories](lab-rocks/{variant}/trajectories.svg)")), "{md}");
    }
    std::fs::remove_dir_all(&out).ok();
}
