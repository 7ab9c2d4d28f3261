//! The marker uncertainty models of the thesis's §8.1.3 (Tab. 8.3) and the 75° gate.
//!
//! Every model gives six sigmas in the module's camera-frame error convention (x, y, z in m;
//! rotation about the camera's x, y, z in rad):
//!
//! | model | sigmas |
//! |---|---|
//! | [`UncertaintyModel::Constant`] | Eq. 8.1: `Σ = diag(1e-4, 1e-4, 1e-4, 5e-4, 5e-4, 5e-4)` (**variances**, T26: σ = 1 cm, 1.28°) |
//! | [`UncertaintyModel::Quadratic`] | Eq. 8.2: `Σ_constant · (1 + d̂)²`, i.e. σ scaled by `1 + d̂` |
//! | [`UncertaintyModel::LutOnly`] | the table at `(d̂, Φ̂)`, bilinear, x/y pairs turned to the tilt axis (module docs) |
//! | [`UncertaintyModel::OnlineOnly`] | the 257-pose spread of the online sampling |
//! | [`UncertaintyModel::LutAndOnline`] | per DOF the larger of the two (the thesis's model) |
//!
//! **Gate (T19).** As in §8.1.3, the online sampling runs for every model and a detection whose
//! largest rotational sigma (the model's or the sampling's, whichever is larger) exceeds 75° is
//! rejected: [`MarkerPose::gate_passed`] is false and the caller drops it.

use hal::sensor::Pinhole;
use nalgebra::{Isometry3, Matrix6, Vector6};

use super::ippe::{PnpError, PnpOptions, SquarePnp, solve_square};
use super::lut::MarkerLut;
use super::sampling::{PoseSpread, sample_pose_spread};
use super::{DOFS, ViewGeometry, view_geometry};

/// Eq. 8.1's variances (m², rad²).
pub const CONSTANT_VARIANCES: [f64; DOFS] = [1e-4, 1e-4, 1e-4, 5e-4, 5e-4, 5e-4];
/// The rotational-uncertainty gate of §8.1.3.
pub const ROTATION_GATE_DEG: f64 = 75.0;

/// Which sigmas a detection gets (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UncertaintyModel {
    Constant,
    Quadratic,
    LutOnly,
    OnlineOnly,
    LutAndOnline,
}

impl UncertaintyModel {
    pub const ALL: [UncertaintyModel; 5] = [
        UncertaintyModel::Constant,
        UncertaintyModel::Quadratic,
        UncertaintyModel::LutOnly,
        UncertaintyModel::OnlineOnly,
        UncertaintyModel::LutAndOnline,
    ];

    pub fn needs_lut(self) -> bool {
        matches!(self, UncertaintyModel::LutOnly | UncertaintyModel::LutAndOnline)
    }

    /// The model's number in messages (`msgs::MarkerMsg::model`): its index in [`Self::ALL`].
    pub fn code(self) -> u32 {
        Self::ALL.iter().position(|&m| m == self).unwrap_or(0) as u32
    }

    /// The model of a message's number, `None` for an unknown one.
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.get(code as usize).copied()
    }

    pub fn name(self) -> &'static str {
        match self {
            UncertaintyModel::Constant => "constant",
            UncertaintyModel::Quadratic => "quadratic",
            UncertaintyModel::LutOnly => "LUT only",
            UncertaintyModel::OnlineOnly => "online only",
            UncertaintyModel::LutAndOnline => "LUT + online",
        }
    }
}

/// Settings of [`estimate_marker_pose_with`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerPoseConfig {
    /// Corner perturbation of the online sampling (Eq. 6.9), pixels.
    pub delta_px: f64,
    /// Largest rotational sigma a detection may have.
    pub gate_deg: f64,
    pub pnp: PnpOptions,
}

impl Default for MarkerPoseConfig {
    fn default() -> Self {
        MarkerPoseConfig { delta_px: 0.5, gate_deg: ROTATION_GATE_DEG, pnp: PnpOptions::default() }
    }
}

/// A marker detection's pose with its uncertainty.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerPose {
    /// The chosen pose: the IPPE solution with the lower reprojection error.
    pub t_cam_marker: Isometry3<f64>,
    /// Both IPPE solutions, their reprojection RMS and the ratio second/best.
    pub pnp: SquarePnp,
    /// `d̂`, signed `Φ̂` and the tilt axis of the chosen pose.
    pub view: ViewGeometry,
    pub model: UncertaintyModel,
    /// The model's sigmas (x, y, z in m; rx, ry, rz in rad; camera frame).
    pub sigmas: [f64; DOFS],
    /// The table's sigmas at `(d̂, Φ̂)`, turned to the tilt axis (when a table was given).
    pub lut_sigmas: Option<[f64; DOFS]>,
    /// The online sampling (always run: it feeds the gate).
    pub spread: PoseSpread,
    /// False: the largest rotational sigma exceeds the gate; drop the detection.
    pub gate_passed: bool,
}

impl MarkerPose {
    /// `diag(σ²)` over `[δt; δθ]` (camera frame).
    pub fn covariance(&self) -> Matrix6<f64> {
        Matrix6::from_diagonal(&Vector6::from_iterator(self.sigmas.iter().map(|s| s * s)))
    }
}

/// Why a detection got no pose.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MarkerPoseError {
    #[error("PnP: {0}")]
    Pnp(#[from] PnpError),
    #[error("the {0} model needs a look-up table")]
    MissingLut(&'static str),
    #[error("the look-up table was made for another {0}")]
    LutMismatch(&'static str),
}

/// [`estimate_marker_pose_with`] with the default configuration (Δp = 0.5 px, 75° gate, IPPE).
pub fn estimate_marker_pose(
    corners_px: &[[f64; 2]; 4],
    intrinsics: &Pinhole,
    tag_size_m: f64,
    model: UncertaintyModel,
    lut: Option<&MarkerLut>,
) -> Result<MarkerPose, MarkerPoseError> {
    estimate_marker_pose_with(corners_px, intrinsics, tag_size_m, model, lut, &MarkerPoseConfig::default())
}

/// Pose, sigmas and gate of one detection (corners in the AprilTag order, see [`super::ippe`]).
pub fn estimate_marker_pose_with(
    corners_px: &[[f64; 2]; 4],
    intrinsics: &Pinhole,
    tag_size_m: f64,
    model: UncertaintyModel,
    lut: Option<&MarkerLut>,
    config: &MarkerPoseConfig,
) -> Result<MarkerPose, MarkerPoseError> {
    if model.needs_lut() && lut.is_none() {
        return Err(MarkerPoseError::MissingLut(model.name()));
    }
    if let Some(lut) = lut {
        check_lut(lut, intrinsics, tag_size_m)?;
    }
    let pnp = solve_square(corners_px, intrinsics, tag_size_m, &config.pnp)?;
    let t_cam_marker = pnp.best.t_cam_marker;
    let view = view_geometry(&t_cam_marker);
    let spread = sample_pose_spread(corners_px, intrinsics, tag_size_m, config.delta_px, &config.pnp, &t_cam_marker)?;
    let lut_sigmas = lut.map(|l| lut_sigmas(l, &view));
    let online = spread.max_deviation;
    let sigmas = match (model, lut_sigmas) {
        (UncertaintyModel::Constant, _) => CONSTANT_VARIANCES.map(f64::sqrt),
        (UncertaintyModel::Quadratic, _) => CONSTANT_VARIANCES.map(|v| v.sqrt() * (1.0 + view.distance_m)),
        (UncertaintyModel::OnlineOnly, _) => online,
        (UncertaintyModel::LutOnly, Some(l)) => l,
        (UncertaintyModel::LutAndOnline, Some(l)) => std::array::from_fn(|k| l[k].max(online[k])),
        (UncertaintyModel::LutOnly | UncertaintyModel::LutAndOnline, None) => {
            return Err(MarkerPoseError::MissingLut(model.name()));
        }
    };
    let largest_rotation = sigmas[3..].iter().chain(&online[3..]).fold(0.0f64, |m, &s| m.max(s));
    let gate_passed = largest_rotation.is_finite() && largest_rotation <= config.gate_deg.to_radians();
    Ok(MarkerPose { t_cam_marker, pnp, view, model, sigmas, lut_sigmas, spread, gate_passed })
}

/// The table's sigmas at the pose's `(d̂, Φ̂)`, with the x/y pairs turned by the tilt-axis angle.
pub fn lut_sigmas(lut: &MarkerLut, view: &ViewGeometry) -> [f64; DOFS] {
    let base = lut.lookup(view.distance_m, view.tilt_rad);
    turn_xy(&base, view.axis_angle_rad)
}

/// Sigmas of a diagonal covariance turned by `beta` about the viewing (z) axis, diagonal kept:
/// `σ'_x² = cos²β σ_x² + sin²β σ_y²`, `σ'_y² = sin²β σ_x² + cos²β σ_y²`, for the translation and
/// the rotation pair.
pub fn turn_xy(sigmas: &[f64; DOFS], beta: f64) -> [f64; DOFS] {
    let (s, c) = beta.sin_cos();
    let (s2, c2) = (s * s, c * c);
    let mut out = *sigmas;
    for k in [0, 3] {
        let (x2, y2) = (sigmas[k].powi(2), sigmas[k + 1].powi(2));
        out[k] = (c2 * x2 + s2 * y2).sqrt();
        out[k + 1] = (s2 * x2 + c2 * y2).sqrt();
    }
    out
}

/// Refuses a table made for another camera (intrinsics to 1e-6) or tag size.
pub fn check_lut(lut: &MarkerLut, intrinsics: &Pinhole, tag_size_m: f64) -> Result<(), MarkerPoseError> {
    let p = lut.params();
    let close = |a: f64, b: f64| (a - b).abs() <= 1e-6 * a.abs().max(b.abs()).max(1.0);
    let k = &p.camera.intrinsics;
    if !(close(k.fx_px, intrinsics.fx_px)
        && close(k.fy_px, intrinsics.fy_px)
        && close(k.cx_px, intrinsics.cx_px)
        && close(k.cy_px, intrinsics.cy_px))
    {
        return Err(MarkerPoseError::LutMismatch("camera"));
    }
    if !close(p.tag_size_m, tag_size_m) {
        return Err(MarkerPoseError::LutMismatch("tag size"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn turning_by_a_right_angle_swaps_x_and_y() {
        let s = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let t = turn_xy(&s, std::f64::consts::FRAC_PI_2);
        for (a, b) in t.iter().zip([2.0, 1.0, 3.0, 5.0, 4.0, 6.0]) {
            assert!((a - b).abs() < 1e-12, "{t:?}");
        }
        assert_eq!(turn_xy(&s, 0.0), s);
    }
}
