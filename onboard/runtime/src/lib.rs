//! `onboard` as a library: the pipelines the `onboard` binary runs, for tests and examples.
//!
//! - [`vio`]: stereo visual odometry + local reference filter on any sensor source.
//! - [`team_record`]: a simulated team's filter output (local poses, frame switches, truth), cached.

pub mod slam_eval;
pub mod team_record;
pub mod vio;
