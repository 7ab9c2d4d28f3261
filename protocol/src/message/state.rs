//! Robot state: pose estimates, heartbeats and telemetry (latest-wins messages).

use heapless::{String, Vec};
use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::geometry::{Cov6, Pose3};
use crate::ids::{NodeId, RobotId, SubmapId};

/// Operating mode of a robot, as reported in telemetry and set by commands.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum Mode {
    /// Powered, estimating, not moving on its own.
    Idle,
    /// Driving to an operator-given waypoint.
    Waypoint,
    /// Exploring on its own.
    Autonomous,
    /// Driven by an operator.
    Teleoperated,
    /// Stopped after a fault or an operator stop; leaves only by command.
    Safe,
}

/// A robot's local pose estimate: its body pose in the frame of the submap it is mapping into
/// (the `v` factor of the thesis's graph topology, §4.2.2).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct PoseEstimate {
    pub robot: RobotId,
    /// Capture time of the estimate on the robot's clock, ns.
    pub stamp_ns: u64,
    /// The submap whose origin is the reference frame of `t_submap_body`.
    pub submap: SubmapId,
    pub t_submap_body: Pose3,
    pub covariance: Cov6,
}

/// Liveness of a node, sent at a low fixed rate whether anything else is sent or not.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct Heartbeat {
    pub node: NodeId,
    pub stamp_ns: u64,
    pub uptime_ms: u64,
    /// Random per boot: a changed value tells peers that the node restarted.
    pub boot_id: u32,
    pub mode: Mode,
}

/// Health of the local reference filter.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum FilterStatus {
    Initializing,
    Nominal,
    /// Running on a subset of its sensors (e.g. no visual odometry for a while).
    Degraded,
    /// Innovation checks failed persistently; the estimate must not be trusted.
    Diverged,
}

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct FilterHealth {
    pub status: FilterStatus,
    /// Square root of the largest position variance in the current local frame, m.
    pub position_std_m: f32,
    pub yaw_std_rad: f32,
    /// Age of the last accepted visual-odometry update, ms (`u32::MAX`: never).
    pub vo_age_ms: u32,
}

/// Which of the robot's devices deliver (v3): what its sensor driver reports.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct SensorAvailability {
    pub imu: bool,
    pub wheels: bool,
    pub head: bool,
}

/// Name of a task, queue or link in telemetry.
pub type Label = String<12>;

/// Timing of one fixed-rate task since its start.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct TaskStats {
    pub task: Label,
    pub period_us: u32,
    pub releases: u32,
    pub deadline_overruns: u32,
    /// Release jitter (actual minus planned release), 99th percentile and maximum, µs.
    pub jitter_p99_us: u32,
    pub jitter_max_us: u32,
}

/// Fill level of a bounded queue.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct QueueStats {
    pub queue: Label,
    pub depth: u16,
    pub capacity: u16,
    /// Items dropped by the queue's overflow policy since start.
    pub dropped: u32,
}

/// Counters of one link, as seen by the sender of the telemetry.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct LinkStats {
    pub link: Label,
    pub tx_bytes: u64,
    pub rx_bytes: u64,
    pub tx_rate_bps: u32,
    pub rx_rate_bps: u32,
    pub retransmissions: u32,
    /// Packets rejected by the decoder or the authenticator.
    pub rejected: u32,
    /// Estimated loss over the last window, per mille.
    pub loss_permille: u16,
    /// Smoothed round-trip time, ms (`u32::MAX`: unknown).
    pub rtt_ms: u32,
    pub outages: u32,
}

/// CPU and memory of the compute board.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct ResourceUsage {
    /// Load over all cores, per mille of the board's capacity.
    pub cpu_permille: u16,
    pub mem_used_kib: u32,
    pub mem_total_kib: u32,
}

pub const MAX_TASKS: usize = 8;
pub const MAX_QUEUES: usize = 8;
pub const MAX_LINKS: usize = 4;
/// Message classes in [`Telemetry::classes`]: every type of the protocol with room to grow.
pub const MAX_CLASSES: usize = 12;

/// What the sender put on its links for one message class since its start (all links summed,
/// retransmissions included), so the ground station can plot bytes per second per class.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct ClassBytes {
    /// The class's `MessageKey` (`0x11` = `Telemetry`, …).
    pub message_key: u8,
    /// Cumulative wire bytes (framing included), as the link's rate cap charges them.
    pub tx_bytes: u64,
    /// Cumulative packets; saturates at `u32::MAX`.
    pub tx_packets: u32,
}

/// A robot's periodic health report to the ground station.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Telemetry {
    pub robot: RobotId,
    pub stamp_ns: u64,
    pub mode: Mode,
    pub filter: FilterHealth,
    pub resources: ResourceUsage,
    pub tasks: Vec<TaskStats, MAX_TASKS>,
    pub queues: Vec<QueueStats, MAX_QUEUES>,
    pub links: Vec<LinkStats, MAX_LINKS>,
    /// Uplink commands rejected as forged, corrupted or replayed since start.
    pub auth_rejections: u32,
    /// Bytes sent per message class (v2), in ascending key order.
    pub classes: Vec<ClassBytes, MAX_CLASSES>,
    /// The devices' availability (v3); `None` when the sensors are not devices (a dataset
    /// replay, the simulator in memory) or the driver has not reported yet.
    pub sensors: Option<SensorAvailability>,
}
