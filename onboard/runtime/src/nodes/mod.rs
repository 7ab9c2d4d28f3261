//! The on-board components as bus nodes: each wraps algorithm crates behind one message interface
//! so that both runners drive the same code (DESIGN §3.1):
//!
//! - the **process runner** hosts one node per OS process; its bus adapter ([`crate::bus`]) hands
//!   the node every received sample *in place* in iceoryx2 shared memory as a borrowed
//!   [`Message`], and publishes what the node sends through the [`Outbox`];
//! - the **lockstep runner** ([`crate::lockstep`]) holds the nodes of N robots in one process and
//!   delivers the same borrowed messages directly, on simulated time.
//!
//! A node never reads a clock: time is the stamps of its messages and the `now_ns` of
//! [`Node::on_tick`] (sensor time, nanoseconds since the mission start). It never blocks and never
//! allocates per message on its hot path once warmed up.

pub mod comms;
pub mod driver;
pub mod filter;
pub mod mapper;
pub mod vision;

use msgs::{
    DisparityHeader, DisparityPixel, FilterStateMsg, FrameSwitchMsg, FrameSwitchRequestMsg, ImuMsg, MarkerMsg,
    StereoHeader, TaskStatsMsg, TeamHeader, VoDeltaMsg, WheelOdomMsg,
};

/// A bus topic of one robot (DESIGN §4). The iceoryx2 service is `rover/{robot_id}/{path}`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Topic {
    Imu,
    WheelOdom,
    Stereo,
    Disparity,
    VoDelta,
    Marker,
    FilterState,
    FrameSwitchRequest,
    FrameSwitch,
    ToComms,
    ToMapper,
    TaskStats,
}

impl Topic {
    pub const ALL: [Topic; 12] = [
        Topic::Imu,
        Topic::WheelOdom,
        Topic::Stereo,
        Topic::Disparity,
        Topic::VoDelta,
        Topic::Marker,
        Topic::FilterState,
        Topic::FrameSwitchRequest,
        Topic::FrameSwitch,
        Topic::ToComms,
        Topic::ToMapper,
        Topic::TaskStats,
    ];

    /// Path below `rover/{id}/`.
    pub fn path(self) -> &'static str {
        match self {
            Topic::Imu => "sensors/imu",
            Topic::WheelOdom => "sensors/wheel_odom",
            Topic::Stereo => "sensors/stereo",
            Topic::Disparity => "vision/disparity",
            Topic::VoDelta => "vision/vo_delta",
            Topic::Marker => "vision/markers",
            Topic::FilterState => "filter/state",
            Topic::FrameSwitchRequest => "mapper/frame_switch_request",
            Topic::FrameSwitch => "filter/frame_switch",
            Topic::ToComms => "mapper/to_comms",
            Topic::ToMapper => "comms/to_mapper",
            Topic::TaskStats => "telemetry/tasks",
        }
    }

    /// The iceoryx2 service name of this topic for one robot.
    pub fn service_name(self, robot_id: u16) -> String {
        format!("rover/{robot_id}/{}", self.path())
    }

    /// Stable number of the topic in recordings (never reused).
    pub fn code(self) -> u8 {
        match self {
            Topic::Imu => 1,
            Topic::WheelOdom => 2,
            Topic::Stereo => 3,
            Topic::Disparity => 4,
            Topic::VoDelta => 5,
            Topic::Marker => 6,
            Topic::FilterState => 7,
            Topic::FrameSwitchRequest => 8,
            Topic::FrameSwitch => 9,
            Topic::ToComms => 10,
            Topic::ToMapper => 11,
            Topic::TaskStats => 12,
        }
    }

    pub fn from_code(code: u8) -> Option<Topic> {
        Topic::ALL.into_iter().find(|t| t.code() == code)
    }
}

/// One bus message, borrowed: in the process runner the references point into iceoryx2 shared
/// memory (the sample is read in place), in the lockstep runner into the sender's buffers.
#[derive(Debug, Clone, Copy)]
pub enum Message<'a> {
    Imu(&'a ImuMsg),
    WheelOdom(&'a WheelOdomMsg),
    /// Header and `2 · width · height` bytes: left rows, then right rows.
    Stereo(&'a StereoHeader, &'a [u8]),
    Disparity(&'a DisparityHeader, &'a [DisparityPixel]),
    VoDelta(&'a VoDeltaMsg),
    Marker(&'a MarkerMsg),
    FilterState(&'a FilterStateMsg),
    FrameSwitchRequest(&'a FrameSwitchRequestMsg),
    FrameSwitch(&'a FrameSwitchMsg),
    /// A `protocol`-encoded team message from the mapper for the links.
    ToComms(&'a TeamHeader, &'a [u8]),
    /// A `protocol`-encoded team message received from a peer, for the mapper.
    ToMapper(&'a TeamHeader, &'a [u8]),
    TaskStats(&'a TaskStatsMsg),
}

impl Message<'_> {
    pub fn topic(&self) -> Topic {
        match self {
            Message::Imu(_) => Topic::Imu,
            Message::WheelOdom(_) => Topic::WheelOdom,
            Message::Stereo(..) => Topic::Stereo,
            Message::Disparity(..) => Topic::Disparity,
            Message::VoDelta(_) => Topic::VoDelta,
            Message::Marker(_) => Topic::Marker,
            Message::FilterState(_) => Topic::FilterState,
            Message::FrameSwitchRequest(_) => Topic::FrameSwitchRequest,
            Message::FrameSwitch(_) => Topic::FrameSwitch,
            Message::ToComms(..) => Topic::ToComms,
            Message::ToMapper(..) => Topic::ToMapper,
            Message::TaskStats(_) => Topic::TaskStats,
        }
    }

    /// The message's own time stamp (capture, sample or event time).
    pub fn stamp_ns(&self) -> u64 {
        match self {
            Message::Imu(m) => m.stamp_ns,
            Message::WheelOdom(m) => m.stamp_ns,
            Message::Stereo(h, _) => h.stamp_ns,
            Message::Disparity(h, _) => h.stamp_ns,
            Message::VoDelta(m) => m.capture_stamp_ns,
            Message::Marker(m) => m.capture_stamp_ns,
            Message::FilterState(m) => m.stamp_ns,
            Message::FrameSwitchRequest(m) => m.stamp_ns,
            Message::FrameSwitch(m) => m.stamp_ns,
            Message::ToComms(h, _) | Message::ToMapper(h, _) => h.stamp_ns,
            Message::TaskStats(m) => m.stamp_ns,
        }
    }
}

/// Where a node's messages go: the bus publisher set (process runner) or the lockstep runner's
/// delivery queue. Publishing copies the message once (into shared memory, or into the runner's
/// queue); the node keeps its buffers.
pub trait Outbox {
    fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError>;
}

/// Why a node could not handle a message. Bad data from the bus is counted and skipped by the
/// node itself; an error here means the node cannot go on (the supervisor restarts the process).
#[derive(Debug, thiserror::Error)]
pub enum NodeError {
    #[error("{node}: {reason}")]
    Failed { node: &'static str, reason: String },
    #[error("publishing on {topic:?}: {reason}")]
    Publish { topic: Topic, reason: String },
}

/// One on-board component.
pub trait Node {
    /// Process name (`vision`, `filter`, `mapper`, `comms`, `driver`).
    fn name(&self) -> &'static str;
    /// Topics this node receives (its subscriptions).
    fn subscriptions(&self) -> &'static [Topic];
    /// Handles one received message.
    fn on_message(&mut self, message: Message<'_>, out: &mut dyn Outbox) -> Result<(), NodeError>;
    /// Called once per release of the node's fixed-rate task, after the received messages were
    /// handled. `now_ns` is sensor time (since the mission start).
    fn on_tick(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError>;
}
