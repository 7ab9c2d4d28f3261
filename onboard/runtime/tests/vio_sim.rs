#![allow(clippy::unwrap_used, clippy::expect_used)]
//! The VIO pipeline straight on the simulator (Moon preset, half resolution): drift with and
//! without wheel odometry, and frame switches that do not change the composed trajectory.

mod common;

use std::sync::{Arc, OnceLock};

use common::sim_run::{self, SimRun};
use onboard::vio::SwitchPolicy;
use sim::world::World;

/// 25 s with 1 s stands: about 6 m of driving with two turns.
fn world() -> &'static Arc<World> {
    static WORLD: OnceLock<Arc<World>> = OnceLock::new();
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
        run.summary.vo_updates_applied,
        run.summary.vo_updates_rejected,
        run.summary.wheel_updates_applied,
        run.summary.wheel_updates_rejected,
        run.summary.zupt_updates_applied,
    );
}

#[test]
fn drift_with_and_without_wheel_odometry_stays_below_two_percent() {
    let world = world();
    for use_wheel in [true, false] {
        let run = sim_run::run(world, sim_run::sim_options(world, use_wheel), false, None).unwrap();
        report(if use_wheel { "VO + IMU + wheels" } else { "VO + IMU" }, &run);
        // The scenario must really drive, and the filter must really use the odometry.
        assert!(run.distance_m > 4.0, "{}", run.distance_m);
        assert!(run.summary.vo_updates_applied as f64 > 0.8 * run.summary.frames as f64, "{:?}", run.summary);
        assert_eq!(run.summary.wheel_updates_applied > 0, use_wheel);
        // Issue 7 target over 150 m is 1 %; over a short run the start (levelling) weighs more.
        assert!(run.drift_percent() <= 2.0, "drift {:.2} %", run.drift_percent());
    }
}

#[test]
fn frame_switches_compose_back_to_the_unswitched_trajectory() {
    let world = world();
    let plain = sim_run::run(world, sim_run::sim_options(world, true), false, None).unwrap();
    let mut options = sim_run::sim_options(world, true);
    options.switch = SwitchPolicy { distance_m: Some(1.5), ..SwitchPolicy::default() };
    let switched = sim_run::run(world, options, false, None).unwrap();
    assert!(switched.summary.frame_switches >= 2, "{:?}", switched.summary);
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
