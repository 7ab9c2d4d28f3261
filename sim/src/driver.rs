//! One robot's sensors as a `hal` sensor source (owned by the world helper).

use std::sync::Arc;

use hal::sensor::{SensorError, SensorEvent, SensorSource, StereoCalibration, StereoFrame};
use nalgebra::Vector3;

use crate::trajectory::KinematicState;
use crate::world::World;

/// Ground truth of one robot at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundTruthSample {
    pub stamp_ns: u64,
    pub state: KinematicState,
    pub gyro_bias_radps: Vector3<f64>,
    pub accel_bias_mps2: Vector3<f64>,
}

/// Streams one robot's IMU (every IMU period from 0), wheel odometry (rovers) and stereo pairs,
/// in timestamp order; at equal stamps IMU, then wheel odometry, then stereo.
#[derive(Debug)]
pub struct SimSensorSource {
    world: Arc<World>,
    robot: usize,
}

impl SimSensorSource {
    pub fn new(world: Arc<World>, robot: usize) -> Result<Self, SensorError> {
        if robot >= world.robots.len() {
            return Err(SensorError::Source(format!("no robot {robot}")));
        }
        Ok(SimSensorSource { world, robot })
    }

    pub fn world(&self) -> &Arc<World> {
        &self.world
    }

    pub fn robot(&self) -> usize {
        self.robot
    }

    /// Ground truth at `stamp_ns` (biases as of the last IMU sample).
    pub fn ground_truth(&self, stamp_ns: u64) -> Option<GroundTruthSample> {
        let _ = stamp_ns;
        None
    }

    /// Left-camera depth of the last stereo frame (ground truth for stereo tests).
    pub fn last_depth_m(&self) -> &[f32] {
        &[]
    }
}

impl SensorSource for SimSensorSource {
    fn stereo_calibration(&self) -> Option<StereoCalibration> {
        None
    }

    fn next_event(&mut self, frame: &mut StereoFrame) -> Result<Option<SensorEvent>, SensorError> {
        let _ = frame;
        Ok(None)
    }
}
