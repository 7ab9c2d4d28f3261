//! Stage 3 of `SPEC.md`: path aggregation, one direction at a time, then the sum over the mode.

use super::{AggregatedVolume, CostVolume, PathCostVolume};
use crate::config::{PathMode, SgmConfig};
use crate::image::GrayImage;

/// A path direction `r = (dx, dy)`: the predecessor of pixel `p` on this path is `p − r`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Direction {
    pub dx: isize,
    pub dy: isize,
}

impl Direction {
    /// True for the directions of the first (forward raster) pass: their predecessor `p − r`
    /// comes earlier in raster order (previous pixel of the row, or the previous row).
    pub fn is_forward(self) -> bool {
        self.dy > 0 || (self.dy == 0 && self.dx > 0)
    }
}

/// The forward raster pass: from the left, top-left, top, top-right.
pub const FORWARD_DIRECTIONS: [Direction; 4] =
    [Direction { dx: 1, dy: 0 }, Direction { dx: 1, dy: 1 }, Direction { dx: 0, dy: 1 }, Direction { dx: -1, dy: 1 }];

/// The reverse raster pass of `Eight`: from the right, bottom-right, bottom, bottom-left.
pub const REVERSE_DIRECTIONS: [Direction; 4] = [
    Direction { dx: -1, dy: 0 },
    Direction { dx: -1, dy: -1 },
    Direction { dx: 0, dy: -1 },
    Direction { dx: 1, dy: -1 },
];

/// The directions a path mode aggregates, in the order `SPEC.md` lists them.
pub fn directions(mode: PathMode) -> Vec<Direction> {
    match mode {
        PathMode::Four => FORWARD_DIRECTIONS.to_vec(),
        PathMode::Eight => FORWARD_DIRECTIONS.iter().chain(REVERSE_DIRECTIONS.iter()).copied().collect(),
    }
}

/// The large-jump penalty for an intensity step `gradient = |IL(p) − IL(p − r)|`:
/// `p2` when the adaptation is off (`scale = 0`), else `max(p1, floor(p2 · s / (s + g)))`, so an
/// intensity edge (likely a depth edge) makes a disparity jump cheaper, but never cheaper than a
/// one-pixel step.
pub fn effective_p2(p1: u8, p2: u8, scale: u8, gradient: u8) -> i32 {
    let (p1, p2, s, g) = (i32::from(p1), i32::from(p2), i32::from(scale), i32::from(gradient));
    if s == 0 { p2 } else { p1.max(p2 * s / (s + g)) }
}

/// The path costs `L_r` of one direction over the whole image, saturated to
/// `config.path_cost_bits` bits. Uses `config.p1`, `p2`, `p2_gradient_scale` and
/// `path_cost_bits`; `left` is the image whose intensity steps adapt P2.
///
/// Pixels are visited in raster order for a forward direction and in reverse raster order for
/// a reverse one, so the predecessor `p − r` is always computed before `p`, exactly as the
/// FPGA's single pass (or second pass) meets them.
pub fn path(cost: &CostVolume, left: &GrayImage, direction: Direction, config: &SgmConfig) -> PathCostVolume {
    let (width, height, disparities) = (cost.width, cost.height, cost.disparities);
    let l_max = i32::from(config.path_cost_max());
    let p1 = i32::from(config.p1);
    let mut path_cost = PathCostVolume::zeros(width, height, disparities);

    let rows: Vec<usize> = if direction.is_forward() { (0..height).collect() } else { (0..height).rev().collect() };
    let columns: Vec<usize> = if direction.is_forward() { (0..width).collect() } else { (0..width).rev().collect() };

    // The stored values of the predecessor, copied out so the current pixel can be written.
    let mut previous = vec![0i32; disparities];
    for &y in &rows {
        for &x in &columns {
            let px = x as isize - direction.dx;
            let py = y as isize - direction.dy;
            let matching_cost = cost.pixel(x, y);
            let predecessor_inside = px >= 0 && py >= 0 && (px as usize) < width && (py as usize) < height;

            if !predecessor_inside {
                // First pixel of the path: no smoothness term, only the (saturated) matching cost.
                for (d, out) in path_cost.pixel_mut(x, y).iter_mut().enumerate() {
                    *out = i32::from(matching_cost[d]).min(l_max) as u16;
                }
                continue;
            }

            let (px, py) = (px as usize, py as usize);
            for (d, prev) in previous.iter_mut().enumerate() {
                *prev = i32::from(path_cost.pixel(px, py)[d]);
            }
            // M: minimum over the stored (already saturated) predecessor values.
            let min_previous = previous.iter().copied().min().unwrap_or(0);
            let gradient = left.pixels[y * width + x].abs_diff(left.pixels[py * width + px]);
            let p2_eff = effective_p2(config.p1, config.p2, config.p2_gradient_scale, gradient);

            for (d, out) in path_cost.pixel_mut(x, y).iter_mut().enumerate() {
                let mut best = previous[d].min(min_previous + p2_eff);
                if d >= 1 {
                    best = best.min(previous[d - 1] + p1);
                }
                if d + 2 <= disparities {
                    best = best.min(previous[d + 1] + p1);
                }
                // best − M ≥ 0 (every candidate is ≥ M), so the value never goes negative.
                *out = (i32::from(matching_cost[d]) + best - min_previous).min(l_max) as u16;
            }
        }
    }
    path_cost
}

/// `S(p, d) = Σ_r L_r(p, d)` over the directions of `config.paths`. At most 8 · (2^12 − 1) =
/// 32 760, so the `u16` sum never saturates (`b + 3` bits for Eight, `b + 2` for Four).
pub fn sum(cost: &CostVolume, left: &GrayImage, config: &SgmConfig) -> AggregatedVolume {
    let mut total = AggregatedVolume::zeros(cost.width, cost.height, cost.disparities);
    for direction in directions(config.paths) {
        let path_cost = path(cost, left, direction, config);
        for (s, l) in total.data.iter_mut().zip(&path_cost.data) {
            *s += *l;
        }
    }
    total
}
