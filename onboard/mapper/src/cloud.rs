//! The 5 cm voxel point cloud (thesis §5.1.2 a).
//!
//! One point per occupied voxel of a grid aligned to multiples of the leaf size (as PCL's
//! VoxelGrid): the centroid of the voxel's input points (not the voxel centre), their mean
//! intensity, and an obstacle bit that is the OR over them.

use nalgebra::Point3;

/// Leaf size of the submap clouds (thesis: 5 cm).
pub const CLOUD_LEAF_M: f64 = 0.05;

/// One voxel's point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    /// Centroid of the voxel's input points, in the cloud's frame.
    pub position_m: Point3<f32>,
    /// Mean grey value of the input points (the rovers' cameras are greyscale).
    pub intensity: u8,
    /// True when at least one input point was classified as an obstacle.
    pub obstacle: bool,
}

/// A voxel-filtered cloud: at most one point per `leaf_m` voxel.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VoxelCloud {
    pub leaf_m: f64,
    pub points: Vec<MapPoint>,
}

impl VoxelCloud {
    pub fn new(leaf_m: f64) -> VoxelCloud {
        VoxelCloud { leaf_m, points: Vec::new() }
    }

    /// Index of the voxel containing `p` (grid aligned to multiples of the leaf size).
    pub fn voxel_of(&self, p: &Point3<f32>) -> [i32; 3] {
        let leaf = self.leaf_m;
        [
            (f64::from(p.x) / leaf).floor() as i32,
            (f64::from(p.y) / leaf).floor() as i32,
            (f64::from(p.z) / leaf).floor() as i32,
        ]
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    pub fn obstacle_count(&self) -> usize {
        self.points.iter().filter(|p| p.obstacle).count()
    }
}
