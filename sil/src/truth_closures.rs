//! TEST-ONLY loop closures for the lockstep mission (`--truth-loop-closures`): robot detections
//! and submap matches drawn from the simulator's ground truth with the thesis's noise models
//! (`sim::truth_constraints`), standing in for the robots' own marker detector and submap matcher
//! until those exist. Every report of a mission that used them says so.
//!
//! Each robot's "detector" looks at every camera stamp; its "matcher" runs every 10 s over the
//! submap pairs its own graph's ledger says are open and its own (issue-9 rule), inter-robot
//! pairs only once both robots are connected in its graph. What it finds goes into its mapper as
//! an own measurement, and from there to the team like any other constraint.
//!
//! The outlier experiment ([`TruthLoopClosures::with_wrong_closures`]) replaces a fraction of the
//! inter-robot closures by confidently wrong ones: the true relative pose moved by 1–10 m in a
//! random horizontal direction and turned by a random yaw, reported with the genuine one's
//! covariance. Which closures are wrong is drawn per closure identity from the mission seed, so
//! a closure is wrong or not whatever else happened in the mission.

use std::collections::BTreeSet;
use std::f64::consts::{PI, TAU};
use std::sync::Arc;

use mapper::slam::{
    AttemptOutcome, ClosureKey, MatchAttempt, Measurement, RobotDetection, SubmapId, SubmapMatch, SubmapPair,
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use sim::truth_constraints::{SubmapSpan, TruthConstraintConfig, TruthConstraints, TruthDetection};
use sim::world::World;

use onboard::nodes::Outbox;
use onboard::nodes::mapper::MapperNode;

use crate::mission::MissionError;
use crate::mission::world::robot_id;

const MATCH_PERIOD_NS: u64 = 10_000_000_000;
/// The random stream of the wrong-closure draws (`sim::rng::stream` path head).
const WRONG_CLOSURE_STREAM: u64 = 0x0bad_c105;
/// Wrong closures are off by this much translation (m), uniformly.
const WRONG_TRANSLATION_M: (f64, f64) = (1.0, 10.0);

/// The ground-truth constraint source of a lockstep mission.
#[derive(Debug)]
pub struct TruthLoopClosures {
    truth: TruthConstraints,
    /// Per robot: the filter's initialization stamp and the stamps of its frame switches.
    initialized_ns: Vec<Option<u64>>,
    switches_ns: Vec<Vec<u64>>,
    next_match_ns: u64,
    pub detections: u64,
    pub match_attempts: u64,
    pub matches: u64,
    /// Inter-robot closures handed to the mappers (genuine and wrong).
    pub inter_robot_closures: u64,
    /// Fraction of inter-robot closures made wrong, and the seed of the draws.
    wrong_fraction: f64,
    wrong_seed: u64,
    /// The closures made wrong.
    pub wrong: BTreeSet<ClosureKey>,
    /// Hand out no detection of another robot (robots running alone).
    intra_robot_only: bool,
}

impl TruthLoopClosures {
    pub fn new(world: &Arc<World>, robots: usize) -> TruthLoopClosures {
        TruthLoopClosures {
            truth: TruthConstraints::new(Arc::clone(world), TruthConstraintConfig::default()),
            initialized_ns: vec![None; robots],
            switches_ns: vec![Vec::new(); robots],
            next_match_ns: MATCH_PERIOD_NS,
            detections: 0,
            match_attempts: 0,
            matches: 0,
            inter_robot_closures: 0,
            wrong_fraction: 0.0,
            wrong_seed: 0,
            wrong: BTreeSet::new(),
            intra_robot_only: false,
        }
    }

    /// With `alone`, no detection of another robot is handed out (the matches are intra-robot
    /// anyway when no robot hears another).
    pub fn intra_robot_only(mut self, alone: bool) -> TruthLoopClosures {
        self.intra_robot_only = alone;
        self
    }

    /// Replace `fraction` (0..=1) of the inter-robot closures by wrong ones, drawn from `seed`.
    pub fn with_wrong_closures(mut self, fraction: f64, seed: u64) -> TruthLoopClosures {
        self.wrong_fraction = fraction.clamp(0.0, 1.0);
        self.wrong_seed = seed;
        self
    }

    /// `t_a_b` of an inter-robot closure as handed out: the measurement, or a wrong one.
    fn maybe_wrong(&mut self, key: ClosureKey, t_a_b: Isometry3<f64>) -> Isometry3<f64> {
        self.inter_robot_closures += 1;
        if self.wrong_fraction <= 0.0 {
            return t_a_b;
        }
        let path = match key {
            ClosureKey::Detection { observer, observed, stamp_ns, tag_id } => {
                [WRONG_CLOSURE_STREAM, 0, u64::from(observer), u64::from(observed), stamp_ns, u64::from(tag_id)]
            }
            ClosureKey::Match(pair) => {
                let (a, b) = (pair.first(), pair.second());
                [
                    WRONG_CLOSURE_STREAM,
                    1,
                    u64::from(a.robot),
                    u64::from(a.index),
                    u64::from(b.robot),
                    u64::from(b.index),
                ]
            }
        };
        let mut rng = sim::rng::stream(self.wrong_seed, &path);
        if rng.uniform() >= self.wrong_fraction {
            return t_a_b;
        }
        let distance_m = rng.range(WRONG_TRANSLATION_M.0, WRONG_TRANSLATION_M.1);
        let heading_rad = rng.range(0.0, TAU);
        let yaw_rad = rng.range(-PI, PI);
        self.wrong.insert(key);
        let offset = Isometry3::from_parts(
            Translation3::new(distance_m * heading_rad.cos(), distance_m * heading_rad.sin(), 0.0),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad),
        );
        t_a_b * offset
    }

    pub fn on_initialized(&mut self, robot: usize, stamp_ns: u64) {
        if let Some(slot) = self.initialized_ns.get_mut(robot) {
            slot.get_or_insert(stamp_ns);
        }
    }

    pub fn on_frame_switch(&mut self, robot: usize, stamp_ns: u64) {
        if let Some(list) = self.switches_ns.get_mut(robot) {
            list.push(stamp_ns);
        }
    }

    fn span(&self, robot: usize, index: u32) -> Option<SubmapSpan> {
        let switches = self.switches_ns.get(robot)?;
        let start_ns =
            if index == 0 { (*self.initialized_ns.get(robot)?)? } else { *switches.get(index as usize - 1)? };
        let end_ns = *switches.get(index as usize)?;
        Some(SubmapSpan { robot, index, start_ns, end_ns })
    }

    /// Robot `robot`'s detector at camera stamp `stamp_ns`.
    pub fn detect(
        &mut self,
        robot: usize,
        stamp_ns: u64,
        mapper: &mut MapperNode,
        out: &mut dyn Outbox,
    ) -> Result<(), MissionError> {
        if self.initialized_ns.get(robot).copied().flatten().is_none_or(|init| stamp_ns < init) {
            return Ok(());
        }
        for d in self.truth.detections_at(robot, stamp_ns) {
            let mut detection = detection_measurement(&d, robot_id);
            if self.intra_robot_only && detection.observer != detection.observed {
                continue;
            }
            self.detections += 1;
            if detection.observer != detection.observed {
                let key = ClosureKey::Detection {
                    observer: detection.observer,
                    observed: detection.observed,
                    stamp_ns: detection.stamp_ns,
                    tag_id: detection.tag_id,
                };
                detection.t_observer_observed = self.maybe_wrong(key, detection.t_observer_observed);
            }
            mapper
                .insert_measurement(&Measurement::Detection(detection), out)
                .map_err(|e| MissionError::Node(format!("robot {robot}"), e))?;
        }
        Ok(())
    }

    /// Whether the matchers are due at `now_ns` (then call [`TruthLoopClosures::match_for`] for
    /// every robot and [`TruthLoopClosures::matched`] once).
    pub fn match_due(&self, now_ns: u64) -> bool {
        now_ns >= self.next_match_ns
    }

    pub fn matched(&mut self) {
        self.next_match_ns += MATCH_PERIOD_NS;
    }

    /// Robot `robot`'s matcher: every open pair it owns among the finished submaps its graph knows.
    pub fn match_for(
        &mut self,
        robot: usize,
        mapper: &mut MapperNode,
        out: &mut dyn Outbox,
    ) -> Result<(), MissionError> {
        let own = robot_id(robot);
        let graph = mapper.graph();
        let connected = graph.estimate().connected_robots();
        let finished: Vec<SubmapId> = (0..self.switches_ns.len())
            .flat_map(|r| (0..=self.switches_ns[r].len() as u32).map(move |i| SubmapId::new(robot_id(r), i)))
            .filter(|id| graph.knows_switch_out_of(*id))
            .collect();
        let pairs = graph.ledger().open_pairs(own, &finished);
        for pair in pairs {
            let (a, b) = (pair.first(), pair.second());
            if !(connected.contains(&a.robot) && connected.contains(&b.robot)) {
                continue;
            }
            let index = |id: SubmapId| usize::from(id.robot).saturating_sub(1);
            let (Some(span_a), Some(span_b)) = (self.span(index(a), a.index), self.span(index(b), b.index)) else {
                continue;
            };
            self.match_attempts += 1;
            let result = self.truth.attempt_match(&span_a, &span_b);
            let outcome = if result.is_some() { AttemptOutcome::Matched } else { AttemptOutcome::Failed };
            let node = |e| MissionError::Node(format!("robot {robot}"), e);
            mapper
                .insert_measurement(&Measurement::Attempt(MatchAttempt { pair, by: own, outcome }), out)
                .map_err(node)?;
            if let Some(m) = result {
                self.matches += 1;
                let t_a_b = if a.robot == b.robot {
                    m.t_a_b
                } else {
                    self.maybe_wrong(ClosureKey::Match(SubmapPair::new(a, b)), m.t_a_b)
                };
                let factor = SubmapMatch { a, b, t_a_b, covariance: m.covariance };
                mapper.insert_measurement(&Measurement::Match(factor), out).map_err(node)?;
            }
        }
        Ok(())
    }
}

/// A truth detection as the team graph's measurement; `robot_id` maps the simulator's robot
/// index to the graph's id (the mission's protocol ids, the evaluation's plain indices).
pub fn detection_measurement(d: &TruthDetection, robot_id: fn(usize) -> u16) -> RobotDetection {
    RobotDetection {
        observer: robot_id(d.observer),
        observed: robot_id(d.observed),
        tag_id: d.tag_id,
        stamp_ns: d.stamp_ns,
        t_observer_observed: d.t_observer_observed,
        covariance: d.covariance,
    }
}
