//! Grid-bucketed Shi-Tomasi corner detection.
//!
//! The response is the smaller eigenvalue of the structure tensor of central-difference gradients
//! averaged over a 5×5 window, in (grey levels / pixel)². This is the quantity that conditions the
//! Lucas-Kanade normal equations, so a corner that passes it is one the tracker can localise in both
//! directions; on weakly textured planetary terrain this matters more than FAST's ring test, which
//! needs crisp contrast steps. One feature per grid cell spreads the features over the image (a pose
//! from clustered features is poorly conditioned), and cells already holding a tracked point get
//! none, so the detector only refills where tracks were lost.

use crate::ImageView;

/// Detector tuning. `Default` suits 1024×508 rover images and KITTI/EuRoC.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureConfig {
    /// Total number of features (tracked + new) aimed for.
    pub max_features: usize,
    /// Grid bucketing: at most one new feature per free `cell_size_px`² cell.
    pub cell_size_px: usize,
    /// Minimum Shi-Tomasi response: smaller structure-tensor eigenvalue of the 5×5-averaged
    /// central-difference gradients, (grey levels / px)². Sensor noise of ~1.5 grey levels alone
    /// gives about 0.5; 4 means a corner with roughly 2 levels/px of contrast along both axes.
    pub threshold: f32,
    /// No feature closer than this to the image border (room for the tracking window).
    pub border_px: usize,
}

impl Default for FeatureConfig {
    fn default() -> Self {
        FeatureConfig { max_features: 400, cell_size_px: 32, threshold: 4.0, border_px: 16 }
    }
}

/// A detected corner, level-0 pixel coordinates (pixel centres at integers).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Keypoint {
    pub x: f32,
    pub y: f32,
    pub score: f32,
}

/// Half width of the structure-tensor averaging window (5×5).
const WINDOW_RADIUS: usize = 2;
const WINDOW_SIDE: usize = 2 * WINDOW_RADIUS + 1;

/// Corner detector with its per-image buffers.
#[derive(Debug, Clone)]
pub struct FeatureDetector {
    config: FeatureConfig,
    width: usize,
    height: usize,
    /// Ring of the last `WINDOW_SIDE` rows of horizontal 5-sums of the gradient products
    /// (gxx, gxy, gyy), in integer units of (2 · gradient)², over the columns of one span.
    ring: [Vec<i32>; 3],
    /// Vertical running sums of the ring rows: the 5×5 window sums.
    window: [Vec<i32>; 3],
    /// Gradient products of the current row.
    products: [Vec<i32>; 3],
    /// Shi-Tomasi response per pixel; only the pixels of free cells (plus a one-pixel margin for
    /// the maximum test) are written on each call.
    score: Vec<f32>,
    cells_x: usize,
    cells_y: usize,
    occupied: Vec<bool>,
    candidates: Vec<Keypoint>,
}

impl FeatureDetector {
    pub fn new(config: FeatureConfig, width: usize, height: usize) -> Self {
        let cell = config.cell_size_px.max(1);
        let cells_x = width.div_ceil(cell);
        let cells_y = height.div_ceil(cell);
        let n = width * height;
        let row = || vec![0; width];
        FeatureDetector {
            config,
            width,
            height,
            ring: [vec![0; width * WINDOW_SIDE], vec![0; width * WINDOW_SIDE], vec![0; width * WINDOW_SIDE]],
            window: [row(), row(), row()],
            products: [row(), row(), row()],
            score: vec![0.0; n],
            cells_x,
            cells_y,
            occupied: vec![false; cells_x * cells_y],
            candidates: Vec::with_capacity(cells_x * cells_y),
        }
    }

    pub fn config(&self) -> &FeatureConfig {
        &self.config
    }

    /// Appends new corners to `out` (cleared first), strongest first, only in grid cells that contain
    /// none of `existing` (points already tracked), at most `config.max_features - existing.len()`.
    ///
    /// An image of a size other than the one given to `new` yields no features.
    pub fn detect(&mut self, image: ImageView<'_>, existing: &[[f32; 2]], out: &mut Vec<Keypoint>) {
        out.clear();
        let budget = self.config.max_features.saturating_sub(existing.len());
        if budget == 0 || image.width != self.width || image.height != self.height {
            return;
        }
        if image.data.len() != self.width * self.height {
            return;
        }
        // Gradient window (1) + averaging window (2) + the 3×3 maximum test (1) must fit.
        let border = self.config.border_px.max(WINDOW_RADIUS + 2);
        if self.width <= 2 * border || self.height <= 2 * border {
            return;
        }
        self.mark_occupied(existing);
        self.candidates.clear();
        let cell = self.config.cell_size_px.max(1);
        for cy in 0..self.cells_y {
            let y_start = (cy * cell).max(border);
            let y_end = ((cy + 1) * cell).min(self.height - border);
            if y_start >= y_end {
                continue;
            }
            // Runs of adjacent free cells share one pass over their rows.
            let mut cx = 0;
            while cx < self.cells_x {
                if self.occupied[cy * self.cells_x + cx] {
                    cx += 1;
                    continue;
                }
                let first = cx;
                while cx < self.cells_x && !self.occupied[cy * self.cells_x + cx] {
                    cx += 1;
                }
                let x_start = (first * cell).max(border);
                let x_end = (cx * cell).min(self.width - border);
                if x_start < x_end {
                    // Scores one pixel beyond the span for the maximum test at its edges.
                    self.compute_scores(image, x_start - 1, x_end + 1, y_start - 1, y_end + 1);
                    for c in first..cx {
                        let x_range = ((c * cell).max(border), ((c + 1) * cell).min(self.width - border));
                        if x_range.0 < x_range.1 {
                            self.best_in_cell(x_range, (y_start, y_end));
                        }
                    }
                }
            }
        }
        let candidates = &mut self.candidates;
        // Strongest first; ties broken by position so the result never depends on anything else.
        candidates
            .sort_unstable_by(|a, b| b.score.total_cmp(&a.score).then(a.y.total_cmp(&b.y)).then(a.x.total_cmp(&b.x)));
        out.extend(candidates.iter().take(budget).copied());
    }

    /// Shi-Tomasi response for the pixels `x_lo..x_hi` × `y_lo..y_hi` (at least 3 pixels from the
    /// image edge). Gradients are integer central differences `I(x+1) - I(x-1)` (twice the
    /// gradient), so products and window sums are exact in `i32` (at most 25 · 255² · 4 in
    /// magnitude) and the vertical window can be a running sum without drift.
    fn compute_scores(&mut self, image: ImageView<'_>, x_lo: usize, x_hi: usize, y_lo: usize, y_hi: usize) {
        let w = self.width;
        let data = image.data;
        // Products are needed WINDOW_RADIUS beyond the score area on every side.
        let (px_lo, px_hi) = (x_lo - WINDOW_RADIUS, x_hi + WINDOW_RADIUS);
        let span = x_hi - x_lo;
        let product_span = px_hi - px_lo;
        for window in &mut self.window {
            window[..span].fill(0);
        }
        // (2 · gradient)² summed over 25 pixels = 100 × the mean squared gradient.
        let norm = 1.0 / (4 * WINDOW_SIDE * WINDOW_SIDE) as f32;
        for y in y_lo - WINDOW_RADIUS..y_hi + WINDOW_RADIUS {
            let row = &data[y * w + px_lo - 1..y * w + px_hi + 1];
            let above = &data[(y - 1) * w + px_lo..(y - 1) * w + px_hi];
            let below = &data[(y + 1) * w + px_lo..(y + 1) * w + px_hi];
            let [pxx, pxy, pyy] = &mut self.products;
            let (pxx, pxy, pyy) = (&mut pxx[..product_span], &mut pxy[..product_span], &mut pyy[..product_span]);
            for (((((xx, xy), yy), (&l, &r)), &u), &d) in pxx
                .iter_mut()
                .zip(pxy.iter_mut())
                .zip(pyy.iter_mut())
                .zip(row.iter().zip(&row[2..]))
                .zip(above)
                .zip(below)
            {
                let gx = i32::from(r) - i32::from(l);
                let gy = i32::from(d) - i32::from(u);
                *xx = gx * gx;
                *xy = gx * gy;
                *yy = gy * gy;
            }
            // Horizontal 5-sums into the ring slot of this row, replacing the row that leaves the
            // vertical window.
            let slot = (y % WINDOW_SIDE) * w;
            for ((product, ring), window) in self.products.iter().zip(self.ring.iter_mut()).zip(self.window.iter_mut())
            {
                let product = &product[..product_span];
                let ring = &mut ring[slot..slot + span];
                let window = &mut window[..span];
                let starts_filled = y > y_lo + WINDOW_RADIUS;
                for (((((ring, window), &a), &b), &c), (&d, &e)) in ring
                    .iter_mut()
                    .zip(window.iter_mut())
                    .zip(product)
                    .zip(&product[1..])
                    .zip(&product[2..])
                    .zip(product[3..].iter().zip(&product[4..]))
                {
                    let sum = a + b + c + d + e;
                    if starts_filled {
                        *window -= *ring;
                    }
                    *ring = sum;
                    *window += sum;
                }
            }
            if y + WINDOW_RADIUS + 1 < y_lo + WINDOW_SIDE {
                continue;
            }
            // The window now holds rows y - 4 ..= y: the score row is y - 2.
            let score_row = (y - WINDOW_RADIUS) * w;
            let score = &mut self.score[score_row + x_lo..score_row + x_hi];
            let [sxx, sxy, syy] = &self.window;
            for (((s, &a), &b), &c) in score.iter_mut().zip(&sxx[..span]).zip(&sxy[..span]).zip(&syy[..span]) {
                let (a, b, c) = (a as f32 * norm, b as f32 * norm, c as f32 * norm);
                let half_trace = 0.5 * (a + c);
                let half_diff = 0.5 * (a - c);
                *s = half_trace - (half_diff * half_diff + b * b).sqrt();
            }
        }
    }

    fn mark_occupied(&mut self, existing: &[[f32; 2]]) {
        self.occupied.fill(false);
        let cell = self.config.cell_size_px.max(1) as f32;
        for &[x, y] in existing {
            if !(x >= 0.0 && y >= 0.0 && x < self.width as f32 && y < self.height as f32) {
                continue;
            }
            let cx = ((x / cell) as usize).min(self.cells_x - 1);
            let cy = ((y / cell) as usize).min(self.cells_y - 1);
            self.occupied[cy * self.cells_x + cx] = true;
        }
    }

    /// The strongest 3×3 local maximum above the threshold in one cell, if any.
    fn best_in_cell(&mut self, (x_start, x_end): (usize, usize), (y_start, y_end): (usize, usize)) {
        let w = self.width;
        let score = &self.score;
        let threshold = self.config.threshold;
        let mut best: Option<Keypoint> = None;
        for y in y_start..y_end {
            let row = y * w;
            for (x, &s) in score[row + x_start..row + x_end].iter().enumerate() {
                if s < threshold || best.is_some_and(|b| s <= b.score) {
                    continue;
                }
                if is_local_maximum(score, w, row + x_start + x) {
                    best = Some(Keypoint { x: (x_start + x) as f32, y: y as f32, score: s });
                }
            }
        }
        self.candidates.extend(best);
    }
}

/// Strict maximum over the 8-neighbourhood, with ties resolved towards the earlier pixel in scan
/// order so a plateau yields exactly one maximum.
#[inline]
fn is_local_maximum(score: &[f32], width: usize, i: usize) -> bool {
    let s = score[i];
    let before = [i - width - 1, i - width, i - width + 1, i - 1];
    let after = [i + 1, i + width - 1, i + width, i + width + 1];
    before.iter().all(|&j| score[j] < s) && after.iter().all(|&j| score[j] <= s)
}
