//! The baked part of the albedo texture: material mean × the coarse octaves at every cell
//! centre (u16, 32 MB for the 4001² cells of a 200 m site), with box-filtered coarser levels
//! (a mip pyramid, a third more) for footprints larger than a cell.

use std::sync::OnceLock;

use super::albedo;
use super::bilinear::{self, CHUNK, Pyramid};
use super::{Material, Terrain};
use crate::noise::LANES;

/// Coarsest level: cells of 2⁷ × 5 cm = 6.4 m, beyond which the coarsest octave (4 m) is
/// gone anyway.
const MAX_LEVEL: usize = 7;
/// A footprint is read from the level whose cells are this many footprints wide (bilinear on
/// level 0 up to a footprint of a cell over this). 1.5 gives pixel-to-pixel texture variances
/// at 5 cm to 30 cm footprints close to those of fading the octaves out between wavelengths of
/// four and two footprints (the detail octaves' filter), where 1 (the Nyquist choice for an
/// ideal filter) leaves about twice as much: box filter and bilinear reconstruction leak.
const FILTER_WIDTH: f64 = 1.5;
/// Texels store the albedo in `[0, 1]` in steps of 1/65535.
const TEXEL_SCALE: f32 = 65_535.0;

/// The baked albedo base of a [`Terrain`]: built by [`Terrain::generate`], or on the first
/// albedo lookup of a terrain assembled by hand. It is a pure function of the terrain's config,
/// seed, heightfield grid and materials (whatever the number of threads that builds it); a
/// terrain whose materials or grid are changed afterwards needs a fresh one
/// (`AlbedoBase::default()`).
#[derive(Clone, Default)]
pub struct AlbedoBase {
    baked: OnceLock<BaseLevels>,
}

impl std::fmt::Debug for AlbedoBase {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.baked.get() {
            Some(b) => write!(f, "AlbedoBase({} texels)", b.texel_count()),
            None => write!(f, "AlbedoBase(not built)"),
        }
    }
}

impl AlbedoBase {
    /// Bytes held (0 until built).
    pub fn memory_bytes(&self) -> usize {
        self.baked.get().map_or(0, |b| b.texel_count() * std::mem::size_of::<u16>())
    }

    /// The base, baked now if it is not yet.
    pub(super) fn levels(&self, terrain: &Terrain) -> &BaseLevels {
        self.baked.get_or_init(|| {
            let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
            BaseLevels::bake(terrain, threads)
        })
    }

    /// Builds it now on `threads` threads, unless built already.
    pub(super) fn build(&self, terrain: &Terrain, threads: usize) {
        self.baked.get_or_init(|| BaseLevels::bake(terrain, threads));
    }
}

/// The baked texels and how to look them up.
#[derive(Debug, Clone)]
pub(super) struct BaseLevels {
    /// Level 0: one texel per cell centre, row-major like the heights.
    texels: Vec<u16>,
    /// `None` for a grid without a single cell square.
    pyramid: Option<Pyramid<u16>>,
    origin_m: [f64; 2],
    inv_res: f64,
    /// Level-0 cells per metre of footprint ([`FILTER_WIDTH`] / resolution).
    cells_per_footprint: f32,
    /// Used for a grid without a single cell square.
    fallback: f32,
}

impl BaseLevels {
    fn bake(terrain: &Terrain, threads: usize) -> BaseLevels {
        let hf = &terrain.heightfield;
        let (cols, rows) = (hf.cols, hf.rows);
        let mut out = BaseLevels {
            texels: Vec::new(),
            pyramid: None,
            origin_m: hf.origin_m,
            inv_res: 1.0 / hf.resolution_m,
            cells_per_footprint: (FILTER_WIDTH / hf.resolution_m) as f32,
            fallback: terrain.config.albedo_mean,
        };
        if cols < 2
            || rows < 2
            || terrain.material.len() < cols * rows
            || hf.resolution_m.is_nan()
            || hf.resolution_m <= 0.0
        {
            return out;
        }
        out.texels = vec![0; cols * rows];
        bake_finest(terrain, &mut out.texels, threads);
        out.pyramid = Pyramid::build(&out.texels, cols, rows, MAX_LEVEL);
        out
    }

    fn texel_count(&self) -> usize {
        self.texels.len() + self.pyramid.as_ref().map_or(0, Pyramid::texel_count)
    }

    /// The base albedo at up to [`CHUNK`] points for their footprints, into `out`: bilinear on
    /// level 0 up to a footprint of 1/[`FILTER_WIDTH`] cell, from coarser levels beyond (see
    /// [`Pyramid::sample_many`]). Each point's value depends on its own inputs only.
    pub(super) fn sample_many(&self, x_m: &[f64], y_m: &[f64], footprint_m: &[f32], out: &mut [f32]) {
        let n = out.len().min(x_m.len()).min(y_m.len()).min(footprint_m.len()).min(CHUNK);
        let out = &mut out[..n];
        let Some(pyramid) = &self.pyramid else {
            out.fill(self.fallback);
            return;
        };
        let (mut gx, mut gy, mut cells) = ([0.0f32; CHUNK], [0.0f32; CHUNK], [0.0f32; CHUNK]);
        let (gx, gy, cells) = (&mut gx[..n], &mut gy[..n], &mut cells[..n]);
        bilinear::cell_coordinates(self.origin_m, self.inv_res, &x_m[..n], &y_m[..n], gx, gy);
        for (c, &f) in cells.iter_mut().zip(footprint_m) {
            *c = f * self.cells_per_footprint;
        }
        pyramid.sample_many(&self.texels, gx, gy, cells, out);
        for v in out.iter_mut() {
            *v *= 1.0 / TEXEL_SCALE;
        }
    }
}

#[inline]
fn to_texel(albedo: f32) -> u16 {
    (albedo.clamp(0.0, 1.0) * TEXEL_SCALE + 0.5) as u16
}

/// Level 0: one texel per cell centre, on `threads` threads in bands of rows (each texel depends
/// only on its cell, so the result does not depend on the split).
fn bake_finest(terrain: &Terrain, texels: &mut [u16], threads: usize) {
    let hf = &terrain.heightfield;
    let cols = hf.cols;
    let config = &terrain.config;
    let seeds = albedo::octave_seeds(terrain.seed);
    let factors = [1.0, config.rock_albedo_factor, config.ejecta_albedo_factor];
    let factor = |m: u8| factors[Material::from_u8(m) as usize];
    let bake_row = |row: usize, out: &mut [u16]| {
        let y = (hf.origin_m[1] + row as f64 * hf.resolution_m) as f32;
        let material = &terrain.material[row * cols..(row + 1) * cols];
        for (start, chunk) in (0..cols).step_by(LANES).zip(out.chunks_mut(LANES)) {
            let x: [f32; LANES] =
                std::array::from_fn(|k| (hf.origin_m[0] + (start + k).min(cols - 1) as f64 * hf.resolution_m) as f32);
            let sum = albedo::base_octaves(&seeds, &x, &[y; LANES]);
            for (k, t) in chunk.iter_mut().enumerate() {
                let f = factor(material[start + k]);
                *t = to_texel(config.albedo_mean * f * albedo::base_factor(sum[k], config.albedo_contrast));
            }
        }
    };
    let band_rows = hf.rows.div_ceil(threads.max(1) * 4).max(1);
    let bands: Vec<(usize, &mut [u16])> =
        texels.chunks_mut(band_rows * cols).enumerate().map(|(i, b)| (i * band_rows, b)).collect();
    let queue = std::sync::Mutex::new(bands);
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| {
                loop {
                    let band = match queue.lock() {
                        Ok(mut q) => q.pop(),
                        Err(_) => None,
                    };
                    let Some((first_row, band)) = band else { break };
                    for (k, row) in band.chunks_mut(cols).enumerate() {
                        bake_row(first_row + k, row);
                    }
                }
            });
        }
    });
}
