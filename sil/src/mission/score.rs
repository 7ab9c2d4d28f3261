//! Trajectory errors of a robot's online estimate (thesis ch. 8) with `eval`.
//!
//! The estimate is what the robot had at each moment, in its own global frame (its first submap
//! origin, thesis §3.3); the ground truth is expressed in the same frame through the true pose
//! of that origin, so no alignment is fitted: every error is one the robot really had.

use eval::Trajectory;
use eval::align::Alignment;
use eval::metrics::{PoseRelation, online_ate};
use nalgebra::Isometry3;

/// Errors of one robot's online trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrajectoryScore {
    /// Ground-truth path length over the evaluated stamps.
    pub distance_m: f64,
    pub mean_error_m: f64,
    pub rmse_m: f64,
    pub max_error_m: f64,
    pub final_error_m: f64,
    /// Final error over the distance, `None` for a robot that did not move.
    pub final_error_percent: Option<f64>,
    pub mean_yaw_error_deg: f64,
    pub poses: usize,
}

impl TrajectoryScore {
    /// Mean 3-D error over the distance travelled (%, the thesis's headline figure), `None` for
    /// a robot that did not move.
    pub fn mean_error_percent(&self) -> Option<f64> {
        (self.distance_m > 0.0).then(|| 100.0 * self.mean_error_m / self.distance_m)
    }
}

/// Why a trajectory could not be scored.
#[derive(Debug, thiserror::Error)]
pub enum ScoreError {
    #[error("trajectory: {0}")]
    Trajectory(String),
    #[error("metrics: {0}")]
    Metrics(#[from] eval::metrics::MetricsError),
}

/// Seconds of a nanosecond stamp, for `eval`'s trajectories.
pub fn stamp_s(stamp_ns: u64) -> f64 {
    stamp_ns as f64 * 1e-9
}

/// A trajectory of `(stamp_ns, pose)` rows.
pub fn trajectory(rows: &[(u64, Isometry3<f64>)]) -> Result<Trajectory, ScoreError> {
    Trajectory::new(rows.iter().map(|(s, _)| stamp_s(*s)).collect(), rows.iter().map(|(_, p)| *p).collect())
        .map_err(|e| ScoreError::Trajectory(e.to_string()))
}

/// Scores `estimate` against `truth` (both in the robot's own frame): each estimate row against
/// the truth interpolated at its stamp (gaps over 0.5 s skipped), no alignment.
pub fn score(
    estimate: &[(u64, Isometry3<f64>)],
    truth: &[(u64, Isometry3<f64>)],
) -> Result<TrajectoryScore, ScoreError> {
    let (est, gt) = (trajectory(estimate)?, trajectory(truth)?);
    let report = online_ate(&gt, &est, 0.0, 0.5, &Alignment::None, PoseRelation::Translation)?;
    let yaw_n = report.yaw_errors_rad.len().max(1) as f64;
    Ok(TrajectoryScore {
        distance_m: report.final_error.gt_path_length_m,
        mean_error_m: report.stats.mean,
        rmse_m: report.stats.rmse,
        max_error_m: report.stats.max,
        final_error_m: report.final_error.error_m,
        final_error_percent: report.final_error.percent,
        mean_yaw_error_deg: report.yaw_errors_rad.iter().map(|e| e.abs()).sum::<f64>() / yaw_n * 180.0
            / std::f64::consts::PI,
        poses: report.stats.count,
    })
}
