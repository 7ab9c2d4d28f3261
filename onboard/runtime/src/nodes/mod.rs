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
pub mod gaze;
pub mod mapper;
pub mod markers;
pub mod surroundings;
pub mod vision;

use msgs::{
    DisparityHeader, DisparityPixel, FilterStateMsg, FrameSwitchMsg, FrameSwitchRequestMsg, HazardCellsMsg,
    HeadCommandMsg, ImuMsg, MarkerMsg, StereoHeader, TaskStatsMsg, TeamHeader, VoDeltaMsg, WheelOdomMsg,
};

pub use crate::topics::Topic;

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
    HeadCommand(&'a HeadCommandMsg),
    Hazards(&'a HazardCellsMsg),
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
            Message::HeadCommand(_) => Topic::HeadCommand,
            Message::Hazards(_) => Topic::Hazards,
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
            Message::HeadCommand(m) => m.stamp_ns,
            Message::Hazards(m) => m.stamp_ns,
        }
    }
}

/// Where a node's messages go: the bus publisher set (process runner) or the lockstep runner's
/// delivery queue. [`Outbox::publish`] copies the message once (into shared memory, or into the
/// runner's queue); the node keeps its buffers. An image is not copied at all: the driver writes
/// it straight into the transport's memory with [`Outbox::publish_stereo_with`].
pub trait Outbox {
    fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError>;

    /// Publishes a stereo pair that `fill` writes in place: it gets the payload (left rows, then
    /// right rows, `2 · width · height` bytes of `header`) in the memory the readers will read,
    /// a loaned shared-memory sample on the bus. An error from `fill` publishes nothing.
    ///
    /// The provided body is for outboxes without memory of their own (tests, recorders): it
    /// fills a buffer of its own and publishes that. The runners' outboxes override it.
    fn publish_stereo_with(
        &mut self,
        header: &StereoHeader,
        fill: &mut dyn FnMut(&mut [u8]) -> Result<(), NodeError>,
    ) -> Result<(), NodeError> {
        let len = stereo_len(header)?;
        let mut bytes = vec![0; len];
        fill(&mut bytes)?;
        self.publish(Message::Stereo(header, &bytes))
    }

    /// Publishes a disparity map whose `width · height` pixels `pixel(i)` gives, written straight
    /// into the transport's memory (each pixel once). The provided body is for outboxes without
    /// memory of their own; the runners' outboxes override it.
    fn publish_disparity_with(
        &mut self,
        header: &DisparityHeader,
        pixel: &dyn Fn(usize) -> DisparityPixel,
    ) -> Result<(), NodeError> {
        let pixels: Vec<DisparityPixel> = (0..disparity_len(header)?).map(pixel).collect();
        self.publish(Message::Disparity(header, &pixels))
    }
}

/// The pixel count of a disparity map, `width · height`.
pub fn disparity_len(header: &DisparityHeader) -> Result<usize, NodeError> {
    usize::try_from(header.width_px)
        .ok()
        .and_then(|w| w.checked_mul(usize::try_from(header.height_px).ok()?))
        .ok_or_else(|| NodeError::Publish {
            topic: Topic::Disparity,
            reason: format!("a {}x{} map does not fit in memory", header.width_px, header.height_px),
        })
}

/// The payload length of a stereo pair, `2 · width · height` bytes.
pub fn stereo_len(header: &StereoHeader) -> Result<usize, NodeError> {
    usize::try_from(header.width_px)
        .ok()
        .and_then(|w| w.checked_mul(usize::try_from(header.height_px).ok()?)?.checked_mul(2))
        .ok_or_else(|| NodeError::Publish {
            topic: Topic::Stereo,
            reason: format!("a {}x{} pair does not fit in memory", header.width_px, header.height_px),
        })
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
