//! Composed-map height error on a simulated Moon drive (issue 8): SGM depth of every stereo frame
//! integrated into 7 m submaps twice, once along the ground-truth camera poses and once along the
//! filter's poses (the rover's firmware nodes on the simulator, as in `tests/common/sim_run.rs`),
//! each composed with `mapper::global::GlobalMap` and compared with the true terrain within 5 m of
//! the driven path, away from rocks.
//!
//! `cargo run --release -p sil --example sim_map -- [--duration S] [--seed N] [--downscale N]`

#[path = "../tests/common/sim_run.rs"]
mod sim_run;

use std::collections::VecDeque;
use std::sync::Arc;

use eval::map::{HeightGrid, TrueObstacle};
use filter::FrameSwitch;
use mapper::global::{Composition, GlobalMap, GlobalMapConfig};
use mapper::integrate::{DepthIntegrator, IntegratorConfig};
use mapper::slam::{FramePose, PoseBuffer, SameStamp};
use mapper::submap::{SubmapPolicy, Submapper};
use nalgebra::{Isometry3, Matrix3, Matrix6, Point2, Point3, Vector3};
use onboard::lockstep::{OwnedMessage, RobotStack, STEP_NS};
use onboard::nodes::Topic;
use sim::driver::SimSensorSource;
use vision::depth::{DepthImage, StereoGeometry};
use vision::obstacles::{ObstacleClassifier, ObstacleConfig, PixelLabels};

type BoxError = Box<dyn std::error::Error>;

/// Only map points this close (horizontally) to the driven path are scored (issue 8).
const PATH_RADIUS_M: f64 = 5.0;
/// Points within a rock's footprint plus this margin are left out: rocks are not in the
/// heightfield.
const ROCK_MARGIN_M: f64 = 0.1;

fn arg(name: &str, default: f64) -> f64 {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// A gravity-aligned origin at the body: position and yaw, as the filter's frame switch makes it.
fn gravity_aligned(t_world_body: &Isometry3<f64>) -> Isometry3<f64> {
    let forward = t_world_body.rotation * Vector3::x();
    Isometry3::new(t_world_body.translation.vector, Vector3::z() * forward.y.atan2(forward.x))
}

/// One robot's submaps along one pose source. Its own filter is not in this loop, so the switches the
/// `Submapper` requests (7 m of path) are carried out here: the new origin is the gravity-aligned
/// body pose, as `Filter::switch_frame` would make it.
struct Track {
    submapper: Submapper,
    global: GlobalMap,
    t_world_submap: Option<Isometry3<f64>>,
    frame_id: u32,
    integrate_s: f64,
}

impl Track {
    fn new(geometry: StereoGeometry) -> Track {
        let integrator = DepthIntegrator::new(IntegratorConfig::default(), geometry);
        Track {
            submapper: Submapper::new(0, SubmapPolicy::default(), integrator),
            global: GlobalMap::new(GlobalMapConfig::default()),
            t_world_submap: None,
            frame_id: 0,
            integrate_s: 0.0,
        }
    }

    fn add(
        &mut self,
        stamp_ns: u64,
        depth: &DepthImage,
        grey: &[u8],
        labels: &PixelLabels,
        t_world_body: &Isometry3<f64>,
        t_world_cam: &Isometry3<f64>,
    ) {
        let t_world_submap = *self.t_world_submap.get_or_insert_with(|| gravity_aligned(t_world_body));
        let t_local_body = t_world_submap.inverse() * t_world_body;
        // The filter's position sigma relative to the submap start is not available without its
        // own frame switches, so only the distance threshold applies.
        if self.submapper.on_filter_state(stamp_ns, &t_local_body, &Matrix3::zeros()).is_some() {
            let t_world_next = gravity_aligned(t_world_body);
            let switch = FrameSwitch {
                stamp_ns,
                old_frame_id: self.frame_id,
                new_frame_id: self.frame_id + 1,
                t_old_new: t_world_submap.inverse() * t_world_next,
                covariance: Matrix6::zeros(),
            };
            self.frame_id += 1;
            let finished = self.submapper.on_frame_switch(&switch);
            self.global.insert(Arc::new(finished), t_world_submap);
            self.t_world_submap = Some(t_world_next);
        }
        let t_world_submap = self.t_world_submap.unwrap_or(t_world_submap);
        let started = std::time::Instant::now();
        self.submapper.integrate(stamp_ns, depth, Some(labels), Some(grey), &(t_world_submap.inverse() * t_world_cam));
        self.integrate_s += started.elapsed().as_secs_f64();
    }

    fn compose(&mut self) -> Composition {
        let t = self.t_world_submap.unwrap_or_else(Isometry3::identity);
        self.global.compose(Some((self.submapper.current(), &t)))
    }
}

/// Invalidates the finite depths the obstacle classifier's 2.5D consistency test rejected (SGM
/// mismatches, on the simulated Moon mostly the black sky matched to a few metres): pixels within
/// its range that it did not map. Returns how many.
fn drop_inconsistent(depth: &mut DepthImage, classifier: &ObstacleClassifier, labels: &PixelLabels) -> usize {
    let mut dropped = 0;
    for (i, z) in depth.depth_m.iter_mut().enumerate() {
        let too_far = labels.flags.get(i).is_some_and(|f| f & PixelLabels::TOO_FAR != 0);
        if z.is_finite() && !too_far && classifier.pixel_height_m(i).is_none() {
            *z = f32::NAN;
            dropped += 1;
        }
    }
    dropped
}

fn t_cam_vector(p: &Pending) -> Vector3<f64> {
    p.t_world_cam_true.translation.vector
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}

/// A frame waiting for the filter's pose at its capture time.
struct Pending {
    stamp_ns: u64,
    depth: DepthImage,
    grey: Vec<u8>,
    t_world_body_true: Isometry3<f64>,
    t_world_cam_true: Isometry3<f64>,
}

/// Map points within `radius_m` (horizontal) of the path, away from rocks.
fn scored_points(
    composition: &Composition,
    path: &[Point2<f64>],
    rocks: &[TrueObstacle],
    radius_m: f64,
) -> Vec<Point3<f64>> {
    let near: Vec<Point3<f64>> = composition
        .cloud
        .points
        .iter()
        .map(|p| p.position_m.cast::<f64>())
        .filter(|p| path.iter().any(|q| (q - p.xy()).norm_squared() <= radius_m * radius_m))
        .collect();
    eval::map::points_away_from_obstacles(&near, rocks, ROCK_MARGIN_M)
}

fn main() -> Result<(), BoxError> {
    let duration_s = arg("--duration", 120.0);
    let seed = arg("--seed", 1.0) as u64;
    let downscale = arg("--downscale", 2.0) as u32;
    let wall = std::time::Instant::now();
    let sim_world = sim_run::moon_world(seed, duration_s, downscale, None);
    let world = Arc::clone(&sim_world.world);
    let config = sim_run::sim_config(&sim_world, true);
    let setup = onboard::sensors::sensor_setup(&config)?;
    let calibration = setup.calibration;
    let source = SimSensorSource::new(Arc::clone(&world), 0)?;
    let mut stack = RobotStack::new(&config, &setup, Box::new(source), None, None)?;
    stack.bus.tap(&[Topic::Stereo, Topic::FilterState, Topic::FrameSwitch]);
    // The filter's trajectory in its first local frame (chained across its frame switches).
    let mut trajectory: PoseBuffer<FramePose> = PoseBuffer::unbounded(SameStamp::KeepLatest);
    let mut t_first_local = Isometry3::identity();
    let geometry = StereoGeometry::from_calibration(&calibration);
    let (w, h) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    // The vision node's depth: SGM with its uniqueness margin, then the speckle filter.
    let depth_options = vision::DepthOptions { threads, ..vision::DepthOptions::default() };
    let mut depth = vision::DepthPipeline::new(&calibration, depth_options)?;
    let mut classifier = ObstacleClassifier::new(ObstacleConfig::default())?;
    let mut labels = PixelLabels::default();
    let (mut truth, mut filtered, mut raw) = (Track::new(geometry), Track::new(geometry), Track::new(geometry));
    let mut inconsistent = 0usize;
    // Per integrated frame: the filter camera pose's position error and tilt (roll/pitch) error.
    let (mut position_errors_m, mut tilt_errors_deg) = (Vec::new(), Vec::new());
    let mut pending: VecDeque<Pending> = VecDeque::new();
    let mut pool: Vec<Pending> = Vec::new();
    let mut path: Vec<Point2<f64>> = Vec::new();
    let (mut integrated, mut dropped, mut sgm_s) = (0usize, 0usize, 0.0);
    // Filter's first local frame in the world, fixed at the first filter pose (as sim_run does).
    let mut t_world_first: Option<Isometry3<f64>> = None;
    let mut now_ns = 0;
    while !stack.driver.finished() {
        stack.step(now_ns)?;
        now_ns += STEP_NS;
        for message in stack.bus.take_tapped() {
            let (header, bytes) = match message {
                OwnedMessage::FrameSwitch(s) => {
                    t_first_local *= s.t_old_new.to_isometry().ok_or("bad switch")?;
                    continue;
                }
                OwnedMessage::FilterState(s) if s.status == msgs::FilterStateMsg::RUNNING => {
                    let pose = t_first_local * s.t_local_body.to_isometry().ok_or("bad state")?;
                    // One chained frame: interpolation never stops at a switch.
                    trajectory.insert(FramePose {
                        stamp_ns: s.stamp_ns,
                        frame_id: 0,
                        pose,
                        covariance: Matrix6::zeros(),
                    });
                    continue;
                }
                OwnedMessage::Stereo(header, bytes) => (header, bytes),
                _ => continue,
            };
            let stamp_ns = header.stamp_ns;
            let truth_state = world.robot_state(0, stamp_ns).ok_or("no ground truth")?;
            let t_world_cam = world.t_world_cam(0, stamp_ns).ok_or("no camera pose")?;
            let started = std::time::Instant::now();
            let (frame_left, frame_right) = bytes.split_at(w * h);
            depth.compute(frame_left, frame_right)?;
            let mut p = pool.pop().unwrap_or_else(|| Pending {
                stamp_ns: 0,
                depth: DepthImage::new(w, h),
                grey: vec![0; w * h],
                t_world_body_true: Isometry3::identity(),
                t_world_cam_true: Isometry3::identity(),
            });
            p.depth.depth_m.copy_from_slice(&depth.depth().depth_m);
            sgm_s += started.elapsed().as_secs_f64();
            p.grey.copy_from_slice(frame_left);
            p.stamp_ns = stamp_ns;
            p.t_world_body_true = truth_state.t_world_body;
            p.t_world_cam_true = t_world_cam;
            pending.push_back(p);
            let xy = Point2::from(truth_state.t_world_body.translation.vector.xy());
            if path.last().is_none_or(|q| (q - xy).norm() > 0.1) {
                path.push(xy);
            }
        }
        // A frame is integrated once the filter's trajectory reaches its capture time.
        while let Some(front) = pending.front() {
            let Some(last_ns) = trajectory.latest().map(|p| p.stamp_ns) else { break };
            if front.stamp_ns > last_ns {
                break;
            }
            let Some(mut p) = pending.pop_front() else { break };
            match trajectory.lookup(p.stamp_ns, u64::MAX).map(|s| s.pose) {
                Some(t_first_body) => {
                    let t_world_first = *t_world_first.get_or_insert_with(|| {
                        let first = trajectory.range(0, u64::MAX).next();
                        let first_truth = first.and_then(|f| world.robot_state(0, f.stamp_ns)).map(|g| g.t_world_body);
                        match (first_truth, first) {
                            (Some(g), Some(f)) => g * f.pose.inverse(),
                            _ => Isometry3::identity(),
                        }
                    });
                    let t_body_cam = p.t_world_body_true.inverse() * p.t_world_cam_true;
                    let t_world_body_est = t_world_first * t_first_body;
                    let t_world_cam_est = t_world_body_est * t_body_cam;
                    // Labels from the robot's own (estimated) view; they set the obstacle bit only.
                    position_errors_m.push((t_world_cam_est.translation.vector - t_cam_vector(&p)).norm());
                    let up_est = t_world_body_est.rotation * Vector3::z();
                    let up_true = p.t_world_body_true.rotation * Vector3::z();
                    tilt_errors_deg.push(up_est.angle(&up_true).to_degrees());
                    classifier.classify(&p.depth, &geometry, &t_world_cam_est, &mut labels);
                    let (t_body, t_cam) = (p.t_world_body_true, p.t_world_cam_true);
                    raw.add(p.stamp_ns, &p.depth, &p.grey, &labels, &t_body, &t_cam);
                    inconsistent += drop_inconsistent(&mut p.depth, &classifier, &labels);
                    truth.add(p.stamp_ns, &p.depth, &p.grey, &labels, &t_body, &t_cam);
                    filtered.add(p.stamp_ns, &p.depth, &p.grey, &labels, &t_world_body_est, &t_world_cam_est);
                    integrated += 1;
                }
                None => dropped += 1,
            }
            pool.push(p);
        }
    }
    stack.finish(now_ns)?;
    let summary = stack.filter.summary();
    let t_world_first = t_world_first.ok_or("the filter never produced a pose")?;
    let Some((last_ns, last_pose)) = trajectory.latest().map(|p| (p.stamp_ns, p.pose)) else {
        return Err("no trajectory".into());
    };
    let last_true = world.robot_state(0, last_ns).ok_or("no ground truth")?.t_world_body;
    let last_est = t_world_first * last_pose;
    let final_error_m = (last_true.translation.vector - last_est.translation.vector).norm();
    let distance_m: f64 = path.windows(2).map(|s| (s[1] - s[0]).norm()).sum();

    let hf = &world.terrain.heightfield;
    let gt =
        HeightGrid::new(hf.resolution_m, (hf.origin_m[0], hf.origin_m[1]), hf.cols, hf.rows, hf.heights_m.clone())?;
    let rocks: Vec<TrueObstacle> = world
        .terrain
        .rocks
        .iter()
        .map(|r| TrueObstacle { centre_m: Point2::new(r.base_m.x, r.base_m.y), radius_m: r.radius_m })
        .collect();
    println!(
        "Moon preset, seed {seed}, {duration_s} s, {w}x{h} (downscale {downscale}): {integrated} frames integrated \
         ({dropped} before the filter's first pose), path {distance_m:.1} m, SGM {:.1} ms/frame, \
         {:.0} inconsistent pixels/frame dropped, wall {:.0} s",
        1e3 * sgm_s / integrated.max(1) as f64,
        inconsistent as f64 / integrated.max(1) as f64,
        wall.elapsed().as_secs_f64()
    );
    println!(
        "filter (VO + IMU + wheels): final position error {final_error_m:.3} m = {:.2} % of the path \
         (VO {} applied / {} rejected)",
        100.0 * final_error_m / distance_m.max(1e-9),
        summary.vo_updates_applied,
        summary.vo_updates_rejected
    );
    let near_rocks =
        rocks.iter().filter(|r| path.iter().any(|q| (q - r.centre_m).norm() <= PATH_RADIUS_M + r.radius_m)).count();
    println!(
        "filter camera poses at capture: median position error {:.3} m, median tilt error {:.2}°; \
         {near_rocks} rocks within {PATH_RADIUS_M} m of the path",
        median(&mut position_errors_m),
        median(&mut tilt_errors_deg)
    );
    println!(
        "{:<22} {:>8} {:>9} {:>10} {:>10} {:>10} {:>10}",
        "poses", "submaps", "points", "scored", "median m", "p95 m", "mean m"
    );
    let tracks = [("ground truth, raw SGM", &mut raw), ("ground truth", &mut truth), ("filter", &mut filtered)];
    for (name, track) in tracks {
        let composition = track.compose();
        let scored = scored_points(&composition, &path, &rocks, PATH_RADIUS_M);
        let report = eval::map::cloud_height_error(&scored, &gt);
        let stats = report.stats.ok_or("no point over the terrain")?;
        println!(
            "{name:<22} {:>8} {:>9} {:>10} {:>10.4} {:>10.4} {:>+10.4}   (integration {:.1} ms/frame, compose {:.0} ms)",
            track.global.len() + 1,
            composition.cloud.len(),
            stats.count,
            stats.median_abs_m,
            stats.p95_abs_m,
            stats.mean_m,
            1e3 * track.integrate_s / integrated.max(1) as f64,
            composition.stats.elapsed.as_secs_f64() * 1e3
        );
    }
    Ok(())
}
