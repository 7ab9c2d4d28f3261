//! Command-line front ends of the subcommands.

pub mod posegraph;
pub mod vio;
