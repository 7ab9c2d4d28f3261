//! Navigation's metric: does the hazard reach the rover's rolling local obstacle map before the
//! rover is within stopping distance of it?
//!
//! **The drive.** The rover drives straight at each target (a rock taller than `h_max`, or an
//! edge section of a negative obstacle) at [`DriveModel::speed_mps`] on a path whose body stays
//! on free ground, from [`TraverseOptions::start_m`] to the stopping distance, measured from the
//! chassis front to the nearest point of the target. Stereo pairs are rendered every
//! [`TraverseOptions::frame_every_s`] along it with the ground-truth body pose, matched by the
//! on-board SGM (or, as the classifier's ceiling, taken as the renderer's exact depth),
//! classified, and blended into a [`LocalObstacleMap`] exactly as the vision process does
//! ([`onboard::nodes::surroundings`]). The head is pointed by the firmware's own
//! [`GazePolicy`], run at the vision task's 20 Hz, and moved by the simulator's head model
//! ([`HeadServo`]); without a policy it stays at the mounted tilt.
//!
//! **Found** when, at the moment the front reaches the stopping distance, a hazard cell of the
//! local map lies within the target's radius plus [`super::MATCHING`]'s tolerance (the planner
//! reads the map then); also reported: marked at any frame before, and from how far first.
//!
//! **Precision** of the map at that moment: a hazard cell is right when it lies within the
//! tolerance of any listed hazard of the world (rocks taller than `h_max`, negative-obstacle
//! edge discs) or its 5 × 5 window of true heights spans more than `h_max` (a true terrain step;
//! see the module documentation of [`super`]).

use eval::map::TrueObstacle;
use hal::sensor::HeadTarget;
use nalgebra::{Isometry3, Point2};
use onboard::nodes::gaze::{GazeOptions, GazePolicy};
use sim::head_servo::HeadServo;
use sim::render::Renderer;
use sim::world::{ObstacleMap, World};
use vision::obstacles::{LocalObstacleMap, ObstacleClassifier, ObstacleConfig, PixelLabels};
use vision::{DepthPipeline, SpeckleFilter, depth_sgm_config};

use super::evaluator::stereo_pipeline;
use super::truth::ground_falls;
use super::viewpoints::{body_pose, next_unit, targets, view_on_terrain};
use super::{Aim, EvaluationError, MATCHING, Truth};

/// How the rover drives and stops: the stopping distance is what it covers from the frame that
/// shows a hazard to standing still.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriveModel {
    pub speed_mps: f64,
    pub deceleration_mps2: f64,
    /// From the capture to the wheels braking: classification, the map's low-pass, the
    /// planner's cycle and the drive's command latency.
    pub reaction_s: f64,
}

impl DriveModel {
    /// The simulator's rover (0.3 m/s, its planner's speed) braking at 0.1 m/s² after 3.5 s:
    /// 1.05 m + 0.45 m = 1.5 m.
    pub const LRU: DriveModel = DriveModel { speed_mps: 0.3, deceleration_mps2: 0.1, reaction_s: 3.5 };

    pub fn stopping_distance_m(&self) -> f64 {
        self.speed_mps * self.reaction_s + self.speed_mps * self.speed_mps / (2.0 * self.deceleration_mps2)
    }
}

/// The chassis front lies this far ahead of the body centre (the sim's chassis box).
pub const FRONT_M: f64 = 0.5;
/// The vision task's rate, at which the gaze policy decides.
const GAZE_TICK_NS: u64 = 50_000_000;
/// The local map as the vision process keeps it.
const MAP_SIDE_CELLS: usize = 200;
const MAP_TIME_CONSTANT_S: f64 = 0.5;

/// One traverse campaign's settings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraverseOptions {
    pub drive: DriveModel,
    /// Front-to-target distance where the drive starts (beyond the 4.5 m range cutoff).
    pub start_m: f64,
    /// A pair every this long (the camera's 10 Hz pairs, subsampled to keep a campaign short).
    pub frame_every_s: f64,
    /// The firmware's gaze policy; `None`: the head stays at `mounted_tilt_rad`.
    pub gaze: Option<GazeOptions>,
    pub mounted_tilt_rad: f64,
    /// Classify the renderer's exact depth instead of SGM's.
    pub true_depth: bool,
    /// An edge drive heads into a drop at least this deep (the negative edges, 0.3 m).
    pub edge_drop_m: f64,
}

impl Default for TraverseOptions {
    fn default() -> Self {
        TraverseOptions {
            drive: DriveModel::LRU,
            start_m: 5.5,
            frame_every_s: 0.4,
            gaze: Some(GazeOptions::lru()),
            mounted_tilt_rad: sim::scenario::ROVER_TILT_RAD,
            true_depth: false,
            edge_drop_m: 0.3,
        }
    }
}

/// A straight drive at one target.
#[derive(Debug, Clone)]
pub struct TraversePath {
    pub aim: Aim,
    /// Rock height above h_max (rocks only).
    pub excess_height_m: f64,
    /// The rock, or the edge discs of the approached section.
    pub truth: Vec<TrueObstacle>,
    /// The point driven at, and the heading.
    pub target_m: Point2<f64>,
    pub yaw_rad: f64,
    /// An edge whose drop ahead is steeper than the classifier's slope limit: a cliff, not a
    /// slope the rover could drive down (see [`traverse_paths`]).
    pub steep: bool,
}

/// The true ground along a path at its target point ([`TraversePath::profile_m`]).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct PathProfile {
    pub rise_m: f64,
    pub drop_m: f64,
    pub steep_drop_m: f64,
}

/// What one drive found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TraverseOutcome {
    pub aim: Aim,
    pub excess_height_m: f64,
    /// An edge drive at a drop steeper than the slope limit ([`TraversePath::steep`]).
    pub steep: bool,
    /// In the local map when the front reached the stopping distance.
    pub found_at_stop: bool,
    /// Front-to-target distance of the first frame after which the map held it.
    pub first_found_m: Option<f64>,
    pub frames: usize,
    /// The map's hazard cells at the stop, those on a listed hazard, and those on a listed
    /// hazard or a true terrain step.
    pub hazard_cells: usize,
    pub cells_listed: usize,
    pub cells_true: usize,
    /// Where the false cells lie: within [`BESIDE_M`] of a listed hazard (the hazard drawn too
    /// wide), or where the true ground falls more than `h_max` within 1 m (a drop the lists
    /// do not hold: a gentler slope, a far crater wall); the rest lie on open ground.
    pub cells_beside: usize,
    pub cells_falling: usize,
}

/// A false cell this close to a listed hazard counts as drawn too wide, not as on open ground.
pub const BESIDE_M: f64 = 0.5;

/// The drive's paths: one per rock and per edge target, from the first of 16 bearings
/// (starting at a random one) whose whole path keeps the body on free ground and the view on
/// the terrain and, for an edge, heads into its drop: the ground falls at least
/// [`TraverseOptions::edge_drop_m`] within 1 m past the target point. A rim passed along or
/// climbed from below is not the hazard the rule is for (and the rover would not fall there).
/// An edge whose drop ahead is also steeper than `config.max_slope_rad` is marked
/// [`TraversePath::steep`]: the sim lists rims that drop 0.3 m within 1 m (17°), which the
/// classifier's slope limit (25°) rightly lets the rover drive down.
pub fn traverse_paths(
    world: &World,
    truth: &Truth,
    config: &ObstacleConfig,
    options: &TraverseOptions,
    seed: u64,
) -> Vec<TraversePath> {
    let free = ObstacleMap::build(&world.terrain);
    let cam = world.robots[0].model().t_body_cam(0.0, options.mounted_tilt_rad).translation.vector;
    let stop_m = options.drive.stopping_distance_m();
    let mut rng = seed ^ 0x7A4E_25E1;
    let mut out = Vec::new();
    for (aim, target, section, excess_height_m) in targets(truth, config.max_step_m) {
        if section.is_empty() {
            continue;
        }
        let start = std::f64::consts::TAU * next_unit(&mut rng);
        for k in 0..16 {
            let yaw = start + k as f64 * std::f64::consts::TAU / 16.0;
            let mut path = TraversePath {
                aim,
                excess_height_m,
                truth: section.clone(),
                target_m: target,
                yaw_rad: yaw,
                steep: false,
            };
            // The body from the start to a little past the stop, every 0.1 m.
            let steps = ((options.start_m - stop_m + 0.5) / 0.1).round() as usize;
            let ok = (0..=steps).all(|i| {
                let d = options.start_m - 0.1 * i as f64;
                let body = path.body_xy(d);
                let (s, c) = yaw.sin_cos();
                let cam_xy = [body[0] + c * cam.x - s * cam.y, body[1] + s * cam.x + c * cam.y];
                !free.is_blocked(body) && view_on_terrain(world, cam_xy, yaw)
            });
            if !ok {
                continue;
            }
            if aim == Aim::Edge {
                let profile = path.profile_m(world, config.max_slope_rad);
                if profile.drop_m < options.edge_drop_m {
                    continue;
                }
                path.steep = profile.steep_drop_m >= options.edge_drop_m;
            }
            out.push(path);
            break;
        }
    }
    out
}

impl TraversePath {
    /// The body centre when the front is `d` from the target point (along the path).
    fn body_xy(&self, d: f64) -> [f64; 2] {
        let (s, c) = self.yaw_rad.sin_cos();
        let back = d + FRONT_M;
        [self.target_m.x - c * back, self.target_m.y - s * back]
    }

    /// The true ground along the path, in metres: how much higher the target point lies than
    /// the ground 1 m before it; the largest drop below it within 1 m past it (the reach of
    /// [`Truth::keep_drops`]); and the largest such drop that is also steeper than
    /// `max_slope_rad` from the target point. A negative edge the rover would drive off has its
    /// drop ahead; passed along the rim or approached from below, the drop lies aside or behind.
    pub fn profile_m(&self, world: &World, max_slope_rad: f64) -> PathProfile {
        let hf = &world.terrain.heightfield;
        let (s, c) = self.yaw_rad.sin_cos();
        let at = |d: f64| hf.height_at(self.target_m.x + c * d, self.target_m.y + s * d);
        let Some(top) = at(0.0) else { return PathProfile::default() };
        let slope = max_slope_rad.tan();
        let mut profile = PathProfile { rise_m: at(-1.0).map_or(0.0, |z| top - z), ..PathProfile::default() };
        for i in 1..=20 {
            let d = 0.05 * i as f64;
            if let Some(z) = at(d) {
                profile.drop_m = profile.drop_m.max(top - z);
                if top - z > slope * d {
                    profile.steep_drop_m = profile.steep_drop_m.max(top - z);
                }
            }
        }
        profile
    }

    /// Distance from the front at `body` to the nearest point of the target's obstacles.
    fn front_distance_m(&self, body: [f64; 2]) -> f64 {
        let (s, c) = self.yaw_rad.sin_cos();
        let front = Point2::new(body[0] + c * FRONT_M, body[1] + s * FRONT_M);
        self.truth.iter().map(|o| (o.centre_m - front).norm() - o.radius_m).fold(f64::INFINITY, f64::min).max(0.0)
    }
}

/// Renderer, stereo, classifier and local map for the drives in one world.
#[derive(Debug)]
pub struct Traverse<'w> {
    world: &'w World,
    truth: &'w Truth,
    config: ObstacleConfig,
    options: TraverseOptions,
    renderer: Renderer,
    stereo: DepthPipeline,
    left: Vec<u8>,
    right: Vec<u8>,
    classifier: ObstacleClassifier,
    labels: PixelLabels,
}

impl<'w> Traverse<'w> {
    /// Drives for the world's first robot with the on-board stereo (SGM configuration, speckle
    /// filter).
    pub fn new(
        world: &'w World,
        truth: &'w Truth,
        config: ObstacleConfig,
        options: TraverseOptions,
    ) -> Result<Self, EvaluationError> {
        let camera = world.robots[0].model().camera;
        let (width, height) = (camera.width_px as usize, camera.height_px as usize);
        let speckle = SpeckleFilter::for_image(width, height);
        let stereo = stereo_pipeline(world, depth_sgm_config(), Some(speckle))?;
        Ok(Traverse {
            world,
            truth,
            config,
            options,
            renderer: Renderer::new(camera, world.scenario.sensor),
            stereo,
            left: vec![0; width * height],
            right: vec![0; width * height],
            classifier: ObstacleClassifier::new(config)?,
            labels: PixelLabels::default(),
        })
    }

    /// Drives `path` (pair `i` rendered with noise seed `noise_seed + i`).
    pub fn drive(&mut self, path: &TraversePath, noise_seed: u64) -> Result<TraverseOutcome, EvaluationError> {
        let o = self.options;
        let model = self.world.robots[0].model();
        let stop_m = o.drive.stopping_distance_m();
        let mut map = LocalObstacleMap::new(self.config.cell_size_m, MAP_SIDE_CELLS, MAP_TIME_CONSTANT_S)
            .releasing_unseen_edges(self.config.release_unseen_edges);
        let mut policy = o.gaze.map(GazePolicy::new);
        let mounted = (0.0, o.mounted_tilt_rad);
        let hold = HeadTarget { stamp_ns: 0, pan_rad: 0.0, tilt_rad: o.mounted_tilt_rad, max_rate_radps: 1.0 };
        let mut head = model.head.map(|limits| HeadServo::new(limits, mounted, 0, hold));
        let frame_ns = (o.frame_every_s * 1e9).round().max(1.0) as u64;
        let mut outcome = TraverseOutcome {
            aim: path.aim,
            excess_height_m: path.excess_height_m,
            found_at_stop: false,
            first_found_m: None,
            steep: path.steep,
            frames: 0,
            hazard_cells: 0,
            cells_listed: 0,
            cells_true: 0,
            cells_beside: 0,
            cells_falling: 0,
        };
        let mut tick_ns = 0;
        for frame in 0.. {
            let t_ns = frame as u64 * frame_ns;
            let travelled_m = o.drive.speed_mps * t_ns as f64 * 1e-9;
            let body = path.body_xy(o.start_m - travelled_m);
            if path.front_distance_m(body) < stop_m {
                break;
            }
            // The policy decides at the vision task's rate up to the capture.
            while tick_ns <= t_ns {
                if let (Some(policy), Some(head)) = (policy.as_mut(), head.as_mut())
                    && let Some(target) = policy.update(tick_ns, o.drive.speed_mps, 0.0)
                {
                    head.command(HeadTarget {
                        stamp_ns: tick_ns,
                        pan_rad: target.pan_rad,
                        tilt_rad: target.tilt_rad,
                        max_rate_radps: target.max_rate_radps,
                    });
                }
                tick_ns += GAZE_TICK_NS;
            }
            let (pan, tilt) = head.as_mut().map_or(mounted, |h| h.angles_at(t_ns));
            let Some(t_world_body) = body_pose(self.world, body[0], body[1], path.yaw_rad) else {
                continue;
            };
            let t_world_cam = t_world_body * model.t_body_cam(pan, tilt);
            self.classify(&t_world_cam, noise_seed + frame as u64)?;
            let p = t_world_body.translation.vector;
            map.recentre(p.x, p.y);
            map.integrate(self.classifier.height_map(), t_ns);
            outcome.frames += 1;
            if outcome.first_found_m.is_none() && marks(&map, &path.truth) {
                outcome.first_found_m = Some(path.front_distance_m(body));
            }
        }
        outcome.found_at_stop = marks(&map, &path.truth);
        self.score_cells(&map, &mut outcome);
        Ok(outcome)
    }

    fn classify(&mut self, t_world_cam: &Isometry3<f64>, noise_seed: u64) -> Result<(), EvaluationError> {
        let scene = self.world.scene(&[]);
        self.renderer.render_stereo(&scene, t_world_cam, noise_seed, &mut self.left, &mut self.right);
        self.stereo.compute(&self.left, &self.right)?;
        if self.options.true_depth {
            self.stereo.depth_mut().depth_m.copy_from_slice(self.renderer.depth_m());
        }
        self.classifier.classify(self.stereo.depth(), self.stereo.geometry(), t_world_cam, &mut self.labels);
        Ok(())
    }

    /// Precision of the map's hazard cells (see the module documentation).
    fn score_cells(&self, map: &LocalObstacleMap, outcome: &mut TraverseOutcome) {
        let cell = map.cell_size_m();
        let hf = &self.world.terrain.heightfield;
        let clearance = |c: Point2<f64>| {
            self.truth
                .rocks
                .iter()
                .map(|(o, _)| o)
                .chain(&self.truth.edges)
                .map(|o| (o.centre_m - c).norm() - o.radius_m)
                .fold(f64::INFINITY, f64::min)
        };
        let falling = |c: Point2<f64>| ground_falls(self.world, c, |drop_m, _| drop_m > self.config.max_step_m);
        let half = (self.config.window_cells as i64 - 1) / 2;
        let high = self.config.window_cells as i64 - 1 - half;
        let true_step = |i: i64, j: i64| {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            for dj in -half..=high {
                for di in -half..=high {
                    let x = (i + di) as f64 * cell + 0.5 * cell;
                    let y = (j + dj) as f64 * cell + 0.5 * cell;
                    if let Some(z) = hf.height_at(x, y) {
                        lo = lo.min(z);
                        hi = hi.max(z);
                    }
                }
            }
            hi - lo > self.config.max_step_m
        };
        for (i, j) in map.hazard_cells() {
            let centre = Point2::new((i as f64 + 0.5) * cell, (j as f64 + 0.5) * cell);
            outcome.hazard_cells += 1;
            let clear_m = clearance(centre);
            if clear_m <= MATCHING.tolerance_m {
                outcome.cells_listed += 1;
                outcome.cells_true += 1;
            } else if true_step(i, j) {
                outcome.cells_true += 1;
            } else if clear_m <= BESIDE_M {
                outcome.cells_beside += 1;
            } else if falling(centre) {
                outcome.cells_falling += 1;
            }
        }
    }
}

/// Whether a hazard cell of `map` lies on one of `truth` (within the matching tolerance).
fn marks(map: &LocalObstacleMap, truth: &[TrueObstacle]) -> bool {
    let cell = map.cell_size_m();
    map.hazard_cells().any(|(i, j)| {
        let c = Point2::new((i as f64 + 0.5) * cell, (j as f64 + 0.5) * cell);
        truth.iter().any(|o| (o.centre_m - c).norm() <= o.radius_m + MATCHING.tolerance_m)
    })
}

/// Sums over drives.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct TraverseTally {
    /// Rocks at least 0.05 m above h_max, all rocks above h_max, edge sections: (driven, found
    /// at the stop).
    pub rocks_clear: (usize, usize),
    pub rocks: (usize, usize),
    pub edges: (usize, usize),
    /// The edge drives at drops steeper than the slope limit.
    pub edges_steep: (usize, usize),
    /// Found at any frame before the stop.
    pub rocks_any: usize,
    pub edges_any: usize,
    pub frames: usize,
    pub hazard_cells: usize,
    pub cells_listed: usize,
    pub cells_true: usize,
    pub cells_beside: usize,
    pub cells_falling: usize,
}

/// Rocks this much above h_max must all be found.
pub const CLEAR_EXCESS_M: f64 = 0.05;

impl TraverseTally {
    pub fn add(&mut self, o: &TraverseOutcome) {
        let hit = usize::from(o.found_at_stop);
        let any = usize::from(o.first_found_m.is_some());
        match o.aim {
            Aim::Rock => {
                self.rocks.0 += 1;
                self.rocks.1 += hit;
                self.rocks_any += any;
                if o.excess_height_m >= CLEAR_EXCESS_M {
                    self.rocks_clear.0 += 1;
                    self.rocks_clear.1 += hit;
                }
            }
            Aim::Edge | Aim::Open => {
                self.edges.0 += 1;
                self.edges.1 += hit;
                self.edges_any += any;
                if o.steep {
                    self.edges_steep.0 += 1;
                    self.edges_steep.1 += hit;
                }
            }
        }
        self.frames += o.frames;
        self.hazard_cells += o.hazard_cells;
        self.cells_listed += o.cells_listed;
        self.cells_true += o.cells_true;
        self.cells_beside += o.cells_beside;
        self.cells_falling += o.cells_falling;
    }

    pub fn merge(&mut self, other: &TraverseTally) {
        let pair = |a: &mut (usize, usize), b: (usize, usize)| {
            a.0 += b.0;
            a.1 += b.1;
        };
        pair(&mut self.rocks_clear, other.rocks_clear);
        pair(&mut self.rocks, other.rocks);
        pair(&mut self.edges, other.edges);
        pair(&mut self.edges_steep, other.edges_steep);
        self.rocks_any += other.rocks_any;
        self.edges_any += other.edges_any;
        self.frames += other.frames;
        self.hazard_cells += other.hazard_cells;
        self.cells_listed += other.cells_listed;
        self.cells_true += other.cells_true;
        self.cells_beside += other.cells_beside;
        self.cells_falling += other.cells_falling;
    }

    /// Hazard cells on a listed hazard or a true step, of all hazard cells.
    pub fn precision(&self) -> Option<f64> {
        super::ratio(self.cells_true, self.hazard_cells)
    }
}
