//! What the front-end reports after every update: where every robot and submap is in the own
//! frame, which robots are connected to it, and how big the graph is.

use std::collections::BTreeMap;

use nalgebra::Isometry3;

use super::graph::{FactorClass, TeamGraph};
use super::ids::{NodeId, RobotId, SubmapId};

/// One robot as the own graph sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotStatus {
    pub robot: RobotId,
    /// A chain of constraints links the robot's data to the own first submap. An unconnected
    /// robot has no pose in the own frame: its data is kept, not placed.
    pub connected: bool,
    /// Submaps referenced by any measurement, and how many of them are connected.
    pub submaps_known: usize,
    pub submaps_connected: usize,
    /// Its latest buffered filter pose (stamp) in the own frame by eq. 4.6, when connected.
    pub latest: Option<(u64, Isometry3<f64>)>,
}

/// Poses of all connected submaps and robots in the own frame.
#[derive(Debug, Clone, PartialEq)]
pub struct TeamEstimate {
    pub own: RobotId,
    pub submaps: Vec<(SubmapId, Isometry3<f64>)>,
    pub robots: Vec<RobotStatus>,
}

impl TeamEstimate {
    /// The robots connected to the own frame (the own robot included).
    pub fn connected_robots(&self) -> Vec<RobotId> {
        self.robots.iter().filter(|r| r.connected).map(|r| r.robot).collect()
    }

    pub fn submap_pose(&self, id: SubmapId) -> Option<Isometry3<f64>> {
        self.submaps.iter().find(|(s, _)| *s == id).map(|(_, p)| *p)
    }
}

/// Size of the optimized graph, by kind (thesis Tables 8.7–8.9).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct GraphSize {
    /// Variables and factors in the optimizer.
    pub nodes: usize,
    pub factors: usize,
    /// Connected submap origins and robot-pose nodes per robot.
    pub submaps: BTreeMap<RobotId, usize>,
    pub robot_poses: BTreeMap<RobotId, usize>,
    pub landmarks: usize,
    pub priors: usize,
    pub switch_factors: usize,
    pub filter_pose_factors: usize,
    pub sequential_factors: usize,
    pub detections: usize,
    pub matches: usize,
    pub landmark_observations: usize,
}

impl GraphSize {
    /// The thesis's accounting (spec §3.5, derived from Tables 8.7–8.9) from the per-kind
    /// counts: `nodes = Σ S_r + Σ X_r + L`, `factors = 1 + Σ (S_r − 1) + Σ X_r + D + C + O`.
    /// For the sequential topology the chain replaces `w` and `v`: `1 + Σ (S_r + X_r − 1) + D + C + O`
    /// (the same number).
    pub fn thesis_formula(&self) -> (usize, usize) {
        let s: usize = self.submaps.values().sum();
        let x: usize = self.robot_poses.values().sum();
        let chains: usize = self.submaps.values().map(|n| n.saturating_sub(1)).sum();
        let nodes = s + x + self.landmarks;
        let factors = 1 + chains + x + self.detections + self.matches + self.landmark_observations;
        (nodes, factors)
    }
}

impl TeamGraph {
    /// The current estimate (call after [`TeamGraph::update`]).
    pub fn estimate(&self) -> TeamEstimate {
        let estimates = self.estimates();
        let submaps: Vec<(SubmapId, Isometry3<f64>)> = estimates
            .iter()
            .filter_map(|(node, pose)| if let NodeId::Submap(id) = node { Some((*id, *pose)) } else { None })
            .collect();
        let mut robots: BTreeMap<RobotId, RobotStatus> = BTreeMap::new();
        for id in self.submaps.keys() {
            let status = robots.entry(id.robot).or_insert_with(|| RobotStatus {
                robot: id.robot,
                connected: false,
                submaps_known: 0,
                submaps_connected: 0,
                latest: None,
            });
            status.submaps_known += 1;
            if estimates.contains_key(&NodeId::Submap(*id)) {
                status.submaps_connected += 1;
                status.connected = true;
            }
        }
        for status in robots.values_mut() {
            status.latest = self
                .pose_buffer(status.robot)
                .and_then(|b| b.latest())
                .and_then(|p| self.online_pose(p).map(|pose| (p.stamp_ns, pose)));
        }
        TeamEstimate { own: self.own(), submaps, robots: robots.into_values().collect() }
    }

    /// The graph's size by kind (only what is in the optimizer).
    pub fn size(&self) -> GraphSize {
        let mut size = GraphSize {
            nodes: self.optimizer().num_variables(),
            factors: self.optimizer().factors().len(),
            ..Default::default()
        };
        for node in self.keys.keys() {
            match node {
                NodeId::Submap(id) => *size.submaps.entry(id.robot).or_default() += 1,
                NodeId::Pose(id) => *size.robot_poses.entry(id.robot).or_default() += 1,
                NodeId::Landmark(_) => size.landmarks += 1,
            }
        }
        for f in self.factors.iter().filter(|f| f.inserted) {
            match f.class {
                FactorClass::Prior => size.priors += 1,
                FactorClass::Switch => size.switch_factors += 1,
                FactorClass::FilterPose => size.filter_pose_factors += 1,
                FactorClass::Sequential => size.sequential_factors += 1,
                FactorClass::Detection => size.detections += 1,
                FactorClass::Match => size.matches += 1,
                FactorClass::Landmark => size.landmark_observations += 1,
            }
        }
        size
    }
}
