//! A scenario made real: terrain, shadows, every robot's trajectory (owned by the world helper).

use std::sync::Arc;

use nalgebra::Isometry3;

use crate::lighting::ShadowMap;
use crate::render::{Quad, Scene};
use crate::robot::RobotModel;
use crate::scenario::{RobotSetup, Scenario};
use crate::terrain::Terrain;
use crate::trajectory::{KinematicState, Trajectory};

/// One robot in the world.
#[derive(Debug, Clone)]
pub struct SimRobot {
    pub setup: RobotSetup,
    pub trajectory: Trajectory,
}

impl SimRobot {
    pub fn model(&self) -> &RobotModel {
        &self.setup.model
    }
}

/// Why a world could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WorldError {
    #[error("robot {robot}: {reason}")]
    Robot { robot: usize, reason: String },
}

/// Terrain, light and robots of a run; immutable once built, shared by the robots' drivers.
#[derive(Debug)]
pub struct World {
    pub scenario: Scenario,
    pub terrain: Terrain,
    pub shadows: ShadowMap,
    pub robots: Vec<SimRobot>,
}

impl World {
    /// Builds the world of `scenario` (deterministic for its seed).
    pub fn build(scenario: &Scenario) -> Result<Arc<World>, WorldError> {
        let terrain = Terrain::generate(&scenario.terrain, scenario.seed);
        let shadows = ShadowMap::compute(&terrain.heightfield, &scenario.sun);
        Ok(Arc::new(World { scenario: scenario.clone(), terrain, shadows, robots: Vec::new() }))
    }

    /// End of the run.
    pub fn end_ns(&self) -> u64 {
        (self.scenario.duration_s * 1e9).round() as u64
    }

    /// True state of robot `robot` at `stamp_ns`.
    pub fn robot_state(&self, robot: usize, stamp_ns: u64) -> Option<KinematicState> {
        self.robots.get(robot)?.trajectory.state_at(stamp_ns)
    }

    /// Pan and tilt of robot `robot`'s head at `stamp_ns`.
    pub fn head_angles(&self, robot: usize, stamp_ns: u64) -> (f64, f64) {
        let _ = (robot, stamp_ns);
        (0.0, 0.0)
    }

    /// Pose of robot `robot`'s left camera at `stamp_ns`.
    pub fn t_world_cam(&self, robot: usize, stamp_ns: u64) -> Option<Isometry3<f64>> {
        let state = self.robot_state(robot, stamp_ns)?;
        let (pan, tilt) = self.head_angles(robot, stamp_ns);
        Some(state.t_world_body * self.robots[robot].model().t_body_cam(pan, tilt))
    }

    /// The faces of every robot except `exclude` at `stamp_ns`, appended to `out`.
    pub fn quads_at(&self, stamp_ns: u64, exclude: Option<usize>, out: &mut Vec<Quad>) {
        for (i, robot) in self.robots.iter().enumerate() {
            if Some(i) == exclude {
                continue;
            }
            if let Some(state) = robot.trajectory.state_at(stamp_ns) {
                robot.model().append_quads(&state.t_world_body, out);
            }
        }
    }

    /// The scene for rendering with the given robot faces.
    pub fn scene<'a>(&'a self, quads: &'a [Quad]) -> Scene<'a> {
        Scene {
            terrain: &self.terrain,
            shadows: &self.shadows,
            sun: self.scenario.sun,
            reflectance: self.scenario.reflectance,
            sky_radiance: self.scenario.sky_radiance,
            quads,
        }
    }
}
