#![allow(clippy::unwrap_used, clippy::expect_used)]
//! The rover's firmware nodes straight on the simulator (Moon preset, half resolution): drift
//! with and without wheel odometry, and frame switches that do not change the composed
//! trajectory.

mod common;

use std::sync::OnceLock;

use common::sim_run::{self, SimRun, SimWorld};

/// 25 s with 1 s stands: about 6 m of driving with two turns.
fn world() -> &'static SimWorld {
    static WORLD: OnceLock<SimWorld> = OnceLock::new();
    WORLD.get_or_init(|| sim_run::moon_world(7, 25.0, 2, Some(1.0)))
}

fn report(name: &str, run: &SimRun) {
    eprintln!(
        "{name}: {:.2} m driven, final error {:.3} m ({:.2} %), rotation {:.2}°, VO {} applied / {} rejected, \
         wheel {} / {}, ZUPT {}",
        run.distance_m,
        run.final_error_m,
        run.drift_percent(),
        run.final_rotation_error_deg,
        run.filter.vo_updates_applied,
        run.filter.vo_updates_rejected,
        run.filter.wheel_updates_applied,
        run.filter.wheel_updates_rejected,
        run.filter.zupt_updates_applied,
    );
}

#[test]
fn drift_with_and_without_wheel_odometry_stays_below_two_percent() {
    let world = world();
    for use_wheel in [true, false] {
        let run = sim_run::run(world, sim_run::sim_config(world, use_wheel), false, None).unwrap();
        report(if use_wheel { "VO + IMU + wheels" } else { "VO + IMU" }, &run);
        // The scenario must really drive, and the filter must really use the odometry.
        assert!(run.distance_m > 4.0, "{}", run.distance_m);
        assert!(run.filter.vo_updates_applied as f64 > 0.8 * run.vision.vo_frames as f64, "{:?}", run.filter);
        assert_eq!(run.filter.wheel_updates_applied > 0, use_wheel);
        // Issue 7 target over 150 m is 1 %; over a short run the start (levelling) weighs more.
        assert!(run.drift_percent() <= 2.0, "drift {:.2} %", run.drift_percent());
    }
}

#[test]
fn frame_switches_compose_back_to_the_unswitched_trajectory() {
    let world = world();
    let plain = sim_run::run(world, sim_run::sim_config(world, true), false, None).unwrap();
    let mut config = sim_run::sim_config(world, true);
    // The mapper asks for a new submap (a frame switch) every 1.5 m of path.
    config.mapper.submap_max_distance_m = 1.5;
    let switched = sim_run::run(world, config, false, None).unwrap();
    assert!(switched.filter.frame_switches >= 2, "{:?}", switched.filter);
    assert_eq!(plain.stamps_ns, switched.stamps_ns);
    // A switch re-linearizes the filter (covariance of x, y, z, yaw reset and re-grown), so the
    // estimates are not bit-identical; they must agree far below the drift itself.
    let max_gap_m = plain
        .est
        .iter()
        .zip(&switched.est)
        .map(|(a, b)| (a.translation.vector - b.translation.vector).norm())
        .fold(0.0, f64::max);
    eprintln!(
        "switched vs plain: max position difference {max_gap_m:.4} m, plain final error {:.3} m",
        plain.final_error_m
    );
    // Measured 6.3 mm (deterministic pipeline) against a 32 mm final error.
    assert!(max_gap_m < 0.02, "{max_gap_m}");
}
