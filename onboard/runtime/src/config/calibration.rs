//! The stereo head's calibration as the rover's TOML carries it (`[camera.calibration]`): what a
//! calibration run on the real rover produces, or what the software-in-the-loop harness writes
//! for its simulated head. A replayed dataset brings its own (`hal::replay`), so there the table
//! is optional.
//!
//! Poses are `t_body_cam` (the camera's optical frame in the body frame, `p_body = t · p_cam`) as
//! a translation in metres and a Hamilton quaternion `[w, x, y, z]`. A quaternion whose norm is 1
//! to rounding is taken bit for bit (a calibration written by this module reads back identical);
//! one that is only nearly unit (hand-typed, four decimals) is normalized; anything else is an
//! error.

use hal::sensor::{CameraCalibration, Distortion, PanTiltHead, Pinhole, StereoCalibration};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// A pose: translation (m) and rotation (unit quaternion `[w, x, y, z]`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseConfig {
    pub translation_m: [f64; 3],
    pub rotation_wxyz: [f64; 4],
}

/// Largest deviation of a quaternion's norm from 1 that is accepted (and normalized away).
const QUATERNION_NORM_TOLERANCE: f64 = 1e-4;

impl PoseConfig {
    pub fn from_isometry(pose: &Isometry3<f64>) -> PoseConfig {
        let q = pose.rotation.quaternion();
        PoseConfig { translation_m: pose.translation.vector.into(), rotation_wxyz: [q.w, q.i, q.j, q.k] }
    }

    pub fn to_isometry(&self) -> Result<Isometry3<f64>, String> {
        if !self.translation_m.iter().chain(&self.rotation_wxyz).all(|v| v.is_finite()) {
            return Err("a value is not finite".into());
        }
        let [w, x, y, z] = self.rotation_wxyz;
        let q = Quaternion::new(w, x, y, z);
        let norm = q.norm();
        if (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
            return Err(format!("rotation_wxyz has norm {norm}, expected a unit quaternion"));
        }
        // Rounding-level deviations are kept as written so that a written calibration reads back
        // bit-identical (renormalizing changes the last bits, and the odometry's discrete
        // decisions can flip on such a difference).
        let rotation = if (norm - 1.0).abs() <= 4.0 * f64::EPSILON {
            UnitQuaternion::new_unchecked(q)
        } else {
            UnitQuaternion::new_normalize(q)
        };
        Ok(Isometry3::from_parts(Translation3::from(Vector3::from(self.translation_m)), rotation))
    }
}

/// Pinhole intrinsics (px).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PinholeConfig {
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
}

/// One camera of the pair.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraModelConfig {
    pub width_px: u32,
    pub height_px: u32,
    pub intrinsics: PinholeConfig,
    /// Radial-tangential distortion `[k1, k2, p1, p2]` of a raw camera; absent when rectified.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distortion_radtan: Option<[f64; 4]>,
    /// The camera's pose in the body frame (with a pan-tilt head: at pan = tilt = 0).
    pub t_body_cam: PoseConfig,
}

/// The pan-tilt head the pair sits on (`hal::sensor::PanTiltHead`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadConfig {
    pub pan_axis_body_m: [f64; 3],
    pub stereo_centre_head_m: [f64; 3],
    pub baseline_m: f64,
    pub pan_limit_rad: f64,
    pub tilt_limit_rad: f64,
}

/// `[camera.calibration]`: the stereo head.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CalibrationConfig {
    /// The images are rectified (same intrinsics, no distortion, right camera along +x).
    pub rectified: bool,
    pub baseline_m: f64,
    pub left: CameraModelConfig,
    pub right: CameraModelConfig,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub head: Option<HeadConfig>,
}

fn camera_config(camera: &CameraCalibration) -> CameraModelConfig {
    let i = camera.intrinsics;
    CameraModelConfig {
        width_px: camera.width_px,
        height_px: camera.height_px,
        intrinsics: PinholeConfig { fx_px: i.fx_px, fy_px: i.fy_px, cx_px: i.cx_px, cy_px: i.cy_px },
        distortion_radtan: match camera.distortion {
            Distortion::None => None,
            Distortion::RadTan(k) => Some(k),
        },
        t_body_cam: PoseConfig::from_isometry(&camera.t_body_cam),
    }
}

fn camera_calibration(name: &str, camera: &CameraModelConfig) -> Result<CameraCalibration, String> {
    let i = camera.intrinsics;
    if !(16..=8192).contains(&camera.width_px) || !(16..=8192).contains(&camera.height_px) {
        return Err(format!("{name}: {}x{} px, expected 16..=8192 each", camera.width_px, camera.height_px));
    }
    if !([i.fx_px, i.fy_px].iter().all(|f| f.is_finite() && *f > 0.0) && i.cx_px.is_finite() && i.cy_px.is_finite()) {
        return Err(format!("{name}.intrinsics: focal lengths must be positive and every value finite"));
    }
    if camera.distortion_radtan.is_some_and(|k| !k.iter().all(|v| v.is_finite())) {
        return Err(format!("{name}.distortion_radtan: a value is not finite"));
    }
    Ok(CameraCalibration {
        width_px: camera.width_px,
        height_px: camera.height_px,
        intrinsics: Pinhole { fx_px: i.fx_px, fy_px: i.fy_px, cx_px: i.cx_px, cy_px: i.cy_px },
        distortion: camera.distortion_radtan.map_or(Distortion::None, Distortion::RadTan),
        t_body_cam: camera.t_body_cam.to_isometry().map_err(|e| format!("{name}.t_body_cam: {e}"))?,
    })
}

impl CalibrationConfig {
    pub fn from_calibration(calibration: &StereoCalibration) -> CalibrationConfig {
        CalibrationConfig {
            rectified: calibration.rectified,
            baseline_m: calibration.baseline_m,
            left: camera_config(&calibration.left),
            right: camera_config(&calibration.right),
            head: calibration.head.map(|h| HeadConfig {
                pan_axis_body_m: h.pan_axis_body_m.into(),
                stereo_centre_head_m: h.stereo_centre_head_m.into(),
                baseline_m: h.baseline_m,
                pan_limit_rad: h.pan_limit_rad,
                tilt_limit_rad: h.tilt_limit_rad,
            }),
        }
    }

    /// The calibration, checked: sizes, positive focal lengths and baseline, unit quaternions,
    /// both cameras of one size, no distortion on a rectified pair.
    pub fn to_calibration(&self) -> Result<StereoCalibration, String> {
        let left = camera_calibration("left", &self.left)?;
        let right = camera_calibration("right", &self.right)?;
        if (left.width_px, left.height_px) != (right.width_px, right.height_px) {
            return Err(format!(
                "left is {}x{} px, right {}x{} px: the pair must be of one size",
                left.width_px, left.height_px, right.width_px, right.height_px
            ));
        }
        if !(self.baseline_m.is_finite() && self.baseline_m > 0.0) {
            return Err(format!("baseline_m {}: must be positive", self.baseline_m));
        }
        if self.rectified && (left.distortion != Distortion::None || right.distortion != Distortion::None) {
            return Err("a rectified pair has no distortion".into());
        }
        let head = match &self.head {
            None => None,
            Some(h) => {
                let scalars = [h.baseline_m, h.pan_limit_rad, h.tilt_limit_rad];
                let finite =
                    h.pan_axis_body_m.iter().chain(&h.stereo_centre_head_m).chain(&scalars).all(|v| v.is_finite());
                if !finite || h.pan_limit_rad < 0.0 || h.tilt_limit_rad < 0.0 {
                    return Err("head: every value must be finite and the limits non-negative".into());
                }
                Some(PanTiltHead {
                    pan_axis_body_m: Vector3::from(h.pan_axis_body_m),
                    stereo_centre_head_m: Vector3::from(h.stereo_centre_head_m),
                    baseline_m: h.baseline_m,
                    pan_limit_rad: h.pan_limit_rad,
                    tilt_limit_rad: h.tilt_limit_rad,
                })
            }
        };
        Ok(StereoCalibration { left, right, rectified: self.rectified, baseline_m: self.baseline_m, head })
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    fn lru_like() -> StereoCalibration {
        let camera = CameraCalibration {
            width_px: 256,
            height_px: 127,
            intrinsics: Pinhole { fx_px: 186.3, fy_px: 186.3, cx_px: 127.5, cy_px: 63.0 },
            distortion: Distortion::None,
            t_body_cam: PanTiltHead::lru().t_body_cam(0.0, 0.25),
        };
        StereoCalibration {
            left: camera,
            right: camera,
            rectified: true,
            baseline_m: 0.09,
            head: Some(PanTiltHead::lru()),
        }
    }

    #[test]
    fn a_calibration_survives_toml_bit_for_bit() {
        let calibration = lru_like();
        let text = toml::to_string(&CalibrationConfig::from_calibration(&calibration)).unwrap();
        let back: CalibrationConfig = toml::from_str(&text).unwrap();
        assert_eq!(back.to_calibration().unwrap(), calibration, "{text}");
    }

    #[test]
    fn nearly_unit_quaternions_are_normalized_and_others_refused() {
        let pose = PoseConfig { translation_m: [0.0; 3], rotation_wxyz: [0.60004, 0.0, 0.8, 0.0] };
        let q = pose.to_isometry().unwrap().rotation;
        assert!((q.quaternion().norm() - 1.0).abs() < 1e-15);
        let bad = PoseConfig { rotation_wxyz: [1.0, 0.1, 0.0, 0.0], ..pose };
        assert!(bad.to_isometry().unwrap_err().contains("norm"));
    }

    #[test]
    fn inconsistent_pairs_are_refused() {
        let mut c = CalibrationConfig::from_calibration(&lru_like());
        c.right.width_px = 300;
        assert!(c.to_calibration().unwrap_err().contains("one size"));
        let mut c = CalibrationConfig::from_calibration(&lru_like());
        c.left.distortion_radtan = Some([0.1, 0.0, 0.0, 0.0]);
        assert!(c.to_calibration().unwrap_err().contains("rectified"));
        let mut c = CalibrationConfig::from_calibration(&lru_like());
        c.baseline_m = -0.1;
        assert!(c.to_calibration().is_err());
    }
}
