//! The odometry's output to the filter: a keyframe-relative body motion with covariance.

use nalgebra::{Isometry3, Matrix6};

/// Motion of the body from a keyframe's capture time to the current frame's capture time.
///
/// Covariance convention: see the crate documentation (`[δt; δθ]`, translation in the keyframe's
/// body frame, rotation right-multiplied in the current body frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoDelta {
    /// Capture time of the current frame.
    pub stamp_ns: u64,
    /// Capture time of the keyframe the motion is relative to.
    pub keyframe_stamp_ns: u64,
    /// Body pose at `stamp_ns` in the body frame at `keyframe_stamp_ns`.
    pub t_keyframe_current_body: Isometry3<f64>,
    pub covariance_body: Matrix6<f64>,
    /// Left camera pose at `stamp_ns` in the left camera frame at `keyframe_stamp_ns`.
    pub t_keyframe_current_cam: Isometry3<f64>,
    pub covariance_cam: Matrix6<f64>,
    pub inliers: u32,
}
