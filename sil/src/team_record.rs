//! A simulated rover team's filter output, recorded once per seed for the multi-robot SLAM
//! evaluation: per robot the filter's pose in its current local frame with covariance at every
//! camera capture (the graph's odometry/detection anchors and the online trajectory), the frame
//! switches its mapper requested (the graph's submap factors), and the ground truth at the same
//! stamps.
//!
//! Each robot runs the firmware's own nodes on the lockstep runner ([`RobotStack`]: driver on the
//! simulator, vision, filter and mapper, built from the robot's configuration exactly as in a
//! mission), and the record is what the mapper received: the filter states at the capture stamps
//! and the frame switches, tapped from the robot's bus.
//!
//! Rendering, SGM and stereo odometry dominate the cost, so a record is cached on disk
//! ([`RobotRecord::write`], [`RobotRecord::read`]) as plain text, one line per sample; floats are
//! written in Rust's shortest round-trip form, so reading gives back bit-identical values.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;

use filter::FrameSwitch;
use mapper::submap::SubmapPolicy;
use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector3};
use onboard::config::RoverConfig;
use onboard::lockstep::{OwnedMessage, RobotStack, STEP_NS};
use onboard::nodes::Topic;
use onboard::sensors::sensor_setup;
use sim::driver::SimSensorSource;
use sim::world::World;

use crate::sim_source::{SimDriverConfig, configure_sim_robot};

/// The filter's pose in its current local frame at one camera capture.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalPoseSample {
    pub stamp_ns: u64,
    /// The local frame `t_local_body` is in (the filter's frame id: 0, then +1 per switch).
    pub frame_id: u32,
    pub t_local_body: Isometry3<f64>,
    /// The filter's convention: `[δt (local frame); δθ (body, right-multiplied)]`.
    pub covariance: Matrix6<f64>,
}

/// What the robot's nodes counted.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RecordSummary {
    /// Pairs vision received, and those given to the odometry (after the filter started).
    pub frames: u64,
    pub vo_frames: u64,
    pub keyframes: u64,
    pub vo_resets: u64,
    pub vo_deltas: u64,
    pub vo_updates_applied: u64,
    pub vo_updates_rejected: u64,
    pub wheel_updates_applied: u64,
    pub zupt_updates_applied: u64,
    pub frame_switches: u64,
    pub imu_received: u64,
    /// Images the mapper integrated into its submaps.
    pub images_integrated: u64,
}

/// One robot's recorded run.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotRecord {
    pub robot: usize,
    /// Filter start = start of submap 0 (frame 0).
    pub initialized_ns: u64,
    /// At every camera capture from the filter start on.
    pub poses: Vec<LocalPoseSample>,
    pub switches: Vec<FrameSwitch>,
    /// `t_world_body` at every pose stamp.
    pub truth: Vec<(u64, Isometry3<f64>)>,
    pub summary: RecordSummary,
    /// True path length over the pose stamps (m).
    pub distance_m: f64,
}

/// What to simulate and how the robots' mappers cut submaps.
#[derive(Debug, Clone, PartialEq)]
pub struct TeamRecordOptions {
    pub robots: usize,
    pub duration_s: f64,
    pub seed: u64,
    /// Render at `1 / downscale` of the full camera resolution.
    pub downscale: u32,
    /// The mapper's submap rule (its frame-switch requests).
    pub policy: SubmapPolicy,
    pub use_wheel: bool,
    /// Shorter stands at the waypoints than the preset's 6 s (at least the filter's 0.5 s
    /// at-rest initialization window: the first stand initializes it); the route is then planned
    /// over 4 × `duration_s` and cut, so a short run drives most of its time.
    pub pause_s: Option<f64>,
}

impl Default for TeamRecordOptions {
    /// Two robots, 300 s, seed 1, half resolution, the LRU experiments' 0.2 m / 7 m policy.
    fn default() -> Self {
        TeamRecordOptions {
            robots: 2,
            duration_s: 300.0,
            seed: 1,
            downscale: 2,
            policy: SubmapPolicy::default(),
            use_wheel: true,
            pause_s: None,
        }
    }
}

/// Why a recording (or reading one back) failed.
#[derive(Debug, thiserror::Error)]
pub enum TeamRecordError {
    #[error("invalid options: {0}")]
    Options(String),
    #[error("robot {robot}: {reason}")]
    Robot { robot: usize, reason: String },
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}:{line}: {reason}", path.display())]
    Parse { path: PathBuf, line: usize, reason: String },
}

impl TeamRecordOptions {
    /// The `[driver.sim]` world of these options (the Moon preset).
    pub fn sim_driver(&self) -> SimDriverConfig {
        SimDriverConfig {
            scenario: "moon".into(),
            seed: self.seed,
            robots: self.robots as u16,
            downscale: self.downscale,
            pause_s: self.pause_s,
            rocks_per_100m2: None,
            rocks_in_hub: false,
        }
    }

    /// Robot `robot`'s firmware configuration in the world of these options.
    pub fn robot_config(&self, world: &World, robot: usize) -> Result<RoverConfig, TeamRecordError> {
        let mut config = RoverConfig::default();
        config.robot.id = robot as u16;
        configure_sim_robot(&mut config, &self.sim_driver(), &world.scenario, self.duration_s)
            .map_err(|reason| TeamRecordError::Robot { robot, reason })?;
        config.mapper.submap_max_distance_m = self.policy.max_distance_m;
        config.mapper.max_position_sigma_m = self.policy.max_position_sigma_m;
        config.filter.use_wheel = self.use_wheel;
        Ok(config)
    }
}

/// The Moon preset with `options.robots` rovers on the start ring.
pub fn moon_team_world(options: &TeamRecordOptions) -> Result<Arc<World>, TeamRecordError> {
    if let Some(pause_s) = options.pause_s
        && !(pause_s.is_finite() && pause_s >= 0.5)
    {
        return Err(TeamRecordError::Options(format!("pause must be at least 0.5 s, got {pause_s}")));
    }
    options.sim_driver().world(options.duration_s).map_err(TeamRecordError::Options)
}

/// Records robots `0..options.robots` of `world`, one thread each. Deterministic: every robot's
/// nodes are single-threaded and see only its own sensors.
pub fn record_team(world: &Arc<World>, options: &TeamRecordOptions) -> Result<Vec<RobotRecord>, TeamRecordError> {
    if options.robots == 0 || options.robots > world.robots.len() {
        return Err(TeamRecordError::Options(format!(
            "{} robots asked, the world has {}",
            options.robots,
            world.robots.len()
        )));
    }
    std::thread::scope(|scope| {
        let handles: Vec<_> =
            (0..options.robots).map(|robot| scope.spawn(move || record_robot(world, robot, options))).collect();
        handles
            .into_iter()
            .enumerate()
            .map(|(robot, handle)| {
                handle.join().unwrap_or_else(|_| {
                    Err(TeamRecordError::Robot { robot, reason: "recording thread panicked".to_owned() })
                })
            })
            .collect()
    })
}

/// One robot: its nodes on the lockstep runner, the filter states of the capture stamps and the
/// frame switches taken from its bus.
pub fn record_robot(
    world: &Arc<World>,
    robot: usize,
    options: &TeamRecordOptions,
) -> Result<RobotRecord, TeamRecordError> {
    let fail = |reason: String| TeamRecordError::Robot { robot, reason };
    let config = options.robot_config(world, robot)?;
    let setup = sensor_setup(&config).map_err(|e| fail(e.to_string()))?;
    let source = SimSensorSource::new(Arc::clone(world), robot).map_err(|e| fail(e.to_string()))?;
    let mut stack = RobotStack::new(&config, &setup, Box::new(source), None, None).map_err(|e| fail(e.to_string()))?;
    stack.bus.tap(&[Topic::Stereo, Topic::FilterState, Topic::FrameSwitch]);
    let mut captures = std::collections::BTreeSet::new();
    let mut states: BTreeMap<u64, LocalPoseSample> = BTreeMap::new();
    let mut switches = Vec::new();
    let mut now_ns = 0;
    let mut take = |stack: &mut RobotStack| -> Result<(), TeamRecordError> {
        for message in stack.bus.take_tapped() {
            match message {
                OwnedMessage::Stereo(header, _) => {
                    captures.insert(header.stamp_ns);
                }
                OwnedMessage::FilterState(state) if state.status == msgs::FilterStateMsg::RUNNING => {
                    let (Some(t_local_body), Some(covariance)) =
                        (state.t_local_body.to_isometry(), msgs::covariance_from_array(&state.pose_covariance))
                    else {
                        return Err(fail(format!("a non-finite filter state at {} ns", state.stamp_ns)));
                    };
                    // The newest state of a stamp counts, as the mapper keeps it.
                    states.insert(
                        state.stamp_ns,
                        LocalPoseSample {
                            stamp_ns: state.stamp_ns,
                            frame_id: state.frame_id,
                            t_local_body,
                            covariance,
                        },
                    );
                }
                OwnedMessage::FrameSwitch(s) => {
                    let (Some(t_old_new), Some(covariance)) =
                        (s.t_old_new.to_isometry(), msgs::covariance_from_array(&s.covariance))
                    else {
                        return Err(fail(format!("a non-finite frame switch at {} ns", s.stamp_ns)));
                    };
                    switches.push(FrameSwitch {
                        stamp_ns: s.stamp_ns,
                        old_frame_id: s.old_frame_id,
                        new_frame_id: s.new_frame_id,
                        t_old_new,
                        covariance,
                    });
                }
                _ => {}
            }
        }
        Ok(())
    };
    while !stack.driver.finished() {
        stack.step(now_ns).map_err(|e| fail(e.to_string()))?;
        take(&mut stack)?;
        now_ns += STEP_NS;
    }
    stack.finish(now_ns).map_err(|e| fail(e.to_string()))?;
    take(&mut stack)?;

    let filter = stack.filter.summary();
    let initialized_ns = filter.initialized_ns.ok_or_else(|| fail("the filter never initialized".to_owned()))?;
    let poses: Vec<LocalPoseSample> =
        captures.iter().filter(|&&c| c >= initialized_ns).filter_map(|c| states.get(c).copied()).collect();
    let mut truth = Vec::with_capacity(poses.len());
    for pose in &poses {
        let state = world
            .robot_state(robot, pose.stamp_ns)
            .ok_or_else(|| fail(format!("no ground truth at {} ns", pose.stamp_ns)))?;
        truth.push((pose.stamp_ns, state.t_world_body));
    }
    let distance_m = truth.windows(2).map(|w| (w[1].1.translation.vector - w[0].1.translation.vector).norm()).sum();
    let vision = stack.vision.summary();
    let summary = RecordSummary {
        frames: vision.frames,
        vo_frames: vision.vo_frames,
        keyframes: vision.keyframes,
        vo_resets: vision.vo_resets,
        vo_deltas: vision.vo_deltas,
        vo_updates_applied: filter.vo_updates_applied,
        vo_updates_rejected: filter.vo_updates_rejected,
        wheel_updates_applied: filter.wheel_updates_applied,
        zupt_updates_applied: filter.zupt_updates_applied,
        frame_switches: filter.frame_switches,
        imu_received: filter.imu_received,
        images_integrated: stack.mapper.counters().images_integrated,
    };
    Ok(RobotRecord { robot, initialized_ns, poses, switches, truth, summary, distance_m })
}

const META_FILE: &str = "meta.txt";
const POSES_FILE: &str = "poses.txt";
const SWITCHES_FILE: &str = "switches.txt";
const TRUTH_FILE: &str = "truth.txt";

impl RobotRecord {
    /// Writes the record into `dir` (created if missing): `meta.txt` (robot, start, distance,
    /// summary as `key value` lines), `poses.txt` (`stamp_ns frame_id tx ty tz qx qy qz qw` and
    /// the 36 covariance values row by row), `switches.txt` (`stamp_ns old_id new_id`, pose,
    /// covariance) and `truth.txt` (`stamp_ns`, pose). Lines starting with `#` are comments.
    pub fn write(&self, dir: &Path) -> Result<(), TeamRecordError> {
        std::fs::create_dir_all(dir).map_err(|source| TeamRecordError::Io { path: dir.to_owned(), source })?;
        let mut poses = String::from("# stamp_ns frame_id tx ty tz qx qy qz qw cov[36] (row-major, [dt; dtheta])\n");
        for p in &self.poses {
            poses.push_str(&format!("{} {}", p.stamp_ns, p.frame_id));
            push_pose(&mut poses, &p.t_local_body);
            push_floats(&mut poses, p.covariance.transpose().iter());
            poses.push('\n');
        }
        let mut switches = String::from("# stamp_ns old_frame_id new_frame_id tx ty tz qx qy qz qw cov[36]\n");
        for s in &self.switches {
            switches.push_str(&format!("{} {} {}", s.stamp_ns, s.old_frame_id, s.new_frame_id));
            push_pose(&mut switches, &s.t_old_new);
            push_floats(&mut switches, s.covariance.transpose().iter());
            switches.push('\n');
        }
        let mut truth = String::from("# stamp_ns tx ty tz qx qy qz qw (t_world_body)\n");
        for (stamp_ns, t_world_body) in &self.truth {
            truth.push_str(&stamp_ns.to_string());
            push_pose(&mut truth, t_world_body);
            truth.push('\n');
        }
        for (name, text) in
            [(META_FILE, self.meta_text()), (POSES_FILE, poses), (SWITCHES_FILE, switches), (TRUTH_FILE, truth)]
        {
            let path = dir.join(name);
            std::fs::write(&path, text).map_err(|source| TeamRecordError::Io { path, source })?;
        }
        Ok(())
    }

    /// Reads a record written by [`RobotRecord::write`]; malformed input is an error.
    pub fn read(dir: &Path) -> Result<RobotRecord, TeamRecordError> {
        let meta_path = dir.join(META_FILE);
        let meta = Meta::parse(&meta_path, &read_text(&meta_path)?)?;
        let poses_path = dir.join(POSES_FILE);
        let poses = parse_lines(&poses_path, &read_text(&poses_path)?, |fields| {
            let mut f = Fields::new(fields, 2 + 7 + 36)?;
            Ok(LocalPoseSample {
                stamp_ns: f.next()?,
                frame_id: f.next()?,
                t_local_body: f.pose()?,
                covariance: f.matrix6()?,
            })
        })?;
        let switches_path = dir.join(SWITCHES_FILE);
        let switches = parse_lines(&switches_path, &read_text(&switches_path)?, |fields| {
            let mut f = Fields::new(fields, 3 + 7 + 36)?;
            Ok(FrameSwitch {
                stamp_ns: f.next()?,
                old_frame_id: f.next()?,
                new_frame_id: f.next()?,
                t_old_new: f.pose()?,
                covariance: f.matrix6()?,
            })
        })?;
        let truth_path = dir.join(TRUTH_FILE);
        let truth = parse_lines(&truth_path, &read_text(&truth_path)?, |fields| {
            let mut f = Fields::new(fields, 1 + 7)?;
            Ok((f.next()?, f.pose()?))
        })?;
        // Meta errors name the key; the line is not tracked (0).
        let parse_error = |reason: String| TeamRecordError::Parse { path: meta_path.clone(), line: 0, reason };
        let summary = meta.summary().map_err(parse_error)?;
        Ok(RobotRecord {
            robot: meta.get("robot").map_err(parse_error)?,
            initialized_ns: meta.get("initialized_ns").map_err(parse_error)?,
            poses,
            switches,
            truth,
            summary,
            distance_m: meta.get("distance_m").map_err(parse_error)?,
        })
    }

    fn meta_text(&self) -> String {
        let s = &self.summary;
        let mut out = String::from("# key value\n");
        let mut put = |key: &str, value: String| out.push_str(&format!("{key} {value}\n"));
        put("robot", self.robot.to_string());
        put("initialized_ns", self.initialized_ns.to_string());
        put("distance_m", self.distance_m.to_string());
        for (key, value) in summary_fields(s) {
            put(key, value.to_string());
        }
        out
    }
}

/// The summary's counters with their keys in `meta.txt`.
fn summary_fields(s: &RecordSummary) -> [(&'static str, u64); 12] {
    [
        ("frames", s.frames),
        ("vo_frames", s.vo_frames),
        ("keyframes", s.keyframes),
        ("vo_resets", s.vo_resets),
        ("vo_deltas", s.vo_deltas),
        ("vo_updates_applied", s.vo_updates_applied),
        ("vo_updates_rejected", s.vo_updates_rejected),
        ("wheel_updates_applied", s.wheel_updates_applied),
        ("zupt_updates_applied", s.zupt_updates_applied),
        ("frame_switches", s.frame_switches),
        ("imu_received", s.imu_received),
        ("images_integrated", s.images_integrated),
    ]
}

/// Writes every robot's record into `dir/robot<i>`.
pub fn write_team(dir: &Path, records: &[RobotRecord]) -> Result<(), TeamRecordError> {
    records.iter().try_for_each(|r| r.write(&dir.join(format!("robot{}", r.robot))))
}

/// Reads `dir/robot0`, `dir/robot1`, … until the first missing one.
pub fn read_team(dir: &Path) -> Result<Vec<RobotRecord>, TeamRecordError> {
    let mut records = Vec::new();
    while dir.join(format!("robot{}", records.len())).is_dir() {
        records.push(RobotRecord::read(&dir.join(format!("robot{}", records.len())))?);
    }
    Ok(records)
}

fn push_floats<'a>(out: &mut String, values: impl Iterator<Item = &'a f64>) {
    for v in values {
        out.push(' ');
        out.push_str(&v.to_string());
    }
}

fn push_pose(out: &mut String, pose: &Isometry3<f64>) {
    let q = pose.rotation.quaternion();
    push_floats(out, pose.translation.vector.iter().chain([q.i, q.j, q.k, q.w].iter()));
}

fn read_text(path: &Path) -> Result<String, TeamRecordError> {
    std::fs::read_to_string(path).map_err(|source| TeamRecordError::Io { path: path.to_owned(), source })
}

/// Parses every non-comment, non-empty line of `text` with `parse` (its whitespace-separated
/// fields); errors carry the file and 1-based line.
fn parse_lines<T>(
    path: &Path,
    text: &str,
    parse: impl Fn(&[&str]) -> Result<T, String>,
) -> Result<Vec<T>, TeamRecordError> {
    let mut out = Vec::new();
    for (index, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split_whitespace().collect();
        let item = parse(&fields).map_err(|reason| TeamRecordError::Parse {
            path: path.to_owned(),
            line: index + 1,
            reason,
        })?;
        out.push(item);
    }
    Ok(out)
}

/// A line's fields, consumed in order.
struct Fields<'a> {
    fields: &'a [&'a str],
    at: usize,
}

impl<'a> Fields<'a> {
    fn new(fields: &'a [&'a str], expected: usize) -> Result<Self, String> {
        if fields.len() != expected {
            return Err(format!("{} fields, expected {expected}", fields.len()));
        }
        Ok(Fields { fields, at: 0 })
    }

    fn next<T: FromStr>(&mut self) -> Result<T, String> {
        let text = self.fields.get(self.at).ok_or_else(|| "missing field".to_owned())?;
        self.at += 1;
        text.parse().map_err(|_| format!("field {}: cannot parse `{text}`", self.at))
    }

    fn finite(&mut self) -> Result<f64, String> {
        let v: f64 = self.next()?;
        if v.is_finite() { Ok(v) } else { Err(format!("field {}: not finite", self.at)) }
    }

    /// `tx ty tz qx qy qz qw`; the quaternion is kept as written (bit-exact round trip) after
    /// checking it is a unit quaternion.
    fn pose(&mut self) -> Result<Isometry3<f64>, String> {
        let t = Vector3::new(self.finite()?, self.finite()?, self.finite()?);
        let (i, j, k, w) = (self.finite()?, self.finite()?, self.finite()?, self.finite()?);
        let q = Quaternion::new(w, i, j, k);
        if (q.norm() - 1.0).abs() > 1e-9 {
            return Err(format!("quaternion norm {} is not 1", q.norm()));
        }
        Ok(Isometry3::from_parts(Translation3::from(t), UnitQuaternion::new_unchecked(q)))
    }

    /// 36 values, row by row.
    fn matrix6(&mut self) -> Result<Matrix6<f64>, String> {
        let mut values = [0.0; 36];
        for v in &mut values {
            *v = self.next()?;
        }
        Ok(Matrix6::from_row_slice(&values))
    }
}

/// `key value…` lines of `meta.txt`.
struct Meta {
    values: BTreeMap<String, String>,
}

impl Meta {
    fn parse(path: &Path, text: &str) -> Result<Meta, TeamRecordError> {
        let mut values = BTreeMap::new();
        for (index, line) in text.lines().enumerate() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let (key, value) = line.split_once(' ').unwrap_or((line, ""));
            if values.insert(key.to_owned(), value.trim().to_owned()).is_some() {
                return Err(TeamRecordError::Parse {
                    path: path.to_owned(),
                    line: index + 1,
                    reason: format!("duplicate key `{key}`"),
                });
            }
        }
        Ok(Meta { values })
    }

    fn text(&self, key: &str) -> Result<&str, String> {
        self.values.get(key).map(String::as_str).ok_or_else(|| format!("missing `{key}`"))
    }

    fn get<T: FromStr>(&self, key: &str) -> Result<T, String> {
        let text = self.text(key)?;
        text.parse().map_err(|_| format!("`{key}`: cannot parse `{text}`"))
    }

    fn summary(&self) -> Result<RecordSummary, String> {
        let mut s = RecordSummary::default();
        let keys = summary_fields(&s).map(|(key, _)| key);
        let slots: [&mut u64; 12] = [
            &mut s.frames,
            &mut s.vo_frames,
            &mut s.keyframes,
            &mut s.vo_resets,
            &mut s.vo_deltas,
            &mut s.vo_updates_applied,
            &mut s.vo_updates_rejected,
            &mut s.wheel_updates_applied,
            &mut s.zupt_updates_applied,
            &mut s.frame_switches,
            &mut s.imu_received,
            &mut s.images_integrated,
        ];
        for (key, slot) in keys.iter().zip(slots) {
            *slot = self.get(key)?;
        }
        Ok(s)
    }
}
