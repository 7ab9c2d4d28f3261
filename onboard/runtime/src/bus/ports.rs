//! Publisher and subscriber sets: the [`Outbox`] of a process and its drained inbox.

use std::fmt::Debug;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::port::BackpressureAction;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample::Sample;
use iceoryx2::service::builder::publish_subscribe::{
    Builder, PublishSubscribeCreateError, PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::publisher::PortFactoryPublisher;
use msgs::{
    DisparityHeader, DisparityPixel, FilterStateMsg, FrameSwitchMsg, FrameSwitchRequestMsg, HazardCellsMsg,
    HeadCommandMsg, ImuMsg, MarkerMsg, StereoHeader, TaskStatsMsg, TeamHeader, VoDeltaMsg, WheelOdomMsg,
};

use super::{
    Bus, BusError, Ipc, Overflow, SliceMismatch, disparity_message, qos, remove_hung_services, robot_prefix,
    stereo_message, team_message, topic_index,
};
use crate::nodes::{Message, NodeError, Outbox, Topic};

const TOPICS: usize = Topic::ALL.len();

/// A drain takes at most this many receive-and-merge rounds, so a publisher faster than the
/// drain cannot keep a task in it forever.
const MAX_DRAIN_ROUNDS: usize = 16;

/// Applies a topic's service settings to a service builder.
fn with_qos<P: Debug + IceoryxSend + ?Sized, H: Debug + ZeroCopySend>(
    builder: Builder<P, H, Ipc>,
    topic: Topic,
) -> Builder<P, H, Ipc> {
    let q = qos(topic);
    builder
        .max_publishers(q.max_publishers)
        .max_subscribers(q.max_subscribers)
        .subscriber_max_buffer_size(q.subscriber_buffer)
        .subscriber_max_borrowed_samples(q.subscriber_borrow)
        .history_size(q.history)
        .enable_safe_overflow(q.overflow == Overflow::DropOldest)
}

/// Applies a topic's publisher settings; `discarded` counts samples a full buffer refused.
fn publisher_qos<'f, P: Debug + IceoryxSend + ?Sized, H: Debug + ZeroCopySend>(
    builder: PortFactoryPublisher<'f, Ipc, P, H>,
    topic: Topic,
    discarded: &Arc<AtomicU64>,
) -> PortFactoryPublisher<'f, Ipc, P, H> {
    let builder = builder.max_loaned_samples(2).backpressure_strategy(BackpressureStrategy::DiscardData);
    match qos(topic).overflow {
        Overflow::DropOldest => builder,
        Overflow::DiscardNewest => {
            let discarded = Arc::clone(discarded);
            // Called once per refused delivery; answering DiscardData never blocks the publisher.
            builder.set_backpressure_handler(move |_| {
                discarded.fetch_add(1, Ordering::Relaxed);
                BackpressureAction::DiscardData
            })
        }
    }
}

fn service_error<E: Debug>(topic: Topic) -> impl FnOnce(E) -> BusError {
    move |e| BusError::Service { topic, reason: format!("{e:?}") }
}

fn publisher_error<E: Debug>(topic: Topic) -> impl FnOnce(E) -> BusError {
    move |e| BusError::Publisher { topic, reason: format!("{e:?}") }
}

fn subscriber_error<E: Debug>(topic: Topic) -> impl FnOnce(E) -> BusError {
    move |e| BusError::Subscriber { topic, reason: format!("{e:?}") }
}

fn hangs_in_creation(error: &PublishSubscribeOpenOrCreateError) -> bool {
    matches!(
        error,
        PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(PublishSubscribeOpenError::HangsInCreation)
            | PublishSubscribeOpenOrCreateError::PublishSubscribeCreateError(
                PublishSubscribeCreateError::HangsInCreation
            )
    )
}

/// Opens (or creates) a topic's service with its settings; `$payload` may be a slice type. A
/// service left half-created by a killed process is removed once it counts as hung, then the
/// open is retried once.
macro_rules! service {
    ($bus:expr, $topic:expr, $payload:ty, $header:ty) => {{
        let name = $topic.service_name($bus.robot_id);
        let service_name =
            ServiceName::new(&name).map_err(|e| BusError::Name { name: name.clone(), reason: format!("{e:?}") })?;
        let open = || {
            with_qos(
                $bus.node.service_builder(&service_name).publish_subscribe::<$payload>().user_header::<$header>(),
                $topic,
            )
            .open_or_create()
        };
        match open() {
            Ok(service) => service,
            Err(e) if hangs_in_creation(&e) => {
                let removed = remove_hung_services($bus.node.config(), &robot_prefix($bus.robot_id));
                $bus.hung_services_repaired.fetch_add(removed, Ordering::Relaxed);
                eprintln!(
                    "bus {}: {name} hung in creation; removed {removed} hung service definition(s)",
                    $bus.node_name()
                );
                open().map_err(service_error($topic))?
            }
            Err(e) => return Err(service_error($topic)(e)),
        }
    }};
}

/// One topic's publisher.
#[derive(Debug)]
enum Pub {
    Imu(Publisher<Ipc, ImuMsg, ()>),
    WheelOdom(Publisher<Ipc, WheelOdomMsg, ()>),
    Stereo(Publisher<Ipc, [u8], StereoHeader>),
    Disparity(Publisher<Ipc, [DisparityPixel], DisparityHeader>),
    VoDelta(Publisher<Ipc, VoDeltaMsg, ()>),
    Marker(Publisher<Ipc, MarkerMsg, ()>),
    FilterState(Publisher<Ipc, FilterStateMsg, ()>),
    FrameSwitchRequest(Publisher<Ipc, FrameSwitchRequestMsg, ()>),
    FrameSwitch(Publisher<Ipc, FrameSwitchMsg, ()>),
    Team(Publisher<Ipc, [u8], TeamHeader>),
    TaskStats(Publisher<Ipc, TaskStatsMsg, ()>),
    HeadCommand(Publisher<Ipc, HeadCommandMsg, ()>),
    Hazards(Publisher<Ipc, HazardCellsMsg, ()>),
}

fn send_value<T: Debug + Copy + ZeroCopySend>(port: &Publisher<Ipc, T, ()>, value: T) -> Result<usize, String> {
    let sample = port.loan_uninit().map_err(|e| format!("loan: {e:?}"))?;
    sample.write_payload(value).send().map_err(|e| format!("send: {e:?}"))
}

/// The one copy of a slice message: straight from the node's buffer into the loaned sample.
fn send_slice<T: Debug + Copy + ZeroCopySend, H: Debug + Copy + Default + ZeroCopySend>(
    port: &Publisher<Ipc, [T], H>,
    header: H,
    data: &[T],
) -> Result<usize, String> {
    let mut sample =
        port.loan_slice_uninit(data.len()).map_err(|e| format!("loan of {} elements: {e:?}", data.len()))?;
    *sample.user_header_mut() = header;
    sample.write_from_slice(data).send().map_err(|e| format!("send: {e:?}"))
}

impl Pub {
    fn create(bus: &Bus, topic: Topic, discarded: &Arc<AtomicU64>) -> Result<Pub, BusError> {
        let pixels = bus
            .geometry
            .pixels()
            .ok_or(BusError::Geometry { width_px: bus.geometry.width_px, height_px: bus.geometry.height_px })?;
        macro_rules! fixed {
            ($variant:ident, $payload:ty) => {{
                let service = service!(bus, topic, $payload, ());
                Pub::$variant(
                    publisher_qos(service.publisher_builder(), topic, discarded)
                        .create()
                        .map_err(publisher_error(topic))?,
                )
            }};
        }
        macro_rules! sliced {
            ($variant:ident, $payload:ty, $header:ty, $max_len:expr) => {{
                let service = service!(bus, topic, [$payload], $header);
                Pub::$variant(
                    publisher_qos(service.publisher_builder(), topic, discarded)
                        .initial_max_slice_len($max_len)
                        .create()
                        .map_err(publisher_error(topic))?,
                )
            }};
        }
        Ok(match topic {
            Topic::Imu => fixed!(Imu, ImuMsg),
            Topic::WheelOdom => fixed!(WheelOdom, WheelOdomMsg),
            Topic::Stereo => sliced!(Stereo, u8, StereoHeader, 2 * pixels),
            Topic::Disparity => sliced!(Disparity, DisparityPixel, DisparityHeader, pixels),
            Topic::VoDelta => fixed!(VoDelta, VoDeltaMsg),
            Topic::Marker => fixed!(Marker, MarkerMsg),
            Topic::FilterState => fixed!(FilterState, FilterStateMsg),
            Topic::FrameSwitchRequest => fixed!(FrameSwitchRequest, FrameSwitchRequestMsg),
            Topic::FrameSwitch => fixed!(FrameSwitch, FrameSwitchMsg),
            Topic::ToComms | Topic::ToMapper => sliced!(Team, u8, TeamHeader, protocol::MAX_PACKET_BYTES),
            Topic::TaskStats => fixed!(TaskStats, TaskStatsMsg),
            Topic::HeadCommand => fixed!(HeadCommand, HeadCommandMsg),
            Topic::Hazards => fixed!(Hazards, HazardCellsMsg),
        })
    }

    /// Sends `message`; the number of subscribers it reached.
    fn send(&self, message: Message<'_>) -> Result<usize, String> {
        match (self, message) {
            (Pub::Imu(p), Message::Imu(m)) => send_value(p, *m),
            (Pub::WheelOdom(p), Message::WheelOdom(m)) => send_value(p, *m),
            (Pub::Stereo(p), Message::Stereo(h, bytes)) => {
                stereo_message(h, bytes).map_err(|e| e.to_string())?;
                send_slice(p, *h, bytes)
            }
            (Pub::Disparity(p), Message::Disparity(h, pixels)) => {
                disparity_message(h, pixels).map_err(|e| e.to_string())?;
                send_slice(p, *h, pixels)
            }
            (Pub::VoDelta(p), Message::VoDelta(m)) => send_value(p, *m),
            (Pub::Marker(p), Message::Marker(m)) => send_value(p, *m),
            (Pub::FilterState(p), Message::FilterState(m)) => send_value(p, *m),
            (Pub::FrameSwitchRequest(p), Message::FrameSwitchRequest(m)) => send_value(p, *m),
            (Pub::FrameSwitch(p), Message::FrameSwitch(m)) => send_value(p, *m),
            (Pub::Team(p), Message::ToComms(h, bytes) | Message::ToMapper(h, bytes)) => send_slice(p, *h, bytes),
            (Pub::TaskStats(p), Message::TaskStats(m)) => send_value(p, *m),
            (Pub::HeadCommand(p), Message::HeadCommand(m)) => send_value(p, *m),
            (Pub::Hazards(p), Message::Hazards(m)) => send_value(p, *m),
            _ => Err("publisher and message types differ".to_owned()),
        }
    }
}

/// What a publisher saw on one topic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PublishCounters {
    /// Messages published.
    pub sent: u64,
    /// Sum over messages of the subscribers each reached.
    pub deliveries: u64,
    /// Deliveries refused by a full subscriber buffer (discard-newest topics only; drop-oldest
    /// topics overwrite silently and are counted by the receiver's sequence gaps).
    pub discarded: u64,
    /// Publishes that failed (loan, size, send).
    pub failed: u64,
}

struct OutPort {
    port: Pub,
    discarded: Arc<AtomicU64>,
    counters: PublishCounters,
}

impl OutPort {
    /// Counts a send's outcome (subscribers reached, or the failure) and turns it into the
    /// node's result.
    fn record(&mut self, topic: Topic, sent: Result<usize, String>) -> Result<(), NodeError> {
        match sent {
            Ok(reached) => {
                self.counters.sent += 1;
                self.counters.deliveries += reached as u64;
                Ok(())
            }
            Err(reason) => {
                self.counters.failed += 1;
                Err(NodeError::Publish { topic, reason })
            }
        }
    }
}

/// A process's publishers: implements [`Outbox`] for its node.
pub struct BusOutbox {
    ports: [Option<OutPort>; TOPICS],
}

impl Debug for BusOutbox {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BusOutbox").field("topics", &self.topics()).finish()
    }
}

impl BusOutbox {
    pub(super) fn new(bus: &Bus, topics: &[Topic]) -> Result<BusOutbox, BusError> {
        let mut ports: [Option<OutPort>; TOPICS] = Default::default();
        for &topic in topics {
            let discarded = Arc::new(AtomicU64::new(0));
            let port = Pub::create(bus, topic, &discarded)?;
            ports[topic_index(topic)] = Some(OutPort { port, discarded, counters: PublishCounters::default() });
        }
        Ok(BusOutbox { ports })
    }

    /// Topics this outbox publishes.
    pub fn topics(&self) -> Vec<Topic> {
        Topic::ALL.into_iter().filter(|&t| self.ports[topic_index(t)].is_some()).collect()
    }

    /// Counters of one topic (zero if it has no publisher here).
    pub fn counters(&self, topic: Topic) -> PublishCounters {
        self.ports[topic_index(topic)]
            .as_ref()
            .map(|p| PublishCounters { discarded: p.discarded.load(Ordering::Relaxed), ..p.counters })
            .unwrap_or_default()
    }

    fn out_port(&mut self, topic: Topic) -> Result<&mut OutPort, NodeError> {
        self.ports[topic_index(topic)].as_mut().ok_or_else(|| NodeError::Publish {
            topic,
            reason: "this outbox has no publisher for the topic".to_owned(),
        })
    }
}

fn wrong_port(topic: Topic) -> NodeError {
    NodeError::Publish { topic, reason: "publisher and message types differ".to_owned() }
}

impl Outbox for BusOutbox {
    /// The pair is written into a loaned shared-memory sample, then sent: the one and only time
    /// its bytes are written.
    fn publish_stereo_with(
        &mut self,
        header: &StereoHeader,
        fill: &mut dyn FnMut(&mut [u8]) -> Result<(), NodeError>,
    ) -> Result<(), NodeError> {
        let topic = Topic::Stereo;
        let len = crate::nodes::stereo_len(header)?;
        let out = self.out_port(topic)?;
        let Pub::Stereo(port) = &out.port else { return Err(wrong_port(topic)) };
        let mut sample = match port.loan_slice(len) {
            Ok(sample) => sample,
            Err(e) => return out.record(topic, Err(format!("loan of {len} bytes: {e:?}"))),
        };
        *sample.user_header_mut() = *header;
        // An error here drops the sample unsent: the loan goes back to the publisher.
        fill(sample.payload_mut())?;
        let sent = sample.send().map_err(|e| format!("send: {e:?}"));
        out.record(topic, sent)
    }

    /// Each pixel is written once, straight into a loaned shared-memory sample.
    fn publish_disparity_with(
        &mut self,
        header: &DisparityHeader,
        pixel: &dyn Fn(usize) -> DisparityPixel,
    ) -> Result<(), NodeError> {
        let topic = Topic::Disparity;
        let len = crate::nodes::disparity_len(header)?;
        let out = self.out_port(topic)?;
        let Pub::Disparity(port) = &out.port else { return Err(wrong_port(topic)) };
        let mut sample = match port.loan_slice_uninit(len) {
            Ok(sample) => sample,
            Err(e) => return out.record(topic, Err(format!("loan of {len} pixels: {e:?}"))),
        };
        *sample.user_header_mut() = *header;
        let sent = sample.write_from_fn(pixel).send().map_err(|e| format!("send: {e:?}"));
        out.record(topic, sent)
    }

    fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError> {
        let topic = message.topic();
        let out = self.out_port(topic)?;
        let sent = out.port.send(message);
        out.record(topic, sent)
    }
}

/// One topic's subscriber.
#[derive(Debug)]
enum Sub {
    Imu(Subscriber<Ipc, ImuMsg, ()>),
    WheelOdom(Subscriber<Ipc, WheelOdomMsg, ()>),
    Stereo(Subscriber<Ipc, [u8], StereoHeader>),
    Disparity(Subscriber<Ipc, [DisparityPixel], DisparityHeader>),
    VoDelta(Subscriber<Ipc, VoDeltaMsg, ()>),
    Marker(Subscriber<Ipc, MarkerMsg, ()>),
    FilterState(Subscriber<Ipc, FilterStateMsg, ()>),
    FrameSwitchRequest(Subscriber<Ipc, FrameSwitchRequestMsg, ()>),
    FrameSwitch(Subscriber<Ipc, FrameSwitchMsg, ()>),
    Team(Subscriber<Ipc, [u8], TeamHeader>),
    TaskStats(Subscriber<Ipc, TaskStatsMsg, ()>),
    HeadCommand(Subscriber<Ipc, HeadCommandMsg, ()>),
    Hazards(Subscriber<Ipc, HazardCellsMsg, ()>),
}

/// A received sample, held (still in shared memory) until the drain round hands it over.
#[derive(Debug)]
enum Held {
    Imu(Sample<Ipc, ImuMsg, ()>),
    WheelOdom(Sample<Ipc, WheelOdomMsg, ()>),
    Stereo(Sample<Ipc, [u8], StereoHeader>),
    Disparity(Sample<Ipc, [DisparityPixel], DisparityHeader>),
    VoDelta(Sample<Ipc, VoDeltaMsg, ()>),
    Marker(Sample<Ipc, MarkerMsg, ()>),
    FilterState(Sample<Ipc, FilterStateMsg, ()>),
    FrameSwitchRequest(Sample<Ipc, FrameSwitchRequestMsg, ()>),
    FrameSwitch(Sample<Ipc, FrameSwitchMsg, ()>),
    Team(Topic, Sample<Ipc, [u8], TeamHeader>),
    TaskStats(Sample<Ipc, TaskStatsMsg, ()>),
    HeadCommand(Sample<Ipc, HeadCommandMsg, ()>),
    Hazards(Sample<Ipc, HazardCellsMsg, ()>),
}

impl Held {
    /// The sample as a message borrowed from shared memory; slices are checked against headers.
    fn message(&self) -> Result<Message<'_>, SliceMismatch> {
        Ok(match self {
            Held::Imu(s) => Message::Imu(s.payload()),
            Held::WheelOdom(s) => Message::WheelOdom(s.payload()),
            Held::Stereo(s) => stereo_message(s.user_header(), s.payload())?,
            Held::Disparity(s) => disparity_message(s.user_header(), s.payload())?,
            Held::VoDelta(s) => Message::VoDelta(s.payload()),
            Held::Marker(s) => Message::Marker(s.payload()),
            Held::FilterState(s) => Message::FilterState(s.payload()),
            Held::FrameSwitchRequest(s) => Message::FrameSwitchRequest(s.payload()),
            Held::FrameSwitch(s) => Message::FrameSwitch(s.payload()),
            Held::Team(topic, s) => team_message(*topic, s.user_header(), s.payload())?,
            Held::TaskStats(s) => Message::TaskStats(s.payload()),
            Held::HeadCommand(s) => Message::HeadCommand(s.payload()),
            Held::Hazards(s) => Message::Hazards(s.payload()),
        })
    }
}

impl Sub {
    fn create(bus: &Bus, topic: Topic) -> Result<Sub, BusError> {
        let buffer = qos(topic).subscriber_buffer;
        macro_rules! sub {
            ($variant:ident, $payload:ty, $header:ty) => {{
                let service = service!(bus, topic, $payload, $header);
                Sub::$variant(
                    service.subscriber_builder().buffer_size(buffer).create().map_err(subscriber_error(topic))?,
                )
            }};
        }
        Ok(match topic {
            Topic::Imu => sub!(Imu, ImuMsg, ()),
            Topic::WheelOdom => sub!(WheelOdom, WheelOdomMsg, ()),
            Topic::Stereo => sub!(Stereo, [u8], StereoHeader),
            Topic::Disparity => sub!(Disparity, [DisparityPixel], DisparityHeader),
            Topic::VoDelta => sub!(VoDelta, VoDeltaMsg, ()),
            Topic::Marker => sub!(Marker, MarkerMsg, ()),
            Topic::FilterState => sub!(FilterState, FilterStateMsg, ()),
            Topic::FrameSwitchRequest => sub!(FrameSwitchRequest, FrameSwitchRequestMsg, ()),
            Topic::FrameSwitch => sub!(FrameSwitch, FrameSwitchMsg, ()),
            Topic::ToComms | Topic::ToMapper => sub!(Team, [u8], TeamHeader),
            Topic::TaskStats => sub!(TaskStats, TaskStatsMsg, ()),
            Topic::HeadCommand => sub!(HeadCommand, HeadCommandMsg, ()),
            Topic::Hazards => sub!(Hazards, HazardCellsMsg, ()),
        })
    }

    /// The next pending sample, if any.
    fn receive(&self, topic: Topic) -> Result<Option<Held>, String> {
        fn wrap<T>(r: Result<Option<T>, impl Debug>, f: impl FnOnce(T) -> Held) -> Result<Option<Held>, String> {
            r.map(|s| s.map(f)).map_err(|e| format!("{e:?}"))
        }
        match self {
            Sub::Imu(s) => wrap(s.receive(), Held::Imu),
            Sub::WheelOdom(s) => wrap(s.receive(), Held::WheelOdom),
            Sub::Stereo(s) => wrap(s.receive(), Held::Stereo),
            Sub::Disparity(s) => wrap(s.receive(), Held::Disparity),
            Sub::VoDelta(s) => wrap(s.receive(), Held::VoDelta),
            Sub::Marker(s) => wrap(s.receive(), Held::Marker),
            Sub::FilterState(s) => wrap(s.receive(), Held::FilterState),
            Sub::FrameSwitchRequest(s) => wrap(s.receive(), Held::FrameSwitchRequest),
            Sub::FrameSwitch(s) => wrap(s.receive(), Held::FrameSwitch),
            Sub::Team(s) => wrap(s.receive(), |sample| Held::Team(topic, sample)),
            Sub::TaskStats(s) => wrap(s.receive(), Held::TaskStats),
            Sub::HeadCommand(s) => wrap(s.receive(), Held::HeadCommand),
            Sub::Hazards(s) => wrap(s.receive(), Held::Hazards),
        }
    }

    fn has_samples(&self) -> Result<bool, String> {
        let r = match self {
            Sub::Imu(s) => s.has_samples(),
            Sub::WheelOdom(s) => s.has_samples(),
            Sub::Stereo(s) => s.has_samples(),
            Sub::Disparity(s) => s.has_samples(),
            Sub::VoDelta(s) => s.has_samples(),
            Sub::Marker(s) => s.has_samples(),
            Sub::FilterState(s) => s.has_samples(),
            Sub::FrameSwitchRequest(s) => s.has_samples(),
            Sub::FrameSwitch(s) => s.has_samples(),
            Sub::Team(s) => s.has_samples(),
            Sub::TaskStats(s) => s.has_samples(),
            Sub::HeadCommand(s) => s.has_samples(),
            Sub::Hazards(s) => s.has_samples(),
        };
        r.map_err(|e| format!("{e:?}"))
    }
}

/// What a subscriber saw on one topic.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct TopicCounters {
    /// Samples handed to the handler.
    pub received: u64,
    /// Samples whose slice did not match their header (skipped).
    pub rejected: u64,
    /// Samples missing between consecutive `sequence` numbers (IMU, wheel odometry, stereo,
    /// disparity): what drop-oldest overwrote or a full buffer refused. A sequence that goes
    /// backwards (producer restarted) starts over without counting.
    pub sequence_gaps: u64,
}

fn sequence_of(message: &Message<'_>) -> Option<u64> {
    match message {
        Message::Imu(m) => Some(m.sequence),
        Message::WheelOdom(m) => Some(m.sequence),
        Message::Stereo(h, _) => Some(h.sequence),
        Message::Disparity(h, _) => Some(h.sequence),
        _ => None,
    }
}

/// The fullest receive queue of a process over a span: the samples waiting in one topic's
/// subscriber buffer when a drain found them, against the buffer's capacity.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct QueuePeak {
    pub topic: Topic,
    pub depth: u32,
    pub capacity: u32,
}

impl QueuePeak {
    fn fuller_than(&self, other: &QueuePeak) -> bool {
        // depth / capacity compared without division.
        u64::from(self.depth) * u64::from(other.capacity.max(1))
            > u64::from(other.depth) * u64::from(self.capacity.max(1))
    }
}

/// A process's subscribers, drained once per task release.
pub struct BusInbox {
    subs: Vec<(Topic, Sub)>,
    counters: [TopicCounters; TOPICS],
    last_sequence: [Option<u64>; TOPICS],
    /// Samples taken per topic in the current drain (its queue depth when the drain began).
    drained: [u32; TOPICS],
    peak: Option<QueuePeak>,
    /// Reused across drains so a warmed-up drain does not allocate.
    held: Vec<Held>,
    order: Vec<(u64, u8, usize)>,
}

impl Debug for BusInbox {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BusInbox").field("topics", &self.topics()).finish()
    }
}

impl BusInbox {
    pub(super) fn new(bus: &Bus, topics: &[Topic]) -> Result<BusInbox, BusError> {
        let subs = topics.iter().map(|&t| Ok((t, Sub::create(bus, t)?))).collect::<Result<Vec<_>, BusError>>()?;
        let capacity = topics.iter().map(|&t| qos(t).subscriber_borrow).sum();
        Ok(BusInbox {
            subs,
            counters: [TopicCounters::default(); TOPICS],
            last_sequence: [None; TOPICS],
            drained: [0; TOPICS],
            peak: None,
            held: Vec::with_capacity(capacity),
            order: Vec::with_capacity(capacity),
        })
    }

    pub fn topics(&self) -> Vec<Topic> {
        self.subs.iter().map(|(t, _)| *t).collect()
    }

    /// Counters of one topic (zero if it is not subscribed here).
    pub fn counters(&self, topic: Topic) -> TopicCounters {
        self.counters[topic_index(topic)]
    }

    /// Whether any subscribed topic has a sample waiting.
    pub fn has_pending(&self) -> Result<bool, BusError> {
        for (topic, sub) in &self.subs {
            if sub.has_samples().map_err(|reason| BusError::Receive { topic: *topic, reason })? {
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// Polls until a sample is pending or `timeout` passed (tests and benchmarks; the firmware's
    /// tasks drain at their own rate). Spins briefly, then sleeps 100 µs between polls.
    pub fn wait(&mut self, timeout: Duration) -> Result<bool, BusError> {
        let start = Instant::now();
        loop {
            if self.has_pending()? {
                return Ok(true);
            }
            let waited = start.elapsed();
            if waited >= timeout {
                return Ok(false);
            }
            if waited < Duration::from_micros(200) {
                std::thread::yield_now();
            } else {
                std::thread::sleep(Duration::from_micros(100));
            }
        }
    }

    /// Receives every pending sample and hands each to `handler` as a message borrowed from
    /// shared memory, merged across topics by stamp (module docs: receive order). Returns the
    /// number handed over. Samples whose slice does not match their header are counted as
    /// rejected and skipped. On a handler error the rest of the round is released unhandled.
    pub fn drain(&mut self, handler: &mut dyn FnMut(Message<'_>) -> Result<(), NodeError>) -> Result<usize, BusError> {
        let mut handed = 0;
        self.drained = [0; TOPICS];
        for _ in 0..MAX_DRAIN_ROUNDS {
            let more = self.receive_round()?;
            let result = self.hand_over(handler);
            self.held.clear();
            self.order.clear();
            handed += result?;
            if !more {
                break;
            }
        }
        for &(topic, _) in &self.subs {
            let seen = QueuePeak {
                topic,
                depth: self.drained[topic_index(topic)],
                capacity: u32::try_from(qos(topic).subscriber_buffer).unwrap_or(u32::MAX),
            };
            if self.peak.is_none_or(|peak| seen.fuller_than(&peak)) {
                self.peak = Some(seen);
            }
        }
        Ok(handed)
    }

    /// The fullest queue since the last call (see [`QueuePeak`]); `None` before the first drain.
    pub fn take_queue_peak(&mut self) -> Option<QueuePeak> {
        self.peak.take()
    }

    /// Fills `held`; true if some topic stopped at its borrow limit with samples left.
    fn receive_round(&mut self) -> Result<bool, BusError> {
        let mut more = false;
        for (topic, sub) in &self.subs {
            let limit = qos(*topic).subscriber_borrow;
            let mut taken = 0;
            while taken < limit {
                match sub.receive(*topic).map_err(|reason| BusError::Receive { topic: *topic, reason })? {
                    Some(held) => {
                        self.held.push(held);
                        taken += 1;
                        self.drained[topic_index(*topic)] += 1;
                    }
                    None => break,
                }
            }
            if taken == limit {
                more |= sub.has_samples().map_err(|reason| BusError::Receive { topic: *topic, reason })?;
            }
        }
        Ok(more)
    }

    fn hand_over(&mut self, handler: &mut dyn FnMut(Message<'_>) -> Result<(), NodeError>) -> Result<usize, BusError> {
        for (index, held) in self.held.iter().enumerate() {
            match held.message() {
                Ok(message) => self.order.push((message.stamp_ns(), message.topic().code(), index)),
                Err(mismatch) => self.counters[topic_index(mismatch.topic)].rejected += 1,
            }
        }
        // The key is unique (arrival index), so the unstable sort is deterministic and in place.
        self.order.sort_unstable();
        let mut handed = 0;
        for &(_, _, index) in &self.order {
            let Some(Ok(message)) = self.held.get(index).map(Held::message) else { continue };
            let slot = topic_index(message.topic());
            if let Some(sequence) = sequence_of(&message) {
                if let Some(last) = self.last_sequence[slot]
                    && sequence > last
                {
                    self.counters[slot].sequence_gaps += sequence - last - 1;
                }
                self.last_sequence[slot] = Some(sequence);
            }
            self.counters[slot].received += 1;
            handler(message)?;
            handed += 1;
        }
        Ok(handed)
    }
}
