//! Time synchronization on real EuRoC ground truth with a known clock warp and heading offset.
//!
//! Run with `cargo test -p eval --test timesync -- --nocapture` to see the recovered values.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{SplitMix64, load_euroc_csv, load_tum};
use std::time::Instant;

use eval::Trajectory;
use eval::timesync::{
    HeadingAxis, SyncConfig, SyncError, SyncResult, SyncSignal, apply_sync, heading_rad, sync_cost, synchronize,
    wrap_angle_rad,
};
use nalgebra::{Isometry3, Matrix3, UnitQuaternion, Vector3};

const V102_CSV: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/trajectories/V102_groundtruth.csv");
const V101_TUM: &str =
    concat!(env!("CARGO_MANIFEST_DIR"), "/../data/euroc/v1_01_excerpt/groundtruth_from_evo/V101_gt_tum.txt");

#[derive(Debug, Clone, Copy)]
struct Warp {
    offset_s: f64,
    drift: f64,
    heading_offset_rad: f64,
}

/// The ground truth as an "estimate": every `stride`-th sample, stamped on a clock that runs
/// `τ = t0 + (t − t0 − offset_s)/drift`, rotated about world z by −heading_offset_rad, with
/// white heading noise of `heading_noise_rad` on each pose's rotation.
fn warped_estimate(gt: &Trajectory, warp: Warp, stride: usize, heading_noise_rad: f64, seed: u64) -> Trajectory {
    let t0 = gt.stamps_s[0];
    let frame = Isometry3::rotation(Vector3::z() * -warp.heading_offset_rad);
    let mut rng = SplitMix64(seed);
    let (mut stamps_s, mut poses) = (Vec::new(), Vec::new());
    for i in (0..gt.len()).step_by(stride) {
        stamps_s.push(t0 + (gt.stamps_s[i] - t0 - warp.offset_s) / warp.drift);
        let mut pose = frame * gt.poses[i];
        let noise = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), heading_noise_rad * rng.normal());
        pose.rotation = noise * pose.rotation;
        poses.push(pose);
    }
    Trajectory::new(stamps_s, poses).unwrap()
}

/// Cramér–Rao standard deviations of (offset_s, drift, heading_offset_rad) for white heading
/// noise `sigma_rad` on each estimate sample: every sample j is one measurement of
/// `ψ_gt(t0 + d(τ_j − t0) + Δt) − Δψ` with gradient `(ψ̇, ψ̇·(τ_j − t0), −1)`.
fn cramer_rao_std(gt: &Trajectory, warp: Warp, stride: usize, sigma_rad: f64) -> [f64; 3] {
    let axis = HeadingAxis::Auto.resolve(gt);
    let headings: Vec<f64> = gt.poses.iter().map(|p| heading_rad(&p.rotation, &axis)).collect();
    let t0 = gt.stamps_s[0];
    let mut information = Matrix3::zeros();
    for i in (stride..gt.len() - stride).step_by(stride) {
        // Central difference over ±stride samples: the GT's own jitter would dominate ±1.
        let rate = wrap_angle_rad(headings[i + stride] - headings[i - stride])
            / (gt.stamps_s[i + stride] - gt.stamps_s[i - stride]);
        let tau = t0 + (gt.stamps_s[i] - t0 - warp.offset_s) / warp.drift;
        let g = Vector3::new(rate, rate * (tau - t0), -1.0);
        information += g * g.transpose() / (sigma_rad * sigma_rad);
    }
    let covariance = information.try_inverse().unwrap();
    [covariance[(0, 0)].sqrt(), covariance[(1, 1)].sqrt(), covariance[(2, 2)].sqrt()]
}

struct Errors {
    offset_s: f64,
    drift: f64,
    heading_rad: f64,
}

fn report(label: &str, truth: Warp, result: &SyncResult, elapsed_s: f64) -> Errors {
    let errors = Errors {
        offset_s: result.offset_s - truth.offset_s,
        drift: result.drift - truth.drift,
        heading_rad: wrap_angle_rad(result.heading_offset_rad - truth.heading_offset_rad),
    };
    println!(
        "{label}: offset {:.6} s (err {:+.3} ms), drift {:.8} (err {:+.2e}), heading {:.5} rad (err {:+.4}°), \
         rms residual {:.4}°, overlap {}, evaluations {}, converged {}, at_bound {:?}, {:.0} ms",
        result.offset_s,
        errors.offset_s * 1e3,
        result.drift,
        errors.drift,
        result.heading_offset_rad,
        errors.heading_rad.to_degrees(),
        result.cost.sqrt().to_degrees(),
        result.overlap_samples,
        result.evaluations,
        result.converged,
        result.at_bound,
        elapsed_s * 1e3,
    );
    errors
}

fn run(label: &str, estimate: &Trajectory, gt: &Trajectory, config: &SyncConfig, truth: Warp) -> (SyncResult, Errors) {
    let started = Instant::now();
    let result = synchronize(estimate, gt, config).unwrap();
    let errors = report(label, truth, &result, started.elapsed().as_secs_f64());
    (result, errors)
}

const KNOWN: Warp = Warp { offset_s: 0.3, drift: 1.0003, heading_offset_rad: 0.7 };

/// Asserts every error is within `sigmas` Cramér–Rao standard deviations.
fn assert_within_crb(errors: &Errors, crb: [f64; 3], sigmas: f64) {
    assert!(errors.offset_s.abs() <= sigmas * crb[0], "offset error {} s vs σ {}", errors.offset_s, crb[0]);
    assert!(errors.drift.abs() <= sigmas * crb[1], "drift error {} vs σ {}", errors.drift, crb[1]);
    assert!(errors.heading_rad.abs() <= sigmas * crb[2], "heading error {} vs σ {}", errors.heading_rad, crb[2]);
}

fn print_crb(label: &str, crb: [f64; 3]) {
    println!(
        "{label}: Cramér–Rao std offset {:.3} ms, drift {:.2e}, heading {:.4}°",
        crb[0] * 1e3,
        crb[1],
        crb[2].to_degrees()
    );
}

#[test]
fn recovers_known_warp_without_noise() {
    let gt = load_euroc_csv(V102_CSV);
    let estimate = warped_estimate(&gt, KNOWN, 10, 0.0, 1);
    let (_, e) = run("V102 noise-free 20 Hz", &estimate, &gt, &SyncConfig::default(), KNOWN);
    // What is left is the error of interpolating a 20 Hz heading linearly.
    assert!(e.offset_s.abs() < 0.2e-3, "offset error {} s", e.offset_s);
    assert!(e.drift.abs() < 2e-6, "drift error {}", e.drift);
    assert!(e.heading_rad.abs() < 0.01f64.to_radians(), "heading error {} rad", e.heading_rad);
}

#[test]
fn recovers_known_warp_with_heading_noise() {
    let gt = load_euroc_csv(V102_CSV);
    let config = SyncConfig::default();
    let noise_rad = 0.5f64.to_radians();
    let crb = cramer_rao_std(&gt, KNOWN, 10, noise_rad);
    print_crb("V102, 0.5° white heading noise at 20 Hz", crb);
    let seeds = 7..15u64;
    let (mut sq_offset, mut sq_drift, mut sq_heading) = (0.0, 0.0, 0.0);
    for seed in seeds.clone() {
        let estimate = warped_estimate(&gt, KNOWN, 10, noise_rad, seed);
        let (result, e) = run(&format!("V102 0.5° noise seed {seed}"), &estimate, &gt, &config, KNOWN);
        // The search must find a minimum at least as good as the truth; errors beyond that are
        // the noise's, not the optimizer's.
        let (cost_at_truth, _) =
            sync_cost(&estimate, &gt, &config, KNOWN.offset_s, KNOWN.drift, KNOWN.heading_offset_rad).unwrap();
        assert!(result.cost <= cost_at_truth, "found {} > truth {}", result.cost, cost_at_truth);
        assert_within_crb(&e, crb, 3.5);
        assert!(e.offset_s.abs() < 4e-3 && e.heading_rad.abs() < 0.1f64.to_radians());
        sq_offset += e.offset_s.powi(2);
        sq_drift += e.drift.powi(2);
        sq_heading += e.heading_rad.powi(2);
    }
    let n = seeds.count() as f64;
    println!(
        "RMS error over {n} seeds: offset {:.3} ms, drift {:.2e}, heading {:.4}°",
        (sq_offset / n).sqrt() * 1e3,
        (sq_drift / n).sqrt(),
        (sq_heading / n).sqrt().to_degrees()
    );
}

#[test]
fn recovers_truth_on_the_bounds() {
    // Offset and drift exactly on their bounds, heading offset near +π (next to the seam).
    let gt = load_euroc_csv(V102_CSV);
    let truth = Warp { offset_s: -1.0, drift: 1.01, heading_offset_rad: 3.1 };
    let exact = warped_estimate(&gt, truth, 10, 0.0, 11);
    let (result, e) = run("V102 truth on bounds, noise-free", &exact, &gt, &SyncConfig::default(), truth);
    assert!(e.offset_s.abs() < 0.2e-3 && e.drift.abs() < 2e-6 && e.heading_rad.abs() < 0.01f64.to_radians());
    // Interpolating the 20 Hz heading moves the noise-free minimum a few µs off the truth, so it
    // may land just inside the box; it must not land outside it.
    assert!(result.offset_s >= -1.0 && result.drift <= 1.01);

    // A box that ends 10 ms short of the true offset pins the result to its edge, and says so.
    let config = SyncConfig { offset_bounds_s: -0.99..=1.0, ..SyncConfig::default() };
    let (result, _) = run("V102 truth 10 ms outside the box", &exact, &gt, &config, truth);
    assert_eq!(result.offset_s, -0.99);
    assert_eq!(result.at_bound, [true, false, false]);

    let noise_rad = 0.5f64.to_radians();
    let crb = cramer_rao_std(&gt, truth, 10, noise_rad);
    print_crb("V102 truth on bounds", crb);
    let noisy = warped_estimate(&gt, truth, 10, noise_rad, 11);
    let (_, e) = run("V102 truth on bounds, 0.5° noise", &noisy, &gt, &SyncConfig::default(), truth);
    assert_within_crb(&e, crb, 3.5);

    // Inside a narrow box whose corner holds the truth.
    let config = SyncConfig { offset_bounds_s: -1.0..=-0.99, drift_bounds: 1.0099..=1.01, ..SyncConfig::default() };
    let (_, e) = run("V102 truth in a tight corner, 0.5° noise", &noisy, &gt, &config, truth);
    assert_within_crb(&e, crb, 3.5);
}

#[test]
fn recovers_known_warp_on_v101_tum() {
    // 20 Hz TUM ground truth; the estimate is every second sample (10 Hz).
    let gt = load_tum(V101_TUM);
    let noise_rad = 0.5f64.to_radians();
    let crb = cramer_rao_std(&gt, KNOWN, 2, noise_rad);
    print_crb("V101 TUM, 0.5° white heading noise at 10 Hz", crb);
    let estimate = warped_estimate(&gt, KNOWN, 2, noise_rad, 3);
    let (_, e) = run("V101 TUM 0.5° noise 10 Hz", &estimate, &gt, &SyncConfig::default(), KNOWN);
    assert_within_crb(&e, crb, 3.5);
}

#[test]
fn angular_rate_norm_ignores_constant_frame_rotations() {
    // A tilted world frame and a rotated body frame break the yaw signal but not the rate norm.
    let gt = load_euroc_csv(V102_CSV);
    let estimate = warped_estimate(&gt, KNOWN, 10, 0.0, 1);
    let world = Isometry3::rotation(Vector3::new(0.3, -0.5, 0.9));
    let body = Isometry3::rotation(Vector3::new(-1.1, 0.2, 0.4));
    let rotated = Trajectory {
        stamps_s: estimate.stamps_s.clone(),
        poses: estimate.poses.iter().map(|p| world * p * body).collect(),
    };
    let config = SyncConfig { signal: SyncSignal::AngularRateNorm, ..SyncConfig::default() };
    let truth = Warp { heading_offset_rad: 0.0, ..KNOWN };
    let (result, e) = run("V102 rate norm, rotated frames", &rotated, &gt, &config, truth);
    assert_eq!(result.heading_offset_rad, 0.0);
    assert!(e.offset_s.abs() < 2e-3, "offset error {} s", e.offset_s);
    assert!(e.drift.abs() < 2e-5, "drift error {}", e.drift);
}

#[test]
fn applying_the_result_restores_gt_time_and_heading() {
    let gt = load_euroc_csv(V102_CSV);
    let estimate = warped_estimate(&gt, KNOWN, 10, 0.0, 1);
    let result = synchronize(&estimate, &gt, &SyncConfig::default()).unwrap();
    let synced = apply_sync(&estimate, &result);
    let axis = HeadingAxis::Auto.resolve(&gt);
    let (mut worst_time_s, mut worst_heading_rad) = (0.0f64, 0.0f64);
    for (k, (stamp_s, pose)) in synced.stamps_s.iter().zip(&synced.poses).enumerate() {
        let i = 10 * k;
        worst_time_s = worst_time_s.max((stamp_s - gt.stamps_s[i]).abs());
        let error = wrap_angle_rad(heading_rad(&pose.rotation, &axis) - heading_rad(&gt.poses[i].rotation, &axis));
        worst_heading_rad = worst_heading_rad.max(error.abs());
        // The round trip through both directions of the mapping is exact up to rounding.
        assert!((result.estimate_time_s(*stamp_s) - estimate.stamps_s[k]).abs() < 1e-6);
    }
    println!(
        "apply_sync: worst stamp error {:.3} ms, worst heading error {:.4}°",
        worst_time_s * 1e3,
        worst_heading_rad.to_degrees()
    );
    assert!(worst_time_s < 1e-3);
    assert!(worst_heading_rad < 0.01f64.to_radians());
}

#[test]
fn is_deterministic() {
    let gt = load_tum(V101_TUM);
    let estimate = warped_estimate(&gt, KNOWN, 2, 0.5f64.to_radians(), 5);
    let config = SyncConfig::default();
    assert_eq!(synchronize(&estimate, &gt, &config).unwrap(), synchronize(&estimate, &gt, &config).unwrap());
}

#[test]
fn rejects_disjoint_streams_and_bad_bounds() {
    let gt = load_tum(V101_TUM);
    let late = Trajectory { stamps_s: gt.stamps_s.iter().map(|t| t + 1000.0).collect(), poses: gt.poses.clone() };
    assert!(matches!(
        synchronize(&late, &gt, &SyncConfig::default()),
        Err(SyncError::InsufficientOverlap { best_overlap_samples: 0, .. })
    ));
    #[allow(clippy::reversed_empty_ranges)]
    let config = SyncConfig { drift_bounds: 1.01..=0.99, ..SyncConfig::default() };
    assert_eq!(synchronize(&gt, &gt, &config), Err(SyncError::InvalidBounds { parameter: "drift" }));
    let config = SyncConfig { drift_bounds: -1.0..=1.0, ..SyncConfig::default() };
    assert_eq!(synchronize(&gt, &gt, &config), Err(SyncError::InvalidBounds { parameter: "drift" }));
}
