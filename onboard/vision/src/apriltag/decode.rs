//! From a quad to a tag: the homography, the border's grey-level models, bit sampling with
//! sharpening, and the decision margin.

use super::family::{CodeIndex, Decoded, TagFamily};

/// Largest `total_width` the sampling grid holds.
pub(crate) const MAX_TOTAL_WIDTH: usize = 16;

/// A plane-to-image homography, row-major, `(u, v, w) = H · (x, y, 1)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Homography(pub [f64; 9]);

impl Homography {
    /// The homography taking tag coordinates `(−1, −1), (1, −1), (1, 1), (−1, 1)` to `p[0..4]`
    /// (direct linear transform with `H[2][2] = 1`: eight equations, Gaussian elimination with
    /// partial pivoting). `None` when the corners are degenerate (three in a line).
    pub(crate) fn from_square(p: &[[f64; 2]; 4]) -> Option<Homography> {
        const SQUARE: [[f64; 2]; 4] = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]];
        let mut a = [[0.0f64; 9]; 8];
        for (i, (s, q)) in SQUARE.iter().zip(p).enumerate() {
            let (x, y, u, v) = (s[0], s[1], q[0], q[1]);
            a[2 * i] = [x, y, 1.0, 0.0, 0.0, 0.0, -x * u, -y * u, u];
            a[2 * i + 1] = [0.0, 0.0, 0.0, x, y, 1.0, -x * v, -y * v, v];
        }
        for col in 0..8 {
            let pivot = (col..8).max_by(|&r, &s| a[r][col].abs().total_cmp(&a[s][col].abs()))?;
            if !(a[pivot][col].abs() > 1e-10) {
                return None;
            }
            a.swap(col, pivot);
            for row in col + 1..8 {
                let f = a[row][col] / a[col][col];
                let pivot_row = a[col];
                for (value, p) in a[row][col..].iter_mut().zip(&pivot_row[col..]) {
                    *value -= f * p;
                }
            }
        }
        let mut h = [0.0f64; 9];
        h[8] = 1.0;
        for col in (0..8).rev() {
            let mut sum = a[col][8];
            for k in col + 1..8 {
                sum -= a[col][k] * h[k];
            }
            h[col] = sum / a[col][col];
        }
        let det = h[0] * (h[4] * h[8] - h[5] * h[7]) - h[1] * (h[3] * h[8] - h[5] * h[6])
            + h[2] * (h[3] * h[7] - h[4] * h[6]);
        (det.abs() > 1e-12 && h.iter().all(|v| v.is_finite())).then_some(Homography(h))
    }

    #[inline]
    pub(crate) fn project(&self, x: f64, y: f64) -> [f64; 2] {
        let h = &self.0;
        let w = h[6] * x + h[7] * y + h[8];
        [(h[0] * x + h[1] * y + h[2]) / w, (h[3] * x + h[4] * y + h[5]) / w]
    }

    /// `self · M` for a 3 × 3 row-major `m`.
    pub(crate) fn then_after(&self, m: &[f64; 9]) -> Homography {
        let h = &self.0;
        let mut out = [0.0; 9];
        for r in 0..3 {
            for c in 0..3 {
                out[r * 3 + c] = (0..3).map(|k| h[r * 3 + k] * m[k * 3 + c]).sum();
            }
        }
        Homography(out)
    }
}

/// Least-squares plane `grey(x, y) = c0·x + c1·y + c2` over tag coordinates.
#[derive(Debug, Default)]
struct GreyModel {
    /// Upper triangle of `JᵀJ` (row-major 3 × 3) and `Jᵀ·grey`.
    a: [f64; 9],
    b: [f64; 3],
}

impl GreyModel {
    fn add(&mut self, x: f64, y: f64, grey: f64) {
        self.a[0] += x * x;
        self.a[1] += x * y;
        self.a[2] += x;
        self.a[4] += y * y;
        self.a[5] += y;
        self.a[8] += 1.0;
        self.b[0] += x * grey;
        self.b[1] += y * grey;
        self.b[2] += grey;
    }

    /// The plane's coefficients, `None` if the samples do not determine it.
    fn solve(&self) -> Option<[f64; 3]> {
        let a = &self.a;
        // Cholesky of the symmetric positive (semi)definite normal matrix.
        let l00 = a[0].sqrt();
        if !(l00 > 1e-9) {
            return None;
        }
        let l10 = a[1] / l00;
        let l20 = a[2] / l00;
        let d1 = a[4] - l10 * l10;
        if !(d1 > 1e-9 * a[4].max(1.0)) {
            return None;
        }
        let l11 = d1.sqrt();
        let l21 = (a[5] - l20 * l10) / l11;
        let d2 = a[8] - l20 * l20 - l21 * l21;
        if !(d2 > 1e-9 * a[8].max(1.0)) {
            return None;
        }
        let l22 = d2.sqrt();
        let y0 = self.b[0] / l00;
        let y1 = (self.b[1] - l10 * y0) / l11;
        let y2 = (self.b[2] - l20 * y0 - l21 * y1) / l22;
        let c2 = y2 / l22;
        let c1 = (y1 - l21 * c2) / l11;
        let c0 = (y0 - l10 * c1 - l20 * c2) / l00;
        Some([c0, c1, c2])
    }
}

#[inline]
fn plane(c: &[f64; 3], x: f64, y: f64) -> f64 {
    c[0] * x + c[1] * y + c[2]
}

/// Bilinear grey value at `(x, y)` (pixel centres at integers), `None` unless all four pixels
/// are inside.
#[inline]
pub(crate) fn bilinear(image: &[u8], width: usize, height: usize, x: f64, y: f64) -> Option<f64> {
    // Non-negative (NaN fails too), so truncation is the floor.
    if !(x >= 0.0 && y >= 0.0) {
        return None;
    }
    let (x1, y1) = (x as usize, y as usize);
    let (fx, fy) = (x - x1 as f64, y - y1 as f64);
    let (x2, y2) = (x1 + usize::from(fx > 0.0), y1 + usize::from(fy > 0.0));
    if x2 >= width || y2 >= height {
        return None;
    }
    let at = |xx: usize, yy: usize| f64::from(image[yy * width + xx]);
    Some(
        at(x1, y1) * (1.0 - fx) * (1.0 - fy)
            + at(x2, y1) * fx * (1.0 - fy)
            + at(x1, y2) * (1.0 - fx) * fy
            + at(x2, y2) * fx * fy,
    )
}

/// The decoded tag of a quad and its decision margin.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct QuadDecode {
    pub decoded: Decoded,
    pub margin: f64,
}

/// Reads the code inside the quad whose homography from tag coordinates (x right, y down the
/// tag, black square = [−1, 1]²) is `h`.
///
/// 1. Grey-level models: the pixels nearest to the centres of the white ring's cells and of the
///    black border's cells along all four sides (8 per side for tag36h11) fit one plane each over
///    the tag, so a light gradient across the tag does not bias the threshold. The white plane
///    must be above the black one at the centre.
/// 2. Each data bit is sampled bilinearly at its cell centre minus the local threshold (the mean
///    of the two planes there), on a `total_width²` grid that is zero elsewhere.
/// 3. Sharpening: the grid plus `sharpening` × its Laplacian (4·centre − 4 neighbours), which
///    undoes some of the blur between neighbouring cells of small tags.
/// 4. A bit is 1 where the result is positive. The decision margin is the smaller of the mean
///    positive and the mean negative magnitude (each count starting at one).
pub(crate) fn decode_quad(
    family: &TagFamily,
    index: &CodeIndex,
    image: &[u8],
    width: usize,
    height: usize,
    h: &Homography,
    sharpening: f64,
) -> Option<QuadDecode> {
    let wab = family.width_at_border as usize;
    let cells = wab as f64;
    let to_tag = |c: f64| 2.0 * (c / cells - 0.5);
    let (mut white, mut black) = (GreyModel::default(), GreyModel::default());
    // (first cell centre x, y, step x, y, white?) along each side.
    let sides = [
        (-0.5, 0.5, 0.0, 1.0, true),
        (0.5, 0.5, 0.0, 1.0, false),
        (cells + 0.5, 0.5, 0.0, 1.0, true),
        (cells - 0.5, 0.5, 0.0, 1.0, false),
        (0.5, -0.5, 1.0, 0.0, true),
        (0.5, 0.5, 1.0, 0.0, false),
        (0.5, cells + 0.5, 1.0, 0.0, true),
        (0.5, cells - 0.5, 1.0, 0.0, false),
    ];
    for (x0, y0, dx, dy, is_white) in sides {
        for i in 0..wab {
            let (tx, ty) = (to_tag(x0 + i as f64 * dx), to_tag(y0 + i as f64 * dy));
            let [px, py] = h.project(tx, ty);
            let (ix, iy) = ((px + 0.5).floor(), (py + 0.5).floor());
            if !(ix >= 0.0 && iy >= 0.0 && ix < width as f64 && iy < height as f64) {
                continue;
            }
            let v = f64::from(image[iy as usize * width + ix as usize]);
            if is_white { white.add(tx, ty, v) } else { black.add(tx, ty, v) }
        }
    }
    let (white, black) = (white.solve()?, black.solve()?);
    if !(plane(&white, 0.0, 0.0) > plane(&black, 0.0, 0.0)) {
        return None;
    }

    let tw = family.total_width as usize;
    let border = (tw - wab) / 2;
    let mut values = [0.0f64; MAX_TOTAL_WIDTH * MAX_TOTAL_WIDTH];
    for (&bx, &by) in family.bit_x.iter().zip(family.bit_y) {
        let (tx, ty) = (to_tag(f64::from(bx) + 0.5), to_tag(f64::from(by) + 0.5));
        let [px, py] = h.project(tx, ty);
        let Some(v) = bilinear(image, width, height, px, py) else {
            continue;
        };
        let threshold = 0.5 * (plane(&black, tx, ty) + plane(&white, tx, ty));
        values[(usize::from(by) + border) * tw + usize::from(bx) + border] = v - threshold;
    }
    let mut sharpened = values;
    for y in 0..tw {
        for x in 0..tw {
            let v = values[y * tw + x];
            let mut laplacian = 4.0 * v;
            if x > 0 {
                laplacian -= values[y * tw + x - 1];
            }
            if x + 1 < tw {
                laplacian -= values[y * tw + x + 1];
            }
            if y > 0 {
                laplacian -= values[(y - 1) * tw + x];
            }
            if y + 1 < tw {
                laplacian -= values[(y + 1) * tw + x];
            }
            sharpened[y * tw + x] = v + sharpening * laplacian;
        }
    }

    let mut word = 0u64;
    let (mut white_sum, mut white_count, mut black_sum, mut black_count) = (0.0, 1.0, 0.0, 1.0);
    for (&bx, &by) in family.bit_x.iter().zip(family.bit_y) {
        let v = sharpened[(usize::from(by) + border) * tw + usize::from(bx) + border];
        word <<= 1;
        if v > 0.0 {
            word |= 1;
            white_sum += v;
            white_count += 1.0;
        } else {
            black_sum -= v;
            black_count += 1.0;
        }
    }
    let margin = f64::min(white_sum / white_count, black_sum / black_count);
    let decoded = index.decode(word)?;
    margin.is_finite().then_some(QuadDecode { decoded, margin })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn homography_maps_the_square_to_the_corners() {
        let p = [[10.0, 80.0], [90.0, 70.0], [85.0, 5.0], [12.0, 15.0]];
        let h = Homography::from_square(&p).unwrap();
        for (s, q) in [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]].iter().zip(&p) {
            let r = h.project(s[0], s[1]);
            assert!((r[0] - q[0]).abs() < 1e-9 && (r[1] - q[1]).abs() < 1e-9, "{r:?} vs {q:?}");
        }
        assert_eq!(Homography::from_square(&[[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]]), None);
    }

    #[test]
    fn grey_model_recovers_a_plane() {
        let mut m = GreyModel::default();
        for i in 0..8 {
            for (x, y) in [(-1.0, -0.9 + 0.25 * f64::from(i)), (0.9 - 0.25 * f64::from(i), 1.1)] {
                m.add(x, y, 3.0 * x - 2.0 * y + 100.0);
            }
        }
        let c = m.solve().unwrap();
        assert!((c[0] - 3.0).abs() < 1e-9 && (c[1] + 2.0).abs() < 1e-9 && (c[2] - 100.0).abs() < 1e-9, "{c:?}");
        let mut line = GreyModel::default();
        for i in 0..8 {
            line.add(0.5, f64::from(i), 7.0);
        }
        assert_eq!(line.solve(), None);
    }
}
