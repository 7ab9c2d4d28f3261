//! SLAM exchange: loop-closure constraints, match-attempt records and finished submaps
//! (thesis §3.3, §5.2.1). All are delivered reliably and applied idempotently by their keys.

use heapless::Vec;
use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::geometry::{Cov6, Pose3};
use crate::ids::{NodeRef, RobotId, SubmapId};

/// Team-wide identity of a constraint: the robot that measured it and its running number there.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize, MaxSize)]
pub struct ConstraintId {
    pub robot: RobotId,
    pub seq: u32,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum ConstraintKind {
    /// Two submaps registered against each other (thesis §6.1).
    SubmapMatch,
    /// One robot observed another's AprilTag markers (thesis §6.2).
    RobotDetection,
    /// A robot observed a global landmark.
    LandmarkObservation,
}

/// A loop-closure measurement between two graph nodes: `t_from_to` with its covariance.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Constraint {
    pub id: ConstraintId,
    pub kind: ConstraintKind,
    pub stamp_ns: u64,
    pub from: NodeRef,
    pub to: NodeRef,
    pub t_from_to: Pose3,
    pub covariance: Cov6,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum MatchOutcome {
    /// The sender has started matching the pair; others skip it.
    Claimed,
    /// Tried and found no acceptable registration.
    Rejected,
    /// Tried and matched; the constraint is sent separately.
    Matched(ConstraintId),
}

/// A record that a submap pair was (or is being) tried, so every pair is tried once team-wide.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct MatchAttempt {
    /// The pair, ordered so that `first < second`.
    pub first: SubmapId,
    pub second: SubmapId,
    pub by: RobotId,
    pub outcome: MatchOutcome,
}

impl MatchAttempt {
    /// The pair in canonical order, whatever order the caller names them in.
    pub fn ordered_pair(a: SubmapId, b: SubmapId) -> (SubmapId, SubmapId) {
        if a <= b { (a, b) } else { (b, a) }
    }
}

/// The link of a submap to the one before it, as the wire carries it: the frame-switch transform
/// that started the submap (its origin in the previous submap's origin frame) with covariance (the
/// graph's chain factor, thesis §4.1.2). The filter's `FrameSwitch`, the bus's `FrameSwitchMsg`
/// and the graph's `SubmapSwitch` are the same event in the other layers.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct SubmapLink {
    pub t_previous_this: Pose3,
    pub covariance: Cov6,
}

/// How a submap's payload bytes are encoded (defined by the mapper).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct SubmapEncoding(pub u8);

/// Announces a finished submap; its payload follows in [`SubmapChunk`]s.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct SubmapHeader {
    pub submap: SubmapId,
    pub started_stamp_ns: u64,
    pub finished_stamp_ns: u64,
    /// `None` for a robot's first submap, which anchors its chain.
    pub switch: Option<SubmapLink>,
    pub encoding: SubmapEncoding,
    pub payload_bytes: u32,
    pub chunk_count: u16,
    /// CRC-32 (ISO-HDLC) of the whole payload, checked after reassembly.
    pub payload_crc32: u32,
}

/// Payload bytes per submap chunk: a chunk plus headers fits one 1200-byte UDP datagram.
pub const SUBMAP_CHUNK_BYTES: usize = 1024;

/// One piece of a finished submap's payload.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct SubmapChunk {
    pub submap: SubmapId,
    pub index: u16,
    pub data: Vec<u8, SUBMAP_CHUNK_BYTES>,
}
