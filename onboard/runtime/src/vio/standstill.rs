//! Standstill detection for zero-velocity updates.
//!
//! An IMU alone cannot tell standing from driving straight at constant speed on smooth ground
//! (both give gravity and no rotation), so a quiet IMU only counts as standing when a velocity
//! source agrees: the wheel odometry when the robot has it, else the stereo odometry's speed.
//! A false standstill is far worse than a missed one (it pins a moving filter), hence both tests.

use std::collections::VecDeque;

use hal::sensor::ImuSample;
use nalgebra::Vector3;

/// Thresholds of the detector.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StandstillConfig {
    /// IMU samples over which the variance is taken.
    pub window: usize,
    /// Largest gyro standard deviation (per axis, rad/s). No test on the mean rate: real gyro
    /// biases (EuRoC's ADIS: up to 0.08 rad/s) are larger than slow turns.
    pub gyro_sigma_radps: f64,
    /// Largest accelerometer standard deviation (per axis, m/s²).
    pub accel_sigma_mps2: f64,
    /// Largest speed the velocity source may report (m/s).
    pub speed_mps: f64,
    /// A velocity report older than this is not trusted.
    pub velocity_max_age_ns: u64,
}

impl Default for StandstillConfig {
    fn default() -> Self {
        // Consumer MEMS IMUs at 200 Hz have a per-sample gyro noise of a few mrad/s and an
        // accelerometer noise of a few cm/s²; vibrations of a driving rover are far above both.
        StandstillConfig {
            window: 40,
            gyro_sigma_radps: 0.01,
            accel_sigma_mps2: 0.08,
            speed_mps: 0.01,
            velocity_max_age_ns: 300_000_000,
        }
    }
}

/// Sliding-window standstill detector.
#[derive(Debug)]
pub struct StandstillDetector {
    config: StandstillConfig,
    window: VecDeque<(Vector3<f64>, Vector3<f64>)>,
    /// Latest speed report and its stamp.
    speed: Option<(u64, f64)>,
}

impl StandstillDetector {
    pub fn new(config: StandstillConfig) -> Self {
        StandstillDetector { config, window: VecDeque::with_capacity(config.window + 1), speed: None }
    }

    pub fn push_imu(&mut self, sample: &ImuSample) {
        if self.window.len() == self.config.window {
            self.window.pop_front();
        }
        self.window.push_back((sample.gyro_radps, sample.accel_mps2));
    }

    /// A speed measurement (wheel odometry or stereo odometry) at `stamp_ns`.
    pub fn push_speed(&mut self, stamp_ns: u64, speed_mps: f64) {
        self.speed = Some((stamp_ns, speed_mps));
    }

    /// True when the IMU is quiet and the latest speed is near zero and recent.
    pub fn is_standing(&self, now_ns: u64) -> bool {
        let Some((stamp_ns, speed)) = self.speed else {
            return false;
        };
        if now_ns.saturating_sub(stamp_ns) > self.config.velocity_max_age_ns || speed.abs() > self.config.speed_mps {
            return false;
        }
        if self.window.len() < self.config.window {
            return false;
        }
        let n = self.window.len() as f64;
        let (mut gyro_mean, mut accel_mean) = (Vector3::zeros(), Vector3::zeros());
        for (g, a) in &self.window {
            gyro_mean += g;
            accel_mean += a;
        }
        gyro_mean /= n;
        accel_mean /= n;
        let (mut gyro_var, mut accel_var) = (Vector3::<f64>::zeros(), Vector3::<f64>::zeros());
        for (g, a) in &self.window {
            gyro_var += (g - gyro_mean).component_mul(&(g - gyro_mean));
            accel_var += (a - accel_mean).component_mul(&(a - accel_mean));
        }
        let gyro_sigma = (gyro_var.max() / n).sqrt();
        let accel_sigma = (accel_var.max() / n).sqrt();
        gyro_sigma <= self.config.gyro_sigma_radps && accel_sigma <= self.config.accel_sigma_mps2
    }
}
