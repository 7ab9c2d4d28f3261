//! The iceoryx2 shared-memory bus of the process runner (DESIGN §1, §4).
//!
//! One iceoryx2 IPC node per process (`rover{id}-{process}`), one publish-subscribe service per
//! [`Topic`] (`rover/{id}/…`), payloads exactly the `msgs` types; image-like topics carry a user
//! header plus a slice. A publish writes the message once into a loaned shared-memory sample; a
//! drain hands every received sample to the node as a [`Message`] borrowed *in place* from shared
//! memory (the disparity map the mapper reads is the vision process's memory, not a copy:
//! `tests/zero_copy.rs` shows it through `/proc/*/maps`).
//!
//! Every robot's files carry their own iceoryx2 prefix (`iox2_r{id}_`), so robots simulated on
//! one machine (and parallel tests) neither see nor clean up each other's nodes.
//!
//! # After a crash
//! A killed process leaves its node, its ports and the data segments of its publishers behind
//! (iceoryx2 FAQ: stale shared memory). [`Bus::open`] therefore first lists the robot's nodes and
//! removes the stale resources of every dead one ([`remove_stale`], also callable by the
//! supervisor before it starts anything), and reports what it removed ([`StaleCleanup`]).
//!
//! Two states iceoryx2 0.10 does not recover from on its own are repaired here (both reached by
//! `tests/bus_recovery.rs`, which kills processes in the middle of creating their services):
//! - a node killed while writing its details or a service/port tag leaves an unfinished file,
//!   and the dead-node cleanup then fails on its non-empty directory on every attempt: the
//!   unfinished files of dead nodes are removed first;
//! - a process killed while writing a service's definition leaves it unfinished, and every later
//!   open fails with `HangsInCreation`: once older than iceoryx2's creation timeout (1 s; after
//!   that iceoryx2 itself gives up on it) the definition is removed and the open retried.
//!
//! The publisher counts a full buffer only for subscribers that have attached to their
//! connection (received at least once); for one that has not, a sample that finds its buffer
//! full is dropped uncounted.
//!
//! # Service settings per topic ([`qos`])
//! Buffers are per subscriber and per publisher connection. *Drop oldest* is iceoryx2's safe
//! overflow: the newest sample replaces the oldest unread one. *Discard newest* turns safe
//! overflow off: a sample that finds the buffer full is not delivered to that subscriber, the
//! publisher never blocks, and the publisher counts it ([`PublishCounters::discarded`]).
//!
//! *History* (iceoryx2 0.10): the publisher keeps its last `history` samples, and a subscriber
//! that connects gets up to `min(history, its buffer)` of them, delivered when the publisher next
//! updates its connections (at its next send). Only the IMU has one: a restarted filter resumes
//! from its checkpoint (≤ 0.25 s old) and takes the samples it missed from the history
//! (`nodes::filter`); the buffer is twice the history so that the new samples sent before the
//! filter's first drain still fit behind the replayed ones. Everywhere else history is 0: a
//! restarted process rebuilds its state from its own persistence, and a replayed stale message
//! (e.g. a frame-switch request for a frame that already ended in a previous life) would be
//! misapplied.
//!
//! | topic | rate | sub. buffer | borrow | pubs / subs | full buffer | why |
//! |---|---|---|---|---|---|---|
//! | `sensors/imu` | 200 Hz | 512, history 256 | 512 | 2 / 4 | discard newest, counted | the filter drains every 5 ms; 512 samples = 2.56 s, so a filter stall of up to 2 s loses nothing (`tests/bus_recovery.rs`: 200 samples undrained, all arrive in order). Beyond that the loss is counted by the publisher and seen by the filter as a sequence gap; the prefix stays contiguous. History 256 = 1.28 s: covers a filter restart (checkpoint age + ~0.5 s restart, `tests/mission_faults.rs`). |
//! | `sensors/wheel_odom` | 50 Hz | 64 | 64 | 2 / 4 | discard newest, counted | same 1.28 s as the IMU |
//! | `sensors/stereo` | 10 Hz | 2 | 2 | 2 / 3 | drop oldest | vision must work on the newest pair; a late pair is worth less than a dropped one. Drops show as `sequence` gaps ([`TopicCounters::sequence_gaps`]). 1 MB per sample, so buffers stay small. |
//! | `vision/disparity` | 10 Hz | 4 | 2 | 2 / 3 | drop oldest | the mapper may pause for a submap finish; 0.4 s of maps, then oldest dropped and counted as `sequence` gaps. 2 MB per sample. |
//! | `vision/vo_delta` | 10 Hz | 16 | 16 | 2 / 4 | discard newest, counted | the filter needs every keyframe delta; 1.6 s covers the same 1 s filter stall |
//! | `vision/markers` | ≤ 10 Hz | 16 | 16 | 2 / 4 | discard newest, counted | rare measurements, each one matters |
//! | `filter/state` | 200 Hz | 256 | 256 | 2 / 4 | drop oldest | the mapper and comms want the latest 1.28 s; an old state is superseded by a newer one. Not counted (no sequence). |
//! | `mapper/frame_switch_request` | per submap | 8 | 8 | 2 / 4 | discard newest, counted | rare events |
//! | `filter/frame_switch` | per submap | 8 | 8 | 2 / 4 | discard newest, counted | rare events the mapper must not miss |
//! | `mapper/to_comms`, `comms/to_mapper` | events | 64 | 64 | 2 / 4 | discard newest, counted | submaps and constraints are persisted by the mapper and re-sent; the bus never blocks the mapper, it counts |
//! | `telemetry/tasks` | ~1 Hz per task | 16 | 16 | 8 / 4 | drop oldest | every process publishes; stale telemetry is worthless |
//!
//! Two publishers per topic allow a restarted producer before its predecessor's port is
//! reclaimed (or a replay source); subscribers are the consumers, the recorder and one spare for
//! the same restart overlap. Slice publishers are sized from [`ImageGeometry`] (stereo
//! `2·w·h` bytes, disparity `w·h` pixels) and team messages up to [`protocol::MAX_PACKET_BYTES`].
//!
//! # Receive order
//! [`BusInbox::drain`] receives everything pending (up to each topic's borrow limit), then hands
//! it over merged by [`Message::stamp_ns`] (ties: topic code, then arrival), so the filter sees IMU
//! samples and VO deltas in stamp order. Only when a topic has more pending than its borrow limit
//! (images only, in practice) does a drain take several rounds, each merged on its own.
//!
//! # Threads
//! The ports use `ipc_threadsafe`, so [`Bus`], [`BusOutbox`] and [`BusInbox`] are `Send`. Polling
//! ([`BusInbox::drain`] from a fixed-rate task) is the intended use; [`BusInbox::wait`] is a
//! test and benchmark helper.

mod ports;

use std::collections::BTreeSet;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Duration;

use iceoryx2::node::{DeadNodeView, NodeDetails, NodeView};
use iceoryx2::prelude::*;
use msgs::{DisparityHeader, DisparityPixel, StereoHeader, TeamHeader};

use crate::nodes::{Message, NodeError, Topic};

pub use ports::{BusInbox, BusOutbox, PublishCounters, QueuePeak, TopicCounters};

/// The iceoryx2 service flavour: inter-process, ports usable from any thread.
type Ipc = ipc_threadsafe::Service;

/// Size of the camera images the slice services are made for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ImageGeometry {
    pub width_px: u32,
    pub height_px: u32,
}

impl ImageGeometry {
    /// Pixels per image.
    pub fn pixels(self) -> Option<usize> {
        usize::try_from(self.width_px).ok()?.checked_mul(usize::try_from(self.height_px).ok()?)
    }
}

pub use crate::topics::{Overflow, TopicQos};

/// The settings of `topic` (the registry's, [`crate::topics::TOPICS`]); the reasons are in the
/// module documentation's table.
pub fn qos(topic: Topic) -> TopicQos {
    topic.qos()
}

/// Why the bus could not be set up or used.
#[derive(Debug, thiserror::Error)]
pub enum BusError {
    #[error("image geometry {width_px}x{height_px} px is empty or too large")]
    Geometry { width_px: u32, height_px: u32 },
    #[error("invalid iceoryx2 name {name:?}: {reason}")]
    Name { name: String, reason: String },
    #[error("creating the iceoryx2 node {name}: {reason}")]
    Node { name: String, reason: String },
    #[error("listing or cleaning the iceoryx2 nodes of robot {robot_id}: {reason}")]
    Cleanup { robot_id: u16, reason: String },
    #[error("opening the service of {topic:?}: {reason}")]
    Service { topic: Topic, reason: String },
    #[error("creating a publisher on {topic:?}: {reason}")]
    Publisher { topic: Topic, reason: String },
    #[error("creating a subscriber on {topic:?}: {reason}")]
    Subscriber { topic: Topic, reason: String },
    #[error("{topic:?} is listed twice")]
    DuplicateTopic { topic: Topic },
    #[error("receiving on {topic:?}: {reason}")]
    Receive { topic: Topic, reason: String },
    #[error("handling a received message: {0}")]
    Handler(#[from] NodeError),
}

/// A slice payload that does not fit its header.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{topic:?}: slice of {len} elements, header {width_px}x{height_px} px needs {expected:?}")]
pub struct SliceMismatch {
    pub topic: Topic,
    pub len: usize,
    pub width_px: u32,
    pub height_px: u32,
    /// `None` when the header's size overflows `usize`.
    pub expected: Option<usize>,
}

fn image_elements(width_px: u32, height_px: u32, per_pixel: usize) -> Option<usize> {
    ImageGeometry { width_px, height_px }.pixels()?.checked_mul(per_pixel)
}

/// A stereo sample as a [`Message`], if its slice holds exactly `2·w·h` bytes.
pub fn stereo_message<'a>(header: &'a StereoHeader, bytes: &'a [u8]) -> Result<Message<'a>, SliceMismatch> {
    let expected = image_elements(header.width_px, header.height_px, 2);
    if expected != Some(bytes.len()) {
        return Err(SliceMismatch {
            topic: Topic::Stereo,
            len: bytes.len(),
            width_px: header.width_px,
            height_px: header.height_px,
            expected,
        });
    }
    Ok(Message::Stereo(header, bytes))
}

/// A disparity sample as a [`Message`], if its slice holds exactly `w·h` pixels.
pub fn disparity_message<'a>(
    header: &'a DisparityHeader,
    pixels: &'a [DisparityPixel],
) -> Result<Message<'a>, SliceMismatch> {
    let expected = image_elements(header.width_px, header.height_px, 1);
    if expected != Some(pixels.len()) {
        return Err(SliceMismatch {
            topic: Topic::Disparity,
            len: pixels.len(),
            width_px: header.width_px,
            height_px: header.height_px,
            expected,
        });
    }
    Ok(Message::Disparity(header, pixels))
}

/// A team-message sample as a [`Message`] of `topic` (`ToComms` or `ToMapper`); any length up to
/// [`protocol::MAX_PACKET_BYTES`] fits.
pub fn team_message<'a>(topic: Topic, header: &'a TeamHeader, bytes: &'a [u8]) -> Result<Message<'a>, SliceMismatch> {
    let mismatch = || SliceMismatch { topic, len: bytes.len(), width_px: 0, height_px: 0, expected: None };
    if bytes.len() > protocol::MAX_PACKET_BYTES {
        return Err(mismatch());
    }
    match topic {
        Topic::ToComms => Ok(Message::ToComms(header, bytes)),
        Topic::ToMapper => Ok(Message::ToMapper(header, bytes)),
        _ => Err(mismatch()),
    }
}

/// A dead node whose stale resources were removed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DeadNode {
    /// Node name (`rover{id}-{process}`), empty if its details were unreadable.
    pub name: String,
    pub pid: i32,
}

/// What [`remove_stale`] found and removed for one robot.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct StaleCleanup {
    /// Dead nodes whose ports, services and data segments were removed.
    pub removed: Vec<DeadNode>,
    /// Dead nodes that could not be cleaned (with iceoryx2's reason).
    pub failed: Vec<(DeadNode, String)>,
    /// Nodes in an undefined state (half-created or half-removed node files); iceoryx2 cannot
    /// clean these, they are only reported.
    pub undefined_nodes: usize,
    /// Files under `/dev/shm` with the robot's prefix that disappeared during the cleanup.
    pub shm_files_removed: usize,
    /// Unfinished node files of dead nodes removed first (see [`remove_stale`]).
    pub unfinished_files_removed: usize,
    /// Service definitions left unfinished by a process killed while creating the service.
    pub hung_services_removed: usize,
}

impl StaleCleanup {
    pub fn is_empty(&self) -> bool {
        *self == StaleCleanup::default()
    }
}

impl std::fmt::Display for StaleCleanup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} dead node(s) cleaned [{}], {} shm file(s), {} unfinished node file(s), {} hung service(s) removed, \
             {} failed, {} undefined",
            self.removed.len(),
            self.removed.iter().map(|n| format!("{} pid {}", n.name, n.pid)).collect::<Vec<_>>().join(", "),
            self.shm_files_removed,
            self.unfinished_files_removed,
            self.hung_services_removed,
            self.failed.len(),
            self.undefined_nodes
        )
    }
}

/// The file prefix of one robot's iceoryx2 resources.
pub fn robot_prefix(robot_id: u16) -> String {
    format!("iox2_r{robot_id}_")
}

fn robot_config(robot_id: u16) -> Result<Config, BusError> {
    let prefix = robot_prefix(robot_id);
    // The built-in defaults, not a config file: every process of the robot must agree on them.
    let mut config = Config::default();
    // Holding a full buffer in one drain needs as large an expired-connection buffer.
    config.defaults.publish_subscribe.subscriber_expired_connection_buffer =
        Topic::ALL.iter().map(|&t| qos(t).subscriber_borrow).max().unwrap_or(1);
    config.global.prefix = FileName::new(prefix.as_bytes())
        .map_err(|e| BusError::Name { name: prefix.clone(), reason: format!("{e:?}") })?;
    Ok(config)
}

fn shm_files(prefix: &str) -> BTreeSet<String> {
    let Ok(entries) = std::fs::read_dir("/dev/shm") else { return BTreeSet::new() };
    entries.filter_map(|e| e.ok()?.file_name().into_string().ok()).filter(|name| name.starts_with(prefix)).collect()
}

fn path_string(path: &Path) -> String {
    String::from_utf8_lossy(path.as_bytes()).into_owned()
}

/// Whether a file is one iceoryx2 is still writing: its static storage stays owner read-write
/// until finished, then becomes read-only.
fn is_unfinished(metadata: &std::fs::Metadata) -> bool {
    use std::os::unix::fs::PermissionsExt;
    metadata.is_file() && metadata.permissions().mode() & 0o777 == 0o600
}

/// Removes the unfinished files with `prefix` (and `suffix`) in `dir` that `keep` does not
/// protect; returns how many.
fn remove_unfinished(
    dir: &std::path::Path,
    prefix: &str,
    suffix: &str,
    keep: impl Fn(&std::fs::Metadata) -> bool,
) -> usize {
    let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let stale = entry.metadata().is_ok_and(|m| is_unfinished(&m) && !keep(&m));
        if stale && name.starts_with(prefix) && name.ends_with(suffix) && std::fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Removes the unfinished files a dead node left in its node directory; returns how many.
///
/// iceoryx2 0.10 writes a node's details and its service and port tags as static storage files
/// that count only once finished. A node killed in between leaves an unfinished file that the
/// dead-node cleanup neither lists nor removes; the cleanup then fails on the non-empty node
/// directory, on every later attempt too (`tests/bus_recovery.rs` kills processes during service
/// creation and hits this). The process is gone, so nobody will finish these files.
fn remove_unfinished_node_files(config: &Config, node_id: u128, prefix: &str) -> usize {
    let dir = std::path::Path::new(&path_string(&config.global.node_dir())).join(node_id.to_string());
    remove_unfinished(&dir, prefix, "", |_| false)
}

/// Removes the robot's service definitions that have been unfinished for longer than iceoryx2's
/// creation timeout; returns how many.
///
/// A process killed while creating a service leaves its static definition unfinished, and every
/// later open of that service fails with `HangsInCreation` (iceoryx2 0.10 does not recover it).
/// After the creation timeout iceoryx2 itself gives up on such a service, so removing it cannot
/// race a creation that would still succeed.
fn remove_hung_services(config: &Config, prefix: &str) -> usize {
    let timeout = config.global.creation_timeout;
    let suffix = String::from_utf8_lossy(config.global.service.static_config_storage_suffix.as_bytes()).into_owned();
    let young =
        |m: &std::fs::Metadata| m.modified().ok().and_then(|t| t.elapsed().ok()).is_none_or(|age| age <= timeout);
    remove_unfinished(std::path::Path::new(&path_string(&config.global.service_dir())), prefix, &suffix, young)
}

/// How long a service's dynamic segment may stay zero bytes long before it counts as orphaned.
const SIZELESS_SEGMENT_GRACE: Duration = Duration::from_millis(100);

/// Removes the robot's service dynamic segments under `/dev/shm` that are zero bytes long and
/// have stayed so for [`SIZELESS_SEGMENT_GRACE`]; returns how many.
///
/// A process killed between creating a segment and sizing it leaves an empty file, and
/// iceoryx2 0.10's open of a dynamic storage retries a zero-sized mapping forever without
/// looking at its timeout: the dead-node cleanup, which opens the services of the dead node,
/// then hangs (seen in `tests/bus_recovery.rs`). A live creator sizes its segment right after
/// creating it, so one still empty after the grace period has no creator left.
fn remove_sizeless_dynamic_segments(config: &Config, prefix: &str) -> usize {
    let suffix = String::from_utf8_lossy(config.global.service.dynamic_config_storage_suffix.as_bytes()).into_owned();
    let shm = std::path::Path::new("/dev/shm");
    let sizeless = |name: &str| {
        let metadata = std::fs::metadata(shm.join(name)).ok()?;
        let age = metadata.modified().ok()?.elapsed().unwrap_or_default();
        (metadata.is_file() && metadata.len() == 0).then_some(age)
    };
    let mut removed = 0;
    for name in shm_files(prefix).into_iter().filter(|name| name.ends_with(&suffix)) {
        let Some(age) = sizeless(&name) else { continue };
        std::thread::sleep(SIZELESS_SEGMENT_GRACE.saturating_sub(age));
        if sizeless(&name).is_some() && std::fs::remove_file(shm.join(&name)).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Removes the stale iceoryx2 resources of the robot's dead nodes (processes that were killed
/// or crashed without dropping their node). Safe while other processes of the robot run: only
/// nodes whose process is gone are touched.
pub fn remove_stale(robot_id: u16) -> Result<StaleCleanup, BusError> {
    let config = robot_config(robot_id)?;
    let prefix = robot_prefix(robot_id);
    let shm_before = shm_files(&prefix);
    let mut report = StaleCleanup::default();
    let mut dead = Vec::new();
    Node::<Ipc>::list(&config, |state| {
        match state {
            NodeState::Dead(view) => dead.push(view),
            NodeState::Undefined(_) => report.undefined_nodes += 1,
            NodeState::Alive(_) | NodeState::Inaccessible(_) => {}
        }
        CallbackProgression::Continue
    })
    .map_err(|e| BusError::Cleanup { robot_id, reason: format!("{e:?}") })?;
    if !dead.is_empty() {
        remove_sizeless_dynamic_segments(&config, &prefix);
    }
    let timeout = Duration::from_secs(1);
    for view in dead {
        let node_id = *view.id();
        report.unfinished_files_removed += remove_unfinished_node_files(&config, node_id.value(), &prefix);
        let (node, result) = match view.details() {
            Some(details) => (
                DeadNode { name: details.name().as_str().to_owned(), pid: details.process_id().value() },
                view.blocking_remove_stale_resources(timeout),
            ),
            // Killed before its details were written: iceoryx2 would clean it with its global
            // configuration (another prefix, so nothing); give it the robot's.
            None => (
                DeadNode { name: String::new(), pid: 0 },
                DeadNodeView::<Ipc>::__internal_blocking_remove_stale_resources(
                    node_id,
                    NodeDetails::__internal_new(&None, &config),
                    timeout,
                ),
            ),
        };
        match result {
            Ok(()) => report.removed.push(node),
            Err(e) => report.failed.push((node, format!("{e:?}"))),
        }
    }
    report.hung_services_removed = remove_hung_services(&config, &prefix);
    report.shm_files_removed = shm_before.difference(&shm_files(&prefix)).count();
    Ok(report)
}

/// Removes every iceoryx2 file of the robot: shared memory, service definitions, node files
/// (also the per-prefix management segment iceoryx2 keeps after the last node is gone). Only
/// when none of the robot's processes runs, for robot ids used once (tests, simulated missions
/// with fresh ids); returns the number of files removed.
pub fn purge_robot(robot_id: u16) -> Result<usize, BusError> {
    let config = robot_config(robot_id)?;
    let prefix = robot_prefix(robot_id);
    let remove_in = |dir: &std::path::Path| -> usize {
        let Ok(entries) = std::fs::read_dir(dir) else { return 0 };
        entries
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with(&prefix))
            .filter(|e| std::fs::remove_file(e.path()).is_ok())
            .count()
    };
    let node_dir = std::path::PathBuf::from(path_string(&config.global.node_dir()));
    let mut removed = remove_in(std::path::Path::new("/dev/shm"))
        + remove_in(std::path::Path::new(&path_string(&config.global.service_dir())))
        + remove_in(&node_dir);
    // Node directories are named by node id; the robot's are those holding its files.
    if let Ok(entries) = std::fs::read_dir(&node_dir) {
        for dir in entries.flatten().filter(|e| e.file_type().is_ok_and(|t| t.is_dir())) {
            let n = remove_in(&dir.path());
            if n > 0 {
                removed += n;
                let _ = std::fs::remove_dir(dir.path());
            }
        }
    }
    Ok(removed)
}

/// One process's attachment to its robot's bus.
#[derive(Debug)]
pub struct Bus {
    robot_id: u16,
    geometry: ImageGeometry,
    node: Node<Ipc>,
    cleanup: StaleCleanup,
    /// Hung service definitions removed when opening a service found one.
    hung_services_repaired: AtomicUsize,
}

impl Bus {
    /// Cleans up after dead nodes of the robot (logging what it removed), then creates this
    /// process's node `rover{robot_id}-{process}`.
    pub fn open(robot_id: u16, process: &str, geometry: ImageGeometry) -> Result<Bus, BusError> {
        if geometry.width_px == 0
            || geometry.height_px == 0
            || image_elements(geometry.width_px, geometry.height_px, 4).is_none()
        {
            return Err(BusError::Geometry { width_px: geometry.width_px, height_px: geometry.height_px });
        }
        let cleanup = remove_stale(robot_id)?;
        if !cleanup.is_empty() {
            eprintln!("bus rover{robot_id}-{process}: stale iceoryx2 resources: {cleanup}");
        }
        let config = robot_config(robot_id)?;
        let name = format!("rover{robot_id}-{process}");
        let node_name =
            NodeName::new(&name).map_err(|e| BusError::Name { name: name.clone(), reason: format!("{e:?}") })?;
        // Signal handling stays the process's own: the supervisor stops children with SIGTERM.
        let node = NodeBuilder::new()
            .name(&node_name)
            .config(&config)
            .signal_handling_mode(SignalHandlingMode::Disabled)
            .create::<Ipc>()
            .map_err(|e| BusError::Node { name, reason: format!("{e:?}") })?;
        Ok(Bus { robot_id, geometry, node, cleanup, hung_services_repaired: AtomicUsize::new(0) })
    }

    pub fn robot_id(&self) -> u16 {
        self.robot_id
    }

    pub fn geometry(&self) -> ImageGeometry {
        self.geometry
    }

    /// The node's name (`rover{id}-{process}`).
    pub fn node_name(&self) -> &str {
        self.node.name().as_str()
    }

    /// What [`Bus::open`] removed before creating the node.
    pub fn stale_cleanup(&self) -> &StaleCleanup {
        &self.cleanup
    }

    /// Service definitions this bus found hung in creation (a process killed while creating the
    /// service, younger than the creation timeout when [`Bus::open`] ran) and removed.
    pub fn hung_services_repaired(&self) -> usize {
        self.hung_services_repaired.load(Ordering::Relaxed)
    }

    /// Publishers for `topics` (each at most once).
    pub fn outbox(&self, topics: &[Topic]) -> Result<BusOutbox, BusError> {
        check_unique(topics)?;
        BusOutbox::new(self, topics)
    }

    /// Subscribers for `topics` (each at most once).
    pub fn inbox(&self, topics: &[Topic]) -> Result<BusInbox, BusError> {
        check_unique(topics)?;
        BusInbox::new(self, topics)
    }
}

fn check_unique(topics: &[Topic]) -> Result<(), BusError> {
    let mut seen = BTreeSet::new();
    for &topic in topics {
        if !seen.insert(topic) {
            return Err(BusError::DuplicateTopic { topic });
        }
    }
    Ok(())
}

/// Index of a topic in per-topic arrays.
fn topic_index(topic: Topic) -> usize {
    usize::from(topic.code()).saturating_sub(1)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn only_dynamic_segments_left_empty_are_removed() {
        // A robot id no other test uses; the files are plain /dev/shm files as iceoryx2 makes them.
        let robot_id = 64_001;
        let config = robot_config(robot_id).unwrap();
        let prefix = robot_prefix(robot_id);
        let path = |name: &str| std::path::Path::new("/dev/shm").join(format!("{prefix}{name}"));
        std::fs::write(path("orphan.dynamic"), b"").unwrap();
        std::fs::write(path("sized.dynamic"), b"segment").unwrap();
        std::fs::write(path("other.static"), b"").unwrap();
        assert_eq!(remove_sizeless_dynamic_segments(&config, &prefix), 1);
        assert!(!path("orphan.dynamic").exists());
        assert!(path("sized.dynamic").exists() && path("other.static").exists());
        for name in ["sized.dynamic", "other.static"] {
            std::fs::remove_file(path(name)).unwrap();
        }
    }

    #[test]
    fn ports_move_between_threads() {
        fn send<T: Send>() {}
        send::<Bus>();
        send::<BusOutbox>();
        send::<BusInbox>();
    }

    #[test]
    fn topic_index_covers_all_topics_once() {
        let mut indices: Vec<usize> = Topic::ALL.iter().map(|&t| topic_index(t)).collect();
        indices.sort_unstable();
        assert_eq!(indices, (0..Topic::ALL.len()).collect::<Vec<_>>());
    }

    #[test]
    fn imu_buffer_covers_one_second_filter_stall() {
        let imu = qos(Topic::Imu);
        assert!(imu.subscriber_buffer >= 200 && imu.subscriber_borrow >= imu.subscriber_buffer);
        assert_eq!(imu.overflow, Overflow::DiscardNewest);
    }

    fn stereo_header(width_px: u32, height_px: u32) -> StereoHeader {
        StereoHeader { width_px, height_px, ..Default::default() }
    }

    #[test]
    fn stereo_slice_must_match_header() {
        let bytes = vec![0u8; 2 * 4 * 3];
        assert!(stereo_message(&stereo_header(4, 3), &bytes).is_ok());
        let err = stereo_message(&stereo_header(4, 4), &bytes).unwrap_err();
        assert_eq!(err.expected, Some(32));
        assert!(stereo_message(&stereo_header(u32::MAX, u32::MAX), &bytes).is_err());
    }

    proptest! {
        #[test]
        fn slice_checks_are_total(
            (w, h) in prop_oneof![(0u32..80, 0u32..80), (any::<u32>(), any::<u32>())],
            len in 0usize..16_000,
            exact in any::<bool>(),
        ) {
            let pixels_needed = u128::from(w) * u128::from(h);
            let len = if exact && pixels_needed * 2 < 16_000 { pixels_needed as usize * 2 } else { len };
            let bytes = vec![0u8; len];
            let ok = stereo_message(&stereo_header(w, h), &bytes).is_ok();
            prop_assert_eq!(ok, pixels_needed * 2 == len as u128);
            let header = DisparityHeader { width_px: w, height_px: h, ..Default::default() };
            let pixels = vec![DisparityPixel { disparity_q4: 0, labels: 0, reserved: 0 }; len / 2];
            let ok = disparity_message(&header, &pixels).is_ok();
            prop_assert_eq!(ok, pixels_needed == (len / 2) as u128);
            let team = TeamHeader::default();
            prop_assert_eq!(team_message(Topic::ToComms, &team, &bytes).is_ok(), len <= protocol::MAX_PACKET_BYTES);
            prop_assert!(team_message(Topic::Imu, &team, &bytes).is_err());
        }
    }
}
