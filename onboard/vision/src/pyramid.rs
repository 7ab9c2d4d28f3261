//! Gaussian image pyramids in `f32` for coarse-to-fine tracking.
//!
//! Level `k + 1` is level `k` blurred with the 5-tap binomial kernel `[1 4 6 4 1] / 16` (separable,
//! border pixels replicated) and decimated by keeping the even rows and columns. Because pixel
//! centres sit at integer coordinates and pixel `2i` of level `k` becomes pixel `i` of level `k + 1`,
//! a point `(x, y)` of level 0 is at `(x, y) / 2^k` on level `k`: no half-pixel shift.
//! Level 0 keeps the unblurred image so the finest tracking step sees the full detail.

use crate::ImageView;

/// Gaussian image pyramid in f32 (level 0 = full resolution), buffers reused across frames.
#[derive(Debug, Clone)]
pub struct Pyramid {
    sizes: Vec<(usize, usize)>,
    data: Vec<Vec<f32>>,
    /// Horizontally filtered and decimated rows of the level being built.
    scratch: Vec<f32>,
}

/// One level of a [`Pyramid`].
#[derive(Debug, Clone, Copy)]
pub struct PyramidLevel<'a> {
    pub width: usize,
    pub height: usize,
    pub data: &'a [f32],
}

impl PyramidLevel<'_> {
    /// Bilinear interpolation; coordinates outside the level are clamped to the border.
    #[inline]
    pub fn sample(&self, x: f32, y: f32) -> f32 {
        let max_x = (self.width - 1) as f32;
        let max_y = (self.height - 1) as f32;
        let x = if x.is_nan() { 0.0 } else { x.clamp(0.0, max_x) };
        let y = if y.is_nan() { 0.0 } else { y.clamp(0.0, max_y) };
        let x0 = (x as usize).min(self.width.saturating_sub(2));
        let y0 = (y as usize).min(self.height.saturating_sub(2));
        let fx = x - x0 as f32;
        let fy = y - y0 as f32;
        let x1 = (x0 + 1).min(self.width - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let row0 = &self.data[y0 * self.width..];
        let row1 = &self.data[y1 * self.width..];
        let top = row0[x0] + fx * (row0[x1] - row0[x0]);
        let bottom = row1[x0] + fx * (row1[x1] - row1[x0]);
        top + fy * (bottom - top)
    }

    /// Pixel value at integer coordinates (no bounds clamping beyond the slice check).
    #[inline]
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }
}

impl Pyramid {
    /// A pyramid for `width × height` images with `levels` levels (at least 1). Levels stop early
    /// when a further halving would leave fewer than 8 pixels on a side.
    pub fn new(width: usize, height: usize, levels: usize) -> Self {
        let mut sizes = vec![(width.max(1), height.max(1))];
        while sizes.len() < levels.max(1) {
            let (w, h) = sizes[sizes.len() - 1];
            let (next_w, next_h) = (w.div_ceil(2), h.div_ceil(2));
            if next_w < 8 || next_h < 8 {
                break;
            }
            sizes.push((next_w, next_h));
        }
        let data = sizes.iter().map(|&(w, h)| vec![0.0; w * h]).collect();
        let scratch = vec![0.0; sizes.get(1).map_or(0, |&(w, _)| w * height.max(1))];
        Pyramid { sizes, data, scratch }
    }

    /// Rebuilds all levels from `image` (same size as `new`); no allocation after the first call.
    ///
    /// An image of another size is resampled by clamping to the pyramid's size, which keeps the
    /// call total; callers are expected to pass the configured size.
    pub fn build(&mut self, image: ImageView<'_>) {
        let (width, height) = self.sizes[0];
        let level0 = &mut self.data[0];
        if image.width == width && image.height == height && image.data.len() == width * height {
            for (dst, &src) in level0.iter_mut().zip(image.data) {
                *dst = f32::from(src);
            }
        } else {
            for y in 0..height {
                for x in 0..width {
                    let sx = x.min(image.width.saturating_sub(1));
                    let sy = y.min(image.height.saturating_sub(1));
                    let value = image.data.get(sy * image.width + sx).copied().unwrap_or(0);
                    level0[y * width + x] = f32::from(value);
                }
            }
        }
        for level in 1..self.sizes.len() {
            let (src_w, src_h) = self.sizes[level - 1];
            let (dst_w, dst_h) = self.sizes[level];
            let (finer, coarser) = self.data.split_at_mut(level);
            downsample(&finer[level - 1], src_w, src_h, &mut coarser[0], dst_w, dst_h, &mut self.scratch);
        }
    }

    pub fn levels(&self) -> usize {
        self.sizes.len()
    }

    /// (width, height, data) of a level; `index` beyond the last level returns the last level.
    pub fn level(&self, index: usize) -> PyramidLevel<'_> {
        let index = index.min(self.sizes.len() - 1);
        let (width, height) = self.sizes[index];
        PyramidLevel { width, height, data: &self.data[index] }
    }

    /// Size of level 0.
    pub fn size(&self) -> (usize, usize) {
        self.sizes[0]
    }
}

/// Binomial blur + 2× decimation: horizontal pass on all source rows at even columns into
/// `scratch`, then the vertical pass at even rows.
fn downsample(
    src: &[f32],
    src_w: usize,
    src_h: usize,
    dst: &mut [f32],
    dst_w: usize,
    dst_h: usize,
    scratch: &mut [f32],
) {
    const K0: f32 = 6.0 / 16.0;
    const K1: f32 = 4.0 / 16.0;
    const K2: f32 = 1.0 / 16.0;
    let last_x = src_w - 1;
    for y in 0..src_h {
        let row = &src[y * src_w..(y + 1) * src_w];
        let out = &mut scratch[y * dst_w..(y + 1) * dst_w];
        for (i, value) in out.iter_mut().enumerate() {
            let x = 2 * i;
            if x >= 2 && x + 2 <= last_x {
                *value = K0 * row[x] + K1 * (row[x - 1] + row[x + 1]) + K2 * (row[x - 2] + row[x + 2]);
            } else {
                let at = |dx: isize| row[(x as isize + dx).clamp(0, last_x as isize) as usize];
                *value = K0 * at(0) + K1 * (at(-1) + at(1)) + K2 * (at(-2) + at(2));
            }
        }
    }
    let last_y = (src_h - 1) as isize;
    for j in 0..dst_h {
        let y = 2 * j as isize;
        let row = |dy: isize| {
            let r = (y + dy).clamp(0, last_y) as usize;
            &scratch[r * dst_w..(r + 1) * dst_w]
        };
        let (m2, m1, c, p1, p2) = (row(-2), row(-1), row(0), row(1), row(2));
        let out = &mut dst[j * dst_w..(j + 1) * dst_w];
        for i in 0..dst_w {
            out[i] = K0 * c[i] + K1 * (m1[i] + p1[i]) + K2 * (m2[i] + p2[i]);
        }
    }
}
