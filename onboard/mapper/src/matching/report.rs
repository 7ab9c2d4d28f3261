//! What the matcher returns: the outcome of a pair, its stage times, and why a cloud or a pair
//! was rejected.

use nalgebra::{Isometry3, Matrix6, Vector3};

/// Why a cloud cannot be matched (§6.1.1 a, d).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Unsuitable {
    #[error("too few points ({points} < {min})")]
    TooFewPoints { points: usize, min: usize },
    #[error("too few obstacle points ({points} < {min})")]
    TooFewObstaclePoints { points: usize, min: usize },
    /// Fewer than `min` keypoints lie off the keypoints' RANSAC line (a straight wall, one
    /// stone).
    #[error("keypoints not descriptive ({spread} off their line < {min})")]
    NotDescriptive { spread: usize, min: usize },
}

impl Unsuitable {
    /// Stable snake_case name for reports and JSON.
    pub fn name(&self) -> &'static str {
        match self {
            Unsuitable::TooFewPoints { .. } => "too_few_points",
            Unsuitable::TooFewObstaclePoints { .. } => "too_few_obstacle_points",
            Unsuitable::NotDescriptive { .. } => "not_descriptive",
        }
    }
}

/// The SLAM estimate of the relative pose and the thesis's Δσ_t (t = x, y, z) per axis, metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativePrior {
    pub t_target_source: Isometry3<f64>,
    pub delta_sigma_m: Vector3<f64>,
}

impl RelativePrior {
    /// Whether `t_target_source`'s translation is within `factor`·Δσ_t of the prior's on every
    /// axis (the thesis's 2Δσ gate with `factor` = 2). Δσ_t = 0 rejects everything (trap T5).
    pub fn contains(&self, t_target_source: &Isometry3<f64>, factor: f64) -> bool {
        let d = t_target_source.translation.vector - self.t_target_source.translation.vector;
        (0..3).all(|a| d[a].abs() <= factor * self.delta_sigma_m[a])
    }
}

/// Why a pair gave no match.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum Rejection {
    #[error("source unsuitable: {0}")]
    SourceUnsuitable(Unsuitable),
    #[error("target unsuitable: {0}")]
    TargetUnsuitable(Unsuitable),
    #[error("too few correspondences ({found} < {min})")]
    TooFewCorrespondences { found: usize, min: usize },
    #[error("no Hough/RANSAC hypothesis")]
    NoHypothesis,
    /// Every hypothesis lies outside 2·Δσ_t of the prior.
    #[error("every hypothesis outside the prior's bounds")]
    OutsidePriorBounds,
    /// Every remaining hypothesis failed the keypoint-distribution check.
    #[error("every remaining hypothesis badly distributed")]
    BadlyDistributed,
    /// Too few ICP pairs, a degenerate alignment, or the RMSE above its limit.
    #[error("ICP failed")]
    IcpFailed,
    #[error("ICP result outside the prior's bounds")]
    FinalOutsidePriorBounds,
    /// 6D mode only: roll or pitch implausible after RANSAC (every hypothesis) or after ICP.
    #[error("roll/pitch implausible")]
    RollPitchImplausible,
}

impl Rejection {
    /// Stable snake_case name for reports and JSON.
    pub fn name(&self) -> &'static str {
        match self {
            Rejection::SourceUnsuitable(_) => "source_unsuitable",
            Rejection::TargetUnsuitable(_) => "target_unsuitable",
            Rejection::TooFewCorrespondences { .. } => "too_few_correspondences",
            Rejection::NoHypothesis => "no_hypothesis",
            Rejection::OutsidePriorBounds => "outside_prior_bounds",
            Rejection::BadlyDistributed => "badly_distributed",
            Rejection::IcpFailed => "icp_failed",
            Rejection::FinalOutsidePriorBounds => "final_outside_prior_bounds",
            Rejection::RollPitchImplausible => "roll_pitch_implausible",
        }
    }
}

/// A match.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchFound {
    pub t_target_source: Isometry3<f64>,
    /// 6×6, `[translation, rotation]`, in the convention of `mapper::slam::SubmapMatch::covariance`
    /// (the graph's between-factor tangent); roll/pitch get small fixed variances in 4D mode.
    pub covariance: Matrix6<f64>,
    /// Point-to-point RMSE of the final ICP alignment over its inlier pairs.
    pub rmse_m: f64,
    /// Correspondences of the selected hypothesis's Hough cluster.
    pub correspondences: usize,
    /// RANSAC inliers of the selected hypothesis (the correspondences it is selected by).
    pub inliers: usize,
    pub icp_pairs: usize,
    pub icp_iterations: usize,
}

/// Wall-clock seconds per stage (`features_s` is zero when both clouds' features were cached).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StageTimes {
    pub features_s: f64,
    pub correspondences_s: f64,
    pub hough_ransac_s: f64,
    pub icp_s: f64,
    pub total_s: f64,
}

/// The outcome of one pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchReport {
    pub outcome: Result<MatchFound, Rejection>,
    pub times: StageTimes,
    /// After k-NN both ways + threshold + dedup.
    pub correspondences: usize,
    /// Hough/RANSAC hypotheses from both directions, before filtering.
    pub hypotheses: usize,
}
