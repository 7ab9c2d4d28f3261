//! Obstacle classification on depth images (thesis §5.1.1).
//!
//! Order as in the thesis, both steps before any aggregation because both need the camera's
//! viewpoint: negative edges straight in the depth image ([`negative_edges`]), then the
//! stereo-error-adaptive step test on a 5 cm gravity-aligned height map ([`height_map`], with
//! [`stereo_error`]). [`ObstacleClassifier`] runs both on one depth image and labels its
//! pixels; [`local_map::LocalObstacleMap`] low-passes the cells over time for the planner.
//!
//! **Labels on pixels (spec trap 15).** A step is found per cell, but both the cells on top of
//! a step and those at its foot (within half a window) get the verdict. A pixel is labelled
//! [`PixelLabels::OBSTACLE`] when its cell is a step cell **and** its point lies more than
//! `h_max / 2` above the lowest cell of that cell's window: the rock's upper part and the cliff's
//! upper rim are obstacle points, the ground at their foot is not. The submap matcher takes its
//! keypoints from obstacle points, so labelling the foot would spread them onto flat ground.
//! Negative-edge tops are obstacle pixels too (also flagged [`PixelLabels::NEGATIVE_EDGE`]).
//!
//! **Step support.** The thesis's `h_diff` is max − min over the window; on SGM depth one cell
//! mean pulled by a blunder patch then makes a step. We take the window's second-highest and
//! second-lowest cells instead (`ObstacleConfig::step_support_cells`): a real step has many
//! cells on both sides.
//!
//! **Edge support.** A negative-edge top is kept only within an 8-connected group of at least
//! `min_edge_pixels` tops. On simulated Moon views most single-pair "cliffs" were SGM blunders
//! beside good pixels (the blunder floats above the ground and looks exactly like a rim); they
//! made more than half of the false obstacle clusters. A real rim is a line across many columns.

pub mod config;
pub mod height_map;
pub mod local_map;
pub mod negative_edges;
pub mod stereo_error;

use nalgebra::{Isometry3, Vector3};

pub use config::{ObstacleConfig, ObstacleConfigError};
pub use height_map::{HeightCell, HeightMap};
pub use local_map::LocalObstacleMap;
pub use stereo_error::StereoErrorModel;

use crate::depth::{DepthImage, StereoGeometry};
use negative_edges::{EdgePixel, Top};

/// Per-pixel classification result of one depth image, row-major like the depth image.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PixelLabels {
    pub width: usize,
    pub height: usize,
    /// Bit flags per pixel, see [`PixelLabels::OBSTACLE`] and friends.
    pub flags: Vec<u8>,
}

impl PixelLabels {
    /// The pixel's 3D point is part of an untraversable obstacle (step or cliff).
    pub const OBSTACLE: u8 = 1;
    /// The pixel is the top of a negative edge (cliff) that exceeds the slope limit.
    pub const NEGATIVE_EDGE: u8 = 2;
    /// The pixel's point lies beyond the stereo-error range cutoff (not mapped).
    pub const TOO_FAR: u8 = 4;

    pub fn is_obstacle(&self, x: usize, y: usize) -> bool {
        self.flags.get(y * self.width + x).is_some_and(|f| f & Self::OBSTACLE != 0)
    }
}

/// Counts of one classification.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct ObstacleStats {
    /// Pixels with a finite depth within the range cutoff (in the height map).
    pub mapped_pixels: usize,
    pub too_far_pixels: usize,
    /// Finite pixels dropped by the 2.5D consistency test (see [`ObstacleClassifier`]).
    pub inconsistent_pixels: usize,
    pub known_cells: usize,
    pub step_cells: usize,
    pub negative_edge_pixels: usize,
    pub obstacle_pixels: usize,
}

/// Runs the classification, keeping every buffer between images.
///
/// Before anything else, each column is checked for 2.5D consistency: on a height field seen
/// from above (small roll, as the column-wise edge scan already assumes), a pixel higher in a
/// column cannot see ground nearer (horizontally) than a pixel below it. Points that do, by more
/// than twice their stereo error, are SGM mismatches (on the simulated Moon: the black sky,
/// matched to a few metres) and are dropped; without this they float above the ground and make
/// steps everywhere. Overhangs are lost too, which the 2.5D map cannot represent anyway.
#[derive(Debug, Clone)]
pub struct ObstacleClassifier {
    config: ObstacleConfig,
    map: HeightMap,
    /// Per pixel: flat height-map index (`u32::MAX` = none) and local height of its point.
    pixel_cell: Vec<u32>,
    pixel_z_m: Vec<f32>,
    /// Per column, walking upwards: the nearest valid pixel below the current row and the
    /// unmatched pixels since (the negative-edge test's lower partner).
    below: Vec<Below>,
    /// Per column: the farthest horizontal reach (less 2σ) seen so far, walking upwards.
    column_reach_m: Vec<f64>,
    /// Negative-edge tops of this image: (pixel, cell, traversability).
    /// (pixel, cell, traversability, from the measured-slope rule).
    edge_tops: Vec<(usize, Option<usize>, f32, bool)>,
    /// Per pixel: 1 + index into `edge_tops` (0 = none); scratch of the support test.
    edge_index: Vec<u32>,
    /// Per edge top: kept after the support test; and the flood-fill stack.
    edge_keep: Vec<bool>,
    edge_visited: Vec<bool>,
    edge_stack: Vec<usize>,
    edge_group: Vec<usize>,
}

const NO_CELL: u32 = u32::MAX;

/// The negative-edge test's lower partner in one column (see [`ObstacleClassifier::below`]).
#[derive(Debug, Clone, Copy, Default)]
struct Below {
    pixel: EdgePixel,
    index: usize,
    gap_px: usize,
}

impl ObstacleClassifier {
    pub fn new(config: ObstacleConfig) -> Result<Self, ObstacleConfigError> {
        config.validate()?;
        Ok(ObstacleClassifier {
            config,
            map: HeightMap::default(),
            pixel_cell: Vec::new(),
            pixel_z_m: Vec::new(),
            below: Vec::new(),
            column_reach_m: Vec::new(),
            edge_tops: Vec::new(),
            edge_index: Vec::new(),
            edge_keep: Vec::new(),
            edge_visited: Vec::new(),
            edge_stack: Vec::new(),
            edge_group: Vec::new(),
        })
    }

    pub fn config(&self) -> &ObstacleConfig {
        &self.config
    }

    /// The height map of the last image: cells, their step verdicts and obstacle centres in the
    /// local frame.
    pub fn height_map(&self) -> &HeightMap {
        &self.map
    }

    /// Classifies one depth image taken from `t_local_cam` (gravity-aligned local frame, z up)
    /// and writes the labels (resized to the image).
    pub fn classify(
        &mut self,
        depth: &DepthImage,
        geometry: &StereoGeometry,
        t_local_cam: &Isometry3<f64>,
        labels: &mut PixelLabels,
    ) -> ObstacleStats {
        let (w, h) = (depth.width, depth.height);
        let n = w * h;
        let cfg = self.config;
        let model = cfg.error_model(geometry.fx_px, geometry.baseline_m);
        let max_depth_m = model.max_depth_m(cfg.max_depth_error_m) as f32;
        labels.width = w;
        labels.height = h;
        labels.flags.clear();
        labels.flags.resize(n, 0);
        self.pixel_cell.clear();
        self.pixel_cell.resize(n, NO_CELL);
        self.pixel_z_m.clear();
        self.pixel_z_m.resize(n, f32::NAN);
        self.below.clear();
        self.below.resize(w, Below::default());
        self.edge_tops.clear();
        let t = t_local_cam.translation.vector;
        self.map.reset(cfg.cell_size_m, cfg.map_half_extent_m, [t.x, t.y]);
        let rotation = t_local_cam.rotation.to_rotation_matrix();
        let max_slope = cfg.max_slope_rad.tan();
        let mut stats = ObstacleStats::default();

        self.column_reach_m.clear();
        self.column_reach_m.resize(w, f64::NEG_INFINITY);
        // Bottom row first: the 2.5D consistency test walks each column upwards. The edge test
        // pairs each valid pixel with the nearest valid one below it (across at most
        // `bridge_invalid_px` unmatched pixels), so that one is already known.
        let rows = h.min(depth.depth_m.len() / w.max(1));
        for y in (0..rows).rev() {
            let ray_y = (y as f64 - geometry.cy_px) / geometry.fy_px;
            for x in 0..w {
                let i = y * w + x;
                let z = depth.depth_m[i];
                let ray_cam = Vector3::new((x as f64 - geometry.cx_px) / geometry.fx_px, ray_y, 1.0);
                let pixel = if z.is_nan() || z <= 0.0 {
                    EdgePixel::Invalid
                } else if z.is_infinite() {
                    self.column_reach_m[x] = f64::INFINITY;
                    let r = rotation * ray_cam;
                    EdgePixel::Infinite { ray_local: [r.x, r.y, r.z] }
                } else {
                    let p = rotation * (ray_cam * f64::from(z)) + t;
                    let reach_m = (p.x - t.x).hypot(p.y - t.y);
                    let sigma_m = model.depth_error_m(f64::from(z)) * reach_m / f64::from(z);
                    if reach_m + 2.0 * sigma_m < self.column_reach_m[x] {
                        // Nearer than ground already seen lower in this column: impossible on
                        // a 2.5D surface, an SGM mismatch (typically on a black sky).
                        stats.inconsistent_pixels += 1;
                        EdgePixel::Invalid
                    } else {
                        self.column_reach_m[x] = self.column_reach_m[x].max(reach_m - 2.0 * sigma_m);
                        if z > max_depth_m {
                            labels.flags[i] |= PixelLabels::TOO_FAR;
                            stats.too_far_pixels += 1;
                        } else if let Some(cell) = self.map.index_of(p.x, p.y) {
                            self.map.add_point(cell, p.z);
                            self.pixel_cell[i] = cell as u32;
                            self.pixel_z_m[i] = p.z as f32;
                            stats.mapped_pixels += 1;
                        }
                        EdgePixel::Finite { depth_m: z, p_local: [p.x, p.y, p.z] }
                    }
                };
                let below = self.below[x];
                if pixel == EdgePixel::Invalid {
                    self.below[x].gap_px += 1;
                    continue;
                }
                self.below[x] = Below { pixel, index: i, gap_px: 0 };
                if below.gap_px > cfg.bridge_invalid_px {
                    continue;
                }
                let steep = negative_edges::test_pair(&pixel, &below.pixel, cfg.edge_jump_m)
                    .filter(|&(_, s_min)| s_min > max_slope)
                    .map(|(top, s_min)| (top, s_min / max_slope, true));
                let verdict = steep.or_else(|| {
                    let min_drop = |far_depth_m: f32| {
                        cfg.max_step_m.max(cfg.hidden_drop_m) + model.depth_error_m(f64::from(far_depth_m))
                    };
                    (cfg.hidden_drop_m > 0.0)
                        .then(|| {
                            negative_edges::hidden_drop(&pixel, &below.pixel, cfg.edge_jump_m, [t.x, t.y], min_drop)
                        })
                        .flatten()
                        .map(|drop| (Top::Lower, drop / cfg.max_step_m, false))
                });
                let verdict = verdict.or_else(|| {
                    (below.gap_px > 0)
                        .then(|| negative_edges::unseen_gap(&pixel, &below.pixel, [t.x, t.y]))
                        .flatten()
                        .filter(|&gap_m| gap_m > cfg.max_unseen_gap_m)
                        .map(|gap_m| (Top::Lower, gap_m / cfg.max_unseen_gap_m, false))
                });
                let Some((top, traversability, measured)) = verdict else {
                    continue;
                };
                let (top_pixel, top_point) = match top {
                    Top::Upper => (i, pixel),
                    Top::Lower => (below.index, below.pixel),
                };
                if let EdgePixel::Finite { depth_m, p_local } = top_point
                    && depth_m <= max_depth_m
                {
                    let traversability = traversability.min(f64::from(f32::MAX)) as f32;
                    self.edge_tops.push((
                        top_pixel,
                        self.map.index_of(p_local[0], p_local[1]),
                        traversability,
                        measured,
                    ));
                }
            }
        }

        let t_cam_local = t_local_cam.inverse();
        stats.step_cells = self.map.classify_steps(
            cfg.min_points_per_cell,
            cfg.window_cells,
            cfg.step_support_cells,
            cfg.max_step_m,
            &model,
            &t_cam_local,
        );
        if cfg.min_step_cluster_cells > 1 {
            stats.step_cells = self.map.drop_small_step_clusters(cfg.min_step_cluster_cells);
        }
        stats.known_cells = self.map.cells().iter().filter(|c| c.is_known()).count();
        self.support_edges(w, n);
        for (&(pixel, cell, traversability, measured), _) in
            self.edge_tops.iter().zip(&self.edge_keep).filter(|(_, k)| **k)
        {
            labels.flags[pixel] |= PixelLabels::NEGATIVE_EDGE | PixelLabels::OBSTACLE;
            if let Some(cell) = cell {
                self.map.mark_negative_edge(cell, traversability, measured);
            }
        }
        stats.negative_edge_pixels = self.edge_keep.iter().filter(|&&k| k).count();
        let half_step = (0.5 * cfg.max_step_m) as f32;
        for ((flag, &cell), &z) in labels.flags.iter_mut().zip(&self.pixel_cell).zip(&self.pixel_z_m) {
            if cell == NO_CELL {
                continue;
            }
            let c = self.map.cell(cell as usize);
            if c.step && z > c.window_min_m + half_step {
                *flag |= PixelLabels::OBSTACLE;
            }
        }
        stats.obstacle_pixels = labels.flags.iter().filter(|&&f| f & PixelLabels::OBSTACLE != 0).count();
        stats
    }

    /// Keeps the negative-edge tops that belong to an 8-connected group of at least
    /// `min_edge_pixels` tops: a cliff's rim is a line across the image, while an SGM blunder
    /// next to a good pixel (a jump with a floating "top") is one pixel or a short fragment.
    fn support_edges(&mut self, w: usize, n: usize) {
        let min = self.config.min_edge_pixels;
        self.edge_keep.clear();
        self.edge_keep.resize(self.edge_tops.len(), false);
        self.edge_index.clear();
        self.edge_index.resize(n, 0);
        for (k, &(pixel, ..)) in self.edge_tops.iter().enumerate() {
            self.edge_index[pixel] = k as u32 + 1;
        }
        let visited = &mut self.edge_visited;
        visited.clear();
        visited.resize(self.edge_tops.len(), false);
        for first in 0..self.edge_tops.len() {
            if visited[first] {
                continue;
            }
            visited[first] = true;
            self.edge_group.clear();
            self.edge_stack.clear();
            self.edge_stack.push(first);
            while let Some(k) = self.edge_stack.pop() {
                self.edge_group.push(k);
                let pixel = self.edge_tops[k].0;
                let (x, y) = ((pixel % w) as i64, (pixel / w) as i64);
                for (dx, dy) in [(-1, -1), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w as i64 {
                        continue;
                    }
                    let j = (ny * w as i64 + nx) as usize;
                    if let Some(&e) = self.edge_index.get(j)
                        && e != 0
                        && !visited[e as usize - 1]
                    {
                        visited[e as usize - 1] = true;
                        self.edge_stack.push(e as usize - 1);
                    }
                }
            }
            if self.edge_group.len() >= min {
                for &k in &self.edge_group {
                    self.edge_keep[k] = true;
                }
            }
        }
    }

    /// The local-frame point of pixel `i` of the last image's height map, if it was mapped (for
    /// callers that carry labels onto points).
    pub fn pixel_height_m(&self, i: usize) -> Option<f32> {
        self.pixel_z_m.get(i).copied().filter(|z| !z.is_nan())
    }
}
