//! Fault tests of the process runner (issue 10): a 2-robot, 45 s mission in which robot index 1
//! (folder `robot1/`, report id 2) loses its `filter` to SIGKILL at 25 s, while it drives, and
//! its `mapper` at 31 s, after it finished several 1 m submaps. Robot index 0 runs undisturbed
//! as the control. One mission for both faults keeps the test within the machine's budget; each
//! fault is asserted on its own evidence (its process's restarts, pids and files).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use nalgebra::{Isometry3, Vector3};
use onboard::process::{NodeKind, read_json};
use serde_json::Value;
use sil::mission::process::read_tum;
use sil::mission::process::{Fault, robot_dir, run_mission_with_exe};
use sil::mission::{MissionOptions, Runner};

const FILTER_KILL_S: f64 = 25.0;
const MAPPER_KILL_S: f64 = 31.0;

fn process_record<'a>(supervisor: &'a Value, name: &str) -> &'a Value {
    supervisor["processes"].as_array().unwrap().iter().find(|p| p["process"] == name).unwrap()
}

fn u64s(value: &Value) -> Vec<u64> {
    value.as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect()
}

/// Position error vectors (estimate − truth) at equal stamps, ordered by stamp.
fn error_vectors(estimate: &[(u64, Isometry3<f64>)], truth: &[(u64, Isometry3<f64>)]) -> Vec<(u64, Vector3<f64>)> {
    let truth: std::collections::BTreeMap<u64, Isometry3<f64>> = truth.iter().copied().collect();
    estimate
        .iter()
        .filter_map(|(stamp, pose)| {
            // Both are written at camera stamps; allow a TUM round-off of a few nanoseconds.
            let (_, t) = truth.range(stamp.saturating_sub(1_000)..=stamp + 1_000).next()?;
            Some((*stamp, pose.translation.vector - t.translation.vector))
        })
        .collect()
}

#[test]
fn killed_filter_and_mapper_are_restarted_and_recover() {
    let out = std::env::temp_dir().join(format!("onboard-mission-faults-{}", std::process::id()));
    let options = MissionOptions {
        robots: 2,
        duration_s: 45.0,
        seed: 3,
        downscale: 4,
        out: out.clone(),
        runner: Runner::Process,
        submap_max_distance_m: Some(1.0),
        faults: vec![
            Fault { robot: 1, process: NodeKind::Filter, at_s: FILTER_KILL_S },
            Fault { robot: 1, process: NodeKind::Mapper, at_s: MAPPER_KILL_S },
        ],
        ..MissionOptions::default()
    };
    let wall = std::time::Instant::now();
    let report = run_mission_with_exe(&options, Path::new(env!("CARGO_BIN_EXE_sil"))).unwrap();
    println!("mission wall time {:.1} s", wall.elapsed().as_secs_f64());

    // The mission completed and wrote its report, both robots scored.
    assert!(out.join("report.json").exists() && out.join("report.md").exists());
    assert_eq!(report.robots.len(), 2);
    for r in &report.robots {
        let score = r.score.as_ref().unwrap_or_else(|| panic!("robot {} not scored: {:?}", r.robot, r.score_error));
        println!(
            "robot {}: mean error {:.3} m, max {:.3} m, {} poses",
            r.robot, score.mean_error_m, score.max_error_m, score.poses
        );
    }

    // Both kills happened, at their times, to a real pid.
    let faults = read_json(&out.join("faults.json")).unwrap();
    let faults = faults.as_array().unwrap();
    println!("faults: {faults:?}");
    assert_eq!(faults.len(), 2);
    for f in faults {
        assert!(f["error"].is_null(), "fault {f}");
        assert!(f["pid"].as_u64().is_some(), "fault {f}");
        let late_s = f["killed_at_s"].as_f64().unwrap() - f["at_s"].as_f64().unwrap();
        assert!((0.0..0.5).contains(&late_s), "fault {f} injected {late_s} s late");
    }
    let fault = |name: &str| faults.iter().find(|f| f["process"] == name).unwrap();

    let dir0 = robot_dir(&out, 0);
    let dir1 = robot_dir(&out, 1);
    for log in ["supervisor", "filter", "mapper"] {
        let text = std::fs::read_to_string(dir1.join("logs").join(format!("{log}.log"))).unwrap_or_default();
        println!("robot1/logs/{log}.log:\n{text}");
    }
    let supervisor0 = read_json(&dir0.join("supervisor.json")).unwrap();
    let supervisor1 = read_json(&dir1.join("supervisor.json")).unwrap();
    for kind in NodeKind::ALL {
        assert_eq!(process_record(&supervisor0, kind.name())["restarts"], 0, "control robot's {}", kind.name());
    }

    // --- filter: restarted, resumed from its checkpoint, no sample lost, same frame chain.
    let filter = process_record(&supervisor1, "filter");
    println!("supervisor filter: {filter}");
    assert!(filter["restarts"].as_u64().unwrap() >= 1);
    let pids = u64s(&filter["pids"]);
    assert_eq!(pids.first().copied(), fault("filter")["pid"].as_u64(), "the first filter was the one killed");
    assert!(pids.len() >= 2 && pids[0] != pids[1]);
    assert!(filter["exits"].as_array().unwrap().iter().any(|e| e == "signal SIGKILL"), "{filter}");
    let summary = read_json(&dir1.join("filter_summary.json")).unwrap();
    println!("filter summary after the restart: {summary}");
    assert_eq!(summary["resumes"], 1);
    let resumed_s = summary["resumed_from_ns"].as_u64().unwrap() as f64 * 1e-9;
    assert!(
        (FILTER_KILL_S - 1.0..=FILTER_KILL_S + 0.5).contains(&resumed_s),
        "resumed from a checkpoint at {resumed_s} s for a kill at {FILTER_KILL_S} s"
    );
    let gap_s = summary["restart_gap_ns"].as_u64().unwrap() as f64 * 1e-9;
    // The IMU topic's history (256 samples) covers the checkpoint's age plus the restart.
    assert_eq!(summary["restart_imu_lost"], 0, "the history did not cover the restart");
    assert!(summary["imu_replayed"].as_u64().unwrap() > 0);
    assert_eq!(summary["imu_lost"], 0);
    // The counters carried across the restart describe the whole run (200 Hz for 45 s).
    assert!(summary["imu_received"].as_u64().unwrap() >= 8_900, "{summary}");
    // The original initialization is kept: the report aligns the truth at this stamp.
    let summary0 = read_json(&dir0.join("filter_summary.json")).unwrap();
    assert_eq!(summary["initialized_ns"], summary0["initialized_ns"]);
    assert!(summary["checkpoints_written"].as_u64().unwrap() > 0);
    assert_eq!(summary["checkpoint_errors"], 0);

    // --- mapper: restarted, every submap finished before the kill is in the restarted mapper.
    let mapper = process_record(&supervisor1, "mapper");
    println!("supervisor mapper: {mapper}");
    assert!(mapper["restarts"].as_u64().unwrap() >= 1);
    let pids = u64s(&mapper["pids"]);
    assert_eq!(pids.first().copied(), fault("mapper")["pid"].as_u64());
    assert!(mapper["exits"].as_array().unwrap().iter().any(|e| e == "signal SIGKILL"), "{mapper}");
    let before = u64s(&fault("mapper")["submaps_before"]);
    let status = read_json(&dir1.join("mapper_status.json")).unwrap();
    println!("submaps on disk at the mapper's kill: {before:?}; mapper status after: {status}");
    assert!(before.len() >= 2, "the test needs finished submaps before the kill: {before:?}");
    let own_after = u64s(&status["own_submaps"]);
    for index in &before {
        assert!(own_after.contains(index), "submap {index} lost: after the restart {own_after:?}");
    }
    assert!(status["submaps_restored"].as_u64().unwrap() >= before.len() as u64, "{status}");
    // The filter's frame id went on across its own restart: the mapper's chain reached it.
    assert!(summary["frame_id"].as_u64().unwrap() > *before.last().unwrap(), "{summary}");

    // --- the trajectory after the filter's restart is still scored, with a bounded error, and
    // the restart itself adds no error. The online error drifts at up to ~0.1 m/s on this loaded
    // machine (run to run, with or without faults), so the jump is measured against the error
    // extrapolated from the second before the kill: 0.004 m measured where the drift was 0.08 m/s.
    let estimate = read_tum(&dir1.join("estimate.tum")).unwrap();
    let truth = read_tum(&dir1.join("truth.tum")).unwrap();
    let errors = error_vectors(&estimate, &truth);
    // Frames captured after the kill get their pose from the restarted filter (the mapper takes
    // no filter state older than one it has).
    let kill_ns = (fault("filter")["killed_at_s"].as_f64().unwrap() * 1e9) as u64;
    let (before, after): (Vec<_>, Vec<_>) = errors.iter().partition(|(stamp, _)| *stamp < kill_ns);
    let last = *before.last().unwrap();
    let first = *before.iter().find(|(stamp, _)| *stamp + 1_000_000_000 >= last.0).unwrap();
    let next = *after.first().unwrap();
    let rate =
        if last.0 > first.0 { (last.1 - first.1) / ((last.0 - first.0) as f64 * 1e-9) } else { Vector3::zeros() };
    let predicted = last.1 + rate * ((next.0 - last.0) as f64 * 1e-9);
    let jump_m = (next.1 - predicted).norm();
    let at_kill_m = last.1.norm();
    let max_after_m = after.iter().map(|(_, e)| e.norm()).fold(0.0, f64::max);
    println!(
        "robot index 1: restart gap {gap_s:.3} s; error {at_kill_m:.3} m at {:.2} s before the filter kill, {:.3} m at {:.2} s after (jump against the drift {jump_m:.3} m); max after {max_after_m:.3} m over {} poses",
        last.0 as f64 * 1e-9,
        next.1.norm(),
        next.0 as f64 * 1e-9,
        after.len()
    );
    assert!(after.len() >= 50, "only {} scored poses after the restart", after.len());
    assert!(next.0 - last.0 < 2_000_000_000, "the online estimate paused {} ns at the restart", next.0 - last.0);
    assert!(jump_m < 0.05, "error jump of {jump_m} m at the filter restart");
    assert!(max_after_m < at_kill_m + 0.4 && max_after_m < 1.0, "error after the restart {max_after_m} m");
    let score1 = report.robots[1].score.as_ref().unwrap();
    assert!(score1.poses > 100, "robot index 1: {} scored poses", score1.poses);
    std::fs::remove_dir_all(&out).ok();
}
