//! The team map on the ground: each received submap rasterized once into a height/obstacle tile
//! in its own frame, and the tiles composed at their current poses into one [`HeightGrid`] and one
//! decimated [`MapPoints`] in the reference frame.
//!
//! Composition samples each tile at the centres of the grid cells its footprint covers (inverse
//! mapping, so a rotated tile leaves no holes), later submaps over earlier ones, obstacles OR-ed.
//! It runs only when a tile arrives or a placed tile moved by more than [`MOVE_THRESHOLD_M`] /
//! [`TURN_THRESHOLD_RAD`]; between compositions the published grid is shared, not copied.

use std::collections::BTreeMap;
use std::sync::Arc;

use mapper::Submap;
use mapper::cloud::VoxelCloud;
use nalgebra::{Isometry3, Point3, Vector3};

use crate::view::{HeightGrid, MapPoints};

/// Cell of a submap tile and the finest cell of the composed grid, m.
pub const TILE_CELL_M: f64 = 0.1;
/// The composed grid never exceeds this many cells per side: its cell doubles until it fits
/// (200 m at 0.1 m is 2000 cells).
pub const MAX_GRID_CELLS: usize = 2048;
/// Points per submap kept for the 3D view, decimated in the submap frame.
pub const TILE_POINT_LEAF_M: f64 = 0.2;
/// Most points in the published [`MapPoints`].
pub const MAX_MAP_POINTS: usize = 200_000;
/// A placed tile that moved less than this is not a reason to recompose.
pub const MOVE_THRESHOLD_M: f64 = 0.03;
pub const TURN_THRESHOLD_RAD: f64 = 0.5 * std::f64::consts::PI / 180.0;

/// One submap rasterized in its own frame.
#[derive(Debug, Clone, PartialEq)]
pub struct Tile {
    /// Lower corner of cell (0, 0) in the submap frame, m.
    pub origin_xy_m: [f64; 2],
    pub width: usize,
    pub height: usize,
    /// Highest point per cell, m in the submap frame; NaN where empty.
    pub height_m: Vec<f32>,
    pub obstacle: Vec<bool>,
    /// `[min_x, min_y, max_x, max_y]` of the points, submap frame.
    pub bounds_m: [f64; 4],
    /// Points decimated to [`TILE_POINT_LEAF_M`], submap frame, with their obstacle bit.
    pub points: Vec<([f32; 3], bool)>,
}

impl Tile {
    /// `None` for a submap without finite points.
    pub fn rasterize(submap: &Submap) -> Option<Tile> {
        let finite = |p: &Point3<f32>| p.coords.iter().all(|v| v.is_finite() && v.abs() < 1e5);
        let mut bounds = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
        for p in submap.cloud.points.iter().filter(|p| finite(&p.position_m)) {
            let (x, y) = (f64::from(p.position_m.x), f64::from(p.position_m.y));
            bounds = [bounds[0].min(x), bounds[1].min(y), bounds[2].max(x), bounds[3].max(y)];
        }
        if !bounds.iter().all(|v| v.is_finite()) {
            return None;
        }
        let origin = [(bounds[0] / TILE_CELL_M).floor() * TILE_CELL_M, (bounds[1] / TILE_CELL_M).floor() * TILE_CELL_M];
        let width = ((bounds[2] - origin[0]) / TILE_CELL_M).floor() as usize + 1;
        let height = ((bounds[3] - origin[1]) / TILE_CELL_M).floor() as usize + 1;
        let mut height_m = vec![f32::NAN; width * height];
        let mut obstacle = vec![false; width * height];
        for p in submap.cloud.points.iter().filter(|p| finite(&p.position_m)) {
            let c = ((f64::from(p.position_m.x) - origin[0]) / TILE_CELL_M) as usize;
            let r = ((f64::from(p.position_m.y) - origin[1]) / TILE_CELL_M) as usize;
            let i = r.min(height - 1) * width + c.min(width - 1);
            let h = &mut height_m[i];
            if h.is_nan() || p.position_m.z > *h {
                *h = p.position_m.z;
            }
            obstacle[i] |= p.obstacle;
        }
        let decimated = VoxelCloud::filtered(TILE_POINT_LEAF_M, &submap.cloud.points);
        let points = decimated
            .points
            .iter()
            .filter(|p| finite(&p.position_m))
            .map(|p| ([p.position_m.x, p.position_m.y, p.position_m.z], p.obstacle))
            .collect();
        Some(Tile { origin_xy_m: origin, width, height, height_m, obstacle, bounds_m: bounds, points })
    }

    /// The tile's value at `(x, y)` in the submap frame.
    fn sample(&self, x: f64, y: f64) -> Option<(f32, bool)> {
        let c = ((x - self.origin_xy_m[0]) / TILE_CELL_M).floor();
        let r = ((y - self.origin_xy_m[1]) / TILE_CELL_M).floor();
        if c < 0.0 || r < 0.0 || c >= self.width as f64 || r >= self.height as f64 {
            return None;
        }
        let i = r as usize * self.width + c as usize;
        let h = self.height_m[i];
        (!h.is_nan()).then(|| (h, self.obstacle[i]))
    }
}

/// A tile to compose: its key (composition order), pose in the reference frame and data.
#[derive(Debug, Clone)]
pub struct Placed {
    /// Later keys are drawn over earlier ones (finish stamp, robot, index).
    pub order: (u64, u8, u32),
    pub t_ref_submap: Isometry3<f64>,
    pub tile: Arc<Tile>,
}

/// Composition statistics of the last run.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ComposeStats {
    pub tiles: usize,
    pub cell_m: f64,
    pub grid_cells: usize,
    pub points: usize,
    pub point_leaf_m: f64,
}

/// The composed map and what it was composed from.
#[derive(Debug, Clone)]
pub struct MapComposer {
    /// Poses (and tile identity) at the last composition, by submap.
    composed: BTreeMap<(u8, u32), (Isometry3<f64>, usize)>,
    pub grid: Option<Arc<HeightGrid>>,
    pub points: Arc<MapPoints>,
    revision: u64,
    pub last_stats: ComposeStats,
}

impl Default for MapComposer {
    fn default() -> Self {
        MapComposer {
            composed: BTreeMap::new(),
            grid: None,
            points: Arc::new(MapPoints::default()),
            revision: 0,
            last_stats: ComposeStats::default(),
        }
    }
}

fn moved(a: &Isometry3<f64>, b: &Isometry3<f64>) -> bool {
    let d = a.inverse() * b;
    d.translation.vector.norm() > MOVE_THRESHOLD_M || d.rotation.angle() > TURN_THRESHOLD_RAD
}

impl MapComposer {
    /// Whether composing `placed` would change the map (a tile appeared, vanished or moved).
    pub fn needs_compose(&self, placed: &BTreeMap<(u8, u32), Placed>) -> bool {
        if placed.len() != self.composed.len() {
            return true;
        }
        placed.iter().any(|(key, p)| match self.composed.get(key) {
            Some((pose, tile)) => *tile != Arc::as_ptr(&p.tile) as usize || moved(pose, &p.t_ref_submap),
            None => true,
        })
    }

    /// Recomposes the grid and the points from every placed tile.
    pub fn compose(&mut self, placed: &BTreeMap<(u8, u32), Placed>) {
        self.revision += 1;
        self.composed = placed.iter().map(|(k, p)| (*k, (p.t_ref_submap, Arc::as_ptr(&p.tile) as usize))).collect();
        let mut ordered: Vec<&Placed> = placed.values().collect();
        ordered.sort_by_key(|p| p.order);
        self.grid = compose_grid(&ordered, self.revision).map(Arc::new);
        let (points, leaf) = compose_points(&ordered, self.revision);
        self.last_stats = ComposeStats {
            tiles: ordered.len(),
            cell_m: self.grid.as_ref().map_or(0.0, |g| g.cell_m),
            grid_cells: self.grid.as_ref().map_or(0, |g| g.width * g.height),
            points: points.points_ref_m.len(),
            point_leaf_m: leaf,
        };
        self.points = Arc::new(points);
    }
}

/// The xy corners of a tile's footprint in the reference frame.
fn footprint(p: &Placed) -> [[f64; 2]; 4] {
    let t = &p.tile;
    let (x0, y0) = (t.origin_xy_m[0], t.origin_xy_m[1]);
    let (x1, y1) = (x0 + t.width as f64 * TILE_CELL_M, y0 + t.height as f64 * TILE_CELL_M);
    [[x0, y0], [x1, y0], [x0, y1], [x1, y1]].map(|[x, y]| {
        let q = p.t_ref_submap * Point3::new(x, y, 0.0);
        [q.x, q.y]
    })
}

fn compose_grid(ordered: &[&Placed], revision: u64) -> Option<HeightGrid> {
    let mut lo = [f64::INFINITY; 2];
    let mut hi = [f64::NEG_INFINITY; 2];
    for p in ordered {
        for [x, y] in footprint(p) {
            lo = [lo[0].min(x), lo[1].min(y)];
            hi = [hi[0].max(x), hi[1].max(y)];
        }
    }
    if !(lo.iter().chain(&hi).all(|v| v.is_finite())) {
        return None;
    }
    let mut cell = TILE_CELL_M;
    let cells =
        |cell: f64| (((hi[0] - lo[0]) / cell).ceil() as usize + 1, ((hi[1] - lo[1]) / cell).ceil() as usize + 1);
    while cells(cell).0.max(cells(cell).1) > MAX_GRID_CELLS {
        cell *= 2.0;
    }
    let origin = [(lo[0] / cell).floor() * cell, (lo[1] / cell).floor() * cell];
    let width = (((hi[0] - origin[0]) / cell).ceil() as usize).clamp(1, MAX_GRID_CELLS);
    let height = (((hi[1] - origin[1]) / cell).ceil() as usize).clamp(1, MAX_GRID_CELLS);
    let mut height_m = vec![f32::NAN; width * height];
    let mut obstacle = vec![false; width * height];
    for p in ordered {
        let corners = footprint(p);
        let (mut fx, mut fy) = (f64::INFINITY, f64::INFINITY);
        let (mut tx, mut ty) = (f64::NEG_INFINITY, f64::NEG_INFINITY);
        for [x, y] in corners {
            (fx, fy, tx, ty) = (fx.min(x), fy.min(y), tx.max(x), ty.max(y));
        }
        let c0 = (((fx - origin[0]) / cell).floor().max(0.0) as usize).min(width - 1);
        let c1 = (((tx - origin[0]) / cell).ceil().max(0.0) as usize).min(width);
        let r0 = (((fy - origin[1]) / cell).floor().max(0.0) as usize).min(height - 1);
        let r1 = (((ty - origin[1]) / cell).ceil().max(0.0) as usize).min(height);
        let inverse = p.t_ref_submap.inverse();
        // Reference xy → submap xy is affine: start per row and step by one column's vector.
        let step = inverse.rotation * Vector3::new(cell, 0.0, 0.0);
        let forward = p.t_ref_submap.rotation.to_rotation_matrix();
        let (rz, tz) = (forward.matrix().row(2).into_owned(), p.t_ref_submap.translation.z);
        let z_at = p.t_ref_submap.translation.z;
        for r in r0..r1 {
            let gy = origin[1] + (r as f64 + 0.5) * cell;
            let gx = origin[0] + (c0 as f64 + 0.5) * cell;
            let mut s = inverse * Point3::new(gx, gy, z_at);
            for c in c0..c1 {
                if let Some((h, obstacle_here)) = p.tile.sample(s.x, s.y) {
                    let z = rz[0] * s.x + rz[1] * s.y + rz[2] * f64::from(h) + tz;
                    let i = r * width + c;
                    height_m[i] = z as f32;
                    obstacle[i] |= obstacle_here;
                }
                s += step;
            }
        }
    }
    Some(HeightGrid { origin_xy_m: origin, cell_m: cell, width, height, height_m, obstacle, revision })
}

/// A voxel's key, 21 bits per axis (±100 km at 0.1 m).
fn voxel_key(p: &[f32; 3], leaf: f64) -> u64 {
    let k = |v: f32| (((f64::from(v) / leaf).floor() as i64 + (1 << 20)) as u64) & 0x1F_FFFF;
    (k(p[0]) << 42) | (k(p[1]) << 21) | k(p[2])
}

/// One point per voxel (the first in composition order, obstacle bits OR-ed). The leaf starts
/// where a 2.5D surface would fit the cap and grows until it does.
fn compose_points(ordered: &[&Placed], revision: u64) -> (MapPoints, f64) {
    let mut points: Vec<([f32; 3], bool)> = Vec::new();
    for p in ordered {
        let t = &p.t_ref_submap;
        points.extend(p.tile.points.iter().map(|(q, o)| {
            let r = t * Point3::new(f64::from(q[0]), f64::from(q[1]), f64::from(q[2]));
            ([r.x as f32, r.y as f32, r.z as f32], *o)
        }));
    }
    let mut leaf = TILE_POINT_LEAF_M * (points.len() as f64 / MAX_MAP_POINTS as f64).sqrt().max(1.0);
    loop {
        // Sorting keys (stable for equal keys) instead of hashing: deterministic and fast.
        let mut keys: Vec<(u64, u32)> =
            points.iter().enumerate().map(|(i, (q, _))| (voxel_key(q, leaf), i as u32)).collect();
        keys.sort_unstable();
        let mut kept: Vec<([f32; 3], bool)> = Vec::with_capacity(points.len().min(MAX_MAP_POINTS * 2));
        let mut previous = None;
        for (key, i) in keys {
            let (q, o) = points[i as usize];
            if previous == Some(key) {
                if let Some(last) = kept.last_mut() {
                    last.1 |= o;
                }
            } else {
                kept.push((q, o));
                previous = Some(key);
            }
        }
        points = kept;
        if points.len() <= MAX_MAP_POINTS {
            break;
        }
        leaf *= 1.2;
    }
    let (points_ref_m, obstacle) = points.into_iter().unzip();
    (MapPoints { points_ref_m, obstacle, revision }, leaf)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use mapper::MapPoint;
    use nalgebra::{Matrix6, Translation3, UnitQuaternion};

    fn flat_submap(size_m: f32, z: f32) -> Submap {
        let mut s = Submap::new(1, 0, 0, Isometry3::identity(), Matrix6::zeros());
        let n = (size_m / 0.05) as i32;
        for i in 0..n {
            for j in 0..n {
                let p = Point3::new(i as f32 * 0.05 + 0.025, j as f32 * 0.05 + 0.025, z);
                s.cloud.points.push(MapPoint { position_m: p, intensity: 100, obstacle: i == n / 2 && j == n / 2 });
            }
        }
        s
    }

    #[test]
    fn a_rotated_tile_lands_where_its_pose_says_without_holes() {
        let tile = Arc::new(Tile::rasterize(&flat_submap(2.0, 0.5)).unwrap());
        assert_eq!((tile.width, tile.height), (20, 20));
        let pose = Isometry3::from_parts(
            Translation3::new(10.0, -5.0, 1.0),
            UnitQuaternion::from_euler_angles(0.0, 0.0, std::f64::consts::FRAC_PI_2),
        );
        let placed = BTreeMap::from([((1, 0), Placed { order: (0, 1, 0), t_ref_submap: pose, tile })]);
        let mut composer = MapComposer::default();
        assert!(composer.needs_compose(&placed));
        composer.compose(&placed);
        assert!(!composer.needs_compose(&placed));
        let grid = composer.grid.clone().unwrap();
        // Rotated by 90°: x ∈ [8, 10], y ∈ [-5, -3].
        let at = |x: f64, y: f64| {
            let c = ((x - grid.origin_xy_m[0]) / grid.cell_m) as usize;
            let r = ((y - grid.origin_xy_m[1]) / grid.cell_m) as usize;
            grid.height_m[r * grid.width + c]
        };
        assert!((at(9.0, -4.0) - 1.5).abs() < 1e-5, "{}", at(9.0, -4.0));
        let filled = grid.height_m.iter().filter(|h| !h.is_nan()).count();
        assert!(filled >= 19 * 19, "holes: {filled} of {} cells filled", grid.width * grid.height);
        assert_eq!(grid.obstacle.iter().filter(|o| **o).count(), 1);
        assert!(composer.points.points_ref_m.iter().all(|p| p[0] > 7.9 && p[0] < 10.1 && p[1] > -5.1 && p[1] < -2.9));
    }
}
