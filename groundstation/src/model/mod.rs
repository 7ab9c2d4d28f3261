//! The team model: the truth behind the [`TeamView`].
//!
//! Sans-IO and clock-free: packets come in through [`TeamModel::ingest`] with their ground receive
//! time, time advances through [`TeamModel::tick`], packets for the link leave through
//! [`TeamModel::poll_transmit`], operator actions enter through [`TeamModel::apply`]. The same
//! model therefore runs live (the engine's thread) and in replay (a feed log), and gives the same
//! view for the same packets at the same receive times.
//!
//! - Delivery: a `protocol` [`Endpoint`] as node [`NodeId::GROUND`]: it reorders and
//!   acknowledges the robots' reliable streams (submaps, constraints, command acks) and carries
//!   the authenticated commands with retransmission.
//! - Graph: a `mapper::slam::TeamGraph` whose own robot is the reference robot, fed exactly what
//!   a robot's mapper is fed (`mapper::wire` conversions); the measurements are logged, so a new
//!   reference robot rebuilds its graph from the log. Updates run at most every
//!   [`GRAPH_PERIOD_NS`].
//! - Placement: a submap origin is the graph's estimate, else chained from its predecessor by the
//!   received frame switch, else (the robot's current submap, whose header comes only when it is
//!   finished) provisionally from the robot's last pose in the previous submap and first pose in
//!   this one. Trajectories are the received poses at their submap origins.
//! - Map: see [`map`].
//! - Hazards: each robot's latest hazard cells, placed with the message's own body pose through
//!   the same submap origins as the trajectory (see [`hazards`]).

pub mod hazards;
pub mod link;
pub mod map;

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::sync::Arc;

use mapper::slam::{self, Measurement, TeamGraph, TeamGraphConfig};
use mapper::wire;
use nalgebra::{Isometry3, Matrix2, Matrix3, Point3};
use protocol::codec::decode_header;
use protocol::delivery::{DEFAULT_WINDOW, Delivered, Endpoint, EndpointConfig, RtoConfig};
use protocol::frame::Framing;
use protocol::message::{
    Command, CommandAck, CommandKind, ConstraintKind, HazardCells, PoseEstimate, SubmapChunk, SubmapHeader, Telemetry,
};
use protocol::{AnyMessage, AuthKey, MAX_PACKET_BYTES, MessageKey, NodeId, NodeRef, Priority, RobotId};

use crate::view::{
    CommandState, CommandView, EdgeKind, EdgeView, LOST_AFTER_NS, RobotView, STALE_AFTER_NS, Staleness, SubmapOutline,
    TeamView, UiAction,
};
use hazards::ReceivedHazards;
use link::{LinkAccumulator, LinkState};
use map::{MapComposer, Placed, Tile};

/// Graph updates and map compositions at most this often (ground time).
pub const GRAPH_PERIOD_NS: u64 = 500_000_000;
/// The view is rebuilt at most this often by `tick` (and at every graph update).
pub const VIEW_PERIOD_NS: u64 = 100_000_000;
/// A sent command not acknowledged within this is shown timed out (the link keeps trying).
pub const COMMAND_TIMEOUT_NS: u64 = 60_000_000_000;
/// Commands queued or in flight at once; more are refused.
pub const MAX_PENDING_COMMANDS: usize = 32;
/// Commands kept for display, finished ones dropped oldest first.
pub const MAX_SHOWN_COMMANDS: usize = 64;
pub const MAX_NOTICES: usize = 20;
/// Received poses kept per robot (an hour at 5 Hz).
pub const MAX_POSES_PER_ROBOT: usize = 18_000;
/// Logged graph measurements (the reference-change rebuild replays them).
pub const MAX_MEASUREMENTS: usize = 500_000;
/// Speed given with operator waypoints, m/s.
pub const WAYPOINT_SPEED_MPS: f32 = 0.5;
/// The ground's uplink rate cap, wire bytes/s: commands and acknowledgements are small.
pub const UPLINK_RATE_BYTES_PER_S: u64 = 4_000;
/// Largest submap payload accepted, bytes; submaps in flight at once.
const MAX_SUBMAP_PAYLOAD_BYTES: usize = 16 << 20;
const MAX_PARTIAL_SUBMAPS: usize = 16;
/// Filter poses reach the ground at about 1 Hz, not at image rate: a detection is attached to
/// poses interpolated over up to this gap (coarser than on the robots; the ground only draws).
const GROUND_POSE_MAX_GAP_NS: u64 = 2_500_000_000;

/// How the model is set up.
#[derive(Debug, Clone)]
pub struct ModelConfig {
    /// Key for authenticated commands; without one, commands are refused.
    pub auth_key: Option<AuthKey>,
    /// Shown in the view (`udp://0.0.0.0:47800`, `replay runs/demo`).
    pub source: String,
}

/// Why an operator action was not carried out.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ActionError {
    #[error("commands need the authentication key (start with --key FILE)")]
    NoKey,
    #[error("commands cannot be sent while replaying a recording")]
    Replay,
    #[error("{0} is not a robot id")]
    NotARobot(u8),
    #[error("robot {0} has not been heard")]
    UnknownRobot(u8),
    #[error("waypoint refused: no reference frame yet")]
    NoReference,
    #[error("waypoint refused: robot {robot} is not connected to robot {reference}'s frame")]
    NotConnected { robot: u8, reference: u8 },
    #[error("waypoint refused: coordinates are not finite")]
    NotFinite,
    #[error("command refused: {0} commands are already waiting")]
    QueueFull(usize),
    #[error("{what} is too long (at most {max} characters)")]
    TooLong { what: &'static str, max: usize },
    #[error("{0} is handled by the engine, not by the model")]
    NotAModelAction(&'static str),
}

#[derive(Debug, Clone, Copy)]
struct StoredPose {
    stamp_ns: u64,
    submap: u32,
    t_submap_body: Isometry3<f64>,
    /// Position covariance in the submap frame, m².
    position_cov: Matrix3<f64>,
}

#[derive(Debug, Clone)]
struct RobotState {
    view: RobotView,
    poses: Vec<StoredPose>,
    /// Cumulative tx bytes per message key at the previous telemetry.
    class_tx: BTreeMap<u8, u64>,
    /// The latest hazard cells received (latest wins, as on the link).
    hazards: Option<ReceivedHazards>,
}

impl RobotState {
    fn new(robot: u8) -> Self {
        RobotState {
            view: RobotView {
                robot,
                connected: false,
                mode: None,
                sensors: None,
                filter: None,
                tasks: Vec::new(),
                queues: Vec::new(),
                links: Vec::new(),
                resources: None,
                auth_rejections: 0,
                last_message_ns: None,
                staleness: Staleness::Lost,
                trajectory_ref_m: Vec::new(),
                t_ref_body: None,
                position_cov_xy_m2: None,
                submaps: Vec::new(),
                hazards: None,
            },
            poses: Vec::new(),
            class_tx: BTreeMap::new(),
            hazards: None,
        }
    }
}

#[derive(Debug, Clone)]
struct SubmapEntry {
    header: Option<SubmapHeader>,
    /// `t_previous_this` of the header's frame switch.
    switch: Option<Isometry3<f64>>,
    tile: Option<Arc<Tile>>,
}

/// The graph of the current reference robot and the log it is rebuilt from.
#[derive(Debug)]
struct GraphState {
    reference: Option<u8>,
    graph: Option<TeamGraph>,
    log: Vec<Measurement>,
    dirty: bool,
    last_update_ns: Option<u64>,
    /// Connected node estimates after the last update.
    estimates: BTreeMap<slam::NodeId, Isometry3<f64>>,
    errors: u64,
}

impl Clone for GraphState {
    /// The optimizer is not cloneable: a clone rebuilds it from the log at its next update.
    fn clone(&self) -> Self {
        GraphState {
            reference: self.reference,
            graph: None,
            log: self.log.clone(),
            dirty: true,
            last_update_ns: None,
            estimates: self.estimates.clone(),
            errors: self.errors,
        }
    }
}

fn ground_graph_config() -> TeamGraphConfig {
    TeamGraphConfig { pose_max_gap_ns: GROUND_POSE_MAX_GAP_NS, ..TeamGraphConfig::default() }
}

impl GraphState {
    fn ensure(&mut self) -> Option<&mut TeamGraph> {
        let reference = self.reference?;
        if self.graph.is_none() {
            let mut graph = TeamGraph::new(u16::from(reference), ground_graph_config());
            for m in &self.log {
                graph.insert(m);
            }
            self.graph = Some(graph);
            self.dirty = true;
        }
        self.graph.as_mut()
    }

    fn insert(&mut self, m: Measurement) {
        if self.log.len() >= MAX_MEASUREMENTS {
            return;
        }
        self.log.push(m);
        if let Some(graph) = self.graph.as_mut() {
            graph.insert(&m);
        }
        self.dirty = true;
    }

    fn set_reference(&mut self, reference: u8) {
        self.reference = Some(reference);
        self.graph = None;
        self.estimates.clear();
        self.dirty = true;
        self.last_update_ns = None;
    }

    /// Runs the throttled update; true if the estimates changed.
    /// Optimizes if new measurements arrived, at most once per [`GRAPH_PERIOD_NS`] unless `force`.
    fn update(&mut self, now_ns: u64, force: bool) -> Result<bool, slam::SlamError> {
        let throttled = !force && self.last_update_ns.is_some_and(|t| now_ns < t.saturating_add(GRAPH_PERIOD_NS));
        if !self.dirty || throttled {
            return Ok(false);
        }
        let Some(graph) = self.ensure() else { return Ok(false) };
        let result = graph.update();
        let estimates = graph.estimates();
        self.estimates = estimates;
        self.dirty = false;
        self.last_update_ns = Some(now_ns);
        result.map(|_| true)
    }

    fn submap_pose(&self, robot: u8, index: u32) -> Option<Isometry3<f64>> {
        self.estimates.get(&slam::NodeId::Submap(slam::SubmapId::new(u16::from(robot), index))).copied()
    }
}

#[derive(Debug, Clone)]
struct PendingCommand {
    command: Command,
    view: CommandView,
    first_sent_ns: Option<u64>,
    attempts: u32,
    /// Handed to the endpoint (it retransmits until acknowledged).
    in_endpoint: bool,
}

#[derive(Debug, Clone, Copy)]
struct EdgeRecord {
    kind: EdgeKind,
    from: NodeRef,
    to: NodeRef,
}

/// Counters not shown in the view.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ModelCounters {
    /// Decoded messages the model could not use (bad pose, inconsistent header, ...).
    pub messages_rejected: u64,
    pub submaps_decoded: u64,
    pub submaps_rejected: u64,
    /// The ground's own uplink packets seen in a recording (ignored).
    pub uplink_echoes: u64,
    pub compositions: u64,
    pub graph_updates: u64,
    pub graph_errors: u64,
}

/// See the module documentation.
#[derive(Debug, Clone)]
pub struct TeamModel {
    config: ModelConfig,
    endpoint: GroundEndpoint,
    /// Authentication counter of the next command: never reused with the key.
    counter: u64,
    next_command_id: u32,
    robots: BTreeMap<u8, RobotState>,
    submaps: BTreeMap<(u8, u32), SubmapEntry>,
    reassembler: wire::Reassembler,
    graph: GraphState,
    edges: Vec<EdgeRecord>,
    composer: MapComposer,
    last_compose_ns: Option<u64>,
    link: LinkAccumulator,
    commands: Vec<PendingCommand>,
    notices: VecDeque<String>,
    replay: Option<crate::view::ReplayView>,
    counters: ModelCounters,
    last_rtt_ms: Option<f64>,
    last_view_ns: Option<u64>,
    view: TeamView,
    tx_buf: Vec<u8>,
}

/// The ground's protocol endpoint. It is some 400 KB: built and cloned in functions of their own,
/// never inlined, so no caller's stack frame has to hold copies of it.
#[derive(Debug)]
struct GroundEndpoint(Box<Endpoint<DEFAULT_WINDOW>>);

impl GroundEndpoint {
    #[inline(never)]
    fn new(key: Option<AuthKey>) -> GroundEndpoint {
        let framing = Framing::Datagram { mtu: protocol::frame::datagram::MAX_DATAGRAM_BYTES as u16 };
        let burst = EndpointConfig::min_burst_bytes(framing) * 4;
        let mut config = EndpointConfig::new(NodeId::GROUND, framing, UPLINK_RATE_BYTES_PER_S, burst)
            .with_rto(RtoConfig { initial_ms: 4_000, min_ms: 200, max_ms: 30_000 });
        if let Some(key) = key {
            config = config.with_auth_key(key);
        }
        match Endpoint::new(config) {
            Ok(endpoint) => GroundEndpoint(Box::new(endpoint)),
            // The configuration above is constant and valid (every test builds it).
            Err(e) => unreachable!("ground endpoint configuration refused: {e}"),
        }
    }
}

impl Clone for GroundEndpoint {
    #[inline(never)]
    fn clone(&self) -> Self {
        GroundEndpoint(self.0.clone())
    }
}

impl std::ops::Deref for GroundEndpoint {
    type Target = Endpoint<DEFAULT_WINDOW>;
    fn deref(&self) -> &Self::Target {
        &self.0
    }
}

impl std::ops::DerefMut for GroundEndpoint {
    fn deref_mut(&mut self) -> &mut Self::Target {
        &mut self.0
    }
}

fn ns_to_ms(ns: u64) -> u64 {
    ns / 1_000_000
}

fn class_name(key: u8) -> String {
    AnyMessage::name_of(MessageKey(key)).map_or_else(|| format!("key {key:#04x}"), str::to_string)
}

impl TeamModel {
    pub fn new(config: ModelConfig) -> TeamModel {
        let endpoint = GroundEndpoint::new(config.auth_key.clone());
        // Microseconds since the epoch: above any counter a previous run of the ground used.
        let counter = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(1, |d| u64::try_from(d.as_micros()).unwrap_or(u64::MAX / 2));
        let view = TeamView {
            now_ns: 0,
            reference_robot: None,
            robots: BTreeMap::new(),
            edges: Vec::new(),
            map: None,
            points: Arc::new(Default::default()),
            link: Default::default(),
            commands: Vec::new(),
            can_command: config.auth_key.is_some(),
            replay: None,
            notices: Vec::new(),
            source: config.source.clone(),
        };
        TeamModel {
            config,
            endpoint,
            counter,
            next_command_id: 1,
            robots: BTreeMap::new(),
            submaps: BTreeMap::new(),
            reassembler: wire::Reassembler::new(MAX_PARTIAL_SUBMAPS, MAX_SUBMAP_PAYLOAD_BYTES),
            graph: GraphState {
                reference: None,
                graph: None,
                log: Vec::new(),
                dirty: false,
                last_update_ns: None,
                estimates: BTreeMap::new(),
                errors: 0,
            },
            edges: Vec::new(),
            composer: MapComposer::default(),
            last_compose_ns: None,
            link: LinkAccumulator::default(),
            commands: Vec::new(),
            notices: VecDeque::new(),
            replay: None,
            counters: ModelCounters::default(),
            last_rtt_ms: None,
            last_view_ns: None,
            view,
            tx_buf: vec![0; MAX_PACKET_BYTES],
        }
    }

    /// Starts the command authentication counter at `counter` (it must exceed every counter
    /// used before with the key; the default is the wall clock in µs).
    pub fn with_counter_start(mut self, counter: u64) -> Self {
        self.counter = counter;
        self
    }

    /// Marks the model as showing a recording (commands refused) at this replay position.
    pub fn set_replay(&mut self, replay: Option<crate::view::ReplayView>) {
        self.replay = replay;
        self.view.replay = replay;
        self.view.can_command = self.can_command();
    }

    pub fn counters(&self) -> ModelCounters {
        ModelCounters { graph_errors: self.graph.errors, ..self.counters }
    }

    /// Statistics of the last map composition.
    pub fn compose_stats(&self) -> map::ComposeStats {
        self.composer.last_stats
    }

    pub fn view(&self) -> &TeamView {
        &self.view
    }

    fn can_command(&self) -> bool {
        self.config.auth_key.is_some() && self.replay.is_none()
    }

    fn notice(&mut self, text: String) {
        self.notices.push_back(text);
        while self.notices.len() > MAX_NOTICES {
            self.notices.pop_front();
        }
        self.view.notices = self.notices.iter().cloned().collect();
    }

    fn robot(&mut self, robot: u8) -> &mut RobotState {
        if self.graph.reference.is_none() {
            self.graph.set_reference(robot);
        }
        self.robots.entry(robot).or_insert_with(|| RobotState::new(robot))
    }

    // ------------------------------------------------------------------------------ receiving

    /// One packet from the link. Total: any bytes are either used or counted as rejected.
    pub fn ingest(&mut self, recv_ns: u64, packet: &[u8]) {
        let header = match decode_header(packet) {
            Ok((header, _)) => header,
            Err(_) => {
                self.link.on_rejected();
                return;
            }
        };
        if header.source == NodeId::GROUND {
            self.counters.uplink_echoes += 1;
            return;
        }
        if self.endpoint.handle_packet(ns_to_ms(recv_ns), packet).is_err() {
            self.link.on_rejected();
            return;
        }
        self.link.on_packet(recv_ns, &class_name(header.key), packet.len());
        if header.source.is_robot() {
            let robot = self.robot(header.source.0);
            robot.view.last_message_ns = Some(robot.view.last_message_ns.map_or(recv_ns, |t| t.max(recv_ns)));
        }
        while let Some(delivered) = self.endpoint.poll_deliver() {
            self.on_message(recv_ns, delivered);
        }
    }

    fn on_message(&mut self, recv_ns: u64, delivered: Delivered) {
        match delivered.message {
            AnyMessage::Telemetry(t) => self.on_telemetry(recv_ns, t),
            AnyMessage::PoseEstimate(p) => self.on_pose(p),
            AnyMessage::HazardCells(h) => self.on_hazards(recv_ns, &h),
            AnyMessage::SubmapHeader(h) => self.on_submap_header(h),
            AnyMessage::SubmapChunk(c) => self.on_submap_chunk(c),
            AnyMessage::Constraint(c) => match wire::constraint_measurement(&c) {
                Ok(m) => {
                    for robot in [&c.from, &c.to].into_iter().filter_map(node_robot) {
                        self.robot(robot);
                    }
                    let kind = match c.kind {
                        ConstraintKind::RobotDetection => Some(EdgeKind::RobotDetection),
                        ConstraintKind::SubmapMatch => Some(EdgeKind::SubmapMatch),
                        ConstraintKind::LandmarkObservation => None,
                    };
                    if let Some(kind) = kind {
                        self.edges.push(EdgeRecord { kind, from: c.from, to: c.to });
                    }
                    self.graph.insert(m);
                }
                Err(_) => self.counters.messages_rejected += 1,
            },
            AnyMessage::MatchAttempt(a) => {
                if let Some(m) = wire::attempt_measurement(&a) {
                    self.graph.insert(m);
                }
            }
            AnyMessage::CommandAck(ack) => self.on_command_ack(recv_ns, ack),
            AnyMessage::Heartbeat(h) if h.node.is_robot() => {
                let robot = self.robot(h.node.0);
                robot.view.mode.get_or_insert(h.mode);
            }
            _ => {}
        }
    }

    fn on_telemetry(&mut self, recv_ns: u64, t: Telemetry) {
        let robot = self.robot(t.robot.0);
        let v = &mut robot.view;
        v.mode = Some(t.mode);
        v.filter = Some(t.filter);
        v.resources = Some(t.resources);
        v.sensors = t.sensors;
        v.tasks = t.tasks.to_vec();
        v.queues = t.queues.to_vec();
        v.links = t.links.to_vec();
        v.auth_rejections = t.auth_rejections;
        let mut sent = Vec::new();
        for class in &t.classes {
            let previous = robot.class_tx.insert(class.message_key, class.tx_bytes);
            // The first report, or a counter that went back (a restart), gives no rate.
            if let Some(previous) = previous.filter(|p| *p <= class.tx_bytes) {
                sent.push((class.message_key, class.tx_bytes - previous));
            }
        }
        for (key, bytes) in sent {
            self.link.on_robot_sent(recv_ns, &class_name(key), bytes);
        }
    }

    fn on_pose(&mut self, p: PoseEstimate) {
        let fp = match wire::filter_pose(&p) {
            Ok(fp) => fp,
            Err(_) => {
                self.counters.messages_rejected += 1;
                return;
            }
        };
        let full = p.covariance.to_full();
        let position_cov = Matrix3::from_fn(|r, c| full[r][c]);
        let stored = StoredPose {
            stamp_ns: p.stamp_ns,
            submap: p.submap.index,
            t_submap_body: fp.t_submap_body,
            position_cov: if position_cov.iter().all(|v| v.is_finite()) { position_cov } else { Matrix3::zeros() },
        };
        let robot = self.robot(p.robot.0);
        let at = robot.poses.partition_point(|q| q.stamp_ns < stored.stamp_ns);
        if robot.poses.get(at).is_some_and(|q| q.stamp_ns == stored.stamp_ns) {
            return;
        }
        robot.poses.insert(at, stored);
        if robot.poses.len() > MAX_POSES_PER_ROBOT {
            robot.poses.remove(0);
        }
        self.graph.insert(Measurement::FilterPose(fp));
    }

    fn on_hazards(&mut self, recv_ns: u64, h: &HazardCells) {
        match ReceivedHazards::from_message(recv_ns, h) {
            Some(kept) => self.robot(h.robot.0).hazards = Some(kept),
            None => self.counters.messages_rejected += 1,
        }
    }

    fn on_submap_header(&mut self, h: SubmapHeader) {
        let switch = match wire::header_switch(&h) {
            Ok(switch) => switch,
            Err(_) => {
                self.counters.messages_rejected += 1;
                return;
            }
        };
        self.robot(h.submap.robot.0);
        let entry = self.submaps.entry((h.submap.robot.0, h.submap.index)).or_insert(SubmapEntry {
            header: None,
            switch: None,
            tile: None,
        });
        entry.header = Some(h);
        entry.switch = switch.map(|s| s.t_old_new);
        if let Some(s) = switch {
            self.graph.insert(Measurement::SubmapSwitch(s));
        }
        if h.encoding == wire::SUBMAP_ENCODING_EXCHANGE_V1 && self.reassembler.start(&h).is_err() {
            self.counters.submaps_rejected += 1;
        }
    }

    fn on_submap_chunk(&mut self, c: SubmapChunk) {
        let (header, payload) = match self.reassembler.add(&c) {
            Ok(Some(done)) => done,
            Ok(None) => return,
            Err(_) => {
                self.counters.submaps_rejected += 1;
                return;
            }
        };
        let key = (header.submap.robot.0, header.submap.index);
        match mapper::exchange::decode_submap(&payload) {
            Ok(submap) if submap.robot_id == u16::from(key.0) && submap.index == key.1 => {
                self.counters.submaps_decoded += 1;
                let tile = Tile::rasterize(&submap).map(Arc::new);
                let entry = self.submaps.entry(key).or_insert(SubmapEntry { header: None, switch: None, tile: None });
                entry.header.get_or_insert(header);
                entry.tile = tile;
            }
            _ => self.counters.submaps_rejected += 1,
        }
    }

    fn on_command_ack(&mut self, recv_ns: u64, ack: CommandAck) {
        let Some(c) =
            self.commands.iter_mut().find(|c| c.command.id == ack.command_id && c.command.target == ack.robot)
        else {
            return;
        };
        let sent_ns = c.first_sent_ns.unwrap_or(c.view.queued_ns);
        let rtt_ms = recv_ns.saturating_sub(sent_ns) / 1_000_000;
        c.view.state = CommandState::Acknowledged { outcome: ack.outcome, rtt_ms };
        self.last_rtt_ms = Some(rtt_ms as f64);
    }

    // ------------------------------------------------------------------------------- commands

    /// An operator action. Refusals are also listed in the view's notices.
    pub fn apply(&mut self, now_ns: u64, action: &UiAction) -> Result<(), ActionError> {
        let result = self.apply_inner(now_ns, action);
        if let Err(e) = &result {
            self.notice(e.to_string());
        }
        self.refresh_commands();
        result
    }

    fn apply_inner(&mut self, now_ns: u64, action: &UiAction) -> Result<(), ActionError> {
        let (robot, kind, summary) = match action {
            UiAction::SetReference(robot) => {
                if !self.robots.contains_key(robot) {
                    return Err(ActionError::UnknownRobot(*robot));
                }
                self.graph.set_reference(*robot);
                self.graph.update(now_ns, false).map_err(|_| ActionError::UnknownRobot(*robot))?;
                self.rebuild_view(now_ns, true);
                return Ok(());
            }
            UiAction::ReplaySeek(_) => return Err(ActionError::NotAModelAction("replay seek")),
            UiAction::ReplayPlay(_) => return Err(ActionError::NotAModelAction("replay play")),
            UiAction::ReplaySpeed(_) => return Err(ActionError::NotAModelAction("replay speed")),
            UiAction::SetMode { robot, mode } => (*robot, CommandKind::SetMode(*mode), format!("set mode {mode:?}")),
            UiAction::Waypoint { robot, x_ref_m, y_ref_m } => {
                self.check_command(*robot)?;
                let (x, y, z) = self.waypoint_in_robot_frame(*robot, *x_ref_m, *y_ref_m)?;
                let summary = format!(
                    "waypoint ({x_ref_m:.1}, {y_ref_m:.1}) m → ({x:.1}, {y:.1}, {z:.1}) m in robot {robot}'s frame"
                );
                (*robot, CommandKind::GoToWaypoint { x_m: x, y_m: y, z_m: z, speed_mps: WAYPOINT_SPEED_MPS }, summary)
            }
            UiAction::SetParameter { robot, name, value } => {
                let mut param = protocol::message::ParamName::new();
                param.push_str(name).map_err(|_| ActionError::TooLong { what: "parameter name", max: 32 })?;
                (*robot, CommandKind::SetParameter { name: param, value: *value }, format!("set {name} = {value:?}"))
            }
            UiAction::RequestResend { robot, submap_index } => (
                *robot,
                CommandKind::RequestResend {
                    submap: protocol::SubmapId { robot: RobotId(*robot), index: *submap_index },
                    chunks: None,
                },
                format!("resend submap {submap_index}"),
            ),
            UiAction::StartRecording { robot, label } => {
                let mut text = heapless::String::<32>::new();
                text.push_str(label).map_err(|_| ActionError::TooLong { what: "recording label", max: 32 })?;
                (*robot, CommandKind::StartRecording { label: text }, format!("start recording {label:?}"))
            }
            UiAction::StopRecording { robot } => (*robot, CommandKind::StopRecording, "stop recording".to_string()),
        };
        self.check_command(robot)?;
        let id = self.next_command_id;
        self.next_command_id = self.next_command_id.wrapping_add(1).max(1);
        let command = Command { target: RobotId(robot), id, kind };
        self.commands.push(PendingCommand {
            command,
            view: CommandView { id, target: robot, summary, state: CommandState::Queued, queued_ns: now_ns },
            first_sent_ns: None,
            attempts: 0,
            in_endpoint: false,
        });
        let finished = |c: &PendingCommand| matches!(c.view.state, CommandState::Acknowledged { .. });
        while self.commands.len() > MAX_SHOWN_COMMANDS {
            match self.commands.iter().position(finished) {
                Some(i) => self.commands.remove(i),
                None => self.commands.remove(0),
            };
        }
        self.push_commands(now_ns);
        Ok(())
    }

    fn check_command(&self, robot: u8) -> Result<(), ActionError> {
        if self.replay.is_some() {
            return Err(ActionError::Replay);
        }
        if self.config.auth_key.is_none() {
            return Err(ActionError::NoKey);
        }
        if !NodeId(robot).is_robot() {
            return Err(ActionError::NotARobot(robot));
        }
        let pending = self
            .commands
            .iter()
            .filter(|c| matches!(c.view.state, CommandState::Queued | CommandState::Sent { .. }))
            .count();
        if pending >= MAX_PENDING_COMMANDS {
            return Err(ActionError::QueueFull(pending));
        }
        Ok(())
    }

    /// A reference-frame point in the target robot's own frame (its first submap origin).
    fn waypoint_in_robot_frame(&self, robot: u8, x_ref_m: f64, y_ref_m: f64) -> Result<(f64, f64, f64), ActionError> {
        if !(x_ref_m.is_finite() && y_ref_m.is_finite()) {
            return Err(ActionError::NotFinite);
        }
        let reference = self.graph.reference.ok_or(ActionError::NoReference)?;
        let t_ref_robot = self.graph.submap_pose(robot, 0).ok_or(ActionError::NotConnected { robot, reference })?;
        let z_ref = self
            .view
            .map
            .as_ref()
            .and_then(|g| grid_height(g, x_ref_m, y_ref_m))
            .or_else(|| self.view.robots.get(&robot).and_then(|r| r.t_ref_body).map(|t| t.translation.z))
            .unwrap_or(0.0);
        let p = t_ref_robot.inverse() * Point3::new(x_ref_m, y_ref_m, z_ref);
        Ok((p.x, p.y, p.z))
    }

    /// Hands queued commands to the endpoint for robots whose link is up.
    fn push_commands(&mut self, now_ns: u64) {
        let Some(key) = self.config.auth_key.clone() else { return };
        if self.replay.is_some() {
            return;
        }
        for i in 0..self.commands.len() {
            let c = &self.commands[i];
            if c.in_endpoint || c.view.state != CommandState::Queued {
                continue;
            }
            let target = c.view.target;
            let up = self
                .robots
                .get(&target)
                .and_then(|r| r.view.last_message_ns)
                .is_some_and(|t| now_ns.saturating_sub(t) < STALE_AFTER_NS);
            if !up || self.endpoint.queue_space(NodeId(target), Priority::Command) == 0 {
                continue;
            }
            let message = AnyMessage::Command(c.command.clone());
            match self.endpoint.send_authenticated(ns_to_ms(now_ns), NodeId(target), &message, self.counter, &key) {
                Ok(()) => {
                    self.counter += 1;
                    self.commands[i].in_endpoint = true;
                }
                Err(e) => {
                    let text = format!("command {} to robot {target} not sent: {e}", c.view.id);
                    self.commands[i].view.state = CommandState::TimedOut;
                    self.notice(text);
                }
            }
        }
    }

    fn refresh_commands(&mut self) {
        self.view.commands = self.commands.iter().map(|c| c.view.clone()).collect();
        self.view.can_command = self.can_command();
    }

    // ---------------------------------------------------------------------------- transmitting

    /// The next packet for the link and its destination robot (commands, transport acks).
    pub fn poll_transmit(&mut self, now_ns: u64) -> Option<(u8, Vec<u8>)> {
        let len = self.endpoint.poll_transmit(ns_to_ms(now_ns), &mut self.tx_buf)?;
        let packet = self.tx_buf.get(..len)?.to_vec();
        let destination = decode_header(&packet).ok()?.0.destination.0;
        if let Ok(decoded) = protocol::decode(&packet)
            && let AnyMessage::Command(command) = decoded.message
            && let Some(c) = self.commands.iter_mut().find(|c| c.command.id == command.id && c.in_endpoint)
        {
            c.attempts += 1;
            let first = *c.first_sent_ns.get_or_insert(now_ns);
            if matches!(c.view.state, CommandState::Queued | CommandState::Sent { .. }) {
                c.view.state = CommandState::Sent { first_sent_ns: first, attempts: c.attempts };
            }
            self.refresh_commands();
        }
        Some((destination, packet))
    }

    // ----------------------------------------------------------------------------------- time

    /// Advances ground time: link samples, staleness, command queue and timeouts, the throttled
    /// graph update and map composition, and the view.
    pub fn tick(&mut self, now_ns: u64) {
        self.tick_with(now_ns, false);
    }

    /// [`Self::tick`] without the graph's rate limit: brings graph, map and view up to date now,
    /// for a clock that stops (the end of a replay).
    pub fn settle(&mut self, now_ns: u64) {
        self.tick_with(now_ns, true);
    }

    fn tick_with(&mut self, now_ns: u64, force: bool) {
        for c in &mut self.commands {
            if let (CommandState::Sent { first_sent_ns, .. }, true) = (c.view.state, c.in_endpoint)
                && now_ns.saturating_sub(first_sent_ns) > COMMAND_TIMEOUT_NS
            {
                c.view.state = CommandState::TimedOut;
            }
        }
        self.push_commands(now_ns);
        let state = self.link_state();
        self.link.tick(now_ns, state);
        let changed = match self.graph.update(now_ns, force) {
            Ok(changed) => changed,
            Err(e) => {
                self.graph.errors += 1;
                self.notice(format!("graph update failed: {e}"));
                true
            }
        };
        if changed {
            self.counters.graph_updates += 1;
        }
        // The engine ticks at 100 Hz; the view is published at 10 Hz.
        if changed
            || force
            || self.last_view_ns.is_none_or(|t| now_ns >= t.saturating_add(VIEW_PERIOD_NS) || now_ns < t)
        {
            self.rebuild_view(now_ns, force);
        }
    }

    /// Closes link seconds up to `now_ns` without the graph, map and view work of [`Self::tick`]
    /// (for catching up through a recording).
    pub fn advance_clock(&mut self, now_ns: u64) {
        let state = self.link_state();
        self.link.tick(now_ns, state);
    }

    fn link_state(&self) -> LinkState {
        let stats = self.endpoint.stats();
        let rtt_ms = stats.srtt_ms.map(|v| v as f64).or(self.last_rtt_ms);
        let loss = self
            .robots
            .values()
            .filter_map(|r| {
                let ground = r.view.links.iter().find(|l| l.link.as_str() == "ground");
                ground.map(|l| l.loss_permille).or_else(|| r.view.links.iter().map(|l| l.loss_permille).max())
            })
            .max()
            .map(f64::from);
        let robot_queue_depth =
            self.robots.values().flat_map(|r| r.view.queues.iter().map(|q| u32::from(q.depth))).max().unwrap_or(0);
        let queued = self.commands.iter().filter(|c| c.view.state == CommandState::Queued).count() as u32;
        let command = usize::from(Priority::Command.channel());
        let in_endpoint = stats.queued.get(command).copied().unwrap_or(0);
        LinkState { rtt_ms, loss_permille: loss, robot_queue_depth, ground_queue_depth: queued + in_endpoint }
    }

    /// Origins of every submap that can be placed in the reference frame.
    fn origins(&self) -> BTreeMap<(u8, u32), Isometry3<f64>> {
        let mut origins = BTreeMap::new();
        for (&robot, state) in &self.robots {
            let last_header = self.submaps.range((robot, 0)..=(robot, u32::MAX)).next_back().map(|(k, _)| k.1);
            let last_pose = state.poses.iter().map(|p| p.submap).max();
            let Some(last) = last_header.max(last_pose) else { continue };
            let mut previous: Option<Isometry3<f64>> = None;
            for index in 0..=last.min(100_000) {
                let origin = self.graph.submap_pose(robot, index).or_else(|| {
                    let prev = previous?;
                    if let Some(switch) = self.submaps.get(&(robot, index)).and_then(|e| e.switch) {
                        return Some(prev * switch);
                    }
                    // The switch is not known yet: the last pose before it and the first after it
                    // are (nearly) the same body pose in the two frames.
                    let before = state.poses.iter().rev().find(|p| p.submap + 1 == index)?;
                    let after = state.poses.iter().find(|p| p.submap == index)?;
                    Some(prev * before.t_submap_body * after.t_submap_body.inverse())
                });
                if let Some(o) = origin {
                    origins.insert((robot, index), o);
                }
                previous = origin;
            }
        }
        origins
    }

    fn node_position(&self, node: &NodeRef, origins: &BTreeMap<(u8, u32), Isometry3<f64>>) -> Option<[f64; 3]> {
        let p = match node {
            NodeRef::SubmapOrigin(id) => origins.get(&(id.robot.0, id.index))?.translation.vector,
            NodeRef::RobotPose { robot, stamp_ns } => {
                let id = slam::PoseId { robot: u16::from(robot.0), stamp_ns: *stamp_ns };
                self.graph.estimates.get(&slam::NodeId::Pose(id))?.translation.vector
            }
            NodeRef::Landmark { .. } => return None,
        };
        Some([p.x, p.y, p.z])
    }

    fn rebuild_view(&mut self, now_ns: u64, force_compose: bool) {
        self.last_view_ns = Some(now_ns);
        let origins = self.origins();
        let connected: BTreeSet<u8> = self
            .graph
            .estimates
            .keys()
            .filter_map(|n| match n {
                slam::NodeId::Submap(id) => u8::try_from(id.robot).ok(),
                _ => None,
            })
            .collect();
        let mut robots = BTreeMap::new();
        for (&robot, state) in &self.robots {
            let mut v = state.view.clone();
            v.connected = connected.contains(&robot);
            v.staleness = match v.last_message_ns {
                Some(t) if now_ns.saturating_sub(t) <= STALE_AFTER_NS => Staleness::Fresh,
                Some(t) if now_ns.saturating_sub(t) <= LOST_AFTER_NS => Staleness::Stale,
                _ => Staleness::Lost,
            };
            let mut latest = None;
            if v.connected {
                for p in &state.poses {
                    if let Some(origin) = origins.get(&(robot, p.submap)) {
                        let t = origin * p.t_submap_body;
                        v.trajectory_ref_m.push([t.translation.x, t.translation.y, t.translation.z]);
                        latest = Some((t, origin.rotation.to_rotation_matrix().into_inner(), p.position_cov));
                    }
                }
            }
            v.t_ref_body = latest.map(|(t, _, _)| t);
            // Not connected: no pose in this frame, so nothing to place the cells with.
            v.hazards = state.hazards.as_ref().filter(|_| v.connected).and_then(|h| {
                match origins.get(&(robot, h.submap)) {
                    Some(origin) => Some(h.place(&(origin * h.t_submap_body), true)),
                    // The message's submap is not placed yet (no pose of it has arrived).
                    None => v.t_ref_body.map(|t| h.place(&t, false)),
                }
            });
            v.position_cov_xy_m2 = latest.map(|(_, r, c)| {
                let c = r * c * r.transpose();
                Matrix2::new(c[(0, 0)], c[(0, 1)], c[(1, 0)], c[(1, 1)])
            });
            v.submaps = self
                .submaps
                .range((robot, 0)..=(robot, u32::MAX))
                .filter_map(|(&(_, index), e)| {
                    Some(SubmapOutline {
                        index,
                        t_ref_submap: *origins.get(&(robot, index))?,
                        bounds_submap_m: e.tile.as_ref().map(|t| t.bounds_m),
                    })
                })
                .collect();
            robots.insert(robot, v);
        }
        let edges = self
            .edges
            .iter()
            .filter_map(|e| {
                Some(EdgeView {
                    kind: e.kind,
                    from_ref_m: self.node_position(&e.from, &origins)?,
                    to_ref_m: self.node_position(&e.to, &origins)?,
                })
            })
            .collect();
        let placed: BTreeMap<(u8, u32), Placed> = self
            .submaps
            .iter()
            .filter_map(|(&key, e)| {
                let tile = e.tile.clone()?;
                let order = (e.header.map_or(0, |h| h.finished_stamp_ns), key.0, key.1);
                Some((key, Placed { order, t_ref_submap: *origins.get(&key)?, tile }))
            })
            .collect();
        let due = force_compose || self.last_compose_ns.is_none_or(|t| now_ns >= t.saturating_add(GRAPH_PERIOD_NS));
        if due && self.composer.needs_compose(&placed) {
            self.composer.compose(&placed);
            self.counters.compositions += 1;
            self.last_compose_ns = Some(now_ns);
        }
        self.view.now_ns = now_ns;
        self.view.reference_robot = self.graph.reference;
        self.view.robots = robots;
        self.view.edges = edges;
        self.view.map = self.composer.grid.clone();
        self.view.points = Arc::clone(&self.composer.points);
        self.view.link = self.link.view.clone();
        self.view.replay = self.replay;
        self.refresh_commands();
    }
}

fn node_robot(node: &NodeRef) -> Option<u8> {
    match node {
        NodeRef::SubmapOrigin(id) => Some(id.robot.0),
        NodeRef::RobotPose { robot, .. } => Some(robot.0),
        NodeRef::Landmark { .. } => None,
    }
}

/// The grid's height at a reference-frame point, if observed.
pub fn grid_height(grid: &crate::view::HeightGrid, x_m: f64, y_m: f64) -> Option<f64> {
    let c = ((x_m - grid.origin_xy_m[0]) / grid.cell_m).floor();
    let r = ((y_m - grid.origin_xy_m[1]) / grid.cell_m).floor();
    if c < 0.0 || r < 0.0 || c >= grid.width as f64 || r >= grid.height as f64 {
        return None;
    }
    let h = *grid.height_m.get(r as usize * grid.width + c as usize)?;
    (!h.is_nan()).then_some(f64::from(h))
}
