//! Trajectory and map evaluation (thesis ch. 7.4 and 8; RAWSEEDS D2.1 §4.1.3–4.1.4, §4.2).
//!
//! Conventions: a [`Trajectory`] holds stamped poses `t_world_body` (`Isometry3<f64>`) with
//! stamps in seconds; errors are reported in metres and radians. The library does no I/O of its
//! own beyond parsing text it is given; the `eval` binary reads and writes files.

pub mod align;
pub mod associate;
pub mod fusion;
pub mod io;
pub mod map;
pub mod metrics;
pub mod plot;
pub mod timesync;
pub mod trajectory;

pub use trajectory::Trajectory;
