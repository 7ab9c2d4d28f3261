//! Wheel odometry with slip-dependent error (owned by the IMU helper).
//!
//! The odometry reports the body twist that wheel encoders and steering angles imply:
//! - forward speed `v_meas = v_true / (1 − s) + noise`: slipping wheels turn faster than the
//!   ground passes, so they over-read. The slip `s = base + k·uphill + r(t)` grows with the uphill
//!   grade of the driving direction; `r` is a first-order Gauss–Markov process (soil patches),
//!   and `s` is clamped to `[0, max_slip]` (downhill skid, an under-read, is not modelled);
//! - lateral speed 0: wheels roll forward and cannot sense side slip, whatever the true one is;
//! - vertical speed 0: the odometry is planar in the body frame, it has no sensor for motion
//!   along the body's z axis (suspension travel, bumps);
//! - yaw rate `ω_z·(1 + scale_error) / (1 − s) + noise`: steering geometry gives curvature, and
//!   curvature times the over-read wheel speed gives the yaw rate, so slip scales it as well;
//! - roll and pitch rates 0: wheels cannot sense them;
//! - at standstill (true twist below [`STANDSTILL_MPS`]/[`STANDSTILL_RADPS`]) encoders do not
//!   count, so the twist is exactly zero without noise: the zero-velocity information real wheel
//!   odometry gives.

use hal::sensor::WheelOdomSample;
use nalgebra::Vector3;

use crate::rng::{self, Rng, streams};
use crate::trajectory::KinematicState;

/// Below this true body speed (and [`STANDSTILL_RADPS`]) the rover stands still.
pub const STANDSTILL_MPS: f64 = 1e-6;
/// Below this true body angular rate (and [`STANDSTILL_MPS`]) the rover stands still.
pub const STANDSTILL_RADPS: f64 = 1e-6;

/// Smallest claimed standard deviation, so a filter can always invert the claimed covariance.
pub const MIN_CLAIMED_SIGMA: f64 = 1e-3;

/// Slip and noise of the wheel odometry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelOdomConfig {
    pub rate_hz: f64,
    /// Slip on level ground (ratio, 0 = none).
    pub base_slip: f64,
    /// Added slip per radian of uphill grade of the driving direction.
    pub slip_per_uphill_rad: f64,
    /// White noise on the forward speed, per sample.
    pub speed_noise_mps: f64,
    /// White noise on the yaw rate, per sample.
    pub yaw_rate_noise_radps: f64,
    /// Stationary standard deviation of the slowly varying random slip.
    pub slip_random_sigma: f64,
    /// Correlation time of the random slip.
    pub slip_correlation_s: f64,
    /// Upper clamp of the slip (keeps `1 / (1 − s)` finite).
    pub max_slip: f64,
    /// Relative over-read of the yaw rate from the steering geometry (effective wheel base error).
    pub yaw_rate_scale_error: f64,
    /// Relative speed and yaw-rate uncertainty the odometry claims for its unknown slip and scale.
    pub claimed_relative_sigma: f64,
    /// Claimed standard deviations of the unobserved components (lateral and vertical speed;
    /// roll and pitch rate): large, so a filter takes the reported zeros as uninformative.
    pub unobserved_sigma_mps: f64,
    pub unobserved_sigma_radps: f64,
}

impl Default for WheelOdomConfig {
    /// LRU-like values (our choices; the thesis gives no odometry error figures): 50 Hz platform
    /// control rate; 3 % base slip and +0.6 per radian of grade (≈ 13 % at 10°, ≈ 24 % at 20°),
    /// the order reported for rovers on loose, volcanic or lunar-analogue soil; ±2 % random slip
    /// over ~3 s (about a metre at LRU speeds); 5 mm/s speed noise and 0.005 rad/s yaw-rate noise
    /// per 50 Hz sample (encoder quantisation, wheel and terrain vibration); 3 % yaw-rate
    /// over-read from the effective geometry of four steered wheels on soft ground.
    fn default() -> Self {
        WheelOdomConfig {
            rate_hz: 50.0,
            base_slip: 0.03,
            slip_per_uphill_rad: 0.6,
            speed_noise_mps: 0.005,
            yaw_rate_noise_radps: 0.005,
            slip_random_sigma: 0.02,
            slip_correlation_s: 3.0,
            max_slip: 0.9,
            yaw_rate_scale_error: 0.03,
            claimed_relative_sigma: 0.1,
            unobserved_sigma_mps: 0.5,
            unobserved_sigma_radps: 0.5,
        }
    }
}

impl WheelOdomConfig {
    /// Exact odometry of the forward speed and yaw rate: no slip, scale error or noise.
    pub fn ideal() -> Self {
        WheelOdomConfig {
            base_slip: 0.0,
            slip_per_uphill_rad: 0.0,
            speed_noise_mps: 0.0,
            yaw_rate_noise_radps: 0.0,
            slip_random_sigma: 0.0,
            yaw_rate_scale_error: 0.0,
            ..WheelOdomConfig::default()
        }
    }
}

/// Sub-streams of one odometer's seed.
mod substream {
    pub const SLIP: u64 = 0;
    pub const NOISE: u64 = 1;
}

/// Generates wheel odometry for one rover.
#[derive(Debug, Clone)]
pub struct WheelOdometer {
    config: WheelOdomConfig,
    /// Per-sample decay of the random slip, `exp(−Δt/τ)`.
    slip_decay: f64,
    random_slip: f64,
    last_slip: f64,
    slip_rng: Rng,
    noise_rng: Rng,
}

impl WheelOdometer {
    pub fn new(config: WheelOdomConfig, seed: u64) -> Self {
        let mut slip_rng = rng::stream(seed, &[streams::WHEEL, substream::SLIP]);
        let slip_decay = if config.slip_correlation_s > 0.0 && config.rate_hz > 0.0 {
            (-1.0 / (config.rate_hz * config.slip_correlation_s)).exp()
        } else {
            0.0
        };
        // Start in the stationary distribution so the first seconds are like any others.
        let random_slip = slip_rng.normal() * config.slip_random_sigma;
        WheelOdometer {
            config,
            slip_decay,
            random_slip,
            last_slip: 0.0,
            slip_rng,
            noise_rng: rng::stream(seed, &[streams::WHEEL, substream::NOISE]),
        }
    }

    pub fn config(&self) -> &WheelOdomConfig {
        &self.config
    }

    /// The slip ratio `state` would have with the current random slip (without advancing it).
    pub fn slip_for(&self, state: &KinematicState) -> f64 {
        let c = &self.config;
        let forward_world = state.t_world_body.rotation * Vector3::x();
        let v_forward_mps = state.t_world_body.rotation.inverse_transform_vector(&state.v_world_mps).x;
        let direction = if v_forward_mps < 0.0 { -1.0 } else { 1.0 };
        let uphill_rad = (direction * forward_world.z).clamp(-1.0, 1.0).asin().max(0.0);
        (c.base_slip + c.slip_per_uphill_rad * uphill_rad + self.random_slip).clamp(0.0, c.max_slip.clamp(0.0, 0.999))
    }

    /// The odometry sample at `stamp_ns` for the true state `state`. Call once per period, in order.
    pub fn sample(&mut self, state: &KinematicState, stamp_ns: u64) -> WheelOdomSample {
        let c = self.config;
        let slip = self.slip_for(state);
        self.last_slip = slip;
        let decay = self.slip_decay;
        self.random_slip =
            decay * self.random_slip + c.slip_random_sigma * (1.0 - decay * decay).sqrt() * self.slip_rng.normal();
        // Drawn every period, moving or not, so the noise sequence does not depend on the motion.
        let speed_noise = self.noise_rng.normal() * c.speed_noise_mps;
        let yaw_noise = self.noise_rng.normal() * c.yaw_rate_noise_radps;

        let v_body_mps = state.t_world_body.rotation.inverse_transform_vector(&state.v_world_mps);
        let omega_body_radps = state.omega_body_radps;
        let standing = v_body_mps.norm() < STANDSTILL_MPS && omega_body_radps.norm() < STANDSTILL_RADPS;
        let (forward_mps, yaw_rate_radps) = if standing {
            (0.0, 0.0)
        } else {
            let over_read = 1.0 / (1.0 - slip);
            (
                v_body_mps.x * over_read + speed_noise,
                omega_body_radps.z * (1.0 + c.yaw_rate_scale_error) * over_read + yaw_noise,
            )
        };
        WheelOdomSample {
            stamp_ns,
            linear_mps: Vector3::new(forward_mps, 0.0, 0.0),
            angular_radps: Vector3::new(0.0, 0.0, yaw_rate_radps),
            sigma: [
                (c.speed_noise_mps + c.claimed_relative_sigma * forward_mps.abs()).max(MIN_CLAIMED_SIGMA),
                c.unobserved_sigma_mps.max(MIN_CLAIMED_SIGMA),
                c.unobserved_sigma_mps.max(MIN_CLAIMED_SIGMA),
                c.unobserved_sigma_radps.max(MIN_CLAIMED_SIGMA),
                c.unobserved_sigma_radps.max(MIN_CLAIMED_SIGMA),
                (c.yaw_rate_noise_radps + c.claimed_relative_sigma * yaw_rate_radps.abs()).max(MIN_CLAIMED_SIGMA),
            ],
        }
    }

    /// The slip ratio of the last sample (0 = none), for the ground truth.
    pub fn last_slip(&self) -> f64 {
        self.last_slip
    }
}
