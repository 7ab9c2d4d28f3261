//! Standstill detection for zero-velocity updates.
//!
//! The IMU test looks at the spread (standard deviation per axis, largest axis) of the gyro and the
//! accelerometer over a sliding window: at rest both show only sensor noise, while driving adds
//! vibration and changing rates. Spreads rather than magnitudes make the test independent of the
//! biases (EuRoC's ADIS gyro: up to 0.08 rad/s, more than a slow turn) and of the tilt.
//!
//! An IMU alone cannot tell standing from driving straight at constant speed on smooth ground
//! (both give gravity and no rotation), so a velocity source — wheel odometry, or the stereo
//! odometry's speed on a robot without wheels — must agree: a recent speed above its threshold
//! vetoes standstill, and with [`StandstillConfig::require_speed`] a recent near-zero speed is
//! required. A false standstill is far worse than a missed one: it pins a moving filter.

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
    /// Largest reported speed (norm of the linear velocity) counted as standing.
    pub speed_max_mps: f64,
    /// Speed reports older than this (relative to the latest IMU sample) are ignored.
    pub speed_timeout_ns: u64,
    /// Without a recent speed report, report moving (true) or trust the IMU alone (false).
    pub require_speed: bool,
}

impl Default for StandstillConfig {
    /// A rover's detector: consumer MEMS IMUs at 200 Hz have a per-sample gyro noise of a few
    /// mrad/s and an accelerometer noise of a few cm/s², the vibration of a driving rover is far
    /// above both; a speed report is required.
    fn default() -> Self {
        StandstillConfig {
            window: 40,
            gyro_std_max_radps: 0.01,
            accel_std_max_mps2: 0.08,
            speed_max_mps: 0.01,
            speed_timeout_ns: 300_000_000,
            require_speed: true,
        }
    }
}

impl StandstillConfig {
    /// Thresholds at `factor` times the white-noise sigma per sample at `rate_hz` (the sample
    /// standard deviation of pure noise over a 0.25 s window stays within ~1.2σ), with floors for
    /// real sensors whose noise exceeds their datasheet. The IMU alone decides when no speed
    /// report comes.
    pub fn from_imu_noise(noise: &ImuNoise, rate_hz: f64, factor: f64) -> StandstillConfig {
        let sqrt_rate = rate_hz.max(1.0).sqrt();
        StandstillConfig {
            window: (0.25 * rate_hz).round().max(8.0) as usize,
            gyro_std_max_radps: (factor * noise.gyro_noise_density * sqrt_rate).max(2e-3),
            accel_std_max_mps2: (factor * noise.accel_noise_density * sqrt_rate).max(1e-2),
            speed_max_mps: 0.005,
            speed_timeout_ns: 200_000_000,
            require_speed: false,
        }
    }
}

/// Sliding-window standstill detector; feed it every IMU sample and every speed report.
#[derive(Debug, Clone)]
pub struct StandstillDetector {
    config: StandstillConfig,
    gyro: Vec<Vector3<f64>>,
    accel: Vec<Vector3<f64>>,
    next: usize,
    filled: usize,
    last_imu_ns: u64,
    last_speed: Option<(u64, f64)>,
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
            last_speed: None,
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

    /// A speed measurement (wheel or stereo odometry) at `stamp_ns`.
    pub fn push_speed(&mut self, stamp_ns: u64, speed_mps: f64) {
        self.last_speed = Some((stamp_ns, speed_mps.abs()));
    }

    pub fn push_wheel(&mut self, wheel: &WheelOdomSample) {
        self.push_speed(wheel.stamp_ns, wheel.linear_mps.norm());
    }

    /// Largest per-axis standard deviations `(gyro, accel)` over the window (`None` until full).
    pub fn spreads(&self) -> Option<(f64, f64)> {
        if self.filled < self.config.window {
            return None;
        }
        Some((max_axis_std(&self.gyro), max_axis_std(&self.accel)))
    }

    /// Whether the body stands still at the latest IMU sample.
    pub fn is_standing(&self) -> bool {
        let Some((gyro_std, accel_std)) = self.spreads() else {
            return false;
        };
        let imu_still = gyro_std <= self.config.gyro_std_max_radps && accel_std <= self.config.accel_std_max_mps2;
        let speed_still = match self.last_speed {
            Some((stamp, speed)) if self.last_imu_ns.saturating_sub(stamp) <= self.config.speed_timeout_ns => {
                speed <= self.config.speed_max_mps
            }
            _ => !self.config.require_speed,
        };
        imu_still && speed_still
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

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    fn imu(stamp_ns: u64, gyro_z: f64) -> ImuSample {
        ImuSample { stamp_ns, gyro_radps: Vector3::new(0.0, 0.0, gyro_z), accel_mps2: Vector3::new(0.0, 0.0, 9.81) }
    }

    fn quiet(detector: &mut StandstillDetector, from_ns: u64) -> u64 {
        let mut stamp = from_ns;
        for k in 0..detector.config().window {
            // Bias-like constant rate with tiny noise: quiet.
            detector.push_imu(&imu(stamp, 0.05 + 1e-4 * (k % 3) as f64));
            stamp += 5_000_000;
        }
        stamp
    }

    #[test]
    fn quiet_imu_needs_a_recent_zero_speed_when_required() {
        let mut detector = StandstillDetector::new(StandstillConfig::default());
        let now = quiet(&mut detector, 0);
        assert!(!detector.is_standing(), "no speed report yet");
        detector.push_speed(now - 50_000_000, 0.002);
        assert!(detector.is_standing());
        detector.push_speed(now, 0.3);
        assert!(!detector.is_standing(), "the wheels turn");
        detector.push_speed(now - 5_000_000, 0.0);
        quiet(&mut detector, now + 400_000_000);
        assert!(!detector.is_standing(), "the zero-speed report is stale");
    }

    #[test]
    fn imu_alone_decides_when_speed_is_optional() {
        let config = StandstillConfig { require_speed: false, ..StandstillConfig::default() };
        let mut detector = StandstillDetector::new(config);
        let now = quiet(&mut detector, 0);
        assert!(detector.is_standing());
        // Vibration of a driving rover.
        for k in 0..config.window as u64 {
            detector.push_imu(&imu(now + k * 5_000_000, if k % 2 == 0 { 0.1 } else { -0.1 }));
        }
        assert!(!detector.is_standing());
    }
}
