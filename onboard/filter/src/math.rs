//! Small rotation helpers for the global (left) attitude error `R_true = Exp(δθ)·R̂`.

use nalgebra::{Matrix3, RowVector3, UnitQuaternion, Vector3};

/// `[v]×`, the cross-product matrix.
pub fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// Roll, pitch and yaw (`R = Rz(yaw)·Ry(pitch)·Rx(roll)`).
pub fn roll_pitch_yaw(q: &UnitQuaternion<f64>) -> (f64, f64, f64) {
    q.euler_angles()
}

/// Rotation about the local z axis.
pub fn yaw_rotation(yaw_rad: f64) -> UnitQuaternion<f64> {
    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad)
}

/// Derivative of the yaw angle with respect to a global attitude error:
/// `δψ = δθ_z + tan(pitch)·(cos(yaw)·δθ_x + sin(yaw)·δθ_y)`.
///
/// (From `ω_world = ψ̇·e_z + θ̇·Rz·e_y + φ̇·Rz·Ry·e_x` solved for `ψ̇`.) Singular at ±90° pitch,
/// which a ground rover does not reach.
pub fn yaw_jacobian(q: &UnitQuaternion<f64>) -> RowVector3<f64> {
    let (_, pitch, yaw) = roll_pitch_yaw(q);
    let t = pitch.tan();
    RowVector3::new(t * yaw.cos(), t * yaw.sin(), 1.0)
}

/// Maps small Euler-angle errors `[δroll, δpitch, δyaw]` to the global attitude error:
/// `δθ = [Rz·Ry·e_x, Rz·e_y, e_z]·δeuler`.
pub fn euler_to_global_error(q: &UnitQuaternion<f64>) -> Matrix3<f64> {
    let (_, pitch, yaw) = roll_pitch_yaw(q);
    let (sp, cp) = pitch.sin_cos();
    let (sy, cy) = yaw.sin_cos();
    Matrix3::new(cy * cp, -sy, 0.0, sy * cp, cy, 0.0, -sp, 0.0, 1.0)
}

/// Below this angle (rad) [`left_jacobian`] uses its Taylor series: the closed form cancels.
const SMALL_ANGLE_RAD: f64 = 1e-2;

/// Left Jacobian of SO(3), `Exp(φ + δ) ≈ Exp(J_l(φ)·δ)·Exp(φ)`:
/// `I + (1 − cos θ)/θ²·[φ]× + (θ − sin θ)/θ³·[φ]×²`.
pub fn left_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let (a, b) = if theta < SMALL_ANGLE_RAD {
        (0.5 - theta2 / 24.0 + theta2 * theta2 / 720.0, 1.0 / 6.0 - theta2 / 120.0 + theta2 * theta2 / 5040.0)
    } else {
        ((1.0 - theta.cos()) / theta2, (theta - theta.sin()) / (theta2 * theta))
    };
    let w = skew(phi);
    Matrix3::identity() + w * a + w * w * b
}

/// `Log(q)` as a rotation vector.
pub fn log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    q.scaled_axis()
}

/// `Exp(v)`.
pub fn exp(v: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_scaled_axis(*v)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn yaw_jacobian_matches_finite_differences() {
        let q = UnitQuaternion::from_euler_angles(0.2, -0.3, 2.5);
        let j = yaw_jacobian(&q);
        let m = euler_to_global_error(&q);
        for axis in 0..3 {
            let mut d = Vector3::zeros();
            d[axis] = 1e-7;
            let (_, _, y1) = (exp(&d) * q).euler_angles();
            let (_, _, y0) = q.euler_angles();
            let numeric = (y1 - y0) / 1e-7;
            assert!((numeric - j[axis]).abs() < 1e-5, "axis {axis}: {numeric} vs {}", j[axis]);
        }
        // The yaw row of the inverse of the Euler map is the yaw Jacobian.
        let inv = m.try_inverse().unwrap();
        assert!((inv.row(2) - j).norm() < 1e-12);
    }
}
