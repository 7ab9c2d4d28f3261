//! Quad fitting: four straight edges through a cluster's boundary points.
//!
//! The points are sorted by their angle about the cluster's centre, so that a quad's four edges
//! are four consecutive runs of points. Weighted line-fit moments are accumulated along that
//! order (weight: the image gradient magnitude + 1), which makes the fit of any run O(1). The
//! corners are where the fit error of a window sliding along the outline peaks: the best
//! `max_nmaxima` peaks of the (lightly smoothed) error are candidates, and the four whose edges
//! have the smallest total squared error win, subject to every edge's mean squared error staying
//! below `max_line_fit_mse` and adjacent edges meeting at more than the critical angle. The
//! corners are the intersections of the four fitted lines; quads that are too small, not convex,
//! not clockwise on screen (the order of increasing angle with y down) or have too sharp a
//! corner are dropped.

use super::clusters::Pt;

/// What a quad must satisfy (from the detector's configuration).
#[derive(Debug, Clone, Copy)]
pub(crate) struct QuadParams {
    pub max_nmaxima: usize,
    /// Cosine of the critical angle: adjacent edges must be further from parallel than this.
    pub cos_critical: f64,
    pub max_line_fit_mse: f64,
    /// Smallest tag edge in (decimated) pixels; the quad's area must reach its square.
    pub min_tag_width: f64,
}

/// Corners in pixels (our convention: pixel centres at integers), clockwise on screen; corner
/// `i` is where edge `i` meets edge `i + 1`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Quad {
    pub p: [[f64; 2]; 4],
}

/// Cumulative weighted moments of the points `0 ..= i`.
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    mx: f64,
    my: f64,
    mxx: f64,
    mxy: f64,
    myy: f64,
    w: f64,
}

impl Moments {
    fn sub(self, o: Moments) -> Moments {
        Moments {
            mx: self.mx - o.mx,
            my: self.my - o.my,
            mxx: self.mxx - o.mxx,
            mxy: self.mxy - o.mxy,
            myy: self.myy - o.myy,
            w: self.w - o.w,
        }
    }

    fn add(self, o: Moments) -> Moments {
        Moments {
            mx: self.mx + o.mx,
            my: self.my + o.my,
            mxx: self.mxx + o.mxx,
            mxy: self.mxy + o.mxy,
            myy: self.myy + o.myy,
            w: self.w + o.w,
        }
    }
}

/// A fitted line: a point on it (the weighted mean) and its unit normal.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Line {
    pub point: [f64; 2],
    pub normal: [f64; 2],
}

/// The line through weighted moments (centroid, normal = eigenvector of the smaller eigenvalue of
/// the covariance) and that eigenvalue, the mean squared distance of the points from the line.
pub(crate) fn line_from_moments(w: f64, mx: f64, my: f64, mxx: f64, mxy: f64, myy: f64) -> (Line, f64) {
    let (ex, ey) = (mx / w, my / w);
    let cxx = mxx / w - ex * ex;
    let cxy = mxy / w - ex * ey;
    let cyy = myy / w - ey * ey;
    let root = ((cxx - cyy) * (cxx - cyy) + 4.0 * cxy * cxy).sqrt();
    let small = 0.5 * (cxx + cyy - root);
    let large = 0.5 * (cxx + cyy + root);
    // Rows of (C − λ_large·I) are orthogonal to the major axis: take the longer one as normal.
    let (n1, n2) = ([cxx - large, cxy], [cxy, cyy - large]);
    let (m1, m2) = (n1[0] * n1[0] + n1[1] * n1[1], n2[0] * n2[0] + n2[1] * n2[1]);
    let (n, m) = if m1 > m2 { (n1, m1) } else { (n2, m2) };
    let normal = if m > 0.0 {
        let len = m.sqrt();
        [n[0] / len, n[1] / len]
    } else {
        // Isotropic points: any direction fits equally (badly).
        [1.0, 0.0]
    };
    (Line { point: [ex, ey], normal }, small)
}

/// Where two lines cross, `None` when they are closer to parallel than ~0.06°.
pub(crate) fn intersect(a: &Line, b: &Line) -> Option<[f64; 2]> {
    // Directions are the normals turned by a quarter.
    let (da, db) = ([a.normal[1], -a.normal[0]], [b.normal[1], -b.normal[0]]);
    let cross = da[0] * db[1] - da[1] * db[0];
    if cross.abs() < 1e-3 || !cross.is_finite() {
        return None;
    }
    let d = [b.point[0] - a.point[0], b.point[1] - a.point[1]];
    let s = (d[0] * db[1] - d[1] * db[0]) / cross;
    Some([a.point[0] + s * da[0], a.point[1] + s * da[1]])
}

/// Monotonic in the angle `atan2(dy, dx)` over (−π, π], cheaper than it: (−2, 2].
fn angle_key(dx: f32, dy: f32) -> f32 {
    let t = dy / (dx.abs() + dy.abs());
    if dx >= 0.0 {
        t
    } else if dy >= 0.0 {
        2.0 - t
    } else {
        -2.0 - t
    }
}

/// The error smoothing kernel: a Gaussian with σ = 1 point out to where it falls below 0.05.
const SMOOTHING: [f64; 7] = [
    0.011_108_996_538_242_306,
    0.135_335_283_236_612_7,
    0.606_530_659_712_633_4,
    1.0,
    0.606_530_659_712_633_4,
    0.135_335_283_236_612_7,
    0.011_108_996_538_242_306,
];

/// A candidate edge's line normal, mean and summed squared error.
#[derive(Debug, Clone, Copy, Default)]
struct EdgeFit {
    normal: [f64; 2],
    mse: f64,
    err: f64,
}

/// Scratch buffers of the quad fit, kept between clusters and frames.
#[derive(Debug, Default)]
pub(crate) struct QuadFitter {
    moments: Vec<Moments>,
    errs: Vec<f64>,
    smoothed: Vec<f64>,
    maxima: Vec<usize>,
    maxima_errs: Vec<f64>,
    sorted_errs: Vec<f64>,
    /// Edge fits between corner candidates.
    fits: Vec<EdgeFit>,
    /// Angle sort: bucket offsets and the sorted copy.
    bucket_start: Vec<u32>,
    sorted: Vec<Pt>,
    /// Origin of the moments (the cluster's box centre), for precision.
    origin: [f64; 2],
}

impl QuadFitter {
    /// Fits a quad to `cluster` (sorted and deduplicated in place), whose points lie in `image`
    /// (`width × height`, the image the clusters were found in).
    pub(crate) fn fit(
        &mut self,
        params: &QuadParams,
        image: &[u8],
        width: usize,
        height: usize,
        cluster: &mut [Pt],
    ) -> Option<Quad> {
        // Ample points for four edges (and the same bound again after deduplication).
        const MIN_POINTS: usize = 24;
        if cluster.len() < MIN_POINTS {
            return None;
        }
        let (mut xmin, mut xmax, mut ymin, mut ymax) = (u16::MAX, 0u16, u16::MAX, 0u16);
        for p in cluster.iter() {
            xmin = xmin.min(p.x);
            xmax = xmax.max(p.x);
            ymin = ymin.min(p.y);
            ymax = ymax.max(p.y);
        }
        // Box area in doubled coordinates against the tag width (the upstream test, lenient).
        if f64::from(xmax - xmin) * f64::from(ymax - ymin) < params.min_tag_width {
            return None;
        }
        // A centre slightly off the half-pixel grid, so that no point sits on it and points on
        // one line from the centre are rare.
        let cx = 0.5 * (f32::from(xmin) + f32::from(xmax)) + 0.05118;
        let cy = 0.5 * (f32::from(ymin) + f32::from(ymax)) - 0.028581;
        let mut dot = 0.0f32;
        for p in cluster.iter_mut() {
            let (dx, dy) = (f32::from(p.x) - cx, f32::from(p.y) - cy);
            dot += dx * f32::from(p.gx) + dy * f32::from(p.gy);
            p.slope = angle_key(dx, dy);
        }
        // Gradients point towards white: outwards for a black square in a white border.
        if dot < 0.0 {
            return None;
        }
        self.sort_by_angle(cluster);
        // Points reached from two pixel pairs (crossing diagonals) appear twice.
        let mut n = 1;
        for i in 1..cluster.len() {
            if cluster[i].x != cluster[n - 1].x || cluster[i].y != cluster[n - 1].y {
                cluster[n] = cluster[i];
                n += 1;
            }
        }
        let cluster = &cluster[..n];
        if n < MIN_POINTS {
            return None;
        }
        self.origin = [0.25 * (f64::from(xmin) + f64::from(xmax)), 0.25 * (f64::from(ymin) + f64::from(ymax))];
        self.accumulate(cluster, image, width, height);
        let indices = self.segment(params, n)?;

        let mut lines = [Line::default(); 4];
        for (i, line) in lines.iter_mut().enumerate() {
            let (l, mse) = self.fit_line(indices[i], indices[(i + 1) % 4]);
            if mse > params.max_line_fit_mse {
                return None;
            }
            *line = l;
        }
        let mut p = [[0.0; 2]; 4];
        for i in 0..4 {
            let c = intersect(&lines[i], &lines[(i + 1) % 4])?;
            p[i] = [c[0] + self.origin[0], c[1] + self.origin[1]];
        }
        let quad = Quad { p };
        quad_is_plausible(&quad, params).then_some(quad)
    }

    /// Sorts by angle key: a counting sort into as many buckets as points (the keys spread over
    /// (−2, 2] around an outline), then an insertion sort that only reorders within buckets.
    /// Stable, O(n) for outlines.
    fn sort_by_angle(&mut self, cluster: &mut [Pt]) {
        let n = cluster.len();
        let scale = n as f32 / 4.0;
        let bucket = |key: f32| (((key + 2.0) * scale) as usize).min(n - 1);
        self.bucket_start.clear();
        self.bucket_start.resize(n + 1, 0);
        for p in cluster.iter() {
            self.bucket_start[bucket(p.slope) + 1] += 1;
        }
        for b in 1..=n {
            self.bucket_start[b] += self.bucket_start[b - 1];
        }
        self.sorted.clear();
        self.sorted.resize(n, Pt::default());
        for p in cluster.iter() {
            let slot = &mut self.bucket_start[bucket(p.slope)];
            self.sorted[*slot as usize] = *p;
            *slot += 1;
        }
        for i in 1..n {
            let p = self.sorted[i];
            let mut j = i;
            while j > 0 && self.sorted[j - 1].slope > p.slope {
                self.sorted[j] = self.sorted[j - 1];
                j -= 1;
            }
            self.sorted[j] = p;
        }
        cluster.copy_from_slice(&self.sorted);
    }

    /// Cumulative moments of the sorted points, relative to `origin`.
    fn accumulate(&mut self, cluster: &[Pt], image: &[u8], width: usize, height: usize) {
        self.moments.clear();
        let mut acc = Moments::default();
        for p in cluster {
            // The nearest pixel to the boundary point (x = column + 0.5 for a horizontal pair).
            let (ix, iy) = (usize::from(p.x).div_ceil(2), usize::from(p.y).div_ceil(2));
            let weight = if ix > 0 && ix + 1 < width && iy > 0 && iy + 1 < height {
                let gx = f64::from(image[iy * width + ix + 1]) - f64::from(image[iy * width + ix - 1]);
                let gy = f64::from(image[(iy + 1) * width + ix]) - f64::from(image[(iy - 1) * width + ix]);
                (gx * gx + gy * gy).sqrt() + 1.0
            } else {
                1.0
            };
            let x = 0.5 * f64::from(p.x) - self.origin[0];
            let y = 0.5 * f64::from(p.y) - self.origin[1];
            acc.mx += weight * x;
            acc.my += weight * y;
            acc.mxx += weight * x * x;
            acc.mxy += weight * x * y;
            acc.myy += weight * y * y;
            acc.w += weight;
            self.moments.push(acc);
        }
    }

    /// Summed moments of points `i0 ..= i1` (wrapping around when `i1 < i0`) from the prefix sums,
    /// and how many points that is.
    fn window_moments(&self, i0: usize, i1: usize) -> (Moments, usize) {
        let n = self.moments.len();
        if i0 < i1 {
            let m = if i0 > 0 { self.moments[i1].sub(self.moments[i0 - 1]) } else { self.moments[i1] };
            (m, i1 - i0 + 1)
        } else {
            let tail = if i0 > 0 { self.moments[n - 1].sub(self.moments[i0 - 1]) } else { self.moments[n - 1] };
            (tail.add(self.moments[i1]), n - i0 + i1 + 1)
        }
    }

    /// Line through points `i0 ..= i1` (wrapping around when `i1 < i0`), its mean squared
    /// error, and (third) the summed squared error `points × mse`.
    fn fit_line_err(&self, i0: usize, i1: usize) -> (Line, f64, f64) {
        let (m, count) = self.window_moments(i0, i1);
        let (line, mse) = line_from_moments(m.w, m.mx, m.my, m.mxx, m.mxy, m.myy);
        (line, mse, count as f64 * mse)
    }

    /// Summed squared error of the line through points `i0 ..= i1` (wrapping), without the line.
    fn window_err(&self, i0: usize, i1: usize) -> f64 {
        let (m, count) = self.window_moments(i0, i1);
        let inv = 1.0 / m.w;
        let (ex, ey) = (m.mx * inv, m.my * inv);
        let cxx = m.mxx * inv - ex * ex;
        let cxy = m.mxy * inv - ex * ey;
        let cyy = m.myy * inv - ey * ey;
        let small = 0.5 * (cxx + cyy - ((cxx - cyy) * (cxx - cyy) + 4.0 * cxy * cxy).sqrt());
        count as f64 * small
    }

    fn fit_line(&self, i0: usize, i1: usize) -> (Line, f64) {
        let (line, mse, _) = self.fit_line_err(i0, i1);
        (line, mse)
    }

    /// The four corner indices (ascending), from the peaks of the windowed line-fit error.
    fn segment(&mut self, params: &QuadParams, n: usize) -> Option<[usize; 4]> {
        // Half window: about half the shortest edge's points, smaller for tags seen at an angle.
        let k = (n / 12).min(20);
        if k < 2 {
            return None;
        }
        // The window errors, with the smoothing kernel's half width wrapped around on both ends:
        // `errs[half + c]` is point c's.
        let half = SMOOTHING.len() / 2;
        self.errs.clear();
        self.errs.resize(n + 2 * half, 0.0);
        for c in 0..n {
            let a = if c >= k { c - k } else { c + n - k };
            let b = if c + k < n { c + k } else { c + k - n };
            self.errs[half + c] = self.window_err(a, b);
        }
        for j in 0..half {
            self.errs[j] = self.errs[n + j];
            self.errs[n + half + j] = self.errs[half + j];
        }
        self.smoothed.clear();
        for window in self.errs.windows(SMOOTHING.len()) {
            self.smoothed.push(window.iter().zip(&SMOOTHING).map(|(e, f)| e * f).sum());
        }
        self.maxima.clear();
        self.maxima_errs.clear();
        for i in 0..n {
            let e = self.smoothed[i];
            let (prev, next) = (if i == 0 { n - 1 } else { i - 1 }, if i + 1 == n { 0 } else { i + 1 });
            if e > self.smoothed[next] && e > self.smoothed[prev] {
                self.maxima.push(i);
                self.maxima_errs.push(e);
            }
        }
        if self.maxima.len() < 4 {
            return None;
        }
        if self.maxima.len() > params.max_nmaxima {
            // Keep the peaks above the (max_nmaxima + 1)-th highest.
            self.sorted_errs.clear();
            self.sorted_errs.extend_from_slice(&self.maxima_errs);
            self.sorted_errs.sort_unstable_by(|a, b| b.total_cmp(a));
            let threshold = self.sorted_errs[params.max_nmaxima];
            let mut kept = 0;
            for j in 0..self.maxima.len() {
                if self.maxima_errs[j] > threshold {
                    self.maxima[kept] = self.maxima[j];
                    kept += 1;
                }
            }
            self.maxima.truncate(kept);
        }
        // Every edge between two candidates, fitted once: `fits[a * count + b]` runs from
        // candidate a to candidate b (wrapping around when b < a).
        let count = self.maxima.len();
        self.fits.clear();
        for a in 0..count {
            for b in 0..count {
                let fit = if a == b {
                    EdgeFit::default()
                } else {
                    let (line, mse, err) = self.fit_line_err(self.maxima[a], self.maxima[b]);
                    EdgeFit { normal: line.normal, mse, err }
                };
                self.fits.push(fit);
            }
        }
        let fit = |a: usize, b: usize| &self.fits[a * count + b];
        let max_mse = params.max_line_fit_mse;
        let mut best = f64::INFINITY;
        let mut best_indices = [0usize; 4];
        for a in 0..count.saturating_sub(3) {
            for b in a + 1..count - 2 {
                let f01 = fit(a, b);
                if f01.mse > max_mse {
                    continue;
                }
                for c in b + 1..count - 1 {
                    let f12 = fit(b, c);
                    if f12.mse > max_mse {
                        continue;
                    }
                    let cos = f01.normal[0] * f12.normal[0] + f01.normal[1] * f12.normal[1];
                    if cos.abs() > params.cos_critical {
                        continue;
                    }
                    for d in c + 1..count {
                        let (f23, f30) = (fit(c, d), fit(d, a));
                        if f23.mse > max_mse || f30.mse > max_mse {
                            continue;
                        }
                        let err = f01.err + f12.err + f23.err + f30.err;
                        if err < best {
                            best = err;
                            best_indices = [self.maxima[a], self.maxima[b], self.maxima[c], self.maxima[d]];
                        }
                    }
                }
            }
        }
        (best.is_finite() && best / (n as f64) < max_mse).then_some(best_indices)
    }

    /// Capacities of the buffers (for the no-allocation check).
    #[cfg(test)]
    pub(crate) fn capacities(&self) -> [usize; 9] {
        [
            self.moments.capacity(),
            self.errs.capacity(),
            self.smoothed.capacity(),
            self.maxima.capacity(),
            self.maxima_errs.capacity(),
            self.sorted_errs.capacity(),
            self.fits.capacity(),
            self.bucket_start.capacity(),
            self.sorted.capacity(),
        ]
    }
}

/// Area, convexity, winding and corner-angle checks.
fn quad_is_plausible(quad: &Quad, params: &QuadParams) -> bool {
    let p = &quad.p;
    let cross = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    // Two triangles (0, 1, 2) and (2, 3, 0).
    let area = 0.5 * (cross(p[0], p[1], p[2]).abs() + cross(p[2], p[3], p[0]).abs());
    if !(area >= params.min_tag_width * params.min_tag_width) {
        return false;
    }
    for i in 0..4 {
        let (a, b, c) = (p[i], p[(i + 1) % 4], p[(i + 2) % 4]);
        let (d1, d2) = ([b[0] - a[0], b[1] - a[1]], [c[0] - b[0], c[1] - b[1]]);
        let cos = (d1[0] * d2[0] + d1[1] * d2[1])
            / ((d1[0] * d1[0] + d1[1] * d1[1]) * (d2[0] * d2[0] + d2[1] * d2[1])).sqrt();
        let turn = d1[0] * d2[1] - d1[1] * d2[0];
        if !(cos.abs() <= params.cos_critical) || turn < 0.0 {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn angle_key_is_monotonic_in_the_angle() {
        let mut last = f32::NEG_INFINITY;
        for k in 1..=3600 {
            let a = -std::f64::consts::PI + f64::from(k) * std::f64::consts::TAU / 3600.0;
            let key = angle_key(a.cos() as f32, a.sin() as f32);
            assert!(key > last, "angle {a}: {key} after {last}");
            last = key;
        }
    }

    #[test]
    fn lines_fit_and_cross() {
        // Points on y = 2x + 1 and on x = 3.
        let pts: Vec<[f64; 2]> = (0..10).map(|i| [f64::from(i), 2.0 * f64::from(i) + 1.0]).collect();
        let mut m = [0.0; 6];
        for p in &pts {
            m[0] += 1.0;
            m[1] += p[0];
            m[2] += p[1];
            m[3] += p[0] * p[0];
            m[4] += p[0] * p[1];
            m[5] += p[1] * p[1];
        }
        let (line, mse) = line_from_moments(m[0], m[1], m[2], m[3], m[4], m[5]);
        assert!(mse.abs() < 1e-9);
        let vertical = Line { point: [3.0, 0.0], normal: [1.0, 0.0] };
        let c = intersect(&line, &vertical).unwrap();
        assert!((c[0] - 3.0).abs() < 1e-9 && (c[1] - 7.0).abs() < 1e-9, "{c:?}");
        assert_eq!(intersect(&vertical, &Line { point: [5.0, 1.0], normal: [-1.0, 0.0] }), None);
    }
}
