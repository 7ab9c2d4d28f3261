//! `onboard`: the rover firmware shell. Subcommands so far:
//! - `posegraph`: optimize a g2o pose graph with the on-board back-end (batch or incremental).
//! - `vio`: stereo visual(-inertial) odometry on a recorded dataset, optionally scored.

mod cli;

use std::process::ExitCode;

const USAGE: &str = "usage: onboard <command> [options]

commands:
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
