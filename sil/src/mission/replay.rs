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
            let (score, error) = match truth.map(|truth| score::score(&online_stream(graph.online_log()), truth)) {
                Some(Ok(s)) => (Some(s), None),
                Some(Err(e)) => (None, Some(e.to_string())),
                None => (None, Some("the filter never initialized".to_owned())),
            };
            ReplayScore { variant: variant.name(), score, error, nodes: size.nodes, factors: size.factors }
        })
        .collect()
}

/// A replayed graph's online log as a stream in time. The mapper inserts its own pose at a
/// detection's image stamp when that pose is not in the graph yet; such a pose, older than poses
/// inserted before it, was not the robot's online estimate at its time (the live mapper's online
/// trajectory never holds it) and is left out.
fn online_stream(log: &[(u64, Isometry3<f64>)]) -> Vec<(u64, Isometry3<f64>)> {
    let mut stream: Vec<(u64, Isometry3<f64>)> = Vec::with_capacity(log.len());
    for &(stamp_ns, pose) in log {
        if stream.last().is_none_or(|&(last, _)| stamp_ns > last) {
            stream.push((stamp_ns, pose));
        }
    }
    stream
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn late_poses_for_older_stamps_leave_the_stream() {
        let at = |x: f64| Isometry3::translation(x, 0.0, 0.0);
        let log = [(100, at(1.0)), (200, at(2.0)), (150, at(1.5)), (200, at(2.1)), (300, at(3.0))];
        let stream = online_stream(&log);
        let stamps: Vec<u64> = stream.iter().map(|(s, _)| *s).collect();
        assert_eq!(stamps, [100, 200, 300]);
        assert_eq!(stream[1].1, at(2.0));
    }
}
