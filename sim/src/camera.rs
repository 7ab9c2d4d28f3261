//! The stereo camera model and the pan-tilt head that points it.
//!
//! The simulator renders the canonical *rectified* pair, as the FPGA receives it: two identical
//! pinholes, no distortion, the right camera `baseline_m` to the right (`+x` of the left camera's
//! optical frame). Optical frame: x right, y down, z forward; pixel `(u, v)` has its centre at
//! integer coordinates, `u = fx · x / z + cx`.
//!
//! The pan-tilt head's kinematics ([`PanTiltHead`], positive tilt looks down) live in
//! `hal::sensor`, so every consumer of a calibration can turn a frame's pan and tilt into the
//! camera's pose in the body frame.

use hal::sensor::{CameraCalibration, Distortion, Pinhole, StereoCalibration};
pub use hal::sensor::{PanTiltHead, r_flu_optical};
use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Width × height the rover's FPGA matches (thesis §7.1).
pub const FULL_WIDTH_PX: u32 = 1024;
pub const FULL_HEIGHT_PX: u32 = 508;
/// Stereo baseline of every robot in the thesis (§7.1).
pub const BASELINE_M: f64 = 0.09;
/// Horizontal fields of view of the narrow and the wide-angle set-ups (thesis §7.1).
pub const NARROW_HFOV_DEG: f64 = 50.6;
pub const WIDE_HFOV_DEG: f64 = 112.8;

/// A rectified stereo pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoCamera {
    pub width_px: u32,
    pub height_px: u32,
    /// Focal length (square pixels).
    pub f_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    pub baseline_m: f64,
}

impl StereoCamera {
    /// A pair with the given image size and horizontal field of view, principal point centred.
    pub fn with_hfov(width_px: u32, height_px: u32, hfov_deg: f64, baseline_m: f64) -> Self {
        let f_px = 0.5 * f64::from(width_px) / (0.5 * hfov_deg.to_radians()).tan();
        StereoCamera {
            width_px,
            height_px,
            f_px,
            cx_px: 0.5 * (f64::from(width_px) - 1.0),
            cy_px: 0.5 * (f64::from(height_px) - 1.0),
            baseline_m,
        }
    }

    /// The rovers' narrow set-up: 1024×508, HFOV 50.6° (f ≈ 1080 px), baseline 9 cm.
    pub fn narrow() -> Self {
        Self::with_hfov(FULL_WIDTH_PX, FULL_HEIGHT_PX, NARROW_HFOV_DEG, BASELINE_M)
    }

    /// The wide-angle set-up: 1024×508, HFOV 112.8° (f ≈ 340 px), baseline 9 cm.
    pub fn wide() -> Self {
        Self::with_hfov(FULL_WIDTH_PX, FULL_HEIGHT_PX, WIDE_HFOV_DEG, BASELINE_M)
    }

    /// The same field of view at `1 / factor` of the resolution (the low-resolution test mode).
    /// Pixel centres map as in an image pyramid: `u' = (u + 0.5) / factor - 0.5`.
    pub fn downscaled(&self, factor: u32) -> Self {
        let k = f64::from(factor.max(1));
        StereoCamera {
            width_px: (self.width_px / factor.max(1)).max(1),
            height_px: (self.height_px / factor.max(1)).max(1),
            f_px: self.f_px / k,
            cx_px: (self.cx_px + 0.5) / k - 0.5,
            cy_px: (self.cy_px + 0.5) / k - 0.5,
            baseline_m: self.baseline_m,
        }
    }

    pub fn hfov_rad(&self) -> f64 {
        2.0 * (0.5 * f64::from(self.width_px) / self.f_px).atan()
    }

    pub fn pixels(&self) -> usize {
        self.width_px as usize * self.height_px as usize
    }

    /// Pixel of a point in the left camera frame, `None` behind the camera.
    pub fn project(&self, p_cam: &Vector3<f64>) -> Option<(f64, f64)> {
        (p_cam.z > 1e-9)
            .then(|| (self.f_px * p_cam.x / p_cam.z + self.cx_px, self.f_px * p_cam.y / p_cam.z + self.cy_px))
    }

    /// Direction through pixel `(u, v)` in the camera frame, scaled to `z = 1`.
    pub fn ray(&self, u: f64, v: f64) -> Vector3<f64> {
        Vector3::new((u - self.cx_px) / self.f_px, (v - self.cy_px) / self.f_px, 1.0)
    }

    /// Disparity in pixels of a point at depth `z_m`.
    pub fn disparity_px(&self, z_m: f64) -> f64 {
        self.f_px * self.baseline_m / z_m
    }

    /// Pose of the right camera in the left camera's frame.
    pub fn t_left_right(&self) -> Isometry3<f64> {
        Isometry3::translation(self.baseline_m, 0.0, 0.0)
    }

    /// The calibration `hal` hands to consumers: `t_body_cam` is the left camera at pan = tilt = 0
    /// (or the fixed mounting when `head` is `None`).
    pub fn calibration(&self, t_body_cam: &Isometry3<f64>, head: Option<PanTiltHead>) -> StereoCalibration {
        let intrinsics = Pinhole { fx_px: self.f_px, fy_px: self.f_px, cx_px: self.cx_px, cy_px: self.cy_px };
        let left = CameraCalibration {
            width_px: self.width_px,
            height_px: self.height_px,
            intrinsics,
            distortion: Distortion::None,
            t_body_cam: *t_body_cam,
        };
        let right = CameraCalibration { t_body_cam: t_body_cam * self.t_left_right(), ..left };
        StereoCalibration { left, right, rectified: true, baseline_m: self.baseline_m, head }
    }
}

/// Pose of a camera's optical frame at `position_world_m`, heading `yaw_rad` (from +x towards +y)
/// and tilted down by `tilt_rad` (the pan-tilt head's convention), with no roll.
pub fn t_world_cam_looking(position_world_m: &Vector3<f64>, yaw_rad: f64, tilt_rad: f64) -> Isometry3<f64> {
    let rotation = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw_rad)
        * Rotation3::from_axis_angle(&Vector3::y_axis(), tilt_rad)
        * r_flu_optical();
    Isometry3::from_parts(Translation3::from(*position_world_m), UnitQuaternion::from_rotation_matrix(&rotation))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn narrow_focal_length_matches_the_thesis() {
        // Thesis eq. 6.3 example: f = 1080 px for the narrow cameras, a rounded value: 50.6° over
        // 1024 px gives 1083.1 px.
        let cam = StereoCamera::narrow();
        assert!((cam.f_px - 1083.14).abs() < 0.01, "f = {}", cam.f_px);
        assert!((cam.f_px - 1080.0).abs() < 4.0);
        assert!((cam.hfov_rad().to_degrees() - 50.6).abs() < 1e-9);
        let wide = StereoCamera::wide();
        assert!((wide.f_px - 340.0).abs() < 4.0, "f = {}", wide.f_px);
    }

    #[test]
    fn project_inverts_ray() {
        let cam = StereoCamera::narrow().downscaled(4);
        let p = cam.ray(17.25, 99.5) * 3.7;
        let (u, v) = cam.project(&p).unwrap_or((f64::NAN, f64::NAN));
        assert!((u - 17.25).abs() < 1e-9 && (v - 99.5).abs() < 1e-9);
        assert!(cam.project(&Vector3::new(0.0, 0.0, -1.0)).is_none());
    }

    #[test]
    fn downscaling_keeps_the_field_of_view() {
        let cam = StereoCamera::narrow();
        let low = cam.downscaled(4);
        assert_eq!((low.width_px, low.height_px), (256, 127));
        assert!((low.hfov_rad() - cam.hfov_rad()).abs() < 1e-12);
    }

    #[test]
    fn head_at_rest_looks_forward_and_tilt_looks_down() {
        let head = PanTiltHead::lru();
        let t = head.t_body_cam(0.0, 0.0);
        let forward = t.rotation * Vector3::z();
        assert!((forward - Vector3::x()).norm() < 1e-12);
        let right = t.rotation * Vector3::x();
        assert!((right + Vector3::y()).norm() < 1e-12);
        // The right camera is to the body's right (-y) of the left one.
        let t_right = t * Isometry3::translation(BASELINE_M, 0.0, 0.0);
        assert!((t.translation.vector.y - t_right.translation.vector.y - BASELINE_M).abs() < 1e-12);
        let down = head.t_body_cam(0.0, 0.3).rotation * Vector3::z();
        assert!(down.z < -0.29 && down.x > 0.9);
        let left = head.t_body_cam(std::f64::consts::FRAC_PI_2, 0.0).rotation * Vector3::z();
        assert!((left - Vector3::y()).norm() < 1e-12);
    }
}
