//! Triangle rasterisation into a `1/z` buffer with a surface id and slopes per pixel.
//!
//! Vertices are snapped to 1/256 px and the edge functions evaluated exactly in integers, with a
//! top-left style tie rule: two triangles sharing an edge cover every pixel centre along it
//! exactly once, so the terrain mesh is watertight (no sky speckles between triangles, which
//! stereo matching would take for texture). Pixel centres are at integer coordinates, as in
//! [`crate::camera`]. `1/z` is affine in screen space, so it is interpolated exactly.

/// Sub-pixel precision of snapped vertices.
const SUBPIXEL: f64 = 256.0;
const SUBPIXEL_I: i64 = 256;
/// Vertices further than this off-screen are clipped in 3D first (keeps the integers small).
pub(crate) const GUARD_PX: f64 = 65_536.0;
/// Nothing closer to a camera than this is drawn.
pub(crate) const NEAR_M: f64 = 0.02;

/// 1.5 · 2⁵²: adding it to an f64 below 2⁵¹ in magnitude rounds to an integer (to even on ties)
/// that then fills the low bits of the mantissa, in two's complement.
const ROUNDING_MAGIC: f64 = 6_755_399_441_055_744.0;

/// `t` rounded to the nearest integer (ties to even), for `|t| < 2³¹` (vertices are inside the
/// guard band): one addition, no libm call (the x86-64 baseline has no rounding instruction) and
/// none of the range checks of a saturating `as`.
#[inline]
fn round_to_i32(t: f64) -> i32 {
    (t + ROUNDING_MAGIC).to_bits() as u32 as i32
}

/// A projected vertex: snapped pixel coordinates and `1/z`.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct ScreenVertex {
    pub x: i32,
    pub y: i32,
    pub inv_z: f64,
}

/// Pinhole of one camera of the pair, for projection and clipping.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pinhole {
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: usize,
    pub height: usize,
}

impl Pinhole {
    /// Projects a camera-frame point; `None` when it is behind the near plane or outside the
    /// guard band (it then needs [`clip_and_draw`]).
    #[inline]
    pub fn project(&self, p: &[f64; 3]) -> Option<ScreenVertex> {
        if p[2] <= NEAR_M {
            return None;
        }
        let inv_z = 1.0 / p[2];
        let u = self.f * p[0] * inv_z + self.cx;
        let v = self.f * p[1] * inv_z + self.cy;
        let inside = |t: f64, n: usize| t > -GUARD_PX && t < n as f64 + GUARD_PX;
        (inside(u, self.width) && inside(v, self.height)).then(|| ScreenVertex {
            x: round_to_i32(u * SUBPIXEL),
            y: round_to_i32(v * SUBPIXEL),
            inv_z,
        })
    }

    /// [`Pinhole::project`] into this camera and one `shift_m` to its right (same `1/z`, one
    /// division for both).
    #[inline]
    pub fn project_pair(&self, p: &[f64; 3], shift_m: f64) -> [Option<ScreenVertex>; 2] {
        if p[2] <= NEAR_M {
            return [None, None];
        }
        let inv_z = 1.0 / p[2];
        let u = self.f * p[0] * inv_z + self.cx;
        let u_right = u - self.f * shift_m * inv_z;
        let v = self.f * p[1] * inv_z + self.cy;
        let inside = |t: f64, n: usize| t > -GUARD_PX && t < n as f64 + GUARD_PX;
        if !inside(v, self.height) {
            return [None, None];
        }
        let y = round_to_i32(v * SUBPIXEL);
        let at = |u: f64| inside(u, self.width).then(|| ScreenVertex { x: round_to_i32(u * SUBPIXEL), y, inv_z });
        [at(u), at(u_right)]
    }

    /// Half-spaces `a·x + b·y + c·z + d ≥ 0` of the near plane and the guard band.
    fn clip_planes(&self) -> [[f64; 4]; 5] {
        let (w, h) = (self.width as f64 - 1.0, self.height as f64 - 1.0);
        // Slightly inside the guard band, so that clipped vertices project inside it.
        let g = GUARD_PX - 1.0;
        [
            [0.0, 0.0, 1.0, -NEAR_M * 1.000_001],
            [self.f, 0.0, self.cx + g, 0.0],
            [-self.f, 0.0, w + g - self.cx, 0.0],
            [0.0, self.f, self.cy + g, 0.0],
            [0.0, -self.f, h + g - self.cy, 0.0],
        ]
    }
}

/// A camera's buffers.
#[derive(Debug)]
pub(crate) struct Target<'a> {
    pub width: usize,
    pub height: usize,
    /// `1/z` of the nearest surface, 0 where nothing was drawn.
    pub inv_z: &'a mut [f32],
    pub surface: &'a mut [u32],
    /// Slopes `(dz/dx, dz/dy)` of the terrain triangle seen (world frame).
    pub slopes: &'a mut [[f32; 2]],
}

/// What a triangle leaves in the pixels it wins.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Fragment {
    pub surface: u32,
    pub slopes: [f32; 2],
}

/// Twice the signed area in sub-pixel units; positive for the orientation this module draws.
#[inline]
fn area(a: &ScreenVertex, b: &ScreenVertex, c: &ScreenVertex) -> i64 {
    (i64::from(b.x) - i64::from(a.x)) * (i64::from(c.y) - i64::from(a.y))
        - (i64::from(b.y) - i64::from(a.y)) * (i64::from(c.x) - i64::from(a.x))
}

#[inline]
fn ceil_div(a: i64, b: i64) -> i64 {
    -((-a).div_euclid(b))
}

/// Whether snapped y coordinates `a, b, c` enclose the centre of a pixel row.
#[inline]
pub(crate) fn spans_a_row(a: i32, b: i32, c: i32) -> bool {
    let (lo, hi) = (i64::from(a.min(b).min(c)), i64::from(a.max(b).max(c)));
    ceil_div(lo, SUBPIXEL_I) <= hi.div_euclid(SUBPIXEL_I)
}

/// Edge `j → k`: its function at pixel `(px, py)` (sub-pixel units, bias applied) and its steps.
#[inline]
fn edge(j: &ScreenVertex, k: &ScreenVertex, px: i64, py: i64) -> (i64, i64, i64) {
    let dx = i64::from(k.x) - i64::from(j.x);
    let dy = i64::from(k.y) - i64::from(j.y);
    let value = dx * (py - i64::from(j.y)) - dy * (px - i64::from(j.x));
    // Of the two directions of a shared edge exactly one owns the pixel centres on it.
    let owns = dy < 0 || (dy == 0 && dx > 0);
    (value - i64::from(!owns), -dy * SUBPIXEL_I, dx * SUBPIXEL_I)
}

/// Bounding boxes at least this wide get per-row spans.
const SPAN_MIN_PX: usize = 8;

/// Pixels `t` in `0..=last` where every edge `value + t · step` is non-negative, as `(first,
/// last)`. A float quotient estimates each bound (within one of the truth), exact integer tests
/// settle it.
#[inline]
fn span(edges: [(i64, i64); 3], last: usize) -> Option<(usize, usize)> {
    let (mut lo, mut hi) = (0_i64, last as i64);
    let inside = |value: i64, step: i64, t: i64| value + t * step >= 0;
    for (value, step) in edges {
        if step > 0 {
            // The first inside pixel, or last + 1 if none.
            // Truncation instead of ceil (no libm call): the corrections below fix the difference.
            let mut t = (-(value as f64) / step as f64).clamp(0.0, last as f64 + 1.0) as i64;
            while t > 0 && inside(value, step, t - 1) {
                t -= 1;
            }
            while t <= last as i64 && !inside(value, step, t) {
                t += 1;
            }
            lo = lo.max(t);
        } else if step < 0 {
            // The last inside pixel, or -1 if none.
            let mut t = (value as f64 / -(step as f64)).clamp(-1.0, last as f64) as i64;
            while t < last as i64 && inside(value, step, t + 1) {
                t += 1;
            }
            while t >= 0 && !inside(value, step, t) {
                t -= 1;
            }
            hi = hi.min(t);
        } else if value < 0 {
            return None;
        }
    }
    (lo <= hi).then_some((lo as usize, hi as usize))
}

/// Draws triangle `a, b, c` with `fragment` where it is nearer than what is there. One-sided
/// triangles are drawn only with positive [`area`] (front faces); two-sided ones either way.
/// Returns whether the triangle was front-facing and not degenerate.
pub(crate) fn triangle(
    target: &mut Target<'_>,
    a: &ScreenVertex,
    b: &ScreenVertex,
    c: &ScreenVertex,
    fragment: &Fragment,
    two_sided: bool,
) -> bool {
    // Pixel centres in the bounding box first: most distant triangles cover none.
    let min_x = a.x.min(b.x).min(c.x);
    let max_x = a.x.max(b.x).max(c.x);
    let min_y = a.y.min(b.y).min(c.y);
    let max_y = a.y.max(b.y).max(c.y);
    let x0 = ceil_div(i64::from(min_x), SUBPIXEL_I).max(0);
    let x1 = (i64::from(max_x).div_euclid(SUBPIXEL_I)).min(target.width as i64 - 1);
    let y0 = ceil_div(i64::from(min_y), SUBPIXEL_I).max(0);
    let y1 = (i64::from(max_y).div_euclid(SUBPIXEL_I)).min(target.height as i64 - 1);
    let mut twice_area = area(a, b, c);
    let (b, c) = if twice_area < 0 && two_sided {
        twice_area = -twice_area;
        (c, b)
    } else {
        (b, c)
    };
    if twice_area <= 0 {
        return false;
    }
    if x0 > x1 || y0 > y1 {
        return true;
    }
    let (px, py) = (x0 * SUBPIXEL_I, y0 * SUBPIXEL_I);
    // Edge opposite a is b → c, and so on: each edge function is a's (b's, c's) barycentric weight.
    let (mut row0, dx0, dy0) = edge(b, c, px, py);
    let (mut row1, dx1, dy1) = edge(c, a, px, py);
    let (mut row2, dx2, dy2) = edge(a, b, px, py);
    let inv_area = 1.0 / twice_area as f64;
    let plane = |w0: f64, w1: f64, w2: f64| (w0 * a.inv_z + w1 * b.inv_z + w2 * c.inv_z) * inv_area;
    let mut row_iz = plane(row0 as f64, row1 as f64, row2 as f64);
    let iz_dx = plane(dx0 as f64, dx1 as f64, dx2 as f64);
    let iz_dy = plane(dy0 as f64, dy1 as f64, dy2 as f64);
    let width = target.width;
    let (x0, x1) = (x0 as usize, x1 as usize);
    // Wide boxes are mostly outside the triangle: there each row's inside span is computed
    // once and only the depth is tested; narrow ones are scanned with the edge functions.
    let spans = x1 - x0 >= SPAN_MIN_PX;
    for y in y0 as usize..=y1 as usize {
        let line = y * width + x0;
        if spans {
            if let Some((first, last)) = span([(row0, dx0), (row1, dx1), (row2, dx2)], x1 - x0) {
                let start_iz = row_iz + first as f64 * iz_dx;
                let depth = &mut target.inv_z[line + first..=line + last];
                let ids = &mut target.surface[line + first..=line + last];
                let slopes = &mut target.slopes[line + first..=line + last];
                // `1/z` from the pixel's offset rather than by accumulation: no chain of
                // dependent additions.
                for (t, ((d, id), sl)) in depth.iter_mut().zip(ids.iter_mut()).zip(slopes.iter_mut()).enumerate() {
                    let iz = (start_iz + t as f64 * iz_dx) as f32;
                    let nearer = iz > *d;
                    *d = if nearer { iz } else { *d };
                    *id = if nearer { fragment.surface } else { *id };
                    *sl = if nearer { fragment.slopes } else { *sl };
                }
            }
        } else {
            let (mut e0, mut e1, mut e2, mut iz) = (row0, row1, row2, row_iz);
            let depth = &mut target.inv_z[line..=line + x1 - x0];
            let ids = &mut target.surface[line..=line + x1 - x0];
            let slopes = &mut target.slopes[line..=line + x1 - x0];
            for ((d, id), sl) in depth.iter_mut().zip(ids.iter_mut()).zip(slopes.iter_mut()) {
                // Selects rather than branches: whether a nearer surface is already there is
                // unpredictable (chunks are not drawn front to back).
                let nearer = ((e0 | e1 | e2) >= 0) & (iz as f32 > *d);
                *d = if nearer { iz as f32 } else { *d };
                *id = if nearer { fragment.surface } else { *id };
                *sl = if nearer { fragment.slopes } else { *sl };
                e0 += dx0;
                e1 += dx1;
                e2 += dx2;
                iz += iz_dx;
            }
        }
        row0 += dy0;
        row1 += dy1;
        row2 += dy2;
        row_iz += iz_dy;
    }
    true
}

/// Whether snapped y coordinates of a square's corners enclose the centre of a pixel row.
#[inline]
pub(crate) fn square_spans_a_row(a: i32, b: i32, c: i32, d: i32) -> bool {
    spans_a_row(a.min(b), c.min(d), a.max(b).max(c).max(d))
}

/// Draws the mesh square `a00, a10, a11, a01` as its two one-sided triangles `(a00, a11, a10)`
/// with `lower` and `(a00, a01, a11)` with `upper`, covering exactly the pixels two [`triangle`]
/// calls would: a square a few pixels wide (most of a distant mesh) in one pass over its box,
/// anything else as the two triangles.
pub(crate) fn square(target: &mut Target<'_>, corners: [&ScreenVertex; 4], lower: &Fragment, upper: &Fragment) {
    let [a00, a10, a11, a01] = corners;
    let min_x = a00.x.min(a10.x).min(a11.x).min(a01.x);
    let max_x = a00.x.max(a10.x).max(a11.x).max(a01.x);
    let min_y = a00.y.min(a10.y).min(a11.y).min(a01.y);
    let max_y = a00.y.max(a10.y).max(a11.y).max(a01.y);
    let x0 = ceil_div(i64::from(min_x), SUBPIXEL_I).max(0);
    let x1 = (i64::from(max_x).div_euclid(SUBPIXEL_I)).min(target.width as i64 - 1);
    let y0 = ceil_div(i64::from(min_y), SUBPIXEL_I).max(0);
    let y1 = (i64::from(max_y).div_euclid(SUBPIXEL_I)).min(target.height as i64 - 1);
    // No pixel centre in the square's box: none in either triangle's.
    if x0 > x1 || y0 > y1 {
        return;
    }
    let (area_lower, area_upper) = (area(a00, a11, a10), area(a00, a01, a11));
    if x1 - x0 >= SPAN_MIN_PX as i64 || area_lower <= 0 || area_upper <= 0 {
        triangle(target, a00, a11, a10, lower, false);
        triangle(target, a00, a01, a11, upper, false);
        return;
    }
    let (px, py) = (x0 * SUBPIXEL_I, y0 * SUBPIXEL_I);
    // The edge functions of each triangle as `triangle` sets them up (weights of a00, a11, a10
    // and of a00, a01, a11); the diagonal's tie rule gives its pixel centres to one of the two.
    let lower_edges = [edge(a11, a10, px, py), edge(a10, a00, px, py), edge(a00, a11, px, py)];
    let upper_edges = [edge(a01, a11, px, py), edge(a11, a00, px, py), edge(a00, a01, px, py)];
    let plane = |edges: &[(i64, i64, i64); 3], z: [f64; 3], twice_area: i64| {
        let inv_area = 1.0 / twice_area as f64;
        let at = |w: [i64; 3]| (w[0] as f64 * z[0] + w[1] as f64 * z[1] + w[2] as f64 * z[2]) * inv_area;
        (at(edges.map(|e| e.0)), at(edges.map(|e| e.1)), at(edges.map(|e| e.2)))
    };
    let (mut lower_row_iz, lower_dx, lower_dy) = plane(&lower_edges, [a00.inv_z, a11.inv_z, a10.inv_z], area_lower);
    let (mut upper_row_iz, upper_dx, upper_dy) = plane(&upper_edges, [a00.inv_z, a01.inv_z, a11.inv_z], area_upper);
    let mut lower_row = lower_edges.map(|e| e.0);
    let mut upper_row = upper_edges.map(|e| e.0);
    let (lower_step, upper_step) = (lower_edges.map(|e| e.1), upper_edges.map(|e| e.1));
    let width = target.width;
    let (x0, x1) = (x0 as usize, x1 as usize);
    for y in y0 as usize..=y1 as usize {
        let line = y * width + x0;
        let (mut l, mut u, mut lower_iz, mut upper_iz) = (lower_row, upper_row, lower_row_iz, upper_row_iz);
        let depth = &mut target.inv_z[line..=line + x1 - x0];
        let ids = &mut target.surface[line..=line + x1 - x0];
        let slopes = &mut target.slopes[line..=line + x1 - x0];
        for ((d, id), sl) in depth.iter_mut().zip(ids.iter_mut()).zip(slopes.iter_mut()) {
            let in_lower = (l[0] | l[1] | l[2]) >= 0;
            let in_upper = (u[0] | u[1] | u[2]) >= 0;
            let (iz, fragment) = if in_lower { (lower_iz, lower) } else { (upper_iz, upper) };
            // Selects rather than branches, as in `triangle`.
            let nearer = (in_lower | in_upper) & (iz as f32 > *d);
            *d = if nearer { iz as f32 } else { *d };
            *id = if nearer { fragment.surface } else { *id };
            *sl = if nearer { fragment.slopes } else { *sl };
            for k in 0..3 {
                l[k] += lower_step[k];
                u[k] += upper_step[k];
            }
            lower_iz += lower_dx;
            upper_iz += upper_dx;
        }
        for k in 0..3 {
            lower_row[k] += lower_edges[k].2;
            upper_row[k] += upper_edges[k].2;
        }
        lower_row_iz += lower_dy;
        upper_row_iz += upper_dy;
    }
}

/// Draws a triangle given in the camera frame that [`Pinhole::project`] could not project as a
/// whole: clipped against the near plane and the guard band, then drawn as a fan.
pub(crate) fn clip_and_draw(
    target: &mut Target<'_>,
    pinhole: &Pinhole,
    points: [[f64; 3]; 3],
    fragment: &Fragment,
    two_sided: bool,
) {
    const MAX: usize = 3 + 5;
    let mut poly = [[0.0; 3]; MAX];
    let mut next = [[0.0; 3]; MAX];
    poly[..3].copy_from_slice(&points);
    let mut n = 3;
    for plane in pinhole.clip_planes() {
        let dist = |p: &[f64; 3]| plane[0] * p[0] + plane[1] * p[1] + plane[2] * p[2] + plane[3];
        let mut m = 0;
        for i in 0..n {
            let (p, q) = (poly[i], poly[(i + 1) % n]);
            let (dp, dq) = (dist(&p), dist(&q));
            if dp >= 0.0 {
                next[m] = p;
                m += 1;
            }
            if (dp >= 0.0) != (dq >= 0.0) {
                let t = dp / (dp - dq);
                next[m] = [p[0] + t * (q[0] - p[0]), p[1] + t * (q[1] - p[1]), p[2] + t * (q[2] - p[2])];
                m += 1;
            }
        }
        poly[..m].copy_from_slice(&next[..m]);
        n = m;
        if n < 3 {
            return;
        }
    }
    let mut screen = [ScreenVertex::default(); MAX];
    for i in 0..n {
        match pinhole.project(&poly[i]) {
            Some(s) => screen[i] = s,
            // Rounding put a clipped vertex a hair outside: the sliver is invisible.
            None => return,
        }
    }
    for i in 1..n - 1 {
        triangle(target, &screen[0], &screen[i], &screen[i + 1], fragment, two_sided);
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    fn vertex(x: f64, y: f64) -> ScreenVertex {
        ScreenVertex { x: (x * SUBPIXEL) as i32, y: (y * SUBPIXEL) as i32, inv_z: 1.0 }
    }

    #[test]
    fn a_split_square_covers_every_pixel_once() {
        // Pixel centres lie exactly on the square's edges and on its diagonal: the tie rule must
        // give each of them to exactly one triangle (counted through a per-triangle id).
        let (w, h) = (12, 12);
        let mut inv_z = vec![0.0; w * h];
        let mut surface = vec![0; w * h];
        let mut slopes = vec![[0.0; 2]; w * h];
        let mut counts = vec![0u32; w * h];
        let quad = [vertex(2.0, 2.0), vertex(9.0, 2.0), vertex(9.0, 9.0), vertex(2.0, 9.0)];
        for (id, (a, b, c)) in [(0, 1, 2), (0, 2, 3)].into_iter().enumerate() {
            inv_z.fill(0.0);
            let mut target =
                Target { width: w, height: h, inv_z: &mut inv_z, surface: &mut surface, slopes: &mut slopes };
            let fragment = Fragment { surface: id as u32 + 1, slopes: [0.0; 2] };
            triangle(&mut target, &quad[a], &quad[b], &quad[c], &fragment, true);
            for (count, &z) in counts.iter_mut().zip(&inv_z) {
                *count += u32::from(z > 0.0);
            }
        }
        // The closed square [2, 9]² has 8 × 8 centres; the tie rule drops two of its four sides.
        let covered = counts.iter().filter(|&&c| c == 1).count();
        assert!(counts.iter().all(|&c| c <= 1), "a pixel was drawn by both triangles");
        assert_eq!(covered, 7 * 7);
    }

    #[test]
    fn spans_are_exactly_the_inside_pixels() {
        let mut rng = crate::rng::stream(5, &[99]);
        let mut draw = |range: f64| (rng.uniform() - 0.5) * range;
        for case in 0..20_000 {
            let last = (draw(80.0).abs() as usize).max(1);
            let edges: [(i64, i64); 3] = std::array::from_fn(|_| {
                let step = draw(if case % 3 == 0 { 6.0 } else { 4e5 }) as i64;
                // Every fifth case puts a pixel exactly on the edge (value 0 there).
                let value = if case % 5 == 0 { -step * (draw(100.0) as i64) } else { draw(3e7) as i64 };
                (value, step)
            });
            let brute: Vec<usize> = (0..=last).filter(|&t| edges.iter().all(|&(v, s)| v + t as i64 * s >= 0)).collect();
            let expected = brute.first().map(|&first| (first, *brute.last().unwrap()));
            assert_eq!(span(edges, last), expected, "edges {edges:?}, last {last}");
        }
    }

    #[test]
    fn a_square_covers_what_its_two_triangles_cover() {
        // Small jittered squares (the one-pass path) and larger ones (two triangles), drawn over
        // a random depth background: same winners, same ids and slopes, same depth to rounding.
        let (w, h) = (24, 24);
        let mut rng = crate::rng::stream(6, &[98]);
        let mut drawn = [0; 3];
        for case in 0..3_000 {
            let size = if case % 4 == 0 { 12.0 } else { 1.0 + 4.0 * rng.uniform() };
            let (cx, cy) = (4.0 + 14.0 * rng.uniform(), 4.0 + 14.0 * rng.uniform());
            let mut jitter = |x: f64, y: f64| ScreenVertex {
                x: ((x + 0.3 * size * (rng.uniform() - 0.5)) * SUBPIXEL) as i32,
                y: ((y + 0.3 * size * (rng.uniform() - 0.5)) * SUBPIXEL) as i32,
                inv_z: 0.2 + 0.1 * rng.uniform(),
            };
            // Clockwise on screen (y down): the front-face order of the terrain mesh.
            let a00 = jitter(cx, cy + size);
            let a10 = jitter(cx + size, cy + size);
            let a11 = jitter(cx + size, cy);
            let a01 = jitter(cx, cy);
            let background: Vec<f32> = (0..w * h).map(|_| 0.25 * rng.uniform() as f32).collect();
            let lower = Fragment { surface: 1, slopes: [0.5, -0.25] };
            let upper = Fragment { surface: 2, slopes: [-0.75, 0.125] };
            let draw = |one_pass: bool| {
                let mut inv_z = background.clone();
                let mut surface = vec![0; w * h];
                let mut slopes = vec![[0.0; 2]; w * h];
                let mut target =
                    Target { width: w, height: h, inv_z: &mut inv_z, surface: &mut surface, slopes: &mut slopes };
                if one_pass {
                    square(&mut target, [&a00, &a10, &a11, &a01], &lower, &upper);
                } else {
                    triangle(&mut target, &a00, &a11, &a10, &lower, false);
                    triangle(&mut target, &a00, &a01, &a11, &upper, false);
                }
                (inv_z, surface, slopes)
            };
            let (z1, id1, sl1) = draw(true);
            let (z2, id2, sl2) = draw(false);
            for id in &id1 {
                drawn[*id as usize] += 1;
            }
            assert_eq!(id1, id2, "case {case}");
            assert_eq!(sl1, sl2, "case {case}");
            for (a, b) in z1.iter().zip(&z2) {
                assert!((a - b).abs() <= 1e-6 * b.abs(), "case {case}: {a} vs {b}");
            }
        }
        // Both triangles won pixels, in thousands of cases.
        assert!(drawn[1] > 10_000 && drawn[2] > 10_000, "{drawn:?}");
    }

    #[test]
    fn back_faces_are_culled_unless_two_sided() {
        let (w, h) = (8, 8);
        let mut inv_z = vec![0.0; w * h];
        let mut surface = vec![0; w * h];
        let mut slopes = vec![[0.0; 2]; w * h];
        let mut target = Target { width: w, height: h, inv_z: &mut inv_z, surface: &mut surface, slopes: &mut slopes };
        let (a, b, c) = (vertex(1.0, 1.0), vertex(6.0, 1.0), vertex(1.0, 6.0));
        let fragment = Fragment { surface: 1, slopes: [0.5, -0.25] };
        let front = area(&a, &b, &c) > 0;
        let (a, b, c) = if front { (a, c, b) } else { (a, b, c) };
        assert!(!triangle(&mut target, &a, &b, &c, &fragment, false));
        assert!(target.inv_z.iter().all(|&z| z == 0.0));
        assert!(triangle(&mut target, &a, &b, &c, &fragment, true));
        assert!(target.inv_z.iter().any(|&z| z > 0.0));
        for ((&z, &id), &sl) in target.inv_z.iter().zip(target.surface.iter()).zip(target.slopes.iter()) {
            assert_eq!((id, sl), if z > 0.0 { (1, [0.5, -0.25]) } else { (0, [0.0; 2]) });
        }
    }
}
