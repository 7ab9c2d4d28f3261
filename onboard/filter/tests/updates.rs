//! Delay compensation, chi-square gating and health on simulated runs.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{IMU_PERIOD_NS, START_NS, SimRun, VO_DELAY_NS};
use filter::{Filter, UpdateOutcome};
use nalgebra::{Isometry3, Translation3};

/// Feeds the run's IMU samples from `from_ns` to `to_ns` (inclusive) to `filters`.
fn feed_imu(run: &mut SimRun, filters: &mut [&mut Filter], from_ns: u64, to_ns: u64) {
    let mut t = from_ns;
    while t <= to_ns {
        let sample = run.imu.sample(&run.trajectory.state_at(t).unwrap(), t);
        for f in filters.iter_mut() {
            f.propagate(&sample).unwrap();
        }
        t += IMU_PERIOD_NS;
    }
}

#[test]
fn delayed_update_through_clones_equals_immediate_update() {
    let mut run = SimRun::new(11, 30.0);
    // A trigger at 15 s; its VO delta (relative to the latest keyframe) is queued.
    let t_c = START_NS + 15_000_000_000;
    run.run_until(t_c);
    let m = run.pending.iter().rev().find(|(_, m, _)| m.to_stamp_ns == t_c).map(|(_, m, _)| *m).unwrap();
    let mut immediate = run.filter.clone();
    let mut delayed = run.filter.clone();
    let mut none = run.filter.clone();
    assert_eq!(immediate.stamp_ns(), t_c);
    let UpdateOutcome::Applied { .. } = immediate.update_relative_pose(&m).unwrap() else { panic!("rejected") };
    feed_imu(&mut run, &mut [&mut immediate, &mut delayed, &mut none], t_c + IMU_PERIOD_NS, t_c + VO_DELAY_NS);
    let UpdateOutcome::Applied { .. } = delayed.update_relative_pose(&m).unwrap() else { panic!("rejected") };

    let a = immediate.state().unwrap();
    let b = delayed.state().unwrap();
    let c = none.state().unwrap();
    let correction = (a.t_local_body.translation.vector - c.t_local_body.translation.vector).norm();
    let diff = (a.t_local_body.translation.vector - b.t_local_body.translation.vector).norm();
    let rot_correction = (a.t_local_body.rotation.inverse() * c.t_local_body.rotation).angle();
    let rot_diff = (a.t_local_body.rotation.inverse() * b.t_local_body.rotation).angle();
    let v_diff = (a.v_local_mps - b.v_local_mps).norm();
    let distance = a.t_local_body.translation.vector.norm();
    let cov_rel = (a.covariance - b.covariance).norm() / a.covariance.norm();
    println!(
        "correction {correction:.2e} m / {rot_correction:.2e} rad; immediate vs delayed: {diff:.2e} m \
         ({:.1e} of the distance from the origin), {rot_diff:.2e} rad, velocity {v_diff:.2e} m/s, \
         covariance {cov_rel:.1e} relative",
        diff / distance
    );
    // In a linear-Gaussian system both orders are identical; the EKF differs only by where it
    // linearizes the 250 ms of propagation (before or after the correction): second order in
    // the correction.
    assert!(correction > 1e-4, "the test needs a correction to carry: {correction}");
    assert!(diff / distance < 1e-6, "{diff}");
    assert!(diff < 0.01 * correction && rot_diff < 0.01 * rot_correction.max(1e-6));
    assert!(cov_rel < 1e-3, "{cov_rel}");
}

#[test]
fn gross_outlier_is_rejected_and_counted() {
    let mut run = SimRun::new(5, 30.0);
    let t_c = START_NS + 10_000_000_000;
    run.run_until(t_c);
    let (_, good, _) = *run.pending.iter().rev().find(|(_, m, _)| m.to_stamp_ns == t_c).unwrap();
    let mut bad = good;
    // A 0.5 m error in a sub-metre keyframe delta (a wrong loop of features).
    bad.t_from_to =
        Isometry3::from_parts(Translation3::new(0.5, 0.0, 0.0), nalgebra::UnitQuaternion::identity()) * good.t_from_to;
    let before = run.filter.clone();
    let rejected_before = run.filter.health().relative_pose.rejected;
    let outcome = run.filter.update_relative_pose(&bad).unwrap();
    let UpdateOutcome::Rejected { nis, threshold } = outcome else { panic!("outlier applied: {outcome:?}") };
    assert!((threshold - 22.458).abs() < 1e-2, "6-DoF gate at 0.999: {threshold}");
    assert!(nis > 100.0 * threshold, "{nis}");
    assert_eq!(run.filter.health().relative_pose.rejected, rejected_before + 1);
    assert_eq!(run.filter.state(), before.state(), "a rejected update must not change the state");
    // The good measurement still passes.
    let UpdateOutcome::Applied { .. } = run.filter.update_relative_pose(&good).unwrap() else { panic!() };

    // A delta that refers to a frame never cloned is reported, not applied.
    let mut orphan = good;
    orphan.from_stamp_ns = 7;
    assert_eq!(run.filter.update_relative_pose(&orphan).unwrap(), UpdateOutcome::MissingClone);
    assert_eq!(run.filter.health().missing_clones, 1);
}

#[test]
fn health_is_clean_and_clones_bounded_after_a_normal_run() {
    let mut run = SimRun::new(9, 40.0);
    let mut max_clones = 0;
    while run.stamp_ns < run.end_ns() - 1_000_000_000 {
        run.step();
        max_clones = max_clones.max(run.filter.clone_count());
    }
    let h = *run.filter.health();
    println!("{h:?}; at most {max_clones} clones");
    assert!(h.is_clean(0.01));
    assert_eq!(h.covariance_repairs, 0);
    assert_eq!(h.clones_evicted, 0);
    assert_eq!(h.missing_clones, 0);
    // 1 keyframe referenced + up to 3 frames in flight (250 ms at 10 Hz) + 1 released + older
    // keyframes (at most `max_keyframe_clones`).
    let cfg = run.filter.config();
    assert!(max_clones <= cfg.max_keyframe_clones + 4, "{max_clones}");
    assert!(h.relative_pose.applied > 350);
    let keyframes = run.filter.clone_stamps().filter(|(_, k)| *k).count();
    assert!(keyframes <= cfg.max_keyframe_clones);
}
