//! Chunked level of detail of the terrain mesh.
//!
//! The heightfield is cut into square chunks of [`CHUNK_CELLS`] cells. A chunk drawn at level `k`
//! uses every `2^k`-th vertex (plus the chunk's last row and column, so chunks of any size tile
//! exactly) and splits each of its cells along the same diagonal as the full mesh, so level 0 *is*
//! the terrain mesh. A level's *error* is the largest vertical distance between its mesh and the
//! full mesh at the full mesh's vertices; the renderer takes the coarsest level whose error,
//! projected at the chunk's nearest distance, stays below a pixel tolerance. Where two chunks of
//! different levels meet, their edges differ by at most the sum of their border errors: a skirt
//! that deep hangs below the edge and fills the crack.

use crate::terrain::Heightfield;

/// Cells along a chunk's edge.
pub(crate) const CHUNK_CELLS: usize = 32;
/// Levels 0 (every vertex) to 5 (one cell per chunk).
pub(crate) const LEVELS: usize = 6;
/// Vertices along a chunk's edge at level 0.
pub(crate) const MAX_AXIS: usize = CHUNK_CELLS + 1;

/// Sides of a chunk, indices into the border errors.
pub(crate) const WEST: usize = 0;
pub(crate) const EAST: usize = 1;
pub(crate) const SOUTH: usize = 2;
pub(crate) const NORTH: usize = 3;

/// Vertex indices `a, a + step, …, b` (the last one always `b`) into `out`; returns their count.
pub(crate) fn axis(a: usize, b: usize, step: usize, out: &mut [usize; MAX_AXIS]) -> usize {
    let mut n = 0;
    let mut x = a;
    while x < b {
        out[n] = x;
        n += 1;
        x += step;
    }
    out[n] = b;
    n + 1
}

/// Per-chunk bounds and errors of one terrain, built once per terrain.
#[derive(Debug, Clone)]
pub(crate) struct TerrainLod {
    fingerprint: u64,
    pub chunks_x: usize,
    pub chunks_y: usize,
    cols: usize,
    rows: usize,
    pub z_min_m: Vec<f32>,
    pub z_max_m: Vec<f32>,
    /// Error of each level; computed the first time the chunk is seen (`known`).
    errors_m: Vec<[f32; LEVELS]>,
    /// Error of each level along each side (west, east, south, north).
    border_errors_m: Vec<[[f32; 4]; LEVELS]>,
    known: Vec<bool>,
}

/// Identity of a terrain for the renderer's cache: its buffer, its shape and a sample of heights,
/// so that a different terrain (or one edited in place) is not drawn with stale bounds.
pub(crate) fn fingerprint(hf: &Heightfield, seed: u64) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325_u64;
    let mut eat = |v: u64| {
        h = (h ^ v).wrapping_mul(0x0000_0100_0000_01b3);
        h ^= h >> 29;
    };
    eat(hf.heights_m.as_ptr() as usize as u64);
    eat(hf.heights_m.len() as u64);
    eat(hf.cols as u64);
    eat(hf.rows as u64);
    eat(hf.resolution_m.to_bits());
    eat(hf.origin_m[0].to_bits());
    eat(hf.origin_m[1].to_bits());
    eat(seed);
    let stride = (hf.heights_m.len() / 4099).max(1);
    for v in hf.heights_m.iter().step_by(stride) {
        eat(u64::from(v.to_bits()));
    }
    h
}

impl TerrainLod {
    pub fn build(hf: &Heightfield, fingerprint: u64) -> TerrainLod {
        let chunks_x = hf.cols.saturating_sub(1).div_ceil(CHUNK_CELLS);
        let chunks_y = hf.rows.saturating_sub(1).div_ceil(CHUNK_CELLS);
        let n = chunks_x * chunks_y;
        let mut lod = TerrainLod {
            fingerprint,
            chunks_x,
            chunks_y,
            cols: hf.cols,
            rows: hf.rows,
            z_min_m: vec![f32::INFINITY; n],
            z_max_m: vec![f32::NEG_INFINITY; n],
            errors_m: vec![[0.0; LEVELS]; n],
            border_errors_m: vec![[[0.0; 4]; LEVELS]; n],
            known: vec![false; n],
        };
        // Row by row over the grid (cache friendly); a border vertex belongs to both chunks.
        for r in 0..hf.rows {
            let row = &hf.heights_m[r * hf.cols..(r + 1) * hf.cols];
            let j_lo = r.saturating_sub(1) / CHUNK_CELLS;
            let j_hi = (r / CHUNK_CELLS).min(chunks_y.saturating_sub(1));
            for j in j_lo..=j_hi {
                for i in 0..chunks_x {
                    let (c0, c1) = (i * CHUNK_CELLS, ((i + 1) * CHUNK_CELLS).min(hf.cols - 1));
                    let (lo, hi) = row[c0..=c1]
                        .iter()
                        .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &z| (lo.min(z), hi.max(z)));
                    let k = j * chunks_x + i;
                    lod.z_min_m[k] = lod.z_min_m[k].min(lo);
                    lod.z_max_m[k] = lod.z_max_m[k].max(hi);
                }
            }
        }
        lod
    }

    pub fn fingerprint(&self) -> u64 {
        self.fingerprint
    }

    pub fn chunk_count(&self) -> usize {
        self.chunks_x * self.chunks_y
    }

    /// Vertex index ranges `(c0, c1, r0, r1)` (inclusive) of chunk `(i, j)`.
    pub fn bounds(&self, i: usize, j: usize) -> (usize, usize, usize, usize) {
        let c0 = i * CHUNK_CELLS;
        let r0 = j * CHUNK_CELLS;
        (c0, (c0 + CHUNK_CELLS).min(self.cols - 1), r0, (r0 + CHUNK_CELLS).min(self.rows - 1))
    }

    /// Errors of every level of chunk `k`, computing them on first use.
    pub fn errors(&mut self, hf: &Heightfield, k: usize) -> &[f32; LEVELS] {
        if !self.known[k] {
            self.compute_errors(hf, k);
        }
        &self.errors_m[k]
    }

    /// Border error of level `level` along `side` of chunk `k` (known after [`TerrainLod::errors`]).
    pub fn border_error(&self, k: usize, level: usize, side: usize) -> f32 {
        self.border_errors_m[k][level][side]
    }

    fn compute_errors(&mut self, hf: &Heightfield, k: usize) {
        let (c0, c1, r0, r1) = self.bounds(k % self.chunks_x, k / self.chunks_x);
        let h = |c: usize, r: usize| hf.heights_m[r * hf.cols + c];
        let mut xs = [0; MAX_AXIS];
        let mut ys = [0; MAX_AXIS];
        for level in 1..LEVELS {
            let step = 1 << level;
            let nx = axis(c0, c1, step, &mut xs);
            let ny = axis(r0, r1, step, &mut ys);
            let mut worst = 0.0_f32;
            let mut border = [0.0_f32; 4];
            for y in 0..ny - 1 {
                let (ya, yb) = (ys[y], ys[y + 1]);
                for x in 0..nx - 1 {
                    let (xa, xb) = (xs[x], xs[x + 1]);
                    let (h00, h10, h01, h11) = (h(xa, ya), h(xb, ya), h(xa, yb), h(xb, yb));
                    let (sx, sy) = (1.0 / (xb - xa) as f32, 1.0 / (yb - ya) as f32);
                    for r in ya..=yb {
                        let fy = (r - ya) as f32 * sy;
                        for c in xa..=xb {
                            let fx = (c - xa) as f32 * sx;
                            let coarse = if fx >= fy {
                                h00 + fx * (h10 - h00) + fy * (h11 - h10)
                            } else {
                                h00 + fy * (h01 - h00) + fx * (h11 - h01)
                            };
                            let dev = (coarse - h(c, r)).abs();
                            worst = worst.max(dev);
                            if c == c0 {
                                border[WEST] = border[WEST].max(dev);
                            }
                            if c == c1 {
                                border[EAST] = border[EAST].max(dev);
                            }
                            if r == r0 {
                                border[SOUTH] = border[SOUTH].max(dev);
                            }
                            if r == r1 {
                                border[NORTH] = border[NORTH].max(dev);
                            }
                        }
                    }
                }
            }
            self.errors_m[k][level] = worst;
            self.border_errors_m[k][level] = border;
        }
        self.known[k] = true;
    }
}
