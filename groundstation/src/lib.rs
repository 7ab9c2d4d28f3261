//! The operator's ground station (see README.md).

pub mod app;
pub mod engine;
pub mod model;
pub mod net;
pub mod replay;
pub mod ui;
pub mod view;
