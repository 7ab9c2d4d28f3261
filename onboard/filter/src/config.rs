//! Filter tuning.

use hal::asl::ImuNoiseDensities;

/// Correlation time over which [`FilterConfig::gyro_scale_sigma`] acts as rate noise.
pub const GYRO_SCALE_CORRELATION_S: f64 = 1.0;

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

impl ImuNoise {
    /// Every density multiplied by `factor` (real filters often inflate datasheet or Kalibr
    /// values to cover vibration, temperature and model errors; say so when you do).
    pub fn scaled(&self, factor: f64) -> ImuNoise {
        ImuNoise {
            gyro_noise_density: self.gyro_noise_density * factor,
            gyro_random_walk: self.gyro_random_walk * factor,
            accel_noise_density: self.accel_noise_density * factor,
            accel_random_walk: self.accel_random_walk * factor,
        }
    }
}

impl From<ImuNoiseDensities> for ImuNoise {
    fn from(d: ImuNoiseDensities) -> Self {
        ImuNoise {
            gyro_noise_density: d.gyroscope_noise_density,
            gyro_random_walk: d.gyroscope_random_walk,
            accel_noise_density: d.accelerometer_noise_density,
            accel_random_walk: d.accelerometer_random_walk,
        }
    }
}

/// One-sigma uncertainty of the initial state.
///
/// Position and yaw define the first local frame, so [`crate::Filter::initialize_at_rest`] sets
/// them exactly (zero variance) whatever these say; [`crate::Filter::initialize_with_pose`] uses
/// `position_m` and `yaw_rad`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InitialSigmas {
    pub position_m: f64,
    pub velocity_mps: f64,
    /// Roll and pitch (levelling from the accelerometer: its bias over gravity, ~0.1–0.5°).
    pub roll_pitch_rad: f64,
    pub yaw_rad: f64,
    pub accel_bias_mps2: f64,
    pub gyro_bias_radps: f64,
}

impl Default for InitialSigmas {
    fn default() -> Self {
        InitialSigmas {
            position_m: 0.0,
            velocity_mps: 0.01,
            roll_pitch_rad: 0.5_f64.to_radians(),
            yaw_rad: 0.0,
            // A MEMS accelerometer's turn-on bias after factory calibration: a few mg.
            accel_bias_mps2: 0.05,
            // Residual after averaging the rate at rest; 0.1 °/s is a typical MEMS turn-on bias.
            gyro_bias_radps: 0.1_f64.to_radians(),
        }
    }
}

/// Everything the filter needs to know besides the measurements.
#[derive(Debug, Clone, PartialEq)]
pub struct FilterConfig {
    pub imu: ImuNoise,
    /// Magnitude of gravity at the site (Moon 1.62, Mars 3.721, Earth 9.80665 m/s²).
    pub gravity_mps2: f64,
    /// Nominal IMU rate; only used to turn the gyro noise density into the per-sample sigma of the
    /// zero-rate part of a zero-velocity update.
    pub imu_rate_hz: f64,
    pub initial: InitialSigmas,
    /// Most clones held at once (keyframes plus pending frames); the oldest pending clone (else
    /// the oldest keyframe) is marginalized to make room.
    pub max_clones: usize,
    /// Most keyframe clones held (the odometry keeps 5 keyframes, thesis §4.1.1; one more covers
    /// the keyframe that is being made while the oldest is still referenced).
    pub max_keyframe_clones: usize,
    /// A pending (non-keyframe) clone older than this, relative to the newest state, is dropped:
    /// its measurement is not coming any more.
    pub max_pending_clone_age_ns: u64,
    /// `clone_at` accepts a capture stamp this far before the state stamp (the IMU sample of the
    /// same instant may already have been integrated) and extrapolates back to it.
    pub max_clone_lag_ns: u64,
    /// Chi-square gate probability (e.g. 0.999 → 22.46 for 6 DoF).
    pub gate_probability: f64,
    /// Relative gyro scale and axis-misalignment error (1σ, dimensionless). White noise and bias
    /// do not cover it: a 0.5 % scale error turns a 90° turn into a 0.45° attitude error, far
    /// above the white noise of the same second. It enters the process noise as extra rate noise
    /// of density `σ·|ω|·√τ` with τ = [`GYRO_SCALE_CORRELATION_S`] (one update interval: the
    /// error is systematic over a turn and decorrelates as turns change). Zero for a perfect
    /// scale (the simulator's IMU).
    pub gyro_scale_sigma: f64,
    /// Floor for the wheel odometry's own velocity sigmas (slip is not in them).
    pub wheel_min_sigma_mps: f64,
    /// Correlation time of the wheel odometry's error. Slip follows the soil and the grade, so
    /// consecutive samples share most of their error: treated as independent, a 50 Hz stream
    /// would average the slip away and be trusted √(τ·f) times too much. Each sample's variance is
    /// scaled by `τ / Δt` (Δt since the previous sample), so the odometry adds the information of
    /// one independent sample per `τ`. Zero treats the samples as independent.
    pub wheel_error_correlation_s: f64,
    /// Sigma of the zero-velocity pseudo-measurement (vibration of a standing rover).
    pub zupt_velocity_sigma_mps: f64,
    /// Sigma of the zero-rate part of a zero-velocity update (one gyro sample); `None` derives it
    /// from the gyro noise density at `imu_rate_hz`. Set it on platforms that vibrate at rest.
    pub zupt_rate_sigma_radps: Option<f64>,
    /// Variance given to roll and pitch of the frame-switch transform: they are exactly zero by
    /// construction, but a strictly positive variance keeps the graph factor full rank.
    pub switch_roll_pitch_variance_rad2: f64,
}

impl FilterConfig {
    /// Defaults for everything but the IMU noise and the site's gravity.
    pub fn from_imu_noise(imu: ImuNoise, gravity_mps2: f64) -> FilterConfig {
        FilterConfig {
            imu,
            gravity_mps2,
            imu_rate_hz: 200.0,
            initial: InitialSigmas::default(),
            max_clones: 16,
            max_keyframe_clones: 6,
            max_pending_clone_age_ns: 2_000_000_000,
            max_clone_lag_ns: 20_000_000,
            gate_probability: 0.999,
            gyro_scale_sigma: 0.0,
            wheel_min_sigma_mps: 0.01,
            wheel_error_correlation_s: 1.0,
            zupt_velocity_sigma_mps: 0.005,
            zupt_rate_sigma_radps: None,
            // (1e-6 rad)²: far below any real roll/pitch uncertainty, far above round-off.
            switch_roll_pitch_variance_rad2: 1e-12,
        }
    }
}

impl Default for FilterConfig {
    /// An Xsens MTi-10-class IMU (the thesis's rovers, §7.1) on the Moon.
    fn default() -> Self {
        let imu = ImuNoise {
            gyro_noise_density: 0.03_f64.to_radians(),
            gyro_random_walk: 2e-5,
            accel_noise_density: 60e-6 * 9.80665,
            accel_random_walk: 1e-5,
        };
        // The MTi-10's factory calibration leaves ~0.1 % of scale and misalignment error.
        FilterConfig { gyro_scale_sigma: 0.001, ..FilterConfig::from_imu_noise(imu, 1.62) }
    }
}
