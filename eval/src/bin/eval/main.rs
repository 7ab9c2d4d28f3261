//! `eval`: trajectory and pose-graph evaluation from the command line.
//!
//! ```text
//! eval ate   --gt GT --est EST [--align A] [--max-diff S] [--offset S] [--interpolate] [--online] ...
//! eval rpe   --gt GT --est EST [--delta N] [--unit frames|m|s] [--align A] ...
//! eval stats --g2o G.g2o
//! eval sync  --gt GT --est EST [--signal yaw|rate] [--out SYNCED]
//! eval fuse  --odom ODOM --stream NAME:FILE:SIGMA_XY_M:SIGMA_THETA_DEG ... --out FUSED
//! eval plot  --gt GT --est EST --out FIG.png [--error-out ERR.png]
//! ```
//!
//! Exit codes: 0 success, 1 bad data (unreadable or malformed file, nothing to associate, a
//! degenerate alignment), 2 usage. Each subcommand is one `fn(Vec<OsString>) -> Result<(),
//! CliError>` listed in [`SUBCOMMANDS`]; adding one is a function plus a table row.

mod gt_tools;

use std::ffi::OsString;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use eval::Trajectory;
use eval::align::Alignment;
use eval::associate::{self, Association, DEFAULT_MAX_DIFF_S};
use eval::io::{self, Format};
use eval::metrics::{self, AteReport, Delta, PoseRelation, RpeReport, Stats};
use lexopt::prelude::*;
use serde_json::json;

/// A failed run: `Usage` exits with 2, `Data` with 1.
#[derive(Debug, thiserror::Error)]
enum CliError {
    #[error("{0}\n(see `eval help`)")]
    Usage(String),
    #[error("{0}")]
    Data(String),
}

impl CliError {
    fn exit_code(&self) -> u8 {
        match self {
            Self::Usage(_) => 2,
            Self::Data(_) => 1,
        }
    }
}

impl From<lexopt::Error> for CliError {
    fn from(error: lexopt::Error) -> Self {
        Self::Usage(error.to_string())
    }
}

type Subcommand = fn(Vec<OsString>) -> Result<(), CliError>;

/// Name, one-line description, entry point.
const SUBCOMMANDS: &[(&str, &str, Subcommand)] = &[
    ("ate", "absolute trajectory error (evo_ape), final error in % of distance, online estimates", cmd_ate),
    ("rpe", "relative pose error over frames, metres or seconds (evo_rpe)", cmd_rpe),
    ("stats", "pose-graph statistics of a g2o file", cmd_stats),
    (
        "sync",
        "clock offset, drift and heading offset of an estimate against ground truth (RAWSEEDS)",
        gt_tools::cmd_sync,
    ),
    ("fuse", "EKF + RTS fusion of ground-truth streams with odometry (RAWSEEDS)", gt_tools::cmd_fuse),
    ("plot", "top-down trajectory and error-over-distance plots (PNG)", gt_tools::cmd_plot),
];

const PAIR_OPTIONS_HELP: &str = "\
  --gt FILE              ground truth (TUM, KITTI or EuRoC CSV; detected from the content)
  --est FILE             estimate
  --format F             format of both files: tum, kitti or euroc (default: detect)
  --gt-format F          format of the ground truth, overriding --format
  --gt-times FILE        KITTI times file of the ground truth (default: row index as stamp)
  --est-times FILE       KITTI times file of the estimate
  --max-diff S           max. stamp difference for association [s] (default 0.01, as evo)
  --offset S             added to the estimate's stamps before association [s] (default 0)
  --interpolate          interpolate the ground truth on SE(3) at the estimate stamps instead
                         of taking the nearest stamp
  --max-gap S            with --interpolate: skip estimate stamps between ground-truth samples
                         more than S apart (default 0.1)
  --align A              none (default), se3, sim3, scale, 4dof, se2, first:<N>m (SE(3) fitted on
                         the first N metres of ground-truth path), first:<N>m:4dof
  --relation R           trans_part (default), angle_rad, angle_deg, rot_part, full (evo's names)
  --json                 one JSON object instead of the human summary";

fn usage() -> String {
    let mut text = String::from("usage: eval <subcommand> [options]\n\nsubcommands:\n");
    for (name, description, _) in SUBCOMMANDS {
        text.push_str(&format!("  {name:<8}{description}\n"));
    }
    text.push_str("\nrun `eval <subcommand> --help` for its options");
    text
}

fn main() -> ExitCode {
    let mut args = std::env::args_os().skip(1);
    let Some(name) = args.next() else {
        eprintln!("{}", usage());
        return ExitCode::from(2);
    };
    let rest: Vec<OsString> = args.collect();
    let result = match name.to_str() {
        Some("help" | "--help" | "-h") => {
            println!("{}", usage());
            Ok(())
        }
        Some(name) => match SUBCOMMANDS.iter().find(|(n, _, _)| *n == name) {
            Some((_, _, run)) => run(rest),
            None => Err(CliError::Usage(format!("unknown subcommand `{name}`"))),
        },
        None => Err(CliError::Usage("the subcommand is not valid UTF-8".into())),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("eval: {error}");
            ExitCode::from(error.exit_code())
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Shared option handling

/// Options of the subcommands that compare an estimate with ground truth.
#[derive(Debug)]
struct PairOptions {
    gt: Option<PathBuf>,
    est: Option<PathBuf>,
    format: Option<Format>,
    gt_format: Option<Format>,
    gt_times: Option<PathBuf>,
    est_times: Option<PathBuf>,
    max_diff_s: f64,
    offset_s: f64,
    interpolate: bool,
    max_gap_s: f64,
    align: Alignment,
    relation: PoseRelation,
    json: bool,
}

impl Default for PairOptions {
    fn default() -> Self {
        Self {
            gt: None,
            est: None,
            format: None,
            gt_format: None,
            gt_times: None,
            est_times: None,
            max_diff_s: DEFAULT_MAX_DIFF_S,
            offset_s: 0.0,
            interpolate: false,
            max_gap_s: 0.1,
            align: Alignment::None,
            relation: PoseRelation::Translation,
            json: false,
        }
    }
}

/// Parses an option value with `FromStr`, as a usage error naming the option.
fn value<T>(parser: &mut lexopt::Parser, option: &str) -> Result<T, CliError>
where
    T: core::str::FromStr,
    T::Err: core::fmt::Display,
{
    let raw = parser.value()?;
    let text = raw.to_str().ok_or_else(|| CliError::Usage(format!("{option}: value is not valid UTF-8")))?;
    text.parse().map_err(|e| CliError::Usage(format!("{option}: {e}")))
}

/// The name of a long option (`-h` counts as `help`); anything else is a usage error. Owned, so
/// that the parser can be borrowed again for the option's value.
fn long_name(arg: lexopt::Arg<'_>) -> Result<String, CliError> {
    match arg {
        Long(name) => Ok(name.to_owned()),
        Short('h') => Ok("help".to_owned()),
        other => Err(other.unexpected().into()),
    }
}

fn unknown_option(option: &str) -> CliError {
    CliError::Usage(format!("unknown option `--{option}`"))
}

fn seconds(parser: &mut lexopt::Parser, option: &str) -> Result<f64, CliError> {
    let s: f64 = value(parser, option)?;
    if s.is_finite() { Ok(s) } else { Err(CliError::Usage(format!("{option}: must be a finite number of seconds"))) }
}

impl PairOptions {
    /// Consumes `arg` if it is one of the shared options; returns whether it was.
    fn take(&mut self, option: &str, parser: &mut lexopt::Parser) -> Result<bool, CliError> {
        match option {
            "gt" => self.gt = Some(parser.value()?.into()),
            "est" => self.est = Some(parser.value()?.into()),
            "format" => self.format = Some(value(parser, "--format")?),
            "gt-format" => self.gt_format = Some(value(parser, "--gt-format")?),
            "gt-times" => self.gt_times = Some(parser.value()?.into()),
            "est-times" => self.est_times = Some(parser.value()?.into()),
            "max-diff" => self.max_diff_s = seconds(parser, "--max-diff")?,
            "offset" => self.offset_s = seconds(parser, "--offset")?,
            "interpolate" => self.interpolate = true,
            "max-gap" => self.max_gap_s = seconds(parser, "--max-gap")?,
            "align" => self.align = value(parser, "--align")?,
            "relation" => self.relation = value(parser, "--relation")?,
            "json" => self.json = true,
            _ => return Ok(false),
        }
        Ok(true)
    }

    fn paths(&self) -> Result<(&Path, &Path), CliError> {
        match (&self.gt, &self.est) {
            (Some(gt), Some(est)) => Ok((gt, est)),
            _ => Err(CliError::Usage("both --gt and --est are required".into())),
        }
    }

    /// Reads both trajectories.
    fn load(&self) -> Result<(Trajectory, Trajectory), CliError> {
        let (gt_path, est_path) = self.paths()?;
        let gt = read_trajectory(gt_path, self.gt_format.or(self.format), self.gt_times.as_deref())?;
        let est = read_trajectory(est_path, self.format, self.est_times.as_deref())?;
        Ok((gt, est))
    }

    fn associate(&self, gt: &Trajectory, est: &Trajectory) -> Result<Association, CliError> {
        let association = if self.interpolate {
            associate::associate_interpolated(gt, est, self.offset_s, self.max_gap_s)
        } else {
            associate::associate(gt, est, self.max_diff_s, self.offset_s)
        };
        association.map_err(|e| CliError::Data(format!("{e} (see --max-diff, --offset, --interpolate, --max-gap)")))
    }
}

fn read_text(path: &Path) -> Result<String, CliError> {
    std::fs::read_to_string(path).map_err(|e| CliError::Data(format!("{}: {e}", path.display())))
}

/// Reads a trajectory file, in `format` or the detected one; errors name the file and line.
/// Repeated stamps are kept (as evo keeps them) but reported on stderr.
fn read_trajectory(path: &Path, format: Option<Format>, times: Option<&Path>) -> Result<Trajectory, CliError> {
    let trajectory = read_trajectory_rows(path, format, times)?;
    let repeated = io::repeated_stamps(&trajectory);
    if repeated > 0 {
        eprintln!("eval: warning: {}: {repeated} repeated stamps (kept, as evo does)", path.display());
    }
    Ok(trajectory)
}

fn read_trajectory_rows(path: &Path, format: Option<Format>, times: Option<&Path>) -> Result<Trajectory, CliError> {
    let text = read_text(path)?;
    let at = |e: io::ParseError| CliError::Data(format!("{}: {e}", path.display()));
    let format = match format {
        Some(format) => format,
        None => io::detect_format(&text).map_err(at)?,
    };
    match (format, times) {
        (Format::Kitti, Some(times_path)) => {
            // Poses and stamps are read apart so that each error names its own file.
            let untimed = io::parse_kitti(&text, None).map_err(at)?;
            let stamps_s = io::parse_times(&read_text(times_path)?, untimed.len())
                .map_err(|e| CliError::Data(format!("{}: {e}", times_path.display())))?;
            Ok(Trajectory { stamps_s, poses: untimed.poses })
        }
        (_, Some(_)) => Err(CliError::Usage(format!("{}: a times file only goes with KITTI poses", path.display()))),
        (format, None) => io::parse(&text, Some(format)).map(|(_, t)| t).map_err(at),
    }
}

fn stats_json(stats: &Stats) -> serde_json::Map<String, serde_json::Value> {
    let mut map: serde_json::Map<String, serde_json::Value> =
        stats.named().into_iter().map(|(name, v)| (name.to_owned(), v.into())).collect();
    map.insert("pairs".to_owned(), stats.count.into());
    map
}

fn print_stats(stats: &Stats, unit: &str) {
    for (name, v) in stats.named().into_iter().filter(|(name, _)| *name != "sse") {
        println!("  {name:<8}{v:>14.6} {unit}");
    }
    let squared = if unit.is_empty() { String::new() } else { format!("{unit}²") };
    println!("  {:<8}{:>14.6} {squared}", "sse", stats.sse);
}

fn relation_title(relation: PoseRelation) -> String {
    let unit = relation.unit();
    if unit.is_empty() { relation.name().to_string() } else { format!("{} [{unit}]", relation.name()) }
}

// ---------------------------------------------------------------------------------------------
// ate

const ATE_HELP: &str = "\
usage: eval ate --gt GT --est EST [options]

Absolute trajectory error (evo's APE) after association and alignment, with the final position
error and its ratio to the ground-truth distance travelled (thesis ch. 8).

  --online               the estimate is an online log: every row is the pose the robot reported
                         at that stamp (never re-optimized). Compared with the ground truth
                         interpolated at its stamps (implies --interpolate); --align may only be
                         none or first:<N>m[:4dof], since other fits use the whole run";

fn cmd_ate(args: Vec<OsString>) -> Result<(), CliError> {
    let mut options = PairOptions::default();
    let mut online = false;
    let mut parser = lexopt::Parser::from_args(args);
    while let Some(arg) = parser.next()? {
        let option = long_name(arg)?;
        if options.take(&option, &mut parser)? {
            continue;
        }
        match option.as_str() {
            "online" => online = true,
            "help" => {
                println!("{ATE_HELP}\n{PAIR_OPTIONS_HELP}");
                return Ok(());
            }
            _ => return Err(unknown_option(&option)),
        }
    }
    options.paths()?;
    if online && !matches!(options.align, Alignment::None | Alignment::FirstMetres { .. }) {
        return Err(CliError::Usage(format!(
            "--online allows only --align none or first:<N>m (got {})",
            options.align
        )));
    }
    let (gt, est) = options.load()?;
    let report = if online {
        metrics::online_ate(&gt, &est, options.offset_s, options.max_gap_s, &options.align, options.relation)
    } else {
        let association = options.associate(&gt, &est)?;
        metrics::ate(&association, &options.align, options.relation)
    }
    .map_err(|e| CliError::Data(e.to_string()))?;
    if options.json {
        print_ate_json(&report, &options, online);
    } else {
        print_ate(&report, &options, online);
    }
    Ok(())
}

fn print_ate_json(report: &AteReport, options: &PairOptions, online: bool) {
    let mut map = stats_json(&report.stats);
    let extra = json!({
        "metric": "ate",
        "relation": options.relation.name(),
        "unit": options.relation.unit(),
        "alignment": options.align.to_string(),
        "online": online,
        "final_error_m": report.final_error.error_m,
        "final_error_percent": report.final_error.percent,
        "gt_path_length_m": report.final_error.gt_path_length_m,
        "yaw_error_rmse_deg": report.yaw_stats_rad.rmse.to_degrees(),
        "yaw_error_mean_deg": report.yaw_stats_rad.mean.to_degrees(),
        "yaw_error_max_abs_deg": report.yaw_stats_rad.max.abs().max(report.yaw_stats_rad.min.abs()).to_degrees(),
        "alignment_scale": report.alignment.scale,
    });
    if let serde_json::Value::Object(extra) = extra {
        map.extend(extra);
    }
    println!("{}", serde_json::Value::Object(map));
}

fn print_ate(report: &AteReport, options: &PairOptions, online: bool) {
    let mode = if online { "online estimate, " } else { "" };
    println!(
        "ATE w.r.t. {} ({mode}alignment {}, {} pairs)",
        relation_title(options.relation),
        options.align,
        report.stats.count
    );
    print_stats(&report.stats, options.relation.unit());
    let f = &report.final_error;
    match f.percent {
        Some(percent) => {
            println!("  final error {:.4} m = {percent:.3} % of {:.3} m travelled", f.error_m, f.gt_path_length_m)
        }
        None => println!("  final error {:.4} m (no distance travelled)", f.error_m),
    }
    let yaw = &report.yaw_stats_rad;
    println!(
        "  yaw error   rmse {:.4} deg, mean {:.4} deg (signed, est − gt)",
        yaw.rmse.to_degrees(),
        yaw.mean.to_degrees()
    );
    if options.align != Alignment::None {
        let t = report.alignment.t_gt_est.translation.vector;
        let (roll, pitch, yaw) = report.alignment.t_gt_est.rotation.euler_angles();
        println!(
            "  alignment   t = ({:.4}, {:.4}, {:.4}) m, rpy = ({:.3}, {:.3}, {:.3}) deg, scale {:.6}",
            t.x,
            t.y,
            t.z,
            roll.to_degrees(),
            pitch.to_degrees(),
            yaw.to_degrees(),
            report.alignment.scale
        );
    }
}

// ---------------------------------------------------------------------------------------------
// rpe

const RPE_HELP: &str = "\
usage: eval rpe --gt GT --est EST [options]

Relative pose error (evo's RPE) over consecutive, non-overlapping pairs chosen on the estimate.

  --delta N              pair spacing (default 1)
  --unit U               frames (default), m (path length along the estimate, evo's
                         --delta_unit m) or s (time)";

fn cmd_rpe(args: Vec<OsString>) -> Result<(), CliError> {
    let mut options = PairOptions::default();
    let mut delta: f64 = 1.0;
    let mut unit = String::from("frames");
    let mut parser = lexopt::Parser::from_args(args);
    while let Some(arg) = parser.next()? {
        let option = long_name(arg)?;
        if options.take(&option, &mut parser)? {
            continue;
        }
        match option.as_str() {
            "delta" => delta = value(&mut parser, "--delta")?,
            "unit" => unit = value(&mut parser, "--unit")?,
            "help" => {
                println!("{RPE_HELP}\n{PAIR_OPTIONS_HELP}");
                return Ok(());
            }
            _ => return Err(unknown_option(&option)),
        }
    }
    let delta = match unit.as_str() {
        "frames" | "f" if delta >= 1.0 && delta.fract() == 0.0 && delta <= usize::MAX as f64 => {
            Delta::Frames(delta as usize)
        }
        "frames" | "f" => return Err(CliError::Usage(format!("--delta {delta}: frames need a whole number ≥ 1"))),
        "m" if delta.is_finite() && delta > 0.0 => Delta::Metres(delta),
        "s" if delta.is_finite() && delta > 0.0 => Delta::Seconds(delta),
        "m" | "s" => return Err(CliError::Usage(format!("--delta {delta}: must be positive"))),
        other => return Err(CliError::Usage(format!("--unit {other}: expected frames, m or s"))),
    };
    options.paths()?;
    let (gt, est) = options.load()?;
    let association = options.associate(&gt, &est)?;
    let report = metrics::rpe(&association, &options.align, delta, options.relation)
        .map_err(|e| CliError::Data(e.to_string()))?;
    if options.json {
        print_rpe_json(&report, &options, delta);
    } else {
        print_rpe(&report, &options, delta);
    }
    Ok(())
}

fn delta_text(delta: Delta) -> String {
    match delta {
        Delta::Frames(n) => format!("{n} frames"),
        Delta::Metres(m) => format!("{m} m"),
        Delta::Seconds(s) => format!("{s} s"),
    }
}

fn print_rpe_json(report: &RpeReport, options: &PairOptions, delta: Delta) {
    let mut map = stats_json(&report.stats);
    let (delta_value, delta_unit) = match delta {
        Delta::Frames(n) => (n as f64, "frames"),
        Delta::Metres(m) => (m, "m"),
        Delta::Seconds(s) => (s, "s"),
    };
    let extra = json!({
        "metric": "rpe",
        "relation": options.relation.name(),
        "unit": options.relation.unit(),
        "alignment": options.align.to_string(),
        "delta": delta_value,
        "delta_unit": delta_unit,
        "alignment_scale": report.alignment.scale,
    });
    if let serde_json::Value::Object(extra) = extra {
        map.extend(extra);
    }
    println!("{}", serde_json::Value::Object(map));
}

fn print_rpe(report: &RpeReport, options: &PairOptions, delta: Delta) {
    println!(
        "RPE w.r.t. {} for delta = {} (alignment {}, {} pairs)",
        relation_title(options.relation),
        delta_text(delta),
        options.align,
        report.stats.count
    );
    print_stats(&report.stats, options.relation.unit());
}

// ---------------------------------------------------------------------------------------------
// stats

const STATS_HELP: &str = "\
usage: eval stats --g2o FILE [--json]

Pose-graph statistics: vertices, edges, odometry edges (|i − j| = 1) and loop closures (the
rest), connected components, mean degree.";

fn cmd_stats(args: Vec<OsString>) -> Result<(), CliError> {
    let mut path: Option<PathBuf> = None;
    let mut as_json = false;
    let mut parser = lexopt::Parser::from_args(args);
    while let Some(arg) = parser.next()? {
        match arg {
            Long("g2o") => path = Some(parser.value()?.into()),
            Long("json") => as_json = true,
            Short('h') | Long("help") => {
                println!("{STATS_HELP}");
                return Ok(());
            }
            _ => return Err(arg.unexpected().into()),
        }
    }
    let path = path.ok_or_else(|| CliError::Usage("--g2o FILE is required".into()))?;
    let text = read_text(&path)?;
    let graph = posegraph::g2o::parse(&text).map_err(|e| CliError::Data(format!("{}: {e}", path.display())))?;
    let stats = metrics::graph_stats(&graph);
    if as_json {
        let value = json!({
            "vertices": stats.vertices,
            "edges": stats.edges,
            "odometry_edges": stats.odometry_edges,
            "loop_closure_edges": stats.loop_closure_edges,
            "components": stats.components,
            "mean_degree": stats.mean_degree,
        });
        println!("{value}");
    } else {
        println!("{}", path.display());
        println!("  vertices            {}", stats.vertices);
        println!("  edges               {}", stats.edges);
        println!("  odometry edges      {}", stats.odometry_edges);
        println!("  loop-closure edges  {}", stats.loop_closure_edges);
        println!("  components          {}", stats.components);
        println!("  mean degree         {:.3}", stats.mean_degree);
    }
    Ok(())
}
