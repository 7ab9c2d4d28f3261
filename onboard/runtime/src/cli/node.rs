//! `onboard node <driver|vision|filter|mapper|comms> --config rover.toml`
//!
//! One on-board process of the robot (see [`crate::process::node_main`]); the supervisor
//! (`onboard run`) starts these. Runs until SIGTERM or SIGINT, then writes its files and exits 0.
//! Exit codes: 0 stopped on request, 1 runtime error (the supervisor restarts it), 2 usage error.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;

use crate::process::{NodeKind, node_main};
use crate::sensors::SourceProvider;

const USAGE: &str = "usage: onboard node <driver|vision|filter|mapper|comms> --config FILE

  --config FILE   the rover's TOML configuration (see onboard/runtime/config/rover.toml)

Sensor time is CLOCK_MONOTONIC minus $ONBOARD_EPOCH_NS (set by the supervisor; without it the
process's start). SIGTERM ends the process after its current release; it then writes its files
into the robot's output folder (robot.output_dir).";

fn parse_args(args: Vec<OsString>) -> Result<Option<(NodeKind, PathBuf)>, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let (mut kind, mut config) = (None, None);
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("config") => config = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?)),
            Short('h') | Long("help") => return Ok(None),
            Value(value) if kind.is_none() => {
                let name = value.to_string_lossy().into_owned();
                kind = Some(NodeKind::parse(&name).ok_or_else(|| format!("unknown process {name:?}"))?);
            }
            other => return Err(other.unexpected().to_string()),
        }
    }
    let kind = kind.ok_or("which process? driver, vision, filter, mapper or comms")?;
    let config = config.ok_or("--config FILE is required")?;
    Ok(Some((kind, config)))
}

/// `program node …` with the driver's sensors from `sources`.
pub fn main(program: &str, args: Vec<OsString>, sources: &dyn SourceProvider) -> ExitCode {
    match super::parse_and_run(program, "node", USAGE, args, parse_args, |(kind, config)| {
        node_main(*kind, config, sources).map_err(|e| e.to_string())
    }) {
        Ok(_) => ExitCode::SUCCESS,
        Err(code) => code,
    }
}
