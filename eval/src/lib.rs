//! Trajectory and map evaluation (thesis ch. 7.4 and 8; RAWSEEDS D2.1 §4.1.3–4.1.4, §4.2).
//!
//! Conventions: a [`Trajectory`] holds stamped poses `t_world_body` (`Isometry3<f64>`) with
//! stamps in seconds; errors are reported in metres and radians. The library parses text and
//! bytes it is given and does no other I/O, except that the `plot` functions write their PNGs;
//! the `eval` binary reads and writes the files.

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
