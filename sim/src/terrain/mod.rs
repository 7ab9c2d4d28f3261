//! Procedural planetary terrain, deterministic for a seed: fractal relief, impact craters with
//! raised rims, rocks as solids on the ground, ditches, and the material map the renderer's
//! albedo uses.
//!
//! CONTRACT (owned by the terrain helper; the renderer, motion and pictures rely on it):
//! the surface is the triangle mesh over the cell centres, each cell square `(c, r)–(c+1, r+1)`
//! split along its diagonal from `(c, r)` to `(c+1, r+1)`; [`Heightfield::height_at`] and
//! [`Heightfield::normal_at`] evaluate exactly that mesh, and the ray caster intersects it.

use nalgebra::{Point3, Vector3};

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

impl Heightfield {
    /// Height of the surface mesh at `(x, y)`, `None` outside the grid's cell centres.
    pub fn height_at(&self, x_m: f64, y_m: f64) -> Option<f64> {
        let _ = (x_m, y_m);
        None
    }

    /// Upward unit normal of the mesh triangle under `(x, y)`.
    pub fn normal_at(&self, x_m: f64, y_m: f64) -> Option<Vector3<f64>> {
        let _ = (x_m, y_m);
        None
    }

    /// Height of cell `(col, row)`, indices clamped into the grid.
    pub fn height_at_cell(&self, col: isize, row: isize) -> f32 {
        let c = col.clamp(0, self.cols as isize - 1) as usize;
        let r = row.clamp(0, self.rows as isize - 1) as usize;
        self.heights_m[r * self.cols + c]
    }

    /// The `HEIGHTGRID v1` text `eval::map::HeightGrid::parse` reads, over the cells whose
    /// centres lie in `[min, max]` (world x, y), every `step`-th cell.
    pub fn to_height_grid_text(&self, min_m: [f64; 2], max_m: [f64; 2], step: usize) -> String {
        let _ = (min_m, max_m, step);
        String::new()
    }
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
#[derive(Debug, Clone, PartialEq)]
pub struct TerrainConfig {
    /// Edge lengths in x and y; the terrain is centred on the world origin.
    pub size_m: [f64; 2],
    pub resolution_m: f64,
    /// Helper-defined knobs (relief amplitude, crater and rock densities, ditches, albedo).
    pub relief_amplitude_m: f64,
    pub craters_per_km2: f64,
    pub rocks_per_100m2: f64,
    pub ditches: usize,
    /// Mean albedo and its contrast.
    pub albedo_mean: f32,
    pub albedo_contrast: f32,
}

impl TerrainConfig {
    /// A Moon-analogue site (like the thesis's Mt. Etna tests): 200 m × 200 m at 5 cm.
    pub fn moon() -> Self {
        TerrainConfig {
            size_m: [200.0, 200.0],
            resolution_m: 0.05,
            relief_amplitude_m: 2.0,
            craters_per_km2: 300.0,
            rocks_per_100m2: 1.0,
            ditches: 4,
            albedo_mean: 0.12,
            albedo_contrast: 0.3,
        }
    }

    /// A Mars-like site: 200 m × 200 m at 5 cm.
    pub fn mars() -> Self {
        Self::moon()
    }

    /// The same preset on a smaller square (fast tests).
    pub fn with_size(mut self, edge_m: f64) -> Self {
        self.size_m = [edge_m, edge_m];
        self
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
}

impl Terrain {
    /// Generates the terrain of `config` for `seed` (byte-identical for equal inputs).
    pub fn generate(config: &TerrainConfig, seed: u64) -> Terrain {
        let cols = (config.size_m[0] / config.resolution_m).round() as usize + 1;
        let rows = (config.size_m[1] / config.resolution_m).round() as usize + 1;
        Terrain {
            config: config.clone(),
            seed,
            heightfield: Heightfield {
                resolution_m: config.resolution_m,
                origin_m: [-0.5 * config.size_m[0], -0.5 * config.size_m[1]],
                cols,
                rows,
                heights_m: vec![0.0; cols * rows],
            },
            material: vec![0; cols * rows],
            rocks: Vec::new(),
            craters: Vec::new(),
            ditches: Vec::new(),
        }
    }

    /// Diffuse albedo of the surface at `(x, y)`: multi-scale texture down to millimetres, so
    /// stereo has texture at any range; depends on the cell's material.
    pub fn albedo_at(&self, x_m: f64, y_m: f64) -> f32 {
        let _ = (x_m, y_m);
        self.config.albedo_mean
    }

    /// [`Terrain::albedo_at`] low-pass filtered for a pixel footprint of `footprint_m` on the
    /// ground: octaves finer than the footprint are left out (their mean is kept), so distant
    /// terrain does not alias. This is what the renderer calls per pixel.
    pub fn albedo_filtered(&self, x_m: f64, y_m: f64, footprint_m: f64) -> f32 {
        let _ = footprint_m;
        self.albedo_at(x_m, y_m)
    }

    /// The negative obstacles (crater edges steeper than a rover may descend, ditches).
    pub fn negative_obstacles(&self) -> Vec<NegativeObstacle> {
        Vec::new()
    }
}
