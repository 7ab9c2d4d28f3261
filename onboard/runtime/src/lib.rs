//! `onboard` as a library: the rover firmware (what is flashed) and its runners.
//!
//! - [`nodes`]: the on-board components (driver, vision, filter, mapper, comms) behind one message
//!   interface, driven by either runner.
//! - [`stack`]: the nodes of one robot built from its configuration (the one place both runners
//!   and `onboard vio` get them from).
//! - [`sensors`]: where the sensor data comes from ([`sensors::SourceProvider`]: a dataset replay
//!   in the firmware; the simulator is plugged in by the `sil` harness) and the calibration.
//! - [`topics`]: the registry of the bus topics (path, recording code, publisher, settings).
//! - [`bus`]: the iceoryx2 shared-memory bus of the process runner.
//! - [`process`]: the process runner: one OS process per node, the supervisor.
//! - [`lockstep`]: the lockstep runner's in-process bus (simulated time, deterministic).
//! - [`task`]: fixed-rate tasks with deadlines, jitter and overrun counters, real-time set-up.
//! - [`config`]: the rover's TOML configuration, validated.
//! - [`record`]: recording of bus messages and their replay.
//! - [`vio`]: stereo visual(-inertial) odometry on a recorded dataset (`onboard vio`).
//! - [`tum`]: trajectories in the TUM format.
//! - [`cli`]: the subcommands' front ends (shared with the `sil` binary's `run` and `node`).

pub mod bus;
pub mod cli;
pub mod config;
pub mod lockstep;
pub mod nodes;
pub mod process;
pub mod record;
pub mod sensors;
pub mod stack;
pub mod task;
pub mod topics;
pub mod tum;
pub mod vio;
