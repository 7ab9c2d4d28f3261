//! The mission report: `report.json` (machine-readable), `report.md` and the printed summary.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde_json::{Value, json};

use super::score::TrajectoryScore;

/// What one robot ended with.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotReport {
    pub robot: u16,
    /// `None` when the robot's trajectory could not be scored (reason in `score_error`).
    pub score: Option<TrajectoryScore>,
    pub score_error: Option<String>,
    pub graph_nodes: usize,
    pub graph_factors: usize,
    /// Robots connected to this robot's frame at the end (itself included).
    pub connected: Vec<u16>,
    pub submaps_finished: u64,
    pub submaps_received: u64,
    pub imu_received: u64,
    /// IMU samples lost between the driver and the filter (sequence gaps).
    pub imu_lost: u64,
    /// Bytes this robot put on its links, by protocol message class.
    pub bytes_sent_by_class: BTreeMap<String, u64>,
    /// Tags the vision process published (after the 75° gate), and the robot detections the
    /// mapper made of them (one image per robot and interval, within range).
    pub markers_published: u64,
    pub marker_detections: u64,
    /// Per connected robot: distance between its latest pose in this robot's graph and its true
    /// pose at that stamp in this robot's frame (the team's relative localization). Lockstep
    /// runner only: the process runner's graphs live in the robots' processes.
    pub inter_robot_error_m: BTreeMap<u16, f64>,
    /// The submap matcher's attempts and matches (`None`: it did not run).
    pub matching: Option<super::matching::MatchingReport>,
    /// What this robot's own submaps cost on its links (`None`: not measured, the process
    /// runner's comms stats file has no per-link split).
    pub submap_traffic: Option<SubmapTraffic>,
    /// The robot's graph inserts replayed into the thesis's back-end variants (lockstep runner
    /// with `replay_variants`; empty otherwise).
    pub replays: Vec<super::replay::ReplayScore>,
    /// Loop closures as the graph took them in (lockstep runs that log graph inserts).
    pub closure_events: Vec<super::events::ClosureEvent>,
    /// The mapper's per-step times (lockstep runs; the process runner's mapper keeps its own).
    pub step_times: Option<onboard::nodes::mapper::MapperStepTimes>,
}

/// One robot's submap traffic: `SubmapHeader` and `SubmapChunk` packets it put on its links,
/// against the encoded size of the submaps it finished (issue 28: bytes as measured).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SubmapTraffic {
    /// Own finished submaps and their encoded bytes (the `.subm` files: one copy's payload).
    pub submaps: u64,
    pub payload_bytes: u64,
    /// To the other robots (every team link) and to the ground.
    pub team: LinkTraffic,
    pub ground: LinkTraffic,
}

/// Packets of one kind on one class of link.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkTraffic {
    pub packets: u64,
    /// What the packets cost on the link, framing included, retransmissions included.
    pub wire_bytes: u64,
    pub retransmissions: u64,
}

impl LinkTraffic {
    fn to_json(self) -> Value {
        json!({"packets": self.packets, "wire_bytes": self.wire_bytes, "retransmissions": self.retransmissions})
    }
}

impl SubmapTraffic {
    /// All links' wire bytes per second of mission.
    pub fn wire_bytes_per_s(&self, duration_s: f64) -> f64 {
        (self.team.wire_bytes + self.ground.wire_bytes) as f64 / duration_s.max(f64::MIN_POSITIVE)
    }

    fn to_json(self, duration_s: f64) -> Value {
        json!({
            "submaps": self.submaps,
            "payload_bytes": self.payload_bytes,
            "team": self.team.to_json(),
            "ground": self.ground.to_json(),
            "wire_bytes_per_s": self.wire_bytes_per_s(duration_s),
        })
    }
}

/// The fixed-rate task of one process, as its task file reports it (process runner only: the
/// lockstep runner has no wall-clock tasks to time).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaskTiming {
    pub releases: u64,
    pub deadline_overruns: u64,
    pub skipped_releases: u64,
    pub jitter_p50_us: f64,
    pub jitter_p99_us: f64,
    pub jitter_max_us: f64,
}

/// One process (process runner) or node (lockstep runner) of one robot.
#[derive(Debug, Clone, PartialEq)]
pub struct ProcessReport {
    pub robot: u16,
    pub process: String,
    /// `None`: not measured (the lockstep runner, or a process that wrote no task file).
    pub timing: Option<TaskTiming>,
    /// CPU time of the process (lockstep: time spent in the node's handlers).
    pub cpu_s: f64,
    pub restarts: u64,
}

impl ProcessReport {
    /// A node of the lockstep runner: its handler time, no task timing.
    pub fn lockstep(robot: u16, process: &str, cpu_s: f64) -> ProcessReport {
        ProcessReport { robot, process: process.to_owned(), timing: None, cpu_s, restarts: 0 }
    }
}

/// The whole mission.
#[derive(Debug, Clone, PartialEq)]
pub struct MissionReport {
    pub runner: String,
    pub scenario: String,
    pub seed: u64,
    pub duration_s: f64,
    pub wall_s: f64,
    /// Loop closures came from the simulator's ground truth (test-only source), not from the
    /// robots' own detector and matcher.
    pub truth_loop_closures: bool,
    /// The robots ran alone (`--solo`): no radio between them.
    pub solo: bool,
    /// The marker uncertainty model of the robots' detector; `None`: no detector ran.
    pub marker_model: Option<String>,
    /// The outlier experiment's screening counts (lockstep runner with truth closures).
    pub closure_screening: Option<super::screening::ClosureScreening>,
    pub robots: Vec<RobotReport>,
    pub processes: Vec<ProcessReport>,
    /// The first robot's truly overlapping submap pairs matched in 4D and 6D (`evaluate_match_pairs`).
    pub pair_evaluation: Option<super::matching::PairEvaluation>,
}

/// Team aggregate of the scored robots: distance and errors averaged over robots, the maximum
/// error over robots.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TeamScore {
    pub distance_m: f64,
    pub mean_error_m: f64,
    pub rmse_m: f64,
    pub max_error_m: f64,
    pub final_error_m: f64,
    pub final_error_percent: f64,
}

impl MissionReport {
    pub fn team_score(&self) -> Option<TeamScore> {
        let scores: Vec<&TrajectoryScore> = self.robots.iter().filter_map(|r| r.score.as_ref()).collect();
        if scores.is_empty() {
            return None;
        }
        let n = scores.len() as f64;
        let mean = |f: &dyn Fn(&TrajectoryScore) -> f64| scores.iter().map(|s| f(s)).sum::<f64>() / n;
        Some(TeamScore {
            distance_m: mean(&|s| s.distance_m),
            mean_error_m: mean(&|s| s.mean_error_m),
            rmse_m: mean(&|s| s.rmse_m),
            max_error_m: scores.iter().map(|s| s.max_error_m).fold(0.0, f64::max),
            final_error_m: mean(&|s| s.final_error_m),
            final_error_percent: mean(&|s| s.final_error_percent.unwrap_or(0.0)),
        })
    }

    /// Overruns of all tasks; `None` when no task was timed (the lockstep runner).
    pub fn deadline_overruns(&self) -> Option<u64> {
        let timed: Vec<&TaskTiming> = self.processes.iter().filter_map(|p| p.timing.as_ref()).collect();
        (!timed.is_empty()).then(|| timed.iter().map(|t| t.deadline_overruns).sum())
    }

    /// The sources of loop closures (robot detections, submap matches) that ran in the mission.
    pub fn loop_closure_sources(&self) -> Vec<String> {
        let mut sources = Vec::new();
        if let Some(model) = &self.marker_model {
            let tags: u64 = self.robots.iter().map(|r| r.markers_published).sum();
            let detections: u64 = self.robots.iter().map(|r| r.marker_detections).sum();
            sources.push(format!(
                "robot detections (AprilTag tag36h11, on-board, {model} model): {tags} tags seen, {detections} in the graphs"
            ));
        }
        let matchers: Vec<&super::matching::MatchingReport> =
            self.robots.iter().filter_map(|r| r.matching.as_ref()).collect();
        if !matchers.is_empty() {
            let attempts: u64 = matchers.iter().map(|m| m.attempts).sum();
            let accepted: u64 = matchers.iter().map(|m| m.accepted).sum();
            sources.push(format!("submap matches (on-board 4D matcher): {attempts} attempts, {accepted} accepted"));
        }
        if self.truth_loop_closures {
            sources.push("simulator ground truth (test-only: sim::truth_constraints)".to_owned());
        }
        sources
    }

    fn loop_closure_line(&self) -> String {
        let sources = self.loop_closure_sources();
        if sources.is_empty() {
            "loop closures: none ran (robot detector and submap matcher off): each robot's graph holds \
             only its own odometry"
                .to_owned()
        } else {
            format!("loop closures: {}", sources.join("; "))
        }
    }

    /// Inter-robot errors as `robot→other d m` items.
    fn inter_robot_text(r: &RobotReport) -> String {
        if r.inter_robot_error_m.is_empty() {
            return "-".to_owned();
        }
        r.inter_robot_error_m.iter().map(|(other, e)| format!("{other}: {e:.2} m")).collect::<Vec<_>>().join(", ")
    }

    /// `report.json`: the team aggregate at the top level, then per robot and per process.
    pub fn to_json(&self) -> Value {
        let team = self.team_score();
        let robots: Vec<Value> = self
            .robots
            .iter()
            .map(|r| {
                let s = r.score.as_ref();
                json!({
                    "robot": r.robot,
                    "distance_m": s.map(|s| s.distance_m),
                    "mean_error_m": s.map(|s| s.mean_error_m),
                    "rmse_m": s.map(|s| s.rmse_m),
                    "max_error_m": s.map(|s| s.max_error_m),
                    "final_error_m": s.map(|s| s.final_error_m),
                    "final_error_percent": s.and_then(|s| s.final_error_percent),
                    "mean_yaw_error_deg": s.map(|s| s.mean_yaw_error_deg),
                    "poses": s.map(|s| s.poses),
                    "score_error": r.score_error,
                    "graph_nodes": r.graph_nodes,
                    "graph_factors": r.graph_factors,
                    "connected": r.connected,
                    "submaps_finished": r.submaps_finished,
                    "submaps_received": r.submaps_received,
                    "imu_received": r.imu_received,
                    "imu_lost": r.imu_lost,
                    "bytes_sent_by_class": r.bytes_sent_by_class,
                    "markers_published": r.markers_published,
                    "marker_detections": r.marker_detections,
                    "inter_robot_error_m": r.inter_robot_error_m,
                    "matching": r.matching.as_ref().map(super::matching::MatchingReport::to_json),
                    "submap_traffic": r.submap_traffic.map(|t| t.to_json(self.duration_s)),
                    "step_times_ms": r.step_times.map(|t| {
                        let ms = |s: &onboard::nodes::mapper::StepTime| json!({
                            "count": s.count,
                            "mean": s.mean_s().map(|v| v * 1e3),
                            "max": s.max_s * 1e3,
                        });
                        json!({
                            "graph_update": ms(&t.graph_update),
                            "integration": ms(&t.integration),
                            "matcher_poll": ms(&t.matcher_poll),
                            "composition": ms(&t.composition),
                        })
                    }),
                    "closure_events": r.closure_events.iter().map(|e| json!({
                        "stamp_s": e.stamp_ns as f64 * 1e-9,
                        "kind": e.kind.name(),
                    })).collect::<Vec<_>>(),
                    "replays": r.replays.iter().map(|v| json!({
                        "variant": v.variant,
                        "mean_error_m": v.score.as_ref().map(|s| s.mean_error_m),
                        "max_error_m": v.score.as_ref().map(|s| s.max_error_m),
                        "mean_yaw_error_deg": v.score.as_ref().map(|s| s.mean_yaw_error_deg),
                        "distance_m": v.score.as_ref().map(|s| s.distance_m),
                        "error": v.error,
                        "nodes": v.nodes,
                        "factors": v.factors,
                    })).collect::<Vec<_>>(),
                })
            })
            .collect();
        let processes: Vec<Value> = self
            .processes
            .iter()
            .map(|p| {
                let timing = p.timing.map_or(Value::Null, |t| {
                    json!({
                        "releases": t.releases,
                        "deadline_overruns": t.deadline_overruns,
                        "skipped_releases": t.skipped_releases,
                        "jitter_p50_us": t.jitter_p50_us,
                        "jitter_p99_us": t.jitter_p99_us,
                        "jitter_max_us": t.jitter_max_us,
                    })
                });
                json!({
                    "robot": p.robot,
                    "process": p.process,
                    "task_timing": timing,
                    "cpu_s": p.cpu_s,
                    "restarts": p.restarts,
                })
            })
            .collect();
        json!({
            "runner": self.runner,
            "scenario": self.scenario,
            "seed": self.seed,
            "robots_count": self.robots.len(),
            "duration_s": self.duration_s,
            "wall_s": self.wall_s,
            "truth_loop_closures": self.truth_loop_closures,
            "solo": self.solo,
            "marker_model": self.marker_model,
            "loop_closure_sources": self.loop_closure_sources(),
            "closure_screening": self.closure_screening.as_ref().map(super::screening::ClosureScreening::to_json),
            "distance_m": team.map(|t| t.distance_m),
            "mean_error_m": team.map(|t| t.mean_error_m),
            "rmse_m": team.map(|t| t.rmse_m),
            "max_error_m": team.map(|t| t.max_error_m),
            "final_error_m": team.map(|t| t.final_error_m),
            "final_error_percent": team.map(|t| t.final_error_percent),
            "deadline_overruns": self.deadline_overruns(),
            "imu_lost": self.robots.iter().map(|r| r.imu_lost).sum::<u64>(),
            "robots": robots,
            "processes": processes,
            "pair_evaluation": self.pair_evaluation.as_ref().map(super::matching::PairEvaluation::to_json),
        })
    }

    /// The short human summary the command prints.
    pub fn summary(&self) -> String {
        let mut out = String::new();
        let _ = writeln!(
            out,
            "mission: {} robots, {} scenario, seed {}, {:.0} s simulated in {:.1} s ({} runner)",
            self.robots.len(),
            self.scenario,
            self.seed,
            self.duration_s,
            self.wall_s,
            self.runner
        );
        if self.truth_loop_closures {
            let _ = writeln!(out, "LOOP CLOSURES FROM GROUND TRUTH (sim::truth_constraints, test-only)");
        }
        if self.solo {
            let _ = writeln!(out, "robots alone (--solo): no radio between them, single-robot SLAM each");
        }
        let _ = writeln!(out, "{}", self.loop_closure_line());
        if let Some(screening) = &self.closure_screening {
            let _ = writeln!(out, "{}", screening.line());
        }
        let _ = writeln!(
            out,
            "robot  distance  mean err  rmse     max err  final err  final %  graph (nodes/factors)  connected  submaps  imu lost"
        );
        for r in &self.robots {
            let graph = format!("{}/{}", r.graph_nodes, r.graph_factors);
            let connected = format!("{:?}", r.connected);
            match &r.score {
                Some(s) => {
                    let _ = writeln!(
                        out,
                        "{:>5}  {:>6.1} m  {:>6.3} m  {:>6.3} m  {:>6.3} m  {:>7.3} m  {:>6.2}  {:>21}  {:>9}  {:>7}  {:>8}",
                        r.robot,
                        s.distance_m,
                        s.mean_error_m,
                        s.rmse_m,
                        s.max_error_m,
                        s.final_error_m,
                        s.final_error_percent.unwrap_or(0.0),
                        graph,
                        connected,
                        r.submaps_finished,
                        r.imu_lost
                    );
                }
                None => {
                    let reason = r.score_error.as_deref().unwrap_or("no estimate");
                    let _ = writeln!(out, "{:>5}  not scored: {reason}", r.robot);
                }
            }
        }
        if self.marker_model.is_some() {
            for r in &self.robots {
                let _ = writeln!(
                    out,
                    "robot {}: {} tags seen, {} detections in its graph; other robots' latest poses off by {}",
                    r.robot,
                    r.markers_published,
                    r.marker_detections,
                    Self::inter_robot_text(r)
                );
            }
        }
        for r in &self.robots {
            if let Some(m) = &r.matching {
                let _ = writeln!(out, "robot {} matcher: {}", r.robot, m.summary_line());
            }
        }
        if let Some(e) = &self.pair_evaluation {
            let _ = writeln!(out, "{}", e.summary_line());
        }
        let cpu: f64 = self.processes.iter().map(|p| p.cpu_s).sum();
        let overruns = self.deadline_overruns().map_or("not measured (lockstep)".to_owned(), |n| n.to_string());
        let _ = writeln!(
            out,
            "deadline overruns {overruns}, restarts {}, CPU {:.1} s",
            self.processes.iter().map(|p| p.restarts).sum::<u64>(),
            cpu
        );
        out
    }

    /// `report.md`.
    pub fn to_markdown(&self) -> String {
        let mut out = String::from("# Mission report\n\n");
        let _ = writeln!(
            out,
            "{} robots, `{}` scenario, seed {}, {:.0} s of simulated time in {:.1} s of wall time, `{}` runner.\n",
            self.robots.len(),
            self.scenario,
            self.seed,
            self.duration_s,
            self.wall_s,
            self.runner
        );
        if self.truth_loop_closures {
            out.push_str(
                "**Loop closures came from the simulator's ground truth** (`sim::truth_constraints`, a \
                 test-only source with the thesis's noise models), not from the robots' own detector and matcher.\n\n",
            );
        }
        let _ = writeln!(out, "{}.\n", self.loop_closure_line());
        if let Some(screening) = &self.closure_screening {
            let _ = writeln!(out, "{}.\n", screening.line());
        }
        out.push_str("## Online trajectory errors (thesis ch. 8: the estimate as the robot had it)\n\n");
        out.push_str("| robot | distance | mean | RMSE | max | final | final % | graph nodes / factors | connected | submaps finished / received | IMU lost |\n");
        out.push_str("|---|---|---|---|---|---|---|---|---|---|---|\n");
        for r in &self.robots {
            match &r.score {
                Some(s) => {
                    let _ = writeln!(
                        out,
                        "| {} | {:.1} m | {:.3} m | {:.3} m | {:.3} m | {:.3} m | {:.2} % | {} / {} | {:?} | {} / {} | {} |",
                        r.robot,
                        s.distance_m,
                        s.mean_error_m,
                        s.rmse_m,
                        s.max_error_m,
                        s.final_error_m,
                        s.final_error_percent.unwrap_or(0.0),
                        r.graph_nodes,
                        r.graph_factors,
                        r.connected,
                        r.submaps_finished,
                        r.submaps_received,
                        r.imu_lost
                    );
                }
                None => {
                    let _ = writeln!(
                        out,
                        "| {} | not scored: {} | | | | | | {} / {} | {:?} | {} / {} | {} |",
                        r.robot,
                        r.score_error.as_deref().unwrap_or("no estimate"),
                        r.graph_nodes,
                        r.graph_factors,
                        r.connected,
                        r.submaps_finished,
                        r.submaps_received,
                        r.imu_lost
                    );
                }
            }
        }
        if let Some(model) = &self.marker_model {
            let _ = writeln!(
                out,
                "\n## Robot detections (on-board AprilTag detector, {model} model)\n\n| robot | tags seen | detections in its graph | other robots' latest poses off by |\n|---|---|---|---|"
            );
            for r in &self.robots {
                let _ = writeln!(
                    out,
                    "| {} | {} | {} | {} |",
                    r.robot,
                    r.markers_published,
                    r.marker_detections,
                    Self::inter_robot_text(r)
                );
            }
        }
        if self.robots.iter().any(|r| r.matching.is_some()) {
            out.push_str("\n## Submap matcher (thesis §6.1)\n\n");
            for r in &self.robots {
                if let Some(m) = &r.matching {
                    let _ = writeln!(out, "- robot {}: {}", r.robot, m.summary_line());
                }
            }
        }
        if let Some(e) = &self.pair_evaluation {
            let _ = writeln!(out, "\n## Pair evaluation\n\n{}", e.summary_line());
        }
        if self.robots.iter().any(|r| r.submap_traffic.is_some()) {
            out.push_str(
                "\n## Submap traffic (own submaps, header and chunks, framing included)\n\n| robot | submaps | encoded bytes | team wire bytes (retransmitted packets) | ground wire bytes (retransmitted packets) | all links bytes/s |\n|---|---|---|---|---|---|\n",
            );
            for r in &self.robots {
                if let Some(t) = &r.submap_traffic {
                    let _ = writeln!(
                        out,
                        "| {} | {} | {} | {} ({}) | {} ({}) | {:.0} |",
                        r.robot,
                        t.submaps,
                        t.payload_bytes,
                        t.team.wire_bytes,
                        t.team.retransmissions,
                        t.ground.wire_bytes,
                        t.ground.retransmissions,
                        t.wire_bytes_per_s(self.duration_s)
                    );
                }
            }
        }
        out.push_str("\n## Bytes sent per message class\n\n| robot | class | bytes |\n|---|---|---|\n");
        for r in &self.robots {
            for (class, bytes) in &r.bytes_sent_by_class {
                let _ = writeln!(out, "| {} | {class} | {bytes} |", r.robot);
            }
        }
        out.push_str(
            "\n## Processes\n\n| robot | process | releases | deadline overruns | skipped | jitter p50 / p99 / max | CPU | restarts |\n|---|---|---|---|---|---|---|---|\n",
        );
        for p in &self.processes {
            let timing = match &p.timing {
                Some(t) => format!(
                    "{} | {} | {} | {:.0} / {:.0} / {:.0} µs",
                    t.releases,
                    t.deadline_overruns,
                    t.skipped_releases,
                    t.jitter_p50_us,
                    t.jitter_p99_us,
                    t.jitter_max_us
                ),
                None => "not measured | not measured | not measured | not measured".to_owned(),
            };
            let _ = writeln!(out, "| {} | {} | {timing} | {:.2} s | {} |", p.robot, p.process, p.cpu_s, p.restarts);
        }
        if self.processes.iter().any(|p| p.timing.is_none()) {
            out.push_str(
                "\nTask timing (releases, overruns, jitter) is measured by the process runner's fixed-rate tasks \
                 on the wall clock; the lockstep runner runs on simulated time and has none (its CPU column is \
                 the time spent in each node's handlers).\n",
            );
        }
        out
    }
}
