//! Command-line front ends of the `onboard` subcommands. They live in the library so that the
//! `sil` harness's binary offers `run` and `node` with the same options, the simulator plugged
//! in as the sensor source.

pub mod node;
pub mod posegraph;
pub mod run;
pub mod vio;

use std::ffi::OsString;
use std::process::ExitCode;

/// Parses and runs a subcommand: `--help` prints the usage (exit 0), a usage error prints it with
/// the message (exit 2), a failed run prints the message (exit 1), each prefixed with
/// `program name:`. `Ok` carries the options and the report for the subcommand to print.
pub fn parse_and_run<O, R>(
    program: &str,
    name: &str,
    usage: &str,
    args: Vec<OsString>,
    parse: impl FnOnce(Vec<OsString>) -> Result<Option<O>, String>,
    run: impl FnOnce(&O) -> Result<R, String>,
) -> Result<(O, R), ExitCode> {
    let options = match parse(args) {
        Ok(Some(options)) => options,
        Ok(None) => {
            println!("{usage}");
            return Err(ExitCode::SUCCESS);
        }
        Err(message) => {
            eprintln!("{program} {name}: {message}\n\n{usage}");
            return Err(ExitCode::from(2));
        }
    };
    match run(&options) {
        Ok(report) => Ok((options, report)),
        Err(message) => {
            eprintln!("{program} {name}: {message}");
            Err(ExitCode::FAILURE)
        }
    }
}
