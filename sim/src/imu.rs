//! IMU model: exact specific force and angular rate from the trajectory, plus white noise and
//! bias random walk (owned by the IMU helper). Also the Allan deviation used to check it.

use hal::sensor::ImuSample;
use nalgebra::Vector3;

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
    /// Datasheet-like values of an Xsens MTi-10 (the thesis's rovers, §7.1).
    pub fn xsens_mti10() -> Self {
        ImuNoise {
            gyro_noise_density_radps_rthz: 0.0,
            gyro_bias_rw_radps2_rthz: 0.0,
            accel_noise_density_mps2_rthz: 0.0,
            accel_bias_rw_mps3_rthz: 0.0,
            gyro_bias_init_radps: 0.0,
            accel_bias_init_mps2: 0.0,
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
}

/// Generates IMU samples at a fixed rate for one robot.
#[derive(Debug, Clone)]
pub struct ImuSimulator {
    noise: ImuNoise,
    gravity_world_mps2: Vector3<f64>,
    rate_hz: f64,
    gyro_bias_radps: Vector3<f64>,
    accel_bias_mps2: Vector3<f64>,
}

impl ImuSimulator {
    /// `seed` keys this IMU's noise stream.
    pub fn new(noise: ImuNoise, gravity_world_mps2: Vector3<f64>, rate_hz: f64, seed: u64) -> Self {
        let _ = seed;
        ImuSimulator {
            noise,
            gravity_world_mps2,
            rate_hz,
            gyro_bias_radps: Vector3::zeros(),
            accel_bias_mps2: Vector3::zeros(),
        }
    }

    pub fn noise(&self) -> &ImuNoise {
        &self.noise
    }

    pub fn rate_hz(&self) -> f64 {
        self.rate_hz
    }

    /// The sample at `stamp_ns` for the body state `state`; advances the bias random walk by one
    /// period. Call once per period, in order.
    pub fn sample(&mut self, state: &KinematicState, stamp_ns: u64) -> ImuSample {
        let _ = (state, self.gravity_world_mps2);
        ImuSample { stamp_ns, gyro_radps: Vector3::zeros(), accel_mps2: Vector3::zeros() }
    }

    /// Current true biases (gyro, accel), for the ground truth.
    pub fn biases(&self) -> (Vector3<f64>, Vector3<f64>) {
        (self.gyro_bias_radps, self.accel_bias_mps2)
    }
}
