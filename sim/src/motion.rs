//! How robots move: rovers drive waypoint paths on the terrain (pose from wheel contact), flyers
//! fly free 6D paths (owned by the world helper).

use crate::terrain::Terrain;
use crate::trajectory::{Trajectory, TrajectoryError};

/// Driving parameters of a rover.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RoverDrive {
    pub speed_mps: f64,
    /// Standing time at each waypoint (zero-velocity phases).
    pub pause_s: f64,
    /// Spacing of the trajectory's spline control points.
    pub knot_interval_s: f64,
}

impl Default for RoverDrive {
    fn default() -> Self {
        RoverDrive { speed_mps: 0.3, pause_s: 2.0, knot_interval_s: 0.1 }
    }
}

/// Why a motion could not be planned.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MotionError {
    #[error("a path needs at least two waypoints")]
    TooFewWaypoints,
    #[error("waypoint {0} is off the terrain")]
    OffTerrain(usize),
    #[error(transparent)]
    Trajectory(#[from] TrajectoryError),
}

/// The trajectory of a rover driving `waypoints_m` (world x, y) on `terrain`, starting at
/// `start_ns`, and standing still until at least `until_ns` after the last waypoint.
pub fn rover_trajectory(
    terrain: &Terrain,
    waypoints_m: &[[f64; 2]],
    drive: &RoverDrive,
    start_ns: u64,
    until_ns: u64,
) -> Result<Trajectory, MotionError> {
    let _ = (terrain, drive, start_ns, until_ns);
    if waypoints_m.len() < 2 {
        return Err(MotionError::TooFewWaypoints);
    }
    Err(MotionError::OffTerrain(0))
}
