//! TEST-ONLY loop closures for the lockstep mission (`--truth-loop-closures`): robot detections
//! and submap matches drawn from the simulator's ground truth with the thesis's noise models
//! (`sim::truth_constraints`), standing in for the robots' own marker detector and submap matcher
//! until those exist. Every report of a mission that used them says so.
//!
//! Each robot's "detector" looks at every camera stamp; its "matcher" runs every 10 s over the
//! submap pairs its own graph's ledger says are open and its own (issue-9 rule), inter-robot
//! pairs only once both robots are connected in its graph. What it finds goes into its mapper as
//! an own measurement, and from there to the team like any other constraint.

use std::sync::Arc;

use mapper::slam::{AttemptOutcome, MatchAttempt, Measurement, RobotDetection, SubmapId, SubmapMatch};
use sim::truth_constraints::{SubmapSpan, TruthConstraintConfig, TruthConstraints, TruthDetection};
use sim::world::World;

use onboard::nodes::Outbox;
use onboard::nodes::mapper::MapperNode;

use crate::mission::MissionError;
use crate::mission::world::robot_id;

const MATCH_PERIOD_NS: u64 = 10_000_000_000;

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
        }
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
            self.detections += 1;
            let detection = detection_measurement(&d, robot_id);
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
                let factor = SubmapMatch { a, b, t_a_b: m.t_a_b, covariance: m.covariance };
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
