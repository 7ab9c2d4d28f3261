//! The sensor driver as a bus node: one simulated robot's IMU, wheel odometry and stereo pairs
//! ([`sim::driver::SimSensorSource`]) published on sensor time.
//!
//! [`DriverNode::on_tick`] publishes every event stamped at or before `now_ns`, in the source's
//! order (at equal stamps IMU, wheel odometry, stereo). The source has no look-ahead, so the first
//! event past `now_ns` is read and held for the next tick; on the simulator's grid that event is
//! always an IMU sample (every tick starts with one), so no image is rendered before it is due.
//!
//! The driver keeps the ground truth the mission report needs: the source's state at any stamp
//! and a log of `t_world_body` at every camera capture (the TUM ground truth).

use std::sync::Arc;

use hal::sensor::{ImuSample, SensorEvent, SensorSource, StereoCalibration, StereoFrame, WheelOdomSample};
use msgs::{ImuMsg, StereoHeader, WheelOdomMsg};
use nalgebra::Isometry3;
use sim::driver::{GroundTruthSample, SimSensorSource};
use sim::world::World;

use super::{Message, Node, NodeError, Outbox, Topic};

const NAME: &str = "driver";

/// How the driver runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DriverOptions {
    /// Events after this stamp are not published (the driver is finished there).
    pub end_stamp_ns: Option<u64>,
}

/// Counters of what was published.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DriverCounts {
    pub imu: u64,
    pub wheel: u64,
    pub stereo: u64,
}

/// One robot's sensors on the bus (see the module documentation).
#[derive(Debug)]
pub struct DriverNode {
    source: SimSensorSource,
    options: DriverOptions,
    calibration: Option<StereoCalibration>,
    /// Render target of the source; holds the pair of a held stereo event.
    frame: StereoFrame,
    /// The stereo payload: left rows, then right rows (capacity kept between frames).
    stereo_bytes: Vec<u8>,
    /// An event read from the source but not yet due.
    held: Option<SensorEvent>,
    finished: bool,
    imu_sequence: u64,
    wheel_sequence: u64,
    counts: DriverCounts,
    truth_log: Vec<(u64, Isometry3<f64>)>,
}

impl DriverNode {
    /// The driver of robot `robot` of `world`.
    pub fn new(world: Arc<World>, robot: usize, options: DriverOptions) -> Result<Self, NodeError> {
        let source = SimSensorSource::new(world, robot).map_err(|e| failed(e.to_string()))?;
        let calibration = source.stereo_calibration();
        Ok(DriverNode {
            source,
            options,
            calibration,
            frame: StereoFrame::default(),
            stereo_bytes: Vec::new(),
            held: None,
            finished: false,
            imu_sequence: 0,
            wheel_sequence: 0,
            counts: DriverCounts::default(),
            truth_log: Vec::new(),
        })
    }

    /// Calibration of the stereo head (raw or rectified, as the source delivers its pairs).
    pub fn stereo_calibration(&self) -> Option<StereoCalibration> {
        self.calibration
    }

    /// Ground truth of the robot at `stamp_ns` (biases as of the last IMU sample read).
    pub fn ground_truth(&self, stamp_ns: u64) -> Option<GroundTruthSample> {
        self.source.ground_truth(stamp_ns)
    }

    /// `t_world_body` at every published camera capture, in order.
    pub fn truth_log(&self) -> &[(u64, Isometry3<f64>)] {
        &self.truth_log
    }

    pub fn counts(&self) -> DriverCounts {
        self.counts
    }

    /// The source is exhausted (or past [`DriverOptions::end_stamp_ns`]) and everything was
    /// published.
    pub fn finished(&self) -> bool {
        self.finished && self.held.is_none()
    }

    pub fn robot(&self) -> usize {
        self.source.robot()
    }

    fn event_stamp_ns(&self, event: &SensorEvent) -> u64 {
        match event {
            SensorEvent::Imu(s) => s.stamp_ns,
            SensorEvent::WheelOdom(s) => s.stamp_ns,
            SensorEvent::Stereo => self.frame.stamp_ns,
        }
    }

    fn next_event(&mut self) -> Result<Option<SensorEvent>, NodeError> {
        if let Some(event) = self.held.take() {
            return Ok(Some(event));
        }
        if self.finished {
            return Ok(None);
        }
        let event = self.source.next_event(&mut self.frame).map_err(|e| failed(e.to_string()))?;
        let event = event.filter(|e| self.options.end_stamp_ns.is_none_or(|end| self.event_stamp_ns(e) <= end));
        if event.is_none() {
            self.finished = true;
        }
        Ok(event)
    }

    fn publish_event(&mut self, event: &SensorEvent, out: &mut dyn Outbox) -> Result<(), NodeError> {
        match event {
            SensorEvent::Imu(sample) => {
                let message = imu_message(sample, self.imu_sequence);
                self.imu_sequence += 1;
                self.counts.imu += 1;
                out.publish(Message::Imu(&message))
            }
            SensorEvent::WheelOdom(sample) => {
                let message = wheel_message(sample, self.wheel_sequence);
                self.wheel_sequence += 1;
                self.counts.wheel += 1;
                out.publish(Message::WheelOdom(&message))
            }
            SensorEvent::Stereo => {
                let frame = &self.frame;
                if let Some(truth) = self.source.ground_truth(frame.stamp_ns) {
                    self.truth_log.push((frame.stamp_ns, truth.state.t_world_body));
                }
                self.stereo_bytes.clear();
                self.stereo_bytes.extend_from_slice(&frame.left);
                self.stereo_bytes.extend_from_slice(&frame.right);
                let header = StereoHeader {
                    stamp_ns: frame.stamp_ns,
                    sequence: frame.sequence,
                    pan_rad: frame.pan_rad,
                    tilt_rad: frame.tilt_rad,
                    width_px: frame.width_px,
                    height_px: frame.height_px,
                };
                self.counts.stereo += 1;
                out.publish(Message::Stereo(&header, &self.stereo_bytes))
            }
        }
    }
}

fn failed(reason: String) -> NodeError {
    NodeError::Failed { node: NAME, reason }
}

/// The bus form of an IMU sample.
pub fn imu_message(sample: &ImuSample, sequence: u64) -> ImuMsg {
    ImuMsg {
        stamp_ns: sample.stamp_ns,
        sequence,
        gyro_radps: sample.gyro_radps.into(),
        accel_mps2: sample.accel_mps2.into(),
    }
}

/// The bus form of a wheel odometry sample.
pub fn wheel_message(sample: &WheelOdomSample, sequence: u64) -> WheelOdomMsg {
    WheelOdomMsg {
        stamp_ns: sample.stamp_ns,
        sequence,
        linear_mps: sample.linear_mps.into(),
        angular_radps: sample.angular_radps.into(),
        sigma: sample.sigma,
    }
}

impl Node for DriverNode {
    fn name(&self) -> &'static str {
        NAME
    }

    fn subscriptions(&self) -> &'static [Topic] {
        &[]
    }

    fn on_message(&mut self, _message: Message<'_>, _out: &mut dyn Outbox) -> Result<(), NodeError> {
        Ok(())
    }

    fn on_tick(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        while let Some(event) = self.next_event()? {
            if self.event_stamp_ns(&event) > now_ns {
                self.held = Some(event);
                break;
            }
            self.publish_event(&event, out)?;
        }
        Ok(())
    }
}
