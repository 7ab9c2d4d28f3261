//! Where a robot's sensor data comes from, and what the processes must know about the sensors.
//!
//! The driver process runs one [`SensorSource`] chosen by `driver.kind`:
//! - `replay`: a recorded dataset (EuRoC/ASL or KITTI, [`hal::replay`]), in the firmware;
//! - `sim`: the software-in-the-loop simulator. The firmware does not contain it: the `sil`
//!   harness runs these same processes with its own [`SourceProvider`] that knows the simulator
//!   (the way copper-rs injects simulated sources at the source task);
//! - `devices`: the rover's IMU over serial and wheels and head over CANopen ([`devices`]), a
//!   live source; the cameras publish on the bus themselves.
//!
//! Every other process needs only the [`SensorSetup`]: the stereo calibration of the images the
//! driver publishes and the IMU's noise model. It comes from the configuration
//! (`[camera.calibration]`, `[imu.noise]`) or, for a replay, from the dataset's own files, never
//! from the simulator.

use filter::config::ImuNoise;
use hal::replay::{self, Dataset};
use hal::sensor::{SensorSource, StereoCalibration};

use crate::config::{DriverKind, RoverConfig};

pub mod devices;

/// Why the sensors could not be set up.
#[derive(Debug, thiserror::Error)]
pub enum SensorSetupError {
    #[error(
        "driver.kind = \"sim\": the simulator is not part of the firmware; run this rover through the `sil` harness (`sil run --config FILE`)"
    )]
    SimNotAvailable,
    #[error("replay {path}: {source}")]
    Replay { path: String, source: hal::sensor::SensorError },
    #[error("{0}")]
    Invalid(String),
}

/// Opens the robot's sensor source for the driver process.
pub trait SourceProvider {
    fn open(&self, config: &RoverConfig) -> Result<Box<dyn SensorSource + Send>, SensorSetupError>;
}

/// The firmware's own sources: dataset replay. `driver.kind = "sim"` is refused with a pointer
/// to the harness.
#[derive(Debug, Clone, Copy, Default)]
pub struct FirmwareSources;

impl SourceProvider for FirmwareSources {
    fn open(&self, config: &RoverConfig) -> Result<Box<dyn SensorSource + Send>, SensorSetupError> {
        match config.driver.kind {
            DriverKind::Sim => Err(SensorSetupError::SimNotAvailable),
            DriverKind::Replay => Ok(Box::new(open_replay(config)?.source)),
            DriverKind::Devices => {
                let devices = config
                    .driver
                    .devices
                    .as_ref()
                    .ok_or_else(|| SensorSetupError::Invalid("driver.devices is not set".into()))?;
                Ok(Box::new(devices::DevicesSource::open(devices, config.rates.imu_hz)?))
            }
        }
    }
}

/// The dataset of a replay configuration.
pub fn open_replay(config: &RoverConfig) -> Result<Dataset, SensorSetupError> {
    let path = config
        .driver
        .replay_path
        .as_ref()
        .ok_or_else(|| SensorSetupError::Invalid("driver.replay_path is not set".into()))?;
    replay::open_dataset(path).map_err(|source| SensorSetupError::Replay { path: path.display().to_string(), source })
}

/// What the processes need to know about the sensors.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorSetup {
    /// Calibration of the pairs as the driver publishes them (raw or rectified).
    pub calibration: StereoCalibration,
    /// The IMU's continuous-time noise densities.
    pub imu_noise: ImuNoise,
    /// The source has IMU data (a replayed dataset may have none).
    pub has_imu: bool,
}

/// The EuRoC ADIS16448 densities (`imu0/sensor.yaml` of EuRoC), used when neither the
/// configuration nor the dataset gives any.
pub const EUROC_IMU_NOISE: ImuNoise = ImuNoise {
    gyro_noise_density: 1.6968e-4,
    gyro_random_walk: 1.9393e-5,
    accel_noise_density: 2.0e-3,
    accel_random_walk: 3.0e-3,
};

/// The sensor setup of `config`: the configuration's calibration and IMU noise where it gives
/// them, else the replayed dataset's, else (IMU noise only) [`EUROC_IMU_NOISE`].
pub fn sensor_setup(config: &RoverConfig) -> Result<SensorSetup, SensorSetupError> {
    let configured = config
        .camera
        .calibration
        .as_ref()
        .map(|c| c.to_calibration().map_err(|e| SensorSetupError::Invalid(format!("camera.calibration: {e}"))))
        .transpose()?;
    let configured_noise = config.imu.noise.map(|n| n.noise());
    match config.driver.kind {
        DriverKind::Sim | DriverKind::Devices => {
            let calibration = configured.ok_or_else(|| {
                SensorSetupError::Invalid("camera.calibration is required with a simulated driver or devices".into())
            })?;
            Ok(SensorSetup { calibration, imu_noise: configured_noise.unwrap_or(EUROC_IMU_NOISE), has_imu: true })
        }
        DriverKind::Replay => {
            let dataset = open_replay(config)?;
            Ok(SensorSetup {
                calibration: configured.unwrap_or(dataset.calibration),
                imu_noise: configured_noise.or(dataset.imu_noise.map(ImuNoise::from)).unwrap_or(EUROC_IMU_NOISE),
                has_imu: dataset.imu_samples > 0,
            })
        }
    }
}
