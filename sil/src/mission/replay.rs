//! The thesis's back-end variants (§8.2.2, §8.3.2: filter only, single-robot, sequential
//! odometry topology) from one lockstep mission: each robot's mapper logs every graph insert,
//! and the log is replayed into a graph of each variant, updated in the same batches as the live
//! graph. The front-end (images, detections, matches) runs once; the variants differ only in
//! what their graph keeps and how it links the submaps.

use mapper::slam::{Measurement, RobotId, TeamGraphConfig, Topology};
use nalgebra::Isometry3;

use super::score::{self, TrajectoryScore};
use crate::slam_eval::{self, Variant};

/// The variants replayed, in report order.
pub const VARIANTS: [Variant; 4] = [
    Variant::Multi(Topology::LocalReference),
    Variant::Multi(Topology::SequentialOdometry),
    Variant::Single(Topology::LocalReference),
    Variant::FilterOnly,
];

/// One robot's online trajectory in one replayed variant.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayScore {
    pub variant: &'static str,
    pub score: Option<TrajectoryScore>,
    /// Why there is no score.
    pub error: Option<String>,
    pub nodes: usize,
    pub factors: usize,
}

/// Robot `own`'s `inserts` (see `MapperNode::graph_inserts`) replayed into every variant of
/// [`VARIANTS`] with the live graph's `config`, each scored against `truth` (own frame).
pub fn replay_variants(
    own: RobotId,
    config: &TeamGraphConfig,
    inserts: &[(u64, Measurement)],
    truth: Option<&[(u64, Isometry3<f64>)]>,
) -> Vec<ReplayScore> {
    VARIANTS
        .iter()
        .map(|&variant| {
            let graph = match slam_eval::replay(own, config.clone(), inserts, variant) {
                Ok(graph) => graph,
                Err(e) => {
                    return ReplayScore {
                        variant: variant.name(),
                        score: None,
                        error: Some(e.to_string()),
                        nodes: 0,
                        factors: 0,
                    };
                }
            };
            let size = graph.size();
            let (score, error) = match truth.map(|truth| score::score(graph.online_log(), truth)) {
                Some(Ok(s)) => (Some(s), None),
                Some(Err(e)) => (None, Some(e.to_string())),
                None => (None, Some("the filter never initialized".to_owned())),
            };
            ReplayScore { variant: variant.name(), score, error, nodes: size.nodes, factors: size.factors }
        })
        .collect()
}
