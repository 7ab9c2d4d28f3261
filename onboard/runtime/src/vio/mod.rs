//! Visual-inertial odometry on a [`hal::sensor::SensorSource`]: rectification, keyframe stereo
//! odometry, and the local reference filter (thesis §4.1), as the rover runs them.
//!
//! Data flow per event ([`VioPipeline::process_event`]):
//!
//! - **Stereo** (capture time `t_c`): the filter clones its state at `t_c` (the camera trigger,
//!   spec §2.1: "at the exact time of image capture"); the raw pair is rectified when the
//!   calibration is not rectified, optionally matched by SGM (`fpga_model`, as the FPGA does), and
//!   given to [`vision::StereoOdometry`] with the filter's keyframe→current motion as a prior. The
//!   result is *queued*: it reaches the filter only when the IMU stream passes `t_c + latency`
//!   (default 250 ms, the thesis's SGM + VO latency), so every VO update is a delayed update
//!   against the clone of its capture time.
//! - **IMU**: before initialization the samples are averaged; after [`VioOptions::init_window_ns`]
//!   of data the filter starts at rest (roll and pitch from the mean specific force, gyro bias from
//!   the mean rate, position and yaw zero). The IMU must therefore start while the robot stands
//!   still, as a rover does at power-up; a moving start needs [`VioPipeline::initialize_with_pose`].
//!   Frames before the start are skipped: the odometry's first keyframe must have a filter clone.
//!   Then: propagation, the queued VO results that are due (keyframe marking first, then the
//!   relative-pose update), a zero-velocity update at 10 Hz while [`filter::StandstillDetector`]
//!   says standing, the frame-switch policy, and one output pose per sample.
//! - **Wheel odometry**: a body-velocity update on arrival (wheel odometry has no processing delay).
//!
//! Without IMU the output is the odometry's own chained pose `t_odom_body`, one per frame.
//!
//! Output poses are always in the *first* local frame: after each frame switch the reported
//! `t_old_new` is chained, and `t_first_body = t_first_local · t_local_body`.

pub mod dataset;
pub mod pipeline;
pub mod score;

pub use dataset::{Dataset, DatasetKind, open_dataset};
pub use pipeline::{LocalPoseSample, VioPipeline, VioSummary};
pub use score::{Score, load_ground_truth, score};

use filter::FilterConfig;
use filter::config::ImuNoise;
use mapper::submap::SubmapPolicy;
use vision::VoConfig;

/// When the pipeline asks the filter for a frame-of-reference switch (the mapper's request in the
/// full system; thesis §4.1.2 starts a submap after 7 m or at 0.2 m position uncertainty). The
/// rules are OR-ed; with none set the filter never switches.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SwitchPolicy {
    /// Switch when the body is this far (straight line) from the current frame's origin.
    pub distance_m: Option<f64>,
    /// Switch when the largest position standard deviation (diagonal) exceeds this.
    pub sigma_m: Option<f64>,
    /// The mapper's rule, exactly as [`mapper::submap::Submapper::on_filter_state`] applies it: the
    /// worst-direction position sigma ([`SubmapPolicy::position_sigma_m`]) above
    /// `max_position_sigma_m`, or the path length of the filter's body positions since the last
    /// switch above `max_distance_m`. So the filter switches where the mapper would request it.
    pub submap: Option<SubmapPolicy>,
    /// Evaluate the rules only on the filter states whose stamp reaches the next multiple of
    /// this period (the mapper sees the filter pose with each image, i.e. at the camera rate);
    /// `None` = at every IMU sample. The submap path length is summed over the evaluated states,
    /// as the mapper sums the states it sees.
    pub period_ns: Option<u64>,
}

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

/// Configuration of a [`VioPipeline`].
#[derive(Debug, Clone, PartialEq)]
pub struct VioOptions {
    pub vo: VoConfig,
    /// Depth from the SGM disparity map (`fpga_model`) instead of sparse stereo matching.
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
    pub switch: SwitchPolicy,
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
    /// Log the filter's pose in its current local frame with covariance
    /// ([`VioPipeline::pose_log`]) on the filter state whose stamp reaches the next multiple of
    /// this period. `None` = no log. The simulator's IMU and camera share one grid from stamp 0
    /// (IMU 200 Hz, camera 10 Hz), so a 100 ms period logs exactly at the capture stamps.
    pub pose_log_period_ns: Option<u64>,
}

/// The EuRoC ADIS16448 densities (`imu0/sensor.yaml` of EuRoC), used when a dataset has none.
pub const EUROC_IMU_NOISE: ImuNoise = ImuNoise {
    gyro_noise_density: 1.6968e-4,
    gyro_random_walk: 1.9393e-5,
    accel_noise_density: 2.0e-3,
    accel_random_walk: 3.0e-3,
};

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
            switch: SwitchPolicy::default(),
            filter: FilterConfig {
                gyro_scale_sigma: EUROC_GYRO_SCALE_SIGMA,
                ..FilterConfig::from_imu_noise(EUROC_IMU_NOISE, EARTH_GRAVITY_MPS2)
            },
            init_window_ns: 500_000_000,
            end_stamp_ns: None,
            vo_prior: true,
            vo_updates: VoUpdates::EveryFrame,
            vo_covariance_scale: 8.0,
            pose_log_period_ns: None,
        }
    }
}

/// Why the pipeline stopped.
#[derive(Debug, thiserror::Error)]
pub enum VioError {
    #[error("{0}")]
    Sensor(#[from] hal::sensor::SensorError),
    #[error("{0}")]
    Rectify(#[from] vision::RectifyError),
    #[error("{0}")]
    Odometry(#[from] vision::VoError),
    #[error("{0}")]
    Filter(#[from] filter::FilterError),
    #[error("SGM: {0}")]
    Sgm(String),
    #[error("{0}")]
    Input(String),
}
