//! Pose and uncertainty of a detected robot marker (thesis §6.2, spec §1.4): pure functions, no
//! I/O, no clock.
//!
//! - [`ippe`]: PnP for a square tag, both planar solutions (IPPE), optional LM refinement.
//! - [`sampling`]: the online corner-noise sampling of Eq. 6.9 (257 poses, spread per DOF).
//! - [`render`], [`lut`]: our tag renderer and the offline look-up table over distance and
//!   signed tilt (generation, median filter and fill rules, bilinear lookup, file format).
//! - [`models`]: the uncertainty models of Tab. 8.3 (constant, quadratic, LUT only, online only,
//!   LUT + online) and the 75° gate, behind one entry point, [`estimate_marker_pose`].
//!
//! # Conventions (used everywhere in this module)
//!
//! - **Frames.** `cam`: the rectified left camera's optical frame (x right, y down, z forward).
//!   `marker`: the tag's centre, x to its right, y to its top, z out of its face (the
//!   simulator's and the AprilTag library's). Poses are `t_cam_marker` (the marker in the
//!   camera frame). Pixel `(0, 0)` is the centre of the top-left pixel.
//! - **Error DOFs (T21).** The six per-DOF errors and sigmas, in this order, are all in the
//!   **camera frame**: translation error `t̂ − t` (x, y, z; z is along the viewing direction),
//!   then rotation error `δθ = Log(R̂ Rᵀ)` (components about the camera's x, y, z), where
//!   `(R̂, t̂)` is the estimate and `(R, t)` the truth (or the sample mean, in the sampling step).
//!   So `R = Exp(−δθ)·R̂`: the error rotates about the tag's centre, in camera axes. The
//!   covariance `diag(σ²)` is over that vector; converting it into the robots' frames (the
//!   adjoint through `t_body_cam` and `t_body_marker`) is the caller's job.
//! - **Distance and signed tilt (T22)** ([`view_geometry`]): `d̂ = |t|`. With `v` the unit
//!   direction from the tag to the camera expressed in the marker frame, the tilt magnitude is
//!   the angle between the tag's normal and `v`, `acos(v_z)` (the thesis's Φ), signed by `v_x`
//!   (positive when the camera sits towards the tag's +x side). The table is generated tilting
//!   about the tag's vertical axis, where this is exactly the rendered Φ; a tag tilted about
//!   another axis (the rovers' markers lean back 25°) has its tilt axis at angle `β` from the
//!   camera's y axis in the image, and the table's x/y sigmas (translation and rotation) are
//!   turned by `β` about the viewing axis before use (`σ'_x² = cos²β σ_x² + sin²β σ_y²`, …).
//!   The table is close to symmetric in Φ (measured in `tests/marker_pose.rs` on the committed
//!   table), so the sign's jump for tags tilted purely about their x axis is harmless.

pub mod ippe;
pub mod lut;
pub mod models;
pub mod render;
pub mod sampling;

use nalgebra::{Isometry3, Vector3};

pub use ippe::{PnpError, PnpOptions, PnpSolution, SquarePnp, solve_square};
pub use lut::{LutDecodeError, LutError, LutGrid, LutParams, MarkerLut};
pub use models::{
    CONSTANT_VARIANCES, MarkerPose, MarkerPoseConfig, MarkerPoseError, ROTATION_GATE_DEG, UncertaintyModel, check_lut,
    estimate_marker_pose, estimate_marker_pose_with,
};
pub use sampling::{PoseSpread, sample_pose_spread};

/// Number of error DOFs: x, y, z, rx, ry, rz.
pub const DOFS: usize = 6;

/// Error of `estimate` against `truth` in the module's convention: `[t̂ − t; Log(R̂ Rᵀ)]`, camera
/// frame.
pub fn pose_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> [f64; DOFS] {
    let dt = estimate.translation.vector - truth.translation.vector;
    let dr = (estimate.rotation * truth.rotation.inverse()).scaled_axis();
    [dt.x, dt.y, dt.z, dr.x, dr.y, dr.z]
}

/// Distance, signed tilt and tilt-axis angle of a marker pose (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewGeometry {
    pub distance_m: f64,
    /// Signed Φ in (−π, π]; within ±π/2 for a tag seen from the front.
    pub tilt_rad: f64,
    /// Angle `β` in (−π/2, π/2] of the tilt axis's image from the camera's y axis (0 for the
    /// table's geometry; the tag's own y axis when it faces the camera squarely).
    pub axis_angle_rad: f64,
}

/// See [`ViewGeometry`].
pub fn view_geometry(t_cam_marker: &Isometry3<f64>) -> ViewGeometry {
    let t = t_cam_marker.translation.vector;
    let distance_m = t.norm();
    let to_camera = if distance_m > 0.0 { t_cam_marker.rotation.inverse() * (-t / distance_m) } else { Vector3::z() };
    let magnitude = to_camera.z.clamp(-1.0, 1.0).acos();
    let tilt_rad = if to_camera.x < 0.0 { -magnitude } else { magnitude };
    let axis = Vector3::new(-to_camera.y, to_camera.x, 0.0);
    let axis_marker = if axis.norm() > 1e-9 { axis / axis.norm() } else { Vector3::y() };
    let a = t_cam_marker.rotation * axis_marker;
    let mut beta = (-a.x).atan2(a.y);
    if beta > std::f64::consts::FRAC_PI_2 {
        beta -= std::f64::consts::PI;
    } else if beta <= -std::f64::consts::FRAC_PI_2 {
        beta += std::f64::consts::PI;
    }
    ViewGeometry { distance_m, tilt_rad, axis_angle_rad: beta }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn table_cells_have_their_own_tilt_and_no_axis_turn() {
        let grid = LutGrid::thesis(11);
        for j in 0..11 {
            let truth = lut::cell_truth(&grid, 3, j);
            let g = view_geometry(&truth);
            assert!((g.tilt_rad - grid.tilt_rad(j)).abs() < 1e-12, "{} {}", g.tilt_rad, grid.tilt_rad(j));
            assert!((g.distance_m - grid.distance_m(3)).abs() < 1e-12);
            assert!(g.axis_angle_rad.abs() < 1e-9, "{}", g.axis_angle_rad);
        }
    }

    #[test]
    fn a_tag_leaning_back_has_its_tilt_axis_along_the_image_x() {
        // Upright facing the camera, then turned 30° about the tag's own x axis.
        let grid = LutGrid::thesis(3);
        let upright = lut::cell_truth(&grid, 1, 1);
        let lean = upright * Isometry3::rotation(Vector3::x() * 30f64.to_radians());
        let g = view_geometry(&lean);
        assert!((g.tilt_rad.abs() - 30f64.to_radians()).abs() < 1e-9);
        assert!((g.axis_angle_rad.abs() - std::f64::consts::FRAC_PI_2).abs() < 1e-9, "{}", g.axis_angle_rad);
    }
}
