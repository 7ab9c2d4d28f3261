//! What the front-end consumes: the messages the robots exchange (thesis §3.3's list), each with an
//! identity so that receiving it twice changes nothing (store-and-forward links may repeat).
//!
//! All covariances are in the graph convention (see [`super::covariance`]).

use nalgebra::{Isometry3, Matrix6};

use super::ids::{RobotId, SubmapId, SubmapPair};

/// A submap switch of `robot`, the graph's view of its filter's frame switch (thesis §3.4):
/// submap `from_index + 1` starts at `stamp_ns`; `t_old_new` is its origin in submap
/// `from_index`'s frame (x, y, z, yaw, roll = pitch = 0, with an IMU; in full 6-DoF from a robot
/// without one, whose odometry chain has no gravity to level against).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubmapSwitch {
    pub robot: RobotId,
    pub stamp_ns: u64,
    pub from_index: u32,
    pub t_old_new: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

impl SubmapSwitch {
    pub fn from(&self) -> SubmapId {
        SubmapId::new(self.robot, self.from_index)
    }

    pub fn to(&self) -> SubmapId {
        SubmapId::new(self.robot, self.from_index + 1)
    }
}

/// The filter's estimate of `robot`'s body at `stamp_ns` in submap `submap_index`'s frame (the
/// frame active then): the thesis's `v`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterPose {
    pub robot: RobotId,
    pub stamp_ns: u64,
    pub submap_index: u32,
    pub t_submap_body: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

/// Robot `observer` saw marker `tag_id` of robot `observed` in its image of `stamp_ns`; eq. 4.7
/// gives the observed body in the observer's body frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobotDetection {
    pub observer: RobotId,
    pub observed: RobotId,
    pub tag_id: u32,
    pub stamp_ns: u64,
    pub t_observer_observed: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

/// `robot` saw the static landmark `landmark` (e.g. a marker on the lander) at `stamp_ns`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LandmarkObservation {
    pub robot: RobotId,
    pub landmark: u32,
    pub stamp_ns: u64,
    pub t_body_landmark: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

/// The matcher aligned submap `b` to submap `a`: `t_a_b` is `b`'s origin in `a`'s frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SubmapMatch {
    pub a: SubmapId,
    pub b: SubmapId,
    pub t_a_b: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

impl SubmapMatch {
    pub fn pair(&self) -> SubmapPair {
        SubmapPair::new(self.a, self.b)
    }
}

/// A matcher on robot `by` tried `pair` (successful matches also arrive as [`SubmapMatch`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MatchAttempt {
    pub pair: SubmapPair,
    pub by: RobotId,
    pub outcome: super::ledger::AttemptOutcome,
}

/// Any input of the front-end, for queues and links that carry all kinds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Measurement {
    SubmapSwitch(SubmapSwitch),
    FilterPose(FilterPose),
    Detection(RobotDetection),
    Landmark(LandmarkObservation),
    Match(SubmapMatch),
    Attempt(MatchAttempt),
}

impl Measurement {
    /// The time the measurement refers to, if it refers to one (matches relate maps, not times).
    pub fn stamp_ns(&self) -> Option<u64> {
        match self {
            Measurement::SubmapSwitch(m) => Some(m.stamp_ns),
            Measurement::FilterPose(m) => Some(m.stamp_ns),
            Measurement::Detection(m) => Some(m.stamp_ns),
            Measurement::Landmark(m) => Some(m.stamp_ns),
            Measurement::Match(_) | Measurement::Attempt(_) => None,
        }
    }
}
