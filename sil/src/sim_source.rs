//! The simulator as the rover's sensors: the [`SourceProvider`] the `sil` binary hands to the
//! firmware's processes (`sil run`, `sil node`), and the rover configuration of a simulated robot.
//!
//! A simulated robot's `rover.toml` is an ordinary firmware configuration: the stereo head's
//! calibration, the IMU's noise model, the site's gravity and the sensor rates are written into it
//! from the scenario, exactly as a real rover's come from its calibration. The firmware never asks
//! the simulator; only the driver process, through this provider, renders the world:
//!
//! ```toml
//! [driver]
//! kind = "sim"
//! duration_s = 120.0
//! [driver.sim]
//! scenario = "moon"   # sim::scenario::preset
//! seed = 1
//! robots = 2          # the team (this robot is robot.id)
//! downscale = 4       # 1024x508 / downscale
//! ```

use std::path::{Path, PathBuf};
use std::sync::Arc;

use hal::sensor::{SensorSource, StereoCalibration};
use onboard::config::calibration::PoseConfig;
use onboard::config::{CalibrationConfig, DriverKind, ImuNoiseConfig, MarkerModelConfig, ModeConfig, RoverConfig};
use onboard::sensors::{FirmwareSources, SensorSetupError, SourceProvider};
use serde::{Deserialize, Serialize};
use sim::driver::SimSensorSource;
use sim::scenario::{self, Scenario, ScenarioOptions};
use sim::world::World;

/// `[driver.sim]`: the simulated world a robot lives in.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimDriverConfig {
    /// `sim::scenario::preset` name: `moon` or `mars`.
    pub scenario: String,
    pub seed: u64,
    /// Robots in the team (the simulated robots are `0..robots`; this one is `robot.id`).
    pub robots: u16,
    /// Rendering at `1024x508 / downscale` (1, 2 or 4).
    pub downscale: u32,
    /// Shorter stands at the waypoints than the preset's 6 s (at least the filter's 0.5 s at-rest
    /// initialization: the first stand initializes it); the route is then planned over
    /// 4 × the duration and cut, so a short run drives most of its time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pause_s: Option<f64>,
    /// Rocks per 100 m² instead of the preset's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rocks_per_100m2: Option<f64>,
    /// Rocks in the routes' shared hub too (see `ScenarioOptions::rocks_in_hub`).
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub rocks_in_hub: bool,
}

impl SimDriverConfig {
    /// The `[driver.sim]` table of `config`, checked.
    pub fn of(config: &RoverConfig) -> Result<SimDriverConfig, String> {
        let table = config.driver.sim.clone().ok_or("driver.sim is missing")?;
        let sim: SimDriverConfig = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| format!("driver.sim: {}", e.message()))?;
        if !matches!(sim.downscale, 1 | 2 | 4) {
            return Err(format!("driver.sim.downscale {}: expected 1, 2 or 4", sim.downscale));
        }
        if !(1..=16).contains(&sim.robots) {
            return Err(format!("driver.sim.robots {}: expected 1..=16", sim.robots));
        }
        if let Some(pause_s) = sim.pause_s
            && !(pause_s.is_finite() && pause_s >= 0.5)
        {
            return Err(format!("driver.sim.pause_s {pause_s}: at least 0.5 s (the filter's at-rest start)"));
        }
        if config.robot.id >= sim.robots {
            return Err(format!(
                "robot.id {} is not a robot of the simulated team (0..{})",
                config.robot.id, sim.robots
            ));
        }
        Ok(sim)
    }

    pub fn table(&self) -> toml::Table {
        match toml::Value::try_from(self) {
            Ok(toml::Value::Table(table)) => table,
            _ => toml::Table::new(),
        }
    }

    fn scenario_options(&self, duration_s: f64) -> ScenarioOptions {
        let plan_s = if self.pause_s.is_some() { 4.0 * duration_s } else { duration_s };
        ScenarioOptions {
            robots: usize::from(self.robots),
            duration_s: plan_s,
            seed: self.seed,
            downscale: self.downscale,
            world_size_m: None,
            flyer: false,
            rocks_per_100m2: self.rocks_per_100m2,
            rocks_in_hub: self.rocks_in_hub,
        }
    }

    /// The scenario of this world (cheap: no terrain is built).
    pub fn scenario(&self, duration_s: f64) -> Result<Scenario, String> {
        let mut scenario = scenario::preset(&self.scenario, &self.scenario_options(duration_s))
            .map_err(|e| format!("scenario: {e}"))?;
        scenario.duration_s = duration_s;
        if let Some(pause_s) = self.pause_s {
            for robot in &mut scenario.robots {
                robot.drive.pause_s = pause_s;
            }
        }
        Ok(scenario)
    }

    /// The world (terrain, shadows, trajectories: seconds of CPU). Deterministic for the
    /// settings, so every process of a team that builds it gets the same world.
    pub fn world(&self, duration_s: f64) -> Result<Arc<World>, String> {
        World::build(&self.scenario(duration_s)?).map_err(|e| format!("world: {e}"))
    }
}

/// The simulated robot `robot`'s stereo calibration as its driver publishes the pairs.
pub fn sim_calibration(scenario: &Scenario, robot: usize) -> Option<StereoCalibration> {
    let model = &scenario.robots.get(robot)?.model;
    Some(model.camera.calibration(&model.t_body_cam(0.0, 0.0), model.head))
}

/// Writes into `config` everything the firmware must know about simulated robot `robot.id` of
/// `scenario`, as a real rover's calibration files would: the driver, the stereo head, the IMU's
/// noise and bias model, the site's gravity, the sensor rates, and the mapper's depth-error limit
/// scaled to the rendering resolution.
pub fn configure_sim_robot(
    config: &mut RoverConfig,
    sim: &SimDriverConfig,
    scenario: &Scenario,
    duration_s: f64,
) -> Result<(), String> {
    let robot = usize::from(config.robot.id);
    let calibration =
        sim_calibration(scenario, robot).ok_or_else(|| format!("robot {robot} is not in the scenario"))?;
    // The simulated rovers drive their routes on their own.
    config.robot.mode = ModeConfig::Autonomous;
    config.driver.kind = DriverKind::Sim;
    config.driver.replay_path = None;
    config.driver.duration_s = Some(duration_s);
    config.driver.sim = Some(sim.table());
    config.camera.rate_hz = scenario.camera_rate_hz;
    config.camera.calibration = Some(CalibrationConfig::from_calibration(&calibration));
    config.rates.imu_hz = scenario.imu_rate_hz;
    config.rates.wheel_hz = scenario.wheel.rate_hz;
    let noise = scenario.imu_noise;
    let densities = filter::config::ImuNoise::from(noise.densities(scenario.imu_rate_hz));
    config.imu.noise = Some(ImuNoiseConfig::from_noise(&densities));
    config.imu.gravity_mps2 = scenario.body.gravity_mps2();
    // The simulator's turn-on biases, as the datasheet would state them; its gyro has an ideal
    // scale.
    config.imu.gyro_bias_sigma_radps = Some(noise.gyro_bias_init_radps.max(1e-6));
    config.imu.accel_bias_sigma_mps2 = Some(noise.accel_bias_init_mps2.max(1e-6));
    config.imu.gyro_scale_sigma = 0.0;
    // The integrator's limit is set for full resolution; at 1/k resolution the same disparity
    // error is k times more depth error (Δz = z²·Δd / (f·b)), so k times the limit keeps the
    // mapped range the same (about 4.5 m on the LRU head).
    let default_limit = mapper::integrate::IntegratorConfig::default().max_depth_error_m;
    config.mapper.max_depth_error_m = Some(default_limit * f64::from(sim.downscale.max(1)));
    configure_sim_markers(config, scenario, &calibration);
    validate_sim_rates(config)
}

/// Where the marker uncertainty tables of the simulator's cameras are kept (`marker-lut
/// --downscale K`, one per rendering resolution; vision README "Robot markers").
pub const SIM_MARKER_LUT_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../onboard/vision/luts");

/// The committed table for a simulated camera of `width_px × height_px` and `size_m` tags, if
/// there is one (the vision node refuses it anyway if it was made for other intrinsics).
pub fn sim_marker_lut(width_px: u32, height_px: u32, size_m: f64) -> Option<PathBuf> {
    let size_cm = (size_m * 100.0).round() as u32;
    let path = Path::new(SIM_MARKER_LUT_DIR).join(format!("tag36h11_{size_cm}cm_sim_rover_{width_px}x{height_px}.lut"));
    path.exists().then_some(path)
}

/// Whether the table at `path` was made for `camera` and `size_m` tags (an unreadable one is not).
fn table_fits(path: &Path, camera: &StereoCalibration, size_m: f64) -> bool {
    std::fs::read(path)
        .ok()
        .and_then(|bytes| vision::marker_pose::MarkerLut::decode(&bytes).ok())
        .is_some_and(|lut| vision::marker_pose::check_lut(&lut, &camera.left.intrinsics, size_m).is_ok())
}

/// The team's tag mountings as the rover design states them (the simulator's rovers are all
/// alike: tag `3j + k` of robot `j` at the same place for every `j`), the tag size, and the
/// detector on: the thesis's model (table + online sampling) where the robot's camera has a
/// table, online sampling alone where it has none (the wide-angle and the flyer's cameras).
pub fn configure_sim_markers(config: &mut RoverConfig, scenario: &Scenario, camera: &StereoCalibration) {
    let Some(rover) = scenario.robots.iter().find(|r| r.model.markers.len() == 3) else {
        config.markers.mounting.clear();
        config.markers.detect = false;
        return;
    };
    let mut markers = rover.model.markers.clone();
    markers.sort_by_key(|m| m.tag_id % 3);
    config.markers.tags_per_robot = 3;
    config.markers.size_m = markers[0].size_m;
    config.markers.mounting = markers.iter().map(|m| PoseConfig::from_isometry(&m.t_body_marker)).collect();
    config.markers.detect = true;
    // Tables are named by resolution only; the wide head has the narrow one's resolution with
    // other intrinsics, so a table is taken only if it was made for this camera.
    config.markers.lut = sim_marker_lut(camera.left.width_px, camera.left.height_px, config.markers.size_m)
        .filter(|path| table_fits(path, camera, config.markers.size_m));
    config.markers.model =
        if config.markers.lut.is_some() { MarkerModelConfig::LutOnline } else { MarkerModelConfig::Online };
}

/// The simulator fires every sensor on the IMU's sample grid.
pub fn validate_sim_rates(config: &RoverConfig) -> Result<(), String> {
    let imu_hz = config.rates.imu_hz;
    for (key, hz) in [("camera.rate_hz", config.camera.rate_hz), ("rates.wheel_hz", config.rates.wheel_hz)] {
        let ratio = imu_hz / hz;
        if !(ratio >= 1.0 - 1e-9 && (ratio - ratio.round()).abs() <= 1e-6 * ratio) {
            return Err(format!(
                "{key} {hz} Hz does not divide rates.imu_hz {imu_hz} Hz (the simulator needs whole IMU periods)"
            ));
        }
    }
    Ok(())
}

/// The harness's sources: the simulator for `driver.kind = "sim"`, the firmware's own replays
/// otherwise.
#[derive(Debug, Clone, Copy, Default)]
pub struct SimSources;

impl SourceProvider for SimSources {
    fn open(&self, config: &RoverConfig) -> Result<Box<dyn SensorSource + Send>, SensorSetupError> {
        if config.driver.kind != DriverKind::Sim {
            return FirmwareSources.open(config);
        }
        let invalid = SensorSetupError::Invalid;
        let sim = SimDriverConfig::of(config).map_err(invalid)?;
        validate_sim_rates(config).map_err(invalid)?;
        let duration_s =
            config.driver.duration_s.ok_or_else(|| invalid("driver.duration_s is required in simulation".into()))?;
        let world = sim.world(duration_s).map_err(invalid)?;
        let source = SimSensorSource::new(world, usize::from(config.robot.id))
            .map_err(|e| invalid(format!("simulated sensors: {e}")))?;
        Ok(Box::new(source))
    }
}
