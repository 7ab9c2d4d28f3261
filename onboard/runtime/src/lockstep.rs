//! The lockstep runner: one robot's nodes ([`RobotStack`], built by [`crate::stack`] as the
//! process runner builds them) on simulated time, exchanging the same [`Message`]s as over
//! iceoryx2 through an in-process bus ([`LocalBus`]), delivered in publish order,
//! deterministically. `onboard vio` runs one stack on a dataset; the `sil` harness runs one per
//! robot of a simulated team and moves the radio packets between their comms nodes.
//!
//! A published message is copied once into the robot's queue ([`OwnedMessage`], the recording's
//! owned form; image buffers
//! come from a pool and go back to it after delivery, so a warmed-up run does not allocate per
//! frame) and then handed, borrowed, to every node that subscribes to its topic, in the order
//! the nodes were given. Messages a node publishes while handling one are queued behind it:
//! delivery is breadth-first, as a bus with one message in flight at a time.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::time::Instant;

use bytemuck::Zeroable;
use hal::sensor::SensorSource;
use msgs::{DisparityHeader, DisparityPixel, ProcessKind, StereoHeader, TaskStatsMsg};

use crate::config::RoverConfig;
use crate::nodes::comms::CommsNode;
use crate::nodes::driver::{DriverNode, DriverOptions};
use crate::nodes::filter::FilterNode;
use crate::nodes::mapper::MapperNode;
use crate::nodes::vision::VisionNode;
use crate::nodes::{Message, Node, NodeError, Outbox, Topic};
pub use crate::record::OwnedMessage;
use crate::sensors::SensorSetup;
use crate::stack;

/// Recycled payload buffers.
#[derive(Debug, Default)]
struct Pool {
    bytes: Vec<Vec<u8>>,
    pixels: Vec<Vec<DisparityPixel>>,
}

impl Pool {
    fn bytes(&mut self, data: &[u8]) -> Vec<u8> {
        let mut v = self.bytes.pop().unwrap_or_default();
        v.clear();
        v.extend_from_slice(data);
        v
    }

    fn pixels(&mut self, data: &[DisparityPixel]) -> Vec<DisparityPixel> {
        let mut v = self.pixels.pop().unwrap_or_default();
        v.clear();
        v.extend_from_slice(data);
        v
    }

    fn recycle(&mut self, message: OwnedMessage) {
        // A few buffers per kind cover a robot's in-flight images; more would only hold memory.
        const KEEP: usize = 8;
        match message {
            OwnedMessage::Stereo(_, v) | OwnedMessage::ToComms(_, v) | OwnedMessage::ToMapper(_, v)
                if self.bytes.len() < KEEP =>
            {
                self.bytes.push(v);
            }
            OwnedMessage::Disparity(_, v) if self.pixels.len() < KEEP => self.pixels.push(v),
            _ => {}
        }
    }

    fn own(&mut self, message: &Message<'_>) -> OwnedMessage {
        match *message {
            Message::Imu(m) => OwnedMessage::Imu(*m),
            Message::WheelOdom(m) => OwnedMessage::WheelOdom(*m),
            Message::Stereo(h, d) => OwnedMessage::Stereo(*h, self.bytes(d)),
            Message::Disparity(h, d) => OwnedMessage::Disparity(*h, self.pixels(d)),
            Message::VoDelta(m) => OwnedMessage::VoDelta(*m),
            Message::Marker(m) => OwnedMessage::Marker(*m),
            Message::FilterState(m) => OwnedMessage::FilterState(*m),
            Message::FrameSwitchRequest(m) => OwnedMessage::FrameSwitchRequest(*m),
            Message::FrameSwitch(m) => OwnedMessage::FrameSwitch(*m),
            Message::ToComms(h, d) => OwnedMessage::ToComms(*h, self.bytes(d)),
            Message::ToMapper(h, d) => OwnedMessage::ToMapper(*h, self.bytes(d)),
            Message::TaskStats(m) => OwnedMessage::TaskStats(*m),
            Message::HeadCommand(m) => OwnedMessage::HeadCommand(*m),
            Message::Hazards(m) => OwnedMessage::Hazards(Box::new(*m)),
        }
    }
}

/// The message queue of one robot; it is the [`Outbox`] of every node of that robot.
#[derive(Debug, Default)]
pub struct LocalBus {
    queue: VecDeque<OwnedMessage>,
    pool: Pool,
    /// Messages published per topic (index: `Topic::code()`).
    published: [u64; 16],
    /// Observer of every delivered message (e.g. a recorder or the runner's own taps).
    tap: Vec<Topic>,
    tapped: Vec<OwnedMessage>,
}

impl Outbox for LocalBus {
    fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError> {
        let owned = self.pool.own(&message);
        self.count(message.topic());
        self.queue.push_back(owned);
        Ok(())
    }

    /// The pair is written into a pooled buffer that goes to the readers as it is.
    fn publish_stereo_with(
        &mut self,
        header: &StereoHeader,
        fill: &mut dyn FnMut(&mut [u8]) -> Result<(), NodeError>,
    ) -> Result<(), NodeError> {
        let len = crate::nodes::stereo_len(header)?;
        let mut bytes = self.pool.bytes.pop().unwrap_or_default();
        bytes.resize(len, 0);
        if let Err(e) = fill(&mut bytes) {
            self.pool.recycle(OwnedMessage::Stereo(*header, bytes));
            return Err(e);
        }
        self.count(Topic::Stereo);
        self.queue.push_back(OwnedMessage::Stereo(*header, bytes));
        Ok(())
    }

    /// The map is written into a pooled buffer that goes to the readers as it is.
    fn publish_disparity_with(
        &mut self,
        header: &DisparityHeader,
        pixel: &dyn Fn(usize) -> DisparityPixel,
    ) -> Result<(), NodeError> {
        let len = crate::nodes::disparity_len(header)?;
        let mut pixels = self.pool.pixels.pop().unwrap_or_default();
        pixels.clear();
        pixels.extend((0..len).map(pixel));
        self.count(Topic::Disparity);
        self.queue.push_back(OwnedMessage::Disparity(*header, pixels));
        Ok(())
    }
}

/// Time spent in each node's handlers (the lockstep runner's "CPU per process").
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NodeTimes {
    pub seconds: Vec<f64>,
}

impl LocalBus {
    pub fn new() -> LocalBus {
        LocalBus::default()
    }

    /// Keep a copy of every delivered message of these topics ([`LocalBus::take_tapped`]).
    pub fn tap(&mut self, topics: &[Topic]) {
        self.tap = topics.to_vec();
    }

    /// The tapped messages since the last call.
    pub fn take_tapped(&mut self) -> Vec<OwnedMessage> {
        std::mem::take(&mut self.tapped)
    }

    fn count(&mut self, topic: Topic) {
        if let Some(count) = self.published.get_mut(usize::from(topic.code())) {
            *count += 1;
        }
    }

    pub fn published(&self, topic: Topic) -> u64 {
        self.published.get(usize::from(topic.code())).copied().unwrap_or(0)
    }

    pub fn is_idle(&self) -> bool {
        self.queue.is_empty()
    }

    /// Delivers every queued message (and those published while delivering) to the subscribed
    /// nodes. `times.seconds[i]` accumulates node `i`'s handler time.
    pub fn deliver(&mut self, nodes: &mut [&mut dyn Node], times: &mut NodeTimes) -> Result<(), NodeError> {
        times.seconds.resize(nodes.len(), 0.0);
        while let Some(message) = self.queue.pop_front() {
            let view = message.as_message();
            let topic = view.topic();
            for (i, node) in nodes.iter_mut().enumerate() {
                if node.subscriptions().contains(&topic) {
                    let start = Instant::now();
                    let result = node.on_message(view, self);
                    times.seconds[i] += start.elapsed().as_secs_f64();
                    result?;
                }
            }
            if self.tap.contains(&topic) {
                self.tapped.push(message);
            } else {
                self.pool.recycle(message);
            }
        }
        Ok(())
    }

    /// Calls `on_tick(now_ns)` of the nodes selected by `due` and delivers what they publish.
    pub fn tick(
        &mut self,
        now_ns: u64,
        nodes: &mut [&mut dyn Node],
        due: &[bool],
        times: &mut NodeTimes,
    ) -> Result<(), NodeError> {
        times.seconds.resize(nodes.len(), 0.0);
        for i in 0..nodes.len() {
            if !due.get(i).copied().unwrap_or(false) {
                continue;
            }
            let start = Instant::now();
            let result = nodes[i].on_tick(now_ns, self);
            times.seconds[i] += start.elapsed().as_secs_f64();
            result?;
            self.deliver(nodes, times)?;
        }
        Ok(())
    }
}

/// The lockstep step: one IMU period at 200 Hz.
pub const STEP_NS: u64 = 5_000_000;
/// The nodes' usage goes to the comms node's telemetry once per second of sensor time.
const USAGE_PERIOD_NS: u64 = 1_000_000_000;

/// The node names in [`RobotStack`] order (the index of [`NodeTimes::seconds`]).
pub const NODE_NAMES: [&str; 5] = ["driver", "vision", "filter", "mapper", "comms"];

/// Why a stack could not be built or run.
#[derive(Debug, thiserror::Error)]
pub enum StackError {
    #[error("{0}")]
    Node(#[from] NodeError),
    #[error("set-up: {0}")]
    Setup(String),
}

/// One robot's nodes on the lockstep runner (see the module documentation).
#[derive(Debug)]
pub struct RobotStack {
    pub driver: DriverNode,
    pub vision: VisionNode,
    pub filter: FilterNode,
    pub mapper: MapperNode,
    /// The comms node (absent for a robot alone, e.g. `onboard vio`).
    pub comms: Option<CommsNode>,
    pub bus: LocalBus,
    pub times: NodeTimes,
    mapper_period_ns: u64,
    comms_period_ns: u64,
    /// Next sensor time at which the nodes' usage goes to the comms node's telemetry.
    next_usage_ns: u64,
}

impl RobotStack {
    /// The stack of the robot configured in `config`, its driver reading `source`; the mapper
    /// keeps its state in `state_dir` (none: nothing persisted).
    pub fn new(
        config: &RoverConfig,
        setup: &SensorSetup,
        source: Box<dyn SensorSource + Send>,
        comms: Option<CommsNode>,
        state_dir: Option<PathBuf>,
    ) -> Result<RobotStack, StackError> {
        let driver = DriverNode::new(source, DriverOptions { end_stamp_ns: config.driver.end_stamp_ns() });
        let vision = stack::vision_node(config, setup)?;
        let filter = stack::filter_node(config, setup);
        let mut mapper_config = stack::mapper_config(config, *vision.rectified_calibration());
        mapper_config.state_dir = state_dir;
        let mapper = MapperNode::new(mapper_config).map_err(|e| StackError::Setup(format!("mapper: {e}")))?;
        Ok(RobotStack {
            driver,
            vision,
            filter,
            mapper,
            comms,
            bus: LocalBus::new(),
            times: NodeTimes::default(),
            mapper_period_ns: config.rates.mapper.period_ns().max(STEP_NS),
            comms_period_ns: config.rates.comms.period_ns().max(STEP_NS),
            next_usage_ns: USAGE_PERIOD_NS,
        })
    }

    fn nodes(&mut self) -> (Vec<&mut dyn Node>, &mut LocalBus, &mut NodeTimes) {
        let mut nodes: Vec<&mut dyn Node> =
            vec![&mut self.driver, &mut self.vision, &mut self.filter, &mut self.mapper];
        if let Some(comms) = self.comms.as_mut() {
            nodes.push(comms);
        }
        (nodes, &mut self.bus, &mut self.times)
    }

    /// One step at sensor time `now_ns` (a multiple of [`STEP_NS`]): the driver publishes what is
    /// due, vision and filter tick every step (their time-based work: late-prior waits), the
    /// mapper and comms at their configured rates; everything published is delivered.
    pub fn step(&mut self, now_ns: u64) -> Result<(), NodeError> {
        let due = [
            true,
            true,
            true,
            now_ns.is_multiple_of(self.mapper_period_ns),
            now_ns.is_multiple_of(self.comms_period_ns),
        ];
        if self.comms.is_some() && now_ns >= self.next_usage_ns {
            self.next_usage_ns = now_ns + USAGE_PERIOD_NS;
            self.publish_usage(now_ns)?;
        }
        let (mut nodes, bus, times) = self.nodes();
        bus.tick(now_ns, &mut nodes, &due, times)
    }

    /// What each node has used, measured: its handler time (per second of sensor time it is the
    /// share of one core the robot needs at real time) and the process's resident memory (the
    /// one process all robots of a lockstep run share). No task timing: there are no tasks.
    fn publish_usage(&mut self, now_ns: u64) -> Result<(), NodeError> {
        let rss_bytes = crate::task::usage::ProcessUsage::now().map_or(0, |u| u.rss_bytes);
        let kinds =
            [ProcessKind::Driver, ProcessKind::Vision, ProcessKind::Filter, ProcessKind::Mapper, ProcessKind::Comms];
        for (i, kind) in kinds.into_iter().enumerate() {
            let cpu_s = self.times.seconds.get(i).copied().unwrap_or(0.0);
            let stats = TaskStatsMsg {
                stamp_ns: now_ns,
                period_ns: TaskStatsMsg::NO_TASK,
                process_cpu_ns: (cpu_s * 1e9) as u64,
                process_rss_bytes: rss_bytes,
                process: kind as u32,
                ..TaskStatsMsg::zeroed()
            };
            self.bus.publish(Message::TaskStats(&stats))?;
        }
        Ok(())
    }

    /// Delivers what is queued (e.g. after the runner inserted messages itself).
    pub fn deliver(&mut self) -> Result<(), NodeError> {
        let (mut nodes, bus, times) = self.nodes();
        bus.deliver(&mut nodes, times)
    }

    /// The end of the data at sensor time `end_ns`: the pair still waiting for its prior runs,
    /// the VO results still in flight are applied to the filter (its summary counts them; the
    /// state after them is not published, as a process stopped at that moment would not), and
    /// the mapper's last release integrates what arrived.
    pub fn finish(&mut self, end_ns: u64) -> Result<(), NodeError> {
        self.vision.flush(&mut self.bus)?;
        self.filter.flush();
        let (mut nodes, bus, times) = self.nodes();
        bus.deliver(&mut nodes, times)?;
        bus.tick(end_ns, &mut nodes, &[false, false, false, true, false], times)
    }
}
