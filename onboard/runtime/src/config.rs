//! The rover's configuration: one TOML file (example: `onboard/runtime/config/rover.toml`),
//! validated completely at start so that a bad value stops the rover on the ground with a message
//! naming the key, not in the field.
//!
//! Every key but `robot.id` and the sensor source has a default (see the `Default` impls): the
//! driver needs `driver.kind` with its `replay_path` (a dataset, which brings its own calibration)
//! or its `[driver.sim]` table (the `sil` harness's simulator, which needs `[camera.calibration]`).
//! Unknown keys are rejected (a misspelt key would otherwise silently fall back to its default).
//!
//! | section | what |
//! |---|---|
//! | `[robot]` | id, name, bus id, output folder |
//! | `[driver]` | sensor source: `replay` (dataset folder, pace, duration) or `sim` (`[driver.sim]`) |
//! | `[camera]` | frame rate, `[camera.calibration]` of the stereo head (`calibration` module) |
//! | `[imu]` | gravity at the site, noise densities, initial bias sigmas, gyro scale error |
//! | `[vision]`, `[filter]` | matcher and odometry; the filter's inputs, latency and updates |
//! | `[rates]` | sensor rates and the processes' fixed-rate tasks |
//! | `[mapper]` | submap policy, voxels, depth error limit |
//! | `[markers]` | robot detection: AprilTag detector, uncertainty model and table, the team's tag mountings |
//! | `[gaze]` | the gaze policy that points the pan-tilt head (`nodes::gaze`) |
//! | `[link]` | team link (UDP or serial), ground link, command key |
//! | `[realtime]`, `[recording]` | SCHED_FIFO, CPU, memory locking; bus recording |

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

pub mod calibration;

use filter::config::ImuNoise;
use msgs::ProcessKind;
use serde::{Deserialize, Serialize};

pub use calibration::CalibrationConfig;

use crate::task::TaskSpec;
use crate::task::rt::RtRequest;

/// The SGM core's maximum frame rate at 1024×508 (thesis §7.1).
pub const FPGA_MAX_RATE_HZ: f64 = 14.6;

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoverConfig {
    pub robot: RobotConfig,
    #[serde(default)]
    pub driver: DriverConfig,
    #[serde(default)]
    pub camera: CameraConfig,
    #[serde(default)]
    pub imu: ImuConfig,
    #[serde(default)]
    pub vision: VisionConfig,
    #[serde(default)]
    pub filter: FilterSettings,
    #[serde(default)]
    pub rates: RatesConfig,
    #[serde(default)]
    pub mapper: MapperConfig,
    #[serde(default)]
    pub markers: MarkersConfig,
    #[serde(default)]
    pub gaze: GazeConfig,
    #[serde(default)]
    pub matching: MatchingConfig,
    #[serde(default)]
    pub link: LinkConfig,
    #[serde(default)]
    pub realtime: RealtimeConfig,
    #[serde(default)]
    pub recording: RecordingConfig,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotConfig {
    /// Required: two rovers with the same id would corrupt each other's maps.
    pub id: u16,
    #[serde(default)]
    pub name: String,
    /// iceoryx2 id of the robot's bus (`rover/{bus_id}/…`, files `iox2_r{bus_id}_`); default
    /// `id`. Robots of several simulated teams on one machine (parallel tests) need distinct ids.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bus_id: Option<u16>,
    /// Where the processes write their outputs and telemetry files; default `runs/rover{id}`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub output_dir: Option<PathBuf>,
    /// The operating mode the robot boots into (reported to the ground; a ground command changes
    /// it): `idle` (estimating, not moving on its own), `autonomous` (exploring on its own), ...
    #[serde(default)]
    pub mode: ModeConfig,
}

/// The robot's operating mode (`protocol::message::Mode`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ModeConfig {
    #[default]
    Idle,
    Waypoint,
    Autonomous,
    Teleoperated,
    Safe,
}

impl ModeConfig {
    pub fn mode(self) -> protocol::message::Mode {
        use protocol::message::Mode;
        match self {
            ModeConfig::Idle => Mode::Idle,
            ModeConfig::Waypoint => Mode::Waypoint,
            ModeConfig::Autonomous => Mode::Autonomous,
            ModeConfig::Teleoperated => Mode::Teleoperated,
            ModeConfig::Safe => Mode::Safe,
        }
    }
}

impl RobotConfig {
    pub fn bus_id(&self) -> u16 {
        self.bus_id.unwrap_or(self.id)
    }

    pub fn output_dir(&self) -> PathBuf {
        self.output_dir.clone().unwrap_or_else(|| PathBuf::from(format!("runs/rover{}", self.id)))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DriverKind {
    /// Sensors from the software-in-the-loop simulator: provided by the `sil` harness, which runs
    /// these same processes with its simulated sensors; the firmware alone refuses it.
    Sim,
    /// Sensors from a recorded dataset (`driver.replay_path`: EuRoC/ASL or KITTI layout).
    Replay,
    /// The rover's devices (`[driver.devices]`): the IMU over serial (Xsens MT binary protocol),
    /// the wheel drives and the pan-tilt head over CAN (CANopen); the cameras publish their pairs
    /// on the robot's bus themselves.
    Devices,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DriverConfig {
    pub kind: DriverKind,
    /// The dataset folder; required with `kind = "replay"`.
    pub replay_path: Option<PathBuf>,
    /// Replay pace against the wall clock in the process runner (1 = as recorded, 0.25 = a quarter
    /// of the recorded pace, so that a slow board drops no frame).
    pub replay_speed: f64,
    /// The driver stops after this much sensor time (default: the whole source).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    /// With `kind = "sim"`: the simulated world (scenario, seed, team size, ...). The firmware
    /// passes it through untouched to whoever provides the simulated sensors, which validates it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sim: Option<toml::Table>,
    /// With `kind = "devices"`: where the devices are.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub devices: Option<DevicesConfig>,
}

impl Default for DriverConfig {
    fn default() -> Self {
        DriverConfig {
            kind: DriverKind::Replay,
            replay_path: None,
            replay_speed: 1.0,
            duration_s: None,
            sim: None,
            devices: None,
        }
    }
}

/// `[driver.devices]`: the rover's IMU, wheel drives and pan-tilt head.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DevicesConfig {
    /// Serial port of the Xsens IMU (e.g. `/dev/ttyUSB0`).
    pub imu_port: String,
    pub imu_baud: u32,
    /// `socketcan:can0` or `slcan:/dev/ttyACM0@1000000` (`hal::can::interface`).
    pub can_interface: String,
    /// CANopen node ids of the wheel drives: front-left, front-right, rear-left, rear-right.
    pub wheel_nodes: [u8; 4],
    /// CANopen node id of the pan-tilt unit; none: the head is fixed.
    pub head_node: Option<u8>,
    /// SYNC period of the CANopen master: one wheel odometry sample per SYNC.
    pub sync_period_ms: u32,
    /// A node whose heartbeat is this late is reported missing.
    pub heartbeat_timeout_ms: u32,
    pub wheel_radius_m: f64,
    /// Distance between the left and right wheels' contact points.
    pub track_width_m: f64,
    /// Encoder counts per wheel revolution (after the gear).
    pub counts_per_rev: u32,
    /// Relative 1σ of speed and yaw rate the wheel odometry claims (slip, scale).
    pub wheel_relative_sigma: f64,
}

impl Default for DevicesConfig {
    fn default() -> Self {
        DevicesConfig {
            imu_port: "/dev/ttyUSB0".into(),
            imu_baud: 921_600,
            can_interface: "socketcan:can0".into(),
            wheel_nodes: [0x11, 0x12, 0x13, 0x14],
            head_node: Some(0x20),
            sync_period_ms: 20,
            heartbeat_timeout_ms: 300,
            wheel_radius_m: 0.1,
            track_width_m: 0.6,
            counts_per_rev: 4096 * 100,
            wheel_relative_sigma: 0.1,
        }
    }
}

impl DriverConfig {
    /// The driver's last stamp (sensor time), if it has one.
    pub fn end_stamp_ns(&self) -> Option<u64> {
        self.duration_s.map(|s| (s * 1e9) as u64)
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CameraConfig {
    /// Stereo frame rate; at most [`FPGA_MAX_RATE_HZ`].
    pub rate_hz: f64,
    /// The stereo head; optional with a replayed dataset, which brings its own.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration: Option<CalibrationConfig>,
}

impl Default for CameraConfig {
    fn default() -> Self {
        CameraConfig { rate_hz: 10.0, calibration: None }
    }
}

/// `[imu]`: the IMU's noise model and the site's gravity, for the filter.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImuConfig {
    /// Gravity at the site (Moon 1.62, Mars 3.721, Earth 9.80665 m/s²).
    pub gravity_mps2: f64,
    /// Continuous-time noise densities; default: a replayed dataset's `imu0/sensor.yaml`, else
    /// EuRoC's ADIS16448.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub noise: Option<ImuNoiseConfig>,
    /// Initial 1σ of the biases (turn-on bias as the datasheet states it); default: the filter's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gyro_bias_sigma_radps: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub accel_bias_sigma_mps2: Option<f64>,
    /// Relative gyro scale and misalignment error (1σ); 0 for an ideal-scale gyro.
    pub gyro_scale_sigma: f64,
}

impl Default for ImuConfig {
    fn default() -> Self {
        ImuConfig {
            gravity_mps2: crate::vio::EARTH_GRAVITY_MPS2,
            noise: None,
            gyro_bias_sigma_radps: None,
            accel_bias_sigma_mps2: None,
            gyro_scale_sigma: crate::vio::EUROC_GYRO_SCALE_SIGMA,
        }
    }
}

/// IMU noise densities (`filter::config::ImuNoise`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuNoiseConfig {
    /// rad/s/√Hz
    pub gyro_noise_density: f64,
    /// rad/s²/√Hz
    pub gyro_random_walk: f64,
    /// m/s²/√Hz
    pub accel_noise_density: f64,
    /// m/s³/√Hz
    pub accel_random_walk: f64,
}

impl ImuNoiseConfig {
    pub fn noise(&self) -> ImuNoise {
        ImuNoise {
            gyro_noise_density: self.gyro_noise_density,
            gyro_random_walk: self.gyro_random_walk,
            accel_noise_density: self.accel_noise_density,
            accel_random_walk: self.accel_random_walk,
        }
    }

    pub fn from_noise(noise: &ImuNoise) -> ImuNoiseConfig {
        ImuNoiseConfig {
            gyro_noise_density: noise.gyro_noise_density,
            gyro_random_walk: noise.gyro_random_walk,
            accel_noise_density: noise.accel_noise_density,
            accel_random_walk: noise.accel_random_walk,
        }
    }
}

/// `[vision]`: the vision process's matcher and odometry.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct VisionConfig {
    /// Depth for the odometry from the SGM map instead of the odometry's sparse matching.
    pub sgm_depth_for_vo: bool,
    pub sgm_threads: usize,
    /// Disparity range of the SGM core (a multiple of 16; the FPGA's is 128 at 1024 px).
    pub sgm_disparities: u16,
    /// Drop SGM's small blunder patches before depth.
    pub despeckle: bool,
    /// Seed the odometry with the filter's keyframe→current motion.
    pub vo_prior: bool,
    /// Longest wait for the filter state of a capture before the odometry runs without a prior.
    pub prior_wait_ms: f64,
    /// Obstacle classification beyond the thesis's edge rule: a rim with ground seen more than
    /// this much lower beyond it is a hazard whatever the slope between (0 = the thesis's rule;
    /// `vision::obstacles::ObstacleConfig::hidden_drop_m`, measured in `onboard/BENCHMARKS.md`).
    pub hidden_drop_m: f64,
}

impl Default for VisionConfig {
    fn default() -> Self {
        VisionConfig {
            sgm_depth_for_vo: false,
            sgm_threads: 1,
            sgm_disparities: vision::depth_sgm_config().disparities,
            despeckle: true,
            vo_prior: true,
            prior_wait_ms: 50.0,
            hidden_drop_m: 0.0,
        }
    }
}

/// The marker pose uncertainty model (thesis §6.2.3, §8.1.3).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MarkerModelConfig {
    /// Eq. 8.1: 1 cm and 1.3° per axis.
    Constant,
    /// Eq. 8.2: the constant model times `(1 + d)²`.
    Quadratic,
    /// The offline table alone.
    Lut,
    /// The online corner-noise sampling alone.
    Online,
    /// The thesis's model: per axis the larger of table and sampling.
    LutOnline,
}

/// `[gaze]`: the gaze policy in the vision process (see `nodes::gaze` for what each look is
/// for). Off by default: a dataset's or a fixed camera's pairs cannot be pointed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct GazeConfig {
    pub enabled: bool,
    pub ahead_tilt_rad: f64,
    pub down_tilt_rad: f64,
    pub ahead_s: f64,
    pub down_s: f64,
    pub rate_radps: f64,
    pub sweep_pan_rad: f64,
    pub sweep_rate_radps: f64,
    pub moving_mps: f64,
    pub turning_radps: f64,
    pub standing_s: f64,
    pub resend_s: f64,
    /// The odometry skips pairs whose head differs by more than this from the last it tracked
    /// (`nodes::vision::VisionNodeOptions::vo_head_gate_rad`); 0 = it takes every pair.
    pub vo_head_gate_rad: f64,
}

impl Default for GazeConfig {
    fn default() -> Self {
        let o = crate::nodes::gaze::GazeOptions::lru();
        GazeConfig {
            enabled: false,
            ahead_tilt_rad: o.ahead_tilt_rad,
            down_tilt_rad: o.down_tilt_rad,
            ahead_s: o.ahead_s,
            down_s: o.down_s,
            rate_radps: o.rate_radps,
            sweep_pan_rad: o.sweep_pan_rad,
            sweep_rate_radps: o.sweep_rate_radps,
            moving_mps: o.moving_mps,
            turning_radps: o.turning_radps,
            standing_s: o.standing_s,
            resend_s: o.resend_s,
            vo_head_gate_rad: 0.05,
        }
    }
}

impl GazeConfig {
    pub fn options(&self) -> crate::nodes::gaze::GazeOptions {
        crate::nodes::gaze::GazeOptions {
            ahead_tilt_rad: self.ahead_tilt_rad,
            down_tilt_rad: self.down_tilt_rad,
            ahead_s: self.ahead_s,
            down_s: self.down_s,
            rate_radps: self.rate_radps,
            sweep_pan_rad: self.sweep_pan_rad,
            sweep_rate_radps: self.sweep_rate_radps,
            moving_mps: self.moving_mps,
            turning_radps: self.turning_radps,
            standing_s: self.standing_s,
            resend_s: self.resend_s,
        }
    }
}

/// `[markers]`: robot detection from the AprilTags on the team's masts (thesis §6.2). A robot with
/// configuration id `j` carries tags `tags_per_robot · j + k`, tag `k` at `mounting[k]` on its
/// body; the team shares one rover design.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MarkersConfig {
    /// Run the tag36h11 detector in the vision process.
    pub detect: bool,
    /// Also detect in the right image (a tag the left image misses, or sees cut by its border).
    pub right_image: bool,
    /// Edge of a tag's black square.
    pub size_m: f64,
    pub model: MarkerModelConfig,
    /// The camera's uncertainty table (`marker-lut --out FILE`), required by the `lut` and
    /// `lut_online` models; refused at start-up unless it was made for this camera and tag size.
    pub lut: Option<PathBuf>,
    pub tags_per_robot: u32,
    /// Pose of tag `k` in the body frame of the robot that carries it.
    pub mounting: Vec<calibration::PoseConfig>,
    /// At most one image's detections of a robot per this interval enter the graph (the LRU
    /// experiments had about 27 detections in 370 m: sparse robot-pose nodes).
    pub min_interval_s: f64,
    /// Tags farther than this are not used (the uncertainty table's range).
    pub max_distance_m: f64,
}

impl Default for MarkersConfig {
    fn default() -> Self {
        MarkersConfig {
            detect: false,
            right_image: true,
            size_m: 0.16,
            model: MarkerModelConfig::LutOnline,
            lut: None,
            tags_per_robot: 3,
            mounting: Vec::new(),
            min_interval_s: 10.0,
            max_distance_m: 7.0,
        }
    }
}

impl MarkerModelConfig {
    /// The vision crate's model of this setting.
    pub fn uncertainty_model(self) -> vision::marker_pose::UncertaintyModel {
        use vision::marker_pose::UncertaintyModel;
        match self {
            MarkerModelConfig::Constant => UncertaintyModel::Constant,
            MarkerModelConfig::Quadratic => UncertaintyModel::Quadratic,
            MarkerModelConfig::Lut => UncertaintyModel::LutOnly,
            MarkerModelConfig::Online => UncertaintyModel::OnlineOnly,
            MarkerModelConfig::LutOnline => UncertaintyModel::LutAndOnline,
        }
    }
}

/// Which odometry results become filter updates (`crate::vio::VoUpdates`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VoUpdatesConfig {
    EveryFrame,
    Keyframes,
}

/// `[filter]`: the local reference filter's inputs and timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct FilterSettings {
    /// Fuse the IMU (the error-state filter); `false`: the stereo odometry's own chain, for a
    /// dataset without IMU.
    pub use_imu: bool,
    pub use_wheel: bool,
    /// Zero-velocity updates while standing.
    pub zupt: bool,
    /// Sensor time from an image's capture to the application of its odometry result (thesis:
    /// SGM + VO latency).
    pub vo_latency_ms: f64,
    pub vo_updates: VoUpdatesConfig,
    /// Factor on the odometry's delta covariance before fusion (see `crate::vio::VioOptions`).
    pub vo_covariance_scale: f64,
    /// IMU data averaged for the at-rest initialization.
    pub init_window_ms: f64,
}

impl Default for FilterSettings {
    fn default() -> Self {
        FilterSettings {
            use_imu: true,
            use_wheel: true,
            zupt: true,
            vo_latency_ms: 250.0,
            vo_updates: VoUpdatesConfig::EveryFrame,
            vo_covariance_scale: 8.0,
            init_window_ms: 500.0,
        }
    }
}

/// One fixed-rate task's rate and deadline. The deadline is either a fraction of the period or
/// an absolute time; neither means the whole period.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaskRate {
    pub hz: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deadline_fraction: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub deadline_ns: Option<u64>,
}

impl TaskRate {
    fn at(hz: f64, deadline_fraction: f64) -> TaskRate {
        TaskRate { hz, deadline_fraction: Some(deadline_fraction), deadline_ns: None }
    }

    pub fn period_ns(&self) -> u64 {
        (1e9 / self.hz).round() as u64
    }

    pub fn deadline_ns(&self) -> u64 {
        match (self.deadline_ns, self.deadline_fraction) {
            (Some(ns), _) => ns,
            (None, Some(f)) => (self.period_ns() as f64 * f).round() as u64,
            (None, None) => self.period_ns(),
        }
    }

    /// The task spec (valid once the configuration validated).
    pub fn spec(&self, name: &str) -> TaskSpec {
        TaskSpec { name: name.into(), period_ns: self.period_ns(), deadline_ns: self.deadline_ns() }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RatesConfig {
    /// Sensor rates of the driver.
    pub imu_hz: f64,
    pub wheel_hz: f64,
    /// Fixed-rate tasks of the processes.
    pub filter: TaskRate,
    pub vision: TaskRate,
    pub mapper: TaskRate,
    pub comms: TaskRate,
}

impl Default for RatesConfig {
    fn default() -> Self {
        RatesConfig {
            imu_hz: 200.0,
            wheel_hz: 50.0,
            // The filter must finish one IMU sample's work well inside a period.
            filter: TaskRate::at(200.0, 0.5),
            // Twice the camera rate so a frame waits at most half a frame period.
            vision: TaskRate::at(20.0, 1.0),
            mapper: TaskRate::at(10.0, 1.0),
            comms: TaskRate::at(50.0, 1.0),
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MapperConfig {
    /// A new submap starts after this travelled distance (thesis: 3.5 m early, 7 m later).
    pub submap_max_distance_m: f64,
    /// ... or when the position sigma exceeds this (thesis: 0.1–0.2 m).
    pub max_position_sigma_m: f64,
    /// Point cloud voxel (thesis: 5 cm).
    pub point_voxel_m: f64,
    /// Occupancy octree voxel (thesis: 10 cm).
    pub octree_voxel_m: f64,
    /// Depth points whose stereo depth error exceeds this are not mapped (default: the
    /// integrator's, set for the LRU head at full resolution; at `1/k` of the resolution the same
    /// disparity error is `k` times more depth error, so `k` times the limit keeps the range).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub max_depth_error_m: Option<f64>,
    /// Screening of inter-robot loop closures before they enter the pose graph
    /// (`mapper::slam::ConsistencyCheck`): `none` (the thesis: Cauchy kernel only) or `pcm`
    /// (pairwise consistency maximization with its default parameters, then the kernel).
    pub inter_robot_consistency: InterRobotConsistency,
}

/// `[mapper] inter_robot_consistency`.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum InterRobotConsistency {
    #[default]
    None,
    Pcm,
}

impl InterRobotConsistency {
    pub fn check(self) -> mapper::slam::ConsistencyCheck {
        match self {
            InterRobotConsistency::None => mapper::slam::ConsistencyCheck::None,
            InterRobotConsistency::Pcm => mapper::slam::ConsistencyCheck::Pcm(mapper::slam::PcmParams::default()),
        }
    }
}

impl Default for MapperConfig {
    fn default() -> Self {
        // `mapper::submap::SubmapPolicy::default()`: the LRU multi-robot experiments.
        MapperConfig {
            submap_max_distance_m: 7.0,
            max_position_sigma_m: 0.2,
            point_voxel_m: 0.05,
            octree_voxel_m: 0.1,
            max_depth_error_m: None,
            inter_robot_consistency: InterRobotConsistency::default(),
        }
    }
}

/// `[matching]`: the submap matcher, the mapper's background work (thesis §6.1).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MatchingConfig {
    /// Match submaps (own and the peers') into loop closures.
    pub enabled: bool,
    /// `"4d"` (x, y, z, yaw: the thesis's proposal) or `"6d"` (its baseline).
    pub mode: MatchModeConfig,
    /// Eq. 6.3: the view distance at which the matcher's precision is the stereo depth error
    /// (thesis: 4 m), and the disparity error behind it (thesis: 0.5 px).
    pub precision_view_distance_m: f64,
    pub precision_disparity_px: f64,
    /// Eq. 6.2: least inflated xy overlap (thesis: 2 m²).
    pub min_overlap_m2: f64,
    /// Eq. 6.4's α (thesis: 0.125).
    pub overlap_weight_per_m2: f64,
    /// `"thesis"`: Δσ = sqrt(|Σ_a − Σ_b|) (all the thesis's experiments); `"sum"`: sqrt(Σ_a + Σ_b).
    pub delta_sigma: DeltaSigmaConfig,
    /// On simulated time (lockstep) one attempt starts at most this often; the process runner's
    /// matcher thread takes whatever CPU is free instead.
    pub attempt_period_s: f64,
}

impl Default for MatchingConfig {
    fn default() -> Self {
        MatchingConfig {
            enabled: true,
            mode: MatchModeConfig::FourD,
            precision_view_distance_m: 4.0,
            precision_disparity_px: 0.5,
            min_overlap_m2: 2.0,
            overlap_weight_per_m2: 0.125,
            delta_sigma: DeltaSigmaConfig::Thesis,
            attempt_period_s: 1.0,
        }
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum MatchModeConfig {
    #[serde(rename = "4d")]
    FourD,
    #[serde(rename = "6d")]
    SixD,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum DeltaSigmaConfig {
    Thesis,
    Sum,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum LinkKind {
    Udp,
    Serial,
    /// The team link over a CAN bus (`link.can_interface`), with the protocol's CAN framing.
    Can,
    None,
}

#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PeerConfig {
    pub robot_id: u16,
    /// `ip:port` for UDP links.
    pub address: String,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LinkConfig {
    pub kind: LinkKind,
    /// UDP: local `ip:port` to bind.
    pub bind: String,
    pub peers: Vec<PeerConfig>,
    /// Serial: device path and baud rate.
    pub serial_device: Option<String>,
    pub serial_baud: u32,
    /// CAN: `socketcan:can0` or `slcan:/dev/ttyACM0@1000000` (`hal::can::interface`).
    pub can_interface: Option<String>,
    /// The link's capacity the comms scheduler keeps under (a radio's, not the Ethernet's).
    pub bandwidth_bytes_per_s: u64,
    /// UDP address of the ground link (the ground station, or the mission's relay); none: no
    /// ground link.
    pub ground_feed: Option<String>,
    /// The ground link's rate cap, wire bytes/s (default
    /// [`crate::nodes::comms::GROUND_RATE_BYTES_PER_S`]).
    pub ground_bandwidth_bytes_per_s: u64,
    /// Key file (`hal::keyfile` format, owner-only permissions) that authenticates ground
    /// commands; none: every command is refused.
    pub ground_key_file: Option<PathBuf>,
}

impl Default for LinkConfig {
    fn default() -> Self {
        LinkConfig {
            kind: LinkKind::Udp,
            bind: "0.0.0.0:47000".into(),
            peers: Vec::new(),
            serial_device: None,
            serial_baud: 57_600,
            can_interface: None,
            bandwidth_bytes_per_s: 12_500,
            ground_feed: None,
            ground_bandwidth_bytes_per_s: crate::nodes::comms::GROUND_RATE_BYTES_PER_S,
            ground_key_file: None,
        }
    }
}

impl LinkConfig {
    /// The bind address (valid once the configuration validated).
    pub fn bind_addr(&self) -> Option<SocketAddr> {
        self.bind.parse().ok()
    }

    pub fn ground_feed_addr(&self) -> Option<SocketAddr> {
        self.ground_feed.as_deref().and_then(|a| a.parse().ok())
    }

    /// UDP peers with parsed addresses (valid once the configuration validated).
    pub fn peer_addrs(&self) -> Vec<(u16, SocketAddr)> {
        self.peers.iter().filter_map(|p| Some((p.robot_id, p.address.parse().ok()?))).collect()
    }
}

/// Real-time settings of one process.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ProcessRealtime {
    /// SCHED_FIFO priority 1..=99 of the process's task thread; none keeps normal scheduling.
    pub fifo_priority: Option<u8>,
    pub cpu: Option<usize>,
}

#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RealtimeConfig {
    pub lock_memory: bool,
    pub driver: ProcessRealtime,
    pub vision: ProcessRealtime,
    pub filter: ProcessRealtime,
    pub mapper: ProcessRealtime,
    pub comms: ProcessRealtime,
}

impl RealtimeConfig {
    pub fn process(&self, process: ProcessKind) -> ProcessRealtime {
        match process {
            ProcessKind::Driver => self.driver,
            ProcessKind::Vision => self.vision,
            ProcessKind::Filter => self.filter,
            ProcessKind::Mapper => self.mapper,
            ProcessKind::Comms => self.comms,
            ProcessKind::Supervisor => ProcessRealtime::default(),
        }
    }

    /// What [`crate::task::rt::apply`] should do in `process`.
    pub fn request(&self, process: ProcessKind) -> RtRequest {
        let p = self.process(process);
        RtRequest { fifo_priority: p.fifo_priority, lock_memory: self.lock_memory, cpu: p.cpu }
    }
}

#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RecordingConfig {
    pub enabled: bool,
    pub directory: PathBuf,
}

impl Default for RecordingConfig {
    fn default() -> Self {
        RecordingConfig { enabled: false, directory: PathBuf::from("runs/record") }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("reading {path}: {source}")]
    Read { path: PathBuf, source: std::io::Error },
    /// TOML syntax, a wrong type, an unknown or missing key.
    #[error("{key} (line {line}): {problem}")]
    Syntax { key: String, line: usize, problem: String },
    /// A well-formed value that is out of range or inconsistent with another.
    #[error("{key}: {problem}")]
    Invalid { key: String, problem: String },
}

impl Default for RoverConfig {
    fn default() -> Self {
        RoverConfig {
            robot: RobotConfig { id: 0, name: String::new(), bus_id: None, output_dir: None, mode: ModeConfig::Idle },
            driver: DriverConfig::default(),
            camera: CameraConfig::default(),
            imu: ImuConfig::default(),
            vision: VisionConfig::default(),
            filter: FilterSettings::default(),
            rates: RatesConfig::default(),
            mapper: MapperConfig::default(),
            markers: MarkersConfig::default(),
            gaze: GazeConfig::default(),
            matching: MatchingConfig::default(),
            link: LinkConfig::default(),
            realtime: RealtimeConfig::default(),
            recording: RecordingConfig::default(),
        }
    }
}

impl RoverConfig {
    pub fn from_toml_str(text: &str) -> Result<RoverConfig, ConfigError> {
        let config: RoverConfig = toml::from_str(text).map_err(|e| syntax_error(text, &e))?;
        config.validate()?;
        Ok(config)
    }

    pub fn load(path: &Path) -> Result<RoverConfig, ConfigError> {
        let text =
            std::fs::read_to_string(path).map_err(|source| ConfigError::Read { path: path.to_path_buf(), source })?;
        RoverConfig::from_toml_str(&text)
    }

    /// The configuration as TOML (every default spelt out), e.g. to store next to a run.
    pub fn to_toml_string(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// Checks ranges and consistency between values; the first problem is returned.
    pub fn validate(&self) -> Result<(), ConfigError> {
        let d = &self.driver;
        if let Some(duration_s) = d.duration_s {
            check(duration_s.is_finite() && duration_s > 0.0 && duration_s <= 86_400.0, "driver.duration_s", || {
                format!("{duration_s} s: expected more than 0 and at most a day")
            })?;
        }
        check(
            d.replay_speed.is_finite() && d.replay_speed > 0.0 && d.replay_speed <= 100.0,
            "driver.replay_speed",
            || format!("{}: expected more than 0, at most 100", d.replay_speed),
        )?;
        match d.kind {
            DriverKind::Sim => check(d.sim.is_some(), "driver.sim", || {
                "required with driver.kind = \"sim\" (the simulated world's settings)".into()
            })?,
            DriverKind::Replay => {
                check(d.replay_path.is_some(), "driver.replay_path", || {
                    "required with driver.kind = \"replay\"".into()
                })?;
                check(d.sim.is_none(), "driver.sim", || "only with driver.kind = \"sim\"".into())?;
            }
            DriverKind::Devices => {
                let devices = d.devices.as_ref().ok_or_else(|| ConfigError::Invalid {
                    key: "driver.devices".into(),
                    problem: "required with driver.kind = \"devices\"".into(),
                })?;
                devices.validate()?;
            }
        }
        if d.kind != DriverKind::Devices {
            check(d.devices.is_none(), "driver.devices", || "only with driver.kind = \"devices\"".into())?;
        }

        let c = &self.camera;
        check(c.rate_hz.is_finite() && c.rate_hz > 0.0, "camera.rate_hz", || {
            format!("{} Hz: must be positive", c.rate_hz)
        })?;
        check(c.rate_hz <= FPGA_MAX_RATE_HZ + 1e-9, "camera.rate_hz", || {
            format!("{} Hz is above the FPGA's maximum of {FPGA_MAX_RATE_HZ} Hz", c.rate_hz)
        })?;
        match &c.calibration {
            Some(calibration) => {
                calibration
                    .to_calibration()
                    .map_err(|problem| ConfigError::Invalid { key: "camera.calibration".into(), problem })?;
            }
            None => check(d.kind == DriverKind::Replay, "camera.calibration", || {
                "required unless a replayed dataset brings its own".into()
            })?,
        }

        let i = &self.imu;
        check(
            i.gravity_mps2.is_finite() && i.gravity_mps2 > 0.0 && i.gravity_mps2 <= 30.0,
            "imu.gravity_mps2",
            || format!("{} m/s²: expected more than 0, at most 30", i.gravity_mps2),
        )?;
        if let Some(n) = &i.noise {
            for (key, v) in [
                ("imu.noise.gyro_noise_density", n.gyro_noise_density),
                ("imu.noise.gyro_random_walk", n.gyro_random_walk),
                ("imu.noise.accel_noise_density", n.accel_noise_density),
                ("imu.noise.accel_random_walk", n.accel_random_walk),
            ] {
                check(v.is_finite() && v > 0.0, key, || format!("{v}: must be positive"))?;
            }
        }
        for (key, v) in [
            ("imu.gyro_bias_sigma_radps", i.gyro_bias_sigma_radps),
            ("imu.accel_bias_sigma_mps2", i.accel_bias_sigma_mps2),
        ] {
            if let Some(v) = v {
                check(v.is_finite() && v > 0.0, key, || format!("{v}: must be positive"))?;
            }
        }
        check(
            i.gyro_scale_sigma.is_finite() && (0.0..=0.2).contains(&i.gyro_scale_sigma),
            "imu.gyro_scale_sigma",
            || format!("{}: expected 0..=0.2", i.gyro_scale_sigma),
        )?;

        let v = &self.vision;
        check((1..=64).contains(&v.sgm_threads), "vision.sgm_threads", || {
            format!("{}: expected 1..=64", v.sgm_threads)
        })?;
        check(
            (16..=256).contains(&v.sgm_disparities) && v.sgm_disparities.is_multiple_of(16),
            "vision.sgm_disparities",
            || format!("{}: expected a multiple of 16 in 16..=256", v.sgm_disparities),
        )?;
        check(
            v.prior_wait_ms.is_finite() && (0.0..=10_000.0).contains(&v.prior_wait_ms),
            "vision.prior_wait_ms",
            || format!("{} ms: expected 0..=10000", v.prior_wait_ms),
        )?;

        let f = &self.filter;
        check(
            f.vo_latency_ms.is_finite() && (0.0..=10_000.0).contains(&f.vo_latency_ms),
            "filter.vo_latency_ms",
            || format!("{} ms: expected 0..=10000", f.vo_latency_ms),
        )?;
        check(f.vo_covariance_scale.is_finite() && f.vo_covariance_scale > 0.0, "filter.vo_covariance_scale", || {
            format!("{}: must be positive", f.vo_covariance_scale)
        })?;
        check(
            f.init_window_ms.is_finite() && (0.0..=60_000.0).contains(&f.init_window_ms),
            "filter.init_window_ms",
            || format!("{} ms: expected 0..=60000", f.init_window_ms),
        )?;

        let r = &self.rates;
        for (key, hz) in [("rates.imu_hz", r.imu_hz), ("rates.wheel_hz", r.wheel_hz)] {
            check(hz.is_finite() && hz > 0.0 && hz <= 2000.0, key, || {
                format!("{hz} Hz: expected more than 0, at most 2000")
            })?;
        }
        for (name, task) in [("filter", &r.filter), ("vision", &r.vision), ("mapper", &r.mapper), ("comms", &r.comms)] {
            validate_task_rate(name, task)?;
        }
        check(r.vision.hz >= c.rate_hz - 1e-9, "rates.vision.hz", || {
            format!("{} Hz is below camera.rate_hz {} Hz: vision would fall behind the camera", r.vision.hz, c.rate_hz)
        })?;

        let m = &self.mapper;
        let in_range = |v: f64, lo: f64, hi: f64| v.is_finite() && v >= lo && v <= hi;
        check(in_range(m.submap_max_distance_m, 0.5, 100.0), "mapper.submap_max_distance_m", || {
            format!("{} m: expected 0.5..=100 (thesis: 3.5 or 7)", m.submap_max_distance_m)
        })?;
        check(in_range(m.max_position_sigma_m, 0.01, 2.0), "mapper.max_position_sigma_m", || {
            format!("{} m: expected 0.01..=2 (thesis: 0.1–0.2)", m.max_position_sigma_m)
        })?;
        for (key, v) in [("mapper.point_voxel_m", m.point_voxel_m), ("mapper.octree_voxel_m", m.octree_voxel_m)] {
            check(in_range(v, 0.005, 2.0), key, || format!("{v} m: expected 0.005..=2"))?;
        }
        if let Some(v) = m.max_depth_error_m {
            check(in_range(v, 0.001, 10.0), "mapper.max_depth_error_m", || format!("{v} m: expected 0.001..=10"))?;
        }

        let drop = self.vision.hidden_drop_m;
        check(drop == 0.0 || in_range(drop, 0.05, 5.0), "vision.hidden_drop_m", || {
            format!("{drop} m: expected 0 (off) or 0.05..=5")
        })?;
        self.validate_markers()?;
        if self.gaze.enabled {
            self.gaze
                .options()
                .validate()
                .map_err(|(field, problem)| ConfigError::Invalid { key: format!("gaze.{field}"), problem })?;
            let gate = self.gaze.vo_head_gate_rad;
            check(gate.is_finite() && (0.0..=1.0).contains(&gate), "gaze.vo_head_gate_rad", || {
                format!("{gate}: expected 0 (off) ..= 1 rad")
            })?;
        }
        self.validate_matching()?;
        self.validate_link()?;

        for (name, p) in [
            ("driver", self.realtime.driver),
            ("vision", self.realtime.vision),
            ("filter", self.realtime.filter),
            ("mapper", self.realtime.mapper),
            ("comms", self.realtime.comms),
        ] {
            if let Some(priority) = p.fifo_priority {
                check((1..=99).contains(&priority), &format!("realtime.{name}.fifo_priority"), || {
                    format!("{priority}: SCHED_FIFO priorities are 1..=99")
                })?;
            }
            if let Some(cpu) = p.cpu {
                check(cpu < 1024, &format!("realtime.{name}.cpu"), || {
                    format!("{cpu}: expected a CPU index below 1024")
                })?;
            }
        }

        check(
            !self.recording.enabled || !self.recording.directory.as_os_str().is_empty(),
            "recording.directory",
            || "must not be empty when recording.enabled".into(),
        )?;
        Ok(())
    }

    fn validate_matching(&self) -> Result<(), ConfigError> {
        let m = &self.matching;
        let positive = |value: f64, key: &str, unit: &str| {
            check(value.is_finite() && value > 0.0, key, || format!("{value} {unit}: must be positive"))
        };
        positive(m.precision_view_distance_m, "matching.precision_view_distance_m", "m")?;
        positive(m.precision_disparity_px, "matching.precision_disparity_px", "px")?;
        positive(m.attempt_period_s, "matching.attempt_period_s", "s")?;
        check(m.min_overlap_m2.is_finite() && m.min_overlap_m2 >= 0.0, "matching.min_overlap_m2", || {
            format!("{} m²: must not be negative", m.min_overlap_m2)
        })?;
        check(
            m.overlap_weight_per_m2.is_finite() && m.overlap_weight_per_m2 >= 0.0,
            "matching.overlap_weight_per_m2",
            || format!("{}: must not be negative", m.overlap_weight_per_m2),
        )?;
        Ok(())
    }

    fn validate_markers(&self) -> Result<(), ConfigError> {
        let m = &self.markers;
        check(m.size_m.is_finite() && m.size_m > 0.0 && m.size_m <= 2.0, "markers.size_m", || {
            format!("{} m: expected more than 0, at most 2", m.size_m)
        })?;
        check((1..=16).contains(&m.tags_per_robot), "markers.tags_per_robot", || {
            format!("{}: expected 1..=16", m.tags_per_robot)
        })?;
        check(
            m.min_interval_s.is_finite() && (0.0..=3600.0).contains(&m.min_interval_s),
            "markers.min_interval_s",
            || format!("{} s: expected 0..=3600", m.min_interval_s),
        )?;
        check(m.max_distance_m.is_finite() && m.max_distance_m > 0.0, "markers.max_distance_m", || {
            format!("{} m: must be positive", m.max_distance_m)
        })?;
        check(m.mounting.len() <= m.tags_per_robot as usize, "markers.mounting", || {
            format!("{} mountings for {} tags per robot", m.mounting.len(), m.tags_per_robot)
        })?;
        for (k, pose) in m.mounting.iter().enumerate() {
            pose.to_isometry()
                .map_err(|problem| ConfigError::Invalid { key: format!("markers.mounting[{k}]"), problem })?;
        }
        check(!m.detect || !m.mounting.is_empty(), "markers.mounting", || {
            "required with markers.detect = true (where the team's tags sit on a robot)".into()
        })?;
        let needs_lut = m.model.uncertainty_model().needs_lut();
        check(!m.detect || !needs_lut || m.lut.is_some(), "markers.lut", || {
            let model = if m.model == MarkerModelConfig::Lut { "lut" } else { "lut_online" };
            format!("required by markers.model = \"{model}\" (marker-lut --out FILE makes one for a camera)")
        })?;
        Ok(())
    }

    fn validate_link(&self) -> Result<(), ConfigError> {
        let l = &self.link;
        check(
            l.bandwidth_bytes_per_s > 0 && l.bandwidth_bytes_per_s <= 1_000_000_000,
            "link.bandwidth_bytes_per_s",
            || format!("{}: expected 1..=1e9 bytes/s", l.bandwidth_bytes_per_s),
        )?;
        let mut seen = std::collections::BTreeSet::new();
        for (i, peer) in l.peers.iter().enumerate() {
            let key = format!("link.peers[{i}].robot_id");
            check(peer.robot_id != self.robot.id, &key, || format!("{} is this robot's own id", peer.robot_id))?;
            check(seen.insert(peer.robot_id), &key, || format!("robot {} is listed twice", peer.robot_id))?;
        }
        if let Some(feed) = &l.ground_feed {
            check(feed.parse::<SocketAddr>().is_ok(), "link.ground_feed", || {
                format!("`{feed}` is not an `ip:port` address")
            })?;
        }
        check(
            (1_000..=1_000_000_000).contains(&l.ground_bandwidth_bytes_per_s),
            "link.ground_bandwidth_bytes_per_s",
            || {
                // Below 1 kB/s a telemetry report and a submap chunk no longer fit a second.
                format!("{}: expected 1000..=1e9 bytes/s", l.ground_bandwidth_bytes_per_s)
            },
        )?;
        if let Some(path) = &l.ground_key_file {
            // Loaded here so that a missing or unsafe key stops the rover before it starts; the
            // error names the file, never the key.
            if let Err(e) = hal::keyfile::load_auth_key(path) {
                return Err(ConfigError::Invalid { key: "link.ground_key_file".into(), problem: e.to_string() });
            }
        }
        match l.kind {
            LinkKind::Udp => {
                check(l.bind.parse::<SocketAddr>().is_ok(), "link.bind", || {
                    format!("`{}` is not an `ip:port` address (e.g. 0.0.0.0:47000)", l.bind)
                })?;
                for (i, peer) in l.peers.iter().enumerate() {
                    check(peer.address.parse::<SocketAddr>().is_ok(), &format!("link.peers[{i}].address"), || {
                        format!("`{}` is not an `ip:port` address", peer.address)
                    })?;
                }
            }
            LinkKind::Serial => {
                check(l.serial_device.as_deref().is_some_and(|d| !d.is_empty()), "link.serial_device", || {
                    "required with link.kind = \"serial\"".into()
                })?;
                check((300..=4_000_000).contains(&l.serial_baud), "link.serial_baud", || {
                    format!("{}: expected 300..=4000000", l.serial_baud)
                })?;
            }
            LinkKind::Can => {
                let interface = l.can_interface.as_deref().unwrap_or_default();
                interface.parse::<hal::can::interface::CanInterface>().map_err(|e| ConfigError::Invalid {
                    key: "link.can_interface".into(),
                    problem: format!("{interface:?}: {e}"),
                })?;
            }
            LinkKind::None => {}
        }
        Ok(())
    }
}

impl DevicesConfig {
    fn validate(&self) -> Result<(), ConfigError> {
        let key = |k: &str| format!("driver.devices.{k}");
        check(!self.imu_port.is_empty(), &key("imu_port"), || "required".into())?;
        check((300..=4_000_000).contains(&self.imu_baud), &key("imu_baud"), || {
            format!("{}: expected 300..=4000000", self.imu_baud)
        })?;
        self.can_interface.parse::<hal::can::interface::CanInterface>().map_err(|e| ConfigError::Invalid {
            key: key("can_interface"),
            problem: format!("{:?}: {e}", self.can_interface),
        })?;
        let mut nodes: Vec<u8> = self.wheel_nodes.iter().copied().chain(self.head_node).collect();
        check(nodes.iter().all(|n| (1..=127).contains(n)), &key("wheel_nodes"), || {
            format!("{nodes:?}: CANopen node ids are 1..=127")
        })?;
        nodes.sort_unstable();
        nodes.dedup();
        check(nodes.len() == 4 + usize::from(self.head_node.is_some()), &key("wheel_nodes"), || {
            "the wheel drives and the head need distinct node ids".into()
        })?;
        check((1..=1000).contains(&self.sync_period_ms), &key("sync_period_ms"), || {
            format!("{} ms: expected 1..=1000", self.sync_period_ms)
        })?;
        check(self.heartbeat_timeout_ms > self.sync_period_ms, &key("heartbeat_timeout_ms"), || {
            "must exceed the SYNC period".into()
        })?;
        for (name, value) in [("wheel_radius_m", self.wheel_radius_m), ("track_width_m", self.track_width_m)] {
            check(value.is_finite() && value > 0.0 && value < 10.0, &key(name), || {
                format!("{value}: expected more than 0 and less than 10 m")
            })?;
        }
        check(self.counts_per_rev > 0, &key("counts_per_rev"), || "must be positive".into())?;
        check(
            self.wheel_relative_sigma.is_finite() && self.wheel_relative_sigma > 0.0,
            &key("wheel_relative_sigma"),
            || "must be positive".into(),
        )?;
        Ok(())
    }
}

fn validate_task_rate(name: &str, task: &TaskRate) -> Result<(), ConfigError> {
    check(task.hz.is_finite() && task.hz > 0.0 && task.hz <= 1000.0, &format!("rates.{name}.hz"), || {
        format!("{} Hz: expected more than 0, at most 1000", task.hz)
    })?;
    check(task.deadline_fraction.is_none() || task.deadline_ns.is_none(), &format!("rates.{name}"), || {
        "give deadline_fraction or deadline_ns, not both".into()
    })?;
    if let Some(f) = task.deadline_fraction {
        check(f.is_finite() && f > 0.0 && f <= 1.0, &format!("rates.{name}.deadline_fraction"), || {
            format!("{f}: expected more than 0, at most 1 (the deadline lies within the period)")
        })?;
    }
    if let Some(ns) = task.deadline_ns {
        check(ns > 0 && ns <= task.period_ns(), &format!("rates.{name}.deadline_ns"), || {
            format!("{ns} ns: expected 1..={} ns (the period)", task.period_ns())
        })?;
    }
    Ok(())
}

fn check(ok: bool, key: &str, problem: impl FnOnce() -> String) -> Result<(), ConfigError> {
    if ok { Ok(()) } else { Err(ConfigError::Invalid { key: key.into(), problem: problem() }) }
}

/// Turns a toml/serde error into one naming the dotted key at the error's position: toml's own
/// message names the field but not its table.
fn syntax_error(text: &str, error: &toml::de::Error) -> ConfigError {
    let problem = error.message().trim().to_string();
    let Some(offset) = error.span().map(|s| s.start.min(text.len())) else {
        return ConfigError::Syntax { key: "(document)".into(), line: 1, problem };
    };
    let before = text.get(..offset).unwrap_or("");
    let line = before.matches('\n').count() + 1;
    let line_text = text.lines().nth(line - 1).unwrap_or("").trim();
    let above = &before[..before.rfind('\n').map_or(0, |i| i + 1)];
    let table = above
        .lines()
        .rev()
        .map(str::trim)
        .find(|l| l.starts_with('['))
        .map(|l| l.trim_start_matches('[').split(']').next().unwrap_or("").trim().to_string());
    let key = if let Some(header) = line_text.strip_prefix('[') {
        header.trim_start_matches('[').split(']').next().unwrap_or("").trim().to_string()
    } else if let Some((k, _)) = line_text.split_once('=') {
        let k = k.trim().trim_matches('"');
        match table {
            Some(t) if !t.is_empty() => format!("{t}.{k}"),
            _ => k.to_string(),
        }
    } else {
        table.unwrap_or_else(|| "(document)".into())
    };
    ConfigError::Syntax { key, line, problem }
}
