//! The error-state EKF.

use crate::{FilterConfig, FilterHealth, FrameSwitch};
use hal::sensor::{ImuSample, WheelOdomSample};
use nalgebra::{Isometry3, Matrix6, SMatrix, Vector3};

/// Why the filter refused an input.
#[derive(Debug, thiserror::Error)]
pub enum FilterError {
    #[error("filter: not initialized")]
    NotInitialized,
    #[error("filter: {0}")]
    BadInput(String),
}

/// A relative pose of the body between two capture times (for example a VO keyframe delta),
/// `t_from_to` = body at `to_stamp_ns` in the body frame at `from_stamp_ns`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativePoseMeasurement {
    pub from_stamp_ns: u64,
    pub to_stamp_ns: u64,
    pub t_from_to: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

/// Result of one measurement update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UpdateOutcome {
    /// Applied; `nis` is the normalized innovation squared.
    Applied { nis: f64 },
    /// Failed the chi-square gate.
    Rejected { nis: f64, threshold: f64 },
    /// No clone of a referenced capture time is held (too old or never cloned).
    MissingClone,
}

/// The filter's output at IMU rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterState {
    pub stamp_ns: u64,
    /// Id of the current local frame (incremented by every frame switch).
    pub frame_id: u32,
    pub t_local_body: Isometry3<f64>,
    pub v_local_mps: Vector3<f64>,
    pub accel_bias_mps2: Vector3<f64>,
    pub gyro_bias_radps: Vector3<f64>,
    /// Covariance of the 15-D error state (δp, δv, δθ, δb_a, δb_g).
    pub covariance: SMatrix<f64, 15, 15>,
}

/// The local reference filter.
#[derive(Debug)]
pub struct Filter {
    config: FilterConfig,
    health: FilterHealth,
}

impl Filter {
    pub fn new(config: FilterConfig) -> Self {
        Filter { config, health: FilterHealth::default() }
    }

    pub fn config(&self) -> &FilterConfig {
        &self.config
    }

    pub fn is_initialized(&self) -> bool {
        false
    }

    /// Starts at rest: roll and pitch from the mean specific force, gyro bias from the mean
    /// rate, position and yaw zero (the first local frame).
    pub fn initialize_at_rest(
        &mut self,
        _stamp_ns: u64,
        _mean_accel_mps2: &Vector3<f64>,
        _mean_gyro_radps: &Vector3<f64>,
    ) -> Result<(), FilterError> {
        Err(FilterError::NotInitialized)
    }

    /// Starts from a known pose and velocity (for example ground truth in a test), with the
    /// configured initial uncertainty.
    pub fn initialize_with_pose(
        &mut self,
        _stamp_ns: u64,
        _t_local_body: &Isometry3<f64>,
        _v_local_mps: &Vector3<f64>,
    ) -> Result<(), FilterError> {
        Err(FilterError::NotInitialized)
    }

    /// Integrates one IMU sample (propagation of state and covariance up to its stamp).
    pub fn propagate(&mut self, _imu: &ImuSample) -> Result<(), FilterError> {
        Err(FilterError::NotInitialized)
    }

    /// Clones the pose at an image's capture time (the trigger), propagating to it first.
    pub fn clone_at(&mut self, _stamp_ns: u64) -> Result<(), FilterError> {
        Err(FilterError::NotInitialized)
    }

    /// Keeps the clone of `stamp_ns` as a keyframe clone (VO made that frame a keyframe).
    pub fn mark_keyframe(&mut self, _stamp_ns: u64) {}

    /// Relative pose between two cloned capture times (delay compensated: both may lie in the
    /// past). The clone of `to_stamp_ns` is released afterwards unless it is a keyframe.
    pub fn update_relative_pose(&mut self, _m: &RelativePoseMeasurement) -> Result<UpdateOutcome, FilterError> {
        Err(FilterError::NotInitialized)
    }

    /// Wheel odometry body velocity.
    pub fn update_wheel_odometry(&mut self, _sample: &WheelOdomSample) -> Result<UpdateOutcome, FilterError> {
        Err(FilterError::NotInitialized)
    }

    /// Zero velocity (and zero rotation rate) while standing.
    pub fn update_zero_velocity(&mut self) -> Result<UpdateOutcome, FilterError> {
        Err(FilterError::NotInitialized)
    }

    /// Absolute pose in the current local frame (tests with ground truth; a landmark).
    pub fn update_pose(
        &mut self,
        _t_local_body: &Isometry3<f64>,
        _covariance: &Matrix6<f64>,
    ) -> Result<UpdateOutcome, FilterError> {
        Err(FilterError::NotInitialized)
    }

    /// Frame-of-reference switch (thesis §4.1.2).
    pub fn switch_frame(&mut self) -> Result<FrameSwitch, FilterError> {
        Err(FilterError::NotInitialized)
    }

    pub fn state(&self) -> Option<FilterState> {
        None
    }

    pub fn health(&self) -> &FilterHealth {
        &self.health
    }
}
