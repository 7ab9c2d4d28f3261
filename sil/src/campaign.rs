//! `sil campaign`: the named experiments, each in several variants of the back-end, and one
//! report in the form of the thesis's tables (Tab. 8.8 and 8.9).
//!
//! Variants:
//! - `team`: the robots as they are, loop closures from their own detector and matcher;
//! - `solo`: no radio between the robots, each alone on the same route (single-robot SLAM,
//!   Tab. 8.9's right half);
//! - `truth`: loop closures drawn from the simulator's ground truth instead (a test-only upper
//!   bound, not a result).
//!
//! The thesis's back-end variants (multi-robot with its topology and with sequential odometry,
//! single-robot, filter only) replay the team run's graph inputs, so the images are rendered and
//! matched once for them. `solo` and `truth` run the whole mission again (the same images: the
//! runs are deterministic for a seed); the default campaign runs `team` and `truth`, `solo` is
//! there to check the single-robot replay against a robot that really was alone.
//! `report.md` is rewritten after every run, so an interrupted campaign keeps what it has.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use sim::scenario::experiments::{self, Experiment};

pub mod pictures;

use crate::mission::replay::ReplayScore;
use crate::mission::report::{MissionReport, RobotReport};
use crate::mission::{self, MissionError, MissionOptions};

/// How the back-end of a campaign run differs from the team's.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    Team,
    Solo,
    Truth,
}

impl Variant {
    pub const ALL: [Variant; 3] = [Variant::Team, Variant::Solo, Variant::Truth];
    /// What `sil campaign` runs unless told otherwise.
    pub const DEFAULT: [Variant; 2] = [Variant::Team, Variant::Truth];

    pub fn name(self) -> &'static str {
        match self {
            Variant::Team => "team",
            Variant::Solo => "solo",
            Variant::Truth => "truth",
        }
    }

    pub fn parse(text: &str) -> Option<Variant> {
        Variant::ALL.into_iter().find(|v| v.name() == text)
    }

    fn describe(self) -> &'static str {
        match self {
            Variant::Team => "multi-robot, the robots' own detections and matches",
            Variant::Solo => "single-robot: no radio between the robots, each alone on its route",
            Variant::Truth => {
                "multi-robot with loop closures from the simulator's truth (upper bound, test-only source)"
            }
        }
    }

    fn apply(self, options: &mut MissionOptions) {
        match self {
            // The front-end runs once; the thesis's back-end variants replay its graph inputs.
            Variant::Team => options.replay_variants = true,
            Variant::Solo => options.solo = true,
            Variant::Truth => {
                options.truth_loop_closures = true;
                options.matching = None;
            }
        }
    }
}

/// Everything `sil campaign` takes.
#[derive(Debug, Clone)]
pub struct CampaignOptions {
    pub out: PathBuf,
    pub experiments: Vec<&'static Experiment>,
    pub variants: Vec<Variant>,
    pub downscale: u32,
    /// Run only the first seconds of each experiment (tests, quick looks).
    pub duration_s: Option<f64>,
    pub step_threads: usize,
    pub progress: bool,
}

impl Default for CampaignOptions {
    fn default() -> Self {
        let mission = MissionOptions::default();
        CampaignOptions {
            out: PathBuf::from("runs/campaign"),
            experiments: experiments::EXPERIMENTS.iter().collect(),
            variants: Variant::DEFAULT.to_vec(),
            downscale: mission.downscale,
            duration_s: None,
            step_threads: mission.step_threads,
            progress: false,
        }
    }
}

/// One mission of the campaign.
#[derive(Debug, Clone)]
pub struct CampaignRun {
    pub experiment: &'static Experiment,
    pub variant: Variant,
    pub report: MissionReport,
}

/// The campaign's runs and its wall time.
#[derive(Debug, Clone, Default)]
pub struct Campaign {
    pub runs: Vec<CampaignRun>,
    pub wall_s: f64,
}

/// The mission of `experiment` in `variant`, its outputs in `out/NAME/VARIANT`.
pub fn mission_options(options: &CampaignOptions, experiment: &Experiment, variant: Variant) -> MissionOptions {
    let mut mission = MissionOptions {
        robots: 2,
        scenario: experiment.name.to_owned(),
        duration_s: options.duration_s.map_or(experiment.duration_s, |d| d.min(experiment.duration_s)),
        seed: experiment.seed,
        downscale: options.downscale,
        out: run_dir(&options.out, experiment, variant),
        step_threads: options.step_threads,
        progress: options.progress,
        ..MissionOptions::default()
    };
    variant.apply(&mut mission);
    mission
}

/// Runs every experiment of `options` in every variant, writing `out/report.md` after each run.
pub fn run(options: &CampaignOptions) -> Result<Campaign, MissionError> {
    let wall = Instant::now();
    std::fs::create_dir_all(&options.out).map_err(|e| MissionError::Io { path: options.out.clone(), source: e })?;
    let mut campaign = Campaign::default();
    // Variant by variant, so that an interrupted campaign has every scenario's team run first.
    for &variant in &options.variants {
        for &experiment in &options.experiments {
            let report = mission::run(&mission_options(options, experiment, variant))?;
            campaign.runs.push(CampaignRun { experiment, variant, report });
            campaign.wall_s = wall.elapsed().as_secs_f64();
            write_pictures(&options.out, &campaign, experiment)?;
            write_report(&options.out, &campaign, options)?;
        }
    }
    Ok(campaign)
}

/// The run directory of `experiment` in `variant` (see [`mission_options`]).
fn run_dir(out: &Path, experiment: &Experiment, variant: Variant) -> PathBuf {
    out.join(experiment.name).join(variant.name())
}

fn write_svg(path: PathBuf, svg: String) -> Result<(), MissionError> {
    std::fs::write(&path, svg).map_err(|e| MissionError::Io { path, source: e })
}

/// `NAME/VARIANT/trajectories.svg` of `experiment`'s latest run and `NAME/error.svg` over all of
/// its runs so far, the team run's loop closures marked.
fn write_pictures(out: &Path, campaign: &Campaign, experiment: &Experiment) -> Result<(), MissionError> {
    let runs: Vec<&CampaignRun> = campaign.runs.iter().filter(|r| r.experiment.name == experiment.name).collect();
    let mut tracks = Vec::new();
    for run in &runs {
        let dir = run_dir(out, experiment, run.variant);
        let mut robots = Vec::new();
        for (i, robot) in run.report.robots.iter().enumerate() {
            // A robot that never initialised has no trajectory to draw.
            if let Ok(track) = pictures::RobotTrack::read(robot.robot, &dir.join(format!("robot{i}"))) {
                robots.push(track);
            }
        }
        tracks.push((run.variant, robots));
    }
    if let Some((variant, latest)) = tracks.last() {
        write_svg(
            run_dir(out, experiment, *variant).join("trajectories.svg"),
            pictures::trajectories(latest, variant.name()),
        )?;
    }
    let events: Vec<Vec<_>> = runs
        .iter()
        .find(|r| r.variant == Variant::Team)
        .map(|team| team.report.robots.iter().map(|r| r.closure_events.clone()).collect())
        .unwrap_or_default();
    // The team run first: it is drawn solid, in the robot's colour.
    tracks.sort_by_key(|(v, _)| *v != Variant::Team);
    let variants: Vec<(&str, &[pictures::RobotTrack])> =
        tracks.iter().filter(|(_, t)| !t.is_empty()).map(|(v, t)| (v.name(), t.as_slice())).collect();
    write_svg(out.join(experiment.name).join("error.svg"), pictures::errors(&variants, &events))
}

fn write_report(out: &Path, campaign: &Campaign, options: &CampaignOptions) -> Result<(), MissionError> {
    let path = out.join("report.md");
    std::fs::write(&path, report_markdown(campaign, options)).map_err(|e| MissionError::Io { path, source: e })
}

/// Mean 3-D error over the distance travelled (%), `None` without a scored trajectory or distance.
fn error_percent(robot: &RobotReport) -> Option<f64> {
    robot.score.as_ref()?.mean_error_percent()
}

/// Accepted matches of the robot's own matcher: (intra-robot, inter-robot).
fn matches(robot: &RobotReport) -> (usize, usize) {
    robot.matching.as_ref().map_or((0, 0), |m| {
        let inter = m.scores.iter().filter(|s| s.inter_robot()).count();
        (m.scores.len() - inter, inter)
    })
}

/// `report.md` of `campaign`.
pub fn report_markdown(campaign: &Campaign, options: &CampaignOptions) -> String {
    let mut md = String::from("# Campaign: the named experiments in every variant\n\n");
    let names: Vec<&str> = options.experiments.iter().map(|e| e.name).collect();
    let variants: Vec<&str> = options.variants.iter().map(|v| v.name()).collect();
    let _ = writeln!(
        md,
        "`sil campaign --out {} --scenarios {} --variants {} --downscale {}{}`: {} runs in {:.0} s of wall time.\n",
        options.out.display(),
        names.join(","),
        variants.join(","),
        options.downscale,
        options.duration_s.map_or(String::new(), |d| format!(" --duration {d}")),
        campaign.runs.len(),
        campaign.wall_s
    );
    md.push_str("Variants:\n\n");
    for v in &options.variants {
        let _ = writeln!(md, "- `{}`: {}", v.name(), v.describe());
    }
    md.push_str(
        "\nErrors are of the online estimates (as each robot had them at the time), unaligned, in each \
         robot's start frame. Yaw error: mean absolute. The replayed variants feed the team run's graph \
         inputs (filter poses, frame switches, detections, matches, as the robot received them, in the \
         same update batches) into a fresh graph of each variant.\n",
    );
    for experiment in &options.experiments {
        let runs: Vec<&CampaignRun> = campaign.runs.iter().filter(|r| r.experiment.name == experiment.name).collect();
        if runs.is_empty() {
            continue;
        }
        let _ = writeln!(
            md,
            "\n## {} ({} site, seed {}, {:.0} s; after {})\n",
            experiment.name, experiment.site, experiment.seed, runs[0].report.duration_s, experiment.after
        );
        experiment_table(&mut md, &runs);
        let _ = writeln!(md, "\n![error over time]({}/error.svg)\n", experiment.name);
        for run in &runs {
            let _ =
                writeln!(md, "![{0} trajectories]({1}/{0}/trajectories.svg)\n", run.variant.name(), experiment.name);
        }
        if let Some(team) = runs.iter().find(|r| r.variant == Variant::Team) {
            replay_table(&mut md, team);
            runtime_table(&mut md, team);
            step_table(&mut md, team);
        }
    }
    summary(&mut md, campaign);
    md
}

fn experiment_table(md: &mut String, runs: &[&CampaignRun]) {
    let columns: Vec<(&CampaignRun, &RobotReport)> =
        runs.iter().flat_map(|run| run.report.robots.iter().map(move |robot| (*run, robot))).collect();
    md.push_str("| |");
    for (run, robot) in &columns {
        let _ = write!(md, " {} robot {} |", run.variant.name(), robot.robot);
    }
    md.push('\n');
    md.push_str("|---|");
    md.push_str(&"---:|".repeat(columns.len()));
    md.push('\n');
    let score = |robot: &RobotReport, f: &dyn Fn(&crate::mission::score::TrajectoryScore) -> String| {
        robot.score.as_ref().map_or_else(|| "–".to_owned(), f)
    };
    type Cell<'a> = Box<dyn Fn(&RobotReport) -> String + 'a>;
    let duration_s = runs.first().map_or(1.0, |r| r.report.duration_s.max(f64::MIN_POSITIVE));
    let matcher = |r: &RobotReport, f: &dyn Fn(&crate::mission::matching::MatchingReport) -> String| {
        r.matching.as_ref().map_or_else(|| "–".to_owned(), f)
    };
    let rows: Vec<(&str, Cell<'_>)> = vec![
        ("submaps", Box::new(|r: &RobotReport| r.submaps_finished.to_string())),
        ("map matches intra-robot", Box::new(|r: &RobotReport| matches(r).0.to_string())),
        ("map matches inter-robot", Box::new(|r: &RobotReport| matches(r).1.to_string())),
        ("robot detections made", Box::new(|r: &RobotReport| r.marker_detections.to_string())),
        ("graph nodes / factors", Box::new(|r: &RobotReport| format!("{} / {}", r.graph_nodes, r.graph_factors))),
        ("connected robots", Box::new(|r: &RobotReport| format!("{:?}", r.connected))),
        ("distance [m]", Box::new(move |r: &RobotReport| score(r, &|s| format!("{:.2}", s.distance_m)))),
        ("mean 3D error [m]", Box::new(move |r: &RobotReport| score(r, &|s| format!("{:.3}", s.mean_error_m)))),
        ("max 3D error [m]", Box::new(move |r: &RobotReport| score(r, &|s| format!("{:.3}", s.max_error_m)))),
        ("mean yaw error [°]", Box::new(move |r: &RobotReport| score(r, &|s| format!("{:.2}", s.mean_yaw_error_deg)))),
        (
            "mean error / distance [%]",
            Box::new(|r: &RobotReport| error_percent(r).map_or_else(|| "–".to_owned(), |p| format!("{p:.3}"))),
        ),
        (
            "sent, all links [KB/s]",
            Box::new(move |r: &RobotReport| {
                format!("{:.2}", r.bytes_sent_by_class.values().sum::<u64>() as f64 / duration_s / 1e3)
            }),
        ),
        (
            "of it submaps [KB/s]",
            Box::new(move |r: &RobotReport| {
                r.submap_traffic
                    .map_or_else(|| "–".to_owned(), |t| format!("{:.2}", t.wire_bytes_per_s(duration_s) / 1e3))
            }),
        ),
        (
            "matcher attempts / accepted",
            Box::new(move |r: &RobotReport| matcher(r, &|m| format!("{} / {}", m.attempts, m.accepted))),
        ),
        (
            "matcher time per attempt [s]",
            Box::new(move |r: &RobotReport| {
                matcher(r, &|m| if m.attempts > 0 { format!("{:.2}", m.mean_stage_s[4]) } else { "–".to_owned() })
            }),
        ),
    ];
    for (name, cell) in &rows {
        let _ = write!(md, "| {name} |");
        for (_, robot) in &columns {
            let _ = write!(md, " {} |", cell(robot));
        }
        md.push('\n');
    }
}

/// The team run's graph inputs replayed into the thesis's back-end variants.
fn replay_table(md: &mut String, team: &CampaignRun) {
    let robots = &team.report.robots;
    let Some(first) = robots.first() else { return };
    if first.replays.is_empty() {
        return;
    }
    md.push_str("\nThe team run's graph inputs replayed into the back-end variants (same front-end):\n\n| variant |");
    for r in robots {
        let _ =
            write!(md, " robot {0} mean / max [m] | robot {0} [% of distance] | robot {0} nodes / factors |", r.robot);
    }
    md.push_str("\n|---|");
    md.push_str(&"---:|---:|---:|".repeat(robots.len()));
    md.push('\n');
    for (k, replay) in first.replays.iter().enumerate() {
        let _ = write!(md, "| {} |", replay.variant);
        for r in robots {
            match r.replays.get(k) {
                Some(ReplayScore { score: Some(s), nodes, factors, .. }) => {
                    let percent = s.mean_error_percent().unwrap_or(f64::NAN);
                    let _ = write!(
                        md,
                        " {:.3} / {:.3} | {percent:.3} | {nodes} / {factors} |",
                        s.mean_error_m, s.max_error_m
                    );
                }
                Some(ReplayScore { error, .. }) => {
                    let _ = write!(md, " {} | – | – |", error.as_deref().unwrap_or("–"));
                }
                None => md.push_str(" – | – | – |"),
            }
        }
        md.push('\n');
    }
}

/// Per robot and process of the team run: time in the node's handlers per second of sensor time
/// (lockstep: wall time of the handlers, so contention from other jobs inflates it).
fn runtime_table(md: &mut String, team: &CampaignRun) {
    let report = &team.report;
    let mut names: Vec<&str> = Vec::new();
    for p in &report.processes {
        if !names.contains(&p.process.as_str()) {
            names.push(&p.process);
        }
    }
    if names.is_empty() {
        return;
    }
    md.push_str("\nTeam run, time in each process's handlers per second of sensor time:\n\n| robot |");
    for name in &names {
        let _ = write!(md, " {name} |");
    }
    md.push_str(" total |\n|---|");
    md.push_str(&"---:|".repeat(names.len() + 1));
    md.push('\n');
    let duration_s = report.duration_s.max(f64::MIN_POSITIVE);
    for robot in &report.robots {
        let _ = write!(md, "| {} |", robot.robot);
        let mut total = 0.0;
        for name in &names {
            let cpu_s: f64 =
                report.processes.iter().filter(|p| p.robot == robot.robot && p.process == *name).map(|p| p.cpu_s).sum();
            total += cpu_s;
            let _ = write!(md, " {:.3} |", cpu_s / duration_s);
        }
        let _ = writeln!(md, " {:.3} |", total / duration_s);
    }
}

/// The team run's per-step wall times in the layout of the thesis's runtime table (§8.4, LRU2 in
/// experiment #2 on a 4-core Xeon E5-1620; here one core per robot at most).
fn step_table(md: &mut String, team: &CampaignRun) {
    let robots: Vec<&RobotReport> = team.report.robots.iter().filter(|r| r.step_times.is_some()).collect();
    if robots.is_empty() {
        return;
    }
    md.push_str("\nTeam run, wall time per step, mean / max [ms] (thesis §8.4 beside):\n\n| step | thesis |");
    for r in &robots {
        let _ = write!(md, " robot {} |", r.robot);
    }
    md.push_str("\n|---|---:|");
    md.push_str(&"---:|".repeat(robots.len()));
    md.push('\n');
    type Step = fn(&onboard::nodes::mapper::MapperStepTimes) -> onboard::nodes::mapper::StepTime;
    let steps: [(&str, &str, Step); 4] = [
        ("graph update (iSAM2)", "1.7 / 162", |t| t.graph_update),
        ("submap integration of one depth image", "10 / 40", |t| t.integration),
        ("matcher on the mapper thread (prepare, rank with marginals, take in)", "106 / 341 (marginals)", |t| {
            t.matcher_poll
        }),
        ("global map composition", "260 / 3270", |t| t.composition),
    ];
    for (name, thesis, step) in steps {
        let _ = write!(md, "| {name} | {thesis} |");
        for r in &robots {
            match r.step_times.as_ref().map(step).filter(|s| s.count > 0) {
                Some(s) => {
                    let _ =
                        write!(md, " {:.2} / {:.2} ({}×) |", s.mean_s().unwrap_or(0.0) * 1e3, s.max_s * 1e3, s.count);
                }
                None => md.push_str(" – |"),
            }
        }
        md.push('\n');
    }
    let stages = [
        ("matcher: keypoints and descriptors, per attempt", "390 / 670 (per map)"),
        ("matcher: descriptor correspondences", "3070 / 8710"),
        ("matcher: Hough voting and RANSAC", "20 / 50"),
        ("matcher: ICP", "2380 / 4810"),
        ("matcher: whole attempt", "–"),
    ];
    for (k, (name, thesis)) in stages.iter().enumerate() {
        let _ = write!(md, "| {name} (mean over attempts) | {thesis} |");
        for r in &robots {
            match r.matching.as_ref().filter(|m| m.attempts > 0) {
                Some(m) => {
                    let _ = write!(md, " {:.1} ({}×) |", m.mean_stage_s[k] * 1e3, m.attempts);
                }
                None => md.push_str(" – |"),
            }
        }
        md.push('\n');
    }
}

fn summary(md: &mut String, campaign: &Campaign) {
    md.push_str("\n## Summary: mean error as % of distance, over all experiments and robots\n\n");
    md.push_str("| variant | robots scored | mean error / distance [%] | worst robot [%] |\n|---|---:|---:|---:|\n");
    for variant in Variant::ALL {
        let percents: Vec<f64> = campaign
            .runs
            .iter()
            .filter(|r| r.variant == variant)
            .flat_map(|r| r.report.robots.iter().filter_map(error_percent))
            .collect();
        if percents.is_empty() {
            continue;
        }
        let mean = percents.iter().sum::<f64>() / percents.len() as f64;
        let worst = percents.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let _ = writeln!(md, "| {} | {} | {mean:.3} | {worst:.3} |", variant.name(), percents.len());
    }
    for variant in crate::mission::replay::VARIANTS {
        let percents: Vec<f64> = campaign
            .runs
            .iter()
            .filter(|r| r.variant == Variant::Team)
            .flat_map(|r| r.report.robots.iter())
            .filter_map(|robot| robot.replays.iter().find(|v| v.variant == variant.name()))
            .filter_map(|v| v.score.as_ref()?.mean_error_percent())
            .collect();
        if percents.is_empty() {
            continue;
        }
        let mean = percents.iter().sum::<f64>() / percents.len() as f64;
        let worst = percents.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        let _ = writeln!(md, "| replayed: {} | {} | {mean:.3} | {worst:.3} |", variant.name(), percents.len());
    }
    md.push_str("\nThe thesis: < 0.5 % of each robot's distance over its real multi-robot experiments (§8.5); our goal < 0.3 %.\n");
}
