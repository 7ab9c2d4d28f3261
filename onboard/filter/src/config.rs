//! Filter tuning.

/// Continuous-time IMU noise (the densities of a datasheet or EuRoC's `imu0/sensor.yaml`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuNoise {
    /// rad/s/√Hz
    pub gyro_noise_density: f64,
    /// rad/s²/√Hz
    pub gyro_random_walk: f64,
    /// m/s²/√Hz
    pub accel_noise_density: f64,
    /// m/s³/√Hz
    pub accel_random_walk: f64,
}

/// Everything the filter needs to know besides the measurements.
#[derive(Debug, Clone, PartialEq)]
pub struct FilterConfig {
    pub imu: ImuNoise,
    /// Magnitude of gravity at the site (Moon 1.62, Mars 3.721, Earth 9.80665 m/s²).
    pub gravity_mps2: f64,
}
