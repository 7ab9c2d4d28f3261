//! Rectification of raw stereo pairs (pinhole + radial-tangential) into the canonical pair.

use hal::sensor::{StereoCalibration, StereoFrame};

/// Why a rectifier could not be built or applied.
#[derive(Debug, thiserror::Error)]
pub enum RectifyError {
    #[error("rectification: {0}")]
    Calibration(String),
    #[error("rectification: frame is {got_w}x{got_h}, calibration is {want_w}x{want_h}")]
    FrameSize { got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
}

/// Precomputed remapping of a raw pair into a rectified pair.
#[derive(Debug)]
pub struct Rectifier {}

impl Rectifier {
    /// A rectifier for a raw calibration (an already rectified one gives the identity mapping).
    pub fn new(_raw: &StereoCalibration) -> Result<Self, RectifyError> {
        Err(RectifyError::Calibration("not built yet".into()))
    }

    /// The calibration of the output pair: `rectified == true`, shared pinhole, no distortion,
    /// right camera at `+baseline_m` along x, `left.t_body_cam` the rectified left camera.
    pub fn rectified_calibration(&self) -> StereoCalibration {
        unreachable!()
    }

    /// Rectifies `raw` into `out` (resized; allocation reused). Stamps and head angles are copied.
    pub fn rectify(&self, _raw: &StereoFrame, _out: &mut StereoFrame) -> Result<(), RectifyError> {
        Err(RectifyError::Calibration("not built yet".into()))
    }
}
