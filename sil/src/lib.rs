//! `sil`: the software-in-the-loop harness around the unmodified rover firmware (`onboard`).
//!
//! - [`sim_source`]: the simulator as the rover's sensors (the [`onboard::sensors::SourceProvider`]
//!   of the `sil` binary's `run` and `node`), and a simulated robot's configuration.
//! - [`mission`]: the simulated multi-robot mission (the project's main job) on the lockstep and
//!   the process runner, its report and scores.
//! - [`relay`], [`ground_end`]: the radios between the robots and the ground link of a simulated
//!   team (link emulation on the wall clock), and the ground station's end.
//! - [`truth_closures`]: TEST-ONLY loop closures from the simulator's ground truth.
//! - [`team_record`], [`slam_eval`]: a simulated team's filter output recorded through the
//!   firmware's nodes, and the multi-robot SLAM evaluation on it.
//! - [`vio_score`]: scoring `onboard vio`'s estimate on a dataset against its ground truth.
//! - [`obstacles`]: obstacle classification on rendered stereo against the simulator's true
//!   obstacles (the `sim_obstacles` example and its tests).

pub mod campaign;
pub mod cli;
pub mod ground_end;
pub mod mission;
pub mod obstacles;
pub mod relay;
pub mod sim_source;
pub mod slam_eval;
pub mod team_record;
pub mod truth_closures;
pub mod vio_score;
