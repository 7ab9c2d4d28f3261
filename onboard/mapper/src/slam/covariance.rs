//! Covariance conventions at the border between the filter and the graph (trap 6).
//!
//! The filter reports a pose `t_local_body` with covariance in `[δt; δθ]`: `δt` in the local
//! frame, `δθ` right-multiplied in the body frame. The graph perturbs on the right,
//! `T·Exp([ρ; φ])`, whose translation part is `R·ρ`: so `ρ = Rᵀ·δt`, `φ = δθ`.

use nalgebra::{Isometry3, Matrix3, Matrix6, SymmetricEigen};

#[cfg(test)]
#[path = "../../../graph/src/numdiff.rs"]
pub(crate) mod numdiff;

/// A filter pose covariance (`[δt local; δθ body]`) in the graph's convention.
pub fn from_filter(t_local_body: &Isometry3<f64>, covariance: &Matrix6<f64>) -> Matrix6<f64> {
    let r_t: Matrix3<f64> = t_local_body.rotation.to_rotation_matrix().matrix().transpose();
    let mut j = Matrix6::identity();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_t);
    symmetric(&(j * covariance * j.transpose()))
}

/// The inverse of [`from_filter`].
pub fn to_filter(t_local_body: &Isometry3<f64>, covariance: &Matrix6<f64>) -> Matrix6<f64> {
    let r: Matrix3<f64> = *t_local_body.rotation.to_rotation_matrix().matrix();
    let mut j = Matrix6::identity();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    symmetric(&(j * covariance * j.transpose()))
}

/// `(C + Cᵀ)/2`.
pub fn symmetric(c: &Matrix6<f64>) -> Matrix6<f64> {
    (c + c.transpose()) * 0.5
}

/// The symmetric matrix nearest to `c` whose eigenvalues are at least `floor`: how eq. 4.9's
/// "max(Σ, I·10⁻¹⁰)" is made a valid covariance (the thesis leaves open whether the max acts
/// element-wise, which need not give a PSD matrix; trap 24).
pub fn clamp_eigenvalues(c: &Matrix6<f64>, floor: f64) -> Matrix6<f64> {
    let eigen = SymmetricEigen::new(symmetric(c));
    let clamped = eigen.eigenvalues.map(|l| if l.is_finite() { l.max(floor) } else { floor });
    symmetric(&(eigen.eigenvectors * Matrix6::from_diagonal(&clamped) * eigen.eigenvectors.transpose()))
}

/// Whether `c` is a usable covariance: finite, symmetric to rounding, positive definite.
pub fn is_valid(c: &Matrix6<f64>) -> bool {
    if !c.iter().all(|v| v.is_finite()) {
        return false;
    }
    let scale = c.amax().max(f64::MIN_POSITIVE);
    if (c - c.transpose()).amax() > 1e-9 * scale {
        return false;
    }
    symmetric(c).cholesky().is_some()
}

/// Whether `c` is finite, symmetric to rounding and positive semi-definite (a filter covariance
/// right after a frame switch is singular in position and yaw).
pub fn is_psd(c: &Matrix6<f64>) -> bool {
    if !c.iter().all(|v| v.is_finite()) {
        return false;
    }
    let scale = c.amax().max(f64::MIN_POSITIVE);
    if (c - c.transpose()).amax() > 1e-9 * scale {
        return false;
    }
    SymmetricEigen::new(symmetric(c)).eigenvalues.min() >= -1e-9 * scale
}

#[cfg(test)]
mod tests {
    //! The conversions are congruences `J·C·Jᵀ` with the Jacobian between the two tangent
    //! conventions; here `J` is taken by central differences ([`super::numdiff`]) of the actual
    //! perturbations, at poses with rotations near 0, generic and near π.
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use nalgebra::{Const, Translation3, UnitQuaternion, Vector3, Vector6};
    use numdiff::{STEP, Tolerance};
    use posegraph::se3;
    use std::f64::consts::PI;

    fn stack(a: &Vector3<f64>, b: &Vector3<f64>) -> Vector6<f64> {
        Vector6::new(a.x, a.y, a.z, b.x, b.y, b.z)
    }

    /// Poses within 100 m, rotation angles near 0, generic and near π, deterministic.
    fn poses() -> Vec<Isometry3<f64>> {
        let mut out = Vec::new();
        for (i, angle) in [0.0, 1e-7, 3e-3, 0.4, 1.7, 3.0, PI - 1e-3, PI - 1e-4].into_iter().enumerate() {
            let s = i as f64;
            let axis = Vector3::new((1.3 * s).sin(), (0.7 * s).cos(), 0.4).normalize();
            let t = Vector3::new(100.0 * (0.9 * s).sin(), -40.0 + 11.0 * s, 3.0 * (2.1 * s).cos());
            out.push(Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(axis * angle)));
        }
        out
    }

    /// A full-rank covariance with correlations between every pair of axes.
    fn covariance(seed: usize) -> Matrix6<f64> {
        let b = Matrix6::from_fn(|i, j| ((i * 7 + j * 3 + seed) as f64 * 0.91).sin());
        let c = b * b.transpose() * 0.01 + Matrix6::identity() * 1e-4;
        (c + c.transpose()) * 0.5
    }

    fn check(name: &str, converted: &Matrix6<f64>, j: &Matrix6<f64>, c: &Matrix6<f64>) -> numdiff::Comparison {
        let expected = j * c * j.transpose();
        // Entries of J·C·Jᵀ err by |ΔJ|·|C|·|J| twice over; J's entries are ≤ 1.
        let t = Tolerance::central(STEP, 100.0);
        let comparison = numdiff::compare(converted, &expected, Tolerance { abs: 2.0 * t.abs * c.amax(), rel: t.rel });
        assert!(comparison.passes(), "{name}: {comparison:?}");
        comparison
    }

    #[test]
    fn from_filter_is_the_tangent_jacobian() {
        let mut worst = numdiff::Comparison::none();
        for (k, t) in poses().iter().enumerate() {
            // The filter's perturbation (δt in the local frame, δθ on the right) read as the
            // graph's `Log(T⁻¹·T')` through the chart `[t; Log R]` of the small difference.
            let j = numdiff::jacobian(Const::<6>, STEP, |d: &Vector6<f64>| {
                let perturbed = Isometry3::from_parts(
                    Translation3::from(t.translation.vector + d.fixed_rows::<3>(0)),
                    numdiff::right_plus(&t.rotation, &d.fixed_rows::<3>(3).into_owned()),
                );
                let diff = t.inverse() * perturbed;
                stack(&diff.translation.vector, &numdiff::rotation_log(&diff.rotation))
            });
            let c = covariance(k);
            worst = worst.worse(check("from_filter", &from_filter(t, &c), &j, &c));
        }
        println!(
            "covariance::from_filter: worst |error| {:.1e}, worst error/tolerance {:.1e}",
            worst.max_abs_error, worst.worst_ratio
        );
    }

    #[test]
    fn to_filter_is_the_tangent_jacobian() {
        let mut worst = numdiff::Comparison::none();
        for (k, t) in poses().iter().enumerate() {
            // The graph's retraction `T·Exp(ξ)` read as the filter's `[δt; δθ]`.
            let j = numdiff::jacobian(Const::<6>, STEP, |xi: &Vector6<f64>| {
                let perturbed = se3::retract(t, xi);
                stack(
                    &(perturbed.translation.vector - t.translation.vector),
                    &numdiff::right_minus(&perturbed.rotation, &t.rotation),
                )
            });
            let c = covariance(k + 3);
            worst = worst.worse(check("to_filter", &to_filter(t, &c), &j, &c));
        }
        println!(
            "covariance::to_filter: worst |error| {:.1e}, worst error/tolerance {:.1e}",
            worst.max_abs_error, worst.worst_ratio
        );
    }
}
