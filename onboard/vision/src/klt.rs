//! Pyramidal Lucas-Kanade feature tracking.
//!
//! Per point and pyramid level (coarse to fine) a Gauss-Newton solve for a translation and an
//! intensity offset: `I_next(x + d) ≈ T(x) + β` over a square window, inverse compositional: the
//! Jacobian comes from the template gradients, so the template, its gradients and the inverse
//! 3×3 normal matrix are computed once per point and level, and an iteration is one bilinear
//! resampling of the window plus five window sums. The offset β absorbs exposure changes.
//! A track fails when it leaves the image, its normal matrix is ill-conditioned, its final mean
//! absolute residual is too large, or tracking it back from `next` to `prev` does not return to
//! the start (forward-backward check).
//!
//! Cost control (most of the time used to go to points that never converge): a level stops
//! early once the sum of squared residuals has not improved for a few iterations (oscillation or
//! divergence) and keeps its lowest-cost estimate; coarse levels, whose result only seeds the next
//! level, use a looser convergence threshold. All samples of one
//! translated window share one sub-pixel fraction, so the bilinear weights are computed once per
//! window; windows reaching past the border gather their clamped pixels once.

use crate::pyramid::{Pyramid, PyramidLevel};
use nalgebra::{Cholesky, Const, SMatrix, SVector};

/// Tracker tuning.
#[derive(Debug, Clone, PartialEq)]
pub struct KltConfig {
    /// Window half width, pixels (7 = 15×15), on every pyramid level.
    pub window_radius_px: usize,
    /// Gauss-Newton iterations per level at most.
    pub max_iterations: usize,
    /// A level has converged when the update is shorter than this, pixels of that level.
    pub epsilon_px: f32,
    /// Mean absolute intensity residual (grey levels, after the offset) above which a track fails.
    /// Default 20: on KITTI at 10 Hz, correctly tracked (forward-backward < 0.1 px) high-contrast
    /// foliage windows under forward-motion scale change reach 12–20; the forward-backward check is
    /// the sharper outlier gate.
    pub max_residual: f32,
    /// Forward-backward check threshold, level-0 pixels; `<= 0` disables the check.
    pub forward_backward_px: f32,
    /// Pyramid levels (counted from level 0) on which the window warp is affine rather than a
    /// pure translation. Affine windows are 4× more accurate under rotation/scale on clean texture
    /// but tracked slightly fewer KITTI/EuRoC features (more freedom, weaker forward-backward
    /// agreement), so the default is 0 (translation + intensity offset only).
    pub affine_levels: usize,
}

impl Default for KltConfig {
    fn default() -> Self {
        KltConfig {
            window_radius_px: 7,
            max_iterations: 20,
            epsilon_px: 0.01,
            max_residual: 20.0,
            forward_backward_px: 0.5,
            affine_levels: 0,
        }
    }
}

/// Smallest eigenvalue of the translation block of the normal matrix, per window pixel,
/// (grey levels / px)²: below it the window has no usable texture in some direction.
const MIN_EIGENVALUE_PER_PIXEL: f32 = 1e-3;

/// Pyramidal KLT tracker with its window buffers.
#[derive(Debug, Clone)]
pub struct KltTracker {
    config: KltConfig,
    /// Template samples with a one-pixel margin for the gradients.
    padded: Vec<f32>,
    template: Vec<f32>,
    grad_x: Vec<f32>,
    grad_y: Vec<f32>,
    warped: Vec<f32>,
    /// Clamped source pixels of a window that reaches beyond the level.
    patch: Vec<f32>,
    /// Gauss-Newton iterations spent by the last `track` call (all points, both directions).
    iterations: usize,
}

impl KltTracker {
    pub fn new(config: KltConfig) -> Self {
        let side = 2 * config.window_radius_px + 1;
        let padded_side = side + 2;
        KltTracker {
            config,
            padded: vec![0.0; padded_side * padded_side],
            template: vec![0.0; side * side],
            grad_x: vec![0.0; side * side],
            grad_y: vec![0.0; side * side],
            warped: vec![0.0; side * side],
            patch: vec![0.0; (padded_side + 1) * (padded_side + 1)],
            iterations: 0,
        }
    }

    pub fn config(&self) -> &KltConfig {
        &self.config
    }

    /// Gauss-Newton iterations spent by the last [`KltTracker::track`] call, summed over points,
    /// levels and both directions (a cost figure for telemetry).
    pub fn last_iterations(&self) -> usize {
        self.iterations
    }

    /// Tracks `points` (level-0 pixel coordinates in `prev`) into `next`. `predicted` (same length)
    /// seeds the search (e.g. from a rotation prior); `None` = start at the same position.
    /// `out` is cleared and gets one entry per point: `Some([x, y])` or `None` when lost / out of image.
    ///
    /// A `predicted` slice of the wrong length is ignored.
    pub fn track(
        &mut self,
        prev: &Pyramid,
        next: &Pyramid,
        points: &[[f32; 2]],
        predicted: Option<&[[f32; 2]]>,
        out: &mut Vec<Option<[f32; 2]>>,
    ) {
        out.clear();
        self.iterations = 0;
        let predicted = predicted.filter(|p| p.len() == points.len());
        if prev.size() != next.size() {
            out.extend(points.iter().map(|_| None));
            return;
        }
        let levels = prev.levels().min(next.levels());
        let fb_threshold = self.config.forward_backward_px;
        for (i, &start) in points.iter().enumerate() {
            let seed = predicted.map_or(start, |p| p[i]);
            let forward = self.track_point(prev, next, levels, start, seed);
            let result = forward.filter(|&end| {
                fb_threshold <= 0.0
                    || self.track_point(next, prev, levels, end, start).is_some_and(|back| {
                        let (dx, dy) = (back[0] - start[0], back[1] - start[1]);
                        dx * dx + dy * dy <= fb_threshold * fb_threshold
                    })
            });
            out.push(result);
        }
    }

    /// Tracks one point from `from` to `to`, starting the search at `seed` (level-0 pixels).
    fn track_point(
        &mut self,
        from: &Pyramid,
        to: &Pyramid,
        levels: usize,
        point: [f32; 2],
        seed: [f32; 2],
    ) -> Option<[f32; 2]> {
        let (width, height) = from.size();
        if !in_image(point, width, height) || !seed[0].is_finite() || !seed[1].is_finite() {
            return None;
        }
        let top_scale = (1u32 << (levels - 1)) as f32;
        let mut warp = Warp {
            d: [(seed[0] - point[0]) / top_scale, (seed[1] - point[1]) / top_scale],
            a: [1.0, 0.0, 0.0, 1.0],
            offset: 0.0,
        };
        let mut residual = f32::INFINITY;
        for level in (0..levels).rev() {
            let scale = (1u32 << level) as f32;
            let template_level = from.level(level);
            let target_level = to.level(level);
            let p = [point[0] / scale, point[1] / scale];
            let epsilon_px =
                if level == 0 { self.config.epsilon_px } else { self.config.epsilon_px.max(COARSE_EPSILON_PX) };
            let limits = Limits { iterations: self.config.max_iterations, epsilon_px };
            residual = if level < self.config.affine_levels {
                self.solve_level_affine(&template_level, &target_level, p, &mut warp, &limits)?
            } else {
                self.solve_level_translation(&template_level, &target_level, p, &mut warp, &limits)?
            };
            if level > 0 {
                warp.d = [2.0 * warp.d[0], 2.0 * warp.d[1]];
            }
        }
        let end = [point[0] + warp.d[0], point[1] + warp.d[1]];
        (residual <= self.config.max_residual && in_image(end, width, height)).then_some(end)
    }

    /// Gauss-Newton on one level for translation + intensity offset; returns the mean absolute
    /// residual of the estimate kept (the lowest-cost one seen).
    fn solve_level_translation(
        &mut self,
        template_level: &PyramidLevel<'_>,
        target_level: &PyramidLevel<'_>,
        p: [f32; 2],
        warp: &mut Warp,
        limits: &Limits,
    ) -> Option<f32> {
        let r = self.config.window_radius_px;
        let radius = r as f32;
        let inverse = self.prepare_translation_template(template_level, p)?;
        let eps2 = limits.epsilon_px * limits.epsilon_px;
        let mut previous_step = [0.0f32; 2];
        let mut tracker = BestEstimate::new(*warp);
        for _ in 0..limits.iterations.max(1) {
            self.iterations += 1;
            let centre = [p[0] + warp.d[0], p[1] + warp.d[1]];
            // Far outside this level's image: the window sees only replicated border pixels.
            if !near_level(target_level, centre, radius) {
                return None;
            }
            let sums = self.translation_sums(target_level, centre, warp.offset);
            if tracker.observe(*warp, &sums) {
                break;
            }
            let (b0, b1, b2) = (f64::from(sums.gx_e), f64::from(sums.gy_e), f64::from(sums.e));
            let step = [
                (inverse[0][0] * b0 + inverse[0][1] * b1 + inverse[0][2] * b2) as f32,
                (inverse[1][0] * b0 + inverse[1][1] * b1 + inverse[1][2] * b2) as f32,
                (inverse[2][0] * b0 + inverse[2][1] * b1 + inverse[2][2] * b2) as f32,
            ];
            // Inverse compositional with an identity matrix part: the template moves by the step,
            // so the estimate moves against it.
            warp.d = [warp.d[0] - step[0], warp.d[1] - step[1]];
            warp.offset += step[2];
            if !(warp.d[0].is_finite() && warp.d[1].is_finite() && warp.offset.is_finite()) {
                return None;
            }
            if step[0] * step[0] + step[1] * step[1] < eps2 {
                tracker.accept_last_step(*warp);
                break;
            }
            // Bilinear interpolation makes the cost piecewise smooth; near the optimum Gauss-Newton
            // can jump back and forth across a pixel-cell edge. The midpoint is the answer then.
            let (bx, by) = (step[0] + previous_step[0], step[1] + previous_step[1]);
            if bx * bx + by * by < eps2 {
                warp.d = [warp.d[0] + 0.5 * step[0], warp.d[1] + 0.5 * step[1]];
                tracker.accept_last_step(*warp);
                break;
            }
            previous_step = [step[0], step[1]];
        }
        *warp = tracker.best;
        Some(tracker.mean_abs_residual)
    }

    /// Gauss-Newton on one level with an affine window (see [`KltConfig::affine_levels`]).
    fn solve_level_affine(
        &mut self,
        template_level: &PyramidLevel<'_>,
        target_level: &PyramidLevel<'_>,
        p: [f32; 2],
        warp: &mut Warp,
        limits: &Limits,
    ) -> Option<f32> {
        let r = self.config.window_radius_px;
        let radius = r as f32;
        let normal = self.prepare_template(template_level, p)?;
        let solver = Solver::new(&normal)?;
        let eps2 = limits.epsilon_px * limits.epsilon_px;
        let mut previous_shift = [0.0f32; 2];
        for _ in 0..limits.iterations {
            self.iterations += 1;
            let centre = [p[0] + warp.d[0], p[1] + warp.d[1]];
            if !near_level(target_level, centre, radius) {
                return None;
            }
            sample_affine(target_level, centre, &warp.a, r, &mut self.patch, &mut self.warped);
            let step = solver.solve(&self.affine_rhs(warp.offset));
            let before = warp.d;
            if !warp.compose_inverse(&step) {
                return None;
            }
            let shift = [warp.d[0] - before[0], warp.d[1] - before[1]];
            let change = shift[0] * shift[0]
                + shift[1] * shift[1]
                + radius * radius * (step[2] * step[2] + step[3] * step[3] + step[4] * step[4] + step[5] * step[5]);
            if change < eps2 {
                break;
            }
            let (bx, by) = (shift[0] + previous_shift[0], shift[1] + previous_shift[1]);
            if bx * bx + by * by < eps2 {
                warp.d = [warp.d[0] - 0.5 * shift[0], warp.d[1] - 0.5 * shift[1]];
                break;
            }
            previous_shift = shift;
        }
        let centre = [p[0] + warp.d[0], p[1] + warp.d[1]];
        sample_affine(target_level, centre, &warp.a, r, &mut self.patch, &mut self.warped);
        let sum: f32 = self.warped.iter().zip(&self.template).map(|(&w, &t)| (w - t - warp.offset).abs()).sum();
        Some(sum / self.warped.len() as f32)
    }

    /// Samples the template window around `p` and its gradients (translation model) and returns
    /// the inverse of the 3×3 normal matrix of the Jacobian rows `[gx, gy, 1]`, or `None` if the
    /// window is untextured.
    fn prepare_translation_template(&mut self, level: &PyramidLevel<'_>, p: [f32; 2]) -> Option<[[f64; 3]; 3]> {
        let r = self.config.window_radius_px;
        let side = 2 * r + 1;
        let padded_side = side + 2;
        sample_translated(
            level,
            [p[0] - (r + 1) as f32, p[1] - (r + 1) as f32],
            padded_side,
            &mut self.patch,
            &mut self.padded,
        );
        let rows = self.padded.chunks_exact(padded_side);
        let outputs = self
            .template
            .chunks_exact_mut(side)
            .zip(self.grad_x.chunks_exact_mut(side))
            .zip(self.grad_y.chunks_exact_mut(side));
        for (((above, row), below), ((t_row, gx_row), gy_row)) in
            rows.clone().zip(rows.clone().skip(1)).zip(rows.skip(2)).zip(outputs)
        {
            t_row.copy_from_slice(&row[1..=side]);
            for ((gx, &l), &r) in gx_row.iter_mut().zip(&row[..side]).zip(&row[2..side + 2]) {
                *gx = 0.5 * (r - l);
            }
            for ((gy, &u), &d) in gy_row.iter_mut().zip(&above[1..=side]).zip(&below[1..=side]) {
                *gy = 0.5 * (d - u);
            }
        }
        let mut lanes = [[0.0f32; LANES]; 5];
        for (gx, gy) in self.grad_x.chunks_exact(LANES).zip(self.grad_y.chunks_exact(LANES)) {
            for l in 0..LANES {
                lanes[0][l] += gx[l] * gx[l];
                lanes[1][l] += gx[l] * gy[l];
                lanes[2][l] += gy[l] * gy[l];
                lanes[3][l] += gx[l];
                lanes[4][l] += gy[l];
            }
        }
        let tail = self.grad_x.len() / LANES * LANES;
        for (&gx, &gy) in self.grad_x[tail..].iter().zip(&self.grad_y[tail..]) {
            lanes[0][0] += gx * gx;
            lanes[1][0] += gx * gy;
            lanes[2][0] += gy * gy;
            lanes[3][0] += gx;
            lanes[4][0] += gy;
        }
        let [gxx, gxy, gyy, sx, sy] = lanes.map(|lane| lane.iter().sum::<f32>());
        let n = (side * side) as f64;
        let half_trace = 0.5 * f64::from(gxx + gyy);
        let half_diff = 0.5 * f64::from(gxx - gyy);
        let min_eigenvalue = half_trace - (half_diff * half_diff + f64::from(gxy) * f64::from(gxy)).sqrt();
        if min_eigenvalue < f64::from(MIN_EIGENVALUE_PER_PIXEL) * n {
            return None;
        }
        let normal = nalgebra::Matrix3::new(
            f64::from(gxx),
            f64::from(gxy),
            f64::from(sx),
            f64::from(gxy),
            f64::from(gyy),
            f64::from(sy),
            f64::from(sx),
            f64::from(sy),
            n,
        );
        let inverse = normal.try_inverse()?;
        Some([
            [inverse[(0, 0)], inverse[(0, 1)], inverse[(0, 2)]],
            [inverse[(1, 0)], inverse[(1, 1)], inverse[(1, 2)]],
            [inverse[(2, 0)], inverse[(2, 1)], inverse[(2, 2)]],
        ])
    }

    /// Residual sums of the translated window at `centre` against the template, fused with the
    /// bilinear sampling (no intermediate buffer) when the window lies inside the level.
    fn translation_sums(&mut self, level: &PyramidLevel<'_>, centre: [f32; 2], offset: f32) -> ResidualSums {
        let r = self.config.window_radius_px;
        let side = 2 * r + 1;
        let rf = r as f32;
        sample_translated(level, [centre[0] - rf, centre[1] - rf], side, &mut self.patch, &mut self.warped);
        // Eight independent partial sums per quantity: the additions vectorise instead of
        // forming one serial dependency chain per sum.
        let mut lanes = [[0.0f32; LANES]; 5];
        let chunks = self
            .warped
            .chunks_exact(LANES)
            .zip(self.template.chunks_exact(LANES))
            .zip(self.grad_x.chunks_exact(LANES).zip(self.grad_y.chunks_exact(LANES)));
        for ((value, t), (gx, gy)) in chunks {
            for l in 0..LANES {
                let e = value[l] - t[l] - offset;
                lanes[0][l] += gx[l] * e;
                lanes[1][l] += gy[l] * e;
                lanes[2][l] += e;
                lanes[3][l] += e * e;
                lanes[4][l] += e.abs();
            }
        }
        let [gx_e, gy_e, e, squared, absolute] = lanes.map(|lane| lane.iter().sum::<f32>());
        let mut sums = ResidualSums { gx_e, gy_e, e, squared, absolute, pixels: (side * side) as f32 };
        let tail = self.warped.len() / LANES * LANES;
        for ((&value, &t), (&gx, &gy)) in self.warped[tail..]
            .iter()
            .zip(&self.template[tail..])
            .zip(self.grad_x[tail..].iter().zip(&self.grad_y[tail..]))
        {
            sums.add(value - t - offset, gx, gy);
        }
        sums
    }

    /// Right-hand side `Σ Jᵀ (I(W(x)) - T(x) - offset)` for the full affine parameter set.
    fn affine_rhs(&self, offset: f32) -> [f32; PARAMS] {
        let r = self.config.window_radius_px;
        let radius = r as f32;
        let mut b = [0.0f32; PARAMS];
        let mut k = 0;
        for j in 0..=2 * r {
            let v = j as f32 - radius;
            for i in 0..=2 * r {
                let u = i as f32 - radius;
                let e = self.warped[k] - self.template[k] - offset;
                let (gx, gy) = (self.grad_x[k] * e, self.grad_y[k] * e);
                b[0] += gx;
                b[1] += gy;
                b[2] += gx * u;
                b[3] += gx * v;
                b[4] += gy * u;
                b[5] += gy * v;
                b[6] += e;
                k += 1;
            }
        }
        b
    }

    /// Samples the template window around `p` and its gradients; returns the normal matrix of the
    /// Jacobian rows `[gx, gy, gx·u, gx·v, gy·u, gy·v, 1]` or `None` if the window is untextured.
    fn prepare_template(&mut self, level: &PyramidLevel<'_>, p: [f32; 2]) -> Option<SMatrix<f64, PARAMS, PARAMS>> {
        let r = self.config.window_radius_px;
        let side = 2 * r + 1;
        let padded_side = side + 2;
        sample_translated(
            level,
            [p[0] - (r + 1) as f32, p[1] - (r + 1) as f32],
            padded_side,
            &mut self.patch,
            &mut self.padded,
        );
        // Moments of the gradient products over the window coordinates (u, v): the normal matrix
        // of the rows [gx, gy, gx·u, gx·v, gy·u, gy·v, 1] is assembled from them below.
        let mut m = Moments::default();
        for j in 0..side {
            let v = j as f32 - r as f32;
            for i in 0..side {
                let u = i as f32 - r as f32;
                let c = (j + 1) * padded_side + i + 1;
                let gx = 0.5 * (self.padded[c + 1] - self.padded[c - 1]);
                let gy = 0.5 * (self.padded[c + padded_side] - self.padded[c - padded_side]);
                let k = j * side + i;
                self.template[k] = self.padded[c];
                self.grad_x[k] = gx;
                self.grad_y[k] = gy;
                let products = [gx * gx, gx * gy, gy * gy];
                let weights = [1.0, u, v, u * u, u * v, v * v];
                for (acc, &g) in m.second.iter_mut().zip(&products) {
                    for (a, &w) in acc.iter_mut().zip(&weights) {
                        *a += g * w;
                    }
                }
                for (acc, g) in m.first.iter_mut().zip([gx, gy]) {
                    acc[0] += g;
                    acc[1] += g * u;
                    acc[2] += g * v;
                }
            }
        }
        let normal = m.normal_matrix((side * side) as f64);
        let (gxx, gxy, gyy) = (normal[(0, 0)], normal[(0, 1)], normal[(1, 1)]);
        let half_trace = 0.5 * (gxx + gyy);
        let half_diff = 0.5 * (gxx - gyy);
        let min_eigenvalue = half_trace - (half_diff * half_diff + gxy * gxy).sqrt();
        (min_eigenvalue >= f64::from(MIN_EIGENVALUE_PER_PIXEL) * (side * side) as f64).then_some(normal)
    }
}

/// Parameters of one Gauss-Newton step: translation (2), affine matrix increment (4, row-major),
/// intensity offset (1).
const PARAMS: usize = 7;

/// Window sums for the normal matrix: `second[g][w]` = Σ (gx², gx·gy, gy²)[g] · (1, u, v, u², uv, v²)[w],
/// `first[g][w]` = Σ (gx, gy)[g] · (1, u, v)[w].
#[derive(Debug, Default)]
struct Moments {
    second: [[f32; 6]; 3],
    first: [[f32; 3]; 2],
}

impl Moments {
    fn normal_matrix(&self, n: f64) -> SMatrix<f64, PARAMS, PARAMS> {
        let s = self.second.map(|row| row.map(f64::from));
        let f = self.first.map(|row| row.map(f64::from));
        // Index of the weight (1, u, v, u², uv, v²) for the product of two coordinate factors.
        const ONE: usize = 0;
        const U: usize = 1;
        const V: usize = 2;
        const UU: usize = 3;
        const UV: usize = 4;
        const VV: usize = 5;
        // Parameter k's row is (gradient index, coordinate weight index): gx, gy, gx·u, gx·v, gy·u, gy·v.
        let parts = [(0usize, ONE), (1, ONE), (0, U), (0, V), (1, U), (1, V)];
        let product = |a: usize, b: usize| match (a.min(b), a.max(b)) {
            (0, 0) => 0,
            (0, 1) => 1,
            _ => 2,
        };
        let weight = |a: usize, b: usize| match (a, b) {
            (ONE, w) | (w, ONE) => w,
            (U, U) => UU,
            (V, V) => VV,
            _ => UV,
        };
        let mut normal = SMatrix::<f64, PARAMS, PARAMS>::zeros();
        for (row, &(ga, wa)) in parts.iter().enumerate() {
            for (col, &(gb, wb)) in parts.iter().enumerate() {
                normal[(row, col)] = s[product(ga, gb)][weight(wa, wb)];
            }
            normal[(row, PARAMS - 1)] = f[ga][wa];
            normal[(PARAMS - 1, row)] = f[ga][wa];
        }
        normal[(PARAMS - 1, PARAMS - 1)] = n;
        normal
    }
}

/// Current estimate: window pixel `x` (offset from the template centre) maps to
/// `p + d + A·x` in the target level; the target intensity there is `T(x) + offset`.
#[derive(Debug, Clone, Copy)]
struct Warp {
    d: [f32; 2],
    a: [f32; 4],
    offset: f32,
}

impl Warp {
    /// Inverse-compositional update `W ← W ∘ W(Δ)⁻¹`; false when the warp degenerates.
    fn compose_inverse(&mut self, step: &[f32; PARAMS]) -> bool {
        let m = [1.0 + step[2], step[3], step[4], 1.0 + step[5]];
        let det = m[0] * m[3] - m[1] * m[2];
        if det.is_nan() || det.abs() <= 1e-3 {
            return false;
        }
        let m_inv = [m[3] / det, -m[1] / det, -m[2] / det, m[0] / det];
        let a = self.a;
        let a_new = [
            a[0] * m_inv[0] + a[1] * m_inv[2],
            a[0] * m_inv[1] + a[1] * m_inv[3],
            a[2] * m_inv[0] + a[3] * m_inv[2],
            a[2] * m_inv[1] + a[3] * m_inv[3],
        ];
        self.d[0] -= a_new[0] * step[0] + a_new[1] * step[1];
        self.d[1] -= a_new[2] * step[0] + a_new[3] * step[1];
        self.a = a_new;
        self.offset += step[6];
        // A window squashed or stretched by more than 2× is no longer the same surface patch.
        let det_a = a_new[0] * a_new[3] - a_new[1] * a_new[2];
        self.d[0].is_finite() && self.d[1].is_finite() && (0.25..=4.0).contains(&det_a)
    }
}

/// Cholesky factor of the full affine normal matrix.
struct Solver(Cholesky<f64, Const<PARAMS>>);

impl Solver {
    fn new(normal: &SMatrix<f64, PARAMS, PARAMS>) -> Option<Self> {
        normal.cholesky().map(Solver)
    }

    fn solve(&self, b: &[f32; PARAMS]) -> [f32; PARAMS] {
        let x = self.0.solve(&SVector::<f64, PARAMS>::from(b.map(f64::from)));
        let mut step = [0.0f32; PARAMS];
        for (s, v) in step.iter_mut().zip(x.iter()) {
            *s = *v as f32;
        }
        step
    }
}

/// Iteration budget of one pyramid level.
struct Limits {
    iterations: usize,
    epsilon_px: f32,
}

/// Window sums of one Gauss-Newton iteration (translation model): `Σ gx·e`, `Σ gy·e`, `Σ e`,
/// `Σ e²`, `Σ |e|` with `e = I(x + d) - T(x) - offset`.
#[derive(Debug, Default)]
struct ResidualSums {
    gx_e: f32,
    gy_e: f32,
    e: f32,
    squared: f32,
    absolute: f32,
    pixels: f32,
}

impl ResidualSums {
    #[inline(always)]
    fn add(&mut self, e: f32, gx: f32, gy: f32) {
        self.gx_e += gx * e;
        self.gy_e += gy * e;
        self.e += e;
        self.squared += e * e;
        self.absolute += e.abs();
    }
}

/// The lowest-cost estimate of a level and the stall counter behind the early exit.
struct BestEstimate {
    best: Warp,
    best_squared: f32,
    mean_abs_residual: f32,
    last_mean_abs_residual: f32,
    stalled: usize,
}

impl BestEstimate {
    fn new(start: Warp) -> Self {
        BestEstimate {
            best: start,
            best_squared: f32::INFINITY,
            mean_abs_residual: f32::INFINITY,
            last_mean_abs_residual: f32::INFINITY,
            stalled: 0,
        }
    }

    /// Records the cost at `warp`; true when the cost has not improved for [`STALL_ITERATIONS`]
    /// iterations in a row, i.e. the point oscillates or diverges and further steps are wasted.
    fn observe(&mut self, warp: Warp, sums: &ResidualSums) -> bool {
        self.last_mean_abs_residual = sums.absolute / sums.pixels;
        if sums.squared < self.best_squared {
            self.best = warp;
            self.best_squared = sums.squared;
            self.mean_abs_residual = self.last_mean_abs_residual;
            self.stalled = 0;
        } else {
            self.stalled += 1;
        }
        self.stalled >= STALL_ITERATIONS
    }

    /// A converged step: its end point is kept, with the residual measured just before it.
    fn accept_last_step(&mut self, warp: Warp) {
        self.best = warp;
        self.mean_abs_residual = self.last_mean_abs_residual;
    }
}

/// Consecutive iterations without a lower sum of squared residuals after which a level stops.
/// Partial sums per quantity in the window reductions.
const LANES: usize = 8;

const STALL_ITERATIONS: usize = 8;

/// Convergence threshold on the coarse levels, pixels of that level: their result only seeds the
/// next finer level, where a remaining error of 2 × this costs one or two more iterations.
const COARSE_EPSILON_PX: f32 = 0.05;

/// True while the window around `centre` still overlaps the level (beyond it the window would see
/// only replicated border pixels).
fn near_level(level: &PyramidLevel<'_>, centre: [f32; 2], radius: f32) -> bool {
    centre[0] >= -radius
        && centre[1] >= -radius
        && centre[0] <= level.width as f32 - 1.0 + radius
        && centre[1] <= level.height as f32 - 1.0 + radius
}

fn in_image(p: [f32; 2], width: usize, height: usize) -> bool {
    p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= (width - 1) as f32 && p[1] <= (height - 1) as f32
}

/// Samples the `(2r+1)²` window `centre + A·(u, v)`, `u, v ∈ [-r, r]` (bilinear, border clamped).
fn sample_affine(
    level: &PyramidLevel<'_>,
    centre: [f32; 2],
    a: &[f32; 4],
    r: usize,
    patch: &mut [f32],
    out: &mut [f32],
) {
    if a == &[1.0, 0.0, 0.0, 1.0] {
        let side = 2 * r + 1;
        sample_translated(level, [centre[0] - r as f32, centre[1] - r as f32], side, patch, out);
        return;
    }
    let side = 2 * r + 1;
    let rf = r as f32;
    // Bounding box of the window's corners decides between the unchecked and the clamped path.
    let ext_x = rf * (a[0].abs() + a[1].abs());
    let ext_y = rf * (a[2].abs() + a[3].abs());
    let inside = centre[0] - ext_x >= 0.0
        && centre[1] - ext_y >= 0.0
        && centre[0] + ext_x < (level.width - 1) as f32
        && centre[1] + ext_y < (level.height - 1) as f32;
    let w = level.width;
    let data = level.data;
    for j in 0..side {
        let v = j as f32 - rf;
        let mut x = centre[0] - rf * a[0] + v * a[1];
        let mut y = centre[1] - rf * a[2] + v * a[3];
        let row = &mut out[j * side..(j + 1) * side];
        if inside {
            for value in row.iter_mut() {
                let (x0, y0) = (x as usize, y as usize);
                let (fx, fy) = (x - x0 as f32, y - y0 as f32);
                let i = y0 * w + x0;
                let top = data[i] + fx * (data[i + 1] - data[i]);
                let bottom = data[i + w] + fx * (data[i + w + 1] - data[i + w]);
                *value = top + fy * (bottom - top);
                x += a[0];
                y += a[2];
            }
        } else {
            for value in row.iter_mut() {
                *value = level.sample(x, y);
                x += a[0];
                y += a[2];
            }
        }
    }
}

/// Samples the `side × side` window whose top-left sample is at `top_left` (bilinear). All samples
/// share one sub-pixel fraction, so one set of weights serves the window. Outside the level the
/// row and column indices are clamped, which is exactly [`PyramidLevel::sample`]'s border rule;
/// such windows first gather their clamped `(side + 1)²` source pixels into `patch`.
fn sample_translated(level: &PyramidLevel<'_>, top_left: [f32; 2], side: usize, patch: &mut [f32], out: &mut [f32]) {
    let (fx0, fy0) = (top_left[0].floor(), top_left[1].floor());
    let (fx, fy) = if fx0.is_finite() && fy0.is_finite() { (top_left[0] - fx0, top_left[1] - fy0) } else { (0.0, 0.0) };
    let weights = [(1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy];
    // `as` saturates (NaN becomes 0), so any coordinate gives valid clamped indices below.
    let (bx, by) = (fx0 as i64, fy0 as i64);
    let (w, h) = (level.width, level.height);
    let inside = bx >= 0 && by >= 0 && bx + (side as i64) < w as i64 && by + (side as i64) < h as i64;
    if inside {
        let (bx, by) = (bx as usize, by as usize);
        interpolate(&level.data[by * w + bx..], w, side, weights, out);
        return;
    }
    let clamp_x = |x: i64| x.clamp(0, w as i64 - 1) as usize;
    let clamp_y = |y: i64| y.clamp(0, h as i64 - 1) as usize * w;
    let patch = &mut patch[..(side + 1) * (side + 1)];
    for (j, patch_row) in patch.chunks_exact_mut(side + 1).enumerate() {
        let source = &level.data[clamp_y(by.saturating_add(j as i64))..];
        for (i, value) in patch_row.iter_mut().enumerate() {
            *value = source[clamp_x(bx.saturating_add(i as i64))];
        }
    }
    interpolate(patch, side + 1, side, weights, out);
}

/// Bilinear interpolation with fixed `weights` of the `side × side` window whose top-left source
/// pixel starts `source` (row stride `stride`, at least `side + 1` columns and rows available).
#[inline]
fn interpolate(source: &[f32], stride: usize, side: usize, weights: [f32; 4], out: &mut [f32]) {
    let rows = source.chunks(stride);
    for ((top, bottom), row) in rows.clone().zip(rows.skip(1)).zip(out.chunks_exact_mut(side)) {
        let (top, bottom) = (&top[..=side], &bottom[..=side]);
        for ((((value, &a), &b), &c), &d) in row.iter_mut().zip(top).zip(&top[1..]).zip(bottom).zip(&bottom[1..]) {
            *value = weights[0] * a + weights[1] * b + weights[2] * c + weights[3] * d;
        }
    }
}
