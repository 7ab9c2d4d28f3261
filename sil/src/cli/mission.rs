//! `sil mission --robots 2 --scenario moon --duration 120 --out runs/demo [--runner lockstep|process] [--json]`
//!
//! The project's main job: a simulated multi-robot exploration with every robot's full on-board
//! stack (see [`crate::mission`]). Prints a summary table, or with `--json` the report object.
//! Exit codes: 0 success, 1 runtime error, 2 usage error.

use std::ffi::OsString;
use std::io::IsTerminal;
use std::process::ExitCode;

use onboard::config::{InterRobotConsistency, MarkerModelConfig, MatchModeConfig};

use sim::scenario::experiments;

use crate::mission::{MissionOptions, MissionReport, RadioPreset, Runner};

const USAGE: &str = "usage: sil mission [--robots N] [--scenario NAME] [--duration S] [--out DIR]
                       [--runner lockstep|process|hil] [--json] [options]

  --robots N             rovers in the team (default 2)
  --scenario NAME        a site (moon, mars: rosettes of petals for any team size) or a named
                         2-robot experiment after the thesis's (lab-rocks, loops, loops-mars,
                         double-loop, leave-reenter, hetero-cameras); `--scenario list`
                         describes them (default moon)
  --duration S           simulated seconds (default 120; an experiment's own length, at most)
  --seed N               world and sensor noise seed (default 1; an experiment's own)
  --downscale K          camera resolution 1024x508 / K, K in 1, 2, 4 (default 1: the thesis's
                         camera; 4 runs about 4x faster, for quick looks and tests)
  --out DIR              output folder (default runs/demo): per robot robotN/ with
                         estimate.tum, truth.tum, graph.g2o, map.ply, map.bt, map.png;
                         report.json and report.md
  --runner R             lockstep (all robots in this process, simulated time, deterministic;
                         default), process (one OS process per component over iceoryx2,
                         fixed-rate tasks on the wall clock) or hil (the process runner with
                         each robot's IMU on a serial line (Xsens MT) and its wheels and head on
                         CAN (CANopen behind an SLCAN adapter), played by the simulator; `sil hil`)
  --device-fault F       hil runner: [R:]FAULT@START+DURATION with FAULT imu-unplug, imu-noise,
                         drive-silent:K (wheel 0..4), babble or sync-lost, on robot index R
                         (default 0); repeatable; recorded in device_faults.json
  --radio R              serial (57.6 kbit/s radio, default) or wifi (lossy mesh)
  --threads N            lockstep runner: threads stepping the robots in parallel between its
                         barriers (default: the machine's cores; the outputs do not depend on it)
  --gaze G               on: the firmware's gaze policy points each rover's pan-tilt head
                         (look ahead / look down while driving, a sweep at stops); off
                         (default): the simulator's scripted head
  --markers M            the robots' AprilTag detector and its uncertainty model: lut_online
                         (the thesis's, default), lut, online, quadratic, constant, or off; a
                         camera without a table (wide-angle, flyer) uses online for the lut models
  --matching M           the robots' submap matcher: 4d (the thesis's, default), 6d (its
                         baseline) or off (the default with --truth-loop-closures)
  --compare-match-modes  after a lockstep mission, match every attempted pair again in the
                         other mode (4d <-> 6d) with the same prior; both are scored in the report
  --evaluate-match-pairs after a lockstep mission, match every truly overlapping pair of the
                         first robot's suitable submaps in 4d and 6d (its final estimate as the
                         prior) and score them in the report
  --rocks-per-100m2 N    rock density of the site instead of the preset's (moon 1, mars 3.5)
  --rocks-in-hub         rocks in the routes' shared hub too (the presets keep it bare; the
                         submap matcher needs obstacles where the robots' paths overlap)
  --solo                 no radio between the robots: each runs single-robot SLAM on the same
                         route (the baseline the team's errors are compared with); lockstep only
  --truth-loop-closures  loop closures (robot detections, submap matches) from the simulator's
                         ground truth with the thesis's noise models: a TEST-ONLY source for
                         comparisons, next to the robots' own detections; reports say so;
                         lockstep runner only
  --wrong-closure-fraction F
                         with --truth-loop-closures: replace the fraction F (0 to 1) of the
                         inter-robot closures by confidently wrong ones (1-10 m, random yaw, the
                         genuine covariance); the report counts what the graphs let in
  --consistency C        the robots' screening of inter-robot closures: none (the thesis's
                         Cauchy kernel only) or pcm (pairwise consistency maximization first);
                         default: the configuration's
  --feed ADDR            the ground station's UDP address (e.g. 127.0.0.1:7700): the robots' ground
                         links (telemetry v2, poses, constraints, submaps) go there from one socket,
                         and what it sends back (acks, commands) reaches the addressed robot;
                         without it an in-process stand-in acknowledges. Either way the ground
                         traffic is recorded in OUT/ground_feed.log (groundstation --replay OUT)
  --ground-key FILE      key file (hex, owner-only permissions) authenticating ground commands on
                         every robot; without it every command is refused
  --ground-delay-ms MS   one-way delay of the emulated ground link, process runner (default 1000)
  --ground-loss P        probability that the emulated ground link loses a packet, each way
                         (process runner, default 0)
  --ground-outage A-B    the emulated ground link carries nothing from A to B seconds of mission
                         time (process runner; repeatable)
  --kill [R:]P@S         fault injection (process runner): SIGKILL to process P (driver, vision,
                         filter, mapper, comms) of robot index R (folder robotR/, default 0) at
                         S seconds of mission time; repeatable; recorded in faults.json
  --json                 print the report as one JSON object instead of the summary";

/// `A-B` in seconds → `[A, B)` in ms.
fn parse_outage(text: &str) -> Result<(u64, u64), String> {
    let bad = || format!("--ground-outage: expected START-END seconds with START < END, got {text:?}");
    let (a, b) = text.split_once('-').ok_or_else(bad)?;
    let seconds = |v: &str| v.trim().parse::<f64>().ok().filter(|s| s.is_finite() && (0.0..=1e6).contains(s));
    match (seconds(a), seconds(b)) {
        (Some(a), Some(b)) if a < b => Ok(((a * 1e3).round() as u64, (b * 1e3).round() as u64)),
        _ => Err(bad()),
    }
}

fn parse_args(args: Vec<OsString>) -> Result<Option<(MissionOptions, bool)>, String> {
    use super::text;
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let mut options = MissionOptions::default();
    let mut json = false;
    let mut matching: Option<Option<MatchModeConfig>> = None;
    let mut duration_s = None;
    let mut seed = None;
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("robots") => {
                let v = text(&mut parser, "--robots")?;
                options.robots = match v.parse::<usize>() {
                    Ok(n) if (1..=8).contains(&n) => n,
                    _ => return Err(format!("--robots: expected 1 to 8, got {v:?}")),
                };
            }
            Long("scenario") => options.scenario = text(&mut parser, "--scenario")?,
            Long("duration") => {
                duration_s = Some(super::duration_s(&text(&mut parser, "--duration")?)?);
            }
            Long("seed") => {
                let v = text(&mut parser, "--seed")?;
                seed = Some(v.parse().map_err(|_| format!("--seed: expected an integer, got {v:?}"))?);
            }
            Long("downscale") => {
                options.downscale = super::downscale(&text(&mut parser, "--downscale")?)?;
            }
            Long("out") => options.out = parser.value().map_err(|e| e.to_string())?.into(),
            Long("device-fault") => {
                options
                    .device_faults
                    .push(text(&mut parser, "--device-fault")?.parse().map_err(|e| format!("--device-fault: {e}"))?);
            }
            Long("runner") => {
                options.runner = match text(&mut parser, "--runner")?.as_str() {
                    "lockstep" => Runner::Lockstep,
                    "process" => Runner::Process,
                    "hil" => {
                        options.hil = true;
                        Runner::Process
                    }
                    other => return Err(format!("--runner: expected lockstep, process or hil, got {other:?}")),
                };
            }
            Long("radio") => {
                options.radio = match text(&mut parser, "--radio")?.as_str() {
                    "serial" => RadioPreset::SerialRadio,
                    "wifi" => RadioPreset::Wifi,
                    other => return Err(format!("--radio: expected serial or wifi, got {other:?}")),
                };
            }
            Long("threads") => {
                options.step_threads = super::step_threads(&text(&mut parser, "--threads")?)?;
            }
            Long("truth-loop-closures") => options.truth_loop_closures = true,
            Long("compare-match-modes") => options.compare_match_modes = true,
            Long("evaluate-match-pairs") => options.evaluate_match_pairs = true,
            Long("rocks-in-hub") => options.rocks_in_hub = true,
            Long("solo") => options.solo = true,
            Long("rocks-per-100m2") => {
                let v = text(&mut parser, "--rocks-per-100m2")?;
                options.rocks_per_100m2 = match v.parse::<f64>() {
                    Ok(d) if d.is_finite() && (0.0..=100.0).contains(&d) => Some(d),
                    _ => return Err(format!("--rocks-per-100m2: expected 0 to 100, got {v:?}")),
                };
            }
            Long("matching") => {
                matching = Some(match text(&mut parser, "--matching")?.as_str() {
                    "off" => None,
                    "4d" => Some(MatchModeConfig::FourD),
                    "6d" => Some(MatchModeConfig::SixD),
                    other => return Err(format!("--matching: expected 4d, 6d or off, got {other:?}")),
                });
            }
            Long("wrong-closure-fraction") => {
                let v = text(&mut parser, "--wrong-closure-fraction")?;
                options.wrong_closure_fraction = match v.parse::<f64>() {
                    Ok(f) if (0.0..=1.0).contains(&f) => f,
                    _ => return Err(format!("--wrong-closure-fraction: expected 0 to 1, got {v:?}")),
                };
            }
            Long("consistency") => {
                options.consistency = match text(&mut parser, "--consistency")?.as_str() {
                    "none" => InterRobotConsistency::None,
                    "pcm" => InterRobotConsistency::Pcm,
                    other => return Err(format!("--consistency: expected none or pcm, got {other:?}")),
                };
            }
            Long("gaze") => {
                options.gaze = match text(&mut parser, "--gaze")?.as_str() {
                    "on" => true,
                    "off" => false,
                    other => return Err(format!("--gaze: expected on or off, got {other:?}")),
                };
            }
            Long("markers") => {
                options.markers = match text(&mut parser, "--markers")?.as_str() {
                    "off" => None,
                    "constant" => Some(MarkerModelConfig::Constant),
                    "quadratic" => Some(MarkerModelConfig::Quadratic),
                    "lut" => Some(MarkerModelConfig::Lut),
                    "online" => Some(MarkerModelConfig::Online),
                    "lut_online" => Some(MarkerModelConfig::LutOnline),
                    other => {
                        return Err(format!(
                            "--markers: expected lut_online, lut, online, quadratic, constant or off, got {other:?}"
                        ));
                    }
                };
            }
            Long("feed") => {
                let v = text(&mut parser, "--feed")?;
                let v = v.strip_prefix("udp://").unwrap_or(&v);
                options.feed = Some(v.parse().map_err(|_| format!("--feed: expected HOST:PORT, got {v:?}"))?);
            }
            Long("kill") => {
                let v = text(&mut parser, "--kill")?;
                options.faults.push(v.parse().map_err(|e| format!("--kill: {e}"))?);
            }
            Long("ground-key") => options.ground_key = Some(parser.value().map_err(|e| e.to_string())?.into()),
            Long("ground-delay-ms") => {
                let v = text(&mut parser, "--ground-delay-ms")?;
                options.ground_link.delay_ms = match v.parse::<u64>() {
                    Ok(ms) if ms <= 60_000 => ms,
                    _ => return Err(format!("--ground-delay-ms: expected 0 to 60000, got {v:?}")),
                };
            }
            Long("ground-loss") => {
                let v = text(&mut parser, "--ground-loss")?;
                options.ground_link.loss = match v.parse::<f64>() {
                    Ok(p) if (0.0..1.0).contains(&p) => p,
                    _ => return Err(format!("--ground-loss: expected a probability in [0, 1), got {v:?}")),
                };
            }
            Long("ground-outage") => {
                let v = text(&mut parser, "--ground-outage")?;
                options.ground_link.outages_ms.push(parse_outage(&v)?);
            }
            Long("json") => json = true,
            Long("help") | Short('h') => return Ok(None),
            other => return Err(other.unexpected().to_string()),
        }
    }
    // The truth closures are the matcher's upper bound: alone unless a matcher is asked for.
    options.matching = match matching {
        Some(choice) => choice,
        None if options.truth_loop_closures => None,
        None => options.matching,
    };
    if let Some(experiment) = experiments::find(&options.scenario) {
        if options.robots != 2 {
            return Err(format!(
                "--scenario {}: a 2-robot experiment, got --robots {}",
                experiment.name, options.robots
            ));
        }
        if duration_s.is_some_and(|d| d > experiment.duration_s) {
            return Err(format!("--duration: experiment {} lasts {} s", experiment.name, experiment.duration_s));
        }
        options.duration_s = duration_s.unwrap_or(experiment.duration_s);
        options.seed = seed.unwrap_or(experiment.seed);
    } else if matches!(options.scenario.as_str(), "moon" | "mars") {
        options.duration_s = duration_s.unwrap_or(options.duration_s);
        options.seed = seed.unwrap_or(options.seed);
    } else {
        return Err(format!(
            "--scenario: expected moon, mars, {} or list, got {:?}",
            experiments::names().join(", "),
            options.scenario
        ));
    }
    if options.truth_loop_closures && options.runner == Runner::Process {
        return Err(
            "--truth-loop-closures needs --runner lockstep (the test-only source reads the lockstep world)".into()
        );
    }
    if options.solo && options.runner == Runner::Process {
        return Err("--solo needs --runner lockstep (the process runner's robots share one radio)".to_owned());
    }
    if options.wrong_closure_fraction > 0.0 && !options.truth_loop_closures {
        return Err("--wrong-closure-fraction needs --truth-loop-closures".to_owned());
    }
    if !options.faults.is_empty() && options.runner != Runner::Process {
        return Err("--kill needs --runner process".to_owned());
    }
    if !options.device_faults.is_empty() && !options.hil {
        return Err("--device-fault needs --runner hil".to_owned());
    }
    if let Some(fault) = options.device_faults.iter().find(|f| f.robot >= options.robots) {
        return Err(format!("--device-fault: robot index {} of {} robots", fault.robot, options.robots));
    }
    if let Some(fault) = options.faults.iter().find(|f| f.robot >= options.robots) {
        return Err(format!("--kill: robot index {} of {} robots", fault.robot, options.robots));
    }
    // A line on a terminal, none in a pipe or a log, none around the JSON object.
    options.progress = !json && std::io::stderr().is_terminal();
    Ok(Some((options, json)))
}

/// Whether `args` ask for the list of scenarios (`--scenario list`).
fn asks_for_list(args: &[OsString]) -> bool {
    args.windows(2).any(|w| w[0] == "--scenario" && w[1] == "list") || args.iter().any(|a| a == "--scenario=list")
}

/// The scenarios, one paragraph each.
pub fn scenario_list() -> String {
    let mut text = String::from(
        "sites (any team size; each rover explores a seeded rosette of petals from a shared hub):\n  \
         moon, mars\n\nexperiments (2 rovers; after the thesis's multi-robot evaluation, §8.3):\n",
    );
    for e in experiments::EXPERIMENTS {
        text.push_str(&format!(
            "  {:<15} {} site, {:.0} s, seed {}, {} rocks/100 m²\n  {:<15} {}\n  {:<15} after {}\n",
            e.name, e.site, e.duration_s, e.seed, e.rocks_per_100m2, "", e.summary, "", e.after
        ));
    }
    text
}

pub fn main(args: Vec<OsString>) -> ExitCode {
    if asks_for_list(&args) {
        print!("{}", scenario_list());
        return ExitCode::SUCCESS;
    }
    let run = |(options, _json): &(MissionOptions, bool)| -> Result<MissionReport, String> {
        crate::mission::run(options).map_err(|e| e.to_string())
    };
    let ((options, json), report) = match onboard::cli::parse_and_run("sil", "mission", USAGE, args, parse_args, run) {
        Ok(done) => done,
        Err(code) => return code,
    };
    if json {
        println!("{}", report.to_json());
    } else {
        print!("{}", report.summary());
        println!("outputs in {}", options.out.display());
    }
    ExitCode::SUCCESS
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;
    use proptest::prelude::*;

    fn parse(args: &[&str]) -> Result<MissionOptions, String> {
        parse_args(args.iter().map(OsString::from).collect()).map(|o| o.unwrap().0)
    }

    #[test]
    fn experiments_bring_their_length_and_seed() {
        let loops = parse(&["--scenario", "loops"]).unwrap();
        assert_eq!((loops.duration_s, loops.seed), (600.0, 12));
        let short = parse(&["--scenario", "loops", "--duration", "30", "--seed", "5"]).unwrap();
        assert_eq!((short.duration_s, short.seed), (30.0, 5));
        let site = parse(&["--scenario", "mars"]).unwrap();
        assert_eq!((site.duration_s, site.seed), (120.0, 1));
        for (args, needle) in [
            (&["--scenario", "loops", "--duration", "601"][..], "lasts 600 s"),
            (&["--scenario", "loops", "--robots", "3"][..], "2-robot"),
            (&["--scenario", "venus"][..], "hetero-cameras"),
        ] {
            let error = parse(args).unwrap_err();
            assert!(error.contains(needle), "{args:?}: {error}");
        }
        assert!(asks_for_list(&["--scenario".into(), "list".into()]));
        let list = scenario_list();
        for e in experiments::EXPERIMENTS {
            assert!(list.contains(e.name) && list.contains(e.after), "{list}");
        }
    }

    #[test]
    fn outages_are_start_end_seconds() {
        assert_eq!(parse_outage("30-45"), Ok((30_000, 45_000)));
        assert_eq!(parse_outage(" 0.5 - 2.25"), Ok((500, 2_250)));
        for bad in ["", "30", "45-30", "30-30", "-5", "a-b", "1-inf", "1-NaN", "-1-4"] {
            assert!(parse_outage(bad).unwrap_err().contains("--ground-outage"), "{bad:?}");
        }
    }

    #[test]
    fn ground_link_options_reach_the_mission_options() {
        let args = ["--ground-delay-ms", "2000", "--ground-loss", "0.2", "--ground-outage", "10-20"];
        let (options, _) = parse_args(args.iter().map(OsString::from).collect()).unwrap().unwrap();
        assert_eq!(options.ground_link.delay_ms, 2_000);
        assert_eq!(options.ground_link.loss, 0.2);
        assert_eq!(options.ground_link.outages_ms, vec![(10_000, 20_000)]);
        for bad in [["--ground-loss", "1.0"], ["--ground-loss", "-0.1"], ["--ground-outage", "5"]] {
            assert!(parse_args(bad.iter().map(OsString::from).collect()).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn outlier_experiment_options_reach_the_mission_options() {
        let args = ["--truth-loop-closures", "--wrong-closure-fraction", "0.2", "--consistency", "pcm"];
        let (options, _) = parse_args(args.iter().map(OsString::from).collect()).unwrap().unwrap();
        assert_eq!(options.wrong_closure_fraction, 0.2);
        assert_eq!(options.consistency, InterRobotConsistency::Pcm);
        let bad: [&[&str]; 3] = [
            &["--wrong-closure-fraction", "0.2"],
            &["--truth-loop-closures", "--wrong-closure-fraction", "1.5"],
            &["--consistency", "ransac"],
        ];
        for bad in bad {
            assert!(parse_args(bad.iter().map(OsString::from).collect()).is_err(), "{bad:?}");
        }
    }

    #[test]
    fn solo_and_hub_rocks_reach_the_mission_options() {
        let args = ["--solo", "--rocks-in-hub", "--rocks-per-100m2", "12"];
        let (options, _) = parse_args(args.iter().map(OsString::from).collect()).unwrap().unwrap();
        assert!(options.solo && options.rocks_in_hub);
        assert_eq!(options.rocks_per_100m2, Some(12.0));
        let (default, _) = parse_args(Vec::new()).unwrap().unwrap();
        assert!(!default.solo && !default.rocks_in_hub);
        let refused = parse_args(["--solo", "--runner", "process"].iter().map(OsString::from).collect());
        assert!(refused.unwrap_err().contains("--solo"));
    }

    proptest! {
        #[test]
        fn any_outage_text_parses_or_is_refused(text in "\\PC{0,24}") {
            if let Ok((start_ms, end_ms)) = parse_outage(&text) {
                prop_assert!(start_ms <= end_ms && end_ms <= 1_000_000_000, "{start_ms}-{end_ms}");
            }
        }
    }
}
