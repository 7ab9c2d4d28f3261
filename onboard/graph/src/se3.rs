//! SE(3) on the manifold: exponential and logarithm maps, adjoint, right Jacobians.
//!
//! Tangent vectors are `ξ = [ρ, φ]` (translation part first, then rotation), the project's
//! covariance order. `exp` and `log` are the true group maps (the translation of `exp(ξ)` is
//! `J_l(φ)·ρ`, not `ρ`), which is what GTSAM's `Pose3::Expmap`/`Logmap` compute, so errors and
//! costs agree with GTSAM's numbers after swapping the two 3-blocks.

use nalgebra::{Isometry3, Matrix3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

/// A rigid-body pose; see the crate docs for the frame convention.
pub type Pose3 = Isometry3<f64>;

/// Below this rotation angle (rad) the Jacobian coefficients use their Taylor series: the closed
/// forms cancel catastrophically (the 1/θ⁵ term loses all digits near 1e-3).
const SMALL_ANGLE_RAD: f64 = 1e-2;

/// The cross-product matrix `[v]×`.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Rotation vector → rotation.
pub fn so3_exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_scaled_axis(*phi)
}

/// Rotation → rotation vector with angle in [0, π].
pub fn so3_log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    // nalgebra picks the shortest arc, so the angle never exceeds π.
    q.scaled_axis()
}

/// Left Jacobian of SO(3): `J_l(φ) = I + (1−cos θ)/θ² [φ]× + (θ−sin θ)/θ³ [φ]×²`.
pub fn so3_left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let (a, b) = if theta < SMALL_ANGLE_RAD {
        (0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0, 1.0 / 6.0 - theta2 / 120.0 + theta2 * theta2 / 5040.0)
    } else {
        ((1.0 - theta.cos()) / theta2, (theta - theta.sin()) / (theta2 * theta))
    };
    let w = hat(phi);
    Matrix3::identity() + w * a + w * w * b
}

/// Inverse of the left Jacobian of SO(3): `I − ½[φ]× + (1/θ² − (1+cos θ)/(2θ sin θ)) [φ]×²`.
pub fn so3_left_jacobian_inv(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let c = if theta < SMALL_ANGLE_RAD {
        1.0 / 12.0 + theta2 / 720.0 + theta2 * theta2 / 30240.0
    } else {
        // (1+cos θ)/sin θ as cot(θ/2), as GTSAM does: near π, 1 + cos θ cancels to ~(π−θ)²/2 and
        // the quotient carried an absolute error of ε/(π−θ), which numdiff saw in `log`'s ρ.
        1.0 / theta2 - 1.0 / (2.0 * theta * (0.5 * theta).tan())
    };
    let w = hat(phi);
    Matrix3::identity() - w * 0.5 + w * w * c
}

/// The coupling block `Q(ρ, φ)` of the SE(3) left Jacobian (Barfoot, State Estimation, eq. 7.86).
fn se3_q(rho: &Vector3<f64>, phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let (c1, c2, c3) = if theta < SMALL_ANGLE_RAD {
        (1.0 / 6.0 - theta2 / 120.0, 1.0 / 24.0 - theta2 / 720.0, 1.0 / 120.0 - theta2 / 2520.0)
    } else {
        let (s, c) = theta.sin_cos();
        let theta4 = theta2 * theta2;
        (
            (theta - s) / (theta2 * theta),
            (theta2 + 2.0 * c - 2.0) / (2.0 * theta4),
            (2.0 * theta - 3.0 * s + theta * c) / (2.0 * theta4 * theta),
        )
    };
    let p = hat(phi);
    let r = hat(rho);
    let pr = p * r;
    let rp = r * p;
    let prp = pr * p;
    r * 0.5 + (pr + rp + prp) * c1 + (p * pr + rp * p - prp * 3.0) * c2 + (prp * p + p * prp) * c3
}

/// Tangent vector → pose: `exp([ρ, φ]) = (Exp(φ), J_l(φ)·ρ)`.
pub fn exp(xi: &Vector6<f64>) -> Pose3 {
    let rho = xi.fixed_rows::<3>(0).into_owned();
    let phi = xi.fixed_rows::<3>(3).into_owned();
    Isometry3::from_parts(Translation3::from(so3_left_jacobian(&phi) * rho), so3_exp(&phi))
}

/// Pose → tangent vector, the inverse of [`exp`] for rotation angles below π.
pub fn log(pose: &Pose3) -> Vector6<f64> {
    let phi = so3_log(&pose.rotation);
    let rho = so3_left_jacobian_inv(&phi) * pose.translation.vector;
    let mut xi = Vector6::zeros();
    xi.fixed_rows_mut::<3>(0).copy_from(&rho);
    xi.fixed_rows_mut::<3>(3).copy_from(&phi);
    xi
}

/// Right retraction `x ⊕ δ = x · exp(δ)`, the one GTSAM's `Pose3::retract` uses.
pub fn retract(pose: &Pose3, delta: &Vector6<f64>) -> Pose3 {
    let mut out = pose * exp(delta);
    out.rotation.renormalize();
    out
}

/// `local(a, b) = log(a⁻¹ · b)`, the inverse of [`retract`].
pub fn local(a: &Pose3, b: &Pose3) -> Vector6<f64> {
    log(&(a.inverse() * b))
}

/// Adjoint for `[ρ, φ]` tangents: `T · exp(ξ) · T⁻¹ = exp(Ad(T) ξ)`, `Ad = [[R, [t]×R], [0, R]]`.
pub fn adjoint(pose: &Pose3) -> Matrix6<f64> {
    let r = pose.rotation.to_rotation_matrix().into_inner();
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3).copy_from(&(hat(&pose.translation.vector) * r));
    ad
}

/// Left Jacobian of SE(3): `exp(ξ + δ) ≈ exp(J_l(ξ) δ) · exp(ξ)`.
pub fn left_jacobian(xi: &Vector6<f64>) -> Matrix6<f64> {
    let rho = xi.fixed_rows::<3>(0).into_owned();
    let phi = xi.fixed_rows::<3>(3).into_owned();
    let j = so3_left_jacobian(&phi);
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&j);
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&j);
    out.fixed_view_mut::<3, 3>(0, 3).copy_from(&se3_q(&rho, &phi));
    out
}

/// Inverse of the left Jacobian of SE(3): `[[J⁻¹, −J⁻¹ Q J⁻¹], [0, J⁻¹]]`.
pub fn left_jacobian_inv(xi: &Vector6<f64>) -> Matrix6<f64> {
    let rho = xi.fixed_rows::<3>(0).into_owned();
    let phi = xi.fixed_rows::<3>(3).into_owned();
    let j_inv = so3_left_jacobian_inv(&phi);
    let mut out = Matrix6::zeros();
    out.fixed_view_mut::<3, 3>(0, 0).copy_from(&j_inv);
    out.fixed_view_mut::<3, 3>(3, 3).copy_from(&j_inv);
    out.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-j_inv * se3_q(&rho, &phi) * j_inv));
    out
}

/// Right Jacobian of SE(3): `exp(ξ + δ) ≈ exp(ξ) · exp(J_r(ξ) δ)`; `J_r(ξ) = J_l(−ξ)`.
pub fn right_jacobian(xi: &Vector6<f64>) -> Matrix6<f64> {
    left_jacobian(&-xi)
}

/// Inverse right Jacobian: `log(exp(ξ) · exp(δ)) ≈ ξ + J_r⁻¹(ξ) δ`.
pub fn right_jacobian_inv(xi: &Vector6<f64>) -> Matrix6<f64> {
    left_jacobian_inv(&-xi)
}
