//! The comms node: carries the mapper's `protocol` messages to the team and the robot's health to
//! the ground station, over bandwidth-capped links (DESIGN §1, thesis §3.3, §5.2, §7.2).
//!
//! Transport-agnostic: the node owns one `protocol` [`Endpoint`] per link (each link is its own
//! medium with its own framing and rate cap; the endpoint's peers are the robots on it) but no
//! sockets. Packets leave through [`CommsNode::poll_transmit`] and arrive through
//! [`CommsNode::handle_packet`], both on the caller's time. Two adapters move them:
//! - [`LinkDriver`] binds real [`hal::link::Link`]s (UDP, serial) for the process runner;
//! - [`step_duplex`] moves them between two nodes through a [`hal::emulator::DuplexEmulator`] on
//!   simulated time for the lockstep runner.
//!
//! Traffic:
//! - `ToComms` from the mapper: one encoded `protocol` packet; it is decoded (garbage is counted
//!   and dropped) and queued to its destination robot, or to every peer for
//!   [`TeamHeader::BROADCAST`] (reliable messages go to each peer of each team link, latest-wins
//!   ones to the links' broadcast address and, poses only, to the ground link too). The
//!   endpoint applies the message's delivery class and priority: submaps, constraints and match
//!   records reliably, poses and telemetry latest-wins, and never more than the link's rate.
//!   A reliable message refused for a full window waits in a bounded per-link backlog (order
//!   kept per destination and class) until acknowledgements free room.
//! - Messages from peers (poses, constraints, match records, submaps) are published as
//!   `ToMapper` with the sender's robot id; the header's `stamp_ns` is the receive time.
//! - Every link carries a 1 Hz [`Heartbeat`]; a changed `boot_id` resets the peer's channels.
//! - The ground feed (its own link and rate cap, so it never delays team traffic; default
//!   [`GROUND_RATE_BYTES_PER_S`]): at 1 Hz a [`protocol::message::Telemetry`] (v2: with the
//!   robot's bytes per message class), and everything the ground station needs to build the
//!   same `TeamGraph` and map a robot has: the robot's **own** poses, constraints, match records
//!   and submaps (headers carry the frame switches; chunks the payload), as its mapper
//!   broadcasts them. Peers' data is not relayed: every robot has its own ground link, so the
//!   peers' data reaches the ground over theirs, and relaying would double the thin link's load.
//!   The endpoint's priorities keep telemetry and poses ahead of the bulk submap chunks. The
//!   filter's pose goes to the ground with the telemetry only while the mapper sends none (before
//!   its graph starts, or while it restarts): otherwise the ground would see poses that are in no
//!   robot's graph.
//! - The vision process's hazard cells (`vision/hazards`, about 1 Hz) go to the ground at most
//!   once per `CommsConfig::hazards_period_ns` (default [`HAZARDS_PERIOD_NS`]) as one latest-wins
//!   [`protocol::message::HazardCells`] at telemetry priority, coarsened and capped on the way
//!   ([`hazards::hazard_cells`]); a newer one replaces an unsent older one.
//! - Ground commands are verified by the endpoint (HMAC, see `protocol::auth`), checked against a
//!   replay guard when executed (persisted to `CommsConfig::replay_state` before execution, so a
//!   command recorded before a restart stays rejected after it) and always answered with a
//!   [`CommandAck`] that says what really happened:
//!   - `SetMode`: `Executed` (the mode is reported in telemetry and heartbeats);
//!   - `GoToWaypoint`: `Accepted` and kept ([`CommsNode::last_waypoint`], counted), but no
//!     process drives to it: the simulated rovers follow scripted paths. `Refused` in `Safe`;
//!   - `SetParameter`: `Executed` for the comms node's own parameters
//!     ([`RUNTIME_PARAMETERS`]), `Invalid` for any other name or a value out of range;
//!   - `RequestResend`: the robot's own submap's header and chunks (all, or the range) are queued
//!     again on the link the request came from: `Accepted`; `Invalid` for a submap this node did
//!     not send to the ground or no longer holds (the last [`RESEND_STORE_BYTES`] are kept), or a
//!     bad range;
//!   - `StartRecording`/`StopRecording`: `Refused`: bus recording is chosen at start
//!     (`recording.enabled` in `rover.toml`), not at run time.
//!
//!   Forged commands never reach the node (the endpoint drops them; counted).

mod driver;
mod ground;
pub mod hazards;
pub mod replay;
mod resend;

use std::collections::{BTreeMap, VecDeque};
use std::path::{Path, PathBuf};

use msgs::{FilterStateMsg, HazardCellsMsg, TaskStatsMsg, TeamHeader};
use protocol::delivery::{DEFAULT_WINDOW, Delivered, Endpoint, EndpointConfig, EndpointStats, RtoConfig, SendError};
use protocol::frame::Framing;
use protocol::message::{CommandAck, CommandKind, CommandOutcome, HazardCells, Heartbeat, Mode, ParamValue};
use protocol::{AnyMessage, AuthKey, Delivery, MAX_PACKET_BYTES, MessageKey, NodeId, Priority, ReplayGuard, RobotId};

pub use driver::{DriverStats, LinkDriver, step_duplex};
pub use replay::ReplayStateError;
pub use resend::RESEND_STORE_BYTES;

/// The ground feed's default rate cap, wire bytes/s (96 kbit/s): a thin per-robot share of the
/// relayed ground link (the thesis's had a 4 s round trip, §7.2, §9.2; its rate here is this
/// project's assumption, like the 16 kB/s of `hal::emulator::EmulatorConfig::moon_earth`) that
/// carries the telemetry, the graph inputs and, at the lowest priority, the robot's submaps.
pub const GROUND_RATE_BYTES_PER_S: u64 = 12_000;

/// Initial retransmission timeout of a ground link: the thesis's ground link has a 4 s round
/// trip, and the default 1 s would resend everything in flight before the first RTT sample.
pub const GROUND_INITIAL_RTO_MS: u64 = 4_000;

/// The default period of the hazard cells on the ground link: the vision process publishes them
/// about once a second, and every other picture is enough for an operator watching a rover that
/// drives at walking pace or slower, at half the cost (at most about 320 B/s of the ground link).
pub const HAZARDS_PERIOD_NS: u64 = 2_000_000_000;

/// How long without an own pose from the mapper (it sends one a second) before the filter's pose
/// goes to the ground instead.
const MAPPER_QUIET_NS: u64 = 3_000_000_000;

/// Parameters a `SetParameter` command can change at run time: `(name, unit, min, max)`,
/// integer values (a float is rounded).
pub const RUNTIME_PARAMETERS: [(&str, &str, i64, i64); 2] =
    [("comms.telemetry_period_ms", "ms", 100, 60_000), ("comms.heartbeat_period_ms", "ms", 100, 60_000)];

/// A waypoint the ground sent (in the robot's own global frame), as accepted.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Waypoint {
    pub command_id: u32,
    pub x_m: f64,
    pub y_m: f64,
    pub z_m: f64,
    pub speed_mps: f32,
}

use crate::nodes::{Message, Node, NodeError, Outbox, Topic};

/// A link of the comms node, as named by its configuration and by the adapters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, serde::Serialize)]
pub struct LinkId(pub u8);

/// What a link is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum LinkRole {
    /// Radio or network to other robots: team traffic and heartbeats.
    Team,
    /// To the ground station: telemetry, the robot's pose, commands and their acks.
    Ground,
}

/// One link's configuration.
#[derive(Debug, Clone)]
pub struct LinkConfig {
    pub id: LinkId,
    /// Shown in telemetry (at most 12 characters are sent).
    pub name: String,
    pub role: LinkRole,
    /// Must match the transport's framing (`Link::framing`), so the rate cap charges real bytes.
    pub framing: Framing,
    /// Wire bytes per second; at or below the link's capacity.
    pub rate_bytes_per_s: u64,
    /// Wire bytes; at least `EndpointConfig::min_burst_bytes(framing)`, at most what the link
    /// can buffer.
    pub burst_bytes: u64,
    /// Robots reachable on a team link (reliable traffic is addressed to each).
    pub peers: Vec<RobotId>,
    pub rto: RtoConfig,
}

impl LinkConfig {
    /// A team link to `peers` with a burst of two largest packets.
    pub fn team(id: LinkId, name: &str, framing: Framing, rate_bytes_per_s: u64, peers: Vec<RobotId>) -> Self {
        LinkConfig {
            id,
            name: name.to_string(),
            role: LinkRole::Team,
            framing,
            rate_bytes_per_s,
            burst_bytes: 2 * EndpointConfig::min_burst_bytes(framing),
            peers,
            rto: RtoConfig::default(),
        }
    }

    /// The ground-station link (initial RTO [`GROUND_INITIAL_RTO_MS`]).
    pub fn ground(id: LinkId, framing: Framing, rate_bytes_per_s: u64) -> Self {
        LinkConfig {
            role: LinkRole::Ground,
            peers: Vec::new(),
            rto: RtoConfig { initial_ms: GROUND_INITIAL_RTO_MS, ..RtoConfig::default() },
            ..Self::team(id, "ground", framing, rate_bytes_per_s, Vec::new())
        }
    }

    pub fn with_rto(mut self, rto: RtoConfig) -> Self {
        self.rto = rto;
        self
    }

    pub fn with_burst(mut self, burst_bytes: u64) -> Self {
        self.burst_bytes = burst_bytes;
        self
    }
}

/// Configuration of a [`CommsNode`].
#[derive(Debug, Clone)]
pub struct CommsConfig {
    pub robot: RobotId,
    /// Random per process start (peers reset their channels when it changes).
    pub boot_id: u32,
    pub links: Vec<LinkConfig>,
    /// Verifies ground commands; without it every command is rejected.
    pub auth_key: Option<AuthKey>,
    pub initial_mode: Mode,
    pub heartbeat_period_ns: u64,
    pub telemetry_period_ns: u64,
    /// The hazard cells go to the ground at most this often.
    pub hazards_period_ns: u64,
    /// Cores of the board, to turn process CPU time into load.
    pub cpu_cores: u16,
    /// The board's memory, KiB (telemetry's `mem_total_kib`; `None`: not known, reported 0).
    pub board_memory_kib: Option<u64>,
    /// Reliable messages waiting per link for room in the endpoint's windows; beyond, dropped
    /// and counted (the mapper persists what it must not lose and re-sends after restarts).
    pub max_backlog: usize,
    /// Received messages waiting for the next tick to be published; when full, the endpoint
    /// holds (and finally refuses, unacknowledged) further ones, which the sender retransmits.
    pub max_inbox: usize,
    /// File of the command replay guard (last executed counter per sender), restored at start
    /// and rewritten atomically before each command is executed. `None`: in memory only, so a
    /// restart forgets it (tests, simulation).
    pub replay_state: Option<PathBuf>,
}

impl CommsConfig {
    pub fn new(robot: RobotId, links: Vec<LinkConfig>) -> Self {
        CommsConfig {
            robot,
            boot_id: 0,
            links,
            auth_key: None,
            initial_mode: Mode::Idle,
            heartbeat_period_ns: 1_000_000_000,
            telemetry_period_ns: 1_000_000_000,
            hazards_period_ns: HAZARDS_PERIOD_NS,
            cpu_cores: 1,
            board_memory_kib: None,
            max_backlog: 2048,
            max_inbox: 256,
            replay_state: None,
        }
    }

    /// Loads the command key from a key file (`hal::keyfile` format).
    pub fn with_key_file(mut self, path: impl AsRef<Path>) -> Result<Self, CommsError> {
        self.auth_key = Some(hal::keyfile::load_auth_key(path)?);
        Ok(self)
    }
}

/// Why a [`CommsNode`] could not be built.
#[derive(Debug, thiserror::Error)]
pub enum CommsError {
    #[error("link {0:?} is configured twice")]
    DuplicateLink(LinkId),
    #[error("more than one ground link ({0:?})")]
    SecondGroundLink(LinkId),
    #[error("robot id {0} is not a robot node id (1..=239)")]
    NotARobot(u8),
    #[error("link {link:?}: {source}")]
    Endpoint {
        link: LinkId,
        #[source]
        source: protocol::delivery::ConfigError,
    },
    #[error("link {link:?}: a team link needs at least one peer robot, and peers must be robots other than this one")]
    BadPeers { link: LinkId },
    #[error(transparent)]
    KeyFile(#[from] hal::keyfile::KeyFileError),
    #[error(transparent)]
    ReplayState(#[from] replay::ReplayStateError),
}

/// Traffic of one message class (a `protocol` message type).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ClassTraffic {
    pub packets: u64,
    /// Packet bytes (header, body, MAC), before framing.
    pub packet_bytes: u64,
    /// What the packets cost on their links, framing included.
    pub wire_bytes: u64,
    /// Of the packets, transmissions of a reliable packet sent before.
    pub retransmissions: u64,
}

impl ClassTraffic {
    fn add(&mut self, packet_bytes: usize, wire_bytes: usize, retransmission: bool) {
        self.packets += 1;
        self.packet_bytes += packet_bytes as u64;
        self.wire_bytes += wire_bytes as u64;
        self.retransmissions += u64::from(retransmission);
    }
}

/// Messages the node gave up on, by reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct CommsDrops {
    /// Reliable messages refused because a link's backlog was full.
    pub backlog_full: u64,
    /// Destination not on any link.
    pub unroutable: u64,
    /// The endpoint refused the message (transport acks, unauthenticated commands, too many
    /// peers or channels): a bug in the sender or the configuration.
    pub send_refused: u64,
    /// Latest-wins messages with no free slot (more destinations × types than slots).
    pub latest_slots_full: u64,
    /// Latest-wins messages replaced by newer ones before they were sent (by design).
    pub latest_replaced: u64,
    /// Valid packets the endpoints dropped unacknowledged because deliveries were not taken or
    /// the reorder pool was full (the sender retransmits reliable ones).
    pub receive_overflow: u64,
    /// Delivered messages not meant for the mapper (telemetry or acks from peers, team data from
    /// a non-robot).
    pub not_for_mapper: u64,
}

/// Ground commands handled.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct CommandCounts {
    pub executed: u64,
    pub accepted: u64,
    pub invalid: u64,
    /// Authentic and valid but not run (`Safe` mode, recording commands).
    pub refused: u64,
    /// Of the accepted, waypoints (kept, not driven to) and resend requests (queued).
    pub waypoints: u64,
    pub resends: u64,
    /// Authentic but replayed (counter not above the last executed one).
    pub replayed: u64,
    /// Refused because the replay guard could not be persisted.
    pub unsaved: u64,
    pub acks_sent: u64,
}

/// Counters for the mission report.
#[derive(Debug, Clone, Default, PartialEq, Eq, serde::Serialize)]
pub struct CommsStats {
    /// Per `protocol` message type (`MessageKey` name), packets put on the links (all links).
    pub sent_by_class: BTreeMap<&'static str, ClassTraffic>,
    /// Of these, the packets put on the ground link.
    pub ground_sent_by_class: BTreeMap<&'static str, ClassTraffic>,
    /// Per message type, valid packets received (duplicates included).
    pub received_by_class: BTreeMap<&'static str, ClassTraffic>,
    pub packets_sent: u64,
    pub packets_received: u64,
    pub retransmissions: u64,
    pub drops: CommsDrops,
    /// `ToComms` payloads that did not decode as a `protocol` packet.
    pub decode_rejections: u64,
    /// Hazard messages from the vision process with no usable picture (not a pose, not a cell
    /// size).
    pub hazard_rejections: u64,
    /// `ToComms` headers whose `message_key` disagreed with the payload (the payload wins).
    pub header_key_mismatches: u64,
    /// Packets from the links that the endpoints rejected (malformed, bad MAC, not for us, …).
    pub packet_rejections: u64,
    /// Of these, packets that failed authentication, plus replayed commands.
    pub auth_rejections: u64,
    pub commands: CommandCounts,
    pub delivered_to_mapper: u64,
    /// Peers seen restarting (changed heartbeat `boot_id`).
    pub peer_restarts: u64,
}

/// State of one link.
#[derive(Debug)]
struct LinkState {
    config: LinkConfig,
    label: protocol::message::Label,
    endpoint: Box<Endpoint>,
    /// Reliable messages the endpoint's window refused, oldest first.
    backlog: VecDeque<(NodeId, AnyMessage)>,
    backlog_dropped: u64,
    /// Boot ids of the nodes heard on this link.
    boots: Vec<(NodeId, u32)>,
    last_rx_ns: Option<u64>,
    silent: bool,
    outages: u32,
    /// Counters at the previous telemetry report, for rates.
    report: ground::LinkReport,
}

/// Keeps one bit per (destination, priority): which reliable channels are known full during a
/// backlog pass.
struct Blocked([u64; 24]);

impl Blocked {
    fn index(node: NodeId, priority: Priority) -> usize {
        usize::from(node.0) * Priority::COUNT + usize::from(priority.channel())
    }

    fn get(&self, node: NodeId, priority: Priority) -> bool {
        let i = Self::index(node, priority);
        self.0[i / 64] & (1 << (i % 64)) != 0
    }

    fn set(&mut self, node: NodeId, priority: Priority) {
        let i = Self::index(node, priority);
        self.0[i / 64] |= 1 << (i % 64);
    }
}

impl LinkState {
    /// Queues a message, through the backlog when its channel already waits there.
    fn send(
        &mut self,
        now_ms: u64,
        destination: NodeId,
        message: &AnyMessage,
        max_backlog: usize,
        drops: &mut CommsDrops,
    ) {
        let reliable = message.delivery() == Delivery::Reliable;
        let channel_waits =
            reliable && self.backlog.iter().any(|(d, m)| *d == destination && m.priority() == message.priority());
        if channel_waits {
            self.push_backlog(destination, message.clone(), max_backlog, drops);
            return;
        }
        match self.endpoint.send(now_ms, destination, message) {
            Ok(()) => {}
            Err(SendError::QueueFull { .. }) if reliable => {
                self.push_backlog(destination, message.clone(), max_backlog, drops)
            }
            Err(SendError::QueueFull { .. }) => drops.latest_slots_full += 1,
            Err(_) => drops.send_refused += 1,
        }
    }

    fn push_backlog(&mut self, destination: NodeId, message: AnyMessage, max_backlog: usize, drops: &mut CommsDrops) {
        if self.backlog.len() >= max_backlog {
            drops.backlog_full += 1;
            self.backlog_dropped += 1;
            return;
        }
        self.backlog.push_back((destination, message));
    }

    /// Moves backlog entries into the endpoint while their channels have room, keeping their
    /// order per channel.
    fn flush_backlog(&mut self, now_ms: u64, drops: &mut CommsDrops) {
        let mut blocked = Blocked([0; 24]);
        for _ in 0..self.backlog.len() {
            let Some((destination, message)) = self.backlog.pop_front() else { break };
            let priority = message.priority();
            if blocked.get(destination, priority) {
                self.backlog.push_back((destination, message));
                continue;
            }
            match self.endpoint.send(now_ms, destination, &message) {
                Ok(()) => {}
                Err(SendError::QueueFull { .. }) => {
                    blocked.set(destination, priority);
                    self.backlog.push_back((destination, message));
                }
                Err(_) => drops.send_refused += 1,
            }
        }
    }
}

/// The comms node (see the [module documentation](self)).
#[derive(Debug)]
pub struct CommsNode {
    robot: RobotId,
    boot_id: u32,
    mode: Mode,
    links: Vec<LinkState>,
    ground_link: Option<usize>,
    heartbeat_period_ns: u64,
    telemetry_period_ns: u64,
    hazards_period_ns: u64,
    /// The newest hazard cells not sent yet (only with a ground link).
    hazards: Option<HazardCells>,
    max_backlog: usize,
    max_inbox: usize,
    replay: ReplayGuard<{ replay::MAX_SENDERS }>,
    replay_state: Option<PathBuf>,
    feed: ground::GroundFeed,
    /// When the mapper last sent an own pose (sensor time), to keep the filter's out of the feed.
    mapper_pose_ns: Option<u64>,
    /// Own submaps as sent to the ground, for resend requests.
    resend: resend::SubmapStore,
    last_waypoint: Option<Waypoint>,
    /// Received messages for the mapper: header and encoded packet.
    inbox: VecDeque<(TeamHeader, Vec<u8>)>,
    /// Emptied inbox buffers, reused so a warmed-up node does not allocate per message.
    spare: Vec<Vec<u8>>,
    tx_buf: Box<[u8; MAX_PACKET_BYTES]>,
    next_link: usize,
    started_ns: Option<u64>,
    next_heartbeat_ns: u64,
    next_telemetry_ns: u64,
    next_hazards_ns: u64,
    stats: CommsStats,
}

fn ns_to_ms(now_ns: u64) -> u64 {
    now_ns / 1_000_000
}

impl CommsNode {
    pub fn new(config: CommsConfig) -> Result<Self, CommsError> {
        let local = NodeId::from(config.robot);
        if !local.is_robot() {
            return Err(CommsError::NotARobot(config.robot.0));
        }
        let mut links: Vec<LinkState> = Vec::with_capacity(config.links.len());
        let mut ground_link = None;
        for link in config.links {
            if links.iter().any(|l| l.config.id == link.id) {
                return Err(CommsError::DuplicateLink(link.id));
            }
            match link.role {
                LinkRole::Ground if ground_link.is_some() => return Err(CommsError::SecondGroundLink(link.id)),
                LinkRole::Ground => ground_link = Some(links.len()),
                LinkRole::Team => {
                    let bad = |r: &RobotId| !NodeId::from(*r).is_robot() || *r == config.robot;
                    if link.peers.is_empty() || link.peers.iter().any(bad) {
                        return Err(CommsError::BadPeers { link: link.id });
                    }
                }
            }
            let mut endpoint_config =
                EndpointConfig::new(local, link.framing, link.rate_bytes_per_s, link.burst_bytes).with_rto(link.rto);
            if let Some(key) = &config.auth_key {
                endpoint_config = endpoint_config.with_auth_key(key.clone());
            }
            let endpoint = Endpoint::new(endpoint_config)
                .map(Box::new)
                .map_err(|source| CommsError::Endpoint { link: link.id, source })?;
            links.push(LinkState {
                label: ground::label(&link.name),
                config: link,
                endpoint,
                backlog: VecDeque::new(),
                backlog_dropped: 0,
                boots: Vec::new(),
                last_rx_ns: None,
                silent: false,
                outages: 0,
                report: ground::LinkReport::default(),
            });
        }
        Ok(CommsNode {
            robot: config.robot,
            boot_id: config.boot_id,
            mode: config.initial_mode,
            links,
            ground_link,
            heartbeat_period_ns: config.heartbeat_period_ns.max(1),
            telemetry_period_ns: config.telemetry_period_ns.max(1),
            hazards_period_ns: config.hazards_period_ns.max(1),
            hazards: None,
            max_backlog: config.max_backlog,
            max_inbox: config.max_inbox.max(1),
            replay: match &config.replay_state {
                Some(path) => replay::load(path)?,
                None => ReplayGuard::new(),
            },
            replay_state: config.replay_state,
            feed: ground::GroundFeed::new(config.cpu_cores, config.board_memory_kib),
            mapper_pose_ns: None,
            resend: resend::SubmapStore::new(RESEND_STORE_BYTES),
            last_waypoint: None,
            inbox: VecDeque::new(),
            spare: Vec::new(),
            tx_buf: Box::new([0; MAX_PACKET_BYTES]),
            next_link: 0,
            started_ns: None,
            next_heartbeat_ns: 0,
            next_telemetry_ns: 0,
            next_hazards_ns: 0,
            stats: CommsStats::default(),
        })
    }

    pub fn robot(&self) -> RobotId {
        self.robot
    }

    /// The operating mode (initial, or as last set by a ground command).
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The last waypoint the ground sent and the node accepted (nothing drives to it here).
    pub fn last_waypoint(&self) -> Option<Waypoint> {
        self.last_waypoint
    }

    /// The telemetry period (initial, or as last set by a ground command), ns.
    pub fn telemetry_period_ns(&self) -> u64 {
        self.telemetry_period_ns
    }

    /// The id of the ground link, if the node has one.
    pub fn ground_link_id(&self) -> Option<LinkId> {
        self.ground_link.and_then(|i| self.links.get(i)).map(|l| l.config.id)
    }

    /// Counters for the mission report (endpoint counters folded in).
    pub fn stats(&self) -> CommsStats {
        let mut stats = self.stats.clone();
        for link in &self.links {
            let s = link.endpoint.stats();
            stats.packet_rejections += s.rejected.total();
            stats.auth_rejections += s.rejected.bad_mac + s.rejected.unauthenticated + s.rejected.no_key;
            stats.drops.receive_overflow += s.dropped_delivery_full + s.dropped_reorder_full;
            stats.drops.latest_replaced += s.latest_wins_replaced;
        }
        stats
    }

    /// The delivery layer's counters of one link.
    pub fn link_stats(&self, link: LinkId) -> Option<&EndpointStats> {
        self.links.iter().find(|l| l.config.id == link).map(|l| l.endpoint.stats())
    }

    /// Reliable messages of a link waiting for window room.
    pub fn backlog_len(&self, link: LinkId) -> Option<usize> {
        self.links.iter().find(|l| l.config.id == link).map(|l| l.backlog.len())
    }

    /// Whether nothing waits to be sent or acknowledged on any link.
    pub fn is_idle(&self) -> bool {
        self.links.iter().all(|l| l.backlog.is_empty() && l.endpoint.is_idle())
    }

    pub fn link_ids(&self) -> impl Iterator<Item = LinkId> + '_ {
        self.links.iter().map(|l| l.config.id)
    }

    // ---------------------------------------------------------------------------- transmit

    /// The next packet due on any link (links take turns), or `None` when nothing may go now.
    /// The bytes are valid until the next call on the node.
    pub fn poll_transmit(&mut self, now_ns: u64) -> Option<(LinkId, &[u8])> {
        let n = self.links.len();
        for k in 0..n {
            let index = (self.next_link + k) % n;
            if let Some(len) = self.transmit_from(index, now_ns) {
                self.next_link = index + 1;
                let id = self.links[index].config.id;
                return Some((id, &self.tx_buf[..len]));
            }
        }
        None
    }

    /// The next packet due on one link.
    pub fn poll_transmit_on(&mut self, now_ns: u64, link: LinkId) -> Option<&[u8]> {
        let index = self.links.iter().position(|l| l.config.id == link)?;
        let len = self.transmit_from(index, now_ns)?;
        Some(&self.tx_buf[..len])
    }

    fn transmit_from(&mut self, index: usize, now_ns: u64) -> Option<usize> {
        let link = self.links.get_mut(index)?;
        let retransmissions_before = link.endpoint.stats().retransmissions;
        let len = link.endpoint.poll_transmit(ns_to_ms(now_ns), &mut self.tx_buf[..])?;
        let retransmission = link.endpoint.stats().retransmissions > retransmissions_before;
        let packet = &self.tx_buf[..len];
        let wire = link.config.framing.wire_bytes(len);
        let class = class_name(packet);
        self.stats.sent_by_class.entry(class).or_default().add(len, wire, retransmission);
        if link.config.role == LinkRole::Ground {
            self.stats.ground_sent_by_class.entry(class).or_default().add(len, wire, retransmission);
        }
        self.stats.packets_sent += 1;
        self.stats.retransmissions += u64::from(retransmission);
        Some(len)
    }

    /// When a packet may be due next on any link (rate cap, retransmission timers), ns; `None`
    /// if nothing will be until a message is queued or a packet arrives.
    pub fn next_transmit_ns(&self, now_ns: u64) -> Option<u64> {
        let now_ms = ns_to_ms(now_ns);
        self.links
            .iter()
            .filter_map(|l| l.endpoint.next_transmit_ms(now_ms))
            .min()
            .map(|ms| ms.saturating_mul(1_000_000).max(now_ns))
    }

    // ----------------------------------------------------------------------------- receive

    /// Handles one packet that arrived on `link`. Total: any bytes, any link id, never a panic;
    /// rejected packets are counted by the link's endpoint, unknown links in `packet_rejections`.
    pub fn handle_packet(&mut self, now_ns: u64, link: LinkId, bytes: &[u8]) {
        let Some(index) = self.links.iter().position(|l| l.config.id == link) else {
            self.stats.packet_rejections += 1;
            return;
        };
        let now_ms = ns_to_ms(now_ns);
        let state = &mut self.links[index];
        if state.endpoint.handle_packet(now_ms, bytes).is_ok() {
            state.last_rx_ns = Some(now_ns);
            state.silent = false;
            let wire = state.config.framing.wire_bytes(bytes.len());
            let class = class_name(bytes);
            self.stats.received_by_class.entry(class).or_default().add(bytes.len(), wire, false);
            self.stats.packets_received += 1;
            // Only acknowledgements free window room; the backlog pass costs O(backlog).
            if class == "Ack" {
                state.flush_backlog(now_ms, &mut self.stats.drops);
            }
        }
        self.take_deliveries(index, now_ns);
    }

    fn take_deliveries(&mut self, index: usize, now_ns: u64) {
        while self.inbox.len() < self.max_inbox {
            let Some(delivered) = self.links.get_mut(index).and_then(|l| l.endpoint.poll_deliver()) else { break };
            self.on_delivered(index, delivered, now_ns);
        }
    }

    fn on_delivered(&mut self, index: usize, delivered: Delivered, now_ns: u64) {
        let source = delivered.header.source;
        match &delivered.message {
            AnyMessage::Heartbeat(heartbeat) => self.on_heartbeat(index, source, heartbeat.boot_id),
            AnyMessage::Command(_) => self.on_command(index, &delivered, now_ns),
            AnyMessage::PoseEstimate(_)
            | AnyMessage::Constraint(_)
            | AnyMessage::MatchAttempt(_)
            | AnyMessage::SubmapHeader(_)
            | AnyMessage::SubmapChunk(_)
                if source.is_robot() =>
            {
                let mut buf = self.spare.pop().unwrap_or_default();
                buf.resize(MAX_PACKET_BYTES, 0);
                let header = delivered.header;
                match protocol::encode(&delivered.message, source, header.destination, header.seq, &mut buf) {
                    Ok(len) => {
                        buf.truncate(len);
                        let team = TeamHeader {
                            stamp_ns: now_ns,
                            robot_id: u32::from(source.0),
                            message_key: u32::from(header.key),
                        };
                        self.inbox.push_back((team, buf));
                    }
                    // Cannot happen for a message that just decoded; counted if it ever does.
                    Err(_) => self.stats.drops.not_for_mapper += 1,
                }
            }
            _ => self.stats.drops.not_for_mapper += 1,
        }
    }

    fn on_heartbeat(&mut self, index: usize, source: NodeId, boot_id: u32) {
        let Some(link) = self.links.get_mut(index) else { return };
        match link.boots.iter_mut().find(|(node, _)| *node == source) {
            Some((_, known)) if *known != boot_id => {
                *known = boot_id;
                link.endpoint.reset_peer(source);
                self.stats.peer_restarts += 1;
            }
            Some(_) => {}
            None => link.boots.push((source, boot_id)),
        }
    }

    fn on_command(&mut self, index: usize, delivered: &Delivered, now_ns: u64) {
        let AnyMessage::Command(command) = &delivered.message else { return };
        // The endpoint delivers a command only with a verified MAC, and then with its counter.
        let Some((sender, counter)) = delivered.auth else { return };
        let accepted = self.replay.accept(sender, counter).is_ok();
        // Persisted before execution: a crash after this point loses the command, never runs it
        // twice. If the guard cannot be saved, the command is not executed.
        let saved = accepted && self.replay_state.as_ref().is_none_or(|path| replay::save(path, &self.replay).is_ok());
        let now_ms = ns_to_ms(now_ns);
        let outcome = if !accepted {
            self.stats.commands.replayed += 1;
            self.stats.auth_rejections += 1;
            CommandOutcome::Refused
        } else if !saved {
            self.stats.commands.unsaved += 1;
            CommandOutcome::Refused
        } else {
            let outcome = if command.target != self.robot {
                CommandOutcome::Invalid
            } else {
                self.execute(index, sender, command.id, &command.kind, now_ms)
            };
            let counts = &mut self.stats.commands;
            match outcome {
                CommandOutcome::Executed => counts.executed += 1,
                CommandOutcome::Accepted => counts.accepted += 1,
                CommandOutcome::Invalid => counts.invalid += 1,
                CommandOutcome::Refused => counts.refused += 1,
            }
            outcome
        };
        let ack = AnyMessage::from(CommandAck { robot: self.robot, command_id: command.id, outcome });
        let max_backlog = self.max_backlog;
        if let Some(link) = self.links.get_mut(index) {
            link.send(now_ms, sender, &ack, max_backlog, &mut self.stats.drops);
            self.stats.commands.acks_sent += 1;
        }
    }

    /// Carries out an authentic command for this robot (see the module documentation).
    fn execute(&mut self, index: usize, sender: NodeId, id: u32, kind: &CommandKind, now_ms: u64) -> CommandOutcome {
        match kind {
            CommandKind::SetMode(mode) => {
                self.mode = *mode;
                CommandOutcome::Executed
            }
            CommandKind::GoToWaypoint { .. } if self.mode == Mode::Safe => CommandOutcome::Refused,
            &CommandKind::GoToWaypoint { x_m, y_m, z_m, speed_mps } => {
                let finite = [x_m, y_m, z_m, f64::from(speed_mps)].iter().all(|v| v.is_finite());
                if !finite || speed_mps < 0.0 {
                    return CommandOutcome::Invalid;
                }
                self.last_waypoint = Some(Waypoint { command_id: id, x_m, y_m, z_m, speed_mps });
                self.stats.commands.waypoints += 1;
                CommandOutcome::Accepted
            }
            CommandKind::SetParameter { name, value } => self.set_parameter(name, *value),
            CommandKind::RequestResend { submap, chunks } => {
                if submap.robot != self.robot {
                    return CommandOutcome::Invalid;
                }
                let Some(messages) = self.resend.resend(*submap, *chunks) else { return CommandOutcome::Invalid };
                let max_backlog = self.max_backlog;
                if let Some(link) = self.links.get_mut(index) {
                    for message in &messages {
                        link.send(now_ms, sender, message, max_backlog, &mut self.stats.drops);
                    }
                }
                self.stats.commands.resends += 1;
                CommandOutcome::Accepted
            }
            CommandKind::StartRecording { .. } | CommandKind::StopRecording => CommandOutcome::Refused,
        }
    }

    fn set_parameter(&mut self, name: &str, value: ParamValue) -> CommandOutcome {
        let Some(&(_, _, min, max)) = RUNTIME_PARAMETERS.iter().find(|(known, ..)| *known == name) else {
            return CommandOutcome::Invalid;
        };
        let value = match value {
            ParamValue::Int(v) => v,
            ParamValue::Float(v) if v.is_finite() && v.abs() < 1e15 => v.round() as i64,
            _ => return CommandOutcome::Invalid,
        };
        if !(min..=max).contains(&value) {
            return CommandOutcome::Invalid;
        }
        let period_ns = value.unsigned_abs() * 1_000_000;
        match name {
            "comms.telemetry_period_ms" => self.telemetry_period_ns = period_ns,
            _ => self.heartbeat_period_ns = period_ns,
        }
        CommandOutcome::Executed
    }

    /// Publishes what arrived for the mapper.
    fn publish_inbox(&mut self, out: &mut dyn Outbox) -> Result<(), NodeError> {
        while let Some((header, bytes)) = self.inbox.pop_front() {
            let result = out.publish(Message::ToMapper(&header, &bytes));
            self.spare.push(bytes);
            result?;
            self.stats.delivered_to_mapper += 1;
        }
        Ok(())
    }

    // ------------------------------------------------------------------------------ route

    fn on_to_comms(&mut self, now_ns: u64, header: &TeamHeader, bytes: &[u8]) {
        let packet = match protocol::decode(bytes) {
            Ok(packet) => packet,
            Err(_) => {
                self.stats.decode_rejections += 1;
                return;
            }
        };
        let message = packet.message;
        if header.message_key != u32::from(message.key().0) {
            self.stats.header_key_mismatches += 1;
        }
        let now_ms = ns_to_ms(now_ns);
        let max_backlog = self.max_backlog;
        // Only what this robot produced goes to the ground (module documentation).
        let own = packet.header.source == NodeId::from(self.robot);
        let for_ground = own
            && header.robot_id == TeamHeader::BROADCAST
            && self.ground_link.is_some()
            && matches!(
                message,
                AnyMessage::PoseEstimate(_)
                    | AnyMessage::Constraint(_)
                    | AnyMessage::MatchAttempt(_)
                    | AnyMessage::SubmapHeader(_)
                    | AnyMessage::SubmapChunk(_)
            );
        if for_ground {
            match &message {
                AnyMessage::PoseEstimate(_) => self.mapper_pose_ns = Some(now_ns),
                AnyMessage::SubmapHeader(h) => self.resend.on_header(h),
                AnyMessage::SubmapChunk(c) => self.resend.on_chunk(c),
                _ => {}
            }
        }
        let drops = &mut self.stats.drops;
        if header.robot_id == TeamHeader::BROADCAST {
            let latest = message.delivery() == Delivery::LatestWins;
            for link in &mut self.links {
                match link.config.role {
                    LinkRole::Team if latest => link.send(now_ms, NodeId::BROADCAST, &message, max_backlog, drops),
                    LinkRole::Team => {
                        for p in 0..link.config.peers.len() {
                            let peer = NodeId::from(link.config.peers[p]);
                            link.send(now_ms, peer, &message, max_backlog, drops);
                        }
                    }
                    LinkRole::Ground if for_ground => link.send(now_ms, NodeId::GROUND, &message, max_backlog, drops),
                    LinkRole::Ground => {}
                }
            }
            return;
        }
        let destination = match u8::try_from(header.robot_id) {
            Ok(id) if NodeId(id) == NodeId::GROUND || NodeId(id).is_robot() => NodeId(id),
            _ => {
                drops.unroutable += 1;
                return;
            }
        };
        let route = self.links.iter().position(|l| match l.config.role {
            LinkRole::Team => l.config.peers.iter().any(|&r| NodeId::from(r) == destination),
            LinkRole::Ground => destination == NodeId::GROUND,
        });
        match route {
            Some(index) => self.links[index].send(now_ms, destination, &message, max_backlog, drops),
            None => drops.unroutable += 1,
        }
    }

    // ------------------------------------------------------------------------------- tick

    fn send_heartbeats(&mut self, now_ns: u64) {
        let uptime_ms = ns_to_ms(now_ns.saturating_sub(self.started_ns.unwrap_or(now_ns)));
        let heartbeat = AnyMessage::from(Heartbeat {
            node: NodeId::from(self.robot),
            stamp_ns: now_ns,
            uptime_ms,
            boot_id: self.boot_id,
            mode: self.mode,
        });
        for link in &mut self.links {
            let to = match link.config.role {
                LinkRole::Team => NodeId::BROADCAST,
                LinkRole::Ground => NodeId::GROUND,
            };
            link.send(ns_to_ms(now_ns), to, &heartbeat, self.max_backlog, &mut self.stats.drops);
        }
    }

    fn send_ground_feed(&mut self, now_ns: u64) {
        let auth_rejections = self.stats().auth_rejections;
        let period_ns = self.telemetry_period_ns;
        let links: Vec<ground::LinkView<'_>> = self
            .links
            .iter_mut()
            .map(|l| ground::LinkView {
                label: &l.label,
                stats: l.endpoint.stats(),
                backlog: l.backlog.len(),
                backlog_dropped: l.backlog_dropped,
                outages: l.outages,
                report: &mut l.report,
            })
            .collect();
        let counters = ground::Counters { links, auth_rejections, sent_by_class: &self.stats.sent_by_class };
        let telemetry = self.feed.telemetry(self.robot, now_ns, period_ns, self.mode, counters);
        let mapper_quiet = self.mapper_pose_ns.is_none_or(|t| now_ns.saturating_sub(t) > MAPPER_QUIET_NS);
        let pose = if mapper_quiet { self.feed.pose_estimate(self.robot) } else { None };
        let Some(index) = self.ground_link else { return };
        let max_backlog = self.max_backlog;
        let Some(link) = self.links.get_mut(index) else { return };
        let now_ms = ns_to_ms(now_ns);
        link.send(now_ms, NodeId::GROUND, &AnyMessage::from(telemetry), max_backlog, &mut self.stats.drops);
        if let Some(pose) = pose {
            link.send(now_ms, NodeId::GROUND, &AnyMessage::from(pose), max_backlog, &mut self.stats.drops);
        }
    }

    /// Keeps the newest hazard picture for the ground (there is nobody else to send it to).
    fn on_hazards(&mut self, msg: &HazardCellsMsg) {
        if self.ground_link.is_none() {
            return;
        }
        match hazards::hazard_cells(self.robot, msg) {
            Some(cells) => self.hazards = Some(cells),
            None => self.stats.hazard_rejections += 1,
        }
    }

    /// Sends the newest hazard picture if one is waiting and the period has passed since the last.
    fn send_hazards(&mut self, now_ns: u64) {
        if now_ns < self.next_hazards_ns {
            return;
        }
        let Some(cells) = self.hazards.take() else { return };
        self.next_hazards_ns = now_ns.saturating_add(self.hazards_period_ns);
        let max_backlog = self.max_backlog;
        if let Some(link) = self.ground_link.and_then(|index| self.links.get_mut(index)) {
            link.send(ns_to_ms(now_ns), NodeId::GROUND, &AnyMessage::from(cells), max_backlog, &mut self.stats.drops);
        }
    }

    /// Counts a link outage once it has been silent for three heartbeat periods after hearing
    /// from someone.
    fn watch_outages(&mut self, now_ns: u64) {
        let silence_ns = self.heartbeat_period_ns.saturating_mul(3);
        for link in &mut self.links {
            if let Some(last) = link.last_rx_ns
                && !link.silent
                && now_ns.saturating_sub(last) > silence_ns
            {
                link.silent = true;
                link.outages = link.outages.saturating_add(1);
            }
        }
    }
}

/// Name of the message class of a packet, from its header alone.
fn class_name(packet: &[u8]) -> &'static str {
    protocol::codec::decode_header(packet)
        .ok()
        .and_then(|(header, _)| AnyMessage::name_of(MessageKey(header.key)))
        .unwrap_or("unknown")
}

impl Node for CommsNode {
    fn name(&self) -> &'static str {
        "comms"
    }

    fn subscriptions(&self) -> &'static [Topic] {
        &[Topic::ToComms, Topic::TaskStats, Topic::FilterState, Topic::Hazards]
    }

    fn on_message(&mut self, message: Message<'_>, out: &mut dyn Outbox) -> Result<(), NodeError> {
        match message {
            Message::ToComms(header, bytes) => self.on_to_comms(header.stamp_ns, header, bytes),
            Message::TaskStats(stats) => self.feed.on_task_stats(stats),
            Message::FilterState(state) => self.feed.on_filter_state(state),
            Message::Hazards(hazards) => self.on_hazards(hazards),
            _ => {}
        }
        self.publish_inbox(out)
    }

    fn on_tick(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        self.started_ns.get_or_insert(now_ns);
        let now_ms = ns_to_ms(now_ns);
        for index in 0..self.links.len() {
            if let Some(link) = self.links.get_mut(index) {
                link.flush_backlog(now_ms, &mut self.stats.drops);
            }
            self.take_deliveries(index, now_ns);
        }
        self.watch_outages(now_ns);
        if now_ns >= self.next_heartbeat_ns {
            self.send_heartbeats(now_ns);
            self.next_heartbeat_ns = now_ns.saturating_add(self.heartbeat_period_ns);
        }
        if now_ns >= self.next_telemetry_ns {
            self.send_ground_feed(now_ns);
            self.next_telemetry_ns = now_ns.saturating_add(self.telemetry_period_ns);
        }
        self.send_hazards(now_ns);
        self.publish_inbox(out)
    }
}

/// The latest filter state and task statistics the node was given (for tests and the runners).
impl CommsNode {
    pub fn latest_filter_state(&self) -> Option<&FilterStateMsg> {
        self.feed.filter_state()
    }

    pub fn task_stats(&self) -> impl Iterator<Item = &TaskStatsMsg> + '_ {
        self.feed.task_stats()
    }
}

/// Reliable windows per link the node uses (for documentation and the runners' sizing).
pub const WINDOW_PACKETS: usize = DEFAULT_WINDOW;
