//! The simulated site and team of a mission, and the per-robot ground truth in the robot's own
//! frame.

use std::sync::Arc;

use nalgebra::Isometry3;
use sim::scenario::{self, ScenarioOptions};
use sim::truth_constraints::{TruthConstraintConfig, TruthConstraints};
use sim::world::World;

use hal::sensor::StereoCalibration;

use super::{MissionError, MissionOptions};
use crate::nodes::mapper::MapperConfig;

/// The world of `options`: the scenario preset with `robots` rovers on its start ring.
pub fn mission_world(options: &MissionOptions) -> Result<Arc<World>, MissionError> {
    let scenario_options = ScenarioOptions {
        robots: options.robots,
        duration_s: options.duration_s,
        seed: options.seed,
        downscale: options.downscale,
        world_size_m: None,
        flyer: false,
    };
    let scenario =
        scenario::preset(&options.scenario, &scenario_options).map_err(|e| MissionError::World(e.to_string()))?;
    World::build(&scenario).map_err(|e| MissionError::World(e.to_string()))
}

/// Protocol robot id of robot index `robot` (protocol ids start at 1).
pub fn robot_id(robot: usize) -> u16 {
    robot as u16 + 1
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
    let source = TruthConstraints::new(Arc::clone(world), TruthConstraintConfig::default());
    let t_world_own = source.true_origin(robot, initialized_ns)?;
    let t_own_world = t_world_own.inverse();
    Some(truth_world.iter().filter(|(s, _)| *s >= initialized_ns).map(|(s, t)| (*s, t_own_world * t)).collect())
}

/// The mapper's configuration for robot `robot` whose images are `1 / downscale` of 1024×508.
/// The integrator's depth-error limit is set for full resolution; at `1/k` resolution the same
/// disparity error is `k` times larger in depth (`Δz = z²·Δd / (f·b)`), so `k` times the limit
/// keeps the mapped range the same (about 4.5 m on the LRU head).
pub fn mapper_config(robot: usize, calibration: StereoCalibration, downscale: u32) -> MapperConfig {
    let mut config = MapperConfig::new(robot_id(robot), calibration);
    config.integrator.max_depth_error_m *= f64::from(downscale.max(1));
    config
}
