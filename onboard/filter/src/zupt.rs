//! Standstill detection for zero-velocity updates.
//!
//! The IMU test looks at the spread (standard deviation per axis, largest axis) of the gyro and the
//! accelerometer over a sliding window: at rest both show only sensor noise, while driving adds
//! vibration and changing rates. Spreads rather than magnitudes make the test independent of the
//! biases and of the tilt. When wheel odometry is fed, a recent wheel speed above its threshold
//! vetoes standstill (and a recent zero speed is required).

use crate::config::ImuNoise;
use hal::sensor::{ImuSample, WheelOdomSample};
use nalgebra::Vector3;

/// Thresholds of the [`StandstillDetector`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StandstillConfig {
    /// Window length in IMU samples.
    pub window: usize,
    /// Largest per-axis standard deviation of the gyro over the window.
    pub gyro_std_max_radps: f64,
    /// Largest per-axis standard deviation of the accelerometer over the window.
    pub accel_std_max_mps2: f64,
    /// Largest wheel speed (norm of the linear velocity) counted as standing.
    pub wheel_speed_max_mps: f64,
    /// Wheel samples older than this (relative to the latest IMU sample) are ignored.
    pub wheel_timeout_ns: u64,
}

impl StandstillConfig {
    /// Thresholds at `factor` times the white-noise sigma per sample at `rate_hz` (the sample
    /// standard deviation of pure noise over a 0.25 s window stays within ~1.2σ), with floors for
    /// real sensors whose noise exceeds their datasheet.
    pub fn from_imu_noise(noise: &ImuNoise, rate_hz: f64, factor: f64) -> StandstillConfig {
        let sqrt_rate = rate_hz.max(1.0).sqrt();
        StandstillConfig {
            window: (0.25 * rate_hz).round().max(8.0) as usize,
            gyro_std_max_radps: (factor * noise.gyro_noise_density * sqrt_rate).max(2e-3),
            accel_std_max_mps2: (factor * noise.accel_noise_density * sqrt_rate).max(1e-2),
            wheel_speed_max_mps: 0.005,
            wheel_timeout_ns: 200_000_000,
        }
    }
}

/// Sliding-window standstill detector; feed it every IMU (and wheel) sample.
#[derive(Debug, Clone)]
pub struct StandstillDetector {
    config: StandstillConfig,
    gyro: Vec<Vector3<f64>>,
    accel: Vec<Vector3<f64>>,
    next: usize,
    filled: usize,
    last_imu_ns: u64,
    last_wheel: Option<(u64, f64)>,
}

impl StandstillDetector {
    pub fn new(config: StandstillConfig) -> StandstillDetector {
        let window = config.window.max(2);
        StandstillDetector {
            config: StandstillConfig { window, ..config },
            gyro: vec![Vector3::zeros(); window],
            accel: vec![Vector3::zeros(); window],
            next: 0,
            filled: 0,
            last_imu_ns: 0,
            last_wheel: None,
        }
    }

    pub fn config(&self) -> &StandstillConfig {
        &self.config
    }

    pub fn push_imu(&mut self, imu: &ImuSample) {
        self.gyro[self.next] = imu.gyro_radps;
        self.accel[self.next] = imu.accel_mps2;
        self.next = (self.next + 1) % self.config.window;
        self.filled = (self.filled + 1).min(self.config.window);
        self.last_imu_ns = imu.stamp_ns;
    }

    pub fn push_wheel(&mut self, wheel: &WheelOdomSample) {
        self.last_wheel = Some((wheel.stamp_ns, wheel.linear_mps.norm()));
    }

    /// Largest per-axis standard deviations `(gyro, accel)` over the window (`None` until full).
    pub fn spreads(&self) -> Option<(f64, f64)> {
        if self.filled < self.config.window {
            return None;
        }
        Some((max_axis_std(&self.gyro), max_axis_std(&self.accel)))
    }

    /// Whether the body stands still now.
    pub fn is_standing(&self) -> bool {
        let Some((gyro_std, accel_std)) = self.spreads() else {
            return false;
        };
        let imu_still = gyro_std <= self.config.gyro_std_max_radps && accel_std <= self.config.accel_std_max_mps2;
        let wheel_still = match self.last_wheel {
            Some((stamp, speed)) if self.last_imu_ns.saturating_sub(stamp) <= self.config.wheel_timeout_ns => {
                speed <= self.config.wheel_speed_max_mps
            }
            _ => true,
        };
        imu_still && wheel_still
    }
}

fn max_axis_std(values: &[Vector3<f64>]) -> f64 {
    let n = values.len() as f64;
    let mean = values.iter().fold(Vector3::zeros(), |acc, v| acc + v) / n;
    let var = values.iter().fold(Vector3::zeros(), |acc, v| {
        let d = v - mean;
        acc + d.component_mul(&d)
    }) / (n - 1.0).max(1.0);
    var.max().sqrt()
}
