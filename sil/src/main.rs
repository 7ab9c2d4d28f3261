//! `sil`: the software-in-the-loop harness. Subcommands:
//! - `mission`: the simulated multi-robot mission (the project's main job);
//! - `hil`: the mission on the process runner with the robots' devices on serial lines and CAN;
//! - `campaign`: the named experiments in every variant, one report in the thesis's form;
//! - `run`, `node`: the firmware's supervisor and processes (`onboard run`, `onboard node`) with
//!   the simulator as the sensor source, for a rover configuration with `driver.kind = "sim"`;
//! - `vio`: `onboard vio` on a dataset, scored against its ground truth.

use std::process::ExitCode;

use sil::sim_source::SimSources;

const USAGE: &str = "usage: sil <command> [options]

commands:
  mission     simulated multi-robot mission: every robot's on-board stack, links, maps, report
  hil         hardware in the loop: `mission --runner hil` (IMU over serial, wheels and head
              over CAN, the simulator playing the devices on pseudo-terminals)
  campaign    the named experiments in every variant (team, solo, truth): one report.md
  run         the firmware's supervisor for a simulated rover (driver.kind = \"sim\")
  node        one firmware process of a simulated rover, started by `run`
  vio         `onboard vio` on a EuRoC/ASL or KITTI dataset, scored against ground truth (--gt)

run `sil <command> --help` for a command's options";

fn main() -> ExitCode {
    let mut args = std::env::args_os().skip(1);
    let Some(command) = args.next() else {
        eprintln!("{USAGE}");
        return ExitCode::from(2);
    };
    let rest: Vec<std::ffi::OsString> = args.collect();
    match command.to_str() {
        Some("mission") => sil::cli::mission::main(rest),
        Some("hil") => {
            let mut args = vec!["--runner".into(), "hil".into()];
            args.extend(rest);
            sil::cli::mission::main(args)
        }
        Some("campaign") => sil::cli::campaign::main(rest),
        Some("run") => onboard::cli::run::main("sil", rest),
        Some("node") => onboard::cli::node::main("sil", rest, &SimSources),
        Some("vio") => sil::cli::vio::main(rest),
        Some("--help" | "-h" | "help") => {
            println!("{USAGE}");
            ExitCode::SUCCESS
        }
        _ => {
            eprintln!("sil: unknown command {command:?}\n\n{USAGE}");
            ExitCode::from(2)
        }
    }
}
