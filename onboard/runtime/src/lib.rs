//! `onboard` as a library: the rover firmware shell and the pipelines the `onboard` binary runs.
//!
//! - [`nodes`]: the on-board components (driver, vision, filter, mapper, comms) behind one message
//!   interface, driven by either runner.
//! - [`bus`]: the iceoryx2 shared-memory bus of the process runner.
//! - [`process`]: the process runner: one OS process per node, the supervisor, the team radio relay.
//! - [`task`]: fixed-rate tasks with deadlines, jitter and overrun counters, real-time set-up.
//! - [`config`]: the rover's TOML configuration, validated.
//! - [`record`]: recording of bus messages and their replay.
//! - [`lockstep`]: the lockstep runner (N robots, one process, simulated time).
//! - [`vio`]: stereo visual odometry + local reference filter on any sensor source.
//! - [`team_record`]: a simulated team's filter output (local poses, frame switches, truth), cached.

pub mod bus;
pub mod config;
pub mod lockstep;
pub mod mission;
pub mod nodes;
pub mod process;
pub mod record;
pub mod slam_eval;
pub mod task;
pub mod team_record;
pub mod vio;
