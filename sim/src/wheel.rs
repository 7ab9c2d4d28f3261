//! Wheel odometry with slip-dependent error (owned by the IMU helper).

use hal::sensor::WheelOdomSample;
use nalgebra::Vector3;

use crate::trajectory::KinematicState;

/// Slip and noise of the wheel odometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelOdomConfig {
    pub rate_hz: f64,
    /// Helper-defined slip and noise parameters.
    pub base_slip: f64,
    pub slip_per_uphill_rad: f64,
    pub speed_noise_mps: f64,
    pub yaw_rate_noise_radps: f64,
}

impl Default for WheelOdomConfig {
    fn default() -> Self {
        WheelOdomConfig {
            rate_hz: 50.0,
            base_slip: 0.0,
            slip_per_uphill_rad: 0.0,
            speed_noise_mps: 0.0,
            yaw_rate_noise_radps: 0.0,
        }
    }
}

/// Generates wheel odometry for one rover.
#[derive(Debug, Clone)]
pub struct WheelOdometer {
    config: WheelOdomConfig,
}

impl WheelOdometer {
    pub fn new(config: WheelOdomConfig, seed: u64) -> Self {
        let _ = seed;
        WheelOdometer { config }
    }

    pub fn config(&self) -> &WheelOdomConfig {
        &self.config
    }

    /// The odometry sample at `stamp_ns` for the true state `state`. Call once per period, in order.
    pub fn sample(&mut self, state: &KinematicState, stamp_ns: u64) -> WheelOdomSample {
        let _ = state;
        WheelOdomSample { stamp_ns, linear_mps: Vector3::zeros(), angular_radps: Vector3::zeros(), sigma: [0.0; 6] }
    }

    /// The slip ratio of the last sample (0 = none), for the ground truth.
    pub fn last_slip(&self) -> f64 {
        0.0
    }
}
