//! Trajectory error metrics: ATE (evo's APE), RPE over frames, metres or seconds, yaw error,
//! final error in % of the distance travelled, evaluation of online estimates, and pose-graph
//! statistics.
//!
//! Definitions follow evo 1.38.1 (`evo/core/metrics.py`, `evo/core/filters.py`) so the numbers
//! agree with `evo_ape` / `evo_rpe`:
//! - APE error pose `E = est⁻¹ · gt`; RPE error pose `E = (gt_i⁻¹ gt_j)⁻¹ (est_i⁻¹ est_j)`.
//! - [`PoseRelation`]: translation part (‖Δp‖, m), rotation angle of `E` (rad or deg), rotation
//!   part ‖R_E − I‖_F, full transformation ‖E − I‖_F (4×4), all as in evo's `PoseRelation`.
//! - [`Stats`]: rmse, mean, median, std (population), min, max, sse, as evo's `get_all_statistics`.
//! - RPE pairs are chosen on the (aligned) estimate, consecutive and non-overlapping, as evo does
//!   by default (`pairs_from_reference = False`, `all_pairs = False`).
//!
//! # Online estimates
//!
//! A SLAM system re-optimizes its past: the final trajectory it writes at the end is smoother and
//! better than what the robot knew while driving. [`online_ate`] evaluates the estimate as the
//! robot had it: a TUM file whose every row is the pose the system reported at that stamp (its
//! latest estimate of the current pose, never revised). Each row is compared with the ground
//! truth interpolated at its stamp ([`associate_interpolated`]); only no alignment (the estimate
//! is already in the ground truth's frame, e.g. initialized from it) or the first-N-metres
//! alignment (thesis §7.4: what a robot could calibrate at the start of a run) are allowed,
//! since a whole-run fit would use knowledge of the future.

use std::collections::HashMap;

use nalgebra::{Isometry3, Matrix3, Matrix4, UnitQuaternion};
use posegraph::g2o::G2oGraph;

use crate::align::{self, AlignError, Alignment, Sim3};
use crate::associate::{AssociateError, Association, associate_interpolated};
use crate::trajectory::Trajectory;

/// What part of the error pose becomes the error value (evo's `PoseRelation`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PoseRelation {
    /// ‖translation of E‖ (m).
    #[default]
    Translation,
    /// Rotation angle of E (rad).
    RotationAngleRad,
    /// Rotation angle of E (deg).
    RotationAngleDeg,
    /// ‖R_E − I‖_F (unitless).
    RotationPart,
    /// ‖E − I‖_F of the 4×4 matrix (unitless).
    Full,
}

impl PoseRelation {
    /// The unit of the error values.
    pub fn unit(self) -> &'static str {
        match self {
            Self::Translation => "m",
            Self::RotationAngleRad => "rad",
            Self::RotationAngleDeg => "deg",
            Self::RotationPart | Self::Full => "",
        }
    }

    /// evo's `--pose_relation` name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Translation => "trans_part",
            Self::RotationAngleRad => "angle_rad",
            Self::RotationAngleDeg => "angle_deg",
            Self::RotationPart => "rot_part",
            Self::Full => "full",
        }
    }
}

/// A pose-relation name other than evo's.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown pose relation `{0}` (expected trans_part, angle_rad, angle_deg, rot_part or full)")]
pub struct UnknownPoseRelation(pub String);

impl core::str::FromStr for PoseRelation {
    type Err = UnknownPoseRelation;

    fn from_str(name: &str) -> Result<Self, Self::Err> {
        match name {
            "trans_part" | "trans" => Ok(Self::Translation),
            "angle_rad" => Ok(Self::RotationAngleRad),
            "angle_deg" => Ok(Self::RotationAngleDeg),
            "rot_part" => Ok(Self::RotationPart),
            "full" => Ok(Self::Full),
            _ => Err(UnknownPoseRelation(name.chars().take(40).collect())),
        }
    }
}

/// Summary statistics of error values, as evo computes them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Stats {
    pub rmse: f64,
    pub mean: f64,
    pub median: f64,
    /// Population standard deviation (numpy's default `ddof = 0`).
    pub std: f64,
    pub min: f64,
    pub max: f64,
    /// Sum of squared errors.
    pub sse: f64,
    pub count: usize,
}

impl Stats {
    /// The statistics under evo's names, in evo's order.
    pub fn named(&self) -> [(&'static str, f64); 7] {
        [
            ("rmse", self.rmse),
            ("mean", self.mean),
            ("median", self.median),
            ("std", self.std),
            ("min", self.min),
            ("max", self.max),
            ("sse", self.sse),
        ]
    }

    /// `None` for no values.
    pub fn from_errors(errors: &[f64]) -> Option<Self> {
        if errors.is_empty() {
            return None;
        }
        let n = errors.len() as f64;
        let sse: f64 = errors.iter().map(|e| e * e).sum();
        let mean = errors.iter().sum::<f64>() / n;
        let variance = errors.iter().map(|e| (e - mean).powi(2)).sum::<f64>() / n;
        let mut sorted = errors.to_vec();
        sorted.sort_by(f64::total_cmp);
        let middle = sorted.len() / 2;
        let median = if sorted.len() % 2 == 1 { sorted[middle] } else { (sorted[middle - 1] + sorted[middle]) / 2.0 };
        Some(Self {
            rmse: (sse / n).sqrt(),
            mean,
            median,
            std: variance.sqrt(),
            min: sorted[0],
            max: sorted[sorted.len() - 1],
            sse,
            count: errors.len(),
        })
    }
}

/// Rotation angle (rad, in [0, π]) of a rotation. atan2 of the quaternion's vector norm and
/// scalar rather than acos of the scalar, which loses half the digits near 0, where RPE angles
/// live.
pub fn rotation_angle_rad(rotation: &UnitQuaternion<f64>) -> f64 {
    let q = rotation.quaternion();
    2.0 * q.imag().norm().atan2(q.w.abs())
}

/// The error value of an error pose `e` under `relation`.
fn error_value(e: &Isometry3<f64>, relation: PoseRelation) -> f64 {
    match relation {
        PoseRelation::Translation => e.translation.vector.norm(),
        PoseRelation::RotationAngleRad => rotation_angle_rad(&e.rotation),
        PoseRelation::RotationAngleDeg => rotation_angle_rad(&e.rotation).to_degrees(),
        PoseRelation::RotationPart => (e.rotation.to_rotation_matrix().into_inner() - Matrix3::identity()).norm(),
        PoseRelation::Full => (e.to_homogeneous() - Matrix4::identity()).norm(),
    }
}

/// Absolute pose errors of paired poses (evo's APE).
pub fn ape_errors(gt: &[Isometry3<f64>], est: &[Isometry3<f64>], relation: PoseRelation) -> Vec<f64> {
    gt.iter()
        .zip(est)
        .map(|(gt, est)| match relation {
            // evo takes the position difference directly: same norm as E's translation, fewer
            // roundings.
            PoseRelation::Translation => (est.translation.vector - gt.translation.vector).norm(),
            _ => error_value(&(est.inverse() * gt), relation),
        })
        .collect()
}

/// Spacing of the RPE pose pairs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Delta {
    /// Every n-th pose (evo's `--delta n --delta_unit f`; evo's default is 1).
    Frames(usize),
    /// Path length (m) along the estimate (evo's `--delta_unit m`): a pair ends at the first pose
    /// where the path since the pair's start reaches the delta.
    Metres(f64),
    /// Time (s): a pair ends at the first pose at least this long after the pair's start.
    Seconds(f64),
}

/// Consecutive, non-overlapping index pairs `(i, j)` of `poses` spaced by `delta` (evo's
/// `filter_pairs_by_index` / `filter_pairs_by_path`, and the same rule over time). Empty when
/// the trajectory is shorter than one delta.
pub fn rpe_pairs(
    poses: &[Isometry3<f64>],
    stamps_s: &[f64],
    delta: Delta,
) -> Result<Vec<(usize, usize)>, MetricsError> {
    let mut ids = Vec::new();
    match delta {
        Delta::Frames(0) => return Err(MetricsError::BadDelta("delta must be at least 1 frame".into())),
        Delta::Frames(step) => ids.extend((0..poses.len()).step_by(step)),
        Delta::Metres(delta_m) => {
            if !(delta_m.is_finite() && delta_m > 0.0) {
                return Err(MetricsError::BadDelta(format!("delta must be a positive distance, got {delta_m} m")));
            }
            if !poses.is_empty() {
                ids.push(0);
            }
            let mut path_m = 0.0;
            for i in 1..poses.len() {
                path_m += (poses[i].translation.vector - poses[i - 1].translation.vector).norm();
                if path_m >= delta_m {
                    ids.push(i);
                    path_m = 0.0;
                }
            }
        }
        Delta::Seconds(delta_s) => {
            if !(delta_s.is_finite() && delta_s > 0.0) {
                return Err(MetricsError::BadDelta(format!("delta must be a positive duration, got {delta_s} s")));
            }
            if poses.len() != stamps_s.len() {
                return Err(MetricsError::LengthMismatch { gt: stamps_s.len(), est: poses.len() });
            }
            let Some(&first_s) = stamps_s.first() else {
                return Ok(Vec::new());
            };
            ids.push(0);
            let mut start_s = first_s;
            for (i, &t) in stamps_s.iter().enumerate().skip(1) {
                if t - start_s >= delta_s {
                    ids.push(i);
                    start_s = t;
                }
            }
        }
    }
    Ok(ids.windows(2).map(|w| (w[0], w[1])).collect())
}

/// Relative pose errors over `pairs` of paired poses (evo's RPE).
pub fn rpe_errors(
    gt: &[Isometry3<f64>],
    est: &[Isometry3<f64>],
    pairs: &[(usize, usize)],
    relation: PoseRelation,
) -> Vec<f64> {
    pairs
        .iter()
        .filter(|&&(i, j)| i < gt.len() && j < gt.len() && i < est.len() && j < est.len())
        .map(|&(i, j)| {
            let gt_rel = gt[i].inverse() * gt[j];
            let est_rel = est[i].inverse() * est[j];
            error_value(&(gt_rel.inverse() * est_rel), relation)
        })
        .collect()
}

/// Wraps an angle (rad) to (−π, π].
pub fn wrap_angle_rad(angle_rad: f64) -> f64 {
    use core::f64::consts::PI;
    // In range already: returned untouched, since `rem_euclid` would round a tiny negative angle
    // up to 2π, i.e. to 0.
    if angle_rad > -PI && angle_rad <= PI {
        return angle_rad;
    }
    let wrapped = angle_rad.rem_euclid(core::f64::consts::TAU);
    if wrapped > PI { wrapped - core::f64::consts::TAU } else { wrapped }
}

/// Signed heading errors yaw(est) − yaw(gt) (rad), wrapped to (−π, π]. Yaw is the z angle of
/// the `Rz·Ry·Rx` decomposition, meaningful for ground vehicles (pitch far from ±90°).
pub fn yaw_errors_rad(gt: &[Isometry3<f64>], est: &[Isometry3<f64>]) -> Vec<f64> {
    gt.iter()
        .zip(est)
        .map(|(gt, est)| wrap_angle_rad(align::yaw_rad(&est.rotation) - align::yaw_rad(&gt.rotation)))
        .collect()
}

/// Position error at the last pair, and relative to the distance travelled (thesis ch. 8).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FinalError {
    pub error_m: f64,
    /// Path length of the paired ground-truth poses (m).
    pub gt_path_length_m: f64,
    /// `error_m / gt_path_length_m` in %; `None` for a robot that did not move.
    pub percent: Option<f64>,
}

/// Final position error of paired poses. The distance travelled is the path length of the
/// paired ground-truth poses, i.e. sampled at the estimate's rate: a 200 Hz motion-capture
/// ground truth summed sample by sample would add its millimetre jitter at every step, and at
/// standstill that jitter alone accumulates into metres.
pub fn final_error(gt: &[Isometry3<f64>], est: &[Isometry3<f64>]) -> Option<FinalError> {
    let (last_gt, last_est) = (gt.last()?, est.last()?);
    let error_m = (last_est.translation.vector - last_gt.translation.vector).norm();
    let gt_path_length_m = align::path_distances_m(gt).last().copied().unwrap_or(0.0);
    let percent = (gt_path_length_m > 0.0).then(|| 100.0 * error_m / gt_path_length_m);
    Some(FinalError { error_m, gt_path_length_m, percent })
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MetricsError {
    #[error("no pose pairs to evaluate")]
    NoPairs,
    #[error("{0}")]
    BadDelta(String),
    #[error("the delta produced no RPE pairs: the trajectory is shorter than one delta")]
    NoRpePairs,
    #[error("ground truth and estimate have different numbers of poses ({gt} vs {est})")]
    LengthMismatch { gt: usize, est: usize },
    #[error("alignment: {0}")]
    Align(#[from] AlignError),
    #[error("association: {0}")]
    Associate(#[from] AssociateError),
    #[error("online estimates allow only `none` or `first:<N>m` alignment (got `{0}`): any other fit uses the future")]
    OnlineAlignment(Alignment),
}

/// Result of [`ate`].
#[derive(Debug, Clone, PartialEq)]
pub struct AteReport {
    pub stats: Stats,
    /// Per-pair error values, in the relation's unit.
    pub errors: Vec<f64>,
    pub final_error: FinalError,
    /// Signed heading errors (rad, wrapped to (−π, π]) and their statistics.
    pub yaw_errors_rad: Vec<f64>,
    pub yaw_stats_rad: Stats,
    /// The fitted alignment (identity for [`Alignment::None`]).
    pub alignment: Sim3,
    /// Aligned estimate and ground truth as evaluated (projected to the plane for SE(2)).
    pub est_aligned: Vec<Isometry3<f64>>,
    pub gt: Vec<Isometry3<f64>>,
}

/// The fitted alignment, the ground truth and the aligned estimate.
struct AlignedPairs {
    sim3: Sim3,
    gt: Vec<Isometry3<f64>>,
    est: Vec<Isometry3<f64>>,
}

/// Fits the alignment and applies it; both sides are projected to the xy plane for
/// [`Alignment::Se2`].
fn aligned_pairs(association: &Association, alignment: &Alignment) -> Result<AlignedPairs, MetricsError> {
    if association.gt.len() != association.est.len() {
        return Err(MetricsError::LengthMismatch { gt: association.gt.len(), est: association.est.len() });
    }
    if association.is_empty() {
        return Err(MetricsError::NoPairs);
    }
    let sim3 = align::fit(alignment, &association.est, &association.gt)?;
    let est = sim3.apply_all(&association.est);
    Ok(match alignment {
        Alignment::Se2 => {
            AlignedPairs { sim3, gt: align::project_to_plane(&association.gt), est: align::project_to_plane(&est) }
        }
        _ => AlignedPairs { sim3, gt: association.gt.clone(), est },
    })
}

/// Absolute trajectory error of associated poses after `alignment` (evo's `evo_ape`).
pub fn ate(
    association: &Association,
    alignment: &Alignment,
    relation: PoseRelation,
) -> Result<AteReport, MetricsError> {
    let AlignedPairs { sim3, gt, est } = aligned_pairs(association, alignment)?;
    let errors = ape_errors(&gt, &est, relation);
    let yaw_errors = yaw_errors_rad(&gt, &est);
    let (Some(stats), Some(yaw_stats), Some(final_error)) =
        (Stats::from_errors(&errors), Stats::from_errors(&yaw_errors), final_error(&gt, &est))
    else {
        return Err(MetricsError::NoPairs);
    };
    Ok(AteReport {
        stats,
        errors,
        final_error,
        yaw_errors_rad: yaw_errors,
        yaw_stats_rad: yaw_stats,
        alignment: sim3,
        est_aligned: est,
        gt,
    })
}

/// Result of [`rpe`].
#[derive(Debug, Clone, PartialEq)]
pub struct RpeReport {
    pub stats: Stats,
    pub errors: Vec<f64>,
    /// Index pairs into the association.
    pub pairs: Vec<(usize, usize)>,
    pub alignment: Sim3,
}

/// Relative pose error of associated poses after `alignment` (evo's `evo_rpe`). Alignment only
/// matters through scale (Sim(3)) and, for a metre delta, through the pair choice on the scaled
/// estimate; a rigid alignment leaves relative poses unchanged.
pub fn rpe(
    association: &Association,
    alignment: &Alignment,
    delta: Delta,
    relation: PoseRelation,
) -> Result<RpeReport, MetricsError> {
    let AlignedPairs { sim3, gt, est } = aligned_pairs(association, alignment)?;
    let pairs = rpe_pairs(&est, &association.stamps_s, delta)?;
    let errors = rpe_errors(&gt, &est, &pairs, relation);
    let stats = Stats::from_errors(&errors).ok_or(MetricsError::NoRpePairs)?;
    Ok(RpeReport { stats, errors, pairs, alignment: sim3 })
}

/// ATE of an online estimate (see the module documentation): every estimate row against the
/// ground truth interpolated at its stamp + `offset_s` (rows in ground-truth gaps over
/// `max_gap_s` are skipped), with no alignment or the first-N-metres alignment only.
pub fn online_ate(
    gt: &Trajectory,
    est: &Trajectory,
    offset_s: f64,
    max_gap_s: f64,
    alignment: &Alignment,
    relation: PoseRelation,
) -> Result<AteReport, MetricsError> {
    if !matches!(alignment, Alignment::None | Alignment::FirstMetres { .. }) {
        return Err(MetricsError::OnlineAlignment(*alignment));
    }
    let association = associate_interpolated(gt, est, offset_s, max_gap_s)?;
    ate(&association, alignment, relation)
}

/// Pose-graph statistics of a g2o file.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GraphStats {
    /// Distinct vertex ids, from vertex records and edge endpoints.
    pub vertices: usize,
    pub edges: usize,
    /// Edges between consecutive ids (|i − j| = 1).
    pub odometry_edges: usize,
    /// All other edges.
    pub loop_closure_edges: usize,
    /// Connected components over the edges (an isolated vertex is one).
    pub components: usize,
    /// 2 · edges / vertices (0 without vertices).
    pub mean_degree: f64,
}

/// Counts vertices, odometry and loop-closure edges and connected components of a graph.
pub fn graph_stats(graph: &G2oGraph) -> GraphStats {
    let mut index_of: HashMap<u64, usize> = HashMap::new();
    let ids = graph.vertices.iter().map(|v| v.id).chain(graph.edges.iter().flat_map(|e| [e.from, e.to]));
    for id in ids {
        let next = index_of.len();
        index_of.entry(id).or_insert(next);
    }
    let mut parent: Vec<usize> = (0..index_of.len()).collect();
    let mut components = index_of.len();
    let mut odometry_edges = 0;
    for edge in &graph.edges {
        if edge.from.abs_diff(edge.to) == 1 {
            odometry_edges += 1;
        }
        let (Some(&a), Some(&b)) = (index_of.get(&edge.from), index_of.get(&edge.to)) else {
            continue;
        };
        let (root_a, root_b) = (find_root(&mut parent, a), find_root(&mut parent, b));
        if root_a != root_b {
            parent[root_a] = root_b;
            components -= 1;
        }
    }
    let vertices = index_of.len();
    GraphStats {
        vertices,
        edges: graph.edges.len(),
        odometry_edges,
        loop_closure_edges: graph.edges.len() - odometry_edges,
        components,
        mean_degree: if vertices == 0 { 0.0 } else { 2.0 * graph.edges.len() as f64 / vertices as f64 },
    }
}

/// Union-find root with path halving.
fn find_root(parent: &mut [usize], mut node: usize) -> usize {
    while parent[node] != node {
        parent[node] = parent[parent[node]];
        node = parent[node];
    }
    node
}
