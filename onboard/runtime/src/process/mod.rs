//! The process runner (DESIGN §1, §3.1): every component of a robot in its own OS process over
//! the iceoryx2 bus, on fixed-rate tasks on the wall clock.
//!
//! - [`node_main`]: one process (`onboard node <kind> --config rover.toml`);
//! - [`supervisor`]: `onboard run --config rover.toml`, starts, watches and restarts the five.
//!
//! The same two entry points serve the `sil` harness: its binary's `run` and `node` commands call
//! them with its own [`crate::sensors::SourceProvider`] (the simulator), and the supervisor
//! starts the processes from whichever executable it runs in.
//!
//! # Time
//! Sensor time is `CLOCK_MONOTONIC − epoch`, the epoch coming from [`EPOCH_ENV`] (set by the
//! supervisor, or by the mission for all robots), so a restarted process keeps the time base and
//! every process's fixed-rate task releases on one grid that starts at the epoch.
//!
//! # Files (in the robot's `robot.output_dir`)
//! Written when a process ends on SIGTERM: `tasks/<process>.json` (every process; the driver's
//! holds `time_offset_ns`, the source's stamp of sensor time 0), the filter's `filter_summary.json`, the mapper's map, graph, `estimate.tum`
//! and `mapper_status.json`, the comms' `comms_stats.json`; the supervisor's `supervisor.json`.
//! A restarted process overwrites its predecessor's files: they describe its last life (the
//! filter carries its main counters across lives in its checkpoint, `state/filter.ckpt`).
//! `pids/<process>` holds the pid of the running process (written by the supervisor at every
//! start, removed when it is reaped): the mission's fault injection uses it.
//!
//! # Signals
//! SIGTERM and SIGINT set the task's stop flag from a handler (`signal_hook::flag`, no unsafe
//! code of ours; [`termination_flag`]), so whichever thread takes the signal, the process ends
//! its release and writes its files. (Blocking the signals and waiting on one thread, as before,
//! killed the devices driver: `serialport` waits in `ppoll` with an empty mask, so its reading
//! thread took SIGTERM with the default action; `sil/tests/hil.rs` asserts every exit is 0.)

pub mod node_main;
pub mod supervisor;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

use msgs::ProcessKind;
use nalgebra::Isometry3;
use nix::time::{ClockId, clock_gettime};

use crate::config::{ConfigError, RatesConfig, TaskRate};
use crate::nodes::Topic;

pub use node_main::node_main;
pub use supervisor::{SupervisorReport, supervise};

/// Environment variable with the mission epoch (`CLOCK_MONOTONIC` nanoseconds of sensor time 0).
pub const EPOCH_ENV: &str = "ONBOARD_EPOCH_NS";
/// Environment variable naming a file that will hold the epoch (decimal nanoseconds), for a
/// parent that fixes the epoch only once every process is ready ([`READY_DIR`]): a process
/// without [`EPOCH_ENV`] waits for the file after its set-up.
pub const EPOCH_FILE_ENV: &str = "ONBOARD_EPOCH_FILE";
/// Folder in the robot's output folder where each process leaves `<process>` once set up.
pub const READY_DIR: &str = "ready";
/// Folder in the robot's output folder with one file per running process: its pid.
pub const PID_DIR: &str = "pids";

/// Why a process of the runner failed.
#[derive(Debug, thiserror::Error)]
pub enum ProcessError {
    #[error("configuration: {0}")]
    Config(#[from] ConfigError),
    #[error("{EPOCH_ENV}={value:?} is not a nanosecond count")]
    Epoch { value: String },
    #[error("signals: {0}")]
    Signal(std::io::Error),
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("bus: {0}")]
    Bus(#[from] crate::bus::BusError),
    #[error("task: {0}")]
    Task(#[from] crate::task::TaskError),
    #[error("{0}")]
    Setup(String),
    #[error("sensors: {0}")]
    Sensors(#[from] crate::sensors::SensorSetupError),
    #[error("node: {0}")]
    Node(#[from] crate::nodes::NodeError),
    #[error("link: {0}")]
    Link(#[from] hal::link::LinkError),
    #[error("outputs: {0}")]
    Output(String),
}

pub(crate) fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> ProcessError + '_ {
    move |source| ProcessError::Io { path: path.to_owned(), source }
}

/// The five processes of a robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum NodeKind {
    Driver,
    Vision,
    Filter,
    Mapper,
    Comms,
}

impl NodeKind {
    pub const ALL: [NodeKind; 5] =
        [NodeKind::Driver, NodeKind::Vision, NodeKind::Filter, NodeKind::Mapper, NodeKind::Comms];

    pub fn name(self) -> &'static str {
        match self {
            NodeKind::Driver => "driver",
            NodeKind::Vision => "vision",
            NodeKind::Filter => "filter",
            NodeKind::Mapper => "mapper",
            NodeKind::Comms => "comms",
        }
    }

    pub fn parse(name: &str) -> Option<NodeKind> {
        NodeKind::ALL.into_iter().find(|k| k.name() == name)
    }

    pub fn process_kind(self) -> ProcessKind {
        match self {
            NodeKind::Driver => ProcessKind::Driver,
            NodeKind::Vision => ProcessKind::Vision,
            NodeKind::Filter => ProcessKind::Filter,
            NodeKind::Mapper => ProcessKind::Mapper,
            NodeKind::Comms => ProcessKind::Comms,
        }
    }

    /// Topics the process publishes (the node's outputs plus its task telemetry), from the
    /// registry.
    pub fn publishes(self) -> Vec<Topic> {
        crate::topics::published_by(self)
    }

    /// The process's fixed-rate task. The driver runs at the IMU rate (it publishes every sample
    /// on time; a frame render may take longer than a period, hence the whole period).
    pub fn task_rate(self, rates: &RatesConfig) -> TaskRate {
        match self {
            NodeKind::Driver => TaskRate { hz: rates.imu_hz, deadline_fraction: None, deadline_ns: None },
            NodeKind::Vision => rates.vision.clone(),
            NodeKind::Filter => rates.filter.clone(),
            NodeKind::Mapper => rates.mapper.clone(),
            NodeKind::Comms => rates.comms.clone(),
        }
    }
}

/// `CLOCK_MONOTONIC` now, nanoseconds.
pub fn monotonic_ns() -> u64 {
    clock_gettime(ClockId::CLOCK_MONOTONIC)
        .map(|t| (t.tv_sec().max(0) as u64).saturating_mul(1_000_000_000).saturating_add(t.tv_nsec().max(0) as u64))
        .unwrap_or(0)
}

/// The epoch from [`EPOCH_ENV`], `None` if it is not set.
pub fn epoch_from_env() -> Result<Option<u64>, ProcessError> {
    match std::env::var(EPOCH_ENV) {
        Ok(value) => value.trim().parse().map(Some).map_err(|_| ProcessError::Epoch { value }),
        Err(std::env::VarError::NotPresent) => Ok(None),
        Err(std::env::VarError::NotUnicode(v)) => Err(ProcessError::Epoch { value: format!("{v:?}") }),
    }
}

/// The epoch: [`EPOCH_ENV`] if set, else the content of the [`EPOCH_FILE_ENV`] file once it
/// exists (polled every 10 ms; `None` if `stop` is set meanwhile), else now.
pub fn wait_for_epoch(stop: &AtomicBool) -> Result<Option<u64>, ProcessError> {
    if let Some(epoch) = epoch_from_env()? {
        return Ok(Some(epoch));
    }
    let Some(path) = std::env::var_os(EPOCH_FILE_ENV).map(PathBuf::from) else { return Ok(Some(monotonic_ns())) };
    while !stop.load(Ordering::Relaxed) {
        if let Ok(text) = std::fs::read_to_string(&path) {
            return text.trim().parse().map(Some).map_err(|_| ProcessError::Epoch { value: text });
        }
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    Ok(None)
}

/// A flag that SIGTERM and SIGINT set (from a signal handler, `signal_hook::flag`): the process
/// finishes its current release, writes its files and exits 0. Call it first in `main`.
///
/// Blocking the signals and waiting for them on one thread is not enough here: `serialport`
/// waits for data in `ppoll` with an *empty* signal mask, so a thread reading a serial line (the
/// IMU, an SLCAN adapter, a serial radio) would take a blocked-elsewhere SIGTERM with the default
/// action, death without outputs. A handler makes every thread safe; a read it interrupts returns
/// `EINTR`, which the device threads treat as a lost line, at shutdown only.
pub fn termination_flag() -> Result<Arc<AtomicBool>, ProcessError> {
    let flag = Arc::new(AtomicBool::new(false));
    for signal in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(signal, Arc::clone(&flag)).map_err(ProcessError::Signal)?;
    }
    Ok(flag)
}

/// Writes `rows` as a TUM trajectory in sensor time (nothing for an empty one).
pub fn write_tum(path: &Path, rows: &[(u64, Isometry3<f64>)]) -> Result<(), ProcessError> {
    if rows.is_empty() {
        return Ok(());
    }
    crate::tum::write_tum(path, rows, 0).map_err(io_error(path))
}

/// Writes `value` as pretty JSON.
pub fn write_json(path: &Path, value: &serde_json::Value) -> Result<(), ProcessError> {
    let text = serde_json::to_string_pretty(value).map_err(|e| ProcessError::Output(e.to_string()))?;
    std::fs::write(path, text + "\n").map_err(io_error(path))
}

/// Reads a JSON file.
pub fn read_json(path: &Path) -> Result<serde_json::Value, ProcessError> {
    let text = std::fs::read_to_string(path).map_err(io_error(path))?;
    serde_json::from_str(&text).map_err(|e| ProcessError::Output(format!("{}: {e}", path.display())))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn node_kinds_round_trip_and_publish_telemetry() {
        for kind in NodeKind::ALL {
            assert_eq!(NodeKind::parse(kind.name()), Some(kind));
            assert!(kind.publishes().contains(&Topic::TaskStats));
        }
        assert_eq!(NodeKind::parse("ground"), None);
    }
}
