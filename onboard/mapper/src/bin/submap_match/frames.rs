//! The `--up` alignment: input frames ↔ the z-up frames the matcher works in.
//!
//! Both clouds are rotated by the same `r_aligned_input`, so a transform found between the
//! aligned clouds, `t'`, is `t = r⁻¹ · t' · r` between the inputs. The covariance is the right
//! perturbation tangent in the source frame; rotating that frame by `r` rotates both its
//! translation and rotation parts: `Σ = J Σ' Jᵀ` with `J = diag(rᵀ, rᵀ)`.

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use mapper::MapPoint;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct UpAlignment {
    r_aligned_input: UnitQuaternion<f64>,
}

impl UpAlignment {
    /// The smallest rotation taking the unit vector `up` (input frame) to +z.
    pub fn new(up: &Vector3<f64>) -> UpAlignment {
        let r_aligned_input = UnitQuaternion::rotation_between(up, &Vector3::z())
            // Only `up` = −z has no unique smallest rotation; any half turn about x will do.
            .unwrap_or_else(|| UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI));
        UpAlignment { r_aligned_input }
    }

    pub fn is_identity(&self) -> bool {
        self.r_aligned_input.angle() < 1e-12
    }

    /// Rotates a cloud's points into the aligned frame.
    pub fn align_points(&self, points: &mut [MapPoint]) {
        if self.is_identity() {
            return;
        }
        let r: Matrix3<f32> = self.r_aligned_input.to_rotation_matrix().into_inner().cast();
        for p in points {
            p.position_m = Point3::from(r * p.position_m.coords);
        }
    }

    /// A transform between the inputs expressed between the aligned clouds.
    pub fn aligned_from_input(&self, t_input: &Isometry3<f64>) -> Isometry3<f64> {
        let r = Isometry3::from_parts(Translation3::identity(), self.r_aligned_input);
        r * t_input * r.inverse()
    }

    /// A transform between the aligned clouds expressed between the inputs.
    pub fn input_from_aligned(&self, t_aligned: &Isometry3<f64>) -> Isometry3<f64> {
        let r = Isometry3::from_parts(Translation3::identity(), self.r_aligned_input);
        r.inverse() * t_aligned * r
    }

    /// The covariance of [`UpAlignment::input_from_aligned`]'s result.
    pub fn covariance_to_input(&self, covariance_aligned: &Matrix6<f64>) -> Matrix6<f64> {
        let rt = self.r_aligned_input.to_rotation_matrix().into_inner().transpose();
        let mut j = Matrix6::zeros();
        j.fixed_view_mut::<3, 3>(0, 0).copy_from(&rt);
        j.fixed_view_mut::<3, 3>(3, 3).copy_from(&rt);
        j * covariance_aligned * j.transpose()
    }

    /// A yaw about the up direction as a rotation of the input frame.
    pub fn yaw_about_up(&self, yaw_rad: f64) -> Rotation3<f64> {
        let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw_rad);
        let r = self.r_aligned_input.to_rotation_matrix();
        r.inverse() * yaw * r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn aligned_and_input_transforms_round_trip_and_yaw_becomes_yaw_about_z() {
        for up in [Vector3::z(), Vector3::y(), -Vector3::z(), Vector3::new(0.3, -0.2, 0.9).normalize()] {
            let a = UpAlignment::new(&up);
            let r = a.r_aligned_input;
            assert!((r * up - Vector3::z()).norm() < 1e-12, "{up:?}");
            let t = Isometry3::new(Vector3::new(0.5, -1.0, 2.0), up * 0.7);
            assert!(
                (a.input_from_aligned(&a.aligned_from_input(&t)).to_homogeneous() - t.to_homogeneous()).abs().max()
                    < 1e-12
            );
            // A rotation about `up` in the input is a pure yaw once aligned.
            let aligned = a.aligned_from_input(&t);
            let (roll, pitch, yaw) = aligned.rotation.euler_angles();
            assert!(roll.abs() < 1e-9 && pitch.abs() < 1e-9 && (yaw - 0.7).abs() < 1e-9, "{up:?}");
            let back = a.yaw_about_up(0.7);
            assert!((back.matrix() - t.rotation.to_rotation_matrix().matrix()).abs().max() < 1e-12);
        }
    }

    #[test]
    fn covariance_follows_the_frame() {
        let a = UpAlignment::new(&Vector3::y());
        // x-translation variance in the aligned frame is x in the input too (the y→z rotation
        // about x keeps x), while the aligned z (up) becomes the input's y.
        let aligned = Matrix6::from_diagonal(&nalgebra::Vector6::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0));
        let input = a.covariance_to_input(&aligned);
        assert!((input[(0, 0)] - 1.0).abs() < 1e-12);
        assert!((input[(1, 1)] - 3.0).abs() < 1e-12 && (input[(2, 2)] - 2.0).abs() < 1e-12);
        assert!((input[(4, 4)] - 6.0).abs() < 1e-12 && (input[(5, 5)] - 5.0).abs() < 1e-12);
    }
}
