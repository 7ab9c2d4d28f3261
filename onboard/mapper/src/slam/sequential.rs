//! The sequential-odometry baseline (thesis §4.2.2, eqs. 4.8–4.9): each robot's graph nodes
//! (submap origins and robot poses) chained in time by the filter's relative motion, with the
//! difference of the filter's covariances as the motion's covariance.
//!
//! The thesis argues this is wrong for a keyframe filter (its estimates are not independent
//! increments) and measured 15 % higher errors (Table 8.6); it is here to repeat that comparison.
//! The chain only grows at its end: a measurement older than the chain's last node cannot be
//! inserted without removing a factor, so it is dropped (the thesis delayed both graphs by 2 s to
//! give the baseline chronological input).

use nalgebra::{Isometry3, Matrix6};

use super::covariance;
use super::ids::{NodeId, RobotId, SubmapId};
use super::measurements::{FilterPose, SubmapSwitch};

/// A node on a robot's chain, with the filter's pose of it in the submap active then.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ChainNode {
    pub node: NodeId,
    pub stamp_ns: u64,
    pub submap_index: u32,
    pub t_submap_node: Isometry3<f64>,
    /// Graph convention; zero for a submap origin in its own frame.
    pub covariance: Matrix6<f64>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ChainError {
    /// Older than the chain's end, or in another submap than the chain's end.
    OutOfOrder,
}

/// One robot's chain.
#[derive(Debug, Clone)]
pub(crate) struct Chain {
    nodes: Vec<ChainNode>,
}

type Link = (NodeId, Isometry3<f64>, Matrix6<f64>);

impl Chain {
    /// A chain starting at the robot's first submap origin.
    pub fn new(robot: RobotId) -> Self {
        Chain {
            nodes: vec![ChainNode {
                node: NodeId::Submap(SubmapId::new(robot, 0)),
                stamp_ns: 0,
                submap_index: 0,
                t_submap_node: Isometry3::identity(),
                covariance: Matrix6::zeros(),
            }],
        }
    }

    fn end(&self) -> &ChainNode {
        // The chain is created with its first node and never shrinks.
        &self.nodes[self.nodes.len() - 1]
    }

    pub fn end_submap(&self) -> u32 {
        self.end().submap_index
    }

    /// The latest node of submap `submap_index` at or before `stamp_ns`.
    pub fn latest_at(&self, submap_index: u32, stamp_ns: u64) -> Option<&ChainNode> {
        self.nodes.iter().rev().find(|n| n.submap_index == submap_index && n.stamp_ns <= stamp_ns)
    }

    /// Eq. 4.8/4.9 from the chain's end to a robot pose; returns the factor (from, measured, cov).
    pub fn append_pose(&mut self, node: NodeId, pose: &FilterPose, floor: f64) -> Result<Link, ChainError> {
        let end = *self.end();
        if pose.submap_index != end.submap_index || pose.stamp_ns < end.stamp_ns {
            return Err(ChainError::OutOfOrder);
        }
        let measured = end.t_submap_node.inverse() * pose.t_submap_body;
        let cov = covariance::clamp_eigenvalues(&(pose.covariance - end.covariance), floor);
        self.nodes.push(ChainNode {
            node,
            stamp_ns: pose.stamp_ns,
            submap_index: pose.submap_index,
            t_submap_node: pose.t_submap_body,
            covariance: pose.covariance,
        });
        Ok((end.node, measured, cov))
    }

    /// From the chain's end to the next submap origin (the frame switch).
    pub fn append_switch(&mut self, switch: &SubmapSwitch, floor: f64) -> Result<Link, ChainError> {
        let end = *self.end();
        if switch.from_index != end.submap_index || switch.stamp_ns < end.stamp_ns {
            return Err(ChainError::OutOfOrder);
        }
        let measured = end.t_submap_node.inverse() * switch.t_old_new;
        let cov = covariance::clamp_eigenvalues(&(switch.covariance - end.covariance), floor);
        self.nodes.push(ChainNode {
            node: NodeId::Submap(switch.to()),
            stamp_ns: switch.stamp_ns,
            submap_index: switch.from_index + 1,
            t_submap_node: Isometry3::identity(),
            covariance: Matrix6::zeros(),
        });
        Ok((end.node, measured, cov))
    }
}
