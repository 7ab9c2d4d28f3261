//! Visual(-inertial) odometry on a recorded dataset: `onboard vio`. The dataset is replayed
//! through the rover's own nodes on the lockstep runner ([`crate::lockstep::RobotStack`]: driver,
//! vision, filter, mapper, built from the configuration as on the rover), so what it measures is
//! what the rover runs; `onboard run --config` with `driver.kind = "replay"` runs the same nodes
//! as separate processes.
//!
//! The estimate is the robot's online one, the mapper's (`estimate.tum` of a rover run): the
//! body pose at each image in the robot's first local frame, as the robot had it at that moment.
//! Stamps are the dataset's own (sensor time plus [`DatasetReport::time_offset_ns`]).
//!
//! [`VioOptions`] gathers what the vision and filter nodes take from the configuration
//! ([`crate::stack::vio_options`]).

use std::path::Path;
use std::time::Instant;

use filter::FilterConfig;
use hal::replay::DatasetKind;
use nalgebra::{Isometry3, Vector3};
use vision::VoConfig;

use crate::config::{DriverKind, RoverConfig};
use crate::lockstep::{NODE_NAMES, RobotStack, STEP_NS, StackError};
use crate::nodes::driver::DriverCounts;
use crate::nodes::filter::FilterNodeSummary;
use crate::nodes::vision::VisionNodeSummary;
use crate::sensors::{FirmwareSources, SensorSetupError, SourceProvider, sensor_setup};

pub use crate::sensors::EUROC_IMU_NOISE;

/// Which odometry results become filter updates.
///
/// The deltas of consecutive frames against one keyframe share that keyframe's triangulation
/// errors, so fusing every one as an independent measurement makes the filter overconfident (in
/// simulation: position NEES ~8× its dimension). Fusing only the keyframe-to-keyframe deltas keeps
/// the measurements nearly independent; the IMU (and wheels) bridge the frames in between.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VoUpdates {
    /// Every frame's delta to its keyframe.
    EveryFrame,
    /// Only the delta of a frame that becomes a new keyframe, relative to the previous one.
    Keyframes,
}

/// The odometry's and the filter's settings (from the configuration: [`crate::stack::vio_options`]).
#[derive(Debug, Clone, PartialEq)]
pub struct VioOptions {
    pub vo: VoConfig,
    /// Depth for the odometry from the SGM disparity map (`fpga_model`) instead of its sparse
    /// stereo matching.
    pub sgm: bool,
    /// Worker threads of the SGM matcher.
    pub sgm_threads: usize,
    /// Fuse the IMU (the full filter); `false` = stereo odometry alone.
    pub use_imu: bool,
    pub use_wheel: bool,
    /// Zero-velocity updates while standing.
    pub zupt: bool,
    /// Sensor time between an image's capture and the arrival of its VO result at the filter.
    pub latency_ns: u64,
    /// Filter tuning: IMU noise densities, gravity at the site, gates, initial sigmas.
    pub filter: FilterConfig,
    /// IMU data averaged for the at-rest initialization.
    pub init_window_ns: u64,
    /// Events after this stamp are not processed (e.g. IMU data past the last image).
    pub end_stamp_ns: Option<u64>,
    /// Seed the odometry with the filter's predicted keyframe→current motion.
    pub vo_prior: bool,
    pub vo_updates: VoUpdates,
    /// Factor on the odometry's delta covariance before fusion. The deltas of consecutive frames
    /// against one keyframe share the keyframe's triangulation errors; the filter fuses them as
    /// independent, so they must count for less than their individual covariance says. The
    /// default 8 comes from the 20-seed simulation (onboard/BENCHMARKS.md): it brings the
    /// orientation NEES into its chi-square bounds.
    pub vo_covariance_scale: f64,
}

/// Relative scale and misalignment error of EuRoC's ADIS16448 gyro (datasheet: ±1 % initial
/// sensitivity tolerance; 0.5 % at 1σ makes the ground-truth-corrected filter consistent over
/// V1_01, `filter`'s `euroc` test).
pub const EUROC_GYRO_SCALE_SIGMA: f64 = 0.005;

/// Standard gravity (m/s²).
pub const EARTH_GRAVITY_MPS2: f64 = 9.806_65;

impl Default for VioOptions {
    fn default() -> Self {
        VioOptions {
            vo: VoConfig::default(),
            sgm: false,
            sgm_threads: 1,
            use_imu: true,
            use_wheel: true,
            zupt: true,
            latency_ns: 250_000_000,
            filter: FilterConfig {
                gyro_scale_sigma: EUROC_GYRO_SCALE_SIGMA,
                ..FilterConfig::from_imu_noise(EUROC_IMU_NOISE, EARTH_GRAVITY_MPS2)
            },
            init_window_ns: 500_000_000,
            end_stamp_ns: None,
            vo_prior: true,
            vo_updates: VoUpdates::EveryFrame,
            vo_covariance_scale: 8.0,
        }
    }
}

/// Why a dataset run failed.
#[derive(Debug, thiserror::Error)]
pub enum VioError {
    #[error("{0}")]
    Sensors(#[from] SensorSetupError),
    #[error("{0}")]
    Stack(#[from] StackError),
    #[error("configuration: {0}")]
    Config(#[from] crate::config::ConfigError),
    #[error("{0}")]
    Input(String),
}

/// The configuration `onboard vio` runs a dataset with: the firmware's defaults, the dataset as
/// a replay, a robot of its own. Callers adjust it (the CLI's options) before
/// [`run_dataset`].
pub fn dataset_config(dataset: &Path) -> RoverConfig {
    let mut config = RoverConfig::default();
    config.robot.name = "vio".into();
    config.driver.kind = DriverKind::Replay;
    config.driver.replay_path = Some(dataset.to_owned());
    config
}

/// What a dataset run measured.
#[derive(Debug, Clone)]
pub struct DatasetReport {
    pub layout: DatasetKind,
    /// The filter fused the IMU (`"vio"`) or the odometry ran alone (`"vo"`).
    pub use_imu: bool,
    /// The dataset's stamp of sensor time 0.
    pub time_offset_ns: u64,
    /// The robot's online estimate, sensor time (add [`DatasetReport::time_offset_ns`] for the
    /// dataset's clock).
    pub estimate: Vec<(u64, Isometry3<f64>)>,
    /// Capture stamps of the dataset's pairs (dataset clock).
    pub image_stamps_ns: Vec<u64>,
    pub driver: DriverCounts,
    pub vision: VisionNodeSummary,
    pub filter: FilterNodeSummary,
    /// Frame switches the mapper asked for.
    pub switch_requests: u64,
    pub initial_gyro_bias_radps: Option<Vector3<f64>>,
    pub final_gyro_bias_radps: Option<Vector3<f64>>,
    pub final_accel_bias_mps2: Option<Vector3<f64>>,
    /// Sensor time replayed.
    pub data_duration_s: f64,
    /// Handler time per node (driver, vision, filter, mapper), s.
    pub node_seconds: Vec<(&'static str, f64)>,
    pub wall_s: f64,
}

impl DatasetReport {
    /// The estimate in the dataset's clock.
    pub fn estimate_in_dataset_time(&self) -> Vec<(u64, Isometry3<f64>)> {
        self.estimate.iter().map(|(s, p)| (s + self.time_offset_ns, *p)).collect()
    }

    /// Largest distance of any estimate pose from the first one (m).
    pub fn max_displacement_m(&self) -> f64 {
        let Some((_, first)) = self.estimate.first() else { return 0.0 };
        self.estimate.iter().map(|(_, p)| (p.translation.vector - first.translation.vector).norm()).fold(0.0, f64::max)
    }
}

/// Replays the dataset of `config` through the robot's nodes on the lockstep runner. Unless
/// `config.driver.duration_s` says otherwise, the replay ends once the last image's odometry
/// result has reached the filter (IMU data after it has no vision to correct it: EuRoC V1_01's
/// excerpt has 1 s of images and 144 s of IMU); `all_imu` replays everything.
pub fn run_dataset(config: &RoverConfig, all_imu: bool) -> Result<DatasetReport, VioError> {
    let wall = Instant::now();
    let dataset = crate::sensors::open_replay(config)?;
    let (Some(&first_image_ns), Some(&last_image_ns)) =
        (dataset.image_stamps_ns.first(), dataset.image_stamps_ns.last())
    else {
        return Err(VioError::Input("the dataset has no stereo pairs".into()));
    };
    let first_ns = dataset.first_stamp_ns.min(first_image_ns);
    let mut config = config.clone();
    if config.driver.duration_s.is_none() && !all_imu {
        let end_ns = (last_image_ns - first_ns).saturating_add((config.filter.vo_latency_ms * 1e6).round() as u64);
        config.driver.duration_s = Some(end_ns as f64 * 1e-9);
    }
    config.validate()?;
    let setup = sensor_setup(&config)?;
    let source = FirmwareSources.open(&config)?;
    let mut stack = RobotStack::new(&config, &setup, source, None, None)?;
    let mut now_ns = 0;
    while !stack.driver.finished() {
        stack.step(now_ns).map_err(StackError::Node)?;
        now_ns += STEP_NS;
    }
    stack.finish(now_ns).map_err(StackError::Node)?;

    let filter = stack.filter.summary();
    let state = stack.filter.filter().state();
    let use_imu = crate::stack::vio_options(&config, &setup).use_imu;
    Ok(DatasetReport {
        layout: dataset.kind,
        use_imu,
        time_offset_ns: stack.driver.time_offset_ns().unwrap_or(first_ns),
        estimate: stack.mapper.online_trajectory().to_vec(),
        image_stamps_ns: dataset.image_stamps_ns.clone(),
        driver: stack.driver.counts(),
        vision: stack.vision.summary(),
        filter,
        switch_requests: stack.mapper.counters().switch_requests,
        initial_gyro_bias_radps: stack.filter.initial_gyro_bias_radps(),
        final_gyro_bias_radps: state.filter(|_| use_imu).map(|s| s.gyro_bias_radps),
        final_accel_bias_mps2: state.filter(|_| use_imu).map(|s| s.accel_bias_mps2),
        data_duration_s: now_ns as f64 * 1e-9,
        node_seconds: NODE_NAMES.iter().copied().zip(stack.times.seconds.iter().copied()).collect(),
        wall_s: wall.elapsed().as_secs_f64(),
    })
}
