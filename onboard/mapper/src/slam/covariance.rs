//! Covariance conventions at the border between the filter and the graph (trap 6).
//!
//! The filter reports a pose `t_local_body` with covariance in `[δt; δθ]`: `δt` in the local
//! frame, `δθ` right-multiplied in the body frame. The graph perturbs on the right,
//! `T·Exp([ρ; φ])`, whose translation part is `R·ρ`: so `ρ = Rᵀ·δt`, `φ = δθ`.

use nalgebra::{Isometry3, Matrix3, Matrix6, SymmetricEigen};

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
