//! A simulated rover team's filter output, recorded once per seed for the multi-robot SLAM
//! evaluation: per robot the filter's pose in its current local frame with covariance at every
//! camera capture (the graph's odometry/detection anchors and the online trajectory), the frame
//! switches the mapper's [`SubmapPolicy`] requests (the graph's submap factors), and the ground
//! truth at the same stamps.
//!
//! Rendering and stereo odometry dominate the cost, so a record is cached on disk
//! ([`RobotRecord::write`], [`RobotRecord::read`]) as plain text, one line per sample; floats are
//! written in Rust's shortest round-trip form, so reading gives back bit-identical values.
//!
//! Pose stamps: the simulator's IMU (200 Hz) and camera (10 Hz) run on one grid from stamp 0,
//! so logging the filter state every camera period lands exactly on the capture stamps;
//! [`record_team`] checks that and fails otherwise.

use std::collections::BTreeMap;
use std::fmt::Display;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::sync::Arc;

use filter::config::ImuNoise;
use filter::health::GateCounters;
use filter::{FilterConfig, FilterHealth, FrameSwitch};
use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
use mapper::submap::SubmapPolicy;
use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector3};
use sim::driver::SimSensorSource;
use sim::scenario::{self, ScenarioError, ScenarioOptions};
use sim::world::{World, WorldError};

use crate::vio::{LocalPoseSample, SwitchPolicy, VioError, VioOptions, VioPipeline, VioSummary};

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
    pub summary: VioSummary,
    /// True path length over the pose stamps (m).
    pub distance_m: f64,
}

/// What to simulate and how the filter switches frames.
#[derive(Debug, Clone, PartialEq)]
pub struct TeamRecordOptions {
    pub robots: usize,
    pub duration_s: f64,
    pub seed: u64,
    /// Render at `1 / downscale` of the full camera resolution.
    pub downscale: u32,
    /// The mapper's submap rule the filter's frame switches follow.
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
    #[error("scenario: {0}")]
    Scenario(#[from] ScenarioError),
    #[error("world: {0}")]
    World(#[from] WorldError),
    #[error("invalid options: {0}")]
    Options(String),
    #[error("robot {robot}: {source}")]
    Vio { robot: usize, source: VioError },
    #[error("robot {robot}: {reason}")]
    Robot { robot: usize, reason: String },
    #[error("{}: {source}", path.display())]
    Io { path: PathBuf, source: std::io::Error },
    #[error("{}:{line}: {reason}", path.display())]
    Parse { path: PathBuf, line: usize, reason: String },
}

/// Filter tuning for the simulated IMU (its own noise model) and the site's gravity.
pub fn sim_vio_options(world: &World, use_wheel: bool) -> VioOptions {
    scenario_vio_options(&world.scenario, use_wheel)
}

/// [`sim_vio_options`] from the scenario alone (a filter process needs no world built).
pub fn scenario_vio_options(scenario: &scenario::Scenario, use_wheel: bool) -> VioOptions {
    let noise = scenario.imu_noise;
    let imu = ImuNoise::from(noise.densities(scenario.imu_rate_hz));
    let mut filter = FilterConfig::from_imu_noise(imu, scenario.body.gravity_mps2());
    filter.imu_rate_hz = scenario.imu_rate_hz;
    // The simulator's turn-on biases, as the datasheet would state them.
    filter.initial.gyro_bias_radps = noise.gyro_bias_init_radps.max(1e-6);
    filter.initial.accel_bias_mps2 = noise.accel_bias_init_mps2.max(1e-6);
    VioOptions { use_wheel, filter, ..VioOptions::default() }
}

/// The Moon preset with `options.robots` rovers on the start ring.
pub fn moon_team_world(options: &TeamRecordOptions) -> Result<Arc<World>, TeamRecordError> {
    if let Some(pause_s) = options.pause_s
        && !(pause_s.is_finite() && pause_s >= 0.5)
    {
        return Err(TeamRecordError::Options(format!("pause must be at least 0.5 s, got {pause_s}")));
    }
    let plan_s = if options.pause_s.is_some() { 4.0 * options.duration_s } else { options.duration_s };
    let scenario_options = ScenarioOptions {
        robots: options.robots,
        duration_s: plan_s,
        seed: options.seed,
        downscale: options.downscale,
        world_size_m: None,
        flyer: false,
    };
    let mut scenario = scenario::preset("moon", &scenario_options)?;
    scenario.duration_s = options.duration_s;
    if let Some(pause_s) = options.pause_s {
        for robot in &mut scenario.robots {
            robot.drive.pause_s = pause_s;
        }
    }
    Ok(World::build(&scenario)?)
}

/// Runs robots `0..options.robots` of `world` through the VIO pipeline, one thread each.
/// Deterministic: every robot's filter is single-threaded and sees only its own sensors.
pub fn record_team(world: &Arc<World>, options: &TeamRecordOptions) -> Result<Vec<RobotRecord>, TeamRecordError> {
    Ok(record_team_with_pipelines(world, options)?.into_iter().map(|(record, _)| record).collect())
}

/// [`record_team`], also returning each robot's finished pipeline.
pub fn record_team_with_pipelines(
    world: &Arc<World>,
    options: &TeamRecordOptions,
) -> Result<Vec<(RobotRecord, VioPipeline)>, TeamRecordError> {
    if options.robots == 0 || options.robots > world.robots.len() {
        return Err(TeamRecordError::Options(format!(
            "{} robots asked, the world has {}",
            options.robots,
            world.robots.len()
        )));
    }
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..options.robots)
            .map(|robot| scope.spawn(move || record_robot_with_pipeline(world, robot, options)))
            .collect();
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

/// One robot: the pipeline with the mapper's switch rule evaluated and the pose logged at every
/// camera capture (the mapper sees the filter pose with each image).
pub fn record_robot(
    world: &Arc<World>,
    robot: usize,
    options: &TeamRecordOptions,
) -> Result<RobotRecord, TeamRecordError> {
    record_robot_with_pipeline(world, robot, options).map(|(record, _)| record)
}

/// [`record_robot`], also returning the finished pipeline (its full-rate trajectory in the first
/// frame, its filter).
pub fn record_robot_with_pipeline(
    world: &Arc<World>,
    robot: usize,
    options: &TeamRecordOptions,
) -> Result<(RobotRecord, VioPipeline), TeamRecordError> {
    let vio = |source: VioError| TeamRecordError::Vio { robot, source };
    let fail = |reason: String| TeamRecordError::Robot { robot, reason };
    let camera_rate_hz = world.scenario.camera_rate_hz;
    if !(camera_rate_hz.is_finite() && camera_rate_hz > 0.0) {
        return Err(fail(format!("camera rate {camera_rate_hz} Hz")));
    }
    let camera_period_ns = (1e9 / camera_rate_hz).round() as u64;
    let mut source = SimSensorSource::new(Arc::clone(world), robot).map_err(|e| vio(e.into()))?;
    let calibration = source.stereo_calibration().ok_or_else(|| fail("no stereo camera".to_owned()))?;
    let vio_options = VioOptions {
        pose_log_period_ns: Some(camera_period_ns),
        switch: SwitchPolicy {
            submap: Some(options.policy),
            period_ns: Some(camera_period_ns),
            ..SwitchPolicy::default()
        },
        ..sim_vio_options(world, options.use_wheel)
    };
    let mut pipeline = VioPipeline::new(&calibration, vio_options).map_err(vio)?;
    let mut frame = StereoFrame::default();
    let mut capture_stamps_ns = Vec::new();
    while let Some(event) = source.next_event(&mut frame).map_err(|e| vio(e.into()))? {
        if matches!(event, SensorEvent::Stereo) {
            capture_stamps_ns.push(frame.stamp_ns);
        }
        pipeline.process_event(&event, &frame).map_err(vio)?;
    }
    let summary = pipeline.finish();
    let initialized_ns = summary.initialized_ns.ok_or_else(|| fail("the filter never initialized".to_owned()))?;
    let poses = pipeline.pose_log().to_vec();
    if let Some(off) = poses.iter().find(|p| capture_stamps_ns.binary_search(&p.stamp_ns).is_err()) {
        return Err(fail(format!("pose stamp {} ns is not a camera capture stamp", off.stamp_ns)));
    }
    let mut truth = Vec::with_capacity(poses.len());
    for pose in &poses {
        let sample = source
            .ground_truth(pose.stamp_ns)
            .ok_or_else(|| fail(format!("no ground truth at {} ns", pose.stamp_ns)))?;
        truth.push((pose.stamp_ns, sample.state.t_world_body));
    }
    let distance_m = truth.windows(2).map(|w| (w[1].1.translation.vector - w[0].1.translation.vector).norm()).sum();
    let record = RobotRecord {
        robot,
        initialized_ns,
        poses,
        switches: pipeline.frame_switches().to_vec(),
        truth,
        summary,
        distance_m,
    };
    Ok((record, pipeline))
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
        for (key, value) in [
            ("frames", s.frames),
            ("frames_before_init", s.frames_before_init),
            ("keyframes", s.keyframes),
            ("vo_resets", s.vo_resets),
            ("vo_deltas", s.vo_deltas),
            ("min_inliers", u64::from(s.min_inliers)),
            ("vo_updates_applied", s.vo_updates_applied),
            ("vo_updates_rejected", s.vo_updates_rejected),
            ("vo_updates_missing_clone", s.vo_updates_missing_clone),
            ("vo_updates_skipped", s.vo_updates_skipped),
            ("wheel_updates_applied", s.wheel_updates_applied),
            ("wheel_updates_rejected", s.wheel_updates_rejected),
            ("zupt_updates_applied", s.zupt_updates_applied),
            ("zupt_updates_rejected", s.zupt_updates_rejected),
            ("frame_switches", s.frame_switches),
            ("imu_samples", s.imu_samples),
        ] {
            put(key, value.to_string());
        }
        for (key, value) in [
            ("mean_inliers", s.mean_inliers),
            ("data_duration_s", s.data_duration_s),
            ("rectify_ms_per_frame", s.rectify_ms_per_frame),
            ("sgm_ms_per_frame", s.sgm_ms_per_frame),
            ("vo_ms_per_frame", s.vo_ms_per_frame),
            ("vo_ms_max", s.vo_ms_max),
            ("filter_ms_per_s", s.filter_ms_per_s),
        ] {
            put(key, value.to_string());
        }
        put("summary_initialized_ns", s.initialized_ns.map_or_else(|| NONE.to_owned(), |v| v.to_string()));
        for (key, value) in [
            ("initial_gyro_bias_radps", s.initial_gyro_bias_radps),
            ("initial_accel_bias_mps2", s.initial_accel_bias_mps2),
            ("final_gyro_bias_radps", s.final_gyro_bias_radps),
            ("final_accel_bias_mps2", s.final_accel_bias_mps2),
        ] {
            put(key, value.map_or_else(|| NONE.to_owned(), |v| join(v.iter())));
        }
        put("filter_health", s.filter_health.map_or_else(|| NONE.to_owned(), |h| health_text(&h)));
        out
    }
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

const NONE: &str = "none";

fn join<T: Display>(values: impl Iterator<Item = T>) -> String {
    values.map(|v| v.to_string()).collect::<Vec<_>>().join(" ")
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

/// The filter's health counters in a fixed order (see [`parse_health`]).
fn health_text(h: &FilterHealth) -> String {
    let mut parts: Vec<String> = [
        h.imu_samples,
        h.updates_applied,
        h.updates_rejected,
        h.missing_clones,
        h.clones_evicted,
        h.imu_out_of_order,
        h.imu_gaps,
        h.covariance_repairs,
        h.frame_switches,
    ]
    .iter()
    .map(u64::to_string)
    .collect();
    for g in [&h.relative_pose, &h.wheel, &h.zero_velocity, &h.pose] {
        parts.extend([g.applied.to_string(), g.rejected.to_string(), g.last_nis.to_string()]);
    }
    parts.join(" ")
}

fn parse_health(text: &str) -> Result<FilterHealth, String> {
    let fields: Vec<&str> = text.split_whitespace().collect();
    let mut f = Fields::new(&fields, 9 + 4 * 3)?;
    let mut h = FilterHealth {
        imu_samples: f.next()?,
        updates_applied: f.next()?,
        updates_rejected: f.next()?,
        missing_clones: f.next()?,
        clones_evicted: f.next()?,
        imu_out_of_order: f.next()?,
        imu_gaps: f.next()?,
        covariance_repairs: f.next()?,
        frame_switches: f.next()?,
        ..FilterHealth::default()
    };
    for g in [&mut h.relative_pose, &mut h.wheel, &mut h.zero_velocity, &mut h.pose] {
        *g = GateCounters { applied: f.next()?, rejected: f.next()?, last_nis: f.next()? };
    }
    Ok(h)
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

    fn optional<T>(&self, key: &str, parse: impl Fn(&str) -> Result<T, String>) -> Result<Option<T>, String> {
        let text = self.text(key)?;
        if text == NONE { Ok(None) } else { parse(text).map(Some).map_err(|e| format!("`{key}`: {e}")) }
    }

    fn vector3(&self, key: &str) -> Result<Option<Vector3<f64>>, String> {
        self.optional(key, |text| {
            let fields: Vec<&str> = text.split_whitespace().collect();
            let mut f = Fields::new(&fields, 3)?;
            Ok(Vector3::new(f.next()?, f.next()?, f.next()?))
        })
    }

    fn summary(&self) -> Result<VioSummary, String> {
        Ok(VioSummary {
            frames: self.get("frames")?,
            frames_before_init: self.get("frames_before_init")?,
            keyframes: self.get("keyframes")?,
            vo_resets: self.get("vo_resets")?,
            vo_deltas: self.get("vo_deltas")?,
            mean_inliers: self.get("mean_inliers")?,
            min_inliers: self.get("min_inliers")?,
            vo_updates_applied: self.get("vo_updates_applied")?,
            vo_updates_rejected: self.get("vo_updates_rejected")?,
            vo_updates_missing_clone: self.get("vo_updates_missing_clone")?,
            vo_updates_skipped: self.get("vo_updates_skipped")?,
            wheel_updates_applied: self.get("wheel_updates_applied")?,
            wheel_updates_rejected: self.get("wheel_updates_rejected")?,
            zupt_updates_applied: self.get("zupt_updates_applied")?,
            zupt_updates_rejected: self.get("zupt_updates_rejected")?,
            frame_switches: self.get("frame_switches")?,
            imu_samples: self.get("imu_samples")?,
            filter_health: self.optional("filter_health", parse_health)?,
            initialized_ns: self.optional("summary_initialized_ns", |t| t.parse().map_err(|_| format!("`{t}`")))?,
            initial_gyro_bias_radps: self.vector3("initial_gyro_bias_radps")?,
            initial_accel_bias_mps2: self.vector3("initial_accel_bias_mps2")?,
            final_gyro_bias_radps: self.vector3("final_gyro_bias_radps")?,
            final_accel_bias_mps2: self.vector3("final_accel_bias_mps2")?,
            data_duration_s: self.get("data_duration_s")?,
            rectify_ms_per_frame: self.get("rectify_ms_per_frame")?,
            sgm_ms_per_frame: self.get("sgm_ms_per_frame")?,
            vo_ms_per_frame: self.get("vo_ms_per_frame")?,
            vo_ms_max: self.get("vo_ms_max")?,
            filter_ms_per_s: self.get("filter_ms_per_s")?,
        })
    }
}
