//! The submap matcher (thesis §6.1) on a synthetic rocky terrain and on a real outdoor lidar pair.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common {
    pub use mapper::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
    pub mod lidar;
    pub mod terrain;
}

use std::sync::Arc;

use common::terrain::{Pair, frame, standard_pair};
use mapper::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
use mapper::matching::{
    MatchMode, MatchReport, MatcherParams, PreparedCloud, Rejection, RelativePrior, Unsuitable, match_clouds,
};
use nalgebra::{Isometry3, Point3, Vector3};

fn prepare(cloud: VoxelCloud, params: &MatcherParams) -> PreparedCloud {
    PreparedCloud::new(Arc::new(cloud), params)
}

/// Translation error (m) and rotation error (deg) of `est` against `truth`.
fn errors(est: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    let d = truth.inverse() * est;
    (d.translation.vector.norm(), d.rotation.angle().to_degrees())
}

fn run(pair: &Pair, params: &MatcherParams, prior: Option<&RelativePrior>) -> MatchReport {
    let source = prepare(pair.source.clone(), params);
    let target = prepare(pair.target.clone(), params);
    assert_eq!(source.suitability(), Ok(()));
    assert_eq!(target.suitability(), Ok(()));
    let report = match_clouds(&source, &target, prior, params);
    eprintln!(
        "{:?}: {} + {} points, {} + {} keypoints, {} correspondences, {} hypotheses, {:?}, times {:?}",
        params.mode,
        pair.source.len(),
        pair.target.len(),
        source.keypoints().len(),
        target.keypoints().len(),
        report.correspondences,
        report.hypotheses,
        report.outcome.map(|m| (m.rmse_m, m.inliers, m.icp_pairs, m.icp_iterations)),
        report.times
    );
    report
}

#[test]
fn four_dof_recovers_the_terrain_transform() {
    let pair = standard_pair(0.01);
    let params = MatcherParams::default();
    let report = run(&pair, &params, None);
    let found = report.outcome.expect("a match");
    let (dt, dr) = errors(&found.t_target_source, &pair.t_target_source);
    assert!(dt < 0.03 && dr < 0.5, "error {dt:.3} m, {dr:.2}°");
    let (roll, pitch, _) = found.t_target_source.rotation.euler_angles();
    assert!(roll.abs() < 1e-12 && pitch.abs() < 1e-12, "4D keeps roll and pitch at zero");
    // The covariance is a valid one and not absurdly confident or loose.
    assert!(found.covariance.cholesky().is_some());
    let sigma_xy = found.covariance[(0, 0)].sqrt();
    assert!(sigma_xy > 0.005 && sigma_xy < 0.1, "σx {sigma_xy}");
    assert!(report.times.total_s > 0.0);
}

#[test]
fn lidar_pair_matches_the_reference_in_4d() {
    let params = MatcherParams::default();
    let source = common::lidar::cloud("source", 20.0, 0.3).unwrap();
    let target = common::lidar::cloud("target", 20.0, 0.3).unwrap();
    eprintln!(
        "lidar: {} ({} obstacle) + {} ({} obstacle) points",
        source.len(),
        source.obstacle_count(),
        target.len(),
        target.obstacle_count()
    );
    let reference = common::lidar::reference().unwrap();
    let pair = Pair { source, target, t_target_source: reference };
    let report = run(&pair, &params, None);
    let found = report.outcome.expect("a match");
    let (dt, dr) = errors(&found.t_target_source, &reference);
    let yaw_error =
        (found.t_target_source.rotation.euler_angles().2 - reference.rotation.euler_angles().2).to_degrees();
    eprintln!(
        "lidar error {dt:.4} m {dr:.3}° (yaw {yaw_error:.3}°; the reference's roll/pitch, which 4D keeps at zero, are {:.3}°)",
        {
            let (r, p, _) = reference.rotation.euler_angles();
            r.to_degrees().hypot(p.to_degrees())
        }
    );
    assert!(dt < 0.05 && dr < 0.3, "error {dt:.3} m, {dr:.2}°");
}

#[test]
fn six_dof_recovers_an_easy_case() {
    let pair = standard_pair(0.005);
    let params = MatcherParams::with_mode(MatchMode::SixDof);
    let found = run(&pair, &params, None).outcome.expect("a 6D match");
    let (dt, dr) = errors(&found.t_target_source, &pair.t_target_source);
    assert!(dt < 0.03 && dr < 0.5, "error {dt:.3} m, {dr:.2}°");
    // 6D estimates roll and pitch: their variances come from the data, not the fixed 4D value.
    assert!(found.covariance[(3, 3)] < MatcherParams::default().roll_pitch_sigma_rad.powi(2));
}

#[test]
fn the_prior_gates_hypotheses() {
    let pair = standard_pair(0.01);
    let params = MatcherParams::default();
    let source = prepare(pair.source.clone(), &params);
    let target = prepare(pair.target.clone(), &params);
    let far = RelativePrior {
        t_target_source: pair.t_target_source * frame(1.5, -1.0, 0.0, 0.0),
        delta_sigma_m: Vector3::new(0.2, 0.2, 0.1),
    };
    let report = match_clouds(&source, &target, Some(&far), &params);
    assert_eq!(report.outcome.map(|_| ()), Err(Rejection::OutsidePriorBounds));
    assert!(report.hypotheses > 0);
    assert_eq!(Rejection::OutsidePriorBounds.name(), "outside_prior_bounds");
    // A prior 20 cm off with Δσ = 0.15 m (gate 0.3 m) lets the true hypothesis through.
    let near = RelativePrior {
        t_target_source: pair.t_target_source * frame(0.2, 0.0, 0.0, 0.02),
        delta_sigma_m: Vector3::new(0.15, 0.15, 0.15),
    };
    let found = match_clouds(&source, &target, Some(&near), &params).outcome.expect("a match");
    assert!(errors(&found.t_target_source, &pair.t_target_source).0 < 0.03);
    // Δσ = 0 rejects every hypothesis (the thesis's approximation, trap T5).
    let zero = RelativePrior { t_target_source: pair.t_target_source, delta_sigma_m: Vector3::zeros() };
    assert_eq!(
        match_clouds(&source, &target, Some(&zero), &params).outcome.map(|_| ()),
        Err(Rejection::OutsidePriorBounds)
    );
}

#[test]
fn similarity_threshold_is_insensitive() {
    // Trap T9: similarity = 1 − d/2; the thesis found any threshold in [0.4, 0.8] to work.
    let pair = standard_pair(0.01);
    let params = MatcherParams::default();
    let source = prepare(pair.source.clone(), &params);
    let target = prepare(pair.target.clone(), &params);
    for threshold in [0.4, 0.5, 0.6, 0.7, 0.8] {
        let p = MatcherParams { min_similarity: threshold, ..params.clone() };
        let report = match_clouds(&source, &target, None, &p);
        let found = report.outcome.unwrap_or_else(|r| panic!("threshold {threshold}: {r}"));
        let (dt, dr) = errors(&found.t_target_source, &pair.t_target_source);
        eprintln!(
            "threshold {threshold}: {} correspondences, {} inliers, error {dt:.4} m {dr:.3}°",
            report.correspondences, found.inliers
        );
        assert!(dt < 0.03 && dr < 0.5, "threshold {threshold}: error {dt:.3} m, {dr:.2}°");
    }
}

/// A flat 4 m × 4 m ground patch (5 cm grid) plus `extra` obstacle points.
fn flat_with(extra: impl IntoIterator<Item = Point3<f32>>) -> VoxelCloud {
    let mut pts: Vec<MapPoint> = (0..80 * 80)
        .map(|i| MapPoint {
            position_m: Point3::new((i % 80) as f32 * 0.05, (i / 80) as f32 * 0.05, 0.0),
            intensity: 100,
            obstacle: false,
        })
        .collect();
    pts.extend(extra.into_iter().map(|p| MapPoint { position_m: p, intensity: 180, obstacle: true }));
    VoxelCloud::filtered(CLOUD_LEAF_M, &pts)
}

#[test]
fn flat_walls_and_single_stones_are_unsuitable() {
    let params = MatcherParams::default();
    let flat = prepare(flat_with([]), &params);
    assert_eq!(flat.suitability(), Err(Unsuitable::TooFewObstaclePoints { points: 0, min: 100 }));
    // Flat ground whose obstacle points all lie on one line (a curb: flat, obstacle-flagged).
    let curb = prepare(
        flat_with((0..140).map(|i| Point3::new(0.2 + (i / 2) as f32 * 0.05, 1.01 + (i % 2) as f32 * 0.05, 0.07))),
        &params,
    );
    assert!(matches!(curb.suitability(), Err(Unsuitable::NotDescriptive { .. })), "{:?}", curb.suitability());
    // A straight wall 3 m long, 1 m high.
    let wall = prepare(
        flat_with((0..60 * 20).map(|i| Point3::new(0.5 + (i % 60) as f32 * 0.05, 2.0, (i / 60) as f32 * 0.05))),
        &params,
    );
    assert!(matches!(wall.suitability(), Err(Unsuitable::NotDescriptive { .. })), "{:?}", wall.suitability());
    // A single stone (a 0.3 m hemisphere).
    let stone: Vec<Point3<f32>> = (0..400)
        .map(|i| {
            let (az, el) = (i as f32 * 2.399, (i as f32 / 400.0).asin());
            Point3::new(2.0 + 0.3 * el.cos() * az.cos(), 2.0 + 0.3 * el.cos() * az.sin(), 0.3 * el.sin())
        })
        .collect();
    let stone = prepare(flat_with(stone), &params);
    assert!(matches!(stone.suitability(), Err(Unsuitable::NotDescriptive { .. })), "{:?}", stone.suitability());
    // A wall with a second wall 2 m away is descriptive.
    let two = prepare(
        flat_with((0..60 * 20).flat_map(|i| {
            let (u, z) = ((i % 60) as f32 * 0.05, (i / 60) as f32 * 0.05);
            [Point3::new(0.5 + u, 1.0, z), Point3::new(0.5 + u, 3.0, z)]
        })),
        &params,
    );
    assert_eq!(two.suitability(), Ok(()));
    let report = match_clouds(&wall, &two, None, &params);
    assert!(matches!(report.outcome, Err(Rejection::SourceUnsuitable(Unsuitable::NotDescriptive { .. }))));
    assert!(!wall.features_ready(), "an unsuitable pair computes no descriptors");
}

mod never_panics {
    use super::*;
    use proptest::prelude::*;

    fn point() -> impl Strategy<Value = MapPoint> {
        ((-2.0f32..2.0, -2.0f32..2.0, -0.5f32..0.5), any::<u8>(), any::<bool>()).prop_map(
            |((x, y, z), intensity, obstacle)| MapPoint { position_m: Point3::new(x, y, z), intensity, obstacle },
        )
    }

    /// Random clouds, clouds of one repeated point, collinear clouds, and empty ones.
    fn cloud() -> impl Strategy<Value = VoxelCloud> {
        prop_oneof![
            prop::collection::vec(point(), 0..300),
            (point(), 1usize..200).prop_map(|(p, n)| vec![p; n]),
            (point(), 1usize..200).prop_map(|(p, n)| (0..n)
                .map(|i| MapPoint { position_m: p.position_m + Vector3::new(0.05, 0.02, 0.0) * i as f32, ..p })
                .collect()),
        ]
        .prop_map(|points| VoxelCloud { leaf_m: CLOUD_LEAF_M, points })
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]
        #[test]
        fn prepare_and_match_never_panic(a in cloud(), b in cloud(), six in any::<bool>()) {
            // Every gate open, so that degenerate clouds reach every stage.
            let params = MatcherParams {
                mode: if six { MatchMode::SixDof } else { MatchMode::FourDof },
                min_points: 0,
                min_obstacle_points: 0,
                min_spread_keypoints: 0,
                min_support_points: 1,
                min_correspondences: 0,
                hypothesis_min_spread: 0,
                hough_min_votes: 0.0,
                icp_min_pairs: 0,
                icp_min_pair_fraction: 0.0,
                ..MatcherParams::default()
            };
            let source = prepare(a, &params);
            let target = prepare(b, &params);
            let report = match_clouds(&source, &target, None, &params);
            if let Ok(found) = report.outcome {
                prop_assert!(found.t_target_source.translation.vector.iter().all(|v| v.is_finite()));
                prop_assert!(found.covariance.iter().all(|v| v.is_finite()));
            }
        }
    }
}

/// The diagnosis against a known pose tells a matchable pair from one that is not: at the true
/// transform the clouds share keypoints, descriptor correspondences and a hypothesis agree with
/// it and ICP stays put; at a transform 3 m off none of that holds.
#[test]
fn diagnosis_against_the_truth_and_against_a_wrong_pose() {
    use mapper::matching::diagnose::diagnose;
    let pair = standard_pair(0.01);
    let params = MatcherParams::default();
    let source = prepare(pair.source.clone(), &params);
    let target = prepare(pair.target.clone(), &params);
    let truth = diagnose(&source, &target, &pair.t_target_source, &params);
    eprintln!("at the truth: {truth:?}");
    assert!(truth.shared_keypoints > source.keypoints().len() / 4, "{truth:?}");
    assert!(truth.true_correspondences > truth.correspondences / 20, "{truth:?}");
    assert!(truth.true_hypotheses >= 1 && truth.best_true_inliers == truth.best_inliers, "{truth:?}");
    let (moved_m, moved_deg, _) = truth.icp_from_truth.expect("ICP from the truth converges");
    assert!(moved_m < 0.02 && moved_deg < 0.2, "{truth:?}");

    let wrong = Isometry3::from_parts(
        (pair.t_target_source.translation.vector + Vector3::new(3.0, 0.0, 0.0)).into(),
        pair.t_target_source.rotation,
    );
    let off = diagnose(&source, &target, &wrong, &params);
    eprintln!("3 m off: {off:?}");
    // 45 rocks in 8 m: keypoints of other rocks fall near one another by chance.
    assert!(off.shared_keypoints < truth.shared_keypoints / 2, "{off:?}");
    assert!(off.true_correspondences < truth.true_correspondences / 10, "{off:?}");
    assert_eq!(off.true_hypotheses, 0, "{off:?}");
    // Same features and correspondences whatever pose they are measured against.
    assert_eq!((off.correspondences, off.hypotheses), (truth.correspondences, truth.hypotheses));
}
