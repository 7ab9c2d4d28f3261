//! The hazard cells around a robot, for the operator's map (thesis §5.1.1: the rolling local
//! obstacle map, coarsened on board). Latest wins: only the newest picture is worth the link.

use heapless::Vec;
use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::geometry::Pose3;
use crate::ids::{RobotId, SubmapId};

/// Cells one [`HazardCells`] carries at most, the nearest first: 2 bytes each, so the worst case
/// stays under 600 bytes, about 80 ms of a 57.6 kbit/s radio.
pub const HAZARD_CELLS_MAX: usize = 256;

/// A robot's hazard cells relative to its body, so the ground can place them with the robot's own
/// pose (the robot's local frame has an origin only the robot and its graph know).
///
/// The cells lie on a lattice of `cell_size_m` in the body's **heading frame**: origin at the
/// body, z up (gravity-aligned), x along the body's x axis projected onto the horizontal plane.
/// Cell `[i, j]` is centred at `(i·cell_size_m, j·cell_size_m)` in that frame. With 0.1 m cells
/// the offsets reach ±12.7 m, beyond the robot's 10 m × 10 m local map.
///
/// Decoders accept any bytes; consumers call [`HazardCells::is_valid`] before placing the cells.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct HazardCells {
    pub robot: RobotId,
    /// Robot time of the body pose the cells are relative to, ns.
    pub stamp_ns: u64,
    /// The submap whose origin is the reference frame of `t_submap_body` (as in
    /// [`super::PoseEstimate`]).
    pub submap: SubmapId,
    /// The body the cells are relative to.
    pub t_submap_body: Pose3,
    pub cell_size_m: f32,
    /// Hazard cells the robot knew but left out, the farthest ones (saturating): zero means the
    /// picture is complete. Counted in the robot map's cells where it dropped them itself, so
    /// this is a size hint, not an exact count of wire cells.
    pub omitted: u16,
    /// `[i, j]` offsets in cells (see the type's documentation), the nearest first, no duplicates.
    pub cells: Vec<[i8; 2], HAZARD_CELLS_MAX>,
}

impl HazardCells {
    /// Whether the pose is valid and the cell size is a positive finite length up to 10 m.
    pub fn is_valid(&self) -> bool {
        self.t_submap_body.is_valid()
            && self.cell_size_m.is_finite()
            && self.cell_size_m > 0.0
            && self.cell_size_m <= 10.0
    }
}
