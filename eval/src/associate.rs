//! Pairing estimate and ground-truth poses by time.
//!
//! Two ways:
//! - [`associate`]: nearest stamps within `max_diff_s`, exactly evo's
//!   `sync.associate_trajectories` with its default `SyncMethod.nearest_time` (evo 1.38.1,
//!   `evo/core/sync.py`), including its choice of which side to iterate over and its tie-break, so
//!   the pairs, and with them every statistic, agree with `evo_ape` / `evo_rpe`.
//! - [`associate_interpolated`]: the ground truth interpolated on SE(3) at every estimate stamp
//!   (linear translation, slerp rotation: [`Trajectory::interpolate`]). No pose is snapped to a
//!   neighbour up to `max_diff_s` away, which matters for sparse ground truth (e.g. 20 Hz) against
//!   a fast estimate, and for online estimates whose stamps follow no grid.
//!
//! In both, `offset_s` is added to the estimate's stamps before matching (evo's `--t_offset`),
//! i.e. `t_gt = t_est + offset_s`. The returned stamps are the estimate's own, without offset.

use nalgebra::Isometry3;

use crate::trajectory::Trajectory;

/// evo's default maximum stamp difference for association (s).
pub const DEFAULT_MAX_DIFF_S: f64 = 0.01;

/// Corresponding poses: `gt[k]` and `est[k]` belong to the same moment. The ground-truth side of
/// a nearest-stamp association may repeat a pose when two estimate stamps share the nearest
/// ground-truth stamp (evo keeps such pairs too).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Association {
    /// The estimate's stamps of the pairs (s), in the estimate's time frame (no offset).
    pub stamps_s: Vec<f64>,
    pub gt: Vec<Isometry3<f64>>,
    pub est: Vec<Isometry3<f64>>,
    /// Row of each pair in the estimate trajectory.
    pub est_indices: Vec<usize>,
}

impl Association {
    pub fn len(&self) -> usize {
        self.est.len()
    }

    pub fn is_empty(&self) -> bool {
        self.est.is_empty()
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AssociateError {
    #[error(
        "found no matching stamps between ground truth and estimate with max. difference {max_diff_s} s and offset {offset_s} s"
    )]
    NoMatches { max_diff_s: f64, offset_s: f64 },
    #[error(
        "no estimate stamp (+ offset {offset_s} s) lies within the ground truth's time span with gaps ≤ {max_gap_s} s"
    )]
    NoInterpolated { offset_s: f64, max_gap_s: f64 },
    #[error("max. difference / gap must be a finite non-negative number of seconds, got {0}")]
    BadTolerance(f64),
    #[error("offset must be a finite number of seconds, got {0}")]
    BadOffset(f64),
}

/// For every stamp of `stamps_1`, the index of the nearest stamp of `stamps_2 + offset_2_s` if it
/// is within `max_diff_s`: evo's `matching_time_indices`, step for step (binary search on sorted
/// `stamps_2`, linear search otherwise; on a tie the earlier stamp wins). Returns the matched
/// indices into `stamps_1` and `stamps_2`.
pub fn matching_time_indices(
    stamps_1: &[f64],
    stamps_2: &[f64],
    max_diff_s: f64,
    offset_2_s: f64,
) -> (Vec<usize>, Vec<usize>) {
    let mut matches_1 = Vec::new();
    let mut matches_2 = Vec::new();
    // evo adds the offset element-wise before comparing; doing the same keeps ties identical.
    let stamps_2: Vec<f64> = stamps_2.iter().map(|t| t + offset_2_s).collect();
    let (Some(&first_2), Some(&last_2)) = (stamps_2.first(), stamps_2.last()) else {
        return (matches_1, matches_2);
    };
    let sorted = stamps_2.windows(2).all(|w| w[1] - w[0] >= 0.0);
    if !sorted {
        for (index_1, &stamp_1) in stamps_1.iter().enumerate() {
            // np.argmin: the first minimum; a NaN difference never wins here, which only matters
            // for trajectories built by hand (readers reject NaN stamps).
            let mut best: Option<(usize, f64)> = None;
            for (index_2, &stamp_2) in stamps_2.iter().enumerate() {
                let diff = (stamp_2 - stamp_1).abs();
                if best.is_none_or(|(_, best_diff)| diff < best_diff) {
                    best = Some((index_2, diff));
                }
            }
            if let Some((index_2, diff)) = best
                && diff <= max_diff_s
            {
                matches_1.push(index_1);
                matches_2.push(index_2);
            }
        }
        return (matches_1, matches_2);
    }
    for (index_1, &stamp_1) in stamps_1.iter().enumerate() {
        if stamp_1 < first_2 - max_diff_s || stamp_1 > last_2 + max_diff_s {
            continue;
        }
        // np.searchsorted(side="right"): the first index whose stamp is greater than stamp_1.
        let index_2 = stamps_2.partition_point(|&s| s <= stamp_1).min(stamps_2.len() - 1);
        let diff_ub = stamps_2[index_2] - stamp_1;
        let diff_lb = if index_2 > 0 { stamp_1 - stamps_2[index_2 - 1] } else { f64::INFINITY };
        let best = if diff_ub <= max_diff_s && diff_ub < diff_lb {
            index_2
        } else if diff_lb <= max_diff_s && diff_lb <= diff_ub {
            index_2 - 1
        } else {
            continue;
        };
        matches_1.push(index_1);
        matches_2.push(best);
    }
    (matches_1, matches_2)
}

fn check_tolerance(value: f64) -> Result<(), AssociateError> {
    if value.is_finite() && value >= 0.0 { Ok(()) } else { Err(AssociateError::BadTolerance(value)) }
}

fn check_offset(value: f64) -> Result<(), AssociateError> {
    if value.is_finite() { Ok(()) } else { Err(AssociateError::BadOffset(value)) }
}

/// Nearest-stamp association with evo's semantics: the trajectory with fewer poses (the estimate
/// when both have as many) is iterated over, so none of its poses is lost, and each of its stamps
/// is matched to the nearest stamp of the other within `max_diff_s`. `offset_s` is added to the
/// estimate's stamps.
pub fn associate(
    gt: &Trajectory,
    est: &Trajectory,
    max_diff_s: f64,
    offset_s: f64,
) -> Result<Association, AssociateError> {
    check_tolerance(max_diff_s)?;
    check_offset(offset_s)?;
    // evo: `second_longer = traj_2.num_poses > traj_1.num_poses` with traj_1 = ref, traj_2 = est.
    let est_longer = est.len() > gt.len();
    let (gt_indices, est_indices) = if est_longer {
        let (gt_indices, est_indices) = matching_time_indices(&gt.stamps_s, &est.stamps_s, max_diff_s, offset_s);
        (gt_indices, est_indices)
    } else {
        let (est_indices, gt_indices) = matching_time_indices(&est.stamps_s, &gt.stamps_s, max_diff_s, -offset_s);
        (gt_indices, est_indices)
    };
    if est_indices.is_empty() {
        return Err(AssociateError::NoMatches { max_diff_s, offset_s });
    }
    Ok(Association {
        stamps_s: est_indices.iter().map(|&i| est.stamps_s[i]).collect(),
        gt: gt_indices.iter().map(|&i| gt.poses[i]).collect(),
        est: est_indices.iter().map(|&i| est.poses[i]).collect(),
        est_indices,
    })
}

/// Association by interpolating the ground truth at every estimate stamp plus `offset_s`.
/// Estimate rows outside the ground truth's time span, or falling between ground-truth samples
/// more than `max_gap_s` apart (a tracking dropout), are left out.
pub fn associate_interpolated(
    gt: &Trajectory,
    est: &Trajectory,
    offset_s: f64,
    max_gap_s: f64,
) -> Result<Association, AssociateError> {
    check_tolerance(max_gap_s)?;
    check_offset(offset_s)?;
    let mut association = Association::default();
    for (index, (&stamp_s, pose)) in est.stamps_s.iter().zip(&est.poses).enumerate() {
        if let Some(gt_pose) = gt.interpolate(stamp_s + offset_s, max_gap_s) {
            association.stamps_s.push(stamp_s);
            association.gt.push(gt_pose);
            association.est.push(*pose);
            association.est_indices.push(index);
        }
    }
    if association.is_empty() {
        return Err(AssociateError::NoInterpolated { offset_s, max_gap_s });
    }
    Ok(association)
}
