//! Which submap pairs the matcher tries, and in which order (thesis §6.1.1 (e)).
//!
//! Every finished, suitable submap is placed with the graph's latest estimate of its origin. For
//! each pair not yet attempted anywhere in the team (the ledger's business, not this module's):
//!
//! 1. the xy bounding boxes of the two submaps' obstacle keypoints in the robot's global frame
//!    overlap by `overlap_t` in t ∈ {x, y}, inflated by the relative uncertainty:
//!    `overlap'_t = overlap_t + 2·Δσ_t` (eq. 6.1), each required to be positive (trap T6: two gaps
//!    would multiply to a positive "area"), and `overlap' = overlap'_x · overlap'_y > 2 m²` (eq. 6.2);
//! 2. pairs whose relative uncertainty is already below the matcher's precision are dropped:
//!    `mean_t Δσ_t < Δp · p_z² / (f · b) · √2` over t ∈ {x, y, z} (eq. 6.3, trap T7);
//! 3. the rest are ranked by `score = α · overlap' + Σ_t Δσ_t` (eq. 6.4), highest first.
//!
//! Keypoints are 0.1 m centroids of obstacle points, so their bounding box is the obstacle
//! points' box to within a voxel (the thesis boxes the obstacle points, trap T11).
//!
//! # Δσ
//!
//! The thesis's approximation, used in all its experiments (trap T5), is
//! `Δσ_t ≈ sqrt(|Σ_a,tt − Σ_b,tt|)` from the graph's marginal position variances, expressed in
//! the global frame. It is exact for two submaps on one odometry chain (the later one's variance
//! is the earlier one's plus what was accumulated between them), and it can under-estimate the
//! relative uncertainty elsewhere, which only discards pairs (the thesis accepts that).
//! [`DeltaSigma::Sum`] is the conservative alternative `sqrt(Σ_a,tt + Σ_b,tt)` (exact for
//! independent origins, an over-estimate for correlated ones).
//!
//! The graph's marginals are in its tangent convention (perturbation on the right, i.e. in the
//! origin's own frame); the translation block is rotated into the global frame here.

use std::cmp::Ordering;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use crate::slam::{SubmapId, SubmapPair};

/// How the relative standard deviation between two origins is approximated.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum DeltaSigma {
    /// `sqrt(|Σ_a − Σ_b|)` per axis: the thesis's (§6.1.1).
    #[default]
    ThesisDifference,
    /// `sqrt(Σ_a + Σ_b)` per axis: treats the two origins as independent.
    Sum,
}

/// The pairing rules' thresholds (thesis values by default).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PairingParams {
    /// Eq. 6.2: least inflated overlap area (thesis: 2 m²).
    pub min_overlap_m2: f64,
    /// Eq. 6.4: weight of the overlap in the score (thesis: 0.125, multi-robot experiments).
    pub overlap_weight_per_m2: f64,
    /// Eq. 6.3's right-hand side: the matcher's precision (see [`matcher_precision_m`]).
    pub precision_m: f64,
    pub delta_sigma: DeltaSigma,
}

impl Default for PairingParams {
    /// The thesis's LRU values (f = 1080 px, b = 0.09 m, Δp = 0.5 px, p_z = 4 m: 0.116 m).
    fn default() -> Self {
        PairingParams {
            min_overlap_m2: 2.0,
            overlap_weight_per_m2: 0.125,
            precision_m: matcher_precision_m(1080.0, 0.09, 0.5, 4.0),
            delta_sigma: DeltaSigma::ThesisDifference,
        }
    }
}

/// Eq. 6.3's precision of a match: the stereo depth error at view distance `view_distance_m`
/// (eq. 5.2c) times √2 (two submaps).
pub fn matcher_precision_m(focal_px: f64, baseline_m: f64, disparity_error_px: f64, view_distance_m: f64) -> f64 {
    disparity_error_px * view_distance_m * view_distance_m / (focal_px * baseline_m) * std::f64::consts::SQRT_2
}

/// One finished, suitable submap as the pairing sees it.
#[derive(Debug, Clone, Copy)]
pub struct PlacedSubmap<'a> {
    pub id: SubmapId,
    /// The graph's latest estimate of the origin in the robot's global frame.
    pub t_global_submap: Isometry3<f64>,
    /// The graph's marginal covariance of the origin's translation, in the origin's own frame
    /// (the upper-left block of the graph's 6×6 marginal).
    pub position_covariance_m2: Matrix3<f64>,
    /// Obstacle keypoints in the submap frame.
    pub keypoints: &'a [Point3<f32>],
}

/// Why a pair is not queued.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PairSkip {
    /// One of the two has no keypoints to place.
    Empty,
    /// An inflated overlap in x or y is not positive (a gap wider than 2·Δσ).
    Disjoint,
    /// The inflated area is at most `min_overlap_m2`.
    SmallOverlap,
    /// The relative uncertainty is already below the matcher's precision (eq. 6.3).
    Precise,
}

/// A pair worth trying, with what ranked it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Candidate {
    pub pair: SubmapPair,
    pub score: f64,
    pub overlap_m2: f64,
    /// Δσ_t, t = x, y, z, in the global frame (m).
    pub delta_sigma_m: Vector3<f64>,
}

/// The xy bounding box of a submap's keypoints in the global frame: `[min_x, min_y, max_x, max_y]`.
pub fn xy_bounds(placed: &PlacedSubmap<'_>) -> Option<[f64; 4]> {
    let mut bounds: Option<[f64; 4]> = None;
    for k in placed.keypoints {
        let p = placed.t_global_submap * k.cast::<f64>();
        let b = bounds.get_or_insert([p.x, p.y, p.x, p.y]);
        b[0] = b[0].min(p.x);
        b[1] = b[1].min(p.y);
        b[2] = b[2].max(p.x);
        b[3] = b[3].max(p.y);
    }
    bounds
}

/// The origin's position variances per global axis.
pub fn global_position_variance_m2(placed: &PlacedSubmap<'_>) -> Vector3<f64> {
    let r = placed.t_global_submap.rotation.to_rotation_matrix();
    let global = r.matrix() * placed.position_covariance_m2 * r.matrix().transpose();
    global.diagonal().map(|v| v.max(0.0))
}

/// Δσ_t of two origins (t = x, y, z, global frame).
pub fn delta_sigma_m(variance_a_m2: &Vector3<f64>, variance_b_m2: &Vector3<f64>, mode: DeltaSigma) -> Vector3<f64> {
    variance_a_m2.zip_map(variance_b_m2, |a, b| match mode {
        DeltaSigma::ThesisDifference => (a - b).abs().sqrt(),
        DeltaSigma::Sum => (a + b).sqrt(),
    })
}

/// Δσ ranked in global axes, in the axes of the frame `t_global_frame` (the matcher compares
/// translations in the target submap's frame): the diagonal of the rotated diagonal covariance.
pub fn delta_sigma_in_frame(delta_sigma_global_m: &Vector3<f64>, t_global_frame: &Isometry3<f64>) -> Vector3<f64> {
    let r = t_global_frame.rotation.to_rotation_matrix();
    let sigma2_global = Matrix3::from_diagonal(&delta_sigma_global_m.map(|s| s * s));
    let sigma2_frame = r.matrix().transpose() * sigma2_global * r.matrix();
    sigma2_frame.diagonal().map(|v| v.max(0.0).sqrt())
}

/// The pairing rules for one pair, given both submaps' bounds and global variances.
fn assess(
    pair: SubmapPair,
    bounds: (&[f64; 4], &[f64; 4]),
    variances: (&Vector3<f64>, &Vector3<f64>),
    params: &PairingParams,
) -> Result<Candidate, PairSkip> {
    let (a, b) = bounds;
    let delta_sigma_m = delta_sigma_m(variances.0, variances.1, params.delta_sigma);
    let overlap_1d = |lo_a: f64, hi_a: f64, lo_b: f64, hi_b: f64| hi_a.min(hi_b) - lo_a.max(lo_b);
    let overlap_x = overlap_1d(a[0], a[2], b[0], b[2]) + 2.0 * delta_sigma_m.x;
    let overlap_y = overlap_1d(a[1], a[3], b[1], b[3]) + 2.0 * delta_sigma_m.y;
    if overlap_x <= 0.0 || overlap_y <= 0.0 {
        return Err(PairSkip::Disjoint);
    }
    let overlap_m2 = overlap_x * overlap_y;
    if overlap_m2 <= params.min_overlap_m2 {
        return Err(PairSkip::SmallOverlap);
    }
    if delta_sigma_m.mean() < params.precision_m {
        return Err(PairSkip::Precise);
    }
    let score = params.overlap_weight_per_m2 * overlap_m2 + delta_sigma_m.sum();
    Ok(Candidate { pair, score, overlap_m2, delta_sigma_m })
}

/// Tallies of why pairs were not queued.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SkipCounts {
    pub unplaced: usize,
    pub empty: usize,
    pub disjoint: usize,
    pub small_overlap: usize,
    pub precise: usize,
}

/// Ranks `pairs` (those still open) among the `placed` submaps, best first; ties keep the pairs'
/// order, so every robot ranks alike. Pairs with a submap not in `placed` are skipped as
/// `unplaced` (not suitable, or not connected to the own frame).
pub fn rank(placed: &[PlacedSubmap<'_>], pairs: &[SubmapPair], params: &PairingParams) -> (Vec<Candidate>, SkipCounts) {
    let prepared: Vec<(SubmapId, Option<[f64; 4]>, Vector3<f64>)> =
        placed.iter().map(|p| (p.id, xy_bounds(p), global_position_variance_m2(p))).collect();
    let find = |id: SubmapId| prepared.iter().find(|(pid, _, _)| *pid == id);
    let mut skips = SkipCounts::default();
    let mut queue = Vec::new();
    for &pair in pairs {
        let (Some(a), Some(b)) = (find(pair.first()), find(pair.second())) else {
            skips.unplaced += 1;
            continue;
        };
        let (Some(bounds_a), Some(bounds_b)) = (&a.1, &b.1) else {
            skips.empty += 1;
            continue;
        };
        match assess(pair, (bounds_a, bounds_b), (&a.2, &b.2), params) {
            Ok(candidate) => queue.push(candidate),
            Err(PairSkip::Empty) => skips.empty += 1,
            Err(PairSkip::Disjoint) => skips.disjoint += 1,
            Err(PairSkip::SmallOverlap) => skips.small_overlap += 1,
            Err(PairSkip::Precise) => skips.precise += 1,
        }
    }
    // Stable sort: equal scores keep the ascending pair order.
    queue.sort_by(|x, y| y.score.partial_cmp(&x.score).unwrap_or(Ordering::Equal));
    (queue, skips)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion};

    use super::*;

    fn square(side_m: f32, step_m: f32) -> Vec<Point3<f32>> {
        let n = (side_m / step_m) as i32;
        (0..=n).flat_map(|i| (0..=n).map(move |j| Point3::new(i as f32 * step_m, j as f32 * step_m, 0.0))).collect()
    }

    fn placed(
        id: SubmapId,
        x_m: f64,
        yaw_rad: f64,
        var_m2: Vector3<f64>,
        keypoints: &[Point3<f32>],
    ) -> PlacedSubmap<'_> {
        PlacedSubmap {
            id,
            t_global_submap: Isometry3::from_parts(
                Translation3::new(x_m, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_rad),
            ),
            position_covariance_m2: Matrix3::from_diagonal(&var_m2),
            keypoints,
        }
    }

    #[test]
    fn thesis_precision_is_0_116_m() {
        assert!((matcher_precision_m(1080.0, 0.09, 0.5, 4.0) - 0.1164).abs() < 1e-4);
    }

    #[test]
    fn overlap_delta_sigma_and_score_follow_eqs_6_1_to_6_4() {
        let keys = square(4.0, 0.5);
        let a = SubmapId::new(1, 0);
        let b = SubmapId::new(1, 5);
        // 4 × 4 m squares shifted 3 m in x: overlap 1 m × 4 m; Δσ = sqrt(0.25 − 0.0) = 0.5 m per axis.
        let list = [
            placed(a, 0.0, 0.0, Vector3::new(0.0, 0.0, 0.0), &keys),
            placed(b, 3.0, 0.0, Vector3::new(0.25, 0.25, 0.25), &keys),
        ];
        let (queue, skips) = rank(&list, &[SubmapPair::new(a, b)], &PairingParams::default());
        assert_eq!(skips, SkipCounts::default());
        let c = queue[0];
        assert!((c.delta_sigma_m - Vector3::repeat(0.5)).norm() < 1e-12);
        let overlap = (1.0 + 1.0) * (4.0 + 1.0);
        assert!((c.overlap_m2 - overlap).abs() < 1e-9, "{}", c.overlap_m2);
        assert!((c.score - (0.125 * overlap + 1.5)).abs() < 1e-9);
    }

    #[test]
    fn two_gaps_are_disjoint_not_a_positive_area() {
        let keys = square(2.0, 0.5);
        let a = SubmapId::new(1, 0);
        let b = SubmapId::new(2, 0);
        let mut far = placed(b, 10.0, 0.0, Vector3::new(0.2, 0.2, 0.2), &keys);
        far.t_global_submap.translation.vector.y = 10.0;
        let list = [placed(a, 0.0, 0.0, Vector3::zeros(), &keys), far];
        let (queue, skips) = rank(&list, &[SubmapPair::new(a, b)], &PairingParams::default());
        assert!(queue.is_empty());
        assert_eq!(skips.disjoint, 1);
    }

    #[test]
    fn equal_variances_are_below_precision_and_sum_mode_keeps_them() {
        let keys = square(4.0, 0.5);
        let a = SubmapId::new(1, 0);
        let b = SubmapId::new(2, 3);
        let var = Vector3::new(0.3, 0.3, 0.3);
        let list = [placed(a, 0.0, 0.0, var, &keys), placed(b, 1.0, 0.0, var, &keys)];
        let pairs = [SubmapPair::new(a, b)];
        let (queue, skips) = rank(&list, &pairs, &PairingParams::default());
        assert!(queue.is_empty());
        assert_eq!(skips.precise, 1);
        let sum = PairingParams { delta_sigma: DeltaSigma::Sum, ..PairingParams::default() };
        let (queue, _) = rank(&list, &pairs, &sum);
        assert_eq!(queue.len(), 1);
    }

    #[test]
    fn marginal_translation_is_rotated_into_the_global_frame() {
        let keys = square(1.0, 0.5);
        // Variance only along the origin's own x, origin yawed by 90°: global y.
        let p = placed(SubmapId::new(1, 0), 0.0, std::f64::consts::FRAC_PI_2, Vector3::new(1.0, 0.0, 0.0), &keys);
        let v = global_position_variance_m2(&p);
        assert!(v.x.abs() < 1e-12 && (v.y - 1.0).abs() < 1e-12, "{v:?}");
    }

    #[test]
    fn best_score_first_and_unplaced_counted() {
        let keys = square(4.0, 0.5);
        let ids = [SubmapId::new(1, 0), SubmapId::new(1, 4), SubmapId::new(1, 8), SubmapId::new(2, 0)];
        let list = [
            placed(ids[0], 0.0, 0.0, Vector3::zeros(), &keys),
            placed(ids[1], 0.5, 0.0, Vector3::repeat(0.2), &keys),
            placed(ids[2], 3.0, 0.0, Vector3::repeat(0.6), &keys),
        ];
        let pairs: Vec<SubmapPair> = vec![
            SubmapPair::new(ids[0], ids[1]),
            SubmapPair::new(ids[0], ids[2]),
            SubmapPair::new(ids[1], ids[2]),
            SubmapPair::new(ids[0], ids[3]),
        ];
        let (queue, skips) = rank(&list, &pairs, &PairingParams::default());
        assert_eq!(skips.unplaced, 1);
        assert!(queue.windows(2).all(|w| w[0].score >= w[1].score));
        assert_eq!(queue.len(), 3);
    }
}
