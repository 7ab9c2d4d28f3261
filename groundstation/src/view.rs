//! What the UI draws and what it asks for: the contract between the team model
//! ([`crate::model`]) and the panels ([`crate::ui`]).
//!
//! The model owns the truth (packets in, graph, composed map, link statistics, the command queue)
//! and publishes a [`TeamView`] snapshot; the UI reads only the snapshot and answers with
//! [`UiAction`]s. Neither waits on the other or on I/O.
//!
//! # Frames
//!
//! There is no shared global frame in the team (thesis §3.3). The ground station shows the team
//! in the global frame of one **reference robot** (its first submap origin, gravity-aligned,
//! z up): every pose and point in a `TeamView` is `t_ref_*` / `p_ref` in that frame, metres.
//! Robots not (yet) connected to the reference robot by a detection or a submap match have no
//! pose in that frame; they are listed with `connected == false` and drawn nowhere on the map.

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

use nalgebra::{Isometry3, Matrix2};
use protocol::message::{CommandOutcome, FilterHealth, LinkStats, Mode, QueueStats, ResourceUsage, TaskStats};

/// How fresh a robot's data is on the ground (thesis §9.2: a 4 s round trip is normal).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Staleness {
    /// A message within [`STALE_AFTER_NS`].
    Fresh,
    /// Nothing for longer than [`STALE_AFTER_NS`].
    Stale,
    /// Nothing for longer than [`LOST_AFTER_NS`].
    Lost,
}

/// Telemetry comes at 1 Hz; three missed reports plus the link's 2 s one-way delay.
pub const STALE_AFTER_NS: u64 = 5_000_000_000;
pub const LOST_AFTER_NS: u64 = 30_000_000_000;

/// A submap's footprint on the map: its origin and the xy bounds of its points in its own frame.
#[derive(Debug, Clone, PartialEq)]
pub struct SubmapOutline {
    /// Robot-local submap index.
    pub index: u32,
    pub t_ref_submap: Isometry3<f64>,
    /// `[min_x, min_y, max_x, max_y]` in the submap frame, m (`None` until its payload arrived).
    pub bounds_submap_m: Option<[f64; 4]>,
}

/// A robot's latest hazard cells (its local obstacle map, as its comms coarsened it), placed in
/// the reference frame.
#[derive(Debug, Clone, PartialEq)]
pub struct HazardView {
    /// Ground receive time of the message (mission clock, ns).
    pub received_ns: u64,
    /// Robot time of the body pose the cells are relative to, ns.
    pub stamp_ns: u64,
    /// Edge of a cell, m.
    pub cell_m: f64,
    /// Yaw of the cells' lattice in the reference frame (the body's heading), rad.
    pub yaw_ref_rad: f64,
    /// Cell centres in the reference frame, m, the nearest to the robot first.
    pub cells_ref_m: Vec<[f64; 2]>,
    /// Hazard cells the robot left out, the farthest (`protocol::message::HazardCells::omitted`).
    pub omitted: u16,
    /// Placed with the body pose the message carries; `false`: that pose's submap is not placed
    /// yet, and the robot's latest pose stood in for it.
    pub exact: bool,
}

/// One robot as the operator sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotView {
    pub robot: u8,
    /// Connected to the reference robot's frame (the reference robot itself is).
    pub connected: bool,
    pub mode: Option<Mode>,
    pub filter: Option<FilterHealth>,
    /// The devices' availability from the last telemetry (`None`: not devices, or not reported).
    pub sensors: Option<protocol::message::SensorAvailability>,
    pub tasks: Vec<TaskStats>,
    pub queues: Vec<QueueStats>,
    pub links: Vec<LinkStats>,
    pub resources: Option<ResourceUsage>,
    pub auth_rejections: u32,
    /// Ground receive time of the robot's latest message (mission clock, ns).
    pub last_message_ns: Option<u64>,
    pub staleness: Staleness,
    /// Online estimate as received, in the reference frame (empty when not connected).
    pub trajectory_ref_m: Vec<[f64; 3]>,
    /// Latest pose in the reference frame.
    pub t_ref_body: Option<Isometry3<f64>>,
    /// xy position covariance of the latest pose in the reference frame, m².
    pub position_cov_xy_m2: Option<Matrix2<f64>>,
    pub submaps: Vec<SubmapOutline>,
    /// The latest hazard cells (`None`: none received, or the robot is not connected).
    pub hazards: Option<HazardView>,
}

/// What connects two places on the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EdgeKind {
    /// A robot detected another one (AprilTag).
    RobotDetection,
    /// Two submaps were matched.
    SubmapMatch,
}

/// A loop-closure edge, endpoints in the reference frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeView {
    pub kind: EdgeKind,
    pub from_ref_m: [f64; 3],
    pub to_ref_m: [f64; 3],
}

/// The composed 2.5D map in the reference frame: row `r`, column `c` covers
/// `x ∈ origin_x + c·cell ..`, `y ∈ origin_y + r·cell ..`.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightGrid {
    pub origin_xy_m: [f64; 2],
    pub cell_m: f64,
    pub width: usize,
    pub height: usize,
    /// Row-major surface heights, m; NaN where nothing was observed.
    pub height_m: Vec<f32>,
    /// Row-major: some point in the cell was classified as an obstacle.
    pub obstacle: Vec<bool>,
    /// Changes whenever the content changes (the UI re-uploads its texture only then).
    pub revision: u64,
}

/// A level-of-detail point set for the 3D view (already voxel-decimated by the model).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct MapPoints {
    pub points_ref_m: Vec<[f32; 3]>,
    pub obstacle: Vec<bool>,
    pub revision: u64,
}

/// The ground link at one moment (one sample per second of mission time).
#[derive(Debug, Clone, PartialEq)]
pub struct LinkSample {
    /// Mission time, s.
    pub t_s: f64,
    /// Received bytes per second over the last second, per message class (`Telemetry`,
    /// `PoseEstimate`, `SubmapChunk`, ...), as seen by the ground.
    pub rx_bytes_per_s_by_class: BTreeMap<String, f64>,
    /// Sent by the robots per class (from their telemetry), summed over the team, bytes/s.
    pub tx_bytes_per_s_by_class: BTreeMap<String, f64>,
    /// Smoothed round-trip time of the command uplink, ms (`None`: unknown).
    pub rtt_ms: Option<f64>,
    /// Packet loss over the last window, per mille (the robots' reports, worst robot).
    pub loss_permille: Option<f64>,
    /// Deepest queue the robots reported, and the ground's own command queue.
    pub robot_queue_depth: u32,
    pub ground_queue_depth: u32,
    /// No packet at all in this second.
    pub outage: bool,
}

/// The ground link over time.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct LinkView {
    /// Oldest first; bounded (the model keeps the last 10 minutes).
    pub samples: VecDeque<LinkSample>,
    pub outages: u32,
    pub packets_received: u64,
    /// Packets the decoder refused (corrupted, unknown version).
    pub packets_rejected: u64,
}

/// Where a command is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandState {
    /// Waiting for the link (outage or rate cap).
    Queued,
    /// Sent; retransmitted until acknowledged.
    Sent {
        first_sent_ns: u64,
        attempts: u32,
    },
    Acknowledged {
        outcome: CommandOutcome,
        rtt_ms: u64,
    },
    /// Not acknowledged in time; the operator may send it again.
    TimedOut,
}

#[derive(Debug, Clone, PartialEq)]
pub struct CommandView {
    pub id: u32,
    pub target: u8,
    /// Human-readable summary, e.g. `waypoint (12.0, -3.5) m`.
    pub summary: String,
    pub state: CommandState,
    pub queued_ns: u64,
}

/// Replay position, when the source is a recorded mission.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ReplayView {
    pub start_ns: u64,
    pub end_ns: u64,
    pub position_ns: u64,
    pub playing: bool,
    /// Playback speed, × real time.
    pub speed: f64,
}

/// Everything the UI shows, as one consistent snapshot.
#[derive(Debug, Clone, PartialEq)]
pub struct TeamView {
    /// Mission time of the snapshot on the ground, ns.
    pub now_ns: u64,
    /// The robot whose frame the map is drawn in (`None` before the first robot is heard).
    pub reference_robot: Option<u8>,
    pub robots: BTreeMap<u8, RobotView>,
    pub edges: Vec<EdgeView>,
    /// Shared, not copied, between snapshots: a 200 m map is millions of cells.
    pub map: Option<Arc<HeightGrid>>,
    pub points: Arc<MapPoints>,
    pub link: LinkView,
    pub commands: Vec<CommandView>,
    /// Whether commands can be sent (a key was loaded and the source is live).
    pub can_command: bool,
    pub replay: Option<ReplayView>,
    /// Recent results of operator actions the model refused or could not carry out, newest last
    /// (e.g. `waypoint refused: robot 2 is not connected to robot 1's frame`).
    pub notices: Vec<String>,
    /// Where the data comes from, e.g. `udp://0.0.0.0:47800` or `replay runs/demo`.
    pub source: String,
}

/// A mode change, waypoint or other command the operator asked for.
#[derive(Debug, Clone, PartialEq)]
pub enum UiAction {
    SetMode {
        robot: u8,
        mode: Mode,
    },
    /// A waypoint clicked on the map, in the reference frame; the model converts it into the
    /// target robot's own frame (refused when the target is not connected).
    Waypoint {
        robot: u8,
        x_ref_m: f64,
        y_ref_m: f64,
    },
    SetParameter {
        robot: u8,
        name: String,
        value: protocol::message::ParamValue,
    },
    RequestResend {
        robot: u8,
        submap_index: u32,
    },
    StartRecording {
        robot: u8,
        label: String,
    },
    StopRecording {
        robot: u8,
    },
    /// Draw the team in this robot's frame.
    SetReference(u8),
    ReplaySeek(u64),
    ReplayPlay(bool),
    ReplaySpeed(f64),
}
