//! When a robot's graph took in each loop closure, from its logged graph inserts (see
//! `MapperNode::graph_inserts`): for the campaign's error-over-time pictures.
//!
//! Matches relate two maps, not a time, so a match is dated by the latest stamped measurement
//! inserted before it (the filter pose of the same graph update, within one camera period).

use mapper::slam::Measurement;

/// What joined the graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ClosureKind {
    /// A marker detection between two robots (by either of them).
    Detection,
    /// A submap match between two of one robot's submaps.
    IntraMatch,
    /// A submap match between two robots' submaps.
    InterMatch,
}

impl ClosureKind {
    pub fn name(self) -> &'static str {
        match self {
            ClosureKind::Detection => "detection",
            ClosureKind::IntraMatch => "intra-robot match",
            ClosureKind::InterMatch => "inter-robot match",
        }
    }
}

/// One loop closure taken into a robot's graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClosureEvent {
    pub stamp_ns: u64,
    pub kind: ClosureKind,
}

/// The loop closures among `inserts`, in insert order. Inserts before the first stamped one
/// carry no time and are left out (the graph starts with a filter pose, so there are none).
pub fn closure_events(inserts: &[(u64, Measurement)]) -> Vec<ClosureEvent> {
    let mut last_stamp_ns: Option<u64> = None;
    let mut events = Vec::new();
    for (_, m) in inserts {
        let kind = match m {
            Measurement::Detection(_) => Some(ClosureKind::Detection),
            Measurement::Match(found) if found.a.robot == found.b.robot => Some(ClosureKind::IntraMatch),
            Measurement::Match(_) => Some(ClosureKind::InterMatch),
            _ => None,
        };
        if let Some(stamp) = m.stamp_ns() {
            last_stamp_ns = Some(last_stamp_ns.map_or(stamp, |s| s.max(stamp)));
        }
        if let (Some(kind), Some(stamp_ns)) = (kind, last_stamp_ns) {
            events.push(ClosureEvent { stamp_ns, kind });
        }
    }
    events
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use mapper::slam::{FilterPose, RobotDetection, SubmapId, SubmapMatch};
    use nalgebra::{Isometry3, Matrix6};

    use super::*;

    fn pose(robot: u16, stamp_ns: u64) -> Measurement {
        Measurement::FilterPose(FilterPose {
            robot,
            stamp_ns,
            submap_index: 0,
            t_submap_body: Isometry3::identity(),
            covariance: Matrix6::identity(),
        })
    }

    fn matched(a: (u16, u32), b: (u16, u32)) -> Measurement {
        Measurement::Match(SubmapMatch {
            a: SubmapId::new(a.0, a.1),
            b: SubmapId::new(b.0, b.1),
            t_a_b: Isometry3::identity(),
            covariance: Matrix6::identity(),
        })
    }

    #[test]
    fn closures_are_dated_by_the_latest_stamp_before_them() {
        let detection = Measurement::Detection(RobotDetection {
            observer: 1,
            observed: 2,
            tag_id: 4,
            stamp_ns: 250,
            t_observer_observed: Isometry3::identity(),
            covariance: Matrix6::identity(),
        });
        let inserts = [
            (0, matched((1, 0), (1, 3))),
            (0, pose(1, 100)),
            (1, matched((1, 0), (1, 4))),
            (1, pose(2, 300)),
            (1, pose(1, 200)),
            (2, detection),
            (2, matched((1, 2), (2, 5))),
        ];
        let events = closure_events(&inserts);
        let got: Vec<(u64, ClosureKind)> = events.iter().map(|e| (e.stamp_ns, e.kind)).collect();
        assert_eq!(
            got,
            [(100, ClosureKind::IntraMatch), (300, ClosureKind::Detection), (300, ClosureKind::InterMatch),]
        );
    }
}
