//! Evaluation of the multi-robot SLAM front-end on recorded simulated team runs (issue 9).
//!
//! **Loop closures come from `sim::truth_constraints`, the test-only source that draws robot
//! detections and submap matches from the simulator's ground truth with the thesis's noise
//! models.** Every report of this module says so. The filter data is real: each robot's VIO
//! pipeline on rendered stereo, IMU and wheel odometry ([`crate::team_record`]).
//!
//! [`exchange`] plays the team's data exchange forward in time: each robot's graph receives its own
//! filter poses and frame switches, the other robots' switches, 1 Hz pose stream and the poses
//! answering detections over a link with latency, detections when they are made, and the matches
//! of the pairs it owns (tried at most once team-wide, inter-robot pairs only once the two robots
//! are connected in the owner's graph, thesis §6.1.3). As in the thesis's topology comparison
//! (§8.2.2), every measurement waits a fixed insertion delay, so the sequential topology gets
//! chronological input. What each robot received, and when, is logged; [`evaluate`] replays that
//! log into any variant (topology, multi- or single-robot), so all variants see the same data.

use std::collections::{BTreeMap, BinaryHeap};
use std::sync::Arc;

use eval::metrics::Stats;
use mapper::slam::{
    self, AttemptOutcome, FilterPose, GraphSize, MatchAttempt, Measurement, RobotId, SubmapId, SubmapMatch,
    SubmapSwitch, TeamGraph, TeamGraphConfig, Topology,
};
use nalgebra::Isometry3;
use sim::truth_constraints::{SubmapSpan, TruthConstraintConfig, TruthConstraints};
use sim::world::World;

use crate::team_record::RobotRecord;

/// How the exchange is simulated.
#[derive(Debug, Clone, PartialEq)]
pub struct ExchangeOptions {
    /// One-way link latency between robots.
    pub link_latency_ns: u64,
    /// Every measurement is inserted this long after its stamp (thesis §8.2.2: 2 s for both
    /// topologies, so the sequential one gets chronological input).
    pub insertion_delay_ns: u64,
    /// Rate of the pose stream to the other robots.
    pub remote_pose_period_ns: u64,
    /// How often each robot's matcher looks for open pairs.
    pub match_period_ns: u64,
    pub truth: TruthConstraintConfig,
}

impl Default for ExchangeOptions {
    fn default() -> Self {
        ExchangeOptions {
            link_latency_ns: 1_000_000_000,
            insertion_delay_ns: 2_000_000_000,
            remote_pose_period_ns: 1_000_000_000,
            match_period_ns: 10_000_000_000,
            truth: TruthConstraintConfig::default(),
        }
    }
}

/// What each robot received, and counts of what the constraint source produced.
#[derive(Debug, Clone, Default)]
pub struct ExchangeLog {
    /// Per robot: (arrival stamp, measurement), in arrival order.
    pub received: Vec<Vec<(u64, Measurement)>>,
    pub detections: usize,
    pub match_attempts: usize,
    pub matches: usize,
    pub inter_robot_matches: usize,
    pub outlier_matches: usize,
}

/// A measurement on its way to one robot.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Delivery {
    arrival_ns: u64,
    sequence: u64,
    measurement: Measurement,
}

impl Eq for Delivery {}

impl Ord for Delivery {
    /// Earliest arrival first (a max-heap of the reverse), then in sending order.
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (other.arrival_ns, other.sequence).cmp(&(self.arrival_ns, self.sequence))
    }
}

impl PartialOrd for Delivery {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

#[derive(Debug, Default)]
struct Outbox {
    queues: Vec<BinaryHeap<Delivery>>,
    sequence: u64,
}

impl Outbox {
    fn send(&mut self, to: usize, arrival_ns: u64, measurement: Measurement) {
        self.sequence += 1;
        self.queues[to].push(Delivery { arrival_ns, sequence: self.sequence, measurement });
    }
}

fn robot_id(index: usize) -> RobotId {
    RobotId::try_from(index).unwrap_or(RobotId::MAX)
}

/// The robot's filter poses in the graph's terms.
pub fn filter_poses(record: &RobotRecord) -> Vec<FilterPose> {
    record
        .poses
        .iter()
        .map(|p| FilterPose {
            robot: robot_id(record.robot),
            stamp_ns: p.stamp_ns,
            submap_index: p.frame_id,
            t_submap_body: p.t_local_body,
            covariance: slam::covariance::from_filter(&p.t_local_body, &p.covariance),
        })
        .collect()
}

/// The robot's frame switches in the graph's terms.
pub fn frame_switches(record: &RobotRecord) -> Vec<SubmapSwitch> {
    record
        .switches
        .iter()
        .map(|s| SubmapSwitch {
            robot: robot_id(record.robot),
            stamp_ns: s.stamp_ns,
            from_index: s.old_frame_id,
            t_old_new: s.t_old_new,
            covariance: slam::covariance::from_filter(&s.t_old_new, &s.covariance),
        })
        .collect()
}

/// The time span of a submap: from its switch (or the filter start) to the next switch.
fn span(record: &RobotRecord, index: u32) -> Option<SubmapSpan> {
    let start_ns = if index == 0 { record.initialized_ns } else { record.switches.get(index as usize - 1)?.stamp_ns };
    let end_ns = record.switches.get(index as usize)?.stamp_ns;
    Some(SubmapSpan { robot: record.robot, index, start_ns, end_ns })
}

/// Plays the exchange forward (see the module docs).
pub fn exchange(
    world: &Arc<World>,
    records: &[RobotRecord],
    options: &ExchangeOptions,
) -> Result<ExchangeLog, slam::SlamError> {
    let n = records.len();
    let mut truth = TruthConstraints::new(Arc::clone(world), options.truth);
    let mut outbox = Outbox { queues: vec![BinaryHeap::new(); n], sequence: 0 };
    let delay = options.insertion_delay_ns;
    let latency = options.link_latency_ns;
    let poses: Vec<Vec<FilterPose>> = records.iter().map(filter_poses).collect();
    let mut log = ExchangeLog { received: vec![Vec::new(); n], ..ExchangeLog::default() };

    for (r, record) in records.iter().enumerate() {
        for s in frame_switches(record) {
            for to in 0..n {
                let arrival = s.stamp_ns + delay + if to == r { 0 } else { latency };
                outbox.send(to, arrival, Measurement::SubmapSwitch(s));
            }
        }
        let mut next_remote_ns = 0;
        for p in &poses[r] {
            outbox.send(r, p.stamp_ns + delay, Measurement::FilterPose(*p));
            if p.stamp_ns >= next_remote_ns {
                next_remote_ns = p.stamp_ns + options.remote_pose_period_ns;
                for to in (0..n).filter(|&to| to != r) {
                    outbox.send(to, p.stamp_ns + delay + latency, Measurement::FilterPose(*p));
                }
            }
        }
        // Detections at every image, the observed robot's answer with its pose at that stamp.
        for p in &poses[r] {
            for d in truth.detections_at(r, p.stamp_ns) {
                log.detections += 1;
                let detection = crate::truth_closures::detection_measurement(&d, robot_id);
                for to in 0..n {
                    let arrival = d.stamp_ns + delay + if to == r { 0 } else { latency };
                    outbox.send(to, arrival, Measurement::Detection(detection));
                }
                if let Some(answer) = poses[d.observed].iter().find(|q| q.stamp_ns == d.stamp_ns) {
                    for to in (0..n).filter(|&to| to != d.observed) {
                        // The observed robot hears of the detection, then answers.
                        outbox.send(to, d.stamp_ns + delay + 2 * latency, Measurement::FilterPose(*answer));
                    }
                }
            }
        }
    }

    // The online part: graphs, matchers.
    let mut graphs: Vec<TeamGraph> = (0..n).map(|r| TeamGraph::new(robot_id(r), TeamGraphConfig::default())).collect();
    let end_ns = records.iter().filter_map(|r| r.poses.last()).map(|p| p.stamp_ns).max().unwrap_or(0)
        + delay
        + 3 * latency
        + options.match_period_ns;
    let tick_ns = 100_000_000;
    let mut next_match_ns = options.match_period_ns;
    let mut now_ns = 0;
    while now_ns <= end_ns {
        for ((queue, graph), received) in outbox.queues.iter_mut().zip(&mut graphs).zip(&mut log.received) {
            let mut changed = false;
            while queue.peek().is_some_and(|d| d.arrival_ns <= now_ns) {
                let Some(delivery) = queue.pop() else { break };
                graph.insert(&delivery.measurement);
                received.push((now_ns, delivery.measurement));
                changed = true;
            }
            if changed {
                graph.update()?;
            }
        }
        if now_ns >= next_match_ns {
            next_match_ns += options.match_period_ns;
            for r in 0..n {
                try_matches(r, now_ns, records, &mut graphs, &mut truth, &mut outbox, &mut log, latency);
            }
        }
        now_ns += tick_ns;
    }
    Ok(log)
}

/// Robot `r`'s matcher: every open pair it owns among the finished submaps it knows.
#[allow(clippy::too_many_arguments)]
fn try_matches(
    r: usize,
    now_ns: u64,
    records: &[RobotRecord],
    graphs: &mut [TeamGraph],
    truth: &mut TruthConstraints,
    outbox: &mut Outbox,
    log: &mut ExchangeLog,
    latency: u64,
) {
    let estimate = graphs[r].estimate();
    let connected = estimate.connected_robots();
    // Finished = the switch out of it has arrived here.
    let finished: Vec<SubmapId> = records
        .iter()
        .flat_map(|record| {
            let robot = robot_id(record.robot);
            (0..record.switches.len() as u32).map(move |i| SubmapId::new(robot, i))
        })
        .filter(|id| graphs[r].knows_switch_out_of(*id))
        .collect();
    let own = robot_id(r);
    for pair in graphs[r].ledger().open_pairs(own, &finished) {
        let (a, b) = (pair.first(), pair.second());
        // Inter-robot matching waits for a connection in the graph (thesis §6.1.3).
        if !(connected.contains(&a.robot) && connected.contains(&b.robot)) {
            continue;
        }
        let (Some(span_a), Some(span_b)) =
            (span(&records[usize::from(a.robot)], a.index), span(&records[usize::from(b.robot)], b.index))
        else {
            continue;
        };
        log.match_attempts += 1;
        let result = truth.attempt_match(&span_a, &span_b);
        let outcome = if result.is_some() { AttemptOutcome::Matched } else { AttemptOutcome::Failed };
        let attempt = MatchAttempt { pair, by: own, outcome };
        for to in 0..records.len() {
            outbox.send(to, now_ns + if to == r { 0 } else { latency }, Measurement::Attempt(attempt));
        }
        if let Some(m) = result {
            log.matches += 1;
            log.inter_robot_matches += usize::from(a.robot != b.robot);
            log.outlier_matches += usize::from(m.outlier);
            let factor = SubmapMatch { a, b, t_a_b: m.t_a_b, covariance: m.covariance };
            for to in 0..records.len() {
                outbox.send(to, now_ns + if to == r { 0 } else { latency }, Measurement::Match(factor));
            }
        }
    }
}

/// Which graph to build from a robot's received data.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    /// Everything the robot received.
    Multi(Topology),
    /// Only its own data and its own intra-robot matches (thesis Table 8.9's single-robot SLAM).
    Single(Topology),
    /// Only its own filter poses and frame switches: the filter alone.
    FilterOnly,
}

impl Variant {
    pub fn name(&self) -> &'static str {
        match self {
            Variant::Multi(Topology::LocalReference) => "multi, local reference",
            Variant::Multi(Topology::SequentialOdometry) => "multi, sequential odometry",
            Variant::Single(Topology::LocalReference) => "single, local reference",
            Variant::Single(Topology::SequentialOdometry) => "single, sequential odometry",
            Variant::FilterOnly => "filter only",
        }
    }

    pub fn topology(&self) -> Topology {
        match self {
            Variant::Multi(t) | Variant::Single(t) => *t,
            Variant::FilterOnly => Topology::LocalReference,
        }
    }

    /// Whether this variant's graph of robot `own` takes `m`.
    pub fn keeps(&self, own: RobotId, m: &Measurement) -> bool {
        let own_only = match m {
            Measurement::FilterPose(p) => p.robot == own,
            Measurement::SubmapSwitch(s) => s.robot == own,
            Measurement::Match(c) => c.a.robot == own && c.b.robot == own,
            Measurement::Attempt(a) => a.pair.first().robot == own && a.pair.second().robot == own,
            Measurement::Detection(_) | Measurement::Landmark(_) => false,
        };
        match self {
            Variant::Multi(_) => true,
            Variant::Single(_) => own_only,
            Variant::FilterOnly => own_only && matches!(m, Measurement::FilterPose(_) | Measurement::SubmapSwitch(_)),
        }
    }
}

/// One robot's online trajectory error in one variant.
#[derive(Debug, Clone)]
pub struct RobotResult {
    pub robot: usize,
    pub variant: Variant,
    /// 3D position error of the online estimate (thesis ch. 8: what the robot had at each
    /// moment), in the robot's own start frame, at every filter pose.
    pub position: Stats,
    pub final_error_m: f64,
    pub yaw: Stats,
    pub distance_m: f64,
    pub size: GraphSize,
    /// The robots connected to this robot's frame at the end.
    pub connected: Vec<RobotId>,
    pub dropped_out_of_order: usize,
}

/// Robot `own`'s graph of `variant` (with `config` otherwise) after the measurements of
/// `received` that the variant keeps: those with the same arrival key go into one update.
pub fn replay(
    own: RobotId,
    config: TeamGraphConfig,
    received: &[(u64, Measurement)],
    variant: Variant,
) -> Result<TeamGraph, slam::SlamError> {
    let mut graph = TeamGraph::new(own, TeamGraphConfig { topology: variant.topology(), ..config });
    let mut batch = None;
    for (arrival, m) in received.iter().filter(|(_, m)| variant.keeps(own, m)) {
        if batch.is_some_and(|b| b != *arrival) {
            graph.update()?;
        }
        batch = Some(*arrival);
        graph.insert(m);
    }
    graph.update()?;
    Ok(graph)
}

/// Replays `log.received[robot]` into a graph of `variant` and scores its online trajectory.
pub fn evaluate(
    world: &Arc<World>,
    record: &RobotRecord,
    received: &[(u64, Measurement)],
    variant: Variant,
    truth_config: TruthConstraintConfig,
) -> Result<Option<RobotResult>, slam::SlamError> {
    let own = robot_id(record.robot);
    let graph = replay(own, TeamGraphConfig::default(), received, variant)?;
    let source = TruthConstraints::new(Arc::clone(world), truth_config);
    let Some(t_world_own) = source.true_origin(record.robot, record.initialized_ns) else {
        return Ok(None);
    };
    let truth: BTreeMap<u64, Isometry3<f64>> = record.truth.iter().copied().collect();
    let (mut position, mut yaw) = (Vec::new(), Vec::new());
    for (stamp, est) in graph.online_log() {
        let Some(t_world_body) = truth.get(stamp) else { continue };
        let gt = t_world_own.inverse() * t_world_body;
        position.push((est.translation.vector - gt.translation.vector).norm());
        let (_, _, yaw_est) = est.rotation.euler_angles();
        let (_, _, yaw_gt) = gt.rotation.euler_angles();
        yaw.push(eval::metrics::wrap_angle_rad(yaw_est - yaw_gt).abs());
    }
    let (Some(position_stats), Some(yaw_stats), Some(&final_error_m)) =
        (Stats::from_errors(&position), Stats::from_errors(&yaw), position.last())
    else {
        return Ok(None);
    };
    Ok(Some(RobotResult {
        robot: record.robot,
        variant,
        position: position_stats,
        final_error_m,
        yaw: yaw_stats,
        distance_m: record.distance_m,
        size: graph.size(),
        connected: graph.estimate().connected_robots(),
        dropped_out_of_order: graph.dropped_out_of_order(),
    }))
}
