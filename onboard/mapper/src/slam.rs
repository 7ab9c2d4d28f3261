//! The multi-robot SLAM front-end (thesis §3.3, §4.2.2–4.2.3, §5.2): what goes into each robot's
//! pose graph, when, and what comes out.
//!
//! Every robot keeps **one graph for the whole team, in its own global frame**: a prior holds its
//! own first submap origin at zero; there is no shared frame. [`TeamGraph`] takes the measurements
//! of all robots as they arrive, in any order and however late:
//!
//! | input | graph |
//! |---|---|
//! | [`SubmapSwitch`] (filter frame switch `w`) | submap origin `s_{j+1}` and factor `s_j → s_{j+1}` |
//! | [`FilterPose`] (filter pose `v` in the active submap) | buffered by stamp; becomes a factor `s_j → x` only when a measurement needs `x` |
//! | [`RobotDetection`] (eq. 4.7) | robot poses `x` of both robots at the image stamp, factor `x → x` (Cauchy) |
//! | [`LandmarkObservation`] | landmark node, factor `x → l` (Cauchy) |
//! | [`SubmapMatch`] | factor `s → s` (Cauchy) |
//! | [`MatchAttempt`] | the team-wide [`MatchLedger`] (every pair tried at most once) |
//!
//! Beyond the thesis, inter-robot closures (detections between two robots, matches between two
//! robots' submaps) can be screened by pairwise consistency maximization before they enter the
//! graph ([`ConsistencyCheck::Pcm`], module [`consistency`]; off by default, the thesis's graph).
//!
//! Two topologies ([`Topology`]): the thesis's local-reference topology, where robot poses hang
//! off the submap origin they were estimated in and are never chained (so data can be inserted at
//! any time), and, for comparison, the sequential-odometry topology it improves on (robot poses
//! chained in time with covariance differences, eqs. 4.8–4.9), which needs chronological input.
//!
//! Components that are not connected to the own first submap (another robot before any detection
//! or match links it) are **held back** (trap 7): they are kept, complete, and inserted into the
//! incremental optimizer at the moment a constraint connects them. [`TeamEstimate`] says which
//! robots are connected; an unconnected robot has no pose in the own frame, and none is invented.
//!
//! # Conventions
//!
//! Poses `t_a_b` map b-coordinates into a. Covariances of graph measurements use the `posegraph`
//! convention: tangent `[translation, rotation]`, perturbation on the right (`T·Exp(δ)`), i.e. in
//! the frame of the measured pose. The filter reports translation errors in its local frame;
//! [`covariance::from_filter`] converts (trap 6). Stamps are `u64` nanoseconds of the team's
//! synchronized clock (thesis §4.3.2 assumes synchronized clocks).

mod clique;
pub mod consistency;
pub mod covariance;
mod estimate;
mod graph;
mod ids;
mod ledger;
pub mod markers;
mod measurements;
mod odometry_paths;
mod pose_buffer;
mod sequential;

pub use consistency::{ClosureKey, ClosureStatus, ConsistencyCheck, ConsistencyStats, PcmParams};
pub use estimate::{GraphSize, RobotStatus, TeamEstimate};
pub use graph::{InsertOutcome, SlamError, TeamGraph, TeamGraphConfig, Topology};
pub use ids::{NodeId, PoseId, RobotId, SubmapId, SubmapPair};
pub use ledger::{AttemptOutcome, MatchLedger};
pub use markers::{MarkerObservation, TagOwner, TeamMarkers};
pub use measurements::{
    FilterPose, LandmarkObservation, MatchAttempt, Measurement, RobotDetection, SubmapMatch, SubmapSwitch,
};
pub use pose_buffer::{FramePose, PoseBuffer, SameStamp, StampedPose, interpolate_pose};
