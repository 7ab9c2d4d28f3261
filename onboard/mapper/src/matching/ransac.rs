//! RANSAC per Hough cluster (§6.1.2 c): a 2-point gravity-constrained sample in 4D mode
//! (eqs. 6.5–6.7), a 3-point SVD (Kabsch) sample in 6D mode; the best sample's inliers are then
//! refitted by least squares in the same model and recounted.
//!
//! Eq. 6.5 (trap T2). `R_i = (Δp'_i, Δp'_i × z, z)ᵀ` turns the horizontal direction of the
//! sample's two points in cloud i onto a common axis; `R = R_0·R_1ᵀ` is then the rotation about z
//! by the difference of the two directions' headings. The equation's rows are neither
//! normalised nor, read literally, a proper rotation (det −1), so the heading difference is
//! computed directly: `yaw = atan2(Δp'_0) − atan2(Δp'_1)`, which is the same rotation. A sample
//! whose horizontal separation is below [`MIN_HORIZONTAL_M`] in either cloud (points stacked
//! vertically) has no heading and is skipped.

use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, SVD, Translation3, UnitQuaternion, Vector3};

use super::params::{MatchMode, MatcherParams};
use super::rng::SplitMix64;

/// Horizontal separation below which a 2-point sample gives no usable heading (half a
/// keypoint voxel: keypoint noise alone would swing the heading by tens of degrees).
pub(crate) const MIN_HORIZONTAL_M: f64 = 0.05;

/// The rigid transform `x_0 = R·x_1 + t` (eq. 6.7) from two point pairs `(p_0, p_1)`,
/// `(q_0, q_1)`, with R a rotation about z (eqs. 6.5, 6.6). None for a vertical sample.
pub(crate) fn yaw_from_two_points(
    p0: &Point3<f64>,
    q0: &Point3<f64>,
    p1: &Point3<f64>,
    q1: &Point3<f64>,
) -> Option<Isometry3<f64>> {
    let d0 = q0 - p0;
    let d1 = q1 - p1;
    let (h0, h1) = (d0.xy().norm(), d1.xy().norm());
    if !(h0 >= MIN_HORIZONTAL_M) || !(h1 >= MIN_HORIZONTAL_M) {
        return None;
    }
    let yaw = d0.y.atan2(d0.x) - d1.y.atan2(d1.x);
    let rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
    let mean0 = p0.coords.lerp(&q0.coords, 0.5);
    let mean1 = p1.coords.lerp(&q1.coords, 0.5);
    let t = mean0 - rotation * mean1;
    Some(Isometry3::from_parts(Translation3::from(t), rotation))
}

/// Least-squares yaw and translation mapping `from` onto `to` (2-D Procrustes on the
/// horizontal components, translation from the centroids).
pub(crate) fn fit_yaw(from: &[Point3<f64>], to: &[Point3<f64>]) -> Option<Isometry3<f64>> {
    if from.len() < 2 || from.len() != to.len() {
        return None;
    }
    let n = from.len() as f64;
    let cf = from.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let ct = to.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let (mut sin_sum, mut cos_sum) = (0.0, 0.0);
    for (f, t) in from.iter().zip(to) {
        let a = f.coords - cf;
        let b = t.coords - ct;
        sin_sum += a.x * b.y - a.y * b.x;
        cos_sum += a.x * b.x + a.y * b.y;
    }
    if !(sin_sum.abs() + cos_sum.abs() > 1e-12) {
        return None;
    }
    let rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), sin_sum.atan2(cos_sum));
    Some(Isometry3::from_parts(Translation3::from(ct - rotation * cf), rotation))
}

/// Least-squares rigid transform mapping `from` onto `to` (Kabsch/Umeyama without scale).
pub(crate) fn fit_rigid(from: &[Point3<f64>], to: &[Point3<f64>]) -> Option<Isometry3<f64>> {
    if from.len() < 3 || from.len() != to.len() {
        return None;
    }
    let n = from.len() as f64;
    let cf = from.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let ct = to.iter().fold(Vector3::zeros(), |a, p| a + p.coords) / n;
    let mut h = Matrix3::zeros();
    for (f, t) in from.iter().zip(to) {
        h += (t.coords - ct) * (f.coords - cf).transpose();
    }
    let svd = SVD::new(h, true, true);
    let (u, v_t) = (svd.u?, svd.v_t?);
    // A rank-1 cross-covariance (collinear points) leaves the rotation about the line free.
    let mut s = svd.singular_values;
    s.as_mut_slice().sort_by(|a, b| b.total_cmp(a));
    if !(s[1] > 1e-9 * s[0].max(1e-12)) {
        return None;
    }
    let mut d = Matrix3::identity();
    if (u * v_t).determinant() < 0.0 {
        d[(2, 2)] = -1.0;
    }
    let r = Rotation3::from_matrix_unchecked(u * d * v_t);
    let rotation = UnitQuaternion::from_rotation_matrix(&r);
    if !rotation.coords.iter().all(|v| v.is_finite()) {
        return None;
    }
    Some(Isometry3::from_parts(Translation3::from(ct - rotation * cf), rotation))
}

/// The RANSAC model of one cluster.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Model {
    /// Maps the `from` points onto the `to` points.
    pub transform: Isometry3<f64>,
    /// Indices (into the cluster's pairs) of the supporting pairs.
    pub inliers: Vec<usize>,
}

fn inliers_of(transform: &Isometry3<f64>, from: &[Point3<f64>], to: &[Point3<f64>], threshold_m: f64) -> Vec<usize> {
    let t2 = threshold_m * threshold_m;
    (0..from.len()).filter(|&i| (transform * from[i] - to[i]).norm_squared() < t2).collect()
}

/// RANSAC over the pairs `(from[i], to[i])`. Draws `ransac_iterations` samples, or enumerates
/// all 2-point samples when there are fewer.
pub(crate) fn ransac(from: &[Point3<f64>], to: &[Point3<f64>], params: &MatcherParams, seed: u64) -> Option<Model> {
    let n = from.len();
    let sample_size = match params.mode {
        MatchMode::FourDof => 2,
        MatchMode::SixDof => 3,
    };
    if n < sample_size || n != to.len() {
        return None;
    }
    let mut rng = SplitMix64::new(seed);
    let mut best: Option<Model> = None;
    let consider = |transform: Isometry3<f64>, best: &mut Option<Model>| {
        let inliers = inliers_of(&transform, from, to, params.ransac_inlier_m);
        if best.as_ref().is_none_or(|b| inliers.len() > b.inliers.len()) {
            *best = Some(Model { transform, inliers });
        }
    };
    match params.mode {
        MatchMode::FourDof => {
            let pairs = n * (n - 1) / 2;
            if pairs <= params.ransac_iterations {
                for a in 0..n {
                    for b in a + 1..n {
                        if let Some(t) = yaw_from_two_points(&to[a], &to[b], &from[a], &from[b]) {
                            consider(t, &mut best);
                        }
                    }
                }
            } else {
                for _ in 0..params.ransac_iterations {
                    let (a, b) = (rng.below(n), rng.below(n));
                    if a == b {
                        continue;
                    }
                    if let Some(t) = yaw_from_two_points(&to[a], &to[b], &from[a], &from[b]) {
                        consider(t, &mut best);
                    }
                }
            }
        }
        MatchMode::SixDof => {
            for _ in 0..params.ransac_iterations {
                let idx = [rng.below(n), rng.below(n), rng.below(n)];
                if idx[0] == idx[1] || idx[1] == idx[2] || idx[0] == idx[2] {
                    continue;
                }
                let f: Vec<Point3<f64>> = idx.iter().map(|&i| from[i]).collect();
                let t: Vec<Point3<f64>> = idx.iter().map(|&i| to[i]).collect();
                if let Some(tr) = fit_rigid(&f, &t) {
                    consider(tr, &mut best);
                }
            }
        }
    }
    let mut best = best?;
    // Refit on the consensus set and keep the refit only if it does not lose support.
    let f: Vec<Point3<f64>> = best.inliers.iter().map(|&i| from[i]).collect();
    let t: Vec<Point3<f64>> = best.inliers.iter().map(|&i| to[i]).collect();
    let refit = match params.mode {
        MatchMode::FourDof => fit_yaw(&f, &t),
        MatchMode::SixDof => fit_rigid(&f, &t),
    };
    if let Some(refit) = refit {
        let inliers = inliers_of(&refit, from, to, params.ransac_inlier_m);
        if inliers.len() >= best.inliers.len() {
            best = Model { transform: refit, inliers };
        }
    }
    Some(best)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    fn truth() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(1.5, -2.0, 0.3),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.7),
        )
    }

    #[test]
    fn eq_6_5_to_6_7_recover_a_known_yaw() {
        let t = truth();
        let (p1, q1) = (Point3::new(0.3, 0.1, 0.2), Point3::new(-1.0, 2.0, 0.9));
        let (p0, q0) = (t * p1, t * q1);
        let est = yaw_from_two_points(&p0, &q0, &p1, &q1).unwrap();
        assert!((est.rotation.angle_to(&t.rotation)).abs() < 1e-12);
        assert!((est.translation.vector - t.translation.vector).norm() < 1e-12);
        let (_, _, yaw) = est.rotation.euler_angles();
        assert!((yaw - 0.7).abs() < 1e-12);
        // Also across ±π: headings 170° and −170° differ by −340° ≡ 20°.
        let t2 = Isometry3::from_parts(
            Translation3::new(0.0, 0.0, 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 20f64.to_radians()),
        );
        let a1 = Point3::origin();
        let b1 = Point3::new(170f64.to_radians().cos(), 170f64.to_radians().sin(), 0.0);
        let est2 = yaw_from_two_points(&(t2 * a1), &(t2 * b1), &a1, &b1).unwrap();
        assert!(est2.rotation.angle_to(&t2.rotation) < 1e-12);
    }

    #[test]
    fn vertical_samples_are_rejected() {
        let (p, q) = (Point3::new(1.0, 1.0, 0.0), Point3::new(1.0, 1.01, 1.0));
        assert!(yaw_from_two_points(&p, &q, &p, &q).is_none());
    }

    #[test]
    fn ransac_finds_the_model_among_outliers_in_both_modes() {
        let t = truth();
        let mut rng = SplitMix64::new(9);
        let mut u = || rng.below(10_000) as f64 / 10_000.0;
        let mut from = Vec::new();
        let mut to = Vec::new();
        for i in 0..60 {
            let p = Point3::new(u() * 6.0, u() * 6.0, u() * 0.8);
            from.push(p);
            to.push(if i % 3 == 0 {
                Point3::new(u() * 8.0, u() * 8.0, u())
            } else {
                t * p + Vector3::new(u() - 0.5, u() - 0.5, u() - 0.5) * 0.05
            });
        }
        for mode in [MatchMode::FourDof, MatchMode::SixDof] {
            let params = MatcherParams::with_mode(mode);
            let model = ransac(&from, &to, &params, 1).unwrap();
            assert!(model.inliers.len() >= 40, "{mode:?}: {} inliers", model.inliers.len());
            assert!((model.transform.translation.vector - t.translation.vector).norm() < 0.05, "{mode:?}");
            assert!(model.transform.rotation.angle_to(&t.rotation) < 0.02, "{mode:?}");
        }
    }
}
