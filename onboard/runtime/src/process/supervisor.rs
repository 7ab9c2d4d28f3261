//! `onboard run --config rover.toml`: the robot's supervisor.
//!
//! Removes the stale iceoryx2 resources of the robot's dead nodes, fixes the mission epoch
//! ([`super::EPOCH_ENV`], kept from a parent mission if set), and starts the five processes
//! (`onboard node <kind>`, this same executable). Every [`POLL`] it reaps the children that
//! exited; one that exited without being asked is restarted after a back-off that doubles from
//! [`BACKOFF_MIN`] to [`BACKOFF_MAX`] and falls back to the minimum once the process has run
//! [`HEALTHY_AFTER`]. On SIGTERM or SIGINT it forwards SIGTERM to every child, waits up to
//! [`GRACE`] for them (the mapper writes its map then), kills the rest, and writes
//! `supervisor.json` (starts, restarts, exits and pids per process) into the robot's output
//! folder. Children's output goes to `logs/<process>.log` there; the running child's pid is in
//! `pids/<process>` ([`super::PID_DIR`]).

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use serde_json::json;

use super::{
    EPOCH_ENV, EPOCH_FILE_ENV, NodeKind, PID_DIR, ProcessError, epoch_from_env, io_error, monotonic_ns,
    termination_flag, write_json,
};
use crate::bus::remove_stale;
use crate::config::RoverConfig;

pub const POLL: Duration = Duration::from_millis(100);
pub const BACKOFF_MIN: Duration = Duration::from_millis(100);
pub const BACKOFF_MAX: Duration = Duration::from_secs(5);
pub const HEALTHY_AFTER: Duration = Duration::from_secs(30);
pub const GRACE: Duration = Duration::from_secs(30);
/// Sensor time 0 this far after the supervisor's start when no parent set the epoch: the
/// processes build their (simulated) world first.
const STANDALONE_START_DELAY: Duration = Duration::from_secs(3);

/// The restart back-off after `failures` consecutive unrequested exits (1 = the first).
pub fn backoff(failures: u32) -> Duration {
    let factor = 1u32.checked_shl(failures.saturating_sub(1)).unwrap_or(u32::MAX);
    BACKOFF_MIN.saturating_mul(factor).min(BACKOFF_MAX)
}

/// One supervised process.
#[derive(Debug)]
struct Supervised {
    kind: NodeKind,
    child: Option<Child>,
    started: Instant,
    starts: u64,
    restarts: u64,
    /// Unrequested exits since the process last ran [`HEALTHY_AFTER`].
    failures: u32,
    restart_at: Option<Instant>,
    exits: Vec<String>,
    /// Pid of every start, in order.
    pids: Vec<u32>,
}

/// What the supervisor did, per process.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ProcessRecord {
    pub process: String,
    pub starts: u64,
    pub restarts: u64,
    /// Exit statuses in order (the final one included).
    pub exits: Vec<String>,
    /// Pid of every start, in order.
    pub pids: Vec<u32>,
}

#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SupervisorReport {
    pub robot: u16,
    /// `None` when the processes took it from the parent's epoch file.
    pub epoch_ns: Option<u64>,
    pub processes: Vec<ProcessRecord>,
}

impl SupervisorReport {
    pub fn restarts(&self) -> u64 {
        self.processes.iter().map(|p| p.restarts).sum()
    }
}

fn describe(status: ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (status.code(), status.signal()) {
        (Some(code), _) => format!("exit {code}"),
        (None, Some(signal)) => {
            Signal::try_from(signal).map(|s| format!("signal {}", s.as_str())).unwrap_or(format!("signal {signal}"))
        }
        _ => "unknown".to_owned(),
    }
}

struct Launcher {
    exe: PathBuf,
    config: PathBuf,
    epoch_ns: Option<u64>,
    logs: PathBuf,
    pids: PathBuf,
}

impl Launcher {
    fn spawn(&self, kind: NodeKind) -> Result<Child, ProcessError> {
        let log_path = self.logs.join(format!("{}.log", kind.name()));
        let log = File::options().create(true).append(true).open(&log_path).map_err(io_error(&log_path))?;
        let log2 = log.try_clone().map_err(io_error(&log_path))?;
        let mut command = Command::new(&self.exe);
        command.arg("node").arg(kind.name()).arg("--config").arg(&self.config);
        if let Some(epoch_ns) = self.epoch_ns {
            command.env(EPOCH_ENV, epoch_ns.to_string());
        }
        let child = command.stdin(Stdio::null()).stdout(log).stderr(log2).spawn().map_err(io_error(&self.exe))?;
        // tmp + rename: a reader sees the previous pid or this one, never a partial number.
        let path = self.pid_path(kind);
        let tmp = path.with_extension("tmp");
        if let Err(e) = std::fs::write(&tmp, child.id().to_string()).and_then(|()| std::fs::rename(&tmp, &path)) {
            eprintln!("supervisor: writing {}: {e}", path.display());
        }
        Ok(child)
    }

    fn pid_path(&self, kind: NodeKind) -> PathBuf {
        self.pids.join(kind.name())
    }

    /// The child is reaped: its pid may be reused by an unrelated process.
    fn forget_pid(&self, kind: NodeKind) {
        let _ = std::fs::remove_file(self.pid_path(kind));
    }
}

/// Runs the supervisor of the robot configured in `config_path` until SIGTERM or SIGINT.
pub fn supervise(config_path: &Path) -> Result<SupervisorReport, ProcessError> {
    let stop = termination_flag()?;
    let config = RoverConfig::load(config_path)?;
    let dir = config.robot.output_dir();
    let logs = dir.join("logs");
    std::fs::create_dir_all(&logs).map_err(io_error(&logs))?;
    let pids = dir.join(PID_DIR);
    std::fs::create_dir_all(&pids).map_err(io_error(&pids))?;
    let cleanup = remove_stale(config.robot.bus_id())?;
    if !cleanup.is_empty() {
        eprintln!("supervisor robot {}: stale iceoryx2 resources: {cleanup}", config.robot.id);
    }
    // With an epoch file from the parent, the processes read the epoch there themselves.
    let epoch_ns = match epoch_from_env()? {
        Some(epoch) => Some(epoch),
        None if std::env::var_os(EPOCH_FILE_ENV).is_some() => None,
        None => Some(monotonic_ns() + STANDALONE_START_DELAY.as_nanos() as u64),
    };
    let exe = std::env::current_exe().map_err(io_error(Path::new("/proc/self/exe")))?;
    let config_abs = std::path::absolute(config_path).map_err(io_error(config_path))?;
    let launcher = Launcher { exe, config: config_abs, epoch_ns, logs, pids };

    let now = Instant::now();
    let mut children: Vec<Supervised> = NodeKind::ALL
        .into_iter()
        .map(|kind| Supervised {
            kind,
            child: None,
            started: now,
            starts: 0,
            restarts: 0,
            failures: 0,
            restart_at: Some(now),
            exits: Vec::new(),
            pids: Vec::new(),
        })
        .collect();

    while !stop.load(Ordering::Relaxed) {
        let now = Instant::now();
        for s in &mut children {
            if let Some(child) = &mut s.child {
                match child.try_wait() {
                    Ok(Some(status)) => {
                        let ran = now.duration_since(s.started);
                        s.failures = if ran >= HEALTHY_AFTER { 1 } else { s.failures + 1 };
                        let wait = backoff(s.failures);
                        eprintln!(
                            "supervisor robot {}: {} ({}) after {:.1} s; restart in {:.1} s",
                            config.robot.id,
                            s.kind.name(),
                            describe(status),
                            ran.as_secs_f64(),
                            wait.as_secs_f64()
                        );
                        s.exits.push(describe(status));
                        s.child = None;
                        launcher.forget_pid(s.kind);
                        s.restart_at = Some(now + wait);
                    }
                    Ok(None) => {
                        if s.failures > 0 && now.duration_since(s.started) >= HEALTHY_AFTER {
                            s.failures = 0;
                        }
                    }
                    Err(e) => eprintln!("supervisor: waiting for {}: {e}", s.kind.name()),
                }
            }
            if s.child.is_none() && s.restart_at.is_some_and(|at| now >= at) {
                match launcher.spawn(s.kind) {
                    Ok(child) => {
                        if s.starts > 0 {
                            s.restarts += 1;
                        }
                        s.starts += 1;
                        s.pids.push(child.id());
                        s.child = Some(child);
                        s.started = now;
                        s.restart_at = None;
                    }
                    Err(e) => {
                        s.failures += 1;
                        s.restart_at = Some(now + backoff(s.failures));
                        eprintln!("supervisor: starting {}: {e}", s.kind.name());
                    }
                }
            }
        }
        std::thread::sleep(POLL);
    }

    stop_children(&mut children);
    for s in &children {
        launcher.forget_pid(s.kind);
    }
    let report = SupervisorReport {
        robot: config.robot.id,
        epoch_ns,
        processes: children
            .iter()
            .map(|s| ProcessRecord {
                process: s.kind.name().to_owned(),
                starts: s.starts,
                restarts: s.restarts,
                exits: s.exits.clone(),
                pids: s.pids.clone(),
            })
            .collect(),
    };
    let processes: Vec<_> = report
        .processes
        .iter()
        .map(|p| {
            json!({"process": p.process, "starts": p.starts, "restarts": p.restarts, "exits": p.exits, "pids": p.pids})
        })
        .collect();
    write_json(
        &dir.join("supervisor.json"),
        &json!({
            "robot": report.robot,
            "bus_id": config.robot.bus_id(),
            "epoch_ns": epoch_ns,
            "stale_nodes_removed": cleanup.removed.len(),
            "processes": processes,
        }),
    )?;
    Ok(report)
}

/// SIGTERM to every child, up to [`GRACE`] for them to exit, SIGKILL for the rest; reaps all.
fn stop_children(children: &mut [Supervised]) {
    for s in children.iter() {
        if let Some(child) = &s.child
            && let Ok(pid) = i32::try_from(child.id())
        {
            // A child that exited meanwhile is reaped below.
            let _ = kill(Pid::from_raw(pid), Signal::SIGTERM);
        }
    }
    let deadline = Instant::now() + GRACE;
    loop {
        let mut running = 0;
        for s in children.iter_mut() {
            if let Some(child) = &mut s.child {
                match child.try_wait() {
                    Ok(Some(status)) => {
                        s.exits.push(describe(status));
                        s.child = None;
                    }
                    _ => running += 1,
                }
            }
        }
        if running == 0 {
            return;
        }
        if Instant::now() >= deadline {
            break;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    for s in children.iter_mut() {
        if let Some(mut child) = s.child.take() {
            eprintln!("supervisor: {} did not stop within {} s; killing it", s.kind.name(), GRACE.as_secs());
            let _ = child.kill();
            match child.wait() {
                Ok(status) => s.exits.push(describe(status)),
                Err(e) => s.exits.push(format!("wait failed: {e}")),
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn backoff_doubles_from_100_ms_to_5_s() {
        assert_eq!(backoff(1), Duration::from_millis(100));
        assert_eq!(backoff(2), Duration::from_millis(200));
        assert_eq!(backoff(6), Duration::from_millis(3_200));
        assert_eq!(backoff(7), BACKOFF_MAX);
        assert_eq!(backoff(40), BACKOFF_MAX);
        assert_eq!(backoff(0), BACKOFF_MIN);
    }
}
