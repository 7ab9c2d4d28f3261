//! The submap matcher (thesis §6.1) on a synthetic rocky terrain and on a real outdoor lidar pair.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common {
    pub use mapper::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
    pub mod lidar;
    pub mod terrain;
}

use std::sync::Arc;

use common::terrain::{Pair, frame, standard_pair, terrain};
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
    eprintln!("error vector {:?}", (pair.t_target_source.inverse() * found.t_target_source).translation.vector);
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
    let source = common::lidar::cloud("source", 20.0, 0.3);
    let target = common::lidar::cloud("target", 20.0, 0.3);
    eprintln!(
        "lidar: {} ({} obstacle) + {} ({} obstacle) points",
        source.len(),
        source.obstacle_count(),
        target.len(),
        target.obstacle_count()
    );
    let reference = common::lidar::reference();
    let pair = Pair { source, target, t_target_source: reference };
    let report = run(&pair, &params, None);
    let found = report.outcome.expect("a match");
    let (dt, dr) = errors(&found.t_target_source, &reference);
    eprintln!("lidar error {dt:.4} m {dr:.3}°");
    assert!(dt < 0.05 && dr < 0.3, "error {dt:.3} m, {dr:.2}°");
}
