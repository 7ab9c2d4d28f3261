//! Scoring `onboard vio`'s estimate on a dataset against the dataset's ground truth, with `eval`.
//!
//! - ATE: RMSE (mean, max) of the position error after the SE(3) alignment of the whole
//!   trajectory (evo's `--align`), every estimate pose against the ground truth interpolated at
//!   its stamp.
//! - Final drift: the last position error with the estimate anchored at the first paired pose
//!   (`t_gt_0 · t_est_0⁻¹ · t_est`), in % of the ground truth's path length over the paired span;
//!   this is what a rover that knows only its start pose would see. The same after the SE(3)
//!   alignment is reported too (smaller: the fit spreads the drift over the run).

use std::path::Path;

use eval::align::Alignment;
use eval::associate::associate_interpolated;
use eval::io::{self, Format};
use eval::metrics::{self, PoseRelation};
use eval::trajectory::Trajectory;
use nalgebra::Isometry3;

use hal::replay::DatasetKind;

/// Why scoring failed (unreadable or unusable ground truth, nothing to pair).
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub struct ScoreError(String);

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
) -> Result<Trajectory, ScoreError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| ScoreError(format!("cannot read ground truth {}: {e}", path.display())))?;
    let bad = |e: io::ParseError| ScoreError(format!("ground truth {}: {e}", path.display()));
    let (format, mut trajectory) = io::parse(&text, None).map_err(bad)?;
    if format == Format::Kitti {
        if kind != DatasetKind::Kitti {
            return Err(ScoreError(format!(
                "ground truth {}: KITTI poses carry no stamps; use them with a KITTI dataset",
                path.display()
            )));
        }
        if trajectory.len() != image_stamps_ns.len() {
            return Err(ScoreError(format!(
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
pub fn estimate_trajectory(rows: &[(u64, Isometry3<f64>)]) -> Result<Trajectory, ScoreError> {
    Trajectory::new(rows.iter().map(|(s, _)| *s as f64 * 1e-9).collect(), rows.iter().map(|(_, p)| *p).collect())
        .map_err(|e| ScoreError(format!("estimate: {e}")))
}

/// Scores `estimate` (`(stamp_ns, pose)` in the dataset's clock) against `gt` (see the module
/// documentation).
pub fn score(estimate: &[(u64, Isometry3<f64>)], gt: &Trajectory) -> Result<Score, ScoreError> {
    let estimate = &estimate_trajectory(estimate)?;
    let association =
        associate_interpolated(gt, estimate, 0.0, MAX_GT_GAP_S).map_err(|e| ScoreError(format!("scoring: {e}")))?;
    let report = metrics::ate(&association, &Alignment::Se3, PoseRelation::Translation)
        .map_err(|e| ScoreError(format!("scoring: {e}")))?;
    let (Some(gt_first), Some(est_first), Some(gt_last), Some(est_last)) =
        (association.gt.first(), association.est.first(), association.gt.last(), association.est.last())
    else {
        return Err(ScoreError("scoring: no pose pairs".to_owned()));
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

impl Score {
    /// The score's JSON fields (merged into `onboard vio`'s report by `sil vio --json`).
    pub fn json_fields(&self) -> [(&'static str, serde_json::Value); 10] {
        use serde_json::json;
        [
            ("gt_pairs", json!(self.pairs)),
            ("ate_rmse_m", json!(self.ate_rmse_m)),
            ("ate_mean_m", json!(self.ate_mean_m)),
            ("ate_max_m", json!(self.ate_max_m)),
            ("gt_path_length_m", json!(self.gt_path_length_m)),
            ("final_error_m", json!(self.final_error_m)),
            ("final_drift_percent", json!(self.final_drift_percent)),
            ("final_error_aligned_m", json!(self.final_error_aligned_m)),
            ("final_drift_aligned_percent", json!(self.final_drift_aligned_percent)),
            ("final_rotation_error_deg", json!(self.final_rotation_error_deg)),
        ]
    }

    pub fn print(&self) {
        println!(
            "ATE (SE(3))        RMSE {:.4} m, mean {:.4} m, max {:.4} m over {} poses",
            self.ate_rmse_m, self.ate_mean_m, self.ate_max_m, self.pairs
        );
        let percent = |p: Option<f64>| p.map_or("n/a".to_owned(), |p| format!("{p:.2} %"));
        println!(
            "final drift        {:.4} m = {} of {:.2} m (after SE(3) alignment {:.4} m = {}), rotation {:.2}°",
            self.final_error_m,
            percent(self.final_drift_percent),
            self.gt_path_length_m,
            self.final_error_aligned_m,
            percent(self.final_drift_aligned_percent),
            self.final_rotation_error_deg
        );
    }
}
