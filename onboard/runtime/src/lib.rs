//! `onboard` as a library: the pipelines the `onboard` binary runs, for tests and examples.
//!
//! - [`vio`]: stereo visual odometry + local reference filter on any sensor source.

pub mod vio;
