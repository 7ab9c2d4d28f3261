#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Obstacle classification against the simulator's ground truth (thesis §5.1.1): the camera is
//! placed deliberately 2–5 m from each true obstacle of a Moon world, facing it, plus random
//! viewpoints on open terrain; each stereo pair is rendered, matched by SGM and classified with
//! the ground-truth camera pose, and the obstacle cells within 5 m are scored.
//!
//! A drive through the preset's worlds never brings a true obstacle within 5 m (the planner keeps
//! 1 m clearance and tall rocks are sparse), hence the deliberate viewpoints.
//!
//! Truth: rocks taller than `h_max`, the negative obstacles' edges (discs every 0.25 m), and
//! terrain steps: cells of the classifier's 5 cm lattice whose 5 × 5 window of **true** heights
//! (the heightfield at the cell centres) spans more than `h_max`, the classifier's own test
//! without stereo error. Such a window is a step the wheel cannot climb, and also a slope of
//! at least atan(0.15 / 0.28) ≈ 28° (diagonal) to 37° (axis), beyond the 25° slope limit: crater
//! walls at the angle of repose are untraversable whatever the preset's obstacle list says.
//!
//! **Approach runs** (`--approach`): the camera drives straight at each rock and each edge target
//! from 5 m to 2.5 m (`--approach-to M`), a frame every 0.5 m, on a path whose body stays on free
//! ground; a target counts as found when one frame detects it. That is what the planner needs:
//! a warning before the rover is there. A single frame is not enough evidence by construction:
//! the step threshold `h_max + Δd` grows with range, so a rock just above `h_max` passes it only
//! near, where its foot may already be below the image.
//!
//! Experiments: `--true-depth` classifies the renderer's exact depth instead of SGM's (the
//! classifier's own ceiling); `--steep-edges` keeps only the edge discs where the true ground
//! drops by more than `h_max` at more than the slope limit (the sim's crater-edge list also holds
//! rims one may drive down); `--tilt RAD` tilts the head down by another angle than mounted.
//!
//! Run: `cargo run --release -p vision --example sim_obstacles -- [--seeds N] [--per-target K]
//! [--open M] [--dump]`; the stereo defaults are the on-board ones (`vision::depth_sgm_config`,
//! `SpeckleFilter::for_image`), changed with `[--uniqueness PCT] [--lr-diff PX] [--lr-strict]
//! [--speckle PX (0 = off)] [--speckle-step PX]`. The integration test `tests/obstacles.rs`
//! uses [`Evaluator`].

use std::collections::{HashMap, HashSet};
use std::time::Instant;

use eval::map::{HeightGrid, ObstacleMatching, TrueObstacle, evaluate_obstacles, obstacles_in_mapped_area};
use fpga_model::SgmConfig;
use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion};
use sim::motion::wheel_contact_plane;
use sim::render::Renderer;
use sim::robot::ROVER_CHASSIS_HEIGHT_M;
use sim::scenario::{ScenarioOptions, preset};
use sim::world::{ObstacleMap, World};
use vision::obstacles::{ObstacleClassifier, ObstacleConfig, PixelLabels};
use vision::{DepthOptions, DepthPipeline, SpeckleFilter, StereoGeometry, depth_sgm_config};

/// Evaluation radius around the camera (the "within 5 m").
pub const RADIUS_M: f64 = 5.0;
/// A detected cell matches an obstacle within its radius plus this: half the 5-cell step
/// window (the window labels cells up to two cells beyond a step) plus one cell.
pub const MATCHING: ObstacleMatching = ObstacleMatching { tolerance_m: 0.15, link_distance_m: 0.075 };
/// Negative-obstacle edges become discs of this radius every [`EDGE_SPACING_M`] along the edge.
const EDGE_DISC_M: f64 = 0.1;
const EDGE_SPACING_M: f64 = 0.25;
/// Camera distances (horizontal, to the target's centre) of the deliberate viewpoints.
pub const DISTANCES_M: [f64; 3] = [2.5, 3.5, 4.5];
/// Edge targets are taken every this far along a negative obstacle's edge.
const EDGE_TARGET_SPACING_M: f64 = 3.0;

/// Recall by range: bins of this width from the camera out to [`RADIUS_M`].
pub const RANGE_BIN_M: f64 = 1.0;
pub const RANGE_BINS: usize = 6;

fn range_bin(distance_m: f64) -> usize {
    ((distance_m / RANGE_BIN_M).max(0.0) as usize).min(RANGE_BINS - 1)
}

/// Counts one obstacle into a (seen, found) pair.
fn count(pair: &mut (usize, usize), hit: bool) {
    pair.0 += 1;
    pair.1 += usize::from(hit);
}

fn add_pairs(into: &mut [(usize, usize)], from: &[(usize, usize)]) {
    for (a, b) in into.iter_mut().zip(from) {
        a.0 += b.0;
        a.1 += b.1;
    }
}

/// Histogram of the SGM disparity error (see [`Tally::disparity_error_bins`]).
pub const DISPARITY_BIN_PX: f64 = 0.02;
pub const DISPARITY_SPAN_PX: f64 = 3.0;

/// What a viewpoint was chosen for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Aim {
    Rock,
    Edge,
    Open,
}

#[derive(Debug, Clone, Copy)]
pub struct Viewpoint {
    pub aim: Aim,
    pub t_world_body: Isometry3<f64>,
    /// Head tilt (down positive), the robot's mounted tilt unless an experiment changes it.
    pub tilt_rad: f64,
}

/// The listed true obstacles of one world.
#[derive(Debug, Clone)]
pub struct Truth {
    /// Rocks taller than `h_max`, with their heights.
    pub rocks: Vec<(TrueObstacle, f64)>,
    pub edges: Vec<TrueObstacle>,
    /// Points along the edges where edge viewpoints aim.
    pub edge_targets: Vec<Point2<f64>>,
}

impl Truth {
    pub fn of(world: &World, max_step_m: f64) -> Truth {
        let rocks = world
            .terrain
            .rocks
            .iter()
            .filter(|r| r.height_m > max_step_m)
            .map(|r| (TrueObstacle { centre_m: Point2::new(r.base_m.x, r.base_m.y), radius_m: r.radius_m }, r.height_m))
            .collect();
        let mut edges = Vec::new();
        let mut edge_targets = Vec::new();
        for obstacle in world.terrain.negative_obstacles() {
            let mut along_m = 0.0;
            for segment in obstacle.edge_m.windows(2) {
                let (a, b) = (Point2::from(segment[0]), Point2::from(segment[1]));
                let length = (b - a).norm();
                let steps = (length / EDGE_SPACING_M).ceil().max(1.0) as usize;
                for k in 0..steps {
                    let centre_m = a + (b - a) * (k as f64 / steps as f64);
                    edges.push(TrueObstacle { centre_m, radius_m: EDGE_DISC_M });
                    let s = along_m + length * k as f64 / steps as f64;
                    if edge_targets.is_empty() || s.rem_euclid(EDGE_TARGET_SPACING_M) < length / steps as f64 {
                        edge_targets.push(centre_m);
                    }
                }
                along_m += length;
            }
        }
        Truth { rocks, edges, edge_targets }
    }

    /// Keeps only the edge discs where the true ground drops by more than `max_step_m` at a mean
    /// slope steeper than `max_slope_rad` (within 1 m, in any of 16 directions from the disc
    /// centre): the cliffs the rover can neither step nor drive down. The sim's crater-edge rule
    /// (0.3 m within 1 m of the crest, 17°) also lists rims the slope limit lets the rover descend.
    pub fn keep_steep_edges(&mut self, world: &World, max_step_m: f64, max_slope_rad: f64) {
        let hf = &world.terrain.heightfield;
        let slope = max_slope_rad.tan();
        let steep = |p: &Point2<f64>| {
            let Some(top) = hf.height_at(p.x, p.y) else { return false };
            (0..16).any(|k| {
                let (s, c) = (k as f64 * std::f64::consts::TAU / 16.0).sin_cos();
                (1..=20).any(|i| {
                    let d = 0.05 * i as f64;
                    hf.height_at(p.x + c * d, p.y + s * d).is_some_and(|z| top - z > max_step_m && top - z > slope * d)
                })
            })
        };
        self.edges.retain(|o| steep(&o.centre_m));
        let edges = &self.edges;
        self.edge_targets.retain(|t| edges.iter().any(|o| (o.centre_m - t).norm() <= 1e-9));
    }
}

/// The Moon preset's world for `seed` on a square of `size_m`.
pub fn moon_world(seed: u64, size_m: f64) -> std::sync::Arc<World> {
    let options = ScenarioOptions {
        robots: 1,
        duration_s: 20.0,
        seed,
        downscale: 1,
        world_size_m: Some(size_m),
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    World::build(&preset("moon", &options).unwrap()).unwrap()
}

/// splitmix64: a reproducible stream without a dependency.
fn next_unit(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// Body resting on the terrain at `(x, y)` heading `yaw`, as the trajectory generator poses it.
fn body_pose(world: &World, x: f64, y: f64, yaw: f64) -> Option<Isometry3<f64>> {
    let plane = wheel_contact_plane(&world.terrain.heightfield, x, y, yaw)?;
    let (roll, pitch) = plane.roll_pitch_rad();
    Some(Isometry3::from_parts(
        Translation3::new(x, y, plane.height_m + ROVER_CHASSIS_HEIGHT_M),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    ))
}

/// Whether everything the camera at `cam_xy` heading `yaw` maps (within 5 m, 50° field of view)
/// lies on the terrain: beyond its edge the void would look like a cliff.
fn view_on_terrain(world: &World, cam_xy: [f64; 2], yaw: f64) -> bool {
    let hf = &world.terrain.heightfield;
    let (s, c) = yaw.sin_cos();
    [(0.0, 0.0), (7.0, 0.0), (7.0, 3.5), (7.0, -3.5)]
        .iter()
        .all(|&(f, l)| hf.height_at(cam_xy[0] + c * f - s * l, cam_xy[1] + s * f + c * l).is_some())
}

/// Viewpoints: up to `per_target` per rock and per edge target (camera `DISTANCES_M` away,
/// facing it, from bearings tried in turn until the body stands on free ground), then `open`
/// random poses on free ground.
pub fn viewpoints(world: &World, truth: &Truth, per_target: usize, open: usize, seed: u64) -> Vec<Viewpoint> {
    let free = ObstacleMap::build(&world.terrain);
    let robot = &world.robots[0];
    let cam = robot.model().t_body_cam(0.0, robot.setup.tilt_rad).translation.vector;
    let mut rng = seed ^ 0x5EED;
    let mut out = Vec::new();
    let targets = truth
        .rocks
        .iter()
        .map(|(o, _)| (Aim::Rock, o.centre_m))
        .chain(truth.edge_targets.iter().map(|p| (Aim::Edge, *p)));
    for (aim, target) in targets {
        let start = 2.0 * std::f64::consts::PI * next_unit(&mut rng);
        let mut taken = 0;
        for k in 0..16 {
            if taken == per_target {
                break;
            }
            let bearing = start + k as f64 * 2.0 * std::f64::consts::PI / 16.0;
            let d = DISTANCES_M[taken % DISTANCES_M.len()];
            let yaw = bearing + std::f64::consts::PI;
            let (s, c) = yaw.sin_cos();
            let cam_xy = [target.x - c * d, target.y - s * d];
            let body_xy = [cam_xy[0] - (c * cam.x - s * cam.y), cam_xy[1] - (s * cam.x + c * cam.y)];
            if free.is_blocked(body_xy) || !view_on_terrain(world, cam_xy, yaw) {
                continue;
            }
            if let Some(t_world_body) = body_pose(world, body_xy[0], body_xy[1], yaw) {
                out.push(Viewpoint { aim, t_world_body, tilt_rad: robot.setup.tilt_rad });
                taken += 1;
            }
        }
    }
    let hf = &world.terrain.heightfield;
    let span = [(hf.cols - 1) as f64 * hf.resolution_m, (hf.rows - 1) as f64 * hf.resolution_m];
    let mut placed = 0;
    let mut tries = 0;
    while placed < open && tries < 100 * open.max(1) {
        tries += 1;
        let x = hf.origin_m[0] + span[0] * next_unit(&mut rng);
        let y = hf.origin_m[1] + span[1] * next_unit(&mut rng);
        let yaw = 2.0 * std::f64::consts::PI * next_unit(&mut rng);
        let (s, c) = yaw.sin_cos();
        let cam_xy = [x + c * cam.x - s * cam.y, y + s * cam.x + c * cam.y];
        if free.is_blocked([x, y]) || !view_on_terrain(world, cam_xy, yaw) {
            continue;
        }
        if let Some(t_world_body) = body_pose(world, x, y, yaw) {
            out.push(Viewpoint { aim: Aim::Open, t_world_body, tilt_rad: robot.setup.tilt_rad });
            placed += 1;
        }
    }
    out
}

/// Camera distances (horizontal, to the target) of an approach run, far and near: from the range
/// cutoff down to where the target reaches the image's lower edge (the view's nearest
/// ground lies 2.4 m ahead at the mast's 1.24 m and 0.25 rad tilt).
pub const APPROACH_M: (f64, f64) = (5.0, 2.5);
/// Spacing of the approach frames.
pub const APPROACH_STEP_M: f64 = 0.5;
/// The approached section of a negative edge: its discs within this of the edge target.
pub const EDGE_SECTION_M: f64 = 0.5;

/// The frame distances of an approach from `far` to `near`, every [`APPROACH_STEP_M`].
pub fn approach_distances((far_m, near_m): (f64, f64)) -> impl Iterator<Item = f64> {
    let steps = ((far_m - near_m) / APPROACH_STEP_M).round().max(0.0) as usize;
    (0..=steps).map(move |i| far_m - APPROACH_STEP_M * i as f64)
}

/// A straight drive towards one target, as the rolling local map sees it.
#[derive(Debug, Clone)]
pub struct Approach {
    pub aim: Aim,
    /// Rock height above h_max (rocks only; 0 for edges).
    pub excess_height_m: f64,
    /// The true obstacles the run is about: the rock, or the edge discs of the approached section.
    pub truth: Vec<TrueObstacle>,
    /// One pose per distance, far to near, with the distance.
    pub frames: Vec<(Viewpoint, f64)>,
}

/// One approach per rock and per edge target, from the first of 16 bearings (starting at a
/// random one) whose whole straight path keeps the body on free ground and the view on the
/// terrain. Frames every [`APPROACH_STEP_M`] from `distances_m` (far, near), the head tilted down
/// by `tilt_rad`.
pub fn approaches(
    world: &World,
    truth: &Truth,
    max_step_m: f64,
    distances_m: (f64, f64),
    tilt_rad: f64,
    seed: u64,
) -> Vec<Approach> {
    let free = ObstacleMap::build(&world.terrain);
    let robot = &world.robots[0];
    let cam = robot.model().t_body_cam(0.0, tilt_rad).translation.vector;
    let (far_m, near_m) = distances_m;
    let distances: Vec<f64> = approach_distances(distances_m).collect();
    let mut rng = seed ^ 0xA9_9A0C;
    let targets = truth.rocks.iter().map(|(o, h)| (Aim::Rock, o.centre_m, vec![*o], h - max_step_m)).chain(
        truth.edge_targets.iter().map(|p| {
            let section = truth.edges.iter().filter(|o| (o.centre_m - p).norm() <= EDGE_SECTION_M).copied().collect();
            (Aim::Edge, *p, section, 0.0)
        }),
    );
    let mut out = Vec::new();
    for (aim, target, section, excess_height_m) in targets {
        let start = 2.0 * std::f64::consts::PI * next_unit(&mut rng);
        for k in 0..16 {
            let yaw = start + k as f64 * 2.0 * std::f64::consts::PI / 16.0;
            let (s, c) = yaw.sin_cos();
            let body_at = |d: f64| {
                let cam_xy = [target.x - c * d, target.y - s * d];
                (cam_xy, [cam_xy[0] - (c * cam.x - s * cam.y), cam_xy[1] - (s * cam.x + c * cam.y)])
            };
            // The path between the frames too, every 0.1 m.
            let steps = ((far_m - near_m) / 0.1).round() as usize;
            let path_free = (0..=steps).all(|i| !free.is_blocked(body_at(far_m - 0.1 * i as f64).1));
            if !path_free {
                continue;
            }
            let frames: Option<Vec<(Viewpoint, f64)>> = distances
                .iter()
                .map(|&d| {
                    let (cam_xy, body_xy) = body_at(d);
                    if !view_on_terrain(world, cam_xy, yaw) {
                        return None;
                    }
                    body_pose(world, body_xy[0], body_xy[1], yaw)
                        .map(|t_world_body| (Viewpoint { aim, t_world_body, tilt_rad }, d))
                })
                .collect();
            if let Some(frames) = frames {
                out.push(Approach { aim, excess_height_m, truth: section, frames });
                break;
            }
        }
    }
    out
}

/// Counts summed over frames (an obstacle seen from k viewpoints counts k times).
#[derive(Debug, Clone, Default)]
pub struct Tally {
    pub frames: usize,
    pub rocks: usize,
    pub rocks_found: usize,
    /// Rocks by height: [h_max, h_max + 0.1), [+0.1, +0.3), ≥ +0.3; (seen, found).
    pub rock_bins: [(usize, usize); 3],
    /// Rocks and edge discs by horizontal distance from the camera to their centre, in
    /// [`RANGE_BIN_M`] bins; (seen, found).
    pub rock_ranges: [(usize, usize); RANGE_BINS],
    pub edge_ranges: [(usize, usize); RANGE_BINS],
    pub edges: usize,
    pub edges_found: usize,
    /// Known cells within 5 m whose true window step exceeds h_max, and those detected.
    pub step_cells: usize,
    pub step_cells_found: usize,
    pub clusters: usize,
    /// Clusters matched by the rocks alone, by rocks and edges, by rocks, edges and terrain steps.
    pub clusters_rocks: usize,
    pub clusters_listed: usize,
    pub clusters_any: usize,
    pub classify_ms: Vec<f64>,
    /// SGM disparity minus true disparity (from the rendered depth) of pixels whose true depth is
    /// within the range cutoff: counts in bins of [`DISPARITY_BIN_PX`] over ±[`DISPARITY_SPAN_PX`],
    /// then pixels beyond that span (blunders) and pixels SGM left invalid.
    pub disparity_error_bins: Vec<u64>,
    pub disparity_blunders: u64,
    pub disparity_invalid: u64,
}

impl Tally {
    pub fn add(&mut self, other: &Tally) {
        self.frames += other.frames;
        self.rocks += other.rocks;
        self.rocks_found += other.rocks_found;
        add_pairs(&mut self.rock_bins, &other.rock_bins);
        add_pairs(&mut self.rock_ranges, &other.rock_ranges);
        add_pairs(&mut self.edge_ranges, &other.edge_ranges);
        self.edges += other.edges;
        self.edges_found += other.edges_found;
        self.step_cells += other.step_cells;
        self.step_cells_found += other.step_cells_found;
        self.clusters += other.clusters;
        self.clusters_rocks += other.clusters_rocks;
        self.clusters_listed += other.clusters_listed;
        self.clusters_any += other.clusters_any;
        self.classify_ms.extend_from_slice(&other.classify_ms);
        self.disparity_error_bins.resize(other.disparity_error_bins.len().max(self.disparity_error_bins.len()), 0);
        for (a, b) in self.disparity_error_bins.iter_mut().zip(&other.disparity_error_bins) {
            *a += b;
        }
        self.disparity_blunders += other.disparity_blunders;
        self.disparity_invalid += other.disparity_invalid;
    }

    /// Quantile `q` of the signed disparity error within ±[`DISPARITY_SPAN_PX`] (bin centres).
    pub fn disparity_error_quantile_px(&self, q: f64) -> Option<f64> {
        let total: u64 = self.disparity_error_bins.iter().sum();
        let target = (q * total as f64).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (k, &n) in self.disparity_error_bins.iter().enumerate() {
            seen += n;
            if seen >= target {
                return Some((k as f64 + 0.5) * DISPARITY_BIN_PX - DISPARITY_SPAN_PX);
            }
        }
        None
    }

    pub fn rock_recall(&self) -> Option<f64> {
        ratio(self.rocks_found, self.rocks)
    }

    pub fn edge_recall(&self) -> Option<f64> {
        ratio(self.edges_found, self.edges)
    }

    pub fn step_recall(&self) -> Option<f64> {
        ratio(self.step_cells_found, self.step_cells)
    }

    /// Cluster precision against the listed obstacles only (rocks > h_max, negative edges).
    pub fn precision_listed(&self) -> Option<f64> {
        ratio(self.clusters_listed, self.clusters)
    }

    /// Cluster precision with the true terrain steps in the truth set.
    pub fn precision(&self) -> Option<f64> {
        ratio(self.clusters_any, self.clusters)
    }
}

pub fn ratio(a: usize, b: usize) -> Option<f64> {
    (b > 0).then(|| a as f64 / b as f64)
}

/// A cluster of detected cells that matches no listed obstacle (rock > h_max, negative edge), for
/// the analysis of causes.
#[derive(Debug, Clone)]
pub struct FalseCluster {
    pub centre_m: Point2<f64>,
    pub cells: usize,
    pub camera_distance_m: f64,
    /// Largest measured `h_diff` and threshold `h_max + Δd` over the cluster's cells.
    pub h_diff_m: f32,
    pub threshold_m: f32,
    /// Largest true window step over the cluster's cells.
    pub true_step_m: f32,
    /// Whether a negative-edge top lies in the cluster.
    pub negative_edge: bool,
}

/// Renderer, SGM and classifier for one world, all buffers kept between viewpoints.
#[derive(Debug)]
pub struct Evaluator<'w> {
    world: &'w World,
    truth: &'w Truth,
    config: ObstacleConfig,
    renderer: Renderer,
    /// SGM, the speckle filter and depth: the on-board sequence.
    stereo: DepthPipeline,
    width: usize,
    height: usize,
    left: Vec<u8>,
    right: Vec<u8>,
    classifier: ObstacleClassifier,
    labels: PixelLabels,
    true_height_m: Vec<f32>,
    true_step_m: Vec<f32>,
    pub false_clusters: Vec<FalseCluster>,
    /// Classify the renderer's exact depth instead of SGM's: the classifier's ceiling.
    pub true_depth: bool,
    dumps: usize,
}

impl<'w> Evaluator<'w> {
    pub fn new(world: &'w World, truth: &'w Truth, config: ObstacleConfig) -> Self {
        let camera = world.robots[0].model().camera;
        let speckle = SpeckleFilter::for_image(camera.width_px as usize, camera.height_px as usize);
        Self::with_stereo(world, truth, config, depth_sgm_config(), Some(speckle))
    }

    /// As [`Evaluator::new`] (the on-board depth images) with another stereo configuration.
    pub fn with_stereo(
        world: &'w World,
        truth: &'w Truth,
        config: ObstacleConfig,
        sgm: SgmConfig,
        speckle: Option<SpeckleFilter>,
    ) -> Self {
        let camera = world.robots[0].model().camera;
        let (width, height) = (camera.width_px as usize, camera.height_px as usize);
        let geometry = StereoGeometry {
            fx_px: camera.f_px,
            fy_px: camera.f_px,
            cx_px: camera.cx_px,
            cy_px: camera.cy_px,
            baseline_m: camera.baseline_m,
        };
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let options = DepthOptions { sgm, despeckle: false, threads };
        let mut stereo = DepthPipeline::with_geometry(geometry, width, height, options).unwrap();
        stereo.set_speckle_filter(speckle);
        Evaluator {
            world,
            truth,
            config,
            renderer: Renderer::new(camera, world.scenario.sensor),
            stereo,
            width,
            height,
            left: vec![0; width * height],
            right: vec![0; width * height],
            classifier: ObstacleClassifier::new(config).unwrap(),
            labels: PixelLabels::default(),
            true_height_m: Vec::new(),
            true_step_m: Vec::new(),
            false_clusters: Vec::new(),
            true_depth: false,
            dumps: 0,
        }
    }

    /// The left image of the last viewpoint (for dumps).
    pub fn left_image(&self) -> (&[u8], usize, usize) {
        (&self.left, self.width, self.height)
    }

    pub fn labels(&self) -> &PixelLabels {
        &self.labels
    }

    /// Diagnosis: counts where negative-edge pixels and far-off SGM depths lie in the image and
    /// writes the left image to the temp directory (red: obstacle pixels, blue: SGM depth off by
    /// more than max(0.3 m, 10 %) from the rendered truth).
    pub fn diagnose(&mut self) {
        self.dumps += 1;
        let truth = self.renderer.depth_m();
        let (w, h) = (self.width, self.height);
        let mut near_bins = [[0usize; 4]; 4];
        let mut edge_bins = [[0usize; 4]; 4];
        let mut edge_wrong = 0;
        let mut edge_total = 0;
        for y in 0..h {
            for x in 0..w {
                let i = y * w + x;
                let (z, zt) = (self.stereo.depth().depth_m[i], truth[i]);
                let b = (y * 4 / h, x * 4 / w);
                if z.is_finite() && zt.is_finite() && z < zt - 0.3f32.max(0.1 * zt) {
                    near_bins[b.0][b.1] += 1;
                }
                if self.labels.flags[i] & PixelLabels::NEGATIVE_EDGE != 0 {
                    edge_bins[b.0][b.1] += 1;
                    edge_total += 1;
                    if !(z.is_finite() && zt.is_finite() && (z - zt).abs() < 0.2) {
                        edge_wrong += 1;
                        if edge_wrong < 6 {
                            println!(
                                "   edge px ({x},{y}) sgm {z:.2} true {zt:.2} disp {}",
                                self.stereo.disparity().data[i]
                            );
                        }
                    }
                }
            }
        }
        let mut rgb = Vec::with_capacity(3 * w * h);
        for (((&g, &z), &zt), &flags) in
            self.left.iter().zip(&self.stereo.depth().depth_m).zip(truth).zip(&self.labels.flags)
        {
            let bad = z.is_finite() && zt.is_finite() && (z - zt).abs() > 0.3f32.max(0.1 * zt);
            let obstacle = flags & PixelLabels::OBSTACLE != 0;
            rgb.extend_from_slice(&match (obstacle, bad) {
                (true, _) => [255, 0, 0],
                (false, true) => [g / 2, g / 2, 255],
                _ => [g, g, g],
            });
        }
        let file =
            std::fs::File::create(std::env::temp_dir().join(format!("sim_obstacles_view_{}.png", self.dumps))).unwrap();
        let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), w as u32, h as u32);
        encoder.set_color(png::ColorType::Rgb);
        encoder.write_header().unwrap().write_image_data(&rgb).unwrap();
        println!("  too-near SGM pixels by quarter (rows top→bottom, cols left→right): {near_bins:?}");
        println!("  negative-edge pixels {edge_total}, {edge_wrong} with SGM off by > 0.2 m: {edge_bins:?}");
    }

    /// Renders, matches, classifies and scores one viewpoint into `tally`.
    pub fn evaluate(&mut self, viewpoint: &Viewpoint, noise_seed: u64, tally: &mut Tally) {
        let robot = &self.world.robots[0];
        let t_world_cam = viewpoint.t_world_body * robot.model().t_body_cam(0.0, viewpoint.tilt_rad);
        let scene = self.world.scene(&[]);
        self.renderer.render_stereo(&scene, &t_world_cam, noise_seed, &mut self.left, &mut self.right);
        self.stereo.compute(&self.left, &self.right).unwrap();
        self.measure_disparity_error(tally);
        if self.true_depth {
            self.stereo.depth_mut().depth_m.copy_from_slice(self.renderer.depth_m());
        }
        let start = Instant::now();
        self.classifier.classify(self.stereo.depth(), self.stereo.geometry(), &t_world_cam, &mut self.labels);
        tally.classify_ms.push(start.elapsed().as_secs_f64() * 1e3);
        tally.frames += 1;
        self.score(&t_world_cam, tally);
    }

    /// Adds the SGM disparity error of this frame's pixels to `tally` (truth: the rendered
    /// z-depth, `d = f·b / z`), for pixels whose true depth is within the classifier's range.
    fn measure_disparity_error(&self, tally: &mut Tally) {
        let geometry = self.stereo.geometry();
        let fb = geometry.fx_px * geometry.baseline_m;
        let max_depth_m =
            self.config.error_model(geometry.fx_px, geometry.baseline_m).max_depth_m(self.config.max_depth_error_m);
        let bins = (2.0 * DISPARITY_SPAN_PX / DISPARITY_BIN_PX).round() as usize;
        tally.disparity_error_bins.resize(bins, 0);
        let truth = self.renderer.depth_m();
        for (i, &zt) in truth.iter().enumerate() {
            if !(zt.is_finite() && zt > 0.0 && f64::from(zt) <= max_depth_m) {
                continue;
            }
            let Some(d) = self.stereo.disparity().get_px(i % self.width, i / self.width) else {
                tally.disparity_invalid += 1;
                continue;
            };
            let e = f64::from(d) - fb / f64::from(zt);
            let k = ((e + DISPARITY_SPAN_PX) / DISPARITY_BIN_PX).floor();
            if (0.0..bins as f64).contains(&k) {
                tally.disparity_error_bins[k as usize] += 1;
            } else {
                tally.disparity_blunders += 1;
            }
        }
    }

    fn true_steps(&mut self) {
        let map = self.classifier.height_map();
        let hf = &self.world.terrain.heightfield;
        let side = map.side();
        self.true_height_m.clear();
        self.true_height_m.extend((0..side * side).map(|k| {
            let c = map.centre_m(k);
            hf.height_at(c.x, c.y).map_or(f32::NAN, |z| z as f32)
        }));
        let half = (self.config.window_cells as i64 - 1) / 2;
        let hi = self.config.window_cells as i64 - 1 - half;
        self.true_step_m.clear();
        self.true_step_m.resize(side * side, 0.0);
        let side = side as i64;
        for row in 0..side {
            for col in 0..side {
                let (mut lo_z, mut hi_z) = (f32::INFINITY, f32::NEG_INFINITY);
                for r in (row - half).max(0)..=(row + hi).min(side - 1) {
                    for c in (col - half).max(0)..=(col + hi).min(side - 1) {
                        let z = self.true_height_m[(r * side + c) as usize];
                        lo_z = lo_z.min(z);
                        hi_z = hi_z.max(z);
                    }
                }
                self.true_step_m[(row * side + col) as usize] = (hi_z - lo_z).max(0.0);
            }
        }
    }

    /// The last image's obstacle cells within [`RADIUS_M`] of `cam`, and its height map as a grid.
    fn detections(&self, cam: Point2<f64>) -> (Vec<usize>, HeightGrid) {
        let map = self.classifier.height_map();
        let side = map.side();
        let detected =
            (0..side * side).filter(|&k| map.cells()[k].is_obstacle() && (map.centre_m(k) - cam).norm() <= RADIUS_M);
        let heights: Vec<f32> = map.cells().iter().map(|c| c.height_m).collect();
        let grid =
            HeightGrid::new(map.cell_size_m(), (map.centre_m(0).x, map.centre_m(0).y), side, side, heights).unwrap();
        (detected.collect(), grid)
    }

    /// Whether the last image mapped any of `truth` within [`RADIUS_M`] of the camera, and whether
    /// an obstacle cell matched one of those.
    pub fn observe(&self, t_world_cam: &Isometry3<f64>, truth: &[TrueObstacle]) -> (bool, bool) {
        let cam = Point2::new(t_world_cam.translation.vector.x, t_world_cam.translation.vector.y);
        let near: Vec<TrueObstacle> =
            truth.iter().filter(|o| (o.centre_m - cam).norm() - o.radius_m <= RADIUS_M).copied().collect();
        let (detected, grid) = self.detections(cam);
        let seen = obstacles_in_mapped_area(&near, &grid);
        let map = self.classifier.height_map();
        let found = seen.iter().any(|o| {
            detected.iter().any(|&k| (map.centre_m(k) - o.centre_m).norm() <= o.radius_m + MATCHING.tolerance_m)
        });
        (!seen.is_empty(), found)
    }

    /// Evaluates every frame of `run` into `tally` (frame `i` rendered with noise seed
    /// `noise_seed + i`) and reports whether and from how far the target was detected.
    pub fn drive(&mut self, run: &Approach, noise_seed: u64, tally: &mut Tally) -> RunOutcome {
        let robot = &self.world.robots[0];
        let mut outcome =
            RunOutcome { aim: run.aim, excess_height_m: run.excess_height_m, seen: false, found_at_m: None };
        for (i, (view, distance_m)) in run.frames.iter().enumerate() {
            self.evaluate(view, noise_seed + i as u64, tally);
            let t_world_cam = view.t_world_body * robot.model().t_body_cam(0.0, view.tilt_rad);
            let (seen, found) = self.observe(&t_world_cam, &run.truth);
            outcome.seen |= seen;
            if found {
                outcome.found_at_m.get_or_insert(*distance_m);
            }
        }
        outcome
    }

    fn score(&mut self, t_world_cam: &Isometry3<f64>, tally: &mut Tally) {
        self.true_steps();
        let cfg = self.config;
        let cam = Point2::new(t_world_cam.translation.vector.x, t_world_cam.translation.vector.y);
        let map = self.classifier.height_map();
        let side = map.side();
        let near = |o: &TrueObstacle, r: f64| (o.centre_m - cam).norm() - o.radius_m <= r;
        let (detected, grid) = self.detections(cam);
        let detections: Vec<Point2<f64>> = detected.iter().map(|&k| map.centre_m(k)).collect();
        let found =
            |o: &TrueObstacle| detections.iter().any(|p| (p - o.centre_m).norm() <= o.radius_m + MATCHING.tolerance_m);

        let rocks: Vec<TrueObstacle> = self.truth.rocks.iter().map(|(o, _)| *o).filter(|o| near(o, RADIUS_M)).collect();
        for o in obstacles_in_mapped_area(&rocks, &grid) {
            let height = self.truth.rocks.iter().find(|(r, _)| *r == o).map_or(0.0, |(_, h)| *h);
            let bin = usize::from(height >= cfg.max_step_m + 0.1) + usize::from(height >= cfg.max_step_m + 0.3);
            let hit = found(&o);
            count(&mut tally.rock_ranges[range_bin((o.centre_m - cam).norm())], hit);
            count(&mut tally.rock_bins[bin], hit);
            tally.rocks += 1;
            tally.rocks_found += usize::from(hit);
        }
        let edges: Vec<TrueObstacle> = self.truth.edges.iter().filter(|o| near(o, RADIUS_M)).copied().collect();
        let seen_edges = obstacles_in_mapped_area(&edges, &grid);
        for o in &seen_edges {
            let hit = found(o);
            tally.edges += 1;
            tally.edges_found += usize::from(hit);
            count(&mut tally.edge_ranges[range_bin((o.centre_m - cam).norm())], hit);
        }

        // Terrain steps: true step cells (within 6 m, for matching) as half-cell discs.
        let half_cell = 0.5 * map.cell_size_m();
        let detected_set: HashSet<usize> = detected.iter().copied().collect();
        let reach = (MATCHING.tolerance_m + half_cell) / map.cell_size_m();
        let r_cells = reach.ceil() as i64;
        let mut steps = Vec::new();
        for k in 0..side * side {
            if self.true_step_m[k] <= cfg.max_step_m as f32 {
                continue;
            }
            let centre_m = map.centre_m(k);
            let distance = (centre_m - cam).norm();
            if distance > RADIUS_M + 1.0 {
                continue;
            }
            steps.push(TrueObstacle { centre_m, radius_m: half_cell });
            if distance <= RADIUS_M && map.cells()[k].is_known() {
                tally.step_cells += 1;
                let (col, row) = ((k % side) as i64, (k / side) as i64);
                let hit = (-r_cells..=r_cells).any(|dr| {
                    (-r_cells..=r_cells).any(|dc| {
                        let (r, c) = (row + dr, col + dc);
                        (0..side as i64).contains(&r)
                            && (0..side as i64).contains(&c)
                            && ((dr * dr + dc * dc) as f64) <= reach * reach
                            && detected_set.contains(&((r * side as i64 + c) as usize))
                    })
                });
                tally.step_cells_found += usize::from(hit);
            }
        }

        let rocks_all: Vec<TrueObstacle> =
            self.truth.rocks.iter().map(|(o, _)| *o).filter(|o| near(o, RADIUS_M + 1.0)).collect();
        let mut listed = rocks_all.clone();
        listed.extend(self.truth.edges.iter().filter(|o| near(o, RADIUS_M + 1.0)));
        let mut any = listed.clone();
        any.extend_from_slice(&steps);
        let report = |truth: &[TrueObstacle]| evaluate_obstacles(&detections, truth, &MATCHING).unwrap();
        let by_rocks = report(&rocks_all);
        tally.clusters += by_rocks.clusters;
        tally.clusters_rocks += by_rocks.clusters_matched;
        tally.clusters_listed += report(&listed).clusters_matched;
        tally.clusters_any += report(&any).clusters_matched;

        // Clusters the listed obstacles do not explain, with the numbers that tell their cause.
        let matches =
            |p: &Point2<f64>| listed.iter().any(|o| (p - o.centre_m).norm() <= o.radius_m + MATCHING.tolerance_m);
        let index: HashMap<usize, usize> = detected.iter().enumerate().map(|(i, &k)| (k, i)).collect();
        let mut visited = vec![false; detected.len()];
        for first in 0..detected.len() {
            if visited[first] {
                continue;
            }
            visited[first] = true;
            let mut members = vec![first];
            let mut next = 0;
            while next < members.len() {
                let k = detected[members[next]];
                next += 1;
                let (col, row) = ((k % side) as i64, (k / side) as i64);
                for (dr, dc) in [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)] {
                    let (r, c) = (row + dr, col + dc);
                    if !(0..side as i64).contains(&r) || !(0..side as i64).contains(&c) {
                        continue;
                    }
                    if let Some(&j) = index.get(&((r * side as i64 + c) as usize))
                        && !visited[j]
                    {
                        visited[j] = true;
                        members.push(j);
                    }
                }
            }
            let matched = members.iter().filter(|&&i| matches(&detections[i])).count();
            if 2 * matched >= members.len() {
                continue;
            }
            let n = members.len() as f64;
            let centre_m =
                Point2::from(members.iter().map(|&i| detections[i].coords).sum::<nalgebra::Vector2<f64>>() / n);
            let cells = members.iter().map(|&i| map.cells()[detected[i]]);
            self.false_clusters.push(FalseCluster {
                centre_m,
                cells: members.len(),
                camera_distance_m: (centre_m - cam).norm(),
                h_diff_m: cells.clone().map(|c| c.h_diff_m).fold(0.0, f32::max),
                threshold_m: cells.clone().map(|c| c.threshold_m).fold(0.0, f32::max),
                true_step_m: members.iter().map(|&i| self.true_step_m[detected[i]]).fold(0.0, f32::max),
                negative_edge: cells.clone().any(|c| c.negative_edge),
            });
        }
    }
}

/// What one approach run found: whether the target was ever mapped, and the farthest camera
/// distance at which it was detected.
#[derive(Debug, Clone, Copy)]
pub struct RunOutcome {
    pub aim: Aim,
    pub excess_height_m: f64,
    pub seen: bool,
    pub found_at_m: Option<f64>,
}

/// Selects the runs of one summary line.
type RunFilter = fn(&RunOutcome) -> bool;

fn print_approaches(outcomes: &[RunOutcome], (far_m, near_m): (f64, f64), tilt_rad: Option<f64>) {
    println!(
        "approach runs (camera from {far_m:.1} to {near_m:.1} m, a frame every {APPROACH_STEP_M} m, head tilt {}; found = in at least one frame):",
        tilt_rad.map_or_else(|| "as mounted".to_owned(), |t| format!("{t:.2} rad"))
    );
    let groups: [(&str, RunFilter); 5] = [
        ("rocks", |o: &RunOutcome| o.aim == Aim::Rock),
        ("rocks h_max..+0.1 m", |o: &RunOutcome| o.aim == Aim::Rock && o.excess_height_m < 0.1),
        ("rocks +0.1..+0.3 m", |o: &RunOutcome| o.aim == Aim::Rock && (0.1..0.3).contains(&o.excess_height_m)),
        ("rocks >= +0.3 m", |o: &RunOutcome| o.aim == Aim::Rock && o.excess_height_m >= 0.3),
        ("edge sections", |o: &RunOutcome| o.aim == Aim::Edge),
    ];
    for (name, keep) in &groups {
        let runs: Vec<&RunOutcome> = outcomes.iter().filter(|o| keep(o)).collect();
        let seen: Vec<&&RunOutcome> = runs.iter().filter(|o| o.seen).collect();
        let mut at: Vec<f64> = seen.iter().filter_map(|o| o.found_at_m).collect();
        at.sort_by(f64::total_cmp);
        let by_distance: Vec<String> = approach_distances((far_m, near_m))
            .map(|d| format!("{d:.1} m {}", at.iter().filter(|&&a| a >= d - 1e-9).count()))
            .collect();
        println!(
            "  {name:>20}: {} runs, {} mapped, {} found ({}); found by this distance: {}",
            runs.len(),
            seen.len(),
            at.len(),
            pct(ratio(at.len(), seen.len())),
            by_distance.join(", ")
        );
    }
}

fn pct(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".to_owned(), |v| format!("{:.1} %", 100.0 * v))
}

fn print_row(name: &str, t: &Tally) {
    println!(
        "{name:>6} {:5} | rocks {:4}/{:<4} {:>7} | edge discs {:5}/{:<5} {:>7} | step cells {:>7} | clusters {:4}: rocks {:3}, +edges {:3} ({:>7}), +steps {:3} ({:>7})",
        t.frames,
        t.rocks_found,
        t.rocks,
        pct(t.rock_recall()),
        t.edges_found,
        t.edges,
        pct(t.edge_recall()),
        pct(t.step_recall()),
        t.clusters,
        t.clusters_rocks,
        t.clusters_listed,
        pct(t.precision_listed()),
        t.clusters_any,
        pct(t.precision()),
    );
}

#[allow(dead_code)]
fn main() {
    let mut seeds = 3u64;
    let mut per_target = 3usize;
    let mut open = 20usize;
    let mut size_m = 60.0;
    let mut dump = false;
    let mut diagnose = false;
    let mut true_depth = false;
    let mut approach = false;
    let mut approach_m = APPROACH_M;
    let mut tilt_rad: Option<f64> = None;
    let mut steep_edges = false;
    let mut config = ObstacleConfig::default();
    let mut sgm = depth_sgm_config();
    let mut speckle_px: Option<usize> = None;
    let mut speckle_step_px = 1.0f32;
    let mut args = std::env::args().skip(1);
    while let Some(arg) = args.next() {
        let mut value = || args.next().and_then(|v| v.parse::<f64>().ok()).expect("a number");
        match arg.as_str() {
            "--seeds" => seeds = value() as u64,
            "--per-target" => per_target = value() as usize,
            "--open" => open = value() as usize,
            "--size" => size_m = value(),
            "--pixel-error" => config.pixel_error_px = value(),
            "--support" => config.step_support_cells = value() as usize,
            "--min-cluster" => config.min_step_cluster_cells = value() as usize,
            "--window" => config.window_cells = value() as usize,
            "--uniqueness" => sgm.uniqueness_percent = value() as u8,
            "--lr-diff" => sgm.lr_max_diff = value() as u8,
            "--lr-strict" => sgm.lr_lenient = false,
            "--speckle" => speckle_px = Some(value() as usize),
            "--speckle-step" => speckle_step_px = value() as f32,
            "--dump" => dump = true,
            "--diagnose" => diagnose = true,
            "--true-depth" => true_depth = true,
            "--approach" => approach = true,
            "--approach-to" => approach_m.1 = value(),
            "--tilt" => tilt_rad = Some(value()),
            "--steep-edges" => steep_edges = true,
            other => panic!("unknown argument {other}"),
        }
    }
    config.validate().expect("a valid configuration");
    println!(
        "SGM: uniqueness {} %, LR max diff {} px, lenient {}; speckle filter {} px within {speckle_step_px} px (0 = off)",
        sgm.uniqueness_percent,
        sgm.lr_max_diff,
        sgm.lr_lenient,
        speckle_px.map_or_else(|| "400 (at 1024x508, scaled)".to_string(), |px| px.to_string())
    );
    println!(
        "obstacles, Moon preset {size_m} m worlds: h_max {:.2} m, slope {:.0}°, window {} cells, support {}, min cluster {}, Δp {} px; {per_target} viewpoints per target at {DISTANCES_M:?} m, {open} open viewpoints per seed",
        config.max_step_m,
        config.max_slope_rad.to_degrees(),
        config.window_cells,
        config.step_support_cells,
        config.min_step_cluster_cells,
        config.pixel_error_px
    );
    let mut totals = [Tally::default(), Tally::default(), Tally::default()];
    let mut false_clusters = Vec::new();
    let mut outcomes: Vec<RunOutcome> = Vec::new();
    for seed in 1..=seeds {
        let world = moon_world(seed, size_m);
        let mut truth = Truth::of(&world, config.max_step_m);
        if steep_edges {
            truth.keep_steep_edges(&world, config.max_step_m, config.max_slope_rad);
        }
        let tilt_rad = tilt_rad.unwrap_or(world.robots[0].setup.tilt_rad);
        let mut views = viewpoints(&world, &truth, per_target, open, seed);
        for view in &mut views {
            view.tilt_rad = tilt_rad;
        }
        let camera = world.robots[0].model().camera;
        let speckle = match speckle_px {
            None => Some(SpeckleFilter::for_image(camera.width_px as usize, camera.height_px as usize)),
            Some(0) => None,
            Some(px) => Some(SpeckleFilter::new(px, speckle_step_px)),
        };
        let mut evaluator = Evaluator::with_stereo(&world, &truth, config, sgm, speckle);
        evaluator.true_depth = true_depth;
        let mut tallies = [Tally::default(), Tally::default(), Tally::default()];
        if approach {
            let runs = approaches(&world, &truth, config.max_step_m, approach_m, tilt_rad, seed);
            for (r, run) in runs.iter().enumerate() {
                let outcome = evaluator.drive(run, seed * 1_000_003 + (r * 64) as u64, &mut tallies[run.aim as usize]);
                if diagnose && run.aim == Aim::Edge && outcome.found_at_m.is_none() {
                    let t = run.truth.first().map_or(Point2::origin(), |o| o.centre_m);
                    println!("edge run {r} missed, target ({:.2}, {:.2}), last frame:", t.x, t.y);
                    evaluator.diagnose();
                }
                outcomes.push(outcome);
            }
            println!("seed {seed}: {} approach runs", runs.len());
        } else {
            for (i, view) in views.iter().enumerate() {
                let slot = view.aim as usize;
                evaluator.evaluate(view, seed * 1_000_003 + i as u64, &mut tallies[slot]);
                if diagnose && i % 20 == 0 {
                    println!("viewpoint {i} {:?}", view.aim);
                    evaluator.diagnose();
                }
            }
            println!("seed {seed}: {} viewpoints", views.len());
        }
        println!("seed {seed}: {} rocks > h_max, {} edge targets", truth.rocks.len(), truth.edge_targets.len());
        for (name, t) in ["rock", "edge", "open"].iter().zip(&tallies) {
            print_row(name, t);
        }
        for (total, t) in totals.iter_mut().zip(&tallies) {
            total.add(t);
        }
        false_clusters.extend(evaluator.false_clusters.drain(..).map(|c| (seed, c)));
    }
    println!("all seeds:");
    let mut all = Tally::default();
    for (name, t) in ["rock", "edge", "open"].iter().zip(&totals) {
        print_row(name, t);
        all.add(t);
    }
    print_row("all", &all);
    let names = ["h_max..+0.1 m", "+0.1..+0.3 m", ">= +0.3 m"];
    for (name, (seen, found)) in names.iter().zip(&all.rock_bins) {
        println!("  rocks {name:>14}: {found}/{seen} found ({})", pct(ratio(*found, *seen)));
    }
    for (name, bins) in [("rocks", &all.rock_ranges), ("edge discs", &all.edge_ranges)] {
        let cells: Vec<String> = bins
            .iter()
            .enumerate()
            .map(|(k, (seen, found))| {
                let lo = k as f64 * RANGE_BIN_M;
                format!("{lo:.0}-{:.0} m {found}/{seen} {}", lo + RANGE_BIN_M, pct(ratio(*found, *seen)))
            })
            .collect();
        println!("  {name} by camera distance: {}", cells.join(", "));
    }
    if approach {
        print_approaches(&outcomes, approach_m, tilt_rad);
    }
    let real = false_clusters.iter().filter(|(_, c)| c.true_step_m > config.max_step_m as f32).count();
    println!(
        "clusters off the listed obstacles: {} ({} on a true step > h_max, the rest stereo artefacts)",
        false_clusters.len(),
        real
    );
    if dump {
        for (seed, c) in &false_clusters {
            println!(
                "  seed {seed} at ({:7.2}, {:7.2}) {:3} cells, {:.2} m from camera: h_diff {:.3} > {:.3}, true step {:.3}{}",
                c.centre_m.x,
                c.centre_m.y,
                c.cells,
                c.camera_distance_m,
                c.h_diff_m,
                c.threshold_m,
                c.true_step_m,
                if c.negative_edge { ", negative edge" } else { "" }
            );
        }
    }
    let inliers: u64 = all.disparity_error_bins.iter().sum();
    let total = inliers + all.disparity_blunders + all.disparity_invalid;
    let q = |q: f64| all.disparity_error_quantile_px(q).unwrap_or(f64::NAN);
    let (p16, p50, p84) = (q(0.1587), q(0.5), q(0.8413));
    let mad = {
        let mut dev: Vec<(f64, u64)> = all
            .disparity_error_bins
            .iter()
            .enumerate()
            .map(|(k, &n)| (((k as f64 + 0.5) * DISPARITY_BIN_PX - DISPARITY_SPAN_PX - p50).abs(), n))
            .collect();
        dev.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut seen = 0;
        dev.iter()
            .find(|(_, n)| {
                seen += n;
                2 * seen >= inliers
            })
            .map_or(f64::NAN, |(d, _)| *d)
    };
    println!(
        "SGM disparity error vs rendered truth (true depth <= range cutoff, {total} px): {:.2} % invalid, {:.2} % off by > {DISPARITY_SPAN_PX} px; within: median {p50:+.2} px, 15.9/84.1 % quantiles {p16:+.2}/{p84:+.2} px (half-width {:.2} px), 1.4826·MAD {:.2} px, 2.3/97.7 % {:+.2}/{:+.2} px, 0.1/99.9 % {:+.2}/{:+.2} px",
        100.0 * all.disparity_invalid as f64 / total.max(1) as f64,
        100.0 * all.disparity_blunders as f64 / total.max(1) as f64,
        0.5 * (p84 - p16),
        1.4826 * mad,
        q(0.0228),
        q(0.9772),
        q(0.001),
        q(0.999),
    );
    let mut ms = all.classify_ms.clone();
    ms.sort_by(f64::total_cmp);
    if let Some(median) = ms.get(ms.len() / 2) {
        println!("classify: median {median:.1} ms per 1024x508 depth image (this process, not the benchmark)");
    }
}
