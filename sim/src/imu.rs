//! IMU model: exact specific force and angular rate from the trajectory, plus white noise and
//! bias random walk (owned by the IMU helper). The Allan deviation that checks it is in
//! [`crate::allan`].
//!
//! Discretisation follows Kalibr's IMU noise model: at rate `f`, each sample gets white noise of
//! standard deviation `σ_c·√f`, and each bias takes one random-walk step of `σ_b·√(1/f)` per period.

use hal::sensor::ImuSample;
use nalgebra::Vector3;

use crate::rng::{self, Rng, streams};
use crate::trajectory::KinematicState;

/// Continuous-time noise parameters (Kalibr/EuRoC conventions and units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuNoise {
    pub gyro_noise_density_radps_rthz: f64,
    pub gyro_bias_rw_radps2_rthz: f64,
    pub accel_noise_density_mps2_rthz: f64,
    pub accel_bias_rw_mps3_rthz: f64,
    /// Standard deviation of the turn-on biases.
    pub gyro_bias_init_radps: f64,
    pub accel_bias_init_mps2: f64,
}

impl ImuNoise {
    /// The four Kalibr densities, as a dataset's `imu0/sensor.yaml` states them (what a filter is
    /// tuned with; the turn-on biases are not among them).
    pub fn densities(&self, rate_hz: f64) -> hal::asl::ImuNoiseDensities {
        hal::asl::ImuNoiseDensities {
            gyroscope_noise_density: self.gyro_noise_density_radps_rthz,
            gyroscope_random_walk: self.gyro_bias_rw_radps2_rthz,
            accelerometer_noise_density: self.accel_noise_density_mps2_rthz,
            accelerometer_random_walk: self.accel_bias_rw_mps3_rthz,
            rate_hz: Some(rate_hz),
        }
    }
}

/// Standard gravity, for converting datasheet µg.
const G0_MPS2: f64 = 9.806_65;

/// A bias random-walk density from a datasheet's in-run bias stability `b` and white-noise density
/// `n` (same units per second).
///
/// Kalibr's model has no flicker (bias-instability) term, so the flat floor of the real Allan
/// curve is stood in for by a random walk chosen such that the model's Allan curve,
/// `σ²(τ) = n²/τ + k²·τ/3`, has its minimum (`2·n·k/√3`, at `τ = √3·n/k`) equal to `b`:
/// `k = √3·b²/(2·n)`. This is approximate: it matches the floor's depth, not its flatness, so the
/// model over-states drift well beyond that τ and under-states it just below.
pub fn bias_rw_from_stability(bias_stability: f64, noise_density: f64) -> f64 {
    if noise_density <= 0.0 {
        return 0.0;
    }
    3.0_f64.sqrt() * bias_stability * bias_stability / (2.0 * noise_density)
}

impl ImuNoise {
    /// Datasheet-like values of an Xsens MTi-10 (the thesis's rovers, §7.1).
    ///
    /// Xsens "MTi 10-series" leaflet (5th generation, same sensor figures in the MTi user manual
    /// MT0605P): gyroscope noise density 0.03 °/s/√Hz, in-run bias stability 18 °/h; accelerometer
    /// noise density 60 µg/√Hz, in-run bias stability 15 µg. (Earlier MTi-10 leaflets list the
    /// accelerometer at 80 µg/√Hz and 40 µg; the gyroscope figures are unchanged.) The bias
    /// random walks follow [`bias_rw_from_stability`], which is an approximation.
    ///
    /// The leaflet gives no turn-on bias after factory calibration; 0.1 °/s and 2 mg are our
    /// choice of a residual small enough for a filter to estimate within seconds at standstill.
    pub fn xsens_mti10() -> Self {
        let gyro_noise_density_radps_rthz = 0.03_f64.to_radians();
        let gyro_bias_stability_radps = (18.0_f64 / 3600.0).to_radians();
        let accel_noise_density_mps2_rthz = 60e-6 * G0_MPS2;
        let accel_bias_stability_mps2 = 15e-6 * G0_MPS2;
        ImuNoise {
            gyro_noise_density_radps_rthz,
            gyro_bias_rw_radps2_rthz: bias_rw_from_stability(gyro_bias_stability_radps, gyro_noise_density_radps_rthz),
            accel_noise_density_mps2_rthz,
            accel_bias_rw_mps3_rthz: bias_rw_from_stability(accel_bias_stability_mps2, accel_noise_density_mps2_rthz),
            gyro_bias_init_radps: 0.1_f64.to_radians(),
            accel_bias_init_mps2: 2e-3 * G0_MPS2,
        }
    }

    /// No noise and no bias: samples are the exact kinematics.
    pub fn noise_free() -> Self {
        ImuNoise {
            gyro_noise_density_radps_rthz: 0.0,
            gyro_bias_rw_radps2_rthz: 0.0,
            accel_noise_density_mps2_rthz: 0.0,
            accel_bias_rw_mps3_rthz: 0.0,
            gyro_bias_init_radps: 0.0,
            accel_bias_init_mps2: 0.0,
        }
    }

    /// Per-sample standard deviations at `rate_hz`, Kalibr's discretisation.
    pub fn discrete(&self, rate_hz: f64) -> DiscreteImuNoise {
        let sqrt_rate = rate_hz.sqrt();
        DiscreteImuNoise {
            gyro_white_radps: self.gyro_noise_density_radps_rthz * sqrt_rate,
            accel_white_mps2: self.accel_noise_density_mps2_rthz * sqrt_rate,
            gyro_bias_step_radps: self.gyro_bias_rw_radps2_rthz / sqrt_rate,
            accel_bias_step_mps2: self.accel_bias_rw_mps3_rthz / sqrt_rate,
        }
    }
}

/// [`ImuNoise`] as per-sample standard deviations at one rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DiscreteImuNoise {
    /// White noise added to each sample.
    pub gyro_white_radps: f64,
    pub accel_white_mps2: f64,
    /// One step of the bias random walk per sample period.
    pub gyro_bias_step_radps: f64,
    pub accel_bias_step_mps2: f64,
}

/// Sub-streams of one IMU's seed, so that e.g. switching the bias walk off leaves the white noise
/// sequence unchanged.
mod substream {
    pub const TURN_ON: u64 = 0;
    pub const WHITE: u64 = 1;
    pub const BIAS_WALK: u64 = 2;
}

/// Generates IMU samples at a fixed rate for one robot.
#[derive(Debug, Clone)]
pub struct ImuSimulator {
    noise: ImuNoise,
    gravity_world_mps2: Vector3<f64>,
    rate_hz: f64,
    gyro_bias_radps: Vector3<f64>,
    accel_bias_mps2: Vector3<f64>,
    discrete: DiscreteImuNoise,
    white_rng: Rng,
    walk_rng: Rng,
    /// Whether a sample was drawn yet (the first one carries the turn-on biases unchanged).
    started: bool,
}

impl ImuSimulator {
    /// `seed` keys this IMU's noise stream.
    pub fn new(noise: ImuNoise, gravity_world_mps2: Vector3<f64>, rate_hz: f64, seed: u64) -> Self {
        let mut turn_on = rng::stream(seed, &[streams::IMU, substream::TURN_ON]);
        let gyro_bias_radps = turn_on.normal3() * noise.gyro_bias_init_radps;
        let accel_bias_mps2 = turn_on.normal3() * noise.accel_bias_init_mps2;
        ImuSimulator {
            noise,
            gravity_world_mps2,
            rate_hz,
            gyro_bias_radps,
            accel_bias_mps2,
            discrete: noise.discrete(rate_hz),
            white_rng: rng::stream(seed, &[streams::IMU, substream::WHITE]),
            walk_rng: rng::stream(seed, &[streams::IMU, substream::BIAS_WALK]),
            started: false,
        }
    }

    pub fn noise(&self) -> &ImuNoise {
        &self.noise
    }

    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    pub fn gravity_world_mps2(&self) -> Vector3<f64> {
        self.gravity_world_mps2
    }

    /// The exact (noise- and bias-free) angular rate and specific force for `state`.
    pub fn ideal(&self, state: &KinematicState) -> (Vector3<f64>, Vector3<f64>) {
        let f_world = state.a_world_mps2 - self.gravity_world_mps2;
        (state.omega_body_radps, state.t_world_body.rotation.inverse_transform_vector(&f_world))
    }

    /// The sample at `stamp_ns` for the body state `state`; advances the bias random walk by one
    /// period. Call once per period, in order.
    ///
    /// The walk steps before every sample but the first, so the first sample carries the turn-on
    /// biases and [`Self::biases`] after a call is exactly the bias inside that call's sample.
    pub fn sample(&mut self, state: &KinematicState, stamp_ns: u64) -> ImuSample {
        let d = self.discrete;
        if self.started {
            self.gyro_bias_radps += self.walk_rng.normal3() * d.gyro_bias_step_radps;
            self.accel_bias_mps2 += self.walk_rng.normal3() * d.accel_bias_step_mps2;
        }
        self.started = true;
        let (omega_body, f_body) = self.ideal(state);
        let gyro_radps = omega_body + self.gyro_bias_radps + self.white_rng.normal3() * d.gyro_white_radps;
        let accel_mps2 = f_body + self.accel_bias_mps2 + self.white_rng.normal3() * d.accel_white_mps2;
        ImuSample { stamp_ns, gyro_radps, accel_mps2 }
    }

    /// True biases (gyro, accel) of the latest sample (before the first: of the first), for the
    /// ground truth.
    pub fn biases(&self) -> (Vector3<f64>, Vector3<f64>) {
        (self.gyro_bias_radps, self.accel_bias_mps2)
    }
}
