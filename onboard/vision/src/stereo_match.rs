//! Depth of a left-image feature on a rectified pair: sparse ZNCC matching along the row, or a
//! lookup in the SGM disparity map.
//!
//! The sparse matcher compares a `(2r+1)²` window (default 9×9) by zero-mean normalised
//! cross-correlation, which is invariant to the gain and offset differences between the two
//! cameras' auto-exposure. Both windows are sampled at the feature's sub-pixel position
//! (bilinear), so the integer disparity search is exact on the tracked point; a parabola through
//! the scores at the best integer disparity and its neighbours gives the sub-pixel part. A match
//! must beat the second-best non-adjacent candidate clearly (uniqueness) and survive the
//! right-to-left search (left-right consistency).

use crate::ImageView;
use fpga_model::{DISPARITY_FRAC_BITS, DisparityImage, INVALID};

/// Settings of [`SparseStereo`].
#[derive(Debug, Clone, PartialEq)]
pub struct StereoMatchConfig {
    /// Smallest accepted (sub-pixel) disparity, default 0.5 px.
    pub min_disparity_px: f32,
    /// Largest searched disparity, default 128 px.
    pub max_disparity_px: f32,
    /// Half size of the ZNCC window, default 4 (9×9).
    pub window_radius_px: usize,
    /// Smallest accepted ZNCC of the best candidate, default 0.7.
    pub min_score: f32,
    /// Largest accepted ratio of the matching costs `1 − ZNCC` of the best and the second-best
    /// non-adjacent candidate, default 0.8 (repetitive texture gives ratios near 1). The defaults
    /// match 78 % of the Shi-Tomasi corners of KITTI 000000 with a median difference of 0.18 px to
    /// SGM (tests/geometry.rs).
    pub uniqueness: f32,
}

impl Default for StereoMatchConfig {
    fn default() -> Self {
        StereoMatchConfig {
            min_disparity_px: 0.5,
            max_disparity_px: 128.0,
            window_radius_px: 4,
            min_score: 0.7,
            uniqueness: 0.8,
        }
    }
}

/// Windows whose intensity standard deviation is below this (grey levels) carry no usable texture:
/// their ZNCC is dominated by noise.
const MIN_WINDOW_STD: f32 = 2.0;
/// Largest disagreement of the left-to-right and right-to-left disparities.
const LR_MAX_DIFF_PX: f32 = 1.0;

/// Sparse stereo matcher; owns its scratch buffers, so matching allocates nothing after `new`.
#[derive(Debug)]
pub struct SparseStereo {
    config: StereoMatchConfig,
    /// Normalised zero-mean template window.
    template: Vec<f32>,
    /// The search image's rows around the feature, interpolated at the feature's sub-pixel offset.
    strip: Vec<f32>,
    /// Column sums of the strip in f64: the sliding window sums below would drift in f32, and the
    /// variance is a difference of large numbers.
    column_sum: Vec<f64>,
    column_sq: Vec<f64>,
    /// ZNCC per integer disparity.
    scores: Vec<f32>,
    /// Cross-correlation per window position in the strip.
    cross: Vec<f32>,
}

/// Which way the search runs: left-to-right matches move left in the right image.
#[derive(Debug, Clone, Copy)]
enum Direction {
    LeftToRight,
    RightToLeft,
}

impl SparseStereo {
    pub fn new(config: StereoMatchConfig) -> Self {
        let r = config.window_radius_px;
        let side = 2 * r + 1;
        let disparities = max_integer_disparity(&config) + 1;
        let columns = disparities + 2 * r;
        SparseStereo {
            template: vec![0.0; side * side],
            strip: vec![0.0; side * columns],
            column_sum: vec![0.0; columns],
            column_sq: vec![0.0; columns],
            scores: vec![0.0; disparities],
            cross: vec![0.0; disparities],
            config,
        }
    }

    pub fn config(&self) -> &StereoMatchConfig {
        &self.config
    }

    /// Disparity (px, sub-pixel) of the left-image point (x, y) on a rectified pair, or None.
    /// Includes a left-right consistency or uniqueness check.
    pub fn match_point(&mut self, left: ImageView<'_>, right: ImageView<'_>, x: f32, y: f32) -> Option<f32> {
        // The view's fields are public, so a hand-built view may not cover its size.
        let consistent = |v: &ImageView<'_>| v.data.len() == v.width * v.height;
        if left.width != right.width || left.height != right.height || !consistent(&left) || !consistent(&right) {
            return None;
        }
        let disparity = self.search(left, right, x, y, Direction::LeftToRight)?;
        if disparity < self.config.min_disparity_px || disparity > self.config.max_disparity_px {
            return None;
        }
        let back = self.search(right, left, x - disparity, y, Direction::RightToLeft)?;
        ((back - disparity).abs() <= LR_MAX_DIFF_PX).then_some(disparity)
    }

    /// Best sub-pixel disparity of the template at (x, y) in `template_image` along the same row of
    /// `search_image`, with the score and uniqueness tests.
    fn search(
        &mut self,
        template_image: ImageView<'_>,
        search_image: ImageView<'_>,
        x: f32,
        y: f32,
        direction: Direction,
    ) -> Option<f32> {
        let r = self.config.window_radius_px;
        let side = 2 * r + 1;
        let (width, height) = (template_image.width, template_image.height);
        if !(x.is_finite() && y.is_finite()) || x < r as f32 || y < r as f32 {
            return None;
        }
        let (x0, y0) = (x.floor() as usize, y.floor() as usize);
        let (fx, fy) = (x - x0 as f32, y - y0 as f32);
        if x0 + r + 1 >= width || y0 + r + 1 >= height {
            return None;
        }
        if !self.fill_template(template_image, x0, y0, fx, fy) {
            return None;
        }
        // Integer disparities whose window stays inside the search image.
        let d_max = match direction {
            Direction::LeftToRight => (x0 - r).min(self.scores.len() - 1),
            Direction::RightToLeft => (width - 2 - r - x0).min(self.scores.len() - 1),
        };
        if d_max < 2 {
            return None;
        }
        let columns = d_max + 2 * r + 1;
        // Strip column k holds search-image column c(k) (+ fx); the window of disparity d covers
        // strip columns [k0(d), k0(d) + 2r].
        let first_column = match direction {
            Direction::LeftToRight => x0 - d_max - r,
            Direction::RightToLeft => x0 - r,
        };
        let (w00, w10, w01, w11) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
        for j in 0..side {
            let row_top = &search_image.data[(y0 + j - r) * width..][..width];
            let row_bottom = &search_image.data[(y0 + j + 1 - r) * width..][..width];
            let strip_row = &mut self.strip[j * columns..(j + 1) * columns];
            for (k, value) in strip_row.iter_mut().enumerate() {
                let c = first_column + k;
                *value = w00 * f32::from(row_top[c])
                    + w10 * f32::from(row_top[c + 1])
                    + w01 * f32::from(row_bottom[c])
                    + w11 * f32::from(row_bottom[c + 1]);
            }
        }
        for k in 0..columns {
            let (mut sum, mut sq) = (0.0f64, 0.0f64);
            for j in 0..side {
                let v = f64::from(self.strip[j * columns + k]);
                sum += v;
                sq += v * v;
            }
            self.column_sum[k] = sum;
            self.column_sq[k] = sq;
        }
        // Cross-correlation indexed by the window's first strip column, accumulated as one
        // contiguous multiply-add per template pixel (vectorises); the template is zero-mean, so
        // the window's mean drops out of the cross term.
        let windows = d_max + 1;
        let cross = &mut self.cross[..windows];
        cross.fill(0.0);
        for j in 0..side {
            for i in 0..side {
                let t = self.template[j * side + i];
                let row = &self.strip[j * columns + i..j * columns + i + windows];
                for (acc, v) in cross.iter_mut().zip(row) {
                    *acc += t * v;
                }
            }
        }
        let n = (side * side) as f64;
        let min_variance_sum = f64::from(MIN_WINDOW_STD * MIN_WINDOW_STD) * n;
        // Sliding window sums over the strip's column sums.
        let mut sum: f64 = self.column_sum[..side].iter().sum();
        let mut sq: f64 = self.column_sq[..side].iter().sum();
        for k0 in 0..windows {
            if k0 > 0 {
                sum += self.column_sum[k0 + side - 1] - self.column_sum[k0 - 1];
                sq += self.column_sq[k0 + side - 1] - self.column_sq[k0 - 1];
            }
            let d = match direction {
                Direction::LeftToRight => d_max - k0,
                Direction::RightToLeft => k0,
            };
            let variance_sum = sq - sum * sum / n;
            self.scores[d] =
                if variance_sum < min_variance_sum { -1.0 } else { self.cross[k0] / variance_sum.sqrt() as f32 };
        }
        self.pick(d_max)
    }

    /// Loads the normalised zero-mean template; false when it has too little texture.
    fn fill_template(&mut self, image: ImageView<'_>, x0: usize, y0: usize, fx: f32, fy: f32) -> bool {
        let r = self.config.window_radius_px;
        let side = 2 * r + 1;
        let width = image.width;
        let (w00, w10, w01, w11) = ((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
        let mut sum = 0.0f32;
        for j in 0..side {
            let top = &image.data[(y0 + j - r) * width..][..width];
            let bottom = &image.data[(y0 + j + 1 - r) * width..][..width];
            for i in 0..side {
                let c = x0 + i - r;
                let v = w00 * f32::from(top[c])
                    + w10 * f32::from(top[c + 1])
                    + w01 * f32::from(bottom[c])
                    + w11 * f32::from(bottom[c + 1]);
                self.template[j * side + i] = v;
                sum += v;
            }
        }
        let n = (side * side) as f32;
        let mean = sum / n;
        let mut variance_sum = 0.0f32;
        for v in &mut self.template {
            *v -= mean;
            variance_sum += *v * *v;
        }
        if variance_sum < MIN_WINDOW_STD * MIN_WINDOW_STD * n {
            return false;
        }
        let inv_norm = 1.0 / variance_sum.sqrt();
        for v in &mut self.template {
            *v *= inv_norm;
        }
        true
    }

    /// Best integer disparity in `scores[0..=d_max]`, tested and refined by a parabola.
    fn pick(&self, d_max: usize) -> Option<f32> {
        let scores = &self.scores[..=d_max];
        let (best_d, best) =
            scores.iter().copied().enumerate().fold((0, f32::MIN), |acc, (d, s)| if s > acc.1 { (d, s) } else { acc });
        if best < self.config.min_score || best_d == 0 || best_d == d_max {
            return None;
        }
        let second =
            scores.iter().enumerate().filter(|(d, _)| d.abs_diff(best_d) >= 2).map(|(_, &s)| s).fold(-1.0f32, f32::max);
        if 1.0 - best > self.config.uniqueness * (1.0 - second) {
            return None;
        }
        let (before, after) = (scores[best_d - 1], scores[best_d + 1]);
        let curvature = before - 2.0 * best + after;
        if curvature >= 0.0 {
            return None;
        }
        let offset = (0.5 * (before - after) / curvature).clamp(-0.5, 0.5);
        Some(best_d as f32 + offset)
    }
}

fn max_integer_disparity(config: &StereoMatchConfig) -> usize {
    // One beyond the range so the parabola has a neighbour at the largest disparity.
    if config.max_disparity_px.is_finite() { config.max_disparity_px.max(2.0).ceil() as usize + 1 } else { 2 }
}

/// Disparity at a sub-pixel left-image point from the SGM map (1/16 px, INVALID), interpolated only
/// between valid neighbours that agree within 1 px; None otherwise.
///
/// The pixel nearest to the point must be valid: it anchors the interpolation, and bilinear
/// neighbours across a depth edge (more than 1 px away from it) or invalid ones are left out, so
/// no disparity is ever mixed across an occlusion boundary.
pub fn disparity_from_map(map: &DisparityImage, x: f32, y: f32) -> Option<f32> {
    if !(x.is_finite() && y.is_finite()) || x < 0.0 || y < 0.0 {
        return None;
    }
    let (width, height) = (map.width, map.height);
    if map.data.len() != width * height || x > (width - 1) as f32 || y > (height - 1) as f32 {
        return None;
    }
    let scale = 1.0 / (1u32 << DISPARITY_FRAC_BITS) as f32;
    let value = |xi: usize, yi: usize| match map.data[yi * width + xi] {
        INVALID => None,
        raw => Some(f32::from(raw) * scale),
    };
    let anchor = value(x.round() as usize, y.round() as usize)?;
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(width - 1), (y0 + 1).min(height - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let neighbours =
        [(x0, y0, (1.0 - fx) * (1.0 - fy)), (x1, y0, fx * (1.0 - fy)), (x0, y1, (1.0 - fx) * fy), (x1, y1, fx * fy)];
    let (mut sum, mut weight) = (0.0f32, 0.0f32);
    for (xi, yi, w) in neighbours {
        if let Some(d) = value(xi, yi)
            && (d - anchor).abs() <= 1.0
        {
            sum += w * d;
            weight += w;
        }
    }
    // The anchor's own bilinear weight is at least 1/4, so `weight` is never zero here.
    (weight > 0.0).then(|| sum / weight)
}
