//! The operator's ground station (see README.md).

pub mod view;
