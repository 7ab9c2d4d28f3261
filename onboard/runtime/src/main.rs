//! `onboard`: the rover firmware shell. Subcommands so far:
//! - `mission`: the simulated multi-robot mission (the project's main job).
//! - `run`: the rover's supervisor; `node`: one of its processes.
//! - `posegraph`: optimize a g2o pose graph with the on-board back-end (batch or incremental).
//! - `vio`: stereo visual(-inertial) odometry on a recorded dataset, optionally scored.

mod cli;

use std::process::ExitCode;

const USAGE: &str = "usage: onboard <command> [options]

commands:
  mission     simulated multi-robot mission: every robot's on-board stack, links, maps, report
  run         the rover's supervisor: starts, watches and restarts its five processes
  node        one on-board process (driver, vision, filter, mapper, comms), started by `run`
  posegraph   optimize a g2o pose graph (batch Levenberg-Marquardt or incremental iSAM2-style)
  vio         stereo odometry + IMU filter on a EuRoC/ASL or KITTI dataset, TUM output, scoring

run `onboard <command> --help` for a command's options";

fn main() -> ExitCode {
    let mut args = std::env::args_os().skip(1);
    let Some(command) = args.next() else {
        eprintln!("{USAGE}");
        return ExitCode::from(2);
    };
    let rest: Vec<std::ffi::OsString> = args.collect();
    match command.to_str() {
        Some("mission") => cli::mission::main(rest),
        Some("node") => cli::node::main(rest),
        Some("run") => cli::run::main(rest),
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
