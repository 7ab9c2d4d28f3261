//! `sim`: record simulated runs as EuRoC/ASL datasets and draw the README's pictures.
//!
//! ```text
//! sim record   --scenario NAME --out DIR [--robots N] [--duration S] [--seed S] [--downscale K]
//!              [--world-size M] [--flyer] [--threads T] [--json]
//! sim pictures --out DIR [--width W] [--seed S]
//! ```
//!
//! Exit codes: 0 success, 1 runtime error (world cannot be built, files cannot be written),
//! 2 usage (unknown subcommand or option, missing or bad value, unknown scenario).

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use lexopt::prelude::*;
use serde_json::json;
use sim::asl::{self, RecordStats, WorldFiles};
use sim::pictures::{self, PictureOptions};
use sim::scenario::{self, PRESETS, ScenarioError, ScenarioOptions};
use sim::world::World;

const USAGE: &str = "\
usage: sim <subcommand> [options]

  sim record --scenario NAME --out DIR [options]
      Records every robot of a scenario as a EuRoC/ASL dataset in DIR/robot<id>/mav0/ and the
      world's ground truth in DIR/world/.
      --scenario NAME    moon or mars, or a 2-robot experiment (lab-rocks, loops, loops-mars,
                         double-loop, leave-reenter, hetero-cameras; `sil mission --scenario list`)
      --out DIR          output folder (its robot<id>/ and world/ must not exist yet)
      --robots N         rovers in the team (default 2)
      --duration S       length of the run in seconds (default 60)
      --seed S           seed of everything random (default 1)
      --downscale K      render at 1/K of 1024x508 (default 1)
      --world-size M     edge of the terrain square in metres (default: the preset's)
      --flyer            add a flyer to the team
      --threads T        robots recorded in parallel (default: all cores); same bytes either way
      --json             print one JSON object instead of the human summary

  sim pictures --out DIR [--width W] [--seed S]
      Writes <preset>_left.png, <preset>_depth.png and <preset>_topdown.png for each preset.
      --width W          width of the pictures in pixels (default 512)
      --seed S           seed of the worlds (default 1)";

/// A failed run: `Usage` exits with 2, `Runtime` with 1.
#[derive(Debug, thiserror::Error)]
enum CliError {
    #[error("{0}\n(see `sim help`)")]
    Usage(String),
    #[error("{0}")]
    Runtime(String),
}

impl CliError {
    fn exit_code(&self) -> u8 {
        match self {
            CliError::Usage(_) => 2,
            CliError::Runtime(_) => 1,
        }
    }
}

impl From<lexopt::Error> for CliError {
    fn from(error: lexopt::Error) -> Self {
        CliError::Usage(error.to_string())
    }
}

fn runtime(error: impl std::fmt::Display) -> CliError {
    CliError::Runtime(error.to_string())
}

fn main() -> ExitCode {
    let mut args = std::env::args_os().skip(1);
    let Some(name) = args.next() else {
        eprintln!("{USAGE}");
        return ExitCode::from(2);
    };
    let rest: Vec<OsString> = args.collect();
    let result = match name.to_str() {
        Some("help" | "--help" | "-h") => {
            println!("{USAGE}");
            Ok(())
        }
        Some("record") => cmd_record(rest),
        Some("pictures") => cmd_pictures(rest),
        Some(other) => Err(CliError::Usage(format!("unknown subcommand `{other}`"))),
        None => Err(CliError::Usage("the subcommand is not valid UTF-8".to_owned())),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("sim: {error}");
            ExitCode::from(error.exit_code())
        }
    }
}

fn number<T: std::str::FromStr>(option: &str, value: OsString) -> Result<T, CliError> {
    let text = value.to_string_lossy();
    text.parse().map_err(|_| CliError::Usage(format!("--{option}: `{text}` is not a valid number")))
}

fn missing(option: &str) -> CliError {
    CliError::Usage(format!("missing --{option}"))
}

#[derive(Debug)]
struct RecordArgs {
    scenario: String,
    out: PathBuf,
    options: ScenarioOptions,
    threads: usize,
    json: bool,
}

/// `Ok(None)`: `--help` was asked for.
fn parse_record(args: Vec<OsString>) -> Result<Option<RecordArgs>, CliError> {
    let mut parser = lexopt::Parser::from_args(args);
    let mut options = ScenarioOptions::default();
    let (mut scenario, mut out, mut threads, mut json) = (None, None, None, false);
    while let Some(arg) = parser.next()? {
        match arg {
            Long("scenario") => scenario = Some(parser.value()?.to_string_lossy().into_owned()),
            Long("out") => out = Some(PathBuf::from(parser.value()?)),
            Long("robots") => options.robots = number("robots", parser.value()?)?,
            Long("duration") => options.duration_s = number("duration", parser.value()?)?,
            Long("seed") => options.seed = number("seed", parser.value()?)?,
            Long("downscale") => options.downscale = number("downscale", parser.value()?)?,
            Long("world-size") => options.world_size_m = Some(number("world-size", parser.value()?)?),
            Long("flyer") => options.flyer = true,
            Long("threads") => threads = Some(number::<usize>("threads", parser.value()?)?),
            Long("json") => json = true,
            Long("help") | Short('h') => return Ok(None),
            _ => return Err(arg.unexpected().into()),
        }
    }
    let scenario = scenario.ok_or_else(|| missing("scenario"))?;
    if !PRESETS.contains(&scenario.as_str()) && scenario::experiments::find(&scenario).is_none() {
        let known = [PRESETS, &scenario::experiments::names()].concat().join(", ");
        return Err(CliError::Usage(format!("unknown scenario `{scenario}` (known: {known})")));
    }
    if options.robots == 0 {
        return Err(CliError::Usage("--robots must be at least 1".to_owned()));
    }
    if !(options.duration_s.is_finite() && options.duration_s > 0.0) {
        return Err(CliError::Usage("--duration must be a positive number of seconds".to_owned()));
    }
    if options.downscale == 0 {
        return Err(CliError::Usage("--downscale must be at least 1".to_owned()));
    }
    if options.world_size_m.is_some_and(|m| !(m.is_finite() && m > 0.0)) {
        return Err(CliError::Usage("--world-size must be a positive number of metres".to_owned()));
    }
    let threads = match threads {
        Some(0) => return Err(CliError::Usage("--threads must be at least 1".to_owned())),
        Some(t) => t,
        None => std::thread::available_parallelism().map_or(1, usize::from),
    };
    Ok(Some(RecordArgs { scenario, out: out.ok_or_else(|| missing("out"))?, options, threads, json }))
}

fn cmd_record(args: Vec<OsString>) -> Result<(), CliError> {
    let Some(args) = parse_record(args)? else {
        println!("{USAGE}");
        return Ok(());
    };
    let wall = Instant::now();
    // Options the preset rejects are the caller's mistake, reported before any work.
    let scenario = scenario::preset(&args.scenario, &args.options).map_err(|e| match e {
        ScenarioError::Unknown(_) | ScenarioError::Invalid(_) => CliError::Usage(e.to_string()),
    })?;
    let mut targets = vec![args.out.join("world")];
    targets.extend(scenario.robots.iter().map(|r| args.out.join(format!("robot{}", r.id))));
    if let Some(existing) = targets.iter().find(|p| p.exists()) {
        return Err(CliError::Runtime(format!("{} already exists; record into a fresh --out", existing.display())));
    }
    let world = World::build(&scenario).map_err(runtime)?;
    let end_ns = world.end_ns().max(1);
    let quarters: Vec<AtomicU64> = (0..world.robots.len()).map(|_| AtomicU64::new(0)).collect();
    let quiet = args.json;
    let progress = |robot: usize, stamp_ns: u64| {
        let quarter = stamp_ns.saturating_mul(4) / end_ns;
        if !quiet && quarter > quarters[robot].fetch_max(quarter, Ordering::Relaxed) && quarter < 4 {
            eprintln!("sim: robot {robot}: {}% recorded", quarter * 25);
        }
    };
    let (stats, world_files) = asl::record_run(&world, &args.out, args.threads, &progress).map_err(runtime)?;
    let wall_s = wall.elapsed().as_secs_f64();
    report(&args, &world, &stats, &world_files, wall_s);
    Ok(())
}

fn report(args: &RecordArgs, world: &Arc<World>, stats: &[RecordStats], world_files: &WorldFiles, wall_s: f64) {
    let pairs: u64 = stats.iter().map(|s| s.stereo_pairs).sum();
    let bytes = world_files.bytes + stats.iter().map(|s| s.bytes).sum::<u64>();
    let ms_per_pair = |elapsed_s: f64, pairs: u64| if pairs == 0 { f64::NAN } else { 1e3 * elapsed_s / pairs as f64 };
    let dir = |robot: usize| asl::robot_dir(world, &args.out, robot).display().to_string();
    if args.json {
        let robots: Vec<_> = stats
            .iter()
            .enumerate()
            .map(|(i, s)| {
                let camera = world.robots[i].model().camera;
                json!({
                    "dir": dir(i),
                    "stereo_pairs": s.stereo_pairs,
                    "width": camera.width_px,
                    "height": camera.height_px,
                    "imu_samples": s.imu_samples,
                    "wheel_samples": s.wheel_samples,
                    "ground_truth_rows": s.ground_truth_rows,
                    "bytes": s.bytes,
                    "elapsed_s": s.elapsed_s,
                    "ms_per_stereo_pair": ms_per_pair(s.elapsed_s, s.stereo_pairs),
                })
            })
            .collect();
        let report = json!({
            "scenario": world.scenario.name,
            "seed": world.scenario.seed,
            "duration_s": world.scenario.duration_s,
            "out": args.out.display().to_string(),
            "threads": args.threads,
            "robots": robots,
            "world": {
                "bytes": world_files.bytes,
                "rocks": world_files.rocks,
                "markers": world_files.markers,
                "height_grid_min_m": world_files.height_grid_min_m,
                "height_grid_max_m": world_files.height_grid_max_m,
            },
            "stereo_pairs": pairs,
            "bytes": bytes,
            "wall_s": wall_s,
            "wall_ms_per_stereo_pair": ms_per_pair(wall_s, pairs),
        });
        println!("{report}");
        return;
    }
    let s = &world.scenario;
    println!(
        "sim record: scenario {}, seed {}, {} robot(s), {} s -> {}",
        s.name,
        s.seed,
        world.robots.len(),
        s.duration_s,
        args.out.display()
    );
    for (i, st) in stats.iter().enumerate() {
        let camera = world.robots[i].model().camera;
        println!(
            "  {}: {} stereo pairs ({}x{}), {} IMU, {} wheel samples, {:.1} MB, {:.1} ms per pair",
            dir(i),
            st.stereo_pairs,
            camera.width_px,
            camera.height_px,
            st.imu_samples,
            st.wheel_samples,
            st.bytes as f64 / 1e6,
            ms_per_pair(st.elapsed_s, st.stereo_pairs)
        );
    }
    println!(
        "  world: {:.1} MB ({} rocks, {} markers)",
        world_files.bytes as f64 / 1e6,
        world_files.rocks,
        world_files.markers
    );
    println!(
        "  total: {pairs} stereo pairs, {:.1} MB in {wall_s:.1} s wall ({:.1} ms per pair, {} thread(s))",
        bytes as f64 / 1e6,
        ms_per_pair(wall_s, pairs),
        args.threads
    );
}

fn cmd_pictures(args: Vec<OsString>) -> Result<(), CliError> {
    let mut parser = lexopt::Parser::from_args(args);
    let mut options = PictureOptions::default();
    let mut out: Option<PathBuf> = None;
    while let Some(arg) = parser.next()? {
        match arg {
            Long("out") => out = Some(PathBuf::from(parser.value()?)),
            Long("width") => options.width = number("width", parser.value()?)?,
            Long("seed") => options.seed = number("seed", parser.value()?)?,
            Long("help") | Short('h') => {
                println!("{USAGE}");
                return Ok(());
            }
            _ => return Err(arg.unexpected().into()),
        }
    }
    if !(16..=4096).contains(&options.width) {
        return Err(CliError::Usage("--width must be between 16 and 4096 pixels".to_owned()));
    }
    let out = out.ok_or_else(|| missing("out"))?;
    let start = Instant::now();
    let written = pictures::write_pictures(Path::new(&out), &options).map_err(runtime)?;
    for picture in &written {
        println!(
            "{} ({}x{}, {:.0} KB)",
            picture.path.display(),
            picture.width,
            picture.height,
            picture.bytes as f64 / 1e3
        );
    }
    println!("sim pictures: {} files in {:.1} s", written.len(), start.elapsed().as_secs_f64());
    Ok(())
}
