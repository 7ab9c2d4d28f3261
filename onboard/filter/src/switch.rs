//! Frame-of-reference switching (thesis §4.1.2).

use nalgebra::{Isometry3, Matrix6};

/// The result of a frame switch: the new local frame in the old one (x, y, z, yaw of the body at
/// switch time, roll = pitch = 0) with its covariance (`[δt; δθ]` convention). This is the
/// graph's factor between consecutive submap origins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameSwitch {
    pub stamp_ns: u64,
    /// Id of the frame that ended and of the one that starts (`new = old + 1`).
    pub old_frame_id: u32,
    pub new_frame_id: u32,
    pub t_old_new: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}
