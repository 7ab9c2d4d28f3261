//! One robot's sensors as a `hal` sensor source (owned by the world helper).
//!
//! Time runs on the IMU's grid: tick `k` is `k · (1 / imu_rate)`; wheel odometry and stereo fire
//! on the ticks that are multiples of their own periods (rounded to whole ticks). Every stream is
//! keyed by the scenario seed and the robot id, so a robot's data do not depend on how many other
//! robots there are or in which order their drivers run.

use std::sync::Arc;

use hal::sensor::{
    HeadTarget, SensorError, SensorEvent, SensorSource, StereoCalibration, StereoInfo, check_stereo_buffers,
    no_pending_pair,
};
use nalgebra::Vector3;

use crate::head_servo::HeadServo;
use crate::imu::ImuSimulator;
use crate::render::{Quad, Renderer};
use crate::rng::{self, streams};
use crate::robot::RobotKind;
use crate::trajectory::KinematicState;
use crate::wheel::WheelOdometer;
use crate::world::World;

/// Ground truth of one robot at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GroundTruthSample {
    pub stamp_ns: u64,
    pub state: KinematicState,
    pub gyro_bias_radps: Vector3<f64>,
    pub accel_bias_mps2: Vector3<f64>,
}

/// Which sensor fires next within a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Slot {
    Imu,
    Wheel,
    Stereo,
}

/// Streams one robot's IMU (every IMU period from 0), wheel odometry (rovers) and stereo pairs,
/// in timestamp order; at equal stamps IMU, then wheel odometry, then stereo. Events run over
/// `[0, world.end_ns())`.
#[derive(Debug)]
pub struct SimSensorSource {
    world: Arc<World>,
    robot: usize,
    renderer: Renderer,
    imu: ImuSimulator,
    wheel: Option<WheelOdometer>,
    /// Faces of the other robots, refilled for every frame (capacity kept).
    quads: Vec<Quad>,
    tick_ns: u64,
    wheel_every: u64,
    stereo_every: u64,
    tick: u64,
    slot: Slot,
    stereo_sequence: u64,
    /// The pair announced by `next_event`: rendered only when it is read.
    pending: Option<StereoInfo>,
    /// The head once a firmware commands it (before: the scenario's script).
    head: Option<HeadServo>,
}

/// Ticks between events of a sensor at `rate_hz` on a grid of `tick_ns` (at least one).
fn ticks_between(rate_hz: f64, tick_ns: u64) -> u64 {
    ((1e9 / rate_hz / tick_ns as f64).round() as u64).max(1)
}

impl SimSensorSource {
    pub fn new(world: Arc<World>, robot: usize) -> Result<Self, SensorError> {
        let Some(r) = world.robots.get(robot) else {
            return Err(SensorError::Source(format!("no robot {robot}")));
        };
        let s = &world.scenario;
        for (what, rate) in [("IMU", s.imu_rate_hz), ("camera", s.camera_rate_hz), ("wheel", s.wheel.rate_hz)] {
            if !(rate.is_finite() && rate > 0.0) {
                return Err(SensorError::Source(format!("{what} rate must be positive, got {rate} Hz")));
            }
        }
        let id = u64::from(r.setup.id);
        let tick_ns = ((1e9 / s.imu_rate_hz).round() as u64).max(1);
        let imu = ImuSimulator::new(
            s.imu_noise,
            s.body.gravity_world_mps2(),
            s.imu_rate_hz,
            rng::stream_seed(s.seed, &[streams::IMU, id]),
        );
        let wheel = (r.model().kind == RobotKind::Rover)
            .then(|| WheelOdometer::new(s.wheel, rng::stream_seed(s.seed, &[streams::WHEEL, id])));
        let renderer = Renderer::new(r.model().camera, s.sensor);
        let quads = Vec::with_capacity(world.robots.len() * 64);
        Ok(SimSensorSource {
            renderer,
            imu,
            wheel,
            quads,
            tick_ns,
            wheel_every: ticks_between(s.wheel.rate_hz, tick_ns),
            stereo_every: ticks_between(s.camera_rate_hz, tick_ns),
            tick: 0,
            slot: Slot::Imu,
            stereo_sequence: 0,
            pending: None,
            head: None,
            world,
            robot,
        })
    }

    pub fn world(&self) -> &Arc<World> {
        &self.world
    }

    pub fn robot(&self) -> usize {
        self.robot
    }

    /// Ground truth at `stamp_ns` (biases as of the last IMU sample).
    pub fn ground_truth(&self, stamp_ns: u64) -> Option<GroundTruthSample> {
        let state = self.world.robot_state(self.robot, stamp_ns)?;
        let (gyro_bias_radps, accel_bias_mps2) = self.imu.biases();
        Some(GroundTruthSample { stamp_ns, state, gyro_bias_radps, accel_bias_mps2 })
    }

    /// Left-camera depth of the last stereo frame (ground truth for stereo tests).
    pub fn last_depth_m(&self) -> &[f32] {
        self.renderer.depth_m()
    }

    /// Stereo frames announced so far.
    pub fn frames_delivered(&self) -> u64 {
        self.stereo_sequence
    }

    fn state(&self, stamp_ns: u64) -> Result<KinematicState, SensorError> {
        self.world
            .robot_state(self.robot, stamp_ns)
            .ok_or_else(|| SensorError::Source(format!("robot {}: no trajectory at {stamp_ns} ns", self.robot)))
    }

    /// Moves to the next slot that has an event, `None` when past the end of the run.
    fn advance(&mut self) -> Option<(u64, Slot)> {
        loop {
            let stamp = self.tick.checked_mul(self.tick_ns)?;
            if stamp >= self.world.end_ns() {
                return None;
            }
            let slot = self.slot;
            let fires = match slot {
                Slot::Imu => true,
                Slot::Wheel => self.wheel.is_some() && self.tick.is_multiple_of(self.wheel_every),
                Slot::Stereo => self.tick.is_multiple_of(self.stereo_every),
            };
            match slot {
                Slot::Imu => self.slot = Slot::Wheel,
                Slot::Wheel => self.slot = Slot::Stereo,
                Slot::Stereo => {
                    self.slot = Slot::Imu;
                    self.tick += 1;
                }
            }
            if fires {
                return Some((stamp, slot));
            }
        }
    }

    /// Announces the pair of `stamp_ns` (nothing is rendered yet).
    fn announce(&mut self, stamp_ns: u64) -> StereoInfo {
        let (pan_rad, tilt_rad) = match &mut self.head {
            Some(head) => head.angles_at(stamp_ns),
            None => self.world.head_angles(self.robot, stamp_ns),
        };
        let camera = self.renderer.camera();
        let info = StereoInfo {
            stamp_ns,
            sequence: self.stereo_sequence,
            width_px: camera.width_px,
            height_px: camera.height_px,
            pan_rad,
            tilt_rad,
        };
        self.stereo_sequence += 1;
        info
    }

    /// Renders the announced pair `info` into `left` and `right`; the image noise is keyed by the
    /// pair's sequence number, so a skipped pair changes nothing for the next ones.
    fn render(&mut self, info: &StereoInfo, left: &mut [u8], right: &mut [u8]) -> Result<(), SensorError> {
        let state = self.state(info.stamp_ns)?;
        let world = &*self.world;
        let robot = &world.robots[self.robot];
        let t_world_cam = state.t_world_body * robot.model().t_body_cam(info.pan_rad, info.tilt_rad);
        self.quads.clear();
        world.quads_at(info.stamp_ns, Some(self.robot), &mut self.quads);
        let seed =
            rng::stream_seed(world.scenario.seed, &[streams::IMAGE_NOISE, u64::from(robot.setup.id), info.sequence]);
        let scene = world.scene(&self.quads);
        self.renderer.render_stereo(&scene, &t_world_cam, seed, left, right);
        Ok(())
    }
}

impl SensorSource for SimSensorSource {
    fn stereo_calibration(&self) -> Option<StereoCalibration> {
        let robot = &self.world.robots[self.robot];
        let model = robot.model();
        Some(model.camera.calibration(&model.t_body_cam(0.0, 0.0), model.head))
    }

    fn next_event(&mut self) -> Result<Option<SensorEvent>, SensorError> {
        self.pending = None;
        let Some((stamp_ns, slot)) = self.advance() else {
            return Ok(None);
        };
        let event = match slot {
            Slot::Imu => {
                let state = self.state(stamp_ns)?;
                SensorEvent::Imu(self.imu.sample(&state, stamp_ns))
            }
            Slot::Wheel => {
                let state = self.state(stamp_ns)?;
                match self.wheel.as_mut() {
                    Some(wheel) => SensorEvent::WheelOdom(wheel.sample(&state, stamp_ns)),
                    None => return Err(SensorError::Source("wheel odometry on a robot without wheels".to_owned())),
                }
            }
            Slot::Stereo => {
                let info = self.announce(stamp_ns);
                self.pending = Some(info);
                SensorEvent::Stereo(info)
            }
        };
        Ok(Some(event))
    }

    fn read_stereo(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), SensorError> {
        let info = self.pending.take().ok_or_else(no_pending_pair)?;
        check_stereo_buffers(&info, left, right)?;
        self.render(&info, left, right)
    }

    /// A rover's head follows the command from its stamp on ([`HeadServo`]); a fixed camera
    /// (a flyer) has none.
    fn command_head(&mut self, target: &HeadTarget) -> Result<bool, SensorError> {
        if let Some(head) = &mut self.head {
            head.command(*target);
            return Ok(true);
        }
        let Some(limits) = self.world.robots[self.robot].model().head else {
            return Ok(false);
        };
        let start = self.world.head_angles(self.robot, target.stamp_ns);
        self.head = Some(HeadServo::new(limits, start, target.stamp_ns, *target));
        Ok(true)
    }
}
