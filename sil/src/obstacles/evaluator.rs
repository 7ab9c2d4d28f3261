//! The evaluator: renders a viewpoint's stereo pair, matches it with the on-board stereo,
//! classifies the depth with the ground-truth camera pose and scores the obstacle cells.

use std::collections::{HashMap, HashSet};
use std::time::Instant;

use eval::map::{HeightGrid, TrueObstacle, evaluate_obstacles, obstacles_in_mapped_area};
use fpga_model::SgmConfig;
use nalgebra::{Isometry3, Point2};
use sim::pictures::Image;
use sim::render::Renderer;
use sim::world::World;
use vision::obstacles::{ObstacleClassifier, ObstacleConfig, PixelLabels};
use vision::{DepthOptions, DepthPipeline, SpeckleFilter, StereoGeometry, depth_sgm_config};

use super::tally::{count, range_bin};
use super::{
    Approach, DISPARITY_BIN_PX, DISPARITY_SPAN_PX, EvaluationError, FalseCluster, MATCHING, RADIUS_M, RunOutcome,
    Tally, Truth, Viewpoint,
};

/// The stereo of the world's first robot's camera as the vision process runs it (SGM with
/// `sgm`, then `speckle`, then depth), on all cores.
pub(super) fn stereo_pipeline(
    world: &World,
    sgm: SgmConfig,
    speckle: Option<SpeckleFilter>,
) -> Result<DepthPipeline, EvaluationError> {
    let camera = world.robots[0].model().camera;
    let geometry = StereoGeometry {
        fx_px: camera.f_px,
        fy_px: camera.f_px,
        cx_px: camera.cx_px,
        cy_px: camera.cy_px,
        baseline_m: camera.baseline_m,
    };
    let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    let options = DepthOptions { sgm, despeckle: false, threads };
    let mut stereo =
        DepthPipeline::with_geometry(geometry, camera.width_px as usize, camera.height_px as usize, options)?;
    stereo.set_speckle_filter(speckle);
    Ok(stereo)
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
    /// The clusters off the listed obstacles found so far (drained by the caller).
    pub false_clusters: Vec<FalseCluster>,
    /// Classify the renderer's exact depth instead of SGM's: the classifier's ceiling.
    pub true_depth: bool,
}

impl<'w> Evaluator<'w> {
    /// An evaluator for the world's first robot with the on-board depth images (SGM
    /// configuration, speckle filter); fails when the classifier refuses `config` or SGM the
    /// camera's image size.
    pub fn new(world: &'w World, truth: &'w Truth, config: ObstacleConfig) -> Result<Self, EvaluationError> {
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
    ) -> Result<Self, EvaluationError> {
        let camera = world.robots[0].model().camera;
        let (width, height) = (camera.width_px as usize, camera.height_px as usize);
        let stereo = stereo_pipeline(world, sgm, speckle)?;
        Ok(Evaluator {
            world,
            truth,
            config,
            renderer: Renderer::new(camera, world.scenario.sensor),
            stereo,
            width,
            height,
            left: vec![0; width * height],
            right: vec![0; width * height],
            classifier: ObstacleClassifier::new(config)?,
            labels: PixelLabels::default(),
            true_height_m: Vec::new(),
            true_step_m: Vec::new(),
            false_clusters: Vec::new(),
            true_depth: false,
        })
    }

    /// The left image of the last viewpoint (for dumps).
    pub fn left_image(&self) -> (&[u8], usize, usize) {
        (&self.left, self.width, self.height)
    }

    /// The pixel labels of the last viewpoint.
    pub fn labels(&self) -> &PixelLabels {
        &self.labels
    }

    /// Diagnosis of the last viewpoint: counts where negative-edge pixels and far-off SGM depths
    /// lie in the image, and the left image marked (red: obstacle pixels, blue: SGM depth off by
    /// more than max(0.3 m, 10 %) from the rendered truth).
    pub fn diagnose(&self) -> Diagnosis {
        let truth = self.renderer.depth_m();
        let (w, h) = (self.width, self.height);
        let mut near_bins = [[0usize; 4]; 4];
        let mut edge_bins = [[0usize; 4]; 4];
        let mut edge_wrong = 0;
        let mut edge_total = 0;
        let mut edge_samples = Vec::new();
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
                            edge_samples.push(EdgeSample {
                                x,
                                y,
                                depth_m: z,
                                true_depth_m: zt,
                                disparity: self.stereo.disparity().data[i],
                            });
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
        let image = Image { width: w as u32, height: h as u32, channels: 3, pixels: rgb };
        Diagnosis { near_bins, edge_bins, edge_total, edge_wrong, edge_samples, image }
    }

    /// Renders, matches, classifies and scores one viewpoint into `tally`.
    pub fn evaluate(
        &mut self,
        viewpoint: &Viewpoint,
        noise_seed: u64,
        tally: &mut Tally,
    ) -> Result<(), EvaluationError> {
        let robot = &self.world.robots[0];
        let t_world_cam = viewpoint.t_world_body * robot.model().t_body_cam(0.0, viewpoint.tilt_rad);
        let scene = self.world.scene(&[]);
        self.renderer.render_stereo(&scene, &t_world_cam, noise_seed, &mut self.left, &mut self.right);
        self.stereo.compute(&self.left, &self.right)?;
        self.measure_disparity_error(tally);
        if self.true_depth {
            self.stereo.depth_mut().depth_m.copy_from_slice(self.renderer.depth_m());
        }
        let start = Instant::now();
        self.classifier.classify(self.stereo.depth(), self.stereo.geometry(), &t_world_cam, &mut self.labels);
        tally.classify_ms.push(start.elapsed().as_secs_f64() * 1e3);
        tally.frames += 1;
        self.score(&t_world_cam, tally)
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

    /// The true window step of every cell of the classifier's lattice (see the module docs).
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
    fn detections(&self, cam: Point2<f64>) -> Result<(Vec<usize>, HeightGrid), EvaluationError> {
        let map = self.classifier.height_map();
        let side = map.side();
        let detected =
            (0..side * side).filter(|&k| map.cells()[k].is_obstacle() && (map.centre_m(k) - cam).norm() <= RADIUS_M);
        let heights: Vec<f32> = map.cells().iter().map(|c| c.height_m).collect();
        let grid = HeightGrid::new(map.cell_size_m(), (map.centre_m(0).x, map.centre_m(0).y), side, side, heights)?;
        Ok((detected.collect(), grid))
    }

    /// Whether the last image mapped any of `truth` within [`RADIUS_M`] of the camera, and whether
    /// an obstacle cell matched one of those.
    pub fn observe(
        &self,
        t_world_cam: &Isometry3<f64>,
        truth: &[TrueObstacle],
    ) -> Result<(bool, bool), EvaluationError> {
        let cam = Point2::new(t_world_cam.translation.vector.x, t_world_cam.translation.vector.y);
        let near: Vec<TrueObstacle> =
            truth.iter().filter(|o| (o.centre_m - cam).norm() - o.radius_m <= RADIUS_M).copied().collect();
        let (detected, grid) = self.detections(cam)?;
        let seen = obstacles_in_mapped_area(&near, &grid);
        let map = self.classifier.height_map();
        let found = seen.iter().any(|o| {
            detected.iter().any(|&k| (map.centre_m(k) - o.centre_m).norm() <= o.radius_m + MATCHING.tolerance_m)
        });
        Ok((!seen.is_empty(), found))
    }

    /// Evaluates every frame of `run` into `tally` (frame `i` rendered with noise seed
    /// `noise_seed + i`) and reports whether and from how far the target was detected.
    pub fn drive(&mut self, run: &Approach, noise_seed: u64, tally: &mut Tally) -> Result<RunOutcome, EvaluationError> {
        let robot = &self.world.robots[0];
        let mut outcome =
            RunOutcome { aim: run.aim, excess_height_m: run.excess_height_m, seen: false, found_at_m: None };
        for (i, (view, distance_m)) in run.frames.iter().enumerate() {
            self.evaluate(view, noise_seed + i as u64, tally)?;
            let t_world_cam = view.t_world_body * robot.model().t_body_cam(0.0, view.tilt_rad);
            let (seen, found) = self.observe(&t_world_cam, &run.truth)?;
            outcome.seen |= seen;
            if found {
                outcome.found_at_m.get_or_insert(*distance_m);
            }
        }
        Ok(outcome)
    }

    /// Scores the last image's obstacle cells against the truth into `tally` and collects the
    /// clusters off the listed obstacles.
    fn score(&mut self, t_world_cam: &Isometry3<f64>, tally: &mut Tally) -> Result<(), EvaluationError> {
        self.true_steps();
        let cfg = self.config;
        let cam = Point2::new(t_world_cam.translation.vector.x, t_world_cam.translation.vector.y);
        let map = self.classifier.height_map();
        let side = map.side();
        let near = |o: &TrueObstacle, r: f64| (o.centre_m - cam).norm() - o.radius_m <= r;
        let (detected, grid) = self.detections(cam)?;
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
        let report = |truth: &[TrueObstacle]| evaluate_obstacles(&detections, truth, &MATCHING);
        let by_rocks = report(&rocks_all)?;
        tally.clusters += by_rocks.clusters;
        tally.clusters_rocks += by_rocks.clusters_matched;
        tally.clusters_listed += report(&listed)?.clusters_matched;
        tally.clusters_any += report(&any)?.clusters_matched;

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
        Ok(())
    }
}

/// What [`Evaluator::diagnose`] found in the last viewpoint.
#[derive(Debug, Clone)]
pub struct Diagnosis {
    /// SGM pixels nearer than the rendered truth by more than max(0.3 m, 10 %), by image quarter
    /// (rows top→bottom, cols left→right).
    pub near_bins: [[usize; 4]; 4],
    /// Negative-edge pixels by image quarter.
    pub edge_bins: [[usize; 4]; 4],
    /// Negative-edge pixels.
    pub edge_total: usize,
    /// Negative-edge pixels whose SGM depth is not within 0.2 m of the rendered truth.
    pub edge_wrong: usize,
    /// The first five of those.
    pub edge_samples: Vec<EdgeSample>,
    /// The left image, RGB: red obstacle pixels, blue where SGM is off by more than
    /// max(0.3 m, 10 %).
    pub image: Image,
}

/// A negative-edge pixel with a wrong SGM depth.
#[derive(Debug, Clone, Copy)]
pub struct EdgeSample {
    /// Column.
    pub x: usize,
    /// Row.
    pub y: usize,
    /// SGM depth.
    pub depth_m: f32,
    /// Rendered depth.
    pub true_depth_m: f32,
    /// The raw fixed-point SGM disparity.
    pub disparity: u16,
}
