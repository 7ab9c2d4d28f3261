//! One robot's nodes built from its configuration: the only place the process runner
//! ([`crate::process::node_main`]), the lockstep runners and `onboard vio` get their vision,
//! filter and mapper from, so that all of them run the same code with the same settings.

use std::sync::Arc;

use filter::FilterConfig;
use hal::sensor::StereoCalibration;
use mapper::matching::{MatchMode, MatcherParams};
use mapper::pairing::{DeltaSigma, PairingParams, matcher_precision_m};
use mapper::scheduler::{Executor, SchedulerConfig};
use vision::apriltag::TagDetectorConfig;
use vision::marker_pose::MarkerLut;

use crate::config::{DeltaSigmaConfig, MatchModeConfig, RoverConfig, VoUpdatesConfig};
use crate::nodes::NodeError;
use crate::nodes::filter::{FilterNode, FilterNodeOptions};
use crate::nodes::mapper::MapperConfig;
use crate::nodes::markers::MarkerOptions;
use crate::nodes::vision::{VisionNode, VisionNodeOptions};
use crate::sensors::SensorSetup;
use crate::vio::{VioOptions, VoUpdates};

/// Protocol robot id of the robot with configuration id `id` (protocol ids start at 1).
pub fn protocol_robot_id(id: u16) -> u16 {
    id.saturating_add(1)
}

/// The filter's configuration: the IMU noise of `setup` (the configuration's, else the dataset's),
/// the site's gravity, the IMU rate and the initial bias sigmas of `config`.
pub fn filter_config(config: &RoverConfig, setup: &SensorSetup) -> FilterConfig {
    let mut filter = FilterConfig::from_imu_noise(setup.imu_noise, config.imu.gravity_mps2);
    filter.imu_rate_hz = config.rates.imu_hz;
    filter.gyro_scale_sigma = config.imu.gyro_scale_sigma;
    if let Some(sigma) = config.imu.gyro_bias_sigma_radps {
        filter.initial.gyro_bias_radps = sigma;
    }
    if let Some(sigma) = config.imu.accel_bias_sigma_mps2 {
        filter.initial.accel_bias_mps2 = sigma;
    }
    filter
}

/// The odometry and filter options of `config` (IMU only when the source has one).
pub fn vio_options(config: &RoverConfig, setup: &SensorSetup) -> VioOptions {
    let f = &config.filter;
    let v = &config.vision;
    VioOptions {
        sgm: v.sgm_depth_for_vo,
        sgm_threads: v.sgm_threads,
        use_imu: f.use_imu && setup.has_imu,
        use_wheel: f.use_wheel,
        zupt: f.zupt,
        latency_ns: (f.vo_latency_ms * 1e6).round() as u64,
        filter: filter_config(config, setup),
        init_window_ns: (f.init_window_ms * 1e6).round() as u64,
        end_stamp_ns: config.driver.end_stamp_ns(),
        vo_prior: v.vo_prior,
        vo_updates: match f.vo_updates {
            VoUpdatesConfig::EveryFrame => VoUpdates::EveryFrame,
            VoUpdatesConfig::Keyframes => VoUpdates::Keyframes,
        },
        vo_covariance_scale: f.vo_covariance_scale,
        ..VioOptions::default()
    }
}

/// The vision node's options.
pub fn vision_options(config: &RoverConfig, setup: &SensorSetup) -> VisionNodeOptions {
    let mut options = VisionNodeOptions::from_vio(&vio_options(config, setup));
    options.sgm.disparities = config.vision.sgm_disparities;
    options.despeckle = config.vision.despeckle;
    options.prior_wait_ns = (config.vision.prior_wait_ms * 1e6).round() as u64;
    options.gaze = config.gaze.enabled.then(|| config.gaze.options());
    options.vo_head_gate_rad =
        (config.gaze.enabled && config.gaze.vo_head_gate_rad > 0.0).then_some(config.gaze.vo_head_gate_rad);
    options.obstacles.hidden_drop_m = config.vision.hidden_drop_m;
    options
}

pub fn vision_node(config: &RoverConfig, setup: &SensorSetup) -> Result<VisionNode, NodeError> {
    let mut options = vision_options(config, setup);
    options.markers = marker_options(config).map_err(|reason| NodeError::Failed { node: "vision", reason })?;
    VisionNode::new(&setup.calibration, options)
}

/// The vision node's marker detection of `[markers]` (`None` with `detect = false`), its table
/// read from `markers.lut`.
pub fn marker_options(config: &RoverConfig) -> Result<Option<MarkerOptions>, String> {
    let m = &config.markers;
    if !m.detect {
        return Ok(None);
    }
    let lut = match &m.lut {
        Some(path) => {
            let bytes = std::fs::read(path).map_err(|e| format!("markers.lut {}: {e}", path.display()))?;
            let lut = MarkerLut::decode(&bytes).map_err(|e| format!("markers.lut {}: {e}", path.display()))?;
            Some(Arc::new(lut))
        }
        None => None,
    };
    Ok(Some(MarkerOptions {
        detector: TagDetectorConfig::default(),
        right_image: m.right_image,
        size_m: m.size_m,
        model: m.model.uncertainty_model(),
        lut,
    }))
}

/// The filter node (no checkpoint: the process runner adds its path).
pub fn filter_node(config: &RoverConfig, setup: &SensorSetup) -> FilterNode {
    FilterNode::new(FilterNodeOptions::from_vio(&vio_options(config, setup)))
}

/// The calibration of the images vision publishes its disparity for (rectified as
/// [`VisionNode`] does), without building a vision node and its SGM matcher.
pub fn rectified_calibration(setup: &SensorSetup) -> Result<StereoCalibration, vision::RectifyError> {
    if setup.calibration.rectified {
        return Ok(setup.calibration);
    }
    Ok(vision::Rectifier::new(&setup.calibration)?.rectified_calibration())
}

/// The mapper's configuration: the robot's protocol id, the rectified head, `[mapper]`.
pub fn mapper_config(config: &RoverConfig, rectified: StereoCalibration) -> MapperConfig {
    let mut mapper = MapperConfig::new(protocol_robot_id(config.robot.id), rectified);
    mapper.policy = mapper::submap::SubmapPolicy {
        max_position_sigma_m: config.mapper.max_position_sigma_m,
        max_distance_m: config.mapper.submap_max_distance_m,
    };
    if let Some(limit_m) = config.mapper.max_depth_error_m {
        mapper.integrator.max_depth_error_m = limit_m;
    }
    mapper.graph.consistency = config.mapper.inter_robot_consistency.check();
    mapper.markers = team_markers(config);
    mapper.marker_min_interval_ns = (config.markers.min_interval_s * 1e9) as u64;
    mapper.marker_max_distance_m = config.markers.max_distance_m;
    mapper.matching = matching_config(config, &rectified);
    mapper
}

/// The matcher's settings of `[matching]` (`None` when it is off), run inline: the process
/// runner's mapper moves it to a background thread. Eq. 6.3's precision comes from this robot's
/// rectified head (the thesis's LRU: f = 1080 px, b = 0.09 m).
pub fn matching_config(config: &RoverConfig, rectified: &StereoCalibration) -> Option<SchedulerConfig> {
    let m = &config.matching;
    if !m.enabled {
        return None;
    }
    let matcher = MatcherParams::with_mode(match m.mode {
        MatchModeConfig::FourD => MatchMode::FourDof,
        MatchModeConfig::SixD => MatchMode::SixDof,
    });
    let pairing = PairingParams {
        min_overlap_m2: m.min_overlap_m2,
        overlap_weight_per_m2: m.overlap_weight_per_m2,
        precision_m: matcher_precision_m(
            rectified.left.intrinsics.fx_px,
            rectified.baseline_m,
            m.precision_disparity_px,
            m.precision_view_distance_m,
        ),
        delta_sigma: match m.delta_sigma {
            DeltaSigmaConfig::Thesis => DeltaSigma::ThesisDifference,
            DeltaSigmaConfig::Sum => DeltaSigma::Sum,
        },
    };
    let mut scheduler = SchedulerConfig::new(matcher, pairing, Executor::Inline);
    scheduler.attempt_period_ns = (m.attempt_period_s * 1e9) as u64;
    Some(scheduler)
}

/// The team's tag mountings of `[markers]` (validated with the configuration); `None` without
/// any.
pub fn team_markers(config: &RoverConfig) -> Option<mapper::slam::TeamMarkers> {
    let m = &config.markers;
    let t_body_marker: Vec<_> = m.mounting.iter().filter_map(|pose| pose.to_isometry().ok()).collect();
    (!t_body_marker.is_empty()).then_some(mapper::slam::TeamMarkers { tags_per_robot: m.tags_per_robot, t_body_marker })
}
