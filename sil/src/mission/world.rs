//! The simulated site and team of a mission, each robot's firmware configuration, and the
//! per-robot ground truth in the robot's own frame.

use std::sync::Arc;

use nalgebra::Isometry3;
use onboard::config::{MarkerModelConfig, RoverConfig};
use sim::truth_constraints::{TruthConstraintConfig, TruthConstraints};
use sim::world::World;

use super::{MissionError, MissionOptions};
use crate::sim_source::{SimDriverConfig, configure_sim_robot};

/// The `[driver.sim]` world of `options`.
pub fn sim_driver_config(options: &MissionOptions) -> SimDriverConfig {
    SimDriverConfig {
        scenario: options.scenario.clone(),
        seed: options.seed,
        robots: options.robots as u16,
        downscale: options.downscale,
        pause_s: None,
        rocks_per_100m2: options.rocks_per_100m2,
        rocks_in_hub: options.rocks_in_hub,
    }
}

/// The world of `options`: the scenario preset with `robots` rovers on its start ring.
pub fn mission_world(options: &MissionOptions) -> Result<Arc<World>, MissionError> {
    sim_driver_config(options).world(options.duration_s).map_err(MissionError::World)
}

/// Robot `robot`'s firmware configuration in the mission: a simulated driver in the mission's
/// world, the head's calibration and the IMU model from the scenario, the mission's submap
/// length. Both runners build the robot's nodes from it (the process runner also gives it its
/// links and real-time settings).
pub fn robot_config(options: &MissionOptions, world: &World, robot: usize) -> Result<RoverConfig, MissionError> {
    let mut config = RoverConfig::default();
    config.robot.id = robot as u16;
    config.robot.name = format!("robot{robot}");
    configure_sim_robot(&mut config, &sim_driver_config(options), &world.scenario, options.duration_s)
        .map_err(MissionError::Setup)?;
    match options.markers {
        None => config.markers.detect = false,
        Some(model) if config.markers.detect => {
            if model.uncertainty_model().needs_lut() && config.markers.lut.is_none() {
                // A camera without a table (wide-angle, flyer): the sampling alone.
                config.markers.model = MarkerModelConfig::Online;
            } else {
                config.markers.model = model;
            }
        }
        Some(_) => {}
    }
    match options.matching {
        None => config.matching.enabled = false,
        Some(mode) => config.matching.mode = mode,
    }
    // Only a head can be pointed (the flyer's cameras are fixed).
    config.gaze.enabled = options.gaze && world.robots[robot].model().head.is_some();
    config.mapper.inter_robot_consistency = options.consistency;
    if let Some(distance_m) = options.submap_max_distance_m {
        config.mapper.submap_max_distance_m = distance_m;
    }
    Ok(config)
}

/// Protocol robot id of robot index `robot` (protocol ids start at 1).
pub fn robot_id(robot: usize) -> u16 {
    onboard::stack::protocol_robot_id(robot as u16)
}

/// The capture stamps of the simulated cameras (on the IMU grid, as `sim::driver` fires them)
/// and `t_world_body` of robot `robot` at each: the ground truth of every image.
pub fn truth_at_captures(world: &World, robot: usize) -> Vec<(u64, Isometry3<f64>)> {
    let s = &world.scenario;
    let tick_ns = ((1e9 / s.imu_rate_hz).round() as u64).max(1);
    let every = ((1e9 / s.camera_rate_hz / tick_ns as f64).round() as u64).max(1);
    (0..)
        .map(|k: u64| k * every * tick_ns)
        .take_while(|&stamp| stamp < world.end_ns())
        .filter_map(|stamp| Some((stamp, world.robot_state(robot, stamp)?.t_world_body)))
        .collect()
}

/// The world in the robot's own frame (see [`truth_in_own_frame`]).
fn t_own_world(world: &Arc<World>, robot: usize, initialized_ns: u64) -> Option<Isometry3<f64>> {
    let source = TruthConstraints::new(Arc::clone(world), TruthConstraintConfig::default());
    Some(source.true_origin(robot, initialized_ns)?.inverse())
}

/// `truth_world` (stamp, `t_world_body`) re-expressed in the robot's own frame: its filter's first
/// local frame, which the filter put at the body's position with the body's yaw (gravity
/// aligned) at `initialized_ns`. `None` if the world has no state at that stamp.
pub fn truth_in_own_frame(
    world: &Arc<World>,
    robot: usize,
    initialized_ns: u64,
    truth_world: &[(u64, Isometry3<f64>)],
) -> Option<Vec<(u64, Isometry3<f64>)>> {
    let t_own_world = t_own_world(world, robot, initialized_ns)?;
    Some(truth_world.iter().filter(|(s, _)| *s >= initialized_ns).map(|(s, t)| (*s, t_own_world * t)).collect())
}

/// Per connected other robot of `estimate` (robot index `robot`'s graph): the distance between
/// the robot's latest pose in the graph and its true pose at that stamp, both in the own frame
/// (the filter's first frame at `initialized_ns`, as [`truth_in_own_frame`]).
pub fn inter_robot_errors(
    world: &Arc<World>,
    robot: usize,
    initialized_ns: u64,
    latest: &[(u16, u64, Isometry3<f64>)],
) -> std::collections::BTreeMap<u16, f64> {
    let Some(t_own_world) = t_own_world(world, robot, initialized_ns) else { return Default::default() };
    latest
        .iter()
        .filter(|(other, _, _)| *other != robot_id(robot))
        .filter_map(|&(other, stamp_ns, t_own_body)| {
            let index = usize::from(other).checked_sub(1)?;
            let truth = t_own_world * world.robot_state(index, stamp_ns)?.t_world_body;
            Some((other, (truth.translation.vector - t_own_body.translation.vector).norm()))
        })
        .collect()
}

/// The report's name of the mission's marker model (`None`: no detector).
pub fn marker_model_name(options: &super::MissionOptions) -> Option<String> {
    options.markers.map(|m| m.uncertainty_model().name().to_owned())
}
