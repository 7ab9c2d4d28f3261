//! The matcher as the mapper's background work (thesis §6.1, Fig. 6.1): finished submaps in,
//! loop-closure measurements out.
//!
//! The mapper hands every finished submap (its own and its peers') to [`MatchScheduler::add_submap`],
//! which checks it and selects its keypoints at once (milliseconds: the thesis's pairing thread).
//! [`MatchScheduler::poll`], called from the mapper's fixed-rate tick, collects a finished attempt,
//! re-ranks the open pairs when the graph or the submaps changed ([`crate::pairing`]), and hands the
//! best pair to the matcher (the thesis's matching thread). Each attempt yields a
//! [`MatchAttempt`] for the team-wide ledger and, if it succeeded, a [`SubmapMatch`]; the mapper
//! inserts both and sends them to its peers (§3.3: every pair is tried once in the team).
//!
//! Where the matcher runs ([`Executor`]):
//! - [`Executor::Background`]: one thread, which the firmware puts in the lowest scheduling class
//!   (`SCHED_IDLE`), so it takes only what the filter, vision and the mapper's own tick leave
//!   (the thesis: a low-priority process that "can acquire all free processing resources on
//!   demand"). The tick never waits for it.
//! - [`Executor::Inline`]: the attempt runs inside `poll`, deterministic: the lockstep runner
//!   (simulated time) and tests. At most one attempt starts per `attempt_period_ns` of sensor
//!   time there, standing in for the background thread's budget.
//!
//! Only pairs whose two robots are connected in the own graph are ranked: the pairing's overlap
//! and the matcher's 2·Δσ gates need the graph's relative estimate (the robots first meet by a
//! detection; the thesis's team did the same).

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::mpsc::{Receiver, Sender, TryRecvError, channel};

use nalgebra::{Isometry3, Matrix3, Vector3};

use crate::cloud::VoxelCloud;
use crate::matching::{MatchReport, MatcherParams, PreparedCloud, RelativePrior, Unsuitable, match_clouds};
use crate::pairing::{Candidate, PairingParams, PlacedSubmap, SkipCounts, rank};
use crate::slam::{
    AttemptOutcome, MatchAttempt, Measurement, NodeId, RobotId, SubmapId, SubmapMatch, SubmapPair, TeamGraph,
};

/// Where attempts run.
#[derive(Debug, Clone, Copy)]
pub enum Executor {
    Inline,
    /// On one thread that first calls `setup` (the firmware lowers its scheduling class there and
    /// frees it from the mapper task's CPU pinning: this crate does not touch the OS).
    Background {
        setup: fn(),
    },
}

#[derive(Debug, Clone)]
pub struct SchedulerConfig {
    pub matcher: MatcherParams,
    pub pairing: PairingParams,
    pub executor: Executor,
    /// The open pairs are re-ranked at most this often (the graph's marginals are recomputed for it).
    pub rerank_period_ns: u64,
    /// Inline executor: one attempt per this much sensor time at most.
    pub attempt_period_ns: u64,
}

impl SchedulerConfig {
    pub fn new(matcher: MatcherParams, pairing: PairingParams, executor: Executor) -> SchedulerConfig {
        SchedulerConfig {
            matcher,
            pairing,
            executor,
            rerank_period_ns: 2_000_000_000,
            attempt_period_ns: 1_000_000_000,
        }
    }
}

/// One finished attempt, for reports and for scoring against ground truth.
#[derive(Debug, Clone, PartialEq)]
pub struct AttemptRecord {
    pub pair: SubmapPair,
    /// When the attempt started (sensor time of the tick that dispatched it).
    pub started_ns: u64,
    /// The graph's estimate of `t_a_b` (a = first, b = second) when the attempt started.
    pub prior_t_a_b: Isometry3<f64>,
    pub delta_sigma_m: Vector3<f64>,
    /// The matcher's verdict: `Ok(match)` or the rejection's name.
    pub result: Result<SubmapMatch, &'static str>,
    pub rmse_m: Option<f64>,
    pub correspondences: usize,
    pub hypotheses: usize,
    pub times: crate::matching::StageTimes,
}

impl AttemptRecord {
    /// The record of matching `pair` (target = a = first, source = b = second) from the prior
    /// `prior_t_a_b` with uncertainty `delta_sigma_m`: an accepted match maps b's coordinates
    /// into a's; a rejection keeps its name.
    pub fn new(
        pair: SubmapPair,
        started_ns: u64,
        prior_t_a_b: Isometry3<f64>,
        delta_sigma_m: Vector3<f64>,
        report: &crate::matching::MatchReport,
    ) -> AttemptRecord {
        let result = match &report.outcome {
            Ok(found) => Ok(SubmapMatch {
                a: pair.first(),
                b: pair.second(),
                t_a_b: found.t_target_source,
                covariance: found.covariance,
            }),
            Err(rejection) => Err(rejection.name()),
        };
        AttemptRecord {
            pair,
            started_ns,
            prior_t_a_b,
            delta_sigma_m,
            result,
            rmse_m: report.outcome.as_ref().ok().map(|f| f.rmse_m),
            correspondences: report.correspondences,
            hypotheses: report.hypotheses,
            times: report.times,
        }
    }
}

/// Counters of the scheduler.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SchedulerStats {
    pub submaps_added: u64,
    pub submaps_unsuitable: u64,
    /// Unsuitable submaps by the failed check's name.
    pub unsuitable_by: BTreeMap<&'static str, u64>,
    pub attempts: u64,
    pub accepted: u64,
    /// Rejected attempts by the rejecting check's name.
    pub rejected: BTreeMap<&'static str, u64>,
    /// Open pairs left out of the last ranking, and why.
    pub last_skips: SkipCounts,
    /// Pairs in the queue after the last ranking.
    pub queued: usize,
}

struct Job {
    pair: SubmapPair,
    source: Arc<PreparedCloud>,
    target: Arc<PreparedCloud>,
    prior: RelativePrior,
    params: MatcherParams,
}

struct Done {
    pair: SubmapPair,
    report: MatchReport,
}

/// The background thread's ends.
struct Worker {
    jobs: Sender<Job>,
    done: Receiver<Done>,
}

impl Worker {
    fn spawn(setup: fn()) -> Option<Worker> {
        let (jobs, job_rx) = channel::<Job>();
        let (done_tx, done) = channel::<Done>();
        std::thread::Builder::new()
            .name("matcher".into())
            .spawn(move || {
                setup();
                while let Ok(job) = job_rx.recv() {
                    let report = match_clouds(&job.source, &job.target, Some(&job.prior), &job.params);
                    if done_tx.send(Done { pair: job.pair, report }).is_err() {
                        break;
                    }
                }
            })
            .ok()?;
        Some(Worker { jobs, done })
    }
}

struct InFlight {
    pair: SubmapPair,
    started_ns: u64,
    prior_t_a_b: Isometry3<f64>,
    delta_sigma_m: Vector3<f64>,
}

/// The matcher's scheduling state of one robot.
pub struct MatchScheduler {
    own: RobotId,
    config: SchedulerConfig,
    prepared: BTreeMap<SubmapId, Arc<PreparedCloud>>,
    unsuitable: BTreeMap<SubmapId, Unsuitable>,
    queue: Vec<Candidate>,
    dirty: bool,
    next_rank_ns: u64,
    next_attempt_ns: u64,
    worker: Option<Worker>,
    in_flight: Option<InFlight>,
    /// An inline attempt's result, collected by the same `poll`.
    ready: Option<Done>,
    stats: SchedulerStats,
    log: Vec<AttemptRecord>,
}

impl std::fmt::Debug for MatchScheduler {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MatchScheduler")
            .field("own", &self.own)
            .field("prepared", &self.prepared.len())
            .field("queue", &self.queue.len())
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl MatchScheduler {
    /// A scheduler for robot `own`; with [`Executor::Background`] its thread starts here (if the
    /// thread cannot be started the attempts run inline).
    pub fn new(own: RobotId, config: SchedulerConfig) -> MatchScheduler {
        let worker = match config.executor {
            Executor::Background { setup } => Worker::spawn(setup),
            Executor::Inline => None,
        };
        MatchScheduler {
            own,
            config,
            prepared: BTreeMap::new(),
            unsuitable: BTreeMap::new(),
            queue: Vec::new(),
            dirty: false,
            next_rank_ns: 0,
            next_attempt_ns: 0,
            worker,
            in_flight: None,
            ready: None,
            stats: SchedulerStats::default(),
            log: Vec::new(),
        }
    }

    pub fn config(&self) -> &SchedulerConfig {
        &self.config
    }

    pub fn stats(&self) -> &SchedulerStats {
        &self.stats
    }

    /// Every finished attempt, in order.
    pub fn log(&self) -> &[AttemptRecord] {
        &self.log
    }

    /// The suitable submaps, ascending.
    pub fn prepared_ids(&self) -> impl Iterator<Item = SubmapId> + '_ {
        self.prepared.keys().copied()
    }

    /// A suitable submap as the matcher holds it.
    pub fn prepared(&self, id: SubmapId) -> Option<&Arc<PreparedCloud>> {
        self.prepared.get(&id)
    }

    /// Whether the submap was checked and found unsuitable, and why.
    pub fn unsuitable(&self, id: SubmapId) -> Option<&Unsuitable> {
        self.unsuitable.get(&id)
    }

    /// A finished submap (own or a peer's): size and descriptiveness checks and keypoints now.
    pub fn add_submap(&mut self, id: SubmapId, cloud: Arc<VoxelCloud>) {
        if self.prepared.contains_key(&id) || self.unsuitable.contains_key(&id) {
            return;
        }
        self.stats.submaps_added += 1;
        let prepared = PreparedCloud::new(cloud, &self.config.matcher);
        match prepared.suitability() {
            Ok(()) => {
                self.prepared.insert(id, Arc::new(prepared));
                self.dirty = true;
            }
            Err(why) => {
                self.stats.submaps_unsuitable += 1;
                *self.stats.unsuitable_by.entry(why.name()).or_default() += 1;
                self.unsuitable.insert(id, why);
            }
        }
    }

    /// Collects a finished attempt, re-ranks when due and starts the next attempt; returns the
    /// measurements to insert and send (attempt records and matches).
    pub fn poll(&mut self, now_ns: u64, graph: &mut TeamGraph) -> Vec<Measurement> {
        let mut out = Vec::new();
        self.collect(&mut out);
        if self.in_flight.is_none() {
            if (self.dirty || self.queue.is_empty()) && now_ns >= self.next_rank_ns {
                self.rerank(graph);
                self.next_rank_ns = now_ns.saturating_add(self.config.rerank_period_ns);
            }
            let inline_due = self.worker.is_some() || now_ns >= self.next_attempt_ns;
            if inline_due && self.start_next(now_ns, graph) && self.worker.is_none() {
                self.next_attempt_ns = now_ns.saturating_add(self.config.attempt_period_ns);
                self.collect(&mut out);
            }
        }
        out
    }

    fn collect(&mut self, out: &mut Vec<Measurement>) {
        let done = match &self.worker {
            _ if self.ready.is_some() => self.ready.take(),
            Some(worker) => match worker.done.try_recv() {
                Ok(done) => Some(done),
                Err(TryRecvError::Empty) => None,
                Err(TryRecvError::Disconnected) => {
                    // The thread died (it only ends when its channel closes, so a panic): run inline.
                    self.worker = None;
                    self.in_flight = None;
                    None
                }
            },
            None => None,
        };
        if let Some(done) = done {
            self.finish(done, out);
        }
    }

    fn finish(&mut self, done: Done, out: &mut Vec<Measurement>) {
        let Some(flight) = self.in_flight.take().filter(|f| f.pair == done.pair) else {
            return;
        };
        self.stats.attempts += 1;
        let record =
            AttemptRecord::new(flight.pair, flight.started_ns, flight.prior_t_a_b, flight.delta_sigma_m, &done.report);
        match record.result {
            Ok(_) => self.stats.accepted += 1,
            Err(name) => *self.stats.rejected.entry(name).or_default() += 1,
        }
        let outcome = if record.result.is_ok() { AttemptOutcome::Matched } else { AttemptOutcome::Failed };
        out.push(Measurement::Attempt(MatchAttempt { pair: flight.pair, by: self.own, outcome }));
        if let Ok(m) = &record.result {
            out.push(Measurement::Match(*m));
        }
        self.log.push(record);
    }

    /// Ranks the open pairs this robot owns among the suitable submaps of connected robots.
    fn rerank(&mut self, graph: &mut TeamGraph) {
        self.dirty = false;
        let connected = graph.estimate().connected_robots();
        let ids: Vec<SubmapId> = self.prepared.keys().copied().filter(|id| connected.contains(&id.robot)).collect();
        let pairs = graph.ledger().open_pairs(self.own, &ids);
        if pairs.is_empty() {
            self.queue.clear();
            self.stats.queued = 0;
            return;
        }
        let marginals: BTreeMap<SubmapId, Matrix3<f64>> = match graph.submap_marginals() {
            Ok(list) => list.into_iter().map(|(id, m)| (id, m.fixed_view::<3, 3>(0, 0).into_owned())).collect(),
            // Without marginals no Δσ: try again at the next ranking.
            Err(_) => return,
        };
        let placed: Vec<PlacedSubmap<'_>> = ids
            .iter()
            .filter_map(|id| {
                let t_global_submap = graph.node_pose(NodeId::Submap(*id))?;
                Some(PlacedSubmap {
                    id: *id,
                    t_global_submap,
                    position_covariance_m2: *marginals.get(id)?,
                    keypoints: self.prepared.get(id)?.keypoints(),
                })
            })
            .collect();
        let (queue, skips) = rank(&placed, &pairs, &self.config.pairing);
        self.stats.last_skips = skips;
        self.stats.queued = queue.len();
        self.queue = queue;
    }

    /// Pops the best pair still open and starts it; false when there is none.
    fn start_next(&mut self, now_ns: u64, graph: &TeamGraph) -> bool {
        while !self.queue.is_empty() {
            let candidate = self.queue.remove(0);
            let pair = candidate.pair;
            if graph.ledger().is_attempted(&pair) {
                continue;
            }
            let (Some(target), Some(source)) = (self.prepared.get(&pair.first()), self.prepared.get(&pair.second()))
            else {
                continue;
            };
            let (Some(t_global_a), Some(t_global_b)) =
                (graph.node_pose(NodeId::Submap(pair.first())), graph.node_pose(NodeId::Submap(pair.second())))
            else {
                continue;
            };
            let prior_t_a_b = t_global_a.inverse() * t_global_b;
            let delta_sigma_m = crate::pairing::delta_sigma_in_frame(&candidate.delta_sigma_m, &t_global_a);
            let prior = RelativePrior { t_target_source: prior_t_a_b, delta_sigma_m };
            let job = Job {
                pair,
                source: Arc::clone(source),
                target: Arc::clone(target),
                prior,
                params: self.config.matcher.clone(),
            };
            self.in_flight = Some(InFlight { pair, started_ns: now_ns, prior_t_a_b, delta_sigma_m });
            match &self.worker {
                Some(worker) => {
                    if let Err(returned) = worker.jobs.send(job) {
                        // The thread is gone: run this one here.
                        self.worker = None;
                        self.run_inline(returned.0);
                    }
                }
                None => self.run_inline(job),
            }
            return true;
        }
        false
    }

    fn run_inline(&mut self, job: Job) {
        let report = match_clouds(&job.source, &job.target, Some(&job.prior), &job.params);
        self.ready = Some(Done { pair: job.pair, report });
    }
}
