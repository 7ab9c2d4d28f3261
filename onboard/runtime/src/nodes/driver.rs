//! The sensor driver as a bus node: one robot's IMU, wheel odometry and stereo pairs from a
//! [`SensorSource`] (a dataset replay, the simulator in the `sil` harness, later the devices),
//! published on sensor time.
//!
//! Sensor time starts at the source's first event: every stamp is published relative to it
//! ([`DriverNode::time_offset_ns`] is the source's stamp of sensor time 0), so a replayed dataset
//! recorded at an epoch of 1.4·10⁹ s runs on the same clock as a mission that starts at 0.
//!
//! [`DriverNode::on_tick`] publishes every event stamped at or before `now_ns`, in the source's
//! order (at equal stamps the source's own order). The source has no look-ahead, so the first
//! event past `now_ns` is read and held for the next tick; a held pair is only announced, its
//! pixels are rendered or decoded when it is due.
//!
//! A stereo pair is written once: the source renders or decodes it straight into the outbox's
//! memory ([`Outbox::publish_stereo_with`]: a loaned iceoryx2 sample in the process runner), so
//! the driver holds no image buffer and copies nothing.

use hal::sensor::{HeadTarget, ImuSample, SensorEvent, SensorSource, StereoCalibration, WheelOdomSample};
use msgs::{HeadCommandMsg, ImuMsg, StereoHeader, WheelOdomMsg};

use super::{Message, Node, NodeError, Outbox, Topic};

const NAME: &str = "driver";

/// How the driver runs.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DriverOptions {
    /// Events after this sensor time are not published (the driver is finished there).
    pub end_stamp_ns: Option<u64>,
}

/// Counters of what was published.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct DriverCounts {
    pub imu: u64,
    pub wheel: u64,
    pub stereo: u64,
    /// Events whose stamp went backwards (not published).
    pub out_of_order: u64,
    /// Events of a live source stamped before sensor time 0 (not published).
    pub before_epoch: u64,
    /// Head commands passed to a head that moves, and those the source had no head for.
    pub head_commands: u64,
    pub head_commands_ignored: u64,
    pub head_command_errors: u64,
}

/// One robot's sensors on the bus (see the module documentation).
pub struct DriverNode {
    source: Box<dyn SensorSource + Send>,
    options: DriverOptions,
    calibration: Option<StereoCalibration>,
    /// An event read from the source but not yet due.
    held: Option<SensorEvent>,
    /// The source's stamp of sensor time 0 (its first event's), once known.
    time_offset_ns: Option<u64>,
    /// Last published stamp per event kind (IMU, wheel odometry, stereo): each device's stream
    /// must not go back in time. A live source's devices deliver independently (a wheel sample
    /// stamped in the middle of its SYNC interval arrives after IMU samples stamped later), and
    /// every consumer orders by stamp itself (the bus inbox merges by stamp).
    last_stamp_ns: [u64; 3],
    finished: bool,
    imu_sequence: u64,
    wheel_sequence: u64,
    counts: DriverCounts,
}

impl std::fmt::Debug for DriverNode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DriverNode")
            .field("options", &self.options)
            .field("time_offset_ns", &self.time_offset_ns)
            .field("finished", &self.finished)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

impl DriverNode {
    pub fn new(source: Box<dyn SensorSource + Send>, options: DriverOptions) -> DriverNode {
        let calibration = source.stereo_calibration();
        DriverNode {
            source,
            options,
            calibration,
            held: None,
            time_offset_ns: None,
            last_stamp_ns: [0; 3],
            finished: false,
            imu_sequence: 0,
            wheel_sequence: 0,
            counts: DriverCounts::default(),
        }
    }

    /// Calibration of the stereo head (raw or rectified, as the source delivers its pairs).
    pub fn stereo_calibration(&self) -> Option<StereoCalibration> {
        self.calibration
    }

    /// The source's stamp of sensor time 0; `None` before the first event was read.
    pub fn time_offset_ns(&self) -> Option<u64> {
        self.time_offset_ns
    }

    /// Sensor time 0 of a live source, on its clock (`CLOCK_MONOTONIC`): the process runner's
    /// epoch, shared with every process of the robot (and, in a HIL run, with the cameras).
    /// Without it a live source's first event would define sensor time 0.
    pub fn set_live_epoch(&mut self, epoch_ns: u64) {
        if self.source.is_live() {
            self.time_offset_ns = Some(epoch_ns);
        }
    }

    /// The devices of a live source (`None` for a replay or the simulator).
    pub fn device_health(&self) -> Option<hal::sensor::DeviceHealth> {
        self.source.device_health()
    }

    /// A live source's device changes in sensor time (seconds), oldest first.
    pub fn device_log(&self) -> Vec<(f64, String)> {
        let offset = self.time_offset_ns.unwrap_or(0);
        self.source
            .device_log()
            .into_iter()
            .map(|(stamp_ns, line)| ((stamp_ns as i128 - offset as i128) as f64 * 1e-9, line))
            .collect()
    }

    pub fn counts(&self) -> DriverCounts {
        self.counts
    }

    /// The source is exhausted (or past [`DriverOptions::end_stamp_ns`]) and everything was
    /// published.
    pub fn finished(&self) -> bool {
        self.finished && self.held.is_none()
    }

    /// Passes a gaze command to the source on its own clock. A command before the first event
    /// (sensor time not yet defined) is taken as given at the source's time 0.
    fn command_head(&mut self, command: &HeadCommandMsg) -> Result<(), NodeError> {
        let target = HeadTarget {
            stamp_ns: command.stamp_ns.saturating_add(self.time_offset_ns.unwrap_or(0)),
            pan_rad: command.pan_rad,
            tilt_rad: command.tilt_rad,
            max_rate_radps: command.max_rate_radps,
        };
        // A head that cannot be reached must not stop the sensors: the pairs report the
        // angles the head really has, whatever was commanded.
        match self.source.command_head(&target) {
            Ok(true) => self.counts.head_commands += 1,
            Ok(false) => self.counts.head_commands_ignored += 1,
            Err(e) => {
                self.counts.head_command_errors += 1;
                if self.counts.head_command_errors <= 5 {
                    eprintln!("driver: head command not delivered: {e}");
                }
            }
        }
        Ok(())
    }

    /// An event's stamp in sensor time.
    fn event_stamp_ns(&self, event: &SensorEvent) -> u64 {
        event.stamp_ns().saturating_sub(self.time_offset_ns.unwrap_or(0))
    }

    fn next_event(&mut self) -> Result<Option<SensorEvent>, NodeError> {
        if let Some(event) = self.held.take() {
            return Ok(Some(event));
        }
        if self.finished {
            return Ok(None);
        }
        let Some(event) = self.source.next_event().map_err(|e| failed(e.to_string()))? else {
            // A live source has nothing due yet; it ends only with the end stamp.
            self.finished = !self.source.is_live();
            return Ok(None);
        };
        self.time_offset_ns.get_or_insert(event.stamp_ns());
        if self.options.end_stamp_ns.is_some_and(|end| self.event_stamp_ns(&event) > end) {
            self.finished = true;
            return Ok(None);
        }
        Ok(Some(event))
    }

    fn publish_event(&mut self, event: &SensorEvent, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if self.time_offset_ns.is_some_and(|offset| event.stamp_ns() < offset) {
            self.counts.before_epoch += 1;
            return Ok(());
        }
        let stamp_ns = self.event_stamp_ns(event);
        let last_stamp_ns = &mut self.last_stamp_ns[kind_index(event)];
        if stamp_ns < *last_stamp_ns {
            self.counts.out_of_order += 1;
            if self.counts.out_of_order <= 5 {
                eprintln!(
                    "driver: {} sample stamped {:.6} s after one at {:.6} s: not published",
                    event_kind(event),
                    stamp_ns as f64 * 1e-9,
                    *last_stamp_ns as f64 * 1e-9
                );
            }
            return Ok(());
        }
        *last_stamp_ns = stamp_ns;
        match event {
            SensorEvent::Imu(sample) => {
                let message = imu_message(&ImuSample { stamp_ns, ..*sample }, self.imu_sequence);
                self.imu_sequence += 1;
                self.counts.imu += 1;
                out.publish(Message::Imu(&message))
            }
            SensorEvent::WheelOdom(sample) => {
                let message = wheel_message(&WheelOdomSample { stamp_ns, ..*sample }, self.wheel_sequence);
                self.wheel_sequence += 1;
                self.counts.wheel += 1;
                out.publish(Message::WheelOdom(&message))
            }
            SensorEvent::Stereo(info) => {
                let header = StereoHeader {
                    stamp_ns,
                    sequence: info.sequence,
                    pan_rad: info.pan_rad,
                    tilt_rad: info.tilt_rad,
                    width_px: info.width_px,
                    height_px: info.height_px,
                };
                let source = &mut self.source;
                out.publish_stereo_with(&header, &mut |bytes| {
                    let (left, right) = bytes.split_at_mut(bytes.len() / 2);
                    source.read_stereo(left, right).map_err(|e| failed(e.to_string()))
                })?;
                self.counts.stereo += 1;
                Ok(())
            }
        }
    }
}

fn kind_index(event: &SensorEvent) -> usize {
    match event {
        SensorEvent::Imu(_) => 0,
        SensorEvent::WheelOdom(_) => 1,
        SensorEvent::Stereo(_) => 2,
    }
}

fn event_kind(event: &SensorEvent) -> &'static str {
    match event {
        SensorEvent::Imu(_) => "IMU",
        SensorEvent::WheelOdom(_) => "wheel odometry",
        SensorEvent::Stereo(_) => "stereo",
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
        &[Topic::HeadCommand]
    }

    fn on_message(&mut self, message: Message<'_>, _out: &mut dyn Outbox) -> Result<(), NodeError> {
        if let Message::HeadCommand(command) = message {
            self.command_head(command)?;
        }
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
