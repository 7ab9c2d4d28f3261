//! The simulated multi-robot mission (the project's main job): the `sim` world, every robot's
//! on-board stack, the radio links through the link emulator, a UDP feed for the ground station,
//! and the outputs: per robot the online trajectory and the ground truth (TUM), the pose graph
//! (g2o), the map (PLY, OctoMap `.bt`), and `report.json` + `report.md`.

pub mod events;
pub mod hil;
pub mod lockstep;
pub mod matching;
pub mod process;
pub mod progress;
pub mod replay;
pub mod report;
pub mod score;
pub mod screening;
pub mod world;

pub use report::{LinkTraffic, MissionReport, ProcessReport, RobotReport, SubmapTraffic, TeamScore};
pub use score::{TrajectoryScore, score};

use std::net::SocketAddr;
use std::path::{Path, PathBuf};

use nalgebra::Isometry3;

use onboard::nodes::NodeError;
use onboard::nodes::mapper::MapperNode;

/// Which runner drives the robots' stacks.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Runner {
    /// One OS process per component and robot over iceoryx2, fixed-rate tasks on the wall clock.
    Process,
    /// All components of all robots in this process on simulated time, deterministic.
    Lockstep,
}

impl Runner {
    pub fn name(self) -> &'static str {
        match self {
            Runner::Process => "process",
            Runner::Lockstep => "lockstep",
        }
    }
}

/// The radio between robots (`hal::emulator` presets).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RadioPreset {
    /// 57.6 kbit/s serial radio (the LRU's).
    SerialRadio,
    /// Lossy Wi-Fi mesh.
    Wifi,
}

/// Everything `sil mission` takes.
#[derive(Debug, Clone, PartialEq)]
pub struct MissionOptions {
    pub robots: usize,
    pub scenario: String,
    pub duration_s: f64,
    pub seed: u64,
    /// Camera resolution divisor of the simulated 1024×508 stereo head (1, 2 or 4).
    pub downscale: u32,
    pub out: PathBuf,
    pub runner: Runner,
    pub radio: RadioPreset,
    /// Loop closures from the simulator's ground truth (test-only source; reported as such).
    pub truth_loop_closures: bool,
    /// Fraction of the truth source's inter-robot closures replaced by confidently wrong ones
    /// (the outlier experiment; needs `truth_loop_closures`).
    pub wrong_closure_fraction: f64,
    /// The robots' screening of inter-robot closures (`[mapper] inter_robot_consistency`).
    pub consistency: onboard::config::InterRobotConsistency,
    /// The robots' marker detector and its uncertainty model; `None`: no detector (the
    /// simulator's cameras have tables for the `lut` models at every downscale).
    pub markers: Option<onboard::config::MarkerModelConfig>,
    /// The firmware's gaze policy points the rovers' heads (`--gaze on`); off, the simulator's
    /// script does (mounted tilt, a pan sweep at each stop).
    pub gaze: bool,
    /// The robots' submap matcher and its mode (`None`: off).
    pub matching: Option<onboard::config::MatchModeConfig>,
    /// Lockstep runner: after the mission, every pair the matchers attempted is matched again in
    /// the other mode (4D ↔ 6D) with the same prior, and scored (thesis §8.1.2).
    pub compare_match_modes: bool,
    /// Lockstep runner: after the mission, every pair of suitable submaps that truly overlaps is
    /// matched in 4D and 6D with the first robot's final estimate as the prior, and scored.
    pub evaluate_match_pairs: bool,
    /// Rocks per 100 m² instead of the scenario preset's.
    pub rocks_per_100m2: Option<f64>,
    /// Rocks in the routes' shared hub too (only the starts stay clear).
    pub rocks_in_hub: bool,
    /// Lockstep runner: no radio between the robots and no inter-robot truth closures, so each
    /// robot runs single-robot SLAM on the same route (the baseline of thesis Tab. 8.9).
    pub solo: bool,
    /// The ground station's UDP address; `None`: an in-process stand-in acknowledges the
    /// robots' ground links. Either way the ground traffic is recorded in `out/ground_feed.log`.
    pub feed: Option<SocketAddr>,
    /// Key file (`hal::keyfile`) that authenticates ground commands on every robot; `None`:
    /// every command is refused.
    pub ground_key: Option<PathBuf>,
    /// Delay, loss and outages of the emulated ground link (process runner; the lockstep
    /// runner's simulated time has no wall-clock link to emulate).
    pub ground_link: crate::relay::GroundLinkEmulation,
    /// Processes killed (SIGKILL) during the mission: process runner only.
    pub faults: Vec<process::Fault>,
    /// The mapper's submap length instead of the configuration's 7 m (process runner only;
    /// short missions use it to finish submaps).
    pub submap_max_distance_m: Option<f64>,
    /// Lockstep runner: threads that step the robots between its barriers (1: one robot after
    /// the other). The outputs do not depend on it.
    pub step_threads: usize,
    /// Lockstep runner: redraw a progress line on standard error (the CLI sets it on a terminal
    /// without `--json`).
    pub progress: bool,
    /// Lockstep runner: log every robot's graph inserts and replay them into the thesis's
    /// back-end variants after the mission (`RobotReport::replays`).
    pub replay_variants: bool,
    /// Process runner: hardware in the loop. Each robot's firmware reads its IMU over a serial
    /// line and its wheels and head over CAN from the simulator's emulated devices
    /// ([`hil::DeviceBench`]), instead of the simulator in its driver.
    pub hil: bool,
    /// HIL: device faults injected during the run.
    pub device_faults: Vec<hil::DeviceFaultEvent>,
}

impl Default for MissionOptions {
    fn default() -> Self {
        MissionOptions {
            robots: 2,
            scenario: "moon".to_owned(),
            duration_s: 120.0,
            seed: 1,
            downscale: 1,
            out: PathBuf::from("runs/demo"),
            runner: Runner::Lockstep,
            radio: RadioPreset::SerialRadio,
            truth_loop_closures: false,
            wrong_closure_fraction: 0.0,
            consistency: onboard::config::InterRobotConsistency::default(),
            markers: Some(onboard::config::MarkerModelConfig::LutOnline),
            gaze: false,
            matching: Some(onboard::config::MatchModeConfig::FourD),
            compare_match_modes: false,
            evaluate_match_pairs: false,
            rocks_per_100m2: None,
            rocks_in_hub: false,
            solo: false,
            feed: None,
            ground_key: None,
            ground_link: crate::relay::GroundLinkEmulation::default(),
            faults: Vec::new(),
            submap_max_distance_m: None,
            step_threads: std::thread::available_parallelism().map_or(1, |n| n.get()),
            progress: false,
            replay_variants: false,
            hil: false,
            device_faults: Vec::new(),
        }
    }
}

/// Why a mission could not run or write its outputs.
#[derive(Debug, thiserror::Error)]
pub enum MissionError {
    #[error("world: {0}")]
    World(String),
    #[error("set-up: {0}")]
    Setup(String),
    #[error("{0}: {1}")]
    Node(String, #[source] NodeError),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("outputs: {0}")]
    Output(String),
    #[error("process runner: {0}")]
    Process(String),
}

/// Runs the mission on the runner `options` asks for; writes the outputs and the report into
/// `options.out`.
pub fn run(options: &MissionOptions) -> Result<MissionReport, MissionError> {
    match options.runner {
        Runner::Lockstep => lockstep::run(options),
        Runner::Process => process::run_mission(options),
    }
}

/// What [`write_outputs`] wrote and measured for one robot.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotOutputs {
    pub score: Option<TrajectoryScore>,
    pub score_error: Option<String>,
    pub graph_nodes: usize,
    pub graph_factors: usize,
    pub connected: Vec<u16>,
    pub submaps_finished: u64,
    pub submaps_received: u64,
}

fn write_tum(path: &Path, rows: &[(u64, Isometry3<f64>)]) -> Result<(), MissionError> {
    onboard::tum::write_tum(path, rows, 0).map_err(|e| MissionError::Io { path: path.to_owned(), source: e })
}

/// Writes one robot's outputs into `dir`: `estimate.tum` (the online estimate in the robot's own
/// frame), `truth.tum` (the ground truth in the same frame), and the mapper's `graph.g2o`,
/// `map.ply`, `map.bt`, `map.png`; scores the estimate.
pub fn write_outputs(
    dir: &Path,
    mapper: &mut MapperNode,
    estimate: &[(u64, Isometry3<f64>)],
    truth: Option<&[(u64, Isometry3<f64>)]>,
) -> Result<RobotOutputs, MissionError> {
    std::fs::create_dir_all(dir).map_err(|e| MissionError::Io { path: dir.to_owned(), source: e })?;
    let written = mapper.write_outputs(dir).map_err(|e| MissionError::Output(e.to_string()))?;
    let (mut score, mut score_error) = (None, None);
    if !estimate.is_empty() {
        write_tum(&dir.join("estimate.tum"), estimate)?;
    }
    match truth {
        Some(truth) if !truth.is_empty() => {
            write_tum(&dir.join("truth.tum"), truth)?;
            match score::score(estimate, truth) {
                Ok(s) => score = Some(s),
                Err(e) => score_error = Some(e.to_string()),
            }
        }
        _ => score_error = Some("the filter never initialized".to_owned()),
    }
    let estimate_now = mapper.team_estimate();
    Ok(RobotOutputs {
        score,
        score_error,
        graph_nodes: written.graph.nodes,
        graph_factors: written.graph.factors,
        connected: estimate_now.connected_robots(),
        submaps_finished: written.counters.submaps_finished,
        submaps_received: written.counters.submaps_received,
    })
}

/// Writes `report.json` and `report.md` into `out`.
pub fn write_report(out: &Path, report: &MissionReport) -> Result<(), MissionError> {
    let json_path = out.join("report.json");
    let text = serde_json::to_string_pretty(&report.to_json()).map_err(|e| MissionError::Output(e.to_string()))?;
    std::fs::write(&json_path, text + "\n").map_err(|e| MissionError::Io { path: json_path, source: e })?;
    let md_path = out.join("report.md");
    std::fs::write(&md_path, report.to_markdown()).map_err(|e| MissionError::Io { path: md_path, source: e })
}
