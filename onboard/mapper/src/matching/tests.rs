//! Unit tests of the internal stages on the synthetic terrain (tests/common/terrain.rs).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use super::icp::{Problem, icp};
use super::params::{MatchMode, MatcherParams};
use super::prepared::PreparedCloud;
use crate::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};

#[path = "../../tests/common/terrain.rs"]
mod terrain;

fn errors(est: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    let d = truth.inverse() * est;
    (d.translation.vector.norm(), d.rotation.angle().to_degrees())
}

fn rmse_at(t: &Isometry3<f64>, source: &PreparedCloud, target: &PreparedCloud, gate: f32) -> (f64, usize) {
    let tf = t.cast::<f32>();
    let mut sum = 0.0;
    let mut n = 0;
    for p in source.positions() {
        if let Some((_, d2)) = target.index().nearest(&(tf * p))
            && d2 <= gate * gate
        {
            sum += f64::from(d2);
            n += 1;
        }
    }
    ((sum / n.max(1) as f64).sqrt(), n)
}

#[test]
fn lm_icp_converges_from_a_perturbed_start() {
    let pair = terrain::standard_pair(0.01);
    for mode in [MatchMode::FourDof, MatchMode::SixDof] {
        let params = MatcherParams::with_mode(mode);
        let source = PreparedCloud::new(Arc::new(pair.source.clone()), &params);
        let target = PreparedCloud::new(Arc::new(pair.target.clone()), &params);
        let start = pair.t_target_source
            * Isometry3::from_parts(
                Translation3::new(0.15, -0.1, 0.05),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 2f64.to_radians()),
            );
        eprintln!(
            "truth rmse {:?}, start rmse {:?}",
            rmse_at(&pair.t_target_source, &source, &target, 0.15),
            rmse_at(&start, &source, &target, 0.15)
        );
        let problem = Problem {
            source: source.positions(),
            target: target.positions(),
            target_normals: target.normals(),
            metric: params.icp_metric,
        };
        let r = icp(&problem, target.index(), &start, &params).unwrap();
        let (dt, dr) = errors(&r.t_target_source, &pair.t_target_source);
        eprintln!(
            "{mode:?}: error {dt:.4} m {dr:.3}°, rmse {:.4}, {} pairs, {} iterations",
            r.rmse_m,
            r.pairs.len(),
            r.iterations
        );
        assert!(dt < 0.02 && dr < 0.2, "{mode:?}: error {dt:.3} m, {dr:.2}°");
    }
}

/// The LRFs and descriptors of the same keypoints on a rigidly moved cloud: each LRF moves with
/// the cloud, and each descriptor stays the same (up to the sign ambiguities of near-symmetric
/// supports, which SHOT's majority vote does not always resolve).
#[test]
fn lrf_and_descriptor_are_invariant_to_rigid_motion() {
    use super::descriptor::compute_features;
    use super::keypoints::obstacle_keypoints;
    use super::normals::all_normals;
    use super::spatial::PointIndex;

    let pair = terrain::standard_pair(0.01);
    let params = MatcherParams::default();
    let motions = [
        Isometry3::from_parts(
            Translation3::new(3.0, -7.0, 0.4),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 1.1),
        ),
        Isometry3::from_parts(Translation3::new(-1.0, 2.0, 0.0), UnitQuaternion::from_euler_angles(0.1, -0.08, 2.5)),
    ];
    let cloud = &pair.source;
    let keypoints = obstacle_keypoints(cloud, params.keypoint_voxel_m);
    let points: Vec<Point3<f32>> = cloud.points.iter().map(|p| p.position_m).collect();
    let index = PointIndex::new(&points);
    let normals = all_normals(&points, &index, params.normal_radius_m as f32);
    let original = compute_features(cloud, &points, &normals, &index, &keypoints, &params);
    for motion in motions {
        let m = motion.cast::<f32>();
        let moved = VoxelCloud {
            leaf_m: CLOUD_LEAF_M,
            points: cloud.points.iter().map(|p| MapPoint { position_m: m * p.position_m, ..*p }).collect(),
        };
        let moved_points: Vec<Point3<f32>> = moved.points.iter().map(|p| p.position_m).collect();
        let moved_keypoints: Vec<Point3<f32>> = keypoints.iter().map(|k| m * k).collect();
        let moved_index = PointIndex::new(&moved_points);
        let moved_normals = all_normals(&moved_points, &moved_index, params.normal_radius_m as f32);
        let after = compute_features(&moved, &moved_points, &moved_normals, &moved_index, &moved_keypoints, &params);
        let rotation = m.rotation.to_rotation_matrix().into_inner();
        let (mut same_frame, mut similar, mut both) = (0, 0, 0);
        for (i, k) in original.keypoint.iter().enumerate() {
            let Some(j) = after.keypoint.iter().position(|x| x == k) else { continue };
            both += 1;
            if (after.lrf[j] - original.lrf[i] * rotation.transpose()).amax() < 0.05 {
                same_frame += 1;
            }
            if original.descriptors.column(i).dot(&after.descriptors.column(j)) > 0.95 {
                similar += 1;
            }
        }
        eprintln!(
            "{} of {} keypoints described in both; LRF moved with the cloud: {same_frame}; descriptor cosine > 0.95: {similar}",
            both,
            original.len()
        );
        assert!(both as f64 > 0.95 * original.len() as f64);
        assert!(same_frame as f64 > 0.9 * both as f64, "{same_frame} of {both}");
        assert!(similar as f64 > 0.9 * both as f64, "{similar} of {both}");
    }
}

/// The pairing side and a matcher thread share clouds as `Arc<PreparedCloud>`.
#[test]
fn prepared_clouds_and_reports_cross_threads() {
    fn send_sync<T: Send + Sync>() {}
    send_sync::<PreparedCloud>();
    send_sync::<super::MatchReport>();
}
