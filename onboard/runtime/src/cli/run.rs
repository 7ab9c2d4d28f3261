//! `onboard run --config rover.toml [--json]`
//!
//! The rover's supervisor (see [`crate::process::supervise`]): starts the driver, vision,
//! filter, mapper and comms processes, restarts crashed ones with back-off, and on SIGTERM or
//! SIGINT stops them and prints what happened (restarts per process).
//! Exit codes: 0 stopped on request, 1 runtime error, 2 usage error.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;

use crate::process::supervise;

const USAGE: &str = "usage: onboard run --config FILE [--json]

  --config FILE   the rover's TOML configuration (see onboard/runtime/config/rover.toml)
  --json          print the supervisor's record as one JSON object

Starts the robot's five processes (`onboard node <kind>`), restarts a crashed one after a
back-off of 100 ms doubling to 5 s, and stops them all on SIGTERM/SIGINT. Process output goes to
logs/<process>.log, the record to supervisor.json, both in robot.output_dir.";

fn parse_args(args: Vec<OsString>) -> Result<Option<(PathBuf, bool)>, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let (mut config, mut json) = (None, false);
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("config") => config = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?)),
            Long("json") => json = true,
            Short('h') | Long("help") => return Ok(None),
            other => return Err(other.unexpected().to_string()),
        }
    }
    Ok(Some((config.ok_or("--config FILE is required")?, json)))
}

/// `program run …`: the supervisor starts the processes as `program node …` (the executable it
/// runs in).
pub fn main(program: &str, args: Vec<OsString>) -> ExitCode {
    match super::parse_and_run(program, "run", USAGE, args, parse_args, |(config, _)| {
        supervise(config).map_err(|e| e.to_string())
    }) {
        Ok(((_, json), report)) => {
            if json {
                let processes: Vec<_> = report
                    .processes
                    .iter()
                    .map(|p| serde_json::json!({"process": p.process, "starts": p.starts, "restarts": p.restarts, "exits": p.exits}))
                    .collect();
                println!("{}", serde_json::json!({"robot": report.robot, "processes": processes}));
            } else {
                for p in &report.processes {
                    println!(
                        "{:<8} starts {:>3}  restarts {:>3}  exits {}",
                        p.process,
                        p.starts,
                        p.restarts,
                        p.exits.join(", ")
                    );
                }
            }
            ExitCode::SUCCESS
        }
        Err(code) => code,
    }
}
