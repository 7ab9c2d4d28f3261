//! The gravity-aligned 2.5D height map of one depth image: mean height per cell, then the step
//! test per cell (thesis §5.1.1, eqs. 5.3–5.6).
//!
//! Cells are aligned to global multiples of the cell size in the local frame (cell `(i, j)`
//! covers `[i·r, (i+1)·r) × [j·r, (j+1)·r)`), so that maps of successive images and the rolling
//! local map share one lattice.

use nalgebra::{Isometry3, Point2, Point3};

use super::stereo_error::StereoErrorModel;

/// One cell of the height map after classification.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeightCell {
    /// Mean height of the cell's points in the local frame; NaN when the cell has too few.
    pub height_m: f32,
    pub points: u32,
    /// Largest height difference in the step window centred here.
    pub h_diff_m: f32,
    /// Lowest mean height in the window: the pixel rule compares points against it.
    pub window_min_m: f32,
    /// `h_max + Δd` of the window's two extreme cells.
    pub threshold_m: f32,
    /// `h_diff / (h_max + Δd)`, or for a negative-edge top `s_min / tan(max slope)` if larger;
    /// above 1 is untraversable.
    pub traversability: f32,
    /// `h_diff > h_max + Δd`.
    pub step: bool,
    /// A negative-edge top point lies in this cell.
    pub negative_edge: bool,
    /// One of them from the measured-slope rule (the thesis's); otherwise only the hidden-drop
    /// or unseen-gap rules marked it, for ground they did not see.
    pub edge_measured: bool,
}

impl HeightCell {
    const EMPTY: HeightCell = HeightCell {
        height_m: f32::NAN,
        points: 0,
        h_diff_m: 0.0,
        window_min_m: f32::NAN,
        threshold_m: 0.0,
        traversability: 0.0,
        step: false,
        negative_edge: false,
        edge_measured: false,
    };

    pub fn is_known(&self) -> bool {
        !self.height_m.is_nan()
    }

    pub fn is_obstacle(&self) -> bool {
        self.step || self.negative_edge
    }
}

/// A square grid around the camera, reused from image to image.
#[derive(Debug, Clone, Default)]
pub struct HeightMap {
    cell_size_m: f64,
    side: usize,
    /// Global index of cell `(0, 0)`.
    origin: (i64, i64),
    sum_z: Vec<f64>,
    cells: Vec<HeightCell>,
    /// Scratch of the step-cluster size rule.
    visited: Vec<bool>,
    stack: Vec<usize>,
    group: Vec<usize>,
}

impl HeightMap {
    pub(crate) fn reset(&mut self, cell_size_m: f64, half_extent_m: f64, centre_xy_m: [f64; 2]) {
        let half = (half_extent_m / cell_size_m).ceil() as i64;
        self.cell_size_m = cell_size_m;
        self.side = (2 * half) as usize;
        let index = |v: f64| (v / cell_size_m).floor() as i64;
        self.origin = (index(centre_xy_m[0]) - half, index(centre_xy_m[1]) - half);
        let n = self.side * self.side;
        self.sum_z.clear();
        self.sum_z.resize(n, 0.0);
        self.cells.clear();
        self.cells.resize(n, HeightCell::EMPTY);
    }

    pub fn cell_size_m(&self) -> f64 {
        self.cell_size_m
    }

    /// Cells per side.
    pub fn side(&self) -> usize {
        self.side
    }

    /// Global lattice index of cell `(0, 0)` (see the module doc).
    pub fn origin_index(&self) -> (i64, i64) {
        self.origin
    }

    pub fn cells(&self) -> &[HeightCell] {
        &self.cells
    }

    /// Flat index of the cell holding `(x, y)`, `None` outside the map.
    pub fn index_of(&self, x_m: f64, y_m: f64) -> Option<usize> {
        let col = (x_m / self.cell_size_m).floor() as i64 - self.origin.0;
        let row = (y_m / self.cell_size_m).floor() as i64 - self.origin.1;
        let side = self.side as i64;
        (0..side).contains(&col).then_some(())?;
        (0..side).contains(&row).then_some((row * side + col) as usize)
    }

    /// Centre of the cell with flat index `index`, in the local frame.
    pub fn centre_m(&self, index: usize) -> Point2<f64> {
        let (col, row) = ((index % self.side) as i64, (index / self.side) as i64);
        Point2::new(
            ((col + self.origin.0) as f64 + 0.5) * self.cell_size_m,
            ((row + self.origin.1) as f64 + 0.5) * self.cell_size_m,
        )
    }

    /// Appends the centres of the obstacle cells (steps and negative-edge tops) to `out`.
    pub fn obstacle_centres(&self, out: &mut Vec<Point2<f64>>) {
        out.extend(self.cells.iter().enumerate().filter(|(_, c)| c.is_obstacle()).map(|(i, _)| self.centre_m(i)));
    }

    pub(crate) fn add_point(&mut self, index: usize, z_m: f64) {
        self.sum_z[index] += z_m;
        self.cells[index].points += 1;
    }

    pub(crate) fn mark_negative_edge(&mut self, index: usize, traversability: f32, measured: bool) {
        let cell = &mut self.cells[index];
        cell.negative_edge = true;
        cell.edge_measured |= measured;
        cell.traversability = cell.traversability.max(traversability);
    }

    pub(crate) fn cell(&self, index: usize) -> &HeightCell {
        &self.cells[index]
    }

    /// Means, then the step test on every known cell. Returns the number of step cells.
    ///
    /// The window's extremes are its `support`-th highest and `support`-th lowest cells (see
    /// `ObstacleConfig::step_support_cells`): with 1 this is the thesis's max − min.
    pub(crate) fn classify_steps(
        &mut self,
        min_points: u32,
        window_cells: usize,
        support: usize,
        max_step_m: f64,
        model: &StereoErrorModel,
        t_cam_local: &Isometry3<f64>,
    ) -> usize {
        for (cell, sum) in self.cells.iter_mut().zip(&self.sum_z) {
            if cell.points >= min_points {
                cell.height_m = (sum / f64::from(cell.points)) as f32;
            }
        }
        let support = support.clamp(1, MAX_SUPPORT);
        let side = self.side as i64;
        let lo = -((window_cells as i64 - 1) / 2);
        let hi = lo + window_cells as i64 - 1;
        let mut steps = 0;
        for row in 0..side {
            for col in 0..side {
                let index = (row * side + col) as usize;
                if !self.cells[index].is_known() {
                    continue;
                }
                // The `support` lowest and highest (height, index) of the window, sorted from the
                // extreme inwards.
                let mut lows = [(f32::INFINITY, index); MAX_SUPPORT];
                let mut highs = [(f32::NEG_INFINITY, index); MAX_SUPPORT];
                for r in (row + lo).max(0)..=(row + hi).min(side - 1) {
                    for c in (col + lo).max(0)..=(col + hi).min(side - 1) {
                        let k = (r * side + c) as usize;
                        let h = self.cells[k].height_m;
                        if h < lows[support - 1].0 {
                            insert_sorted(&mut lows[..support], (h, k), |a, b| a < b);
                        }
                        if h > highs[support - 1].0 {
                            insert_sorted(&mut highs[..support], (h, k), |a, b| a > b);
                        }
                    }
                }
                let (low, high) = (lows[support - 1], highs[support - 1]);
                // Fewer than `support` known cells on a side: no supported extreme, no step.
                let h_diff =
                    if low.0.is_finite() && high.0.is_finite() { f64::from(high.0 - low.0).max(0.0) } else { 0.0 };
                // Δd of the two extreme cells' centres, back in the camera frame (trap 10).
                let centre = |k: usize| {
                    let xy = self.centre_m(k);
                    let p = t_cam_local * Point3::new(xy.x, xy.y, f64::from(self.cells[k].height_m));
                    [p.x, p.y, p.z]
                };
                let delta_d = if high.1 == low.1 || h_diff == 0.0 {
                    0.0
                } else {
                    model.distance_error_m(&centre(high.1), &centre(low.1))
                };
                let threshold = max_step_m + delta_d;
                let cell = &mut self.cells[index];
                cell.h_diff_m = h_diff as f32;
                cell.window_min_m = if low.0.is_finite() { low.0 } else { cell.height_m };
                cell.threshold_m = threshold as f32;
                cell.traversability = (h_diff / threshold) as f32;
                cell.step = h_diff > threshold;
                steps += usize::from(cell.step);
            }
        }
        steps
    }
}

impl HeightMap {
    /// Clears the step verdict of 8-connected groups of fewer than `min_cells` step cells (see
    /// `ObstacleConfig::min_step_cluster_cells`). Returns the number of step cells left.
    pub(crate) fn drop_small_step_clusters(&mut self, min_cells: usize) -> usize {
        let n = self.cells.len();
        let side = self.side as i64;
        self.visited.clear();
        self.visited.resize(n, false);
        let mut left = 0;
        for first in 0..n {
            if self.visited[first] || !self.cells[first].step {
                continue;
            }
            self.visited[first] = true;
            self.group.clear();
            self.stack.clear();
            self.stack.push(first);
            while let Some(k) = self.stack.pop() {
                self.group.push(k);
                let (col, row) = ((k % self.side) as i64, (k / self.side) as i64);
                for (dr, dc) in [(-1, -1), (-1, 0), (-1, 1), (0, -1), (0, 1), (1, -1), (1, 0), (1, 1)] {
                    let (r, c) = (row + dr, col + dc);
                    if !(0..side).contains(&r) || !(0..side).contains(&c) {
                        continue;
                    }
                    let j = (r * side + c) as usize;
                    if self.cells[j].step && !self.visited[j] {
                        self.visited[j] = true;
                        self.stack.push(j);
                    }
                }
            }
            if self.group.len() < min_cells {
                for &k in &self.group {
                    let cell = &mut self.cells[k];
                    cell.step = false;
                    // Below 1: the cell is traversable now, whatever its noisy h_diff said.
                    cell.traversability = cell.traversability.min(1.0);
                }
            } else {
                left += self.group.len();
            }
        }
        left
    }
}

/// Largest `ObstacleConfig::step_support_cells`.
pub(crate) const MAX_SUPPORT: usize = 3;

/// Inserts `item` into `list` (sorted by `before`, full), dropping the last entry.
fn insert_sorted(list: &mut [(f32, usize)], item: (f32, usize), before: impl Fn(f32, f32) -> bool) {
    let mut k = list.len() - 1;
    list[k] = item;
    while k > 0 && before(list[k].0, list[k - 1].0) {
        list.swap(k, k - 1);
        k -= 1;
    }
}
