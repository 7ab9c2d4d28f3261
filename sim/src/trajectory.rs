//! Smooth continuous-time trajectories with analytic derivatives (owned by the IMU helper).
//!
//! CONTRACT: a uniform quintic B-spline over six channels `[x, y, z, roll, pitch, yaw]`
//! (world position, yaw-pitch-roll `R = Rz·Ry·Rx`), so position is C⁴ and the IMU's specific
//! force and angular rate come from exact derivatives, not finite differences.

use nalgebra::{Isometry3, Vector3};

/// Kinematic state of a body at one instant, from a [`Trajectory`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KinematicState {
    pub t_world_body: Isometry3<f64>,
    pub v_world_mps: Vector3<f64>,
    pub a_world_mps2: Vector3<f64>,
    /// Angular velocity of the body in the body frame.
    pub omega_body_radps: Vector3<f64>,
    /// `[roll, pitch, yaw]` and their rates.
    pub euler_rad: Vector3<f64>,
    pub euler_rate_radps: Vector3<f64>,
}

/// Why a trajectory could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrajectoryError {
    #[error("a quintic B-spline needs at least 6 control points, got {0}")]
    TooFewKnots(usize),
    #[error("knot interval must be positive and finite, got {0}")]
    BadInterval(f64),
    #[error("control point {0} is not finite")]
    NotFinite(usize),
}

/// A uniform quintic B-spline trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    start_ns: u64,
    knot_interval_s: f64,
    control_points: Vec<[f64; 6]>,
}

impl Trajectory {
    /// A spline whose valid time span starts at `start_ns`; `control_points` are
    /// `[x, y, z, roll, pitch, yaw]` (yaw unwrapped by the caller: no jumps of 2π).
    pub fn new(start_ns: u64, knot_interval_s: f64, control_points: Vec<[f64; 6]>) -> Result<Self, TrajectoryError> {
        if !(knot_interval_s.is_finite() && knot_interval_s > 0.0) {
            return Err(TrajectoryError::BadInterval(knot_interval_s));
        }
        if control_points.len() < 6 {
            return Err(TrajectoryError::TooFewKnots(control_points.len()));
        }
        Ok(Trajectory { start_ns, knot_interval_s, control_points })
    }

    pub fn start_ns(&self) -> u64 {
        self.start_ns
    }

    /// End of the valid time span.
    pub fn end_ns(&self) -> u64 {
        self.start_ns
    }

    pub fn knot_interval_s(&self) -> f64 {
        self.knot_interval_s
    }

    pub fn control_points(&self) -> &[[f64; 6]] {
        &self.control_points
    }

    /// State at `stamp_ns`, `None` outside `[start_ns, end_ns]`.
    pub fn state_at(&self, stamp_ns: u64) -> Option<KinematicState> {
        let _ = stamp_ns;
        None
    }
}
