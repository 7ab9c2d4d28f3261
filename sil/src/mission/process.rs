//! The mission on the process runner: one firmware supervisor per robot (`sil run`: the
//! firmware's `onboard run` with the simulator as the driver's source, each starting the robot's
//! five processes over its own iceoryx2 bus), the radios between the robots as a UDP [`Relay`]
//! in this process, all on the wall clock from one shared epoch.
//!
//! Per robot it writes `robotN/rover.toml` (the configuration the lockstep runner builds the same
//! robot from, plus links and real-time settings) and points the robot's output folder at
//! `robotN/`. The epoch is fixed once every process is ready (the driver first rebuilds the
//! deterministic world itself): the mission writes it into `epoch_ns`, which the processes wait
//! for ([`onboard::process::EPOCH_FILE_ENV`]); after `duration_s` of sensor time plus a short
//! tail the supervisors get SIGTERM, and the processes write their files (see
//! [`onboard::process`]), from which the report is made: the online estimate scored against the
//! world's truth in the robot's own frame, as the lockstep runner scores it.
//!
//! Loop closures from the simulator's ground truth (`--truth-loop-closures`) exist only on the
//! lockstep runner, which can reach into every robot's mapper at every step; this runner refuses
//! them rather than write a report that claims them.
//!
//! # Fault injection
//! [`MissionOptions::faults`] (`sil mission --kill 1:mapper@22`): at that sensor time the
//! mission sends SIGKILL to the process, whose pid it reads from the supervisor's
//! `robotN/pids/<process>` (checked to be a child of that supervisor). Each kill is recorded in
//! `faults.json` in the output folder, with the robot's finished submaps on disk at that moment
//! (`state/submaps/`), so that a test can check that none is lost.

use std::net::{SocketAddr, UdpSocket};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::str::FromStr;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::{Value, json};

use onboard::config::{DriverKind, LinkKind, PeerConfig, RoverConfig};
use onboard::process::{EPOCH_FILE_ENV, NodeKind, PID_DIR, READY_DIR, monotonic_ns, read_json, write_json};
use sim::world::World;

use super::hil::DeviceBench;
use super::report::{MissionReport, ProcessReport, RobotReport, TaskTiming};
use super::world::{
    marker_model_name, mission_world, robot_config as mission_robot_config, robot_id, truth_at_captures,
    truth_in_own_frame,
};
use super::{MissionError, MissionOptions, RadioPreset, score};
use crate::ground_end::GroundEnd;
use crate::relay::{GroundLinkEmulation, Relay};

/// After the last sensor stamp: time for the last frames to cross vision, filter and mapper.
const TAIL: Duration = Duration::from_millis(1_500);
/// How long the supervisors get to stop their processes (theirs is 30 s per process).
const STOP_WAIT: Duration = Duration::from_secs(45);
/// From the moment every process is ready to sensor time 0: time for the processes to see the
/// epoch file (they poll it every 10 ms).
const START_DELAY: Duration = Duration::from_millis(300);
const RELAY_PERIOD: Duration = Duration::from_millis(1);

/// A process killed with SIGKILL during a process-runner mission.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fault {
    /// Robot index: the `robotN/` folder (the report's robot id is `N + 1`).
    pub robot: usize,
    pub process: NodeKind,
    /// Sensor time of the kill, seconds since the mission start.
    pub at_s: f64,
}

impl FromStr for Fault {
    type Err = String;

    /// `[ROBOT:]PROCESS@SECONDS`, robot index 0 when omitted: `mapper@12`, `1:filter@20.5`.
    fn from_str(text: &str) -> Result<Fault, String> {
        let usage = || format!("{text:?}: expected [ROBOT:]PROCESS@SECONDS, e.g. 1:mapper@12");
        let (target, at) = text.split_once('@').ok_or_else(usage)?;
        let (robot, process) = match target.split_once(':') {
            Some((robot, process)) => (robot.parse::<usize>().map_err(|_| usage())?, process),
            None => (0, target),
        };
        let process = NodeKind::parse(process)
            .ok_or_else(|| format!("{text:?}: unknown process {process:?} (driver, vision, filter, mapper, comms)"))?;
        let at_s = at.parse::<f64>().ok().filter(|t| t.is_finite() && *t >= 0.0).ok_or_else(usage)?;
        Ok(Fault { robot, process, at_s })
    }
}

/// The faults of a mission, each injected once.
struct FaultPlan {
    pending: Vec<Fault>,
    done: Vec<Value>,
}

impl FaultPlan {
    fn new(faults: &[Fault]) -> FaultPlan {
        let mut pending = faults.to_vec();
        // Latest first: the next one due is popped from the end.
        pending.sort_by(|a, b| b.at_s.total_cmp(&a.at_s));
        FaultPlan { pending, done: Vec::new() }
    }

    fn inject_due(&mut self, now_s: f64, dirs: &[(PathBuf, PathBuf)], supervisors: &[Child]) {
        while self.pending.last().is_some_and(|f| f.at_s <= now_s) {
            let Some(fault) = self.pending.pop() else { return };
            let record = match (dirs.get(fault.robot), supervisors.get(fault.robot)) {
                (Some((dir, _)), Some(supervisor)) => kill_process(&fault, dir, supervisor.id(), now_s),
                _ => json!({"robot": fault.robot, "process": fault.process.name(), "at_s": fault.at_s,
                            "error": format!("no robot {}", fault.robot)}),
            };
            eprintln!("mission: fault {record}");
            self.done.push(record);
        }
    }
}

/// Own submaps the robot's mapper has persisted (`state/submaps/{index}.subm`), ascending.
pub fn persisted_submaps(dir: &Path) -> Vec<u32> {
    let mut indices: Vec<u32> = std::fs::read_dir(dir.join("state").join("submaps"))
        .map(|entries| {
            entries
                .filter_map(|e| e.ok())
                .filter_map(|e| e.file_name().to_str()?.strip_suffix(".subm")?.parse().ok())
                .collect()
        })
        .unwrap_or_default();
    indices.sort_unstable();
    indices
}

/// The parent pid in `/proc/<pid>/stat` (the field after the parenthesized command name).
fn parent_pid(pid: u32) -> Option<u32> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let after_name = &stat[stat.rfind(')')? + 1..];
    after_name.split_whitespace().nth(1)?.parse().ok()
}

fn kill_process(fault: &Fault, dir: &Path, supervisor_pid: u32, now_s: f64) -> Value {
    let submaps_before = persisted_submaps(dir);
    let pid_path = dir.join(PID_DIR).join(fault.process.name());
    let pid = std::fs::read_to_string(&pid_path).ok().and_then(|t| t.trim().parse::<u32>().ok());
    let result = match pid {
        None => Err(format!("no pid in {}", pid_path.display())),
        // A pid file of an exited process may name an unrelated process by now.
        Some(pid) if parent_pid(pid) != Some(supervisor_pid) => {
            Err(format!("pid {pid} is not a child of the supervisor {supervisor_pid}"))
        }
        Some(pid) => i32::try_from(pid)
            .map_err(|e| e.to_string())
            .and_then(|p| kill(Pid::from_raw(p), Signal::SIGKILL).map_err(|e| e.to_string())),
    };
    json!({
        "robot": fault.robot,
        "process": fault.process.name(),
        "at_s": fault.at_s,
        "killed_at_s": now_s,
        "pid": pid,
        "error": result.err(),
        "submaps_before": submaps_before,
    })
}

fn setup(e: impl std::fmt::Display) -> MissionError {
    MissionError::Setup(e.to_string())
}

fn process_error(e: impl std::fmt::Display) -> MissionError {
    MissionError::Process(e.to_string())
}

fn radio_config(preset: RadioPreset) -> hal::emulator::EmulatorConfig {
    match preset {
        RadioPreset::SerialRadio => hal::emulator::EmulatorConfig::serial_radio_57k6(),
        RadioPreset::Wifi => hal::emulator::EmulatorConfig::lossy_wifi(),
    }
}

/// iceoryx2 ids of this mission's robots: distinct per mission process (parallel tests), clear
/// of the ids the bus tests use (40 000 and up).
fn bus_id(robot: usize) -> u16 {
    (10_000 + (std::process::id() % 1_800) * 16) as u16 + robot as u16
}

fn free_local_port() -> Result<SocketAddr, MissionError> {
    // Bound and released: the comms process binds it moments later (a small race with other
    // programs taking the same port, acceptable on a test machine).
    let socket = UdpSocket::bind("127.0.0.1:0").map_err(setup)?;
    socket.local_addr().map_err(setup)
}

fn robot_config(
    options: &MissionOptions,
    world: &World,
    robot: usize,
    dir: &Path,
    bind: SocketAddr,
    relay: &Relay,
) -> Result<RoverConfig, MissionError> {
    let mut config = mission_robot_config(options, world, robot)?;
    config.robot.bus_id = Some(bus_id(robot));
    config.robot.output_dir = Some(dir.to_owned());
    config.link.kind = LinkKind::Udp;
    config.link.bind = bind.to_string();
    config.link.bandwidth_bytes_per_s = radio_config(options.radio).bandwidth_bytes_per_s;
    config.link.peers = (0..options.robots)
        .filter(|&p| p != robot)
        .map(|p| {
            let address = relay.peer_addr(robot, p).ok_or_else(|| setup(format!("relay socket {robot}->{p}")))?;
            Ok(PeerConfig { robot_id: p as u16, address: address.to_string() })
        })
        .collect::<Result<_, MissionError>>()?;
    // The ground link goes through the relay, which delays it and talks to the ground station.
    let ground = relay.ground_addr(robot).ok_or_else(|| setup(format!("relay ground socket of robot {robot}")))?;
    config.link.ground_feed = Some(ground.to_string());
    config.link.ground_key_file = options.ground_key.clone();
    // The filter's path must not wait behind vision or mapping (DESIGN §3.2): the filter and the
    // sensor driver that feeds it run SCHED_FIFO when the system permits (skipped with a log line
    // otherwise); their bodies are short, so they cannot starve the rest.
    config.realtime.filter.fifo_priority = Some(80);
    config.realtime.driver.fifo_priority = Some(70);
    config.validate().map_err(|e| setup(format!("robot {robot} configuration: {e}")))?;
    Ok(config)
}

/// Files of an earlier run in this folder that must not be mistaken for this run's.
fn clear_robot_dir(dir: &Path) -> Result<(), MissionError> {
    for name in ["state", "tasks", READY_DIR, PID_DIR] {
        let path = dir.join(name);
        if path.exists() {
            std::fs::remove_dir_all(&path).map_err(|e| MissionError::Io { path: path.clone(), source: e })?;
        }
    }
    for name in [
        "filter_summary.json",
        "mapper_status.json",
        "comms_stats.json",
        "supervisor.json",
        "estimate.tum",
        "truth.tum",
    ] {
        let path = dir.join(name);
        if path.exists() {
            std::fs::remove_file(&path).map_err(|e| MissionError::Io { path: path.clone(), source: e })?;
        }
    }
    Ok(())
}

/// Runs the mission on the process runner with this executable as `sil`.
pub fn run_mission(options: &MissionOptions) -> Result<MissionReport, MissionError> {
    let exe = std::env::current_exe().map_err(setup)?;
    run_mission_with_exe(options, &exe)
}

/// Runs the mission on the process runner, starting the supervisors as `exe run` (tests pass
/// the `sil` binary; their own executable is the test harness).
pub fn run_mission_with_exe(options: &MissionOptions, exe: &Path) -> Result<MissionReport, MissionError> {
    if options.truth_loop_closures {
        return Err(MissionError::Setup(
            "--truth-loop-closures runs on the lockstep runner only (it reaches into every robot's mapper at \
             every step); the process runner has no loop-closure source yet"
                .into(),
        ));
    }
    let wall = Instant::now();
    let out =
        std::path::absolute(&options.out).map_err(|e| MissionError::Io { path: options.out.clone(), source: e })?;
    std::fs::create_dir_all(&out).map_err(|e| MissionError::Io { path: out.clone(), source: e })?;
    let build_start = Instant::now();
    let world = mission_world(options)?;
    let build_time = build_start.elapsed();

    let radio = radio_config(options.radio);
    let mut relay = Relay::bind(options.robots, &radio, options.seed).map_err(setup)?;
    let nodes: Vec<protocol::NodeId> = (0..options.robots).map(|r| protocol::NodeId(robot_id(r) as u8)).collect();
    let ground_log = out.join(super::lockstep::GROUND_FEED_LOG);
    let ground = GroundEnd::new(options.feed, &nodes, Some(&ground_log)).map_err(setup)?;
    relay
        .enable_ground(&nodes, ground, &GroundLinkEmulation { seed: options.seed, ..options.ground_link.clone() })
        .map_err(setup)?;
    let mut configs = Vec::new();
    let mut benches = Vec::new();
    for robot in 0..options.robots {
        let dir = robot_dir(&out, robot);
        std::fs::create_dir_all(&dir).map_err(|e| MissionError::Io { path: dir.clone(), source: e })?;
        clear_robot_dir(&dir)?;
        let bind = free_local_port()?;
        relay.set_robot_addr(robot, bind);
        let mut config = robot_config(options, &world, robot, &dir, bind, &relay)?;
        if options.hil {
            let setup_of = onboard::sensors::sensor_setup(&config).map_err(setup)?;
            let geometry = onboard::bus::ImageGeometry {
                width_px: setup_of.calibration.left.width_px,
                height_px: setup_of.calibration.left.height_px,
            };
            let bench = DeviceBench::open(&config, &dir, geometry)?;
            config.driver.kind = DriverKind::Devices;
            config.driver.sim = None;
            config.driver.devices = Some(super::hil::devices_config(&bench.imu_path, &bench.can_path));
            config.validate().map_err(|e| setup(format!("robot {robot} configuration: {e}")))?;
            benches.push(bench);
        }
        let path = dir.join("rover.toml");
        std::fs::write(&path, config.to_toml_string())
            .map_err(|e| MissionError::Io { path: path.clone(), source: e })?;
        configs.push((dir, path));
    }

    let epoch_file = out.join("epoch_ns");
    if epoch_file.exists() {
        std::fs::remove_file(&epoch_file).map_err(|e| MissionError::Io { path: epoch_file.clone(), source: e })?;
    }
    let mut supervisors = Vec::new();
    for (dir, path) in &configs {
        match spawn_supervisor(exe, dir, path, &epoch_file) {
            Ok(child) => supervisors.push(child),
            Err(e) => {
                stop_supervisors(&mut supervisors, &mut relay, monotonic_ns());
                return Err(e);
            }
        }
    }
    // Sensor time starts once every process has rebuilt the world and opened its ports, so no
    // sample is published before its subscribers exist.
    let setup_start = Instant::now();
    let cores = std::thread::available_parallelism().map(|n| n.get() as u32).unwrap_or(1);
    let setup_limit = Duration::from_secs(30) + build_time * ((options.robots * 4) as u32).div_ceil(cores) * 3;
    let all_ready = |configs: &[(PathBuf, PathBuf)]| {
        configs.iter().all(|(dir, _)| NodeKind::ALL.iter().all(|k| dir.join(READY_DIR).join(k.name()).exists()))
    };
    let mut failure = None;
    while !all_ready(&configs) {
        if setup_start.elapsed() > setup_limit {
            failure = Some(format!("the processes were not ready within {:.0} s", setup_limit.as_secs_f64()));
        }
        for (robot, child) in supervisors.iter_mut().enumerate() {
            if let Ok(Some(status)) = child.try_wait() {
                failure = Some(format!("the supervisor of robot {robot} exited during set-up ({status})"));
            }
        }
        if let Some(failure) = failure {
            stop_supervisors(&mut supervisors, &mut relay, monotonic_ns());
            return Err(MissionError::Process(failure));
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let epoch_ns = monotonic_ns() + START_DELAY.as_nanos() as u64;
    let tmp = epoch_file.with_extension("tmp");
    std::fs::write(&tmp, epoch_ns.to_string()).map_err(|e| MissionError::Io { path: tmp.clone(), source: e })?;
    std::fs::rename(&tmp, &epoch_file).map_err(|e| MissionError::Io { path: epoch_file.clone(), source: e })?;
    eprintln!(
        "mission (process runner): world built in {:.2} s here, processes ready after {:.1} s",
        build_time.as_secs_f64(),
        setup_start.elapsed().as_secs_f64()
    );

    for bench in &benches {
        bench.start(epoch_ns);
    }
    let end_ns = epoch_ns + (options.duration_s * 1e9) as u64 + TAIL.as_nanos() as u64;
    let mut faults = FaultPlan::new(&options.faults);
    let mut device_faults = super::hil::DeviceFaultPlan::new(&options.device_faults);
    while monotonic_ns() < end_ns {
        relay.pump(relay_ms(epoch_ns));
        let now_s = monotonic_ns().saturating_sub(epoch_ns) as f64 * 1e-9;
        faults.inject_due(now_s, &configs, &supervisors);
        device_faults.apply_due(now_s, &benches);
        for (robot, child) in supervisors.iter_mut().enumerate() {
            if let Ok(Some(status)) = child.try_wait() {
                failure = Some(format!("the supervisor of robot {robot} exited early ({status})"));
            }
        }
        if failure.is_some() {
            break;
        }
        std::thread::sleep(RELAY_PERIOD);
    }
    stop_supervisors(&mut supervisors, &mut relay, epoch_ns);
    for bench in benches {
        if let Err(e) = bench.stop() {
            failure.get_or_insert(e.to_string());
        }
    }
    let device_faults_path = out.join("device_faults.json");
    if !options.device_faults.is_empty() {
        write_json(&device_faults_path, &Value::Array(device_faults.done)).map_err(process_error)?;
    }
    if let Some(mut ground) = relay.finish_ground() {
        ground.flush().map_err(|e| MissionError::Output(e.to_string()))?;
    }
    let faults_path = out.join("faults.json");
    if !options.faults.is_empty() {
        write_json(&faults_path, &Value::Array(faults.done)).map_err(process_error)?;
    } else if faults_path.exists() {
        std::fs::remove_file(&faults_path).map_err(|e| MissionError::Io { path: faults_path.clone(), source: e })?;
    }
    if let Some(failure) = failure {
        return Err(MissionError::Process(failure));
    }

    let mut robots = Vec::new();
    let mut processes = Vec::new();
    for (robot, (dir, _)) in configs.iter().enumerate() {
        let (report, procs) = robot_report(&world, robot, dir)?;
        robots.push(report);
        processes.extend(procs);
    }
    let report = MissionReport {
        runner: if options.hil { "hil" } else { "process" }.to_owned(),
        scenario: options.scenario.clone(),
        seed: options.seed,
        duration_s: options.duration_s,
        wall_s: wall.elapsed().as_secs_f64(),
        truth_loop_closures: options.truth_loop_closures,
        solo: options.solo,
        closure_screening: None,
        marker_model: marker_model_name(options),
        robots,
        processes,
        pair_evaluation: None,
    };
    super::write_report(&out, &report)?;
    Ok(report)
}

fn relay_ms(epoch_ns: u64) -> u64 {
    monotonic_ns().saturating_sub(epoch_ns) / 1_000_000
}

fn spawn_supervisor(exe: &Path, dir: &Path, config: &Path, epoch_file: &Path) -> Result<Child, MissionError> {
    let log_path = dir.join("logs").join("supervisor.log");
    if let Some(parent) = log_path.parent() {
        std::fs::create_dir_all(parent).map_err(|e| MissionError::Io { path: parent.to_owned(), source: e })?;
    }
    let log = std::fs::File::create(&log_path).map_err(|e| MissionError::Io { path: log_path.clone(), source: e })?;
    let log2 = log.try_clone().map_err(|e| MissionError::Io { path: log_path.clone(), source: e })?;
    Command::new(exe)
        .arg("run")
        .arg("--config")
        .arg(config)
        .env(EPOCH_FILE_ENV, epoch_file)
        .stdin(Stdio::null())
        .stdout(log)
        .stderr(log2)
        .spawn()
        .map_err(|e| MissionError::Io { path: exe.to_owned(), source: e })
}

/// SIGTERM to the supervisors; the relay keeps running while they stop their processes (the
/// comms processes still talk); SIGKILL after [`STOP_WAIT`].
fn stop_supervisors(supervisors: &mut [Child], relay: &mut Relay, epoch_ns: u64) {
    for child in supervisors.iter() {
        if let Ok(pid) = i32::try_from(child.id()) {
            let _ = kill(Pid::from_raw(pid), Signal::SIGTERM);
        }
    }
    let deadline = Instant::now() + STOP_WAIT;
    let mut done = vec![false; supervisors.len()];
    while Instant::now() < deadline && done.iter().any(|d| !d) {
        relay.pump(relay_ms(epoch_ns));
        for (child, done) in supervisors.iter_mut().zip(&mut done) {
            *done |= !matches!(child.try_wait(), Ok(None));
        }
        std::thread::sleep(RELAY_PERIOD);
    }
    for (child, done) in supervisors.iter_mut().zip(&done) {
        if !done {
            let _ = child.kill();
        }
        let _ = child.wait();
    }
}

/// A TUM file the mapper process wrote (sensor time) as `(stamp_ns, pose)` rows.
pub fn read_tum(path: &Path) -> Result<Vec<(u64, nalgebra::Isometry3<f64>)>, MissionError> {
    let text = std::fs::read_to_string(path).map_err(|e| MissionError::Io { path: path.to_owned(), source: e })?;
    let trajectory = eval::io::parse_tum(&text).map_err(|e| process_error(format!("{}: {e}", path.display())))?;
    Ok(trajectory.stamps_s.iter().map(|s| (s * 1e9).round().max(0.0) as u64).zip(trajectory.poses).collect())
}

fn u64_at(value: &Value, key: &str) -> u64 {
    value.get(key).and_then(Value::as_u64).unwrap_or(0)
}

fn read_optional(path: &Path) -> Option<Value> {
    path.exists().then(|| read_json(path).ok()).flatten()
}

fn robot_report(
    world: &std::sync::Arc<World>,
    robot: usize,
    dir: &Path,
) -> Result<(RobotReport, Vec<ProcessReport>), MissionError> {
    let filter = read_optional(&dir.join("filter_summary.json"))
        .ok_or_else(|| process_error(format!("robot {robot}: the filter wrote no filter_summary.json")))?;
    let mapper = read_optional(&dir.join("mapper_status.json")).unwrap_or(Value::Null);
    let comms = read_optional(&dir.join("comms_stats.json")).unwrap_or(Value::Null);
    let supervisor = read_optional(&dir.join("supervisor.json")).unwrap_or(Value::Null);

    let estimate_path = dir.join("estimate.tum");
    let estimate = if estimate_path.exists() { read_tum(&estimate_path)? } else { Vec::new() };
    let initialized_ns = filter.get("initialized_ns").and_then(Value::as_u64);
    let truth =
        initialized_ns.and_then(|init| truth_in_own_frame(world, robot, init, &truth_at_captures(world, robot)));
    let (mut score, mut score_error) = (None, None);
    match (&truth, estimate.is_empty()) {
        (Some(truth), false) if !truth.is_empty() => {
            let path = dir.join("truth.tum");
            onboard::tum::write_tum(&path, truth, 0).map_err(|e| MissionError::Io { path, source: e })?;
            match score::score(&estimate, truth) {
                Ok(s) => score = Some(s),
                Err(e) => score_error = Some(e.to_string()),
            }
        }
        (None, _) => score_error = Some("the filter never initialized".to_owned()),
        _ => score_error = Some("no online estimate or no ground truth was written".to_owned()),
    }
    let connected = mapper
        .get("connected")
        .and_then(Value::as_array)
        .map(|a| a.iter().filter_map(Value::as_u64).map(|v| v as u16).collect())
        .unwrap_or_default();
    let bytes_sent_by_class = comms
        .get("sent_wire_bytes_by_class")
        .and_then(Value::as_object)
        .map(|m| m.iter().map(|(k, v)| (k.clone(), v.as_u64().unwrap_or(0))).collect())
        .unwrap_or_default();
    let report = RobotReport {
        robot: robot_id(robot),
        score,
        score_error,
        graph_nodes: u64_at(&mapper, "graph_nodes") as usize,
        graph_factors: u64_at(&mapper, "graph_factors") as usize,
        connected,
        submaps_finished: u64_at(&mapper, "submaps_finished"),
        submaps_received: u64_at(&mapper, "submaps_received"),
        imu_received: u64_at(&filter, "imu_received"),
        imu_lost: u64_at(&filter, "imu_lost"),
        bytes_sent_by_class,
        // What reached the mapper of what vision published (the bus loses nothing in between).
        markers_published: u64_at(&mapper, "markers_received"),
        marker_detections: u64_at(&mapper, "marker_detections"),
        // The graphs live in the robots' processes: no graph here to place the other robots.
        inter_robot_error_m: Default::default(),
        submap_traffic: None,
        // Counts only: the matches' truth needs the submaps' stamps, which stay in the processes.
        matching: mapper.get("matching").filter(|m| !m.is_null()).map(|m| super::matching::MatchingReport {
            submaps_checked: u64_at(m, "submaps_checked"),
            submaps_unsuitable: u64_at(m, "submaps_unsuitable"),
            attempts: u64_at(m, "attempts"),
            accepted: u64_at(m, "accepted"),
            rejected: m
                .get("rejected")
                .and_then(Value::as_object)
                .map(|r| r.iter().map(|(k, v)| (k.clone(), v.as_u64().unwrap_or(0))).collect())
                .unwrap_or_default(),
            queued: u64_at(m, "queued") as usize,
            ..Default::default()
        }),
        replays: Vec::new(),
        closure_events: Vec::new(),
        step_times: None,
    };

    let restarts_of = |name: &str| {
        supervisor
            .get("processes")
            .and_then(Value::as_array)
            .and_then(|a| a.iter().find(|p| p.get("process").and_then(Value::as_str) == Some(name)))
            .map(|p| u64_at(p, "restarts"))
            .unwrap_or(0)
    };
    let mut processes = Vec::new();
    for kind in NodeKind::ALL {
        let task = read_optional(&dir.join("tasks").join(format!("{}.json", kind.name())));
        let timing = task.as_ref().map(|task| {
            let us = |key: &str| u64_at(task, key) as f64 * 1e-3;
            TaskTiming {
                releases: u64_at(task, "releases"),
                deadline_overruns: u64_at(task, "overruns"),
                skipped_releases: u64_at(task, "skipped"),
                jitter_p50_us: us("jitter_p50_ns"),
                jitter_p99_us: us("jitter_p99_ns"),
                jitter_max_us: us("jitter_max_ns"),
            }
        });
        processes.push(ProcessReport {
            robot: robot_id(robot),
            process: kind.name().to_owned(),
            timing,
            cpu_s: task.as_ref().map_or(0.0, |task| u64_at(task, "cpu_ns") as f64 * 1e-9),
            restarts: restarts_of(kind.name()),
        });
    }
    Ok((report, processes))
}

/// The output folder of robot `robot` of a mission in `out`.
pub fn robot_dir(out: &Path, robot: usize) -> PathBuf {
    out.join(format!("robot{robot}"))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn faults_parse_robot_process_and_time() {
        let f: Fault = "mapper@12".parse().unwrap();
        assert_eq!(f, Fault { robot: 0, process: NodeKind::Mapper, at_s: 12.0 });
        let f: Fault = "1:filter@20.5".parse().unwrap();
        assert_eq!(f, Fault { robot: 1, process: NodeKind::Filter, at_s: 20.5 });
        for bad in ["mapper", "mapper@", "ground@3", "x:mapper@3", "mapper@-1", "mapper@nan", "1:@3"] {
            assert!(bad.parse::<Fault>().is_err(), "{bad} parsed");
        }
    }

    #[test]
    fn parent_pid_of_this_process_is_its_parent() {
        assert_eq!(parent_pid(std::process::id()), Some(std::os::unix::process::parent_id()));
        assert_eq!(parent_pid(u32::MAX), None);
    }

    #[test]
    fn faults_fire_once_in_time_order() {
        let mut plan = FaultPlan::new(&[
            Fault { robot: 5, process: NodeKind::Filter, at_s: 2.0 },
            Fault { robot: 5, process: NodeKind::Mapper, at_s: 1.0 },
        ]);
        plan.inject_due(0.5, &[], &[]);
        assert!(plan.done.is_empty());
        plan.inject_due(1.5, &[], &[]);
        assert_eq!(plan.done.len(), 1);
        assert_eq!(plan.done[0]["process"], "mapper");
        plan.inject_due(9.0, &[], &[]);
        plan.inject_due(9.5, &[], &[]);
        assert_eq!(plan.done.len(), 2);
        assert_eq!(plan.done[1]["error"], "no robot 5");
    }
}
