//! `onboard`: the rover firmware. Subcommands:
//! - `run`: the rover's supervisor; `node`: one of its processes.
//! - `posegraph`: optimize a g2o pose graph with the on-board back-end (batch or incremental).
//! - `vio`: a recorded dataset through the rover's own nodes, the online estimate in TUM format.
//!
//! The simulated mission is the harness's: `sil mission`.

use std::process::ExitCode;

use onboard::cli;
use onboard::sensors::FirmwareSources;

const USAGE: &str = "usage: onboard <command> [options]

commands:
  run         the rover's supervisor: starts, watches and restarts its five processes
  node        one on-board process (driver, vision, filter, mapper, comms), started by `run`
  posegraph   optimize a g2o pose graph (batch Levenberg-Marquardt or incremental iSAM2-style)
  vio         a EuRoC/ASL or KITTI dataset through the rover's nodes, online estimate as TUM

run `onboard <command> --help` for a command's options; the simulated mission is `sil mission`";

fn main() -> ExitCode {
    let mut args = std::env::args_os().skip(1);
    let Some(command) = args.next() else {
        eprintln!("{USAGE}");
        return ExitCode::from(2);
    };
    let rest: Vec<std::ffi::OsString> = args.collect();
    match command.to_str() {
        Some("node") => cli::node::main("onboard", rest, &FirmwareSources),
        Some("run") => cli::run::main("onboard", rest),
        Some("posegraph") => cli::posegraph::main(rest),
        Some("vio") => cli::vio::main(rest),
        Some("--help" | "-h" | "help") => {
            println!("{USAGE}");
            ExitCode::SUCCESS
        }
        _ => {
            eprintln!("onboard: unknown command {command:?}\n\n{USAGE}");
            ExitCode::from(2)
        }
    }
}
