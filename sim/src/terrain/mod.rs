//! Procedural planetary terrain, deterministic for a seed: fractal relief, impact craters with
//! raised rims, rocks as solids on the ground, ditches, and the material map the renderer's
//! albedo uses.
//!
//! CONTRACT (owned by the terrain helper; the renderer, motion and pictures rely on it):
//! the surface is the triangle mesh over the cell centres, each cell square `(c, r)–(c+1, r+1)`
//! split along its diagonal from `(c, r)` to `(c+1, r+1)`; [`Heightfield::height_at`] and
//! [`Heightfield::normal_at`] evaluate exactly that mesh, and the ray caster intersects it.
//!
//! Generation order (each step sees the result of the previous ones): fractal relief and ripples,
//! craters from the largest (oldest) to the smallest, an angle-of-repose limit on the natural
//! ground ([`slope`]), ditches, rocks. Ditches and rocks come last so that their steep walls
//! survive the slope limit.

mod albedo;
mod albedo_base;
pub(crate) mod bilinear;
mod craters;
mod ditches;
mod heightfield;
mod relief;
mod rocks;
pub mod slope;

use nalgebra::{Point3, Vector3};

use crate::rng::{self, streams};

pub use albedo_base::AlbedoBase;
pub use craters::{CRATER_EDGE_MIN_DROP_M, CRATER_EDGE_RUN_M};

/// A regular grid of heights. Cell `(col, row)` is centred at
/// `origin_m + (col, row) · resolution_m`; rows run along +y, columns along +x; row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Heightfield {
    pub resolution_m: f64,
    /// World (x, y) of the centre of cell (0, 0).
    pub origin_m: [f64; 2],
    pub cols: usize,
    pub rows: usize,
    pub heights_m: Vec<f32>,
}

/// What a cell is made of (drives albedo and obstacle ground truth).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Material {
    Regolith = 0,
    Rock = 1,
    /// Bright ejecta on crater rims.
    Ejecta = 2,
}

impl Material {
    /// The material stored as `code` in [`Terrain::material`] (unknown codes read as regolith).
    pub fn from_u8(code: u8) -> Material {
        match code {
            1 => Material::Rock,
            2 => Material::Ejecta,
            _ => Material::Regolith,
        }
    }
}

/// A rock, a solid sitting on the ground (baked into the heightfield as a dome).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rock {
    pub id: u32,
    /// Centre of the rock's footprint, at the height of the ground beneath it.
    pub base_m: Point3<f64>,
    /// Horizontal radius of the footprint.
    pub radius_m: f64,
    /// Height of the top above the ground beneath.
    pub height_m: f64,
}

/// An impact crater: a bowl with a raised rim.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Crater {
    pub centre_m: [f64; 2],
    /// Rim crest radius.
    pub radius_m: f64,
    /// Floor depth below the surrounding surface.
    pub depth_m: f64,
    pub rim_height_m: f64,
}

/// A ditch: a straight trench, a negative obstacle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ditch {
    pub start_m: [f64; 2],
    pub end_m: [f64; 2],
    pub width_m: f64,
    pub depth_m: f64,
}

/// Ground truth of a negative obstacle: a place where the ground drops by more than a rover may
/// step down, as a polyline along its edge.
#[derive(Debug, Clone, PartialEq)]
pub struct NegativeObstacle {
    pub kind: NegativeObstacleKind,
    pub edge_m: Vec<[f64; 2]>,
    pub drop_m: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NegativeObstacleKind {
    CraterEdge,
    Ditch,
}

/// How to make a terrain. Presets: [`TerrainConfig::moon`], [`TerrainConfig::mars`].
///
/// Size distributions are truncated power laws: the number of objects larger than `s` goes as
/// `s^−exponent` between the two bounds of the range.
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainConfig {
    /// Edge lengths in x and y; the terrain is centred on the world origin.
    pub size_m: [f64; 2],
    pub resolution_m: f64,
    /// Amplitude of the coarsest relief octave (wavelength `relief_wavelength_m`).
    pub relief_amplitude_m: f64,
    pub relief_wavelength_m: f64,
    /// Octaves stop at this wavelength (finer relief lives in the albedo texture and shading).
    pub relief_min_wavelength_m: f64,
    /// Octave `k` has amplitude `relief_amplitude_m · 2^(−k · relief_hurst)`.
    pub relief_hurst: f64,
    /// Wind ripples (0 = none): crest height, wavelength, and the fraction of the site they cover.
    pub ripple_amplitude_m: f64,
    pub ripple_wavelength_m: f64,
    pub ripple_coverage: f64,
    /// Craters with a rim radius of at least 1 m per km² (the power law extends this to the
    /// whole `crater_radius_m` range).
    pub craters_per_km2: f64,
    pub crater_radius_m: [f64; 2],
    pub crater_size_exponent: f64,
    /// Mean freshness in `(0, 1]`: fresh craters are deep (depth/diameter 0.12), steep-walled
    /// (≈ 30°) with bright ejecta; degraded ones are shallow (0.04) and soft.
    pub crater_freshness: f64,
    /// Rocks at least `rock_height_m[0]` tall per 100 m².
    pub rocks_per_100m2: f64,
    /// Range of rock heights above the ground.
    pub rock_height_m: [f64; 2],
    pub rock_size_exponent: f64,
    /// Number of ditches and the ranges of their length, top width and depth.
    pub ditches: usize,
    pub ditch_length_m: [f64; 2],
    pub ditch_width_m: [f64; 2],
    pub ditch_depth_m: [f64; 2],
    /// Angle of repose: the natural ground (not rocks and ditch walls) is never steeper.
    pub max_natural_slope_deg: f64,
    /// Discs `(centre, radius)` kept free of rocks, ditches and craters (robots' start areas).
    pub keep_clear_m: Vec<([f64; 2], f64)>,
    /// Mean albedo of the regolith and the relative standard deviation of its texture.
    pub albedo_mean: f32,
    pub albedo_contrast: f32,
    /// Mean albedo of rock and of ejecta relative to the regolith.
    pub rock_albedo_factor: f32,
    pub ejecta_albedo_factor: f32,
}

impl TerrainConfig {
    /// A Moon-analogue site (like the thesis's Mt. Etna tests): 200 m × 200 m at 5 cm. Dark
    /// volcanic sand, gently undulating, densely cratered at all sizes with fresh rims and bright
    /// ejecta, scattered small rocks, a few ditches.
    pub fn moon() -> Self {
        TerrainConfig {
            size_m: [200.0, 200.0],
            resolution_m: 0.05,
            relief_amplitude_m: 1.6,
            relief_wavelength_m: 64.0,
            relief_min_wavelength_m: 0.2,
            relief_hurst: 0.85,
            ripple_amplitude_m: 0.0,
            ripple_wavelength_m: 1.0,
            ripple_coverage: 0.0,
            craters_per_km2: 4000.0,
            crater_radius_m: [0.3, 20.0],
            crater_size_exponent: 2.0,
            crater_freshness: 0.5,
            rocks_per_100m2: 1.0,
            rock_height_m: [0.1, 1.0],
            rock_size_exponent: 2.5,
            ditches: 4,
            ditch_length_m: [5.0, 15.0],
            ditch_width_m: [0.6, 1.5],
            ditch_depth_m: [0.3, 1.0],
            max_natural_slope_deg: 30.0,
            keep_clear_m: Vec::new(),
            albedo_mean: 0.12,
            albedo_contrast: 0.3,
            rock_albedo_factor: 1.4,
            ejecta_albedo_factor: 1.45,
        }
    }

    /// A Mars-like site: 200 m × 200 m at 5 cm. Brighter dust, larger undulations with wind
    /// ripples, fewer and mostly degraded craters, more and larger (darker) rocks.
    pub fn mars() -> Self {
        TerrainConfig {
            relief_amplitude_m: 2.5,
            relief_wavelength_m: 64.0,
            relief_hurst: 0.95,
            ripple_amplitude_m: 0.06,
            ripple_wavelength_m: 1.6,
            ripple_coverage: 0.4,
            craters_per_km2: 400.0,
            crater_radius_m: [0.5, 15.0],
            crater_size_exponent: 2.0,
            crater_freshness: 0.25,
            rocks_per_100m2: 3.5,
            rock_size_exponent: 1.8,
            ditches: 3,
            albedo_mean: 0.24,
            albedo_contrast: 0.25,
            rock_albedo_factor: 0.7,
            ejecta_albedo_factor: 1.15,
            ..Self::moon()
        }
    }

    /// The same preset on a smaller square (fast tests).
    pub fn with_size(mut self, edge_m: f64) -> Self {
        self.size_m = [edge_m, edge_m];
        self
    }

    /// The same preset with `(centre, radius)` kept clear of rocks, ditches and craters.
    pub fn with_clear_area(mut self, centre_m: [f64; 2], radius_m: f64) -> Self {
        self.keep_clear_m.push((centre_m, radius_m));
        self
    }

    /// Whether a disc of `extra_radius_m` around `p` reaches into a keep-clear area.
    fn touches_clear_area(&self, p: [f64; 2], extra_radius_m: f64) -> bool {
        self.keep_clear_m.iter().any(|&(c, r)| (p[0] - c[0]).hypot(p[1] - c[1]) < r + extra_radius_m)
    }
}

/// A generated terrain.
#[derive(Debug, Clone)]
pub struct Terrain {
    pub config: TerrainConfig,
    pub seed: u64,
    pub heightfield: Heightfield,
    /// One [`Material`] per cell (as `u8`), same layout as the heights.
    pub material: Vec<u8>,
    pub rocks: Vec<Rock>,
    pub craters: Vec<Crater>,
    pub ditches: Vec<Ditch>,
    /// The baked coarse part of the albedo texture (see [`AlbedoBase`]); `AlbedoBase::default()`
    /// for a terrain assembled by hand builds it on the first albedo lookup.
    pub albedo_base: AlbedoBase,
}

impl Terrain {
    /// Generates the terrain of `config` for `seed` on all cores (byte-identical for equal
    /// inputs, whatever the number of threads).
    pub fn generate(config: &TerrainConfig, seed: u64) -> Terrain {
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        Self::generate_with_threads(config, seed, threads)
    }

    /// [`Terrain::generate`] on `threads` threads (at least one); the result does not depend on it.
    pub fn generate_with_threads(config: &TerrainConfig, seed: u64, threads: usize) -> Terrain {
        let resolution_m = config.resolution_m;
        let cols = ((config.size_m[0] / resolution_m).round() as usize + 1).max(2);
        let rows = ((config.size_m[1] / resolution_m).round() as usize + 1).max(2);
        let mut heightfield = Heightfield {
            resolution_m,
            origin_m: [-0.5 * (cols - 1) as f64 * resolution_m, -0.5 * (rows - 1) as f64 * resolution_m],
            cols,
            rows,
            heights_m: vec![0.0; cols * rows],
        };
        let mut material = vec![Material::Regolith as u8; cols * rows];

        let craters = craters::sample(config, &heightfield, rng::stream_seed(seed, &[streams::CRATERS]));
        let relief = relief::Relief::new(config, rng::stream_seed(seed, &[streams::TERRAIN]));
        fill_rows_parallel(&mut heightfield, &mut material, threads, |grid, first_row, heights, material| {
            relief.fill(grid, first_row, heights);
            craters::apply(&craters, grid, first_row, heights, material);
        });
        slope::limit(&mut heightfield, config.max_natural_slope_deg.to_radians().tan());

        let ditches = ditches::place(config, &mut heightfield, rng::stream_seed(seed, &[streams::DITCHES]));
        let rocks =
            rocks::place(config, &mut heightfield, &mut material, &ditches, rng::stream(seed, &[streams::ROCKS]));

        let terrain = Terrain {
            config: config.clone(),
            seed,
            heightfield,
            material,
            rocks,
            craters: craters.iter().map(|c| c.crater).collect(),
            ditches,
            albedo_base: AlbedoBase::default(),
        };
        terrain.albedo_base.build(&terrain, threads);
        terrain
    }

    /// Diffuse albedo of the surface at `(x, y)`: the material's mean albedo (blended
    /// bilinearly between cell centres) times a multi-scale texture of eight value-noise octaves
    /// from 4 m down to 1.8 mm, so stereo has texture at any range. The four coarse octaves
    /// (4 m to 15 cm) and the material are sampled at the cell centres and interpolated
    /// bilinearly ([`Terrain::albedo_base`]); the four fine ones (5 cm to 1.8 mm) are evaluated
    /// at the point. Deterministic per seed, and non-repeating (hashed lattices, each octave
    /// rotated differently).
    pub fn albedo_at(&self, x_m: f64, y_m: f64) -> f32 {
        self.albedo_filtered(x_m, y_m, 0.0)
    }

    /// [`Terrain::albedo_at`] low-pass filtered for a pixel footprint of `footprint_m` on the
    /// ground, so that distant terrain does not alias: a fine octave fades out between
    /// wavelengths of four and two footprints (and is not evaluated at all once gone); the
    /// baked coarse part is read from a box-filtered level whose cells are as large as the
    /// footprint (trilinear between levels) once the footprint exceeds a cell. Filtering keeps
    /// the mean.
    pub fn albedo_filtered(&self, x_m: f64, y_m: f64, footprint_m: f64) -> f32 {
        albedo::filtered(self, x_m, y_m, footprint_m)
    }

    /// [`Terrain::albedo_filtered`] at many points at once, bit for bit the same per point
    /// (whatever its neighbours in the slices), several times faster: points are evaluated eight
    /// at a time in SIMD lanes, so neighbouring points (an image row) should come together.
    /// Fills `out[i]` for `i` below the shortest slice's length.
    pub fn albedo_filtered_many(&self, x_m: &[f64], y_m: &[f64], footprint_m: &[f32], out: &mut [f32]) {
        albedo::filtered_many(self, x_m, y_m, footprint_m, out);
    }

    /// Material of the cell containing `(x, y)`, `None` outside the grid.
    pub fn material_at(&self, x_m: f64, y_m: f64) -> Option<Material> {
        let (col, row) = self.heightfield.cell_at(x_m, y_m)?;
        Some(Material::from_u8(self.material[row * self.heightfield.cols + col]))
    }

    /// The negative obstacles (crater edges steeper than a rover may descend, ditches).
    ///
    /// A crater contributes the arcs of its rim where the ground inside drops by more than
    /// [`CRATER_EDGE_MIN_DROP_M`] within [`CRATER_EDGE_RUN_M`] of the crest, measured on the
    /// generated heightfield (so later craters and the slope limit are accounted for). A ditch
    /// contributes the closed outline of its top edge.
    pub fn negative_obstacles(&self) -> Vec<NegativeObstacle> {
        let mut out = Vec::new();
        for crater in &self.craters {
            craters::edge_obstacles(crater, &self.heightfield, &mut out);
        }
        for ditch in &self.ditches {
            out.push(NegativeObstacle {
                kind: NegativeObstacleKind::Ditch,
                edge_m: ditches::outline(ditch),
                drop_m: ditch.depth_m,
            });
        }
        out
    }
}

/// Runs `fill(grid, first_row, heights, material)` over bands of rows on all cores. Each cell's
/// value depends only on its coordinates and the fixed order of operations inside `fill`, so
/// the result is identical for any number of threads.
fn fill_rows_parallel(
    heightfield: &mut Heightfield,
    material: &mut [u8],
    threads: usize,
    fill: impl Fn(&Heightfield, usize, &mut [f32], &mut [u8]) + Sync,
) {
    let cols = heightfield.cols;
    let rows = heightfield.rows;
    let threads = threads.clamp(1, rows.max(1));
    // Several bands per thread balance the uneven crater load.
    let band_rows = rows.div_ceil(threads * 4).max(1);
    let mut heights = std::mem::take(&mut heightfield.heights_m);
    let grid: &Heightfield = heightfield;
    let bands: Vec<(usize, &mut [f32], &mut [u8])> = heights
        .chunks_mut(band_rows * cols)
        .zip(material.chunks_mut(band_rows * cols))
        .enumerate()
        .map(|(i, (h, m))| (i * band_rows, h, m))
        .collect();
    let queue = std::sync::Mutex::new(bands);
    std::thread::scope(|scope| {
        for _ in 0..threads {
            scope.spawn(|| {
                loop {
                    let band = match queue.lock() {
                        Ok(mut q) => q.pop(),
                        Err(_) => None,
                    };
                    let Some((first_row, h, m)) = band else { break };
                    fill(grid, first_row, h, m);
                }
            });
        }
    });
    heightfield.heights_m = heights;
}

impl Heightfield {
    /// Height of the surface mesh at `(x, y)`, `None` outside the grid's cell centres.
    pub fn height_at(&self, x_m: f64, y_m: f64) -> Option<f64> {
        let t = self.triangle_at(x_m, y_m)?;
        Some(t.h00 + t.gx_m * t.dx_m + t.gy_m * t.dy_m)
    }

    /// Upward unit normal of the mesh triangle under `(x, y)`.
    pub fn normal_at(&self, x_m: f64, y_m: f64) -> Option<Vector3<f64>> {
        let t = self.triangle_at(x_m, y_m)?;
        Some(Vector3::new(-t.gx_m, -t.gy_m, 1.0).normalize())
    }

    /// Height of cell `(col, row)`, indices clamped into the grid.
    pub fn height_at_cell(&self, col: isize, row: isize) -> f32 {
        let c = col.clamp(0, self.cols as isize - 1) as usize;
        let r = row.clamp(0, self.rows as isize - 1) as usize;
        self.heights_m[r * self.cols + c]
    }

    /// The `HEIGHTGRID v1` text `eval::map::HeightGrid::parse` reads, over the cells whose
    /// centres lie in `[min, max]` (world x, y), every `step`-th cell. Heights are written to the
    /// millimetre. An empty selection gives a header with zero columns or rows.
    pub fn to_height_grid_text(&self, min_m: [f64; 2], max_m: [f64; 2], step: usize) -> String {
        heightfield::height_grid_text(self, min_m, max_m, step)
    }

    /// The cell whose footprint (half a cell either side of its centre) contains `(x, y)`.
    pub fn cell_at(&self, x_m: f64, y_m: f64) -> Option<(usize, usize)> {
        let col = ((x_m - self.origin_m[0]) / self.resolution_m).round();
        let row = ((y_m - self.origin_m[1]) / self.resolution_m).round();
        let inside = |v: f64, n: usize| v >= 0.0 && v < n as f64;
        (inside(col, self.cols) && inside(row, self.rows)).then_some((col as usize, row as usize))
    }

    /// World (x, y) of the centre of cell `(col, row)`.
    pub fn cell_centre_m(&self, col: usize, row: usize) -> [f64; 2] {
        [self.origin_m[0] + col as f64 * self.resolution_m, self.origin_m[1] + row as f64 * self.resolution_m]
    }

    /// World (x, y) bounds of the mesh (the outermost cell centres).
    pub fn bounds_m(&self) -> ([f64; 2], [f64; 2]) {
        (self.origin_m, self.cell_centre_m(self.cols.saturating_sub(1), self.rows.saturating_sub(1)))
    }

    /// Slope of each mesh triangle in radians (two per cell square, lower then upper), row-major
    /// over the `(cols − 1) × (rows − 1)` squares.
    pub fn triangle_slopes_rad(&self) -> Vec<[f32; 2]> {
        heightfield::triangle_slopes(self)
    }

    fn triangle_at(&self, x_m: f64, y_m: f64) -> Option<heightfield::Triangle> {
        heightfield::triangle_at(self, x_m, y_m)
    }
}
