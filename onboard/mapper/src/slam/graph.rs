//! [`TeamGraph`]: the measurements a robot knows, the part of them connected to its own frame, and
//! the incremental optimizer that holds that part.
//!
//! Inserting a measurement only records it (and the factors it implies); [`TeamGraph::update`]
//! moves everything that is now connected to the own first submap into the optimizer, with
//! initial values chained along the new factors, and runs one incremental step. The thesis runs
//! one iSAM2 update per graph change; callers do that by calling `update` after each insert.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix6};
use posegraph::{Factor, GraphError, Isam, IsamParams, Key, LmParams, NoiseModel, RobustKernel, UpdateStats, Values};

use super::consistency::{self, ClosureKey, ClosureStatus, ConsistencyCheck, ConsistencyStats, Pcm};
use super::covariance;
use super::ids::{NodeId, PoseId, RobotId, SubmapId};
use super::ledger::MatchLedger;
use super::measurements::{
    FilterPose, LandmarkObservation, MatchAttempt, Measurement, RobotDetection, SubmapMatch, SubmapSwitch,
};
use super::odometry_paths::OdometryPaths;
use super::pose_buffer::PoseBuffer;
use super::sequential::{Chain, ChainError};

/// How filter estimates enter the graph (thesis §4.2.2, Table 8.6).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Topology {
    /// The thesis's: robot poses hang off the submap origin they were estimated in (`v`), never
    /// chained; submap origins are chained by the frame switches (`w`).
    LocalReference,
    /// The baseline (Brand et al. 2015): every graph node of a robot (submap origins and robot
    /// poses) chained in time by relative motions `u` with covariance differences (eqs. 4.8–4.9).
    /// Needs chronological input per robot; data older than a robot's chain end is dropped.
    SequentialOdometry,
}

/// Parameters (the thesis leaves all of them open, trap 26).
#[derive(Debug, Clone, PartialEq)]
pub struct TeamGraphConfig {
    pub topology: Topology,
    /// Cauchy constant on detections, landmark observations and matches, in whitened units. At
    /// 4, a typical inlier (`d² ≈ 6` for 6 DoF) keeps 73 % of its weight and a 10σ outlier 14 %.
    pub cauchy_c: f64,
    /// Prior on the own first submap origin: a gauge, so small (1 mm, 1 mrad).
    pub prior_sigmas: [f64; 6],
    /// Smallest eigenvalue of a filter-derived covariance (`w`, `v`, `u`). Right after a frame
    /// switch the filter's position and yaw variances are exactly zero; 10⁻⁸ (0.1 mm, 0.1 mrad)
    /// keeps the information finite without weakening any real measurement.
    pub min_filter_variance: f64,
    /// Interpolation of buffered filter poses (see [`PoseBuffer::lookup`]).
    pub pose_max_gap_ns: u64,
    pub isam: IsamParams,
    /// Screening of inter-robot loop closures before they enter the graph (beyond the thesis).
    pub consistency: ConsistencyCheck,
}

impl Default for TeamGraphConfig {
    fn default() -> Self {
        TeamGraphConfig {
            topology: Topology::LocalReference,
            cauchy_c: 4.0,
            prior_sigmas: [1e-3; 6],
            min_filter_variance: 1e-8,
            pose_max_gap_ns: 150_000_000,
            // GTSAM's 0.1 leaves robust-kernel weights and loop-closure linearizations stale by
            // centimetres at thesis graph sizes; 0.01 costs little with fewer than 200 nodes.
            isam: IsamParams { relinearize_threshold: 0.01, ..IsamParams::default() },
            consistency: ConsistencyCheck::None,
        }
    }
}

/// What became of an inserted measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InsertOutcome {
    /// Recorded; its factors enter the optimizer at the next update once connected.
    Added,
    /// Already known (same identity); nothing changed.
    Duplicate,
    /// Waits for the filter poses it needs (a detection before the other robot's pose arrived).
    Pending,
    /// Not usable; the reason says why.
    Rejected(&'static str),
}

/// Errors of the front-end.
#[derive(Debug, thiserror::Error)]
pub enum SlamError {
    #[error("pose graph: {0}")]
    Graph(#[from] GraphError),
    #[error("internal: a factor refers to {0:?}, which has no optimizer key")]
    MissingKey(NodeId),
}

/// The kind of a graph factor, for the size accounting of thesis Tables 8.7–8.9.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) enum FactorClass {
    Prior,
    Switch,
    FilterPose,
    Sequential,
    Detection,
    Landmark,
    Match,
}

#[derive(Debug, Clone)]
pub(crate) struct KnownFactor {
    pub class: FactorClass,
    pub from: NodeId,
    /// Equal to `from` for the prior.
    pub to: NodeId,
    pub measured: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
    pub inserted: bool,
}

type DetectionKey = (RobotId, RobotId, u64, u32);
type LandmarkKey = (RobotId, u32, u64);

/// One robot's graph of the whole team (see the module docs of [`super`]).
#[derive(Debug)]
pub struct TeamGraph {
    own: RobotId,
    config: TeamGraphConfig,
    pub(crate) factors: Vec<KnownFactor>,
    /// Indices into `factors` not yet in the optimizer.
    waiting: Vec<usize>,
    /// Optimizer key of every inserted node; `key_nodes[k]` is the node of `Key(k)`.
    pub(crate) keys: BTreeMap<NodeId, Key>,
    key_nodes: Vec<NodeId>,
    isam: Isam,
    pub(crate) buffers: BTreeMap<RobotId, PoseBuffer>,
    /// Frame switches received, by the submap they start.
    pub(crate) switches: BTreeMap<SubmapId, SubmapSwitch>,
    /// Submaps referenced by any measurement.
    pub(crate) submaps: BTreeMap<SubmapId, ()>,
    detections: BTreeMap<DetectionKey, RobotDetection>,
    pending_detections: Vec<DetectionKey>,
    landmark_observations: BTreeMap<LandmarkKey, LandmarkObservation>,
    pending_landmarks: Vec<LandmarkKey>,
    matches: BTreeMap<super::ids::SubmapPair, SubmapMatch>,
    ledger: MatchLedger,
    /// The filter pose each robot-pose node was created from.
    pub(crate) pose_nodes: BTreeMap<PoseId, FilterPose>,
    pub(crate) chains: BTreeMap<RobotId, Chain>,
    /// Switches a sequential chain could not take yet (their predecessor is missing).
    held_switches: BTreeMap<SubmapId, SubmapSwitch>,
    online: Vec<(u64, Isometry3<f64>)>,
    pub(crate) dropped_out_of_order: usize,
    /// Inter-robot closure screening (`None`: [`ConsistencyCheck::None`]).
    pcm: Option<Pcm>,
    /// A screened closure already in the optimizer left its accepted set: rebuild before the
    /// next update.
    rebuild_pending: bool,
}

impl TeamGraph {
    /// The graph of robot `own`: its first submap origin is the frame's origin.
    pub fn new(own: RobotId, config: TeamGraphConfig) -> Self {
        let isam = Isam::new(config.isam.clone());
        let pcm = match config.consistency {
            ConsistencyCheck::None => None,
            ConsistencyCheck::Pcm(params) => Some(Pcm::new(params)),
        };
        let mut graph = TeamGraph {
            own,
            config,
            factors: Vec::new(),
            waiting: Vec::new(),
            keys: BTreeMap::new(),
            key_nodes: Vec::new(),
            isam,
            buffers: BTreeMap::new(),
            switches: BTreeMap::new(),
            submaps: BTreeMap::new(),
            detections: BTreeMap::new(),
            pending_detections: Vec::new(),
            landmark_observations: BTreeMap::new(),
            pending_landmarks: Vec::new(),
            matches: BTreeMap::new(),
            ledger: MatchLedger::new(),
            pose_nodes: BTreeMap::new(),
            chains: BTreeMap::new(),
            held_switches: BTreeMap::new(),
            online: Vec::new(),
            dropped_out_of_order: 0,
            pcm,
            rebuild_pending: false,
        };
        let origin = NodeId::Submap(SubmapId::new(own, 0));
        graph.submaps.insert(SubmapId::new(own, 0), ());
        let sigmas = graph.config.prior_sigmas;
        let covariance = Matrix6::from_diagonal(&nalgebra::Vector6::from_iterator(sigmas.iter().map(|s| s * s)));
        graph.push_factor(FactorClass::Prior, origin, origin, Isometry3::identity(), covariance);
        graph
    }

    pub fn own(&self) -> RobotId {
        self.own
    }

    pub fn config(&self) -> &TeamGraphConfig {
        &self.config
    }

    pub fn ledger(&self) -> &MatchLedger {
        &self.ledger
    }

    /// The robot's buffered filter poses, if any arrived.
    pub fn pose_buffer(&self, robot: RobotId) -> Option<&PoseBuffer> {
        self.buffers.get(&robot)
    }

    /// The own robot's online trajectory: at every own filter pose, eq. 4.6 with the graph as it
    /// was at that moment (what the robot had; the thesis's evaluation, ch. 8).
    pub fn online_log(&self) -> &[(u64, Isometry3<f64>)] {
        &self.online
    }

    /// Whether the frame switch that finished submap `id` has arrived (the submap is complete).
    pub fn knows_switch_out_of(&self, id: SubmapId) -> bool {
        self.switches.contains_key(&SubmapId::new(id.robot, id.index + 1))
    }

    /// Detections and landmark observations still waiting for filter poses.
    pub fn pending(&self) -> usize {
        self.pending_detections.len() + self.pending_landmarks.len()
    }

    /// Measurements the sequential topology could not chain (older than the chain's end).
    pub fn dropped_out_of_order(&self) -> usize {
        self.dropped_out_of_order
    }

    /// Any measurement.
    pub fn insert(&mut self, measurement: &Measurement) -> InsertOutcome {
        match measurement {
            Measurement::SubmapSwitch(m) => self.insert_switch(m),
            Measurement::FilterPose(m) => self.insert_filter_pose(m),
            Measurement::Detection(m) => self.insert_detection(m),
            Measurement::Landmark(m) => self.insert_landmark_observation(m),
            Measurement::Match(m) => self.insert_match(m),
            Measurement::Attempt(m) => self.insert_attempt(m),
        }
    }

    /// A frame switch: the next submap origin of its robot and the factor `w` to it.
    pub fn insert_switch(&mut self, switch: &SubmapSwitch) -> InsertOutcome {
        if !covariance::is_psd(&switch.covariance) {
            return InsertOutcome::Rejected("frame switch covariance is not a covariance");
        }
        if self.switches.contains_key(&switch.to()) {
            return InsertOutcome::Duplicate;
        }
        self.switches.insert(switch.to(), *switch);
        if let Some(pcm) = &mut self.pcm {
            pcm.odometry_changed(switch.robot);
        }
        self.submaps.insert(switch.from(), ());
        self.submaps.insert(switch.to(), ());
        let covariance = self.filter_covariance(&switch.covariance);
        match self.config.topology {
            Topology::LocalReference => {
                self.push_factor(
                    FactorClass::Switch,
                    NodeId::Submap(switch.from()),
                    NodeId::Submap(switch.to()),
                    switch.t_old_new,
                    covariance,
                );
            }
            Topology::SequentialOdometry => {
                self.held_switches.insert(switch.to(), *switch);
                self.chain_held_switches(switch.robot);
            }
        }
        self.retry_pending();
        InsertOutcome::Added
    }

    /// A filter pose: buffered (and, for the own robot, a sample of the online trajectory).
    pub fn insert_filter_pose(&mut self, pose: &FilterPose) -> InsertOutcome {
        if !covariance::is_psd(&pose.covariance) {
            return InsertOutcome::Rejected("filter pose covariance is not a covariance");
        }
        if !self.buffers.entry(pose.robot).or_default().insert(*pose) {
            return InsertOutcome::Duplicate;
        }
        self.submaps.insert(SubmapId::new(pose.robot, pose.submap_index), ());
        if pose.robot == self.own
            && let Some(online) = self.online_pose(pose)
        {
            self.online.push((pose.stamp_ns, online));
        }
        self.retry_pending();
        InsertOutcome::Added
    }

    /// A robot detection (eq. 4.7); attached once both robots' filter poses at its stamp are known.
    pub fn insert_detection(&mut self, detection: &RobotDetection) -> InsertOutcome {
        if detection.observer == detection.observed {
            return InsertOutcome::Rejected("a robot cannot detect itself");
        }
        if !covariance::is_valid(&detection.covariance) {
            return InsertOutcome::Rejected("detection covariance is not positive definite");
        }
        let key = (detection.observer, detection.observed, detection.stamp_ns, detection.tag_id);
        if self.detections.contains_key(&key) {
            return InsertOutcome::Duplicate;
        }
        self.detections.insert(key, *detection);
        if self.try_attach_detection(&key) {
            InsertOutcome::Added
        } else {
            self.pending_detections.push(key);
            InsertOutcome::Pending
        }
    }

    /// A landmark observation; attached once the robot's filter pose at its stamp is known.
    pub fn insert_landmark_observation(&mut self, observation: &LandmarkObservation) -> InsertOutcome {
        if !covariance::is_valid(&observation.covariance) {
            return InsertOutcome::Rejected("landmark covariance is not positive definite");
        }
        let key = (observation.robot, observation.landmark, observation.stamp_ns);
        if self.landmark_observations.contains_key(&key) {
            return InsertOutcome::Duplicate;
        }
        self.landmark_observations.insert(key, *observation);
        if self.try_attach_landmark(&key) {
            InsertOutcome::Added
        } else {
            self.pending_landmarks.push(key);
            InsertOutcome::Pending
        }
    }

    /// A submap match: a factor between the two origins. The pair is also recorded as attempted.
    pub fn insert_match(&mut self, m: &SubmapMatch) -> InsertOutcome {
        if m.a == m.b {
            return InsertOutcome::Rejected("a submap cannot match itself");
        }
        if !covariance::is_valid(&m.covariance) {
            return InsertOutcome::Rejected("match covariance is not positive definite");
        }
        let pair = m.pair();
        if self.matches.contains_key(&pair) {
            return InsertOutcome::Duplicate;
        }
        self.matches.insert(pair, *m);
        self.ledger.record(MatchAttempt {
            pair,
            by: super::ledger::MatchLedger::owner(&pair),
            outcome: super::ledger::AttemptOutcome::Matched,
        });
        self.submaps.insert(m.a, ());
        self.submaps.insert(m.b, ());
        let key = ClosureKey::Match(pair);
        self.push_closure(key, FactorClass::Match, NodeId::Submap(m.a), NodeId::Submap(m.b), m.t_a_b, m.covariance);
        InsertOutcome::Added
    }

    /// A match attempt record (the team-wide ledger).
    pub fn insert_attempt(&mut self, attempt: &MatchAttempt) -> InsertOutcome {
        if self.ledger.record(*attempt) { InsertOutcome::Added } else { InsertOutcome::Duplicate }
    }

    /// Moves every factor connected to the own frame into the optimizer and runs one incremental
    /// step. Returns `None` if nothing new was connected.
    pub fn update(&mut self) -> Result<Option<UpdateStats>, SlamError> {
        self.screen_closures();
        let rebuilding = self.rebuild_pending;
        if rebuilding {
            self.reset_optimizer();
        }
        let (new_values, ready) = self.connect_waiting();
        if ready.is_empty() {
            return Ok(None);
        }
        let mut new_factors = Vec::with_capacity(ready.len());
        for &i in &ready {
            new_factors.push(self.optimizer_factor(&self.factors[i], &new_values)?);
        }
        let mut values: Vec<(Key, Isometry3<f64>)> = new_values.iter().map(|(_, key, pose)| (*key, *pose)).collect();
        if rebuilding {
            // The chained initial values are odometry only; one incremental step from there
            // would leave the loops open, so the rebuilt graph starts from a converged batch.
            converge(&new_factors, &mut values);
        }
        let stats = self.isam.update(new_factors, &values)?;
        self.rebuild_pending = false;
        // Committed only now, so a failed update leaves the graph as it was.
        for (node, key, _) in &new_values {
            self.keys.insert(*node, *key);
            self.key_nodes.push(*node);
        }
        for &i in &ready {
            self.factors[i].inserted = true;
        }
        self.waiting.retain(|i| !self.factors[*i].inserted);
        Ok(Some(stats))
    }

    /// Runs the consistency check: accepted closures start waiting for the optimizer, withdrawn
    /// ones stop waiting or, if the optimizer holds them already, mark it for a rebuild.
    fn screen_closures(&mut self) {
        let Some(pcm) = &mut self.pcm else {
            return;
        };
        let paths = OdometryPaths {
            switches: &self.switches,
            poses: &self.pose_nodes,
            min_variance: self.config.min_filter_variance,
        };
        let decision = pcm.evaluate(&paths);
        for i in decision.withdraw {
            if self.factors[i].inserted {
                self.rebuild_pending = true;
            }
            self.waiting.retain(|&w| w != i);
        }
        self.waiting.extend(decision.accept);
    }

    /// Empties the optimizer; every factor not held back by the consistency check waits again.
    fn reset_optimizer(&mut self) {
        self.isam = Isam::new(self.config.isam.clone());
        self.keys.clear();
        self.key_nodes.clear();
        for f in &mut self.factors {
            f.inserted = false;
        }
        let held = |i: usize| self.pcm.as_ref().is_some_and(|p| p.is_held(i));
        self.waiting = (0..self.factors.len()).filter(|&i| !held(i)).collect();
    }

    /// Counts of the inter-robot closure screening; `None` without one.
    pub fn consistency_stats(&self) -> Option<ConsistencyStats> {
        self.pcm.as_ref().map(Pcm::stats)
    }

    /// Every screened inter-robot closure and whether it is accepted (empty without screening).
    pub fn screened_closures(&self) -> Vec<ClosureStatus> {
        self.pcm.as_ref().map(Pcm::closures).unwrap_or_default()
    }

    /// The current estimate of a node in the own frame, if it is connected.
    pub fn node_pose(&self, node: NodeId) -> Option<Isometry3<f64>> {
        self.keys.get(&node).and_then(|&key| self.isam.estimate(key))
    }

    /// Eq. 4.6: a filter pose in the own frame, `s_j ⊕ v` with the current estimate of its submap
    /// origin (sequential topology: the latest chained node of that submap at or before the stamp,
    /// plus the filter's motion since). `None` while the submap is not connected.
    pub fn online_pose(&self, pose: &FilterPose) -> Option<Isometry3<f64>> {
        if self.config.topology == Topology::SequentialOdometry
            && let Some(chain) = self.chains.get(&pose.robot)
            && let Some(node) = chain.latest_at(pose.submap_index, pose.stamp_ns)
            && let Some(t_own_node) = self.node_pose(node.node)
        {
            return Some(t_own_node * node.t_submap_node.inverse() * pose.t_submap_body);
        }
        Some(self.origin_estimate(SubmapId::new(pose.robot, pose.submap_index))? * pose.t_submap_body)
    }

    /// A submap origin's estimate; one the optimizer does not hold yet (its switch arrived since
    /// the last update) is chained from its predecessor by the switch, as the update will do.
    fn origin_estimate(&self, id: SubmapId) -> Option<Isometry3<f64>> {
        let mut chained = Isometry3::identity();
        let mut current = id;
        loop {
            if let Some(pose) = self.node_pose(NodeId::Submap(current)) {
                return Some(pose * chained);
            }
            if current == SubmapId::new(self.own, 0) {
                return Some(chained);
            }
            let switch = self.switches.get(&current)?;
            chained = switch.t_old_new * chained;
            current = switch.from();
        }
    }

    /// Marginal covariances of every connected submap origin (graph convention), for the matcher's
    /// pairing heuristics (thesis §6.1.1: computed after every update there).
    pub fn submap_marginals(&mut self) -> Result<Vec<(SubmapId, Matrix6<f64>)>, SlamError> {
        let ids: Vec<(SubmapId, Key)> = self
            .keys
            .iter()
            .filter_map(|(node, key)| if let NodeId::Submap(id) = node { Some((*id, *key)) } else { None })
            .collect();
        let keys: Vec<Key> = ids.iter().map(|(_, k)| *k).collect();
        let marginals = self.isam.marginal_covariances(&keys)?;
        Ok(ids.into_iter().map(|(id, _)| id).zip(marginals).collect())
    }

    /// The connected graph re-solved from scratch by batch Levenberg–Marquardt from the current
    /// estimate: independent of the order in which the data arrived (up to the solver's
    /// tolerance), unlike the incremental estimate. The thesis suggests such occasional batch
    /// solves; the robot's online estimate stays the incremental one.
    pub fn batch_estimate(&self, params: &LmParams) -> Result<BTreeMap<NodeId, Isometry3<f64>>, SlamError> {
        let mut values = self.isam.estimates();
        posegraph::optimize(self.isam.factors(), &mut values, params)?;
        Ok(self.nodes_of(&values))
    }

    /// The optimizer's factors and current values (for g2o export and inspection); keys map to
    /// nodes through [`Self::node_of_key`].
    pub fn optimizer_state(&self) -> (&[Factor], Values) {
        (self.isam.factors(), self.isam.estimates())
    }

    pub fn node_of_key(&self, key: Key) -> Option<NodeId> {
        usize::try_from(key.0).ok().and_then(|i| self.key_nodes.get(i)).copied()
    }

    /// Every connected node's current estimate.
    pub fn estimates(&self) -> BTreeMap<NodeId, Isometry3<f64>> {
        self.nodes_of(&self.isam.estimates())
    }

    fn nodes_of(&self, values: &Values) -> BTreeMap<NodeId, Isometry3<f64>> {
        values.iter().filter_map(|(key, pose)| self.node_of_key(key).map(|node| (node, *pose))).collect()
    }

    pub(crate) fn optimizer(&self) -> &Isam {
        &self.isam
    }

    /// A filter covariance made safe for the graph (see `min_filter_variance`).
    fn filter_covariance(&self, c: &Matrix6<f64>) -> Matrix6<f64> {
        covariance::clamp_eigenvalues(c, self.config.min_filter_variance)
    }

    pub(crate) fn push_factor(
        &mut self,
        class: FactorClass,
        from: NodeId,
        to: NodeId,
        measured: Isometry3<f64>,
        covariance: Matrix6<f64>,
    ) {
        self.factors.push(KnownFactor { class, from, to, measured, covariance, inserted: false });
        self.waiting.push(self.factors.len() - 1);
    }

    /// An inter-robot loop closure goes to the consistency check, which lets it wait for the
    /// optimizer once accepted; everything else waits at once.
    fn push_closure(
        &mut self,
        key: ClosureKey,
        class: FactorClass,
        from: NodeId,
        to: NodeId,
        measured: Isometry3<f64>,
        covariance: Matrix6<f64>,
    ) {
        match &mut self.pcm {
            Some(pcm) if consistency::is_inter_robot(from, to) => {
                self.factors.push(KnownFactor { class, from, to, measured, covariance, inserted: false });
                pcm.add(key, self.factors.len() - 1, from, to, measured, covariance);
            }
            _ => self.push_factor(class, from, to, measured, covariance),
        }
    }

    /// A robot-pose node from a filter pose, with its `v` factor (local reference) or its place in
    /// the robot's chain (sequential). False if the sequential chain cannot take it.
    fn ensure_pose_node(&mut self, pose: &FilterPose) -> bool {
        let id = PoseId { robot: pose.robot, stamp_ns: pose.stamp_ns };
        if self.pose_nodes.contains_key(&id) {
            return true;
        }
        let covariance = self.filter_covariance(&pose.covariance);
        let node = NodeId::Pose(id);
        match self.config.topology {
            Topology::LocalReference => {
                let origin = NodeId::Submap(SubmapId::new(pose.robot, pose.submap_index));
                self.push_factor(FactorClass::FilterPose, origin, node, pose.t_submap_body, covariance);
            }
            Topology::SequentialOdometry => {
                let floor = self.config.min_filter_variance;
                let chain = self.chains.entry(pose.robot).or_insert_with(|| Chain::new(pose.robot));
                match chain.append_pose(node, pose, floor) {
                    Ok((from, measured, cov)) => self.push_factor(FactorClass::Sequential, from, node, measured, cov),
                    Err(ChainError::OutOfOrder) => return false,
                }
            }
        }
        self.pose_nodes.insert(id, *pose);
        true
    }

    /// Chains the held switches of `robot` whose predecessor is in place (sequential topology).
    fn chain_held_switches(&mut self, robot: RobotId) {
        let floor = self.config.min_filter_variance;
        loop {
            let chain = self.chains.entry(robot).or_insert_with(|| Chain::new(robot));
            let next = SubmapId::new(robot, chain.end_submap() + 1);
            let Some(switch) = self.held_switches.get(&next).copied() else {
                return;
            };
            self.held_switches.remove(&next);
            match chain.append_switch(&switch, floor) {
                Ok((from, measured, cov)) => {
                    self.push_factor(FactorClass::Sequential, from, NodeId::Submap(switch.to()), measured, cov)
                }
                Err(ChainError::OutOfOrder) => self.dropped_out_of_order += 1,
            }
        }
    }

    fn lookup(&self, robot: RobotId, stamp_ns: u64) -> Option<FilterPose> {
        self.buffers.get(&robot)?.lookup(stamp_ns, self.config.pose_max_gap_ns)
    }

    /// Attaches a known detection if both poses are available.
    fn try_attach_detection(&mut self, key: &DetectionKey) -> bool {
        let Some(d) = self.detections.get(key).copied() else {
            return true;
        };
        let (Some(observer), Some(observed)) =
            (self.lookup(d.observer, d.stamp_ns), self.lookup(d.observed, d.stamp_ns))
        else {
            return false;
        };
        if !(self.ensure_pose_node(&observer) && self.ensure_pose_node(&observed)) {
            self.dropped_out_of_order += 1;
            return true;
        }
        let from = NodeId::Pose(PoseId { robot: d.observer, stamp_ns: d.stamp_ns });
        let to = NodeId::Pose(PoseId { robot: d.observed, stamp_ns: d.stamp_ns });
        let closure = ClosureKey::Detection {
            observer: d.observer,
            observed: d.observed,
            stamp_ns: d.stamp_ns,
            tag_id: d.tag_id,
        };
        self.push_closure(closure, FactorClass::Detection, from, to, d.t_observer_observed, d.covariance);
        true
    }

    fn try_attach_landmark(&mut self, key: &LandmarkKey) -> bool {
        let Some(o) = self.landmark_observations.get(key).copied() else {
            return true;
        };
        let Some(pose) = self.lookup(o.robot, o.stamp_ns) else {
            return false;
        };
        if !self.ensure_pose_node(&pose) {
            self.dropped_out_of_order += 1;
            return true;
        }
        let from = NodeId::Pose(PoseId { robot: o.robot, stamp_ns: o.stamp_ns });
        self.push_factor(FactorClass::Landmark, from, NodeId::Landmark(o.landmark), o.t_body_landmark, o.covariance);
        true
    }

    fn retry_pending(&mut self) {
        if !self.pending_detections.is_empty() {
            let pending = std::mem::take(&mut self.pending_detections);
            for key in pending {
                if !self.try_attach_detection(&key) {
                    self.pending_detections.push(key);
                }
            }
        }
        if !self.pending_landmarks.is_empty() {
            let pending = std::mem::take(&mut self.pending_landmarks);
            for key in pending {
                if !self.try_attach_landmark(&key) {
                    self.pending_landmarks.push(key);
                }
            }
        }
    }

    /// The waiting factors that are now connected to the own frame, and initial values for their
    /// new nodes, chained from the connected ones (breadth-first over the waiting factors).
    #[allow(clippy::type_complexity)]
    fn connect_waiting(&self) -> (Vec<(NodeId, Key, Isometry3<f64>)>, Vec<usize>) {
        let mut new_values: Vec<(NodeId, Key, Isometry3<f64>)> = Vec::new();
        let mut new_index: BTreeMap<NodeId, usize> = BTreeMap::new();
        let value = |node: &NodeId, new_values: &[(NodeId, Key, Isometry3<f64>)], index: &BTreeMap<NodeId, usize>| {
            if let Some(&key) = self.keys.get(node) {
                return self.isam.estimate(key);
            }
            index.get(node).map(|&i| new_values[i].2)
        };
        let mut progress = true;
        while progress {
            progress = false;
            for &i in &self.waiting {
                let f = &self.factors[i];
                let a = value(&f.from, &new_values, &new_index);
                let b = value(&f.to, &new_values, &new_index);
                let init = match (f.class, a, b) {
                    (FactorClass::Prior, None, _) => Some((f.from, f.measured)),
                    (FactorClass::Prior, Some(_), _) => None,
                    (_, Some(a), None) => Some((f.to, a * f.measured)),
                    (_, None, Some(b)) => Some((f.from, b * f.measured.inverse())),
                    _ => None,
                };
                if let Some((node, pose)) = init {
                    let key = Key((self.key_nodes.len() + new_values.len()) as u64);
                    new_index.insert(node, new_values.len());
                    new_values.push((node, key, pose));
                    progress = true;
                }
            }
        }
        let known = |node: &NodeId| self.keys.contains_key(node) || new_index.contains_key(node);
        let ready = self
            .waiting
            .iter()
            .copied()
            .filter(|&i| known(&self.factors[i].from) && known(&self.factors[i].to))
            .collect();
        (new_values, ready)
    }

    fn optimizer_factor(
        &self,
        f: &KnownFactor,
        new_values: &[(NodeId, Key, Isometry3<f64>)],
    ) -> Result<Factor, SlamError> {
        let key_of = |node: &NodeId| {
            self.keys
                .get(node)
                .copied()
                .or_else(|| new_values.iter().find(|(n, _, _)| n == node).map(|(_, k, _)| *k))
                .ok_or(SlamError::MissingKey(*node))
        };
        let mut noise = NoiseModel::from_covariance(f.covariance)?;
        if matches!(f.class, FactorClass::Detection | FactorClass::Landmark | FactorClass::Match) {
            noise = noise.with_kernel(RobustKernel::cauchy(self.config.cauchy_c)?);
        }
        let from = key_of(&f.from)?;
        Ok(if f.class == FactorClass::Prior {
            Factor::prior(from, f.measured, noise)
        } else {
            Factor::between(from, key_of(&f.to)?, f.measured, noise)
        })
    }
}

/// Levenberg–Marquardt to convergence over `factors` from `values`, in place; on failure the
/// values stay as they were (the incremental solver then starts from them).
fn converge(factors: &[Factor], values: &mut [(Key, Isometry3<f64>)]) {
    let mut all = Values::new();
    for (key, pose) in values.iter() {
        if all.insert(*key, *pose).is_err() {
            return;
        }
    }
    if posegraph::optimize(factors, &mut all, &LmParams::default()).is_err() {
        return;
    }
    for (key, pose) in values.iter_mut() {
        if let Some(p) = all.get(*key) {
            *pose = *p;
        }
    }
}
