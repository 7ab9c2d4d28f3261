//! Bilinear lookups of many points in row-major grids of small integers (the albedo base, the
//! shadow map).
//!
//! A lookup is split in two passes over up to [`CHUNK`] points: addresses and weights (plain
//! arithmetic that the compiler vectorises), then the loads and the blend. Done point by point,
//! the conversions, clamps and bounds checks of a lookup cost several times its four loads.

/// Points per pass; the pass buffers live on the stack.
pub(crate) const CHUNK: usize = 64;

/// 1.5 · 2²³: adding it to an f32 in `[0, 2²²)` rounds to an integer.
const ROUNDING_MAGIC: f32 = 12_582_912.0;

/// The nodes of a grid level: `cols × rows` texels from `offset` on, a node `(c, r)` at cell
/// coordinate `(c, r) · 1/scale + shift/scale` of the grid it is read by.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Level {
    pub offset: usize,
    pub cols: usize,
    pub rows: usize,
    /// Level coordinate = cell coordinate × `scale` − `shift`.
    pub scale: f32,
    pub shift: f32,
}

/// Addresses and weights of a chunk of lookups.
pub(crate) struct Taps {
    pub index: [u32; CHUNK],
    pub ax: [f32; CHUNK],
    pub ay: [f32; CHUNK],
}

impl Taps {
    pub fn new() -> Taps {
        Taps { index: [0; CHUNK], ax: [0.0; CHUNK], ay: [0.0; CHUNK] }
    }

    /// Taps on `level` for points at cell coordinates `gx, gy` (at most [`CHUNK`]), clamped to
    /// the level's nodes (NaN to the first). The level must have at least 2 × 2 nodes and fewer
    /// than 2³² texels before its end.
    #[inline]
    pub fn on_level(&mut self, level: &Level, gx: &[f32], gy: &[f32]) {
        let n = gx.len().min(gy.len()).min(CHUNK);
        let (max_x, max_y) = ((level.cols - 1) as f32, (level.rows - 1) as f32);
        let (max_c, max_r) = ((level.cols - 2) as f32, (level.rows - 2) as f32);
        let (cols, offset) = (level.cols as u32, level.offset as u32);
        let (index, ax, ay) = (&mut self.index[..n], &mut self.ax[..n], &mut self.ay[..n]);
        for i in 0..n {
            // `max` before `min` maps NaN to 0.
            let fx = (gx[i] * level.scale - level.shift).max(0.0).min(max_x);
            let fy = (gy[i] * level.scale - level.shift).max(0.0).min(max_y);
            // Round-to-nearest of `f − ½` is the floor, but for integers, where it may be one
            // less: the weight is then 1 and the lookup the same.
            let c = (((fx - 0.5) + ROUNDING_MAGIC) - ROUNDING_MAGIC).max(0.0).min(max_c);
            let r = (((fy - 0.5) + ROUNDING_MAGIC) - ROUNDING_MAGIC).max(0.0).min(max_r);
            ax[i] = fx - c;
            ay[i] = fy - r;
            index[i] = offset + (r as i32 as u32) * cols + c as i32 as u32;
        }
    }

    /// The blends of the first `out.len()` taps in `texels` (rows `cols` long), unscaled.
    #[inline]
    pub fn blend<T: Copy + Into<f32>>(&self, texels: &[T], cols: usize, out: &mut [f32]) {
        // Taps are in range by construction; the clamp only spares a panic on a short buffer.
        let last = texels.len().saturating_sub(cols + 2);
        for (o, ((&index, &ax), &ay)) in out.iter_mut().zip(self.index.iter().zip(&self.ax).zip(&self.ay)) {
            let k = (index as usize).min(last);
            let Some(w) = texels.get(k..k + cols + 2) else {
                *o = 0.0;
                continue;
            };
            let (t00, t10, t01, t11) = (w[0].into(), w[1].into(), w[cols].into(), w[cols + 1].into());
            let a = t00 + ax * (t10 - t00);
            let b = t01 + ax * (t11 - t01);
            *o = a + ay * (b - a);
        }
    }
}

/// Cell coordinates `((x − origin) / resolution)` of world points, as f32 (a 4000-cell grid
/// keeps 1/4000 of a cell).
#[inline]
pub(crate) fn cell_coordinates(
    origin_m: [f64; 2],
    inv_res: f64,
    x_m: &[f64],
    y_m: &[f64],
    gx: &mut [f32],
    gy: &mut [f32],
) {
    let n = x_m.len().min(y_m.len()).min(gx.len()).min(gy.len());
    for i in 0..n {
        gx[i] = ((x_m[i] - origin_m[0]) * inv_res) as f32;
        gy[i] = ((y_m[i] - origin_m[1]) * inv_res) as f32;
    }
}

/// A texel type of a [`Pyramid`].
pub(crate) trait Texel: Copy + Default + Into<f32> + Send + Sync {
    /// The rounded mean of four texels given as their sum.
    fn mean_of_four(sum: u32) -> Self;
    fn widen(self) -> u32;
}

impl Texel for u8 {
    fn mean_of_four(sum: u32) -> u8 {
        ((sum + 2) / 4) as u8
    }
    fn widen(self) -> u32 {
        u32::from(self)
    }
}

impl Texel for u16 {
    fn mean_of_four(sum: u32) -> u16 {
        ((sum + 2) / 4) as u16
    }
    fn widen(self) -> u32 {
        u32::from(self)
    }
}

/// Box-filtered coarser levels of a grid (a mip pyramid), for lookups filtered over a footprint.
/// Level 0 is the grid itself, which the caller keeps and passes in; node `(i, j)` of level `L`
/// averages the `2^L × 2^L` cells from `(i·2^L, j·2^L)` on (the last row or column repeated
/// where a level has an odd size), so it sits at cell coordinate `i·2^L + (2^L − 1)/2`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Pyramid<T> {
    /// Levels 1 and up, each row-major.
    coarser: Vec<T>,
    /// All levels; level 0 with offset 0 into the caller's grid, the others into `coarser`.
    levels: Vec<Level>,
}

impl<T: Texel> Pyramid<T> {
    /// Levels down to cells of `2^max_level` grid cells, or while both sides keep two nodes.
    /// `None` without a single cell square or with a short grid.
    pub fn build(grid: &[T], cols: usize, rows: usize, max_level: usize) -> Option<Pyramid<T>> {
        if cols < 2 || rows < 2 || grid.len() < cols * rows || cols * rows > u32::MAX as usize {
            return None;
        }
        let mut levels = vec![Level { offset: 0, cols, rows, scale: 1.0, shift: 0.0 }];
        let mut offset = 0;
        while levels.len() <= max_level {
            let last = levels[levels.len() - 1];
            let (c, r) = (last.cols.div_ceil(2), last.rows.div_ceil(2));
            if c < 2 || r < 2 {
                break;
            }
            let scale = 1.0 / (1u32 << levels.len()) as f32;
            levels.push(Level { offset, cols: c, rows: r, scale, shift: 0.5 * (1.0 - scale) });
            offset += c * r;
        }
        let mut coarser = vec![T::default(); offset];
        let mut previous: &[T] = grid;
        let mut rest: &mut [T] = &mut coarser;
        for pair in levels.windows(2) {
            let (fine, coarse) = (pair[0], pair[1]);
            let (this, tail) = rest.split_at_mut(coarse.cols * coarse.rows);
            downsample(previous, fine.cols, fine.rows, this, coarse.cols, coarse.rows);
            previous = this;
            rest = tail;
        }
        Some(Pyramid { coarser, levels })
    }

    pub fn texel_count(&self) -> usize {
        self.coarser.len()
    }

    /// Lookups at up to [`CHUNK`] points given in grid cell coordinates, each filtered over
    /// `cells[i]` grid cells (unscaled texel values): bilinear on the grid up to one cell, then
    /// on the level whose cells are about that wide, blended with the next coarser level in the
    /// middle half of each octave of widths (continuous in the width, and one lookup instead of
    /// two for half of the points). Each point's value depends on its own inputs only.
    pub fn sample_many(&self, grid: &[T], gx: &[f32], gy: &[f32], cells: &[f32], out: &mut [f32]) {
        let n = out.len().min(gx.len()).min(gy.len()).min(cells.len()).min(CHUNK);
        let (gx, gy, cells, out) = (&gx[..n], &gy[..n], &cells[..n], &mut out[..n]);
        let mut taps = Taps::new();
        let finest = &self.levels[0];
        // `f32::max` ignores NaN, which thus takes the finest level.
        if cells.iter().fold(0.0f32, |m, &c| m.max(c)) <= 1.0 {
            taps.on_level(finest, gx, gy);
            taps.blend(grid, finest.cols, out);
            return;
        }
        // log₂ of the width by the float's exponent and mantissa.
        let last = self.levels.len() - 1;
        let (mut level, mut weight) = ([0u8; CHUNK], [0.0f32; CHUNK]);
        let (mut lowest, mut highest) = (last, 0);
        for i in 0..n {
            let (mut l, mut w) = (0, 0.0);
            if cells[i] > 1.0 {
                let bits = cells[i].to_bits();
                l = ((bits >> 23) as usize).saturating_sub(127).min(last);
                if l < last {
                    let fraction = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000) - 1.0;
                    w = (2.0 * fraction - 0.5).clamp(0.0, 1.0);
                    if w >= 1.0 {
                        (l, w) = (l + 1, 0.0);
                    }
                }
            }
            (level[i], weight[i]) = (l as u8, w);
            (lowest, highest) = (lowest.min(l), highest.max(l));
        }
        // Points of one level together: its lookup, then the next level's for those that blend.
        let (mut sel, mut cx, mut cy) = ([0u8; CHUNK], [0.0f32; CHUNK], [0.0f32; CHUNK]);
        let (mut a, mut b) = ([0.0f32; CHUNK], [0.0f32; CHUNK]);
        let (mut blend_at, mut bx, mut by) = ([0u8; CHUNK], [0.0f32; CHUNK], [0.0f32; CHUNK]);
        for l in lowest..=highest {
            let this = &self.levels[l];
            let (mut m, mut k) = (0, 0);
            for i in 0..n {
                if usize::from(level[i]) == l {
                    (sel[m], cx[m], cy[m]) = (i as u8, gx[i], gy[i]);
                    if weight[i] > 0.0 {
                        (blend_at[k], bx[k], by[k]) = (m as u8, gx[i], gy[i]);
                        k += 1;
                    }
                    m += 1;
                }
            }
            if m == 0 {
                continue;
            }
            taps.on_level(this, &cx[..m], &cy[..m]);
            taps.blend(if l == 0 { grid } else { &self.coarser }, this.cols, &mut a[..m]);
            if let (Some(next), true) = (self.levels.get(l + 1), k > 0) {
                taps.on_level(next, &bx[..k], &by[..k]);
                taps.blend(&self.coarser, next.cols, &mut b[..k]);
                for j in 0..k {
                    let at = usize::from(blend_at[j]);
                    a[at] += weight[usize::from(sel[at])] * (b[j] - a[at]);
                }
            }
            for j in 0..m {
                out[usize::from(sel[j])] = a[j];
            }
        }
    }
}

/// A coarser level from a finer one: the mean of each 2 × 2 block.
fn downsample<T: Texel>(fine: &[T], fine_cols: usize, fine_rows: usize, coarse: &mut [T], cols: usize, rows: usize) {
    for r in 0..rows {
        let (r0, r1) = (2 * r, (2 * r + 1).min(fine_rows - 1));
        for c in 0..cols {
            let (c0, c1) = (2 * c, (2 * c + 1).min(fine_cols - 1));
            let sum = fine[r0 * fine_cols + c0].widen()
                + fine[r0 * fine_cols + c1].widen()
                + fine[r1 * fine_cols + c0].widen()
                + fine[r1 * fine_cols + c1].widen();
            coarse[r * cols + c] = T::mean_of_four(sum);
        }
    }
}
