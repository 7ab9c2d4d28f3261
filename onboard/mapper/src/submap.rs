//! A submap (thesis §5.1.2–5.1.3): a gravity-aligned origin plus its cloud and octree.

use nalgebra::{Isometry3, Matrix6};

use crate::cloud::VoxelCloud;
use crate::occupancy::OccupancyMap;

/// One robot's submap. Index 0 is the robot's first; submap `i > 0` starts where the filter
/// switched frames, `t_prev_this` (the previous submap's origin to this one's) is that switch's
/// transform and `switch_covariance` its 6×6 covariance (`[δt; δθ]`, filter convention): the
/// graph factor between the two origins.
#[derive(Debug, Clone, PartialEq)]
pub struct Submap {
    pub robot_id: u16,
    pub index: u32,
    pub start_stamp_ns: u64,
    /// Stamp of the last integrated depth image (the submap is finished when the next starts).
    pub end_stamp_ns: u64,
    pub t_prev_this: Isometry3<f64>,
    pub switch_covariance: Matrix6<f64>,
    pub cloud: VoxelCloud,
    pub occupancy: OccupancyMap,
    /// Depth images integrated.
    pub images: u32,
    /// Distance the body travelled while this submap was current (m).
    pub distance_m: f64,
}
