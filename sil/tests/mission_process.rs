//! The mission on the process runner end to end: two robots, each a supervisor with five OS
//! processes over iceoryx2, the radio relay between them, 30 s of sensor time on the wall clock;
//! then the same mission on the lockstep runner, whose errors the process runner must match.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use sil::mission::process::run_mission_with_exe;
use sil::mission::{self, MissionOptions, MissionReport, Runner};

fn mean_error(report: &MissionReport, robot: u16) -> f64 {
    let r = report.robots.iter().find(|r| r.robot == robot).unwrap();
    let score = r.score.as_ref().unwrap_or_else(|| panic!("robot {robot} not scored: {:?}", r.score_error));
    assert!(score.poses > 100, "robot {robot}: only {} scored poses", score.poses);
    score.mean_error_m
}

#[test]
fn two_robot_process_mission_scores_like_lockstep() {
    let base = std::env::temp_dir().join(format!("sil-mission-process-{}", std::process::id()));
    let options = MissionOptions {
        robots: 2,
        duration_s: 30.0,
        seed: 3,
        downscale: 4,
        out: base.join("process"),
        runner: Runner::Process,
        ..MissionOptions::default()
    };
    let process = run_mission_with_exe(&options, Path::new(env!("CARGO_BIN_EXE_sil"))).unwrap();
    assert!(options.out.join("report.json").exists() && options.out.join("report.md").exists());
    assert_eq!(process.runner, "process");
    for r in &process.robots {
        println!(
            "process robot {}: imu received {} lost {}, graph {} nodes, score {:?}",
            r.robot, r.imu_received, r.imu_lost, r.graph_nodes, r.score
        );
    }
    for p in &process.processes {
        let t = p.timing.unwrap_or_else(|| panic!("robot {} {}: no task timing", p.robot, p.process));
        println!(
            "process robot {} {:<7} releases {:>6} overruns {:>4} skipped {:>4} jitter p50 {:>7.1} p99 {:>8.1} max {:>8.1} us, cpu {:.2} s, restarts {}",
            p.robot,
            p.process,
            t.releases,
            t.deadline_overruns,
            t.skipped_releases,
            t.jitter_p50_us,
            t.jitter_p99_us,
            t.jitter_max_us,
            p.cpu_s,
            p.restarts
        );
    }

    // No IMU sample lost between driver and filter, and the filter saw the whole run (200 Hz).
    for r in &process.robots {
        assert_eq!(r.imu_lost, 0, "robot {}", r.robot);
        assert!(r.imu_received >= 5_900, "robot {}: {} IMU samples of 6000", r.robot, r.imu_received);
    }
    // Every process ran its task over the whole mission, none was restarted.
    assert_eq!(process.processes.len(), 10);
    for p in &process.processes {
        assert!(p.timing.is_some_and(|t| t.releases > 0), "robot {} {} reported no releases", p.robot, p.process);
        assert_eq!(p.restarts, 0, "robot {} {} restarted", p.robot, p.process);
    }
    // The filter's 200 Hz deadline is 2.5 ms while ten processes share two cores and the two
    // vision processes alone need ~0.9 of a core. With normal scheduling that cost 8-12 % of the
    // releases (run-queue waits); the mission runs the filter and driver SCHED_FIFO (this machine
    // permits it), which measured 5 and 8 overruns in 6320 releases (0.1 %) with a jitter p99
    // of 0.2 ms. The bound is the 1 % goal.
    for p in process.processes.iter().filter(|p| p.process == "filter") {
        let p = (p.robot, p.timing.unwrap_or_else(|| panic!("robot {} filter: no task timing", p.robot)));
        let (robot, p) = p;
        let planned = p.releases + p.skipped_releases;
        assert!(planned >= 5_900, "robot {robot} filter: {planned} releases planned in 30 s at 200 Hz");
        assert!(
            p.deadline_overruns * 100 <= p.releases,
            "robot {robot} filter: {} overruns in {} releases",
            p.deadline_overruns,
            p.releases
        );
    }

    let lockstep_options = MissionOptions { out: base.join("lockstep"), runner: Runner::Lockstep, ..options.clone() };
    let lockstep = mission::run(&lockstep_options).unwrap();
    for robot in [1, 2] {
        let (p, l) = (mean_error(&process, robot), mean_error(&lockstep, robot));
        println!("robot {robot}: mean error process {p:.3} m, lockstep {l:.3} m");
        // The process runner is not deterministic (wall-clock release times decide which filter
        // state a frame's prior uses, which frames vision drops), so the errors differ by the
        // run-to-run spread; both must stay in the lockstep runner's accuracy class.
        assert!(p < 0.25, "robot {robot}: process runner mean error {p} m");
        assert!((p - l).abs() <= 0.1 + 0.5 * l, "robot {robot}: process {p} m vs lockstep {l} m");
    }
    std::fs::remove_dir_all(&base).ok();
}
