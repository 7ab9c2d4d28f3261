//! Decimation and the adaptive threshold: every pixel becomes black, white or unknown.

/// Thresholded pixel values.
pub(crate) const BLACK: u8 = 0;
pub(crate) const WHITE: u8 = 255;
/// Low contrast: neither, never part of a component.
pub(crate) const UNKNOWN: u8 = 127;

/// Tile edge of the extrema grid. Small tiles follow illumination closely; a tile needs only to
/// span an edge, not a tag.
const TILE: usize = 4;

/// Keeps every `factor`-th pixel of every `factor`-th row (no averaging: the quads found on it are
/// refined on the full image). Returns the decimated size; `factor` 1 copies nothing and returns
/// the input size (the caller reads the input instead).
pub(crate) fn decimate(image: &[u8], width: usize, height: usize, factor: usize, out: &mut Vec<u8>) -> (usize, usize) {
    if factor <= 1 {
        return (width, height);
    }
    let (w, h) = (1 + (width - 1) / factor, 1 + (height - 1) / factor);
    out.clear();
    for y in (0..height).step_by(factor) {
        let row = &image[y * width..(y + 1) * width];
        out.extend(row.iter().step_by(factor));
    }
    debug_assert_eq!(out.len(), w * h);
    (w, h)
}

/// The extrema grid and scratch rows of the threshold, kept between frames.
#[derive(Debug, Default)]
pub(crate) struct Thresholder {
    tile_min: Vec<u8>,
    tile_max: Vec<u8>,
    grown_min: Vec<u8>,
    grown_max: Vec<u8>,
    scratch: Vec<u8>,
}

impl Thresholder {
    /// Writes the thresholded `image` into `out` (`width × height`).
    ///
    /// Each 4 × 4 tile's minimum and maximum are spread over the 3 × 3 neighbouring tiles (the
    /// window of a pixel then always reaches at least one tile beyond its own, so a threshold
    /// does not jump at a tile edge). A tile whose spread extrema differ by less than
    /// `min_white_black_diff` is unknown; otherwise a pixel is white above the midpoint
    /// `min + (max - min) / 2`, else black. The partial tiles at the right and bottom use the
    /// nearest full tile's extrema and are always thresholded. With `deglitch`, a 3 × 3 closing
    /// (max then min) of the interior follows. An image smaller than one tile is all unknown.
    pub(crate) fn run(
        &mut self,
        image: &[u8],
        width: usize,
        height: usize,
        min_white_black_diff: u8,
        deglitch: bool,
        out: &mut Vec<u8>,
    ) {
        out.clear();
        out.resize(width * height, UNKNOWN);
        let (tw, th) = (width / TILE, height / TILE);
        if tw == 0 || th == 0 {
            return;
        }
        self.tile_extrema(image, width, tw, th);
        self.grow_extrema(tw, th);

        let (mins, maxs) = (&self.grown_min, &self.grown_max);
        for y in 0..height {
            let ty = (y / TILE).min(th - 1);
            let full_row = y < th * TILE;
            let src = &image[y * width..(y + 1) * width];
            let dst = &mut out[y * width..(y + 1) * width];
            let tile_min = &mins[ty * tw..(ty + 1) * tw];
            let tile_max = &maxs[ty * tw..(ty + 1) * tw];
            let x_full = if full_row { tw * TILE } else { 0 };
            if full_row {
                for (tx, (s, d)) in
                    src[..x_full].chunks_exact(TILE).zip(dst[..x_full].chunks_exact_mut(TILE)).enumerate()
                {
                    let (lo, hi) = (tile_min[tx], tile_max[tx]);
                    if hi - lo < min_white_black_diff {
                        d.fill(UNKNOWN);
                    } else {
                        let thresh = lo + (hi - lo) / 2;
                        for (o, &v) in d.iter_mut().zip(s) {
                            *o = if v > thresh { WHITE } else { BLACK };
                        }
                    }
                }
            }
            for x in x_full..width {
                let tx = (x / TILE).min(tw - 1);
                let (lo, hi) = (tile_min[tx], tile_max[tx]);
                let thresh = lo + (hi - lo) / 2;
                dst[x] = if src[x] > thresh { WHITE } else { BLACK };
            }
        }
        if deglitch {
            self.close(out, width, height);
        }
    }

    /// Capacities of the buffers (for the no-allocation check).
    #[cfg(test)]
    pub(crate) fn capacities(&self) -> [usize; 5] {
        [
            self.tile_min.capacity(),
            self.tile_max.capacity(),
            self.grown_min.capacity(),
            self.grown_max.capacity(),
            self.scratch.capacity(),
        ]
    }

    /// Minimum and maximum of every full tile.
    fn tile_extrema(&mut self, image: &[u8], width: usize, tw: usize, th: usize) {
        self.tile_min.clear();
        self.tile_min.resize(tw * th, u8::MAX);
        self.tile_max.clear();
        self.tile_max.resize(tw * th, 0);
        for ty in 0..th {
            let mins = &mut self.tile_min[ty * tw..(ty + 1) * tw];
            let maxs = &mut self.tile_max[ty * tw..(ty + 1) * tw];
            for dy in 0..TILE {
                let y = ty * TILE + dy;
                let row = &image[y * width..y * width + tw * TILE];
                for ((chunk, lo), hi) in row.chunks_exact(TILE).zip(mins.iter_mut()).zip(maxs.iter_mut()) {
                    for &v in chunk {
                        *lo = (*lo).min(v);
                        *hi = (*hi).max(v);
                    }
                }
            }
        }
    }

    /// 3 × 3 erosion of the minima and dilation of the maxima over the tile grid (separable).
    fn grow_extrema(&mut self, tw: usize, th: usize) {
        // Along rows into the scratch grids, then along columns into the grown grids.
        self.grown_min.clear();
        self.grown_min.resize(tw * th, 0);
        self.grown_max.clear();
        self.grown_max.resize(tw * th, 0);
        for ty in 0..th {
            for tx in 0..tw {
                let (a, b) = (tx.saturating_sub(1), (tx + 1).min(tw - 1));
                let row_min = &self.tile_min[ty * tw..(ty + 1) * tw];
                let row_max = &self.tile_max[ty * tw..(ty + 1) * tw];
                self.grown_min[ty * tw + tx] = row_min[a..=b].iter().copied().fold(u8::MAX, u8::min);
                self.grown_max[ty * tw + tx] = row_max[a..=b].iter().copied().fold(0, u8::max);
            }
        }
        std::mem::swap(&mut self.tile_min, &mut self.grown_min);
        std::mem::swap(&mut self.tile_max, &mut self.grown_max);
        for ty in 0..th {
            let (a, b) = (ty.saturating_sub(1), (ty + 1).min(th - 1));
            for tx in 0..tw {
                let mut lo = u8::MAX;
                let mut hi = 0;
                for t in a..=b {
                    lo = lo.min(self.tile_min[t * tw + tx]);
                    hi = hi.max(self.tile_max[t * tw + tx]);
                }
                self.grown_min[ty * tw + tx] = lo;
                self.grown_max[ty * tw + tx] = hi;
            }
        }
    }

    /// 3 × 3 dilation then erosion of the interior (the border rows and columns keep their
    /// values).
    fn close(&mut self, image: &mut [u8], width: usize, height: usize) {
        if width < 3 || height < 3 {
            return;
        }
        self.scratch.clear();
        self.scratch.extend_from_slice(image);
        let window = |img: &[u8], x: usize, y: usize, max: bool| {
            let mut acc = if max { 0 } else { u8::MAX };
            for yy in y - 1..=y + 1 {
                for &v in &img[yy * width + x - 1..=yy * width + x + 1] {
                    acc = if max { acc.max(v) } else { acc.min(v) };
                }
            }
            acc
        };
        for y in 1..height - 1 {
            for x in 1..width - 1 {
                self.scratch[y * width + x] = window(image, x, y, true);
            }
        }
        for y in 1..height - 1 {
            for x in 1..width - 1 {
                image[y * width + x] = window(&self.scratch, x, y, false);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Per-pixel definition: the extrema of the 3 × 3 tiles around the pixel's (clamped) tile.
    fn naive(image: &[u8], w: usize, h: usize, min_diff: u8) -> Vec<u8> {
        let (tw, th) = (w / TILE, h / TILE);
        let tile = |tx: usize, ty: usize| {
            let mut lo = 255u8;
            let mut hi = 0u8;
            for y in ty * TILE..ty * TILE + TILE {
                for x in tx * TILE..tx * TILE + TILE {
                    lo = lo.min(image[y * w + x]);
                    hi = hi.max(image[y * w + x]);
                }
            }
            (lo, hi)
        };
        let mut out = vec![UNKNOWN; w * h];
        for y in 0..h {
            for x in 0..w {
                let (tx, ty) = ((x / TILE).min(tw - 1), (y / TILE).min(th - 1));
                let mut lo = 255u8;
                let mut hi = 0u8;
                for ny in ty.saturating_sub(1)..=(ty + 1).min(th - 1) {
                    for nx in tx.saturating_sub(1)..=(tx + 1).min(tw - 1) {
                        let (a, b) = tile(nx, ny);
                        lo = lo.min(a);
                        hi = hi.max(b);
                    }
                }
                let partial = x >= tw * TILE || y >= th * TILE;
                out[y * w + x] = if !partial && hi - lo < min_diff {
                    UNKNOWN
                } else if image[y * w + x] > lo + (hi - lo) / 2 {
                    WHITE
                } else {
                    BLACK
                };
            }
        }
        out
    }

    #[test]
    fn threshold_equals_its_per_pixel_definition() {
        let mut state = 12345u32;
        for (w, h) in [(4, 4), (17, 9), (33, 30), (8, 13)] {
            let image: Vec<u8> = (0..w * h)
                .map(|i| {
                    state = state.wrapping_mul(1664525).wrapping_add(1013904223);
                    // Smooth areas (low contrast) next to noisy ones.
                    if (i % w) < w / 3 { 100 + (state >> 30) as u8 } else { (state >> 24) as u8 }
                })
                .collect();
            let mut t = Thresholder::default();
            let mut out = Vec::new();
            t.run(&image, w, h, 5, false, &mut out);
            assert_eq!(out, naive(&image, w, h, 5), "{w}x{h}");
        }
    }

    #[test]
    fn tiny_images_are_unknown_and_decimation_keeps_every_other_pixel() {
        let mut t = Thresholder::default();
        let mut out = Vec::new();
        t.run(&[0, 255, 0], 3, 1, 5, false, &mut out);
        assert_eq!(out, vec![UNKNOWN; 3]);
        let image: Vec<u8> = (0..35).collect();
        let mut d = Vec::new();
        assert_eq!(decimate(&image, 7, 5, 2, &mut d), (4, 3));
        assert_eq!(d, vec![0, 2, 4, 6, 14, 16, 18, 20, 28, 30, 32, 34]);
    }
}
