//! Command-line front ends of the `sil` subcommands.

pub mod campaign;
pub mod mission;
pub mod vio;
