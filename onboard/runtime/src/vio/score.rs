//! Scoring an estimate against ground truth with `eval`.
//!
//! - ATE: RMSE (mean, max) of the position error after the SE(3) alignment of the whole
//!   trajectory (evo's `--align`), every estimate pose against the ground truth interpolated at
//!   its stamp.
//! - Final drift: the last position error with the estimate anchored at the first paired pose
//!   (`t_gt_0 · t_est_0⁻¹ · t_est`), in % of the ground truth's path length over the paired span;
//!   this is what a rover that knows only its start pose would see. The same after the SE(3)
//!   alignment is reported too (smaller: the fit spreads the drift over the run).
//! - Maximum displacement of the estimate from its first pose (the stand-still test).

use std::path::Path;

use eval::align::Alignment;
use eval::associate::associate_interpolated;
use eval::io::{self, Format};
use eval::metrics::{self, PoseRelation};
use eval::trajectory::Trajectory;
use nalgebra::Isometry3;

use super::VioError;
use super::dataset::DatasetKind;

/// Largest gap between ground-truth samples an estimate pose may fall into.
const MAX_GT_GAP_S: f64 = 0.5;

/// Errors of an estimate (see the module documentation); JSON keys in the CLI are these names.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Score {
    pub pairs: usize,
    pub ate_rmse_m: f64,
    pub ate_mean_m: f64,
    pub ate_max_m: f64,
    pub gt_path_length_m: f64,
    pub final_error_m: f64,
    pub final_drift_percent: Option<f64>,
    pub final_error_aligned_m: f64,
    pub final_drift_aligned_percent: Option<f64>,
    /// Rotation angle between the anchored final estimate and the final ground truth (deg).
    pub final_rotation_error_deg: f64,
}

/// Reads a ground-truth file (TUM, KITTI poses or EuRoC CSV; detected from the content) as body
/// poses. KITTI poses are `T_world_cam0`: with a KITTI dataset they are turned into body poses
/// with the dataset's `t_body_cam`, and stamped with the dataset's image stamps (one row per
/// frame, as KITTI ships them).
pub fn load_ground_truth(
    path: &Path,
    kind: DatasetKind,
    image_stamps_ns: &[u64],
    t_body_cam: &Isometry3<f64>,
) -> Result<Trajectory, VioError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| VioError::Input(format!("cannot read ground truth {}: {e}", path.display())))?;
    let bad = |e: io::ParseError| VioError::Input(format!("ground truth {}: {e}", path.display()));
    let (format, mut trajectory) = io::parse(&text, None).map_err(bad)?;
    if format == Format::Kitti {
        if kind != DatasetKind::Kitti {
            return Err(VioError::Input(format!(
                "ground truth {}: KITTI poses carry no stamps; use them with a KITTI dataset",
                path.display()
            )));
        }
        if trajectory.len() != image_stamps_ns.len() {
            return Err(VioError::Input(format!(
                "ground truth {}: {} poses for {} frames",
                path.display(),
                trajectory.len(),
                image_stamps_ns.len()
            )));
        }
        trajectory.stamps_s = image_stamps_ns.iter().map(|&s| s as f64 * 1e-9).collect();
        let t_cam_body = t_body_cam.inverse();
        for pose in &mut trajectory.poses {
            *pose *= t_cam_body;
        }
    }
    Ok(trajectory)
}

/// The estimate as an `eval` trajectory (stamps in seconds).
pub fn estimate_trajectory(stamps_ns: &[u64], poses: &[Isometry3<f64>]) -> Result<Trajectory, VioError> {
    Trajectory::new(stamps_ns.iter().map(|&s| s as f64 * 1e-9).collect(), poses.to_vec())
        .map_err(|e| VioError::Input(format!("estimate: {e}")))
}

/// Scores `estimate` against `gt` (see the module documentation).
pub fn score(estimate: &Trajectory, gt: &Trajectory) -> Result<Score, VioError> {
    let association = associate_interpolated(gt, estimate, 0.0, MAX_GT_GAP_S)
        .map_err(|e| VioError::Input(format!("scoring: {e}")))?;
    let report = metrics::ate(&association, &Alignment::Se3, PoseRelation::Translation)
        .map_err(|e| VioError::Input(format!("scoring: {e}")))?;
    let (Some(gt_first), Some(est_first), Some(gt_last), Some(est_last)) =
        (association.gt.first(), association.est.first(), association.gt.last(), association.est.last())
    else {
        return Err(VioError::Input("scoring: no pose pairs".to_owned()));
    };
    let t_gt_est = gt_first * est_first.inverse();
    let anchored_last = t_gt_est * est_last;
    let final_error_m = (anchored_last.translation.vector - gt_last.translation.vector).norm();
    let gt_path_length_m = report.final_error.gt_path_length_m;
    let percent = |error_m: f64| (gt_path_length_m > 0.0).then(|| 100.0 * error_m / gt_path_length_m);
    Ok(Score {
        pairs: association.len(),
        ate_rmse_m: report.stats.rmse,
        ate_mean_m: report.stats.mean,
        ate_max_m: report.stats.max,
        gt_path_length_m,
        final_error_m,
        final_drift_percent: percent(final_error_m),
        final_error_aligned_m: report.final_error.error_m,
        final_drift_aligned_percent: report.final_error.percent,
        final_rotation_error_deg: metrics::rotation_angle_rad(&(gt_last.inverse() * anchored_last).rotation)
            .to_degrees(),
    })
}

/// Largest distance of any pose from the first one (m).
pub fn max_displacement_m(poses: &[Isometry3<f64>]) -> f64 {
    let Some(first) = poses.first() else {
        return 0.0;
    };
    poses.iter().map(|p| (p.translation.vector - first.translation.vector).norm()).fold(0.0, f64::max)
}
