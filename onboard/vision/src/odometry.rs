//! Keyframe stereo visual odometry (thesis §3.2, §4.1.1).

use crate::VoDelta;
use fpga_model::DisparityImage;
use hal::sensor::{StereoCalibration, StereoFrame};
use nalgebra::Isometry3;

/// Tuning of the odometry. `Default` is the rover set-up (1024×508, 10 Hz).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VoConfig {}

/// Why the odometry could not process a frame.
#[derive(Debug, thiserror::Error)]
pub enum VoError {
    /// The calibration is not a rectified pair (rectify first) or the frame does not match it.
    #[error("stereo odometry: {0}")]
    BadInput(String),
}

/// Per-frame counters, for telemetry and benchmarks.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VoStats {
    /// Features tracked from the keyframe into this frame.
    pub tracked: u32,
    /// Tracked features with a valid depth in the keyframe.
    pub with_depth: u32,
    pub inliers: u32,
    /// Reprojection RMS of the inliers after refinement, pixels.
    pub rms_px: f64,
    /// Keyframes held in the history (at most 5).
    pub keyframes: u32,
}

/// What one frame produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoOutput {
    /// Motion relative to a keyframe; `None` for the first frame and after a tracking loss.
    pub delta: Option<VoDelta>,
    /// This frame became a keyframe (the filter keeps its clone of this capture time).
    pub new_keyframe: bool,
    /// The odometry lost track and restarted from this frame as a fresh keyframe.
    pub reset: bool,
    /// Pose of the current body in the odometry's own frame (the body frame of the first
    /// keyframe), chained through the keyframes: the stereo-only trajectory.
    pub t_odom_body: Isometry3<f64>,
    pub stats: VoStats,
}

/// Keyframe-based stereo odometry on rectified pairs.
#[derive(Debug)]
pub struct StereoOdometry {}

impl StereoOdometry {
    /// Odometry for a rectified stereo calibration (`calibration.rectified` must hold).
    pub fn new(_config: VoConfig, _calibration: &StereoCalibration) -> Result<Self, VoError> {
        Err(VoError::BadInput("not built yet".into()))
    }

    /// Processes one rectified pair. `disparity` is the SGM map of this pair when the FPGA
    /// produced one (else features are matched sparsely). `prior_t_keyframe_current_body`
    /// predicts the motion (from the filter's gyro) to seed tracking.
    pub fn process(
        &mut self,
        _frame: &StereoFrame,
        _disparity: Option<&DisparityImage>,
        _prior_t_keyframe_current_body: Option<&Isometry3<f64>>,
    ) -> Result<VoOutput, VoError> {
        Err(VoError::BadInput("not built yet".into()))
    }
}
