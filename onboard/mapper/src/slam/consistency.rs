//! Pairwise consistency maximization (PCM, Mangelson et al. 2018) for inter-robot loop closures:
//! beyond the thesis, which puts every closure straight into the graph behind a Cauchy kernel.
//!
//! For each pair of robots `(r, s)`, two closures `z_i = T(a_i → b_i)` and `z_k = T(a_k → b_k)`
//! (`a` nodes of `r`, `b` nodes of `s`) are **pairwise consistent** when the loop
//!
//! `z_i · P_s(b_i → b_k) · z_k⁻¹ · P_r(a_k → a_i)`
//!
//! is close to identity: its logarithm's squared Mahalanobis distance under the loop's covariance
//! (both closures' and both odometry paths' covariances, propagated to first order; paths from
//! [`super::odometry_paths`]) is below [`PcmParams::max_mahalanobis_sq`]. The closures that enter
//! the graph are a **maximum clique** of the pair's consistency graph ([`super::clique`]), and only
//! once it has [`PcmParams::min_clique_size`] members: one closure alone cannot be checked.
//!
//! The clique is recomputed whenever the pair has a new closure or a pairwise test that could not
//! be decided before (a switch was missing) can be now. Closures that join the clique enter the
//! graph then; closures that leave it are withdrawn, which the graph does by rebuilding its
//! optimizer without them (the incremental solver cannot remove factors). Among cliques of equal
//! size the one holding the closures accepted so far wins, so the accepted set does not flip
//! between equally good answers.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix6};
use posegraph::se3;

use super::clique::{Adjacency, max_clique};
use super::ids::{NodeId, RobotId, SubmapPair};
use super::odometry_paths::{OdometryPaths, Uncertain, compose, invert};

/// How inter-robot loop closures (detections between two robots, matches between two robots'
/// submaps) are screened before they enter the graph. Intra-robot matches, landmark
/// observations and odometry are never screened.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ConsistencyCheck {
    /// The thesis: every closure enters the graph at once, behind the Cauchy kernel.
    None,
    /// Pairwise consistency maximization, then the Cauchy kernel as well.
    Pcm(PcmParams),
}

/// PCM parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PcmParams {
    /// Two closures are consistent when the loop's squared Mahalanobis distance is below this.
    /// 16.81 is the χ² quantile of 6 DoF at 0.99: a consistent pair with Gaussian errors fails
    /// the test 1 % of the time, which costs a clique one member at worst.
    pub max_mahalanobis_sq: f64,
    /// A robot pair's closures enter the graph once this many are mutually consistent. 2: a
    /// single closure cannot be checked against anything, and a confidently wrong first closure
    /// would otherwise place the other robot wrongly until the second arrives.
    pub min_clique_size: usize,
    /// The exact clique search runs up to this many closures per robot pair; above, the greedy
    /// heuristic (tens of closures per pair in the thesis's missions, far below it).
    pub exact_max_closures: usize,
}

impl Default for PcmParams {
    fn default() -> Self {
        PcmParams { max_mahalanobis_sq: 16.81, min_clique_size: 2, exact_max_closures: 128 }
    }
}

/// What an inter-robot closure is, by the identity its measurement has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum ClosureKey {
    Detection { observer: RobotId, observed: RobotId, stamp_ns: u64, tag_id: u32 },
    Match(SubmapPair),
}

/// An inter-robot closure and whether it is in the graph's accepted set.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClosureStatus {
    pub key: ClosureKey,
    pub accepted: bool,
}

/// Counts over all robot pairs.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ConsistencyStats {
    /// Inter-robot closures screened.
    pub closures: usize,
    /// In the current maximum cliques (they are, or will be at the next update, in the graph).
    pub accepted: usize,
    /// Accepted closures withdrawn later (each withdrawal rebuilt the optimizer).
    pub withdrawn: usize,
}

/// One closure, oriented from the lower robot id to the higher.
#[derive(Debug, Clone)]
struct Closure {
    key: ClosureKey,
    /// Index into the graph's factor list.
    factor: usize,
    from: NodeId,
    to: NodeId,
    measured: Uncertain,
}

#[derive(Debug, Clone, Default)]
struct PairState {
    closures: Vec<Closure>,
    /// Decided pairwise tests `(i, k)`, `i < k`; undecided ones (a path not known yet) are absent.
    consistent: BTreeMap<(usize, usize), bool>,
    accepted: Vec<bool>,
    /// Something may have changed since the last clique.
    dirty: bool,
}

/// What an evaluation changed, as factor indices.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub(crate) struct Decision {
    pub accept: Vec<usize>,
    pub withdraw: Vec<usize>,
}

/// The screening state of one graph.
#[derive(Debug, Clone)]
pub(crate) struct Pcm {
    params: PcmParams,
    pairs: BTreeMap<(RobotId, RobotId), PairState>,
    withdrawn: usize,
}

fn robot_of(node: NodeId) -> Option<RobotId> {
    match node {
        NodeId::Submap(id) => Some(id.robot),
        NodeId::Pose(id) => Some(id.robot),
        NodeId::Landmark(_) => None,
    }
}

/// Whether a factor between these nodes is an inter-robot closure.
pub(crate) fn is_inter_robot(from: NodeId, to: NodeId) -> bool {
    matches!((robot_of(from), robot_of(to)), (Some(a), Some(b)) if a != b)
}

impl Pcm {
    pub fn new(params: PcmParams) -> Self {
        Pcm { params, pairs: BTreeMap::new(), withdrawn: 0 }
    }

    /// Registers an inter-robot closure (factor `factor`, `t_from_to` measured); ignored if the
    /// nodes are not of two robots.
    pub fn add(
        &mut self,
        key: ClosureKey,
        factor: usize,
        from: NodeId,
        to: NodeId,
        t_from_to: Isometry3<f64>,
        covariance: Matrix6<f64>,
    ) {
        let (Some(ra), Some(rb)) = (robot_of(from), robot_of(to)) else {
            return;
        };
        if ra == rb {
            return;
        }
        let closure = if ra < rb {
            Closure { key, factor, from, to, measured: (t_from_to, covariance) }
        } else {
            Closure { key, factor, from: to, to: from, measured: invert(&(t_from_to, covariance)) }
        };
        let pair = self.pairs.entry((ra.min(rb), ra.max(rb))).or_default();
        pair.closures.push(closure);
        pair.accepted.push(false);
        pair.dirty = true;
    }

    /// New odometry of `robot` arrived: undecided tests of its pairs may be decidable now.
    pub fn odometry_changed(&mut self, robot: RobotId) {
        for ((a, b), pair) in &mut self.pairs {
            let complete = pair.consistent.len() == pair.closures.len() * pair.closures.len().saturating_sub(1) / 2;
            if (*a == robot || *b == robot) && !complete {
                pair.dirty = true;
            }
        }
    }

    /// Re-tests the changed robot pairs and returns the closures that joined or left their
    /// pair's accepted set.
    pub fn evaluate(&mut self, paths: &OdometryPaths<'_>) -> Decision {
        let mut decision = Decision::default();
        let params = self.params;
        for pair in self.pairs.values_mut().filter(|p| p.dirty) {
            pair.dirty = false;
            let n = pair.closures.len();
            for k in 0..n {
                for i in 0..k {
                    if pair.consistent.contains_key(&(i, k)) {
                        continue;
                    }
                    if let Some(d2) = loop_mahalanobis_sq(&pair.closures[i], &pair.closures[k], paths) {
                        pair.consistent.insert((i, k), d2 <= params.max_mahalanobis_sq);
                    }
                }
            }
            let mut graph = Adjacency::new(n);
            for (&(i, k), &ok) in &pair.consistent {
                if ok {
                    graph.connect(i, k);
                }
            }
            // Accepted closures first, then arrival order: ties keep what the graph holds.
            let order: Vec<usize> =
                (0..n).filter(|&i| pair.accepted[i]).chain((0..n).filter(|&i| !pair.accepted[i])).collect();
            let clique = max_clique(&graph, &order, params.exact_max_closures);
            let mut now = vec![false; n];
            if clique.len() >= params.min_clique_size {
                for &i in &clique {
                    now[i] = true;
                }
            }
            for ((closure, &was), &is) in pair.closures.iter().zip(&pair.accepted).zip(&now) {
                match (was, is) {
                    (false, true) => decision.accept.push(closure.factor),
                    (true, false) => {
                        decision.withdraw.push(closure.factor);
                        self.withdrawn += 1;
                    }
                    _ => {}
                }
            }
            pair.accepted = now;
        }
        decision
    }

    pub fn stats(&self) -> ConsistencyStats {
        let closures = self.pairs.values().map(|p| p.closures.len()).sum();
        let accepted = self.pairs.values().map(|p| p.accepted.iter().filter(|a| **a).count()).sum();
        ConsistencyStats { closures, accepted, withdrawn: self.withdrawn }
    }

    pub fn closures(&self) -> Vec<ClosureStatus> {
        self.pairs
            .values()
            .flat_map(|p| {
                p.closures.iter().zip(&p.accepted).map(|(c, &accepted)| ClosureStatus { key: c.key, accepted })
            })
            .collect()
    }

    /// Whether factor `factor` is a screened closure outside its accepted set.
    pub fn is_held(&self, factor: usize) -> bool {
        self.pairs.values().any(|p| p.closures.iter().zip(&p.accepted).any(|(c, &a)| c.factor == factor && !a))
    }
}

/// The squared Mahalanobis distance of the loop `z_i · P_s(b_i → b_k) · z_k⁻¹ · P_r(a_k → a_i)`
/// from identity; `None` while a path is unknown.
fn loop_mahalanobis_sq(i: &Closure, k: &Closure, paths: &OdometryPaths<'_>) -> Option<f64> {
    let path_s = paths.relative(i.to, k.to)?;
    let path_r = paths.relative(k.from, i.from)?;
    let (t_loop, covariance) = compose(&compose(&compose(&i.measured, &path_s), &invert(&k.measured)), &path_r);
    let error = se3::log(&t_loop);
    let information = covariance.try_inverse()?;
    let d2 = (error.transpose() * information * error)[(0, 0)];
    d2.is_finite().then_some(d2)
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion, Vector6};

    use super::super::ids::{PoseId, SubmapId};
    use super::super::measurements::{FilterPose, SubmapSwitch};
    use super::*;

    fn pose(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::new(x, y, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw))
    }

    fn diag(t: f64, r: f64) -> Matrix6<f64> {
        Matrix6::from_diagonal(&Vector6::new(t * t, t * t, t * t, r * r, r * r, r * r))
    }

    /// Two robots driving straight lines in a shared world, each with submaps every 5 m;
    /// `truth(robot, index)` is submap `index`'s origin in the world.
    struct World {
        switches: BTreeMap<SubmapId, SubmapSwitch>,
        poses: BTreeMap<PoseId, FilterPose>,
    }

    fn truth(robot: RobotId, index: u32) -> Isometry3<f64> {
        let start = if robot == 1 { pose(0.0, 0.0, 0.0) } else { pose(3.0, 4.0, 0.5) };
        start * pose(5.0 * f64::from(index), 0.0, 0.0)
    }

    fn world() -> World {
        let mut switches = BTreeMap::new();
        for robot in [1u16, 2] {
            for index in 1..8 {
                let switch = SubmapSwitch {
                    robot,
                    stamp_ns: u64::from(index) * 1_000_000_000,
                    from_index: index - 1,
                    t_old_new: truth(robot, index - 1).inverse() * truth(robot, index),
                    covariance: diag(0.05, 0.01),
                };
                switches.insert(switch.to(), switch);
            }
        }
        World { switches, poses: BTreeMap::new() }
    }

    fn paths(w: &World) -> OdometryPaths<'_> {
        OdometryPaths { switches: &w.switches, poses: &w.poses, min_variance: 1e-8 }
    }

    fn submap(robot: RobotId, index: u32) -> NodeId {
        NodeId::Submap(SubmapId::new(robot, index))
    }

    /// Robot 1's submap `a` to robot 2's submap `b`, the true relative pose times `error`.
    fn add_match(pcm: &mut Pcm, factor: usize, a: u32, b: u32, error: Isometry3<f64>) {
        let t = truth(1, a).inverse() * truth(2, b) * error;
        let key = ClosureKey::Match(SubmapPair::new(SubmapId::new(1, a), SubmapId::new(2, b)));
        pcm.add(key, factor, submap(1, a), submap(2, b), t, diag(0.1, 0.02));
    }

    #[test]
    fn a_consistent_set_is_accepted_whole() {
        let w = world();
        let mut pcm = Pcm::new(PcmParams::default());
        add_match(&mut pcm, 10, 1, 2, pose(0.05, -0.03, 0.01));
        assert_eq!(pcm.evaluate(&paths(&w)), Decision::default(), "one closure alone waits");
        add_match(&mut pcm, 11, 4, 3, pose(-0.04, 0.02, -0.01));
        add_match(&mut pcm, 12, 6, 7, Isometry3::identity());
        let decision = pcm.evaluate(&paths(&w));
        assert_eq!(decision.accept, vec![10, 11, 12]);
        assert!(decision.withdraw.is_empty());
        assert_eq!(pcm.stats(), ConsistencyStats { closures: 3, accepted: 3, withdrawn: 0 });
    }

    #[test]
    fn injected_outliers_are_rejected() {
        let w = world();
        let mut pcm = Pcm::new(PcmParams::default());
        let genuine = [(1, 1), (2, 3), (3, 3), (5, 4), (6, 6), (7, 5)];
        let wrong = [(2, 2, pose(4.0, -2.0, 1.2)), (4, 6, pose(-1.5, 6.0, -2.5)), (6, 1, pose(1.0, 1.0, 0.3))];
        let mut factor = 0;
        for (i, &(a, b)) in genuine.iter().enumerate() {
            add_match(&mut pcm, factor, a, b, pose(0.03 * (i as f64 - 2.0), 0.02, 0.005));
            factor += 1;
            if let Some(&(a, b, error)) = wrong.get(i) {
                add_match(&mut pcm, factor, a, b, error);
                factor += 1;
            }
        }
        let decision = pcm.evaluate(&paths(&w));
        // Genuine closures went in at even factor indices up to 6, then 7 and 8.
        assert_eq!(decision.accept, vec![0, 2, 4, 6, 7, 8]);
        let rejected: Vec<ClosureKey> = pcm.closures().iter().filter(|c| !c.accepted).map(|c| c.key).collect();
        assert_eq!(rejected.len(), wrong.len());
    }

    #[test]
    fn an_early_wrong_pair_is_withdrawn_when_the_genuine_clique_grows() {
        let w = world();
        let mut pcm = Pcm::new(PcmParams::default());
        // Two wrong closures that agree with each other (the same wrong offset of robot 2).
        let offset = pose(6.0, -3.0, 2.0);
        let wrong = |a: u32, b: u32| truth(1, a).inverse() * offset * truth(2, b);
        for (factor, (a, b)) in [(0, (1, 1)), (1, (2, 3))] {
            let key = ClosureKey::Match(SubmapPair::new(SubmapId::new(1, a), SubmapId::new(2, b)));
            pcm.add(key, factor, submap(1, a), submap(2, b), wrong(a, b), diag(0.1, 0.02));
        }
        assert_eq!(pcm.evaluate(&paths(&w)).accept, vec![0, 1], "two agreeing closures are all PCM can see");
        for (factor, (a, b)) in [(2, (3, 2)), (3, (5, 5)), (4, (6, 4))] {
            add_match(&mut pcm, factor, a, b, Isometry3::identity());
        }
        let decision = pcm.evaluate(&paths(&w));
        assert_eq!(decision, Decision { accept: vec![2, 3, 4], withdraw: vec![0, 1] });
        assert_eq!(pcm.stats().withdrawn, 2);
        assert!(pcm.is_held(0) && !pcm.is_held(3));
    }

    #[test]
    fn missing_odometry_leaves_the_test_undecided() {
        let mut w = world();
        w.switches.remove(&SubmapId::new(2, 3));
        let mut pcm = Pcm::new(PcmParams::default());
        add_match(&mut pcm, 0, 1, 2, Isometry3::identity());
        add_match(&mut pcm, 1, 2, 4, Isometry3::identity());
        assert!(pcm.evaluate(&paths(&w)).accept.is_empty(), "robot 2's path 2 → 4 is unknown");
        let full = world();
        pcm.odometry_changed(2);
        assert_eq!(pcm.evaluate(&paths(&full)).accept, vec![0, 1]);
    }

    #[test]
    fn detections_mix_with_matches_and_either_direction() {
        let mut w = world();
        for (robot, stamp_ns, index) in [(1u16, 7u64, 2u32), (2, 7, 3)] {
            let t_submap_body = pose(1.0, 0.5, 0.1);
            w.poses.insert(
                PoseId { robot, stamp_ns },
                FilterPose { robot, stamp_ns, submap_index: index, t_submap_body, covariance: diag(0.02, 0.005) },
            );
        }
        let x1 = truth(1, 2) * pose(1.0, 0.5, 0.1);
        let x2 = truth(2, 3) * pose(1.0, 0.5, 0.1);
        let mut pcm = Pcm::new(PcmParams::default());
        // Robot 2 observed robot 1: the measurement points from robot 2's node to robot 1's.
        let key = ClosureKey::Detection { observer: 2, observed: 1, stamp_ns: 7, tag_id: 3 };
        let (from, to) =
            (NodeId::Pose(PoseId { robot: 2, stamp_ns: 7 }), NodeId::Pose(PoseId { robot: 1, stamp_ns: 7 }));
        pcm.add(key, 0, from, to, x2.inverse() * x1, diag(0.02, 0.01));
        add_match(&mut pcm, 1, 5, 5, Isometry3::identity());
        assert_eq!(pcm.evaluate(&paths(&w)).accept, vec![0, 1]);
    }

    #[test]
    fn evaluation_is_deterministic() {
        let w = world();
        let run = || {
            let mut pcm = Pcm::new(PcmParams::default());
            for (f, (a, b)) in [(1, 1), (2, 2), (3, 5), (4, 4), (6, 2)].into_iter().enumerate() {
                let error = if f % 2 == 1 { pose(3.0, 1.0, 1.0) } else { Isometry3::identity() };
                add_match(&mut pcm, f, a, b, error);
            }
            (pcm.evaluate(&paths(&w)), pcm.closures())
        };
        assert_eq!(run(), run());
    }
}
