//! Why a pair did or did not match, against a known relative pose (the simulator's truth, a
//! dataset's reference): how many keypoints the clouds share under it, how many of the
//! descriptors' correspondences agree with it, and whether a Hough/RANSAC hypothesis lies near
//! it. The matcher itself never sees the known pose; this is for evaluations and for tuning.

use nalgebra::{Isometry3, Point3};

use super::correspondences::find_correspondences;
use super::icp::{Problem, icp};
use super::params::MatcherParams;
use super::pipeline::hypotheses;
use super::prepared::PreparedCloud;

/// Two keypoints closer than this under the known pose are the same obstacle seen twice (twice
/// the 0.1 m keypoint voxel).
pub const SAME_KEYPOINT_M: f64 = 0.2;

/// A pair's matcher internals measured against a known `t_target_source`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PairDiagnosis {
    /// Source keypoints within [`SAME_KEYPOINT_M`] of a target keypoint.
    pub shared_keypoints: usize,
    /// Described keypoints (source, target).
    pub described: (usize, usize),
    pub correspondences: usize,
    /// Correspondences whose two keypoints lie within `ransac_inlier_m` of each other under the
    /// known pose.
    pub true_correspondences: usize,
    pub hypotheses: usize,
    /// Hypotheses within 0.5 m and 5° of the known pose.
    pub true_hypotheses: usize,
    /// The most RANSAC inliers of any hypothesis, and of a true one.
    pub best_inliers: usize,
    pub best_true_inliers: usize,
    /// ICP (the matcher's, on the full clouds) started at the known pose: how far it moved
    /// away from it (m, degrees) and its RMSE; None when it failed.
    pub icp_from_truth: Option<(f64, f64, f64)>,
}

/// Source keypoints within [`SAME_KEYPOINT_M`] of a target keypoint under `t_target_source`
/// (brute force: a few hundred keypoints per submap).
pub fn shared_keypoints(source: &[Point3<f32>], target: &[Point3<f32>], t_target_source: &Isometry3<f64>) -> usize {
    let r2 = SAME_KEYPOINT_M * SAME_KEYPOINT_M;
    source
        .iter()
        .filter(|p| {
            let q = t_target_source * p.cast::<f64>();
            target.iter().any(|k| (k.cast::<f64>() - q).norm_squared() < r2)
        })
        .count()
}

/// Runs the matcher's features, correspondences and hypotheses on a pair (as `match_clouds`
/// does, without prior, gates or ICP) and measures them against `t_target_source`.
pub fn diagnose(
    source: &PreparedCloud,
    target: &PreparedCloud,
    t_target_source: &Isometry3<f64>,
    params: &MatcherParams,
) -> PairDiagnosis {
    let mut d = PairDiagnosis {
        shared_keypoints: shared_keypoints(source.keypoints(), target.keypoints(), t_target_source),
        ..PairDiagnosis::default()
    };
    if source.suitability().is_err() || target.suitability().is_err() {
        return d;
    }
    let (fs, ft) = (source.features(), target.features());
    d.described = (fs.position.len(), ft.position.len());
    let corrs = find_correspondences(&fs.descriptors, &ft.descriptors, params.k_neighbours, params.min_similarity);
    d.correspondences = corrs.len();
    d.true_correspondences = corrs
        .iter()
        .filter(|c| {
            let q = t_target_source * fs.position[c.source].cast::<f64>();
            (ft.position[c.target].cast::<f64>() - q).norm() < params.ransac_inlier_m
        })
        .count();
    let problem = Problem::between(source, target, params.icp_metric);
    d.icp_from_truth = icp(&problem, target.index(), t_target_source, params).ok().map(|r| {
        let off = t_target_source.inverse() * r.t_target_source;
        (off.translation.vector.norm(), off.rotation.angle().to_degrees(), r.rmse_m)
    });
    let hyps = hypotheses(source, target, &corrs, params);
    d.hypotheses = hyps.len();
    for h in &hyps {
        let off = t_target_source.inverse() * h.t_target_source;
        let near = off.translation.vector.norm() < 0.5 && off.rotation.angle() < 5f64.to_radians();
        d.best_inliers = d.best_inliers.max(h.inliers.len());
        if near {
            d.true_hypotheses += 1;
            d.best_true_inliers = d.best_true_inliers.max(h.inliers.len());
        }
    }
    d
}
