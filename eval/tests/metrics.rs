//! Association, alignment and metrics on synthetic data with known answers.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use core::f64::consts::PI;

use eval::Trajectory;
use eval::align::{self, Alignment, FirstMetresModel, Sim3};
use eval::associate::{self, Association};
use eval::metrics::{self, Delta, MetricsError, PoseRelation, Stats};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

fn pose(x: f64, y: f64, z: f64, roll: f64, pitch: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_euler_angles(roll, pitch, yaw))
}

/// A wiggly 3-D path with varying attitude, `count` poses 0.1 s apart.
fn wiggly_path(count: usize) -> Vec<Isometry3<f64>> {
    (0..count)
        .map(|i| {
            let a = i as f64 * 0.1;
            pose(
                2.0 * a.cos() + a,
                1.5 * (0.7 * a).sin(),
                0.3 * (1.3 * a).sin(),
                0.1 * a.sin(),
                0.05 * a.cos(),
                0.4 * a,
            )
        })
        .collect()
}

fn pairs_of(gt: Vec<Isometry3<f64>>, est: Vec<Isometry3<f64>>) -> Association {
    let n = gt.len();
    Association { stamps_s: (0..n).map(|i| i as f64 * 0.1).collect(), gt, est, est_indices: (0..n).collect() }
}

fn close(a: f64, b: f64, tolerance: f64) -> bool {
    (a - b).abs() <= tolerance
}

fn assert_same_pose(a: &Isometry3<f64>, b: &Isometry3<f64>, tolerance: f64) {
    let dt = (a.translation.vector - b.translation.vector).norm();
    let dr = a.rotation.angle_to(&b.rotation);
    assert!(dt <= tolerance && dr <= tolerance, "poses differ by {dt:.2e} m, {dr:.2e} rad:\n{a}\n{b}");
}

// ---------------------------------------------------------------------------------------------
// Statistics

#[test]
fn stats_match_numpy_definitions() {
    let s = Stats::from_errors(&[4.0, 1.0, 3.0, 2.0]).unwrap();
    assert_eq!((s.mean, s.median, s.min, s.max, s.sse, s.count), (2.5, 2.5, 1.0, 4.0, 30.0, 4));
    assert!(close(s.rmse, 7.5f64.sqrt(), 1e-15));
    assert!(close(s.std, 1.25f64.sqrt(), 1e-15), "population std");
    assert_eq!(Stats::from_errors(&[3.0, 1.0, 2.0]).unwrap().median, 2.0);
    assert!(Stats::from_errors(&[]).is_none());
}

// ---------------------------------------------------------------------------------------------
// Association

fn trajectory(stamps_s: &[f64]) -> Trajectory {
    let poses = stamps_s.iter().map(|&t| pose(t, 0.0, 0.0, 0.0, 0.0, 0.0)).collect();
    Trajectory::new(stamps_s.to_vec(), poses).unwrap()
}

#[test]
fn association_follows_evo() {
    // The shorter side (here the estimate) is iterated; each of its stamps takes the nearest
    // ground-truth stamp within max_diff.
    let gt = trajectory(&[0.0, 0.1, 0.2, 0.3, 0.4, 0.5]);
    let est = trajectory(&[0.099, 0.205, 0.36, 0.7]);
    let a = associate::associate(&gt, &est, 0.01, 0.0).unwrap();
    assert_eq!(a.est_indices, vec![0, 1]);
    assert_eq!(a.gt[0].translation.x, 0.1);
    assert_eq!(a.gt[1].translation.x, 0.2);
    assert_eq!(a.stamps_s, vec![0.099, 0.205]);
    // The offset is added to the estimate's stamps: 0.36 + 0.04 = 0.4.
    let a = associate::associate(&gt, &est, 0.01, 0.04).unwrap();
    assert_eq!(a.est_indices, vec![2]);
    assert_eq!(a.stamps_s, vec![0.36], "stamps stay in the estimate's time frame");
    // A tie goes to the earlier stamp (evo: `diff_lb <= diff_ub`).
    let gt = trajectory(&[0.0, 1.0, 2.0]);
    let est = trajectory(&[0.5]);
    let a = associate::associate(&gt, &est, 0.5, 0.0).unwrap();
    assert_eq!(a.gt[0].translation.x, 0.0);
    // With the ground truth shorter, it is the side iterated over: a sparse ground-truth stamp
    // between two estimate stamps pairs once, with the nearest.
    let gt = trajectory(&[1.0]);
    let est = trajectory(&[0.995, 1.004, 1.2]);
    let a = associate::associate(&gt, &est, 0.01, 0.0).unwrap();
    assert_eq!(a.est_indices, vec![1]);
    assert!(matches!(
        associate::associate(&gt, &trajectory(&[5.0]), 0.01, 0.0),
        Err(associate::AssociateError::NoMatches { .. })
    ));
}

#[test]
fn interpolated_association_is_exact_on_uniform_motion() {
    // Ground truth at 1 Hz moving 1 m/s along x and turning 0.1 rad/s; estimate at 4 Hz.
    let gt_stamps: Vec<f64> = (0..11).map(f64::from).collect();
    let gt_poses = gt_stamps.iter().map(|&t| pose(t, 0.0, 0.0, 0.0, 0.0, 0.1 * t)).collect();
    let gt = Trajectory::new(gt_stamps, gt_poses).unwrap();
    let est_stamps: Vec<f64> = (0..50).map(|i| -0.5 + 0.25 * f64::from(i)).collect();
    let est = Trajectory::new(est_stamps.clone(), est_stamps.iter().map(|_| Isometry3::identity()).collect()).unwrap();
    let a = associate::associate_interpolated(&gt, &est, 0.0, 1.0).unwrap();
    // Only stamps within [0, 10] s.
    assert_eq!(a.len(), 41);
    for (t, p) in a.stamps_s.iter().zip(&a.gt) {
        assert_same_pose(p, &pose(*t, 0.0, 0.0, 0.0, 0.0, 0.1 * t), 1e-12);
    }
    // Gaps over max_gap_s are skipped (only the exact sample stamps remain).
    assert_eq!(associate::associate_interpolated(&gt, &est, 0.0, 0.5).unwrap().len(), 11);
}

// ---------------------------------------------------------------------------------------------
// Alignment

fn known_sim3() -> Sim3 {
    Sim3 { scale: 1.7, t_gt_est: pose(3.0, -1.0, 0.5, 0.3, -0.2, 2.5) }
}

#[test]
fn se3_and_sim3_recover_a_known_transform() {
    let est = wiggly_path(100);
    for (alignment, truth) in [(Alignment::Se3, Sim3 { scale: 1.0, ..known_sim3() }), (Alignment::Sim3, known_sim3())] {
        let gt = truth.apply_all(&est);
        let fitted = align::fit(&alignment, &est, &gt).unwrap();
        assert!(close(fitted.scale, truth.scale, 1e-12), "{alignment}: scale {}", fitted.scale);
        assert_same_pose(&fitted.t_gt_est, &truth.t_gt_est, 1e-11);
        let report = metrics::ate(&pairs_of(gt, est.clone()), &alignment, PoseRelation::Translation).unwrap();
        assert!(report.stats.max < 1e-10, "{alignment}: {:?}", report.stats);
        let rotation_error =
            metrics::ate(&pairs_of(truth.apply_all(&est), est.clone()), &alignment, PoseRelation::Full)
                .unwrap()
                .stats
                .max;
        assert!(rotation_error < 1e-10);
    }
}

#[test]
fn umeyama_sign_correction_gives_a_rotation_for_mirrored_data() {
    // Ground truth mirrored in z: the unconstrained optimum is a reflection; Umeyama's S flips
    // the smallest singular direction so the result stays a proper rotation (det +1).
    let est: Vec<Vector3<f64>> = wiggly_path(50).iter().map(|p| p.translation.vector).collect();
    let gt: Vec<Vector3<f64>> = est.iter().map(|p| Vector3::new(p.x, p.y, -p.z)).collect();
    let fitted = align::umeyama(&est, &gt, false).unwrap();
    let r = fitted.t_gt_est.rotation.to_rotation_matrix();
    assert!(close(r.matrix().determinant(), 1.0, 1e-12));
}

#[test]
fn degenerate_alignments_are_errors() {
    let line: Vec<Vector3<f64>> = (0..10).map(|i| Vector3::new(f64::from(i), 0.0, 0.0)).collect();
    assert_eq!(align::umeyama(&line, &line, false), Err(align::AlignError::Degenerate));
    let point = vec![Vector3::new(1.0, 2.0, 3.0); 5];
    assert_eq!(align::align_4dof(&point, &point), Err(align::AlignError::Degenerate));
    assert!(matches!(align::umeyama(&[], &[], true), Err(align::AlignError::TooFewPairs { .. })));
}

#[test]
fn four_dof_recovers_yaw_and_translation_and_keeps_roll_and_pitch() {
    let est = wiggly_path(80);
    let truth = Sim3 { scale: 1.0, t_gt_est: pose(1.0, 2.0, -0.3, 0.0, 0.0, -2.0) };
    let gt = truth.apply_all(&est);
    let fitted = align::fit(&Alignment::FourDof, &est, &gt).unwrap();
    assert_same_pose(&fitted.t_gt_est, &truth.t_gt_est, 1e-12);
    // Even when the ground truth is tilted against the estimate, the fit rotates about z only:
    // the gravity direction seen from the body is unchanged for every pose.
    let tilted = Sim3 { scale: 1.0, t_gt_est: pose(1.0, 2.0, -0.3, 0.2, -0.1, -2.0) }.apply_all(&est);
    let fitted = align::fit(&Alignment::FourDof, &est, &tilted).unwrap();
    let (roll, pitch, _) = fitted.t_gt_est.rotation.euler_angles();
    assert!(roll.abs() < 1e-15 && pitch.abs() < 1e-15);
    for (before, after) in est.iter().zip(fitted.apply_all(&est)) {
        let gravity_before = before.rotation.inverse() * Vector3::z();
        let gravity_after = after.rotation.inverse() * Vector3::z();
        assert!((gravity_before - gravity_after).norm() < 1e-14);
    }
}

#[test]
fn se2_ignores_z_and_evaluates_in_the_plane() {
    // Planar ground truth; the estimate is rotated and shifted in the plane and has z drift and
    // tilt, which an SE(2) evaluation must not count.
    let gt: Vec<Isometry3<f64>> = wiggly_path(60)
        .iter()
        .map(|p| {
            let t = p.translation.vector;
            pose(t.x, t.y, 0.0, 0.0, 0.0, align::yaw_rad(&p.rotation))
        })
        .collect();
    let est_planar = Sim3 { scale: 1.0, t_gt_est: pose(-4.0, 1.0, 0.0, 0.0, 0.0, 0.7) }.apply_all(&gt);
    let est: Vec<Isometry3<f64>> = est_planar
        .iter()
        .enumerate()
        .map(|(i, p)| {
            Isometry3::from_parts(
                Translation3::new(p.translation.x, p.translation.y, 0.01 * i as f64),
                p.rotation * UnitQuaternion::from_euler_angles(0.05, -0.03, 0.0),
            )
        })
        .collect();
    let fitted = align::fit(&Alignment::Se2, &est, &gt).unwrap();
    assert_eq!(fitted.t_gt_est.translation.z, 0.0);
    let report = metrics::ate(&pairs_of(gt.clone(), est.clone()), &Alignment::Se2, PoseRelation::Translation).unwrap();
    assert!(report.stats.max < 1e-10, "{:?}", report.stats);
    let angles = metrics::ate(&pairs_of(gt, est), &Alignment::Se2, PoseRelation::RotationAngleRad).unwrap();
    assert!(angles.stats.max < 1e-10);
}

#[test]
fn first_metres_alignment_uses_only_the_first_metres() {
    // Ground truth drives 1 m/s along a curve; the estimate equals the ground truth in another
    // frame for the first 4 m and then drifts sideways.
    let gt: Vec<Isometry3<f64>> = (0..200)
        .map(|i| {
            let s = 0.1 * f64::from(i);
            pose(s, 0.05 * s * s, 0.2 * (0.3 * s).sin(), 0.0, 0.0, 0.1 * s)
        })
        .collect();
    let truth = Sim3 { scale: 1.0, t_gt_est: pose(5.0, -3.0, 1.0, 0.1, 0.05, 1.2) };
    let t_est_gt = truth.t_gt_est.inverse();
    let distances_m = align::path_distances_m(&gt);
    let est: Vec<Isometry3<f64>> = gt
        .iter()
        .zip(&distances_m)
        .map(|(p, &d)| {
            let drift = Translation3::new(0.0, 0.05 * (d - 4.5).max(0.0), 0.02 * (d - 4.5).max(0.0));
            t_est_gt * (drift * p)
        })
        .collect();
    let first = Alignment::FirstMetres { distance_m: 4.0, model: FirstMetresModel::Se3 };
    let fitted = align::fit(&first, &est, &gt).unwrap();
    assert_same_pose(&fitted.t_gt_est, &truth.t_gt_est, 1e-10);
    let report = metrics::ate(&pairs_of(gt.clone(), est.clone()), &first, PoseRelation::Translation).unwrap();
    // The first 4 m are error-free, the drift stays fully visible at the end.
    let first_count = distances_m.iter().filter(|&&d| d <= 4.0).count();
    assert!(report.errors[..first_count].iter().all(|&e| e < 1e-10));
    let end_drift = 0.05f64.hypot(0.02) * (distances_m[199] - 4.5);
    assert!(close(report.final_error.error_m, end_drift, 1e-9));
    // A whole-run fit spreads the drift instead: it does not recover the transform.
    let whole = align::fit(&Alignment::Se3, &est, &gt).unwrap();
    assert!((whole.t_gt_est.translation.vector - truth.t_gt_est.translation.vector).norm() > 0.01);
    // The 4-DoF variant recovers it too when the frames differ by yaw only.
    let yaw_only = Sim3 { scale: 1.0, t_gt_est: pose(5.0, -3.0, 1.0, 0.0, 0.0, 1.2) };
    let est_yaw: Vec<Isometry3<f64>> = gt.iter().map(|p| yaw_only.t_gt_est.inverse() * p).collect();
    let model = Alignment::FirstMetres { distance_m: 4.0, model: FirstMetresModel::FourDof };
    assert_same_pose(&align::fit(&model, &est_yaw, &gt).unwrap().t_gt_est, &yaw_only.t_gt_est, 1e-10);
    // Too short a distance to fit.
    let tiny = Alignment::FirstMetres { distance_m: 0.15, model: FirstMetresModel::Se3 };
    assert!(matches!(align::fit(&tiny, &est, &gt), Err(align::AlignError::TooFewPairs { found: 2, needed: 3 })));
}

#[test]
fn alignment_names_parse() {
    assert_eq!(
        "first:4m".parse::<Alignment>().unwrap(),
        Alignment::FirstMetres { distance_m: 4.0, model: FirstMetresModel::Se3 }
    );
    assert_eq!(
        "first:3.5m:4dof".parse::<Alignment>().unwrap(),
        Alignment::FirstMetres { distance_m: 3.5, model: FirstMetresModel::FourDof }
    );
    for name in ["none", "se3", "sim3", "scale", "4dof", "se2", "first:4m", "first:2.5m:4dof"] {
        assert_eq!(name.parse::<Alignment>().unwrap().to_string(), name);
    }
    for bad in ["first:", "first:-1m", "first:nanm", "first:4m:sim3", "SE3", ""] {
        assert!(bad.parse::<Alignment>().is_err(), "{bad}");
    }
}

// ---------------------------------------------------------------------------------------------
// RPE, final error, yaw

/// Ground truth steps 1 m along x every 0.5 s; the estimate steps 1.1 m and turns 0.01 rad more
/// per step than the ground truth (which does not turn).
fn constant_step_error() -> Association {
    let n = 21;
    let gt: Vec<Isometry3<f64>> = (0..n).map(|i| pose(f64::from(i), 0.0, 0.0, 0.0, 0.0, 0.0)).collect();
    let mut est = vec![Isometry3::identity()];
    let step = pose(1.1, 0.0, 0.0, 0.0, 0.0, 0.01);
    for i in 1..n as usize {
        est.push(est[i - 1] * step);
    }
    Association {
        stamps_s: (0..n).map(|i| 0.5 * f64::from(i)).collect(),
        gt,
        est,
        est_indices: (0..n as usize).collect(),
    }
}

#[test]
fn rpe_of_a_constant_per_step_error() {
    let a = constant_step_error();
    // Per step: relative translation (1.1, 0, 0) vs (1, 0, 0), relative rotation 0.01 rad.
    let r = metrics::rpe(&a, &Alignment::None, Delta::Frames(1), PoseRelation::Translation).unwrap();
    assert_eq!(r.stats.count, 20);
    assert!(close(r.stats.rmse, 0.1, 1e-12) && close(r.stats.min, 0.1, 1e-12) && r.stats.std < 1e-12);
    let r = metrics::rpe(&a, &Alignment::None, Delta::Frames(1), PoseRelation::RotationAngleRad).unwrap();
    assert!(close(r.stats.mean, 0.01, 1e-14) && close(r.stats.max, 0.01, 1e-14));
    let r = metrics::rpe(&a, &Alignment::None, Delta::Frames(1), PoseRelation::RotationAngleDeg).unwrap();
    assert!(close(r.stats.mean, 0.01f64.to_degrees(), 1e-12));

    // Two steps: est relative pose = step², gt relative (2, 0, 0); error = |step² translation − 2|.
    let two = pose(1.1, 0.0, 0.0, 0.0, 0.0, 0.01) * pose(1.1, 0.0, 0.0, 0.0, 0.0, 0.01);
    let expected = (two.translation.vector - Vector3::new(2.0, 0.0, 0.0)).norm();
    for delta in [Delta::Frames(2), Delta::Metres(2.0), Delta::Seconds(1.0)] {
        let r = metrics::rpe(&a, &Alignment::None, delta, PoseRelation::Translation).unwrap();
        assert_eq!(r.stats.count, 10, "{delta:?}");
        assert_eq!(r.pairs[0], (0, 2), "{delta:?}");
        assert!(close(r.stats.mean, expected, 1e-12) && r.stats.std < 1e-12, "{delta:?}: {:?}", r.stats);
    }
    // Metres are measured along the estimate: 1.1 m per step reaches 1.5 m after 2 steps.
    let r = metrics::rpe(&a, &Alignment::None, Delta::Metres(1.5), PoseRelation::Translation).unwrap();
    assert_eq!(r.pairs[0], (0, 2));
    assert!(matches!(
        metrics::rpe(&a, &Alignment::None, Delta::Frames(0), PoseRelation::Translation),
        Err(MetricsError::BadDelta(_))
    ));
    assert!(matches!(
        metrics::rpe(&a, &Alignment::None, Delta::Metres(1000.0), PoseRelation::Translation),
        Err(MetricsError::NoRpePairs)
    ));
}

#[test]
fn final_error_in_percent_of_distance_travelled() {
    // 100 m straight; the estimate ends 1 m to the side.
    let gt: Vec<Isometry3<f64>> = (0..=100).map(|i| pose(f64::from(i), 0.0, 0.0, 0.0, 0.0, 0.0)).collect();
    let est: Vec<Isometry3<f64>> =
        (0..=100).map(|i| pose(f64::from(i), 0.01 * f64::from(i), 0.0, 0.0, 0.0, 0.0)).collect();
    let f = metrics::final_error(&gt, &est).unwrap();
    assert!(close(f.error_m, 1.0, 1e-12));
    assert!(close(f.gt_path_length_m, 100.0, 1e-12));
    assert!(close(f.percent.unwrap(), 1.0, 1e-12));
    let report = metrics::ate(&pairs_of(gt.clone(), est), &Alignment::None, PoseRelation::Translation).unwrap();
    assert!(close(report.final_error.percent.unwrap(), 1.0, 1e-12));
    // A robot that did not move has no percentage.
    let still = vec![Isometry3::identity(); 3];
    assert_eq!(metrics::final_error(&still, &still).unwrap().percent, None);
}

#[test]
fn yaw_error_is_signed_and_wrapped() {
    let gt = [pose(0.0, 0.0, 0.0, 0.0, 0.0, (-179f64).to_radians())];
    let est = [pose(0.0, 0.0, 0.0, 0.0, 0.0, 179f64.to_radians())];
    let e = metrics::yaw_errors_rad(&gt, &est);
    assert!(close(e[0], (-2f64).to_radians(), 1e-12), "{}", e[0].to_degrees());
    assert_eq!(metrics::wrap_angle_rad(PI), PI);
    assert_eq!(metrics::wrap_angle_rad(-PI), PI);
    assert!(close(metrics::wrap_angle_rad(3.0 * PI + 0.5), -PI + 0.5, 1e-12));
    assert_eq!(metrics::wrap_angle_rad(-1e-20), -1e-20);
}

#[test]
fn ape_relations() {
    // Estimate off by 0.3 m in y and 0.2 rad about x.
    let gt = [pose(1.0, 2.0, 3.0, 0.0, 0.0, 0.5)];
    let est = [gt[0] * pose(0.0, 0.3, 0.0, 0.2, 0.0, 0.0)];
    let value = |relation| metrics::ape_errors(&gt, &est, relation)[0];
    assert!(close(value(PoseRelation::Translation), 0.3, 1e-12));
    assert!(close(value(PoseRelation::RotationAngleRad), 0.2, 1e-12));
    assert!(close(value(PoseRelation::RotationAngleDeg), 0.2f64.to_degrees(), 1e-10));
    // ‖R − I‖_F = 2√2 sin(θ/2) for a rotation by θ.
    assert!(close(value(PoseRelation::RotationPart), 2.0 * 2f64.sqrt() * 0.1f64.sin(), 1e-12));
    let full = value(PoseRelation::Full);
    assert!(close(full, (value(PoseRelation::RotationPart).powi(2) + 0.09).sqrt(), 1e-12));
}

// ---------------------------------------------------------------------------------------------
// Online estimates

#[test]
fn online_ate_compares_each_row_with_interpolated_ground_truth() {
    // Ground truth at 10 Hz along a curve; the online log at irregular stamps, in a frame rotated
    // and shifted against the ground truth, plus a growing error after 4 m.
    let gt_stamps: Vec<f64> = (0..=200).map(|i| 0.1 * f64::from(i)).collect();
    let gt_pose = |t: f64| pose(t, 0.1 * t * t, 0.0, 0.0, 0.0, 0.2 * t);
    let gt = Trajectory::new(gt_stamps.clone(), gt_stamps.iter().map(|&t| gt_pose(t)).collect()).unwrap();
    let frame = pose(2.0, 1.0, 0.0, 0.0, 0.0, 0.8);
    let est_stamps: Vec<f64> = (0..130).map(|i| 0.013 + 0.153 * f64::from(i)).collect();
    let est_poses = est_stamps
        .iter()
        .map(|&t| frame.inverse() * Translation3::new(0.0, 0.0, 0.01 * (t - 4.0).max(0.0)) * gt_pose(t))
        .collect();
    let est = Trajectory::new(est_stamps, est_poses).unwrap();
    // Interpolation error of the 10 Hz ground truth on this curve is below 1 mm.
    let first = Alignment::FirstMetres { distance_m: 3.0, model: FirstMetresModel::FourDof };
    let report = metrics::online_ate(&gt, &est, 0.0, 0.2, &first, PoseRelation::Translation).unwrap();
    assert_eq!(report.stats.count, 130);
    assert!(report.errors[..10].iter().all(|&e| e < 1e-3), "{:?}", &report.errors[..10]);
    let last_t = 0.013 + 0.153 * 129.0;
    assert!(close(report.final_error.error_m, 0.01 * (last_t - 4.0), 2e-3));
    // Without alignment the frame offset shows.
    let raw = metrics::online_ate(&gt, &est, 0.0, 0.2, &Alignment::None, PoseRelation::Translation).unwrap();
    assert!(raw.stats.min > 1.0);
    // Whole-run fits use the future and are refused.
    for alignment in [Alignment::Se3, Alignment::Sim3, Alignment::FourDof] {
        assert!(matches!(
            metrics::online_ate(&gt, &est, 0.0, 0.2, &alignment, PoseRelation::Translation),
            Err(MetricsError::OnlineAlignment(_))
        ));
    }
}

// ---------------------------------------------------------------------------------------------
// Graph statistics

#[test]
fn graph_statistics() {
    let edge =
        |i: u32, j: u32| format!("EDGE_SE3:QUAT {i} {j} 1 0 0 0 0 0 1 1 0 0 0 0 0 1 0 0 0 0 1 0 0 0 1 0 0 1 0 1\n");
    let mut text = String::new();
    for i in 0..6 {
        text.push_str(&format!("VERTEX_SE3:QUAT {i} {i} 0 0 0 0 0 1\n"));
    }
    // An isolated vertex, a chain 0-1-2-3-4 with a loop closure 4-0, and a separate pair 10-11.
    for (i, j) in [(0, 1), (1, 2), (2, 3), (3, 4), (4, 0), (10, 11)] {
        text.push_str(&edge(i, j));
    }
    let graph = posegraph::g2o::parse(&text).unwrap();
    let stats = metrics::graph_stats(&graph);
    assert_eq!(stats.vertices, 8);
    assert_eq!(stats.edges, 6);
    assert_eq!(stats.odometry_edges, 5);
    assert_eq!(stats.loop_closure_edges, 1);
    // {0..4}, {5}, {10, 11}.
    assert_eq!(stats.components, 3);
    assert!(close(stats.mean_degree, 12.0 / 8.0, 1e-15));
}
