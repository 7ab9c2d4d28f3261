//! The composed global map (thesis §5.2.2): every finished submap (own and received) at its
//! current graph pose, plus the robot's current submap, merged into one 5 cm cloud and one
//! 10 cm occupancy grid.
//!
//! # Merging
//!
//! - Cloud: the submap points are transformed and voxel-filtered again at 5 cm (centroid of the
//!   contributing points, mean intensity, obstacle OR), i.e. "concatenate, then voxel filter".
//! - Occupancy: a submap's grid is rotated by its yaw (and tilted slightly) relative to the global
//!   grid, so its leaves are resampled: a global voxel receives a value when its centre falls
//!   inside a known submap voxel (so known volume is kept, not dilated), and the value is the
//!   trilinear interpolation (Jessup et al. 2015) of the log-odds of the 8 submap voxel centres
//!   around it, over the known ones only (weights renormalized; unknown is not 0, it is absent).
//!   The resampled grids are then summed with clamping sequentially in (robot id, index) order,
//!   as eq. 5.9 does for observations; clamping makes the result order dependent (§5.3.2), so
//!   the order is fixed.
//!
//! # Caching (trap 19)
//!
//! Each finished submap's resampled contribution is kept with the pose it was made at. A
//! compose recomputes only submaps whose pose moved their farthest point by more than
//! [`GlobalMapConfig::recompose_displacement_m`] (default 2 cm, below the 5 cm leaf), and only
//! the voxels those submaps touched before or touch now are re-summed, from all contributions in
//! the fixed order. A cached composition is therefore identical to a composition from scratch
//! at the cached poses. The current (unfinished) own submap is merged fresh on every call and
//! never cached (trap 18).

use std::collections::BTreeMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nalgebra::{Isometry3, Point3};

use crate::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
use crate::occupancy::{OCTREE_RESOLUTION_M, OccupancyMap, OccupancyParams, VoxelKey};
use crate::submap::Submap;

/// A multiply-rotate hasher for integer voxel keys: SipHash's DoS resistance buys nothing for
/// keys we compute ourselves and costs most of the composition time.
#[derive(Debug, Default, Clone, Copy)]
struct KeyHasher(u64);

impl Hasher for KeyHasher {
    /// Four bytes per round: `[i32; 3]` keys are hashed through here, byte-wise that was 13
    /// dependent multiplies per key.
    fn write(&mut self, bytes: &[u8]) {
        let mut words = bytes.chunks_exact(4);
        for w in &mut words {
            if let Ok(w) = <[u8; 4]>::try_from(w) {
                self.write_u64(u64::from(u32::from_le_bytes(w)));
            }
        }
        for b in words.remainder() {
            self.write_u8(*b);
        }
    }

    fn write_usize(&mut self, i: usize) {
        self.write_u64(i as u64);
    }

    fn write_u8(&mut self, i: u8) {
        self.write_u64(u64::from(i));
    }

    fn write_i32(&mut self, i: i32) {
        self.write_u64(u64::from(i as u32));
    }

    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }

    fn finish(&self) -> u64 {
        self.0 ^ (self.0 >> 29)
    }
}

type HashMap<K, V> = std::collections::HashMap<K, V, BuildHasherDefault<KeyHasher>>;
type HashSet<K> = std::collections::HashSet<K, BuildHasherDefault<KeyHasher>>;

/// (robot id, submap index): the key of a submap across the team.
pub type SubmapId = (u16, u32);

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GlobalMapConfig {
    pub cloud_leaf_m: f64,
    pub occupancy_resolution_m: f64,
    pub occupancy_params: OccupancyParams,
    /// A submap is recomposed when its pose change moves any of its points by more than this.
    /// The thesis leaves "significant" open; 2 cm keeps the cached map within half a cloud leaf
    /// of the fresh one while loop closures (decimetres) still trigger a recompose.
    pub recompose_displacement_m: f64,
}

impl Default for GlobalMapConfig {
    fn default() -> Self {
        GlobalMapConfig {
            cloud_leaf_m: CLOUD_LEAF_M,
            occupancy_resolution_m: OCTREE_RESOLUTION_M,
            occupancy_params: OccupancyParams::default(),
            recompose_displacement_m: 0.02,
        }
    }
}

/// Sums of the points falling into one composed cloud voxel.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
struct CloudAcc {
    sum_m: [f64; 3],
    sum_intensity: u64,
    count: u32,
    obstacle: bool,
}

impl CloudAcc {
    fn add(&mut self, other: &CloudAcc) {
        for (s, o) in self.sum_m.iter_mut().zip(other.sum_m) {
            *s += o;
        }
        self.sum_intensity += other.sum_intensity;
        self.count += other.count;
        self.obstacle |= other.obstacle;
    }

    /// The centroid, kept inside voxel `key` after rounding to `f32` so that
    /// [`VoxelCloud::voxel_of`] of the output point is its voxel.
    fn point(&self, key: &[i32; 3], leaf_m: f64) -> MapPoint {
        let n = f64::from(self.count.max(1));
        let coord = |a: usize| {
            let mut c = (self.sum_m[a] / n) as f32;
            for _ in 0..4 {
                let k = (f64::from(c) / leaf_m).floor() as i32;
                if k < key[a] {
                    c = c.next_up();
                } else if k > key[a] {
                    c = c.next_down();
                } else {
                    break;
                }
            }
            c
        };
        MapPoint {
            position_m: Point3::new(coord(0), coord(1), coord(2)),
            intensity: (self.sum_intensity / u64::from(self.count.max(1))).min(255) as u8,
            obstacle: self.obstacle,
        }
    }
}

/// Inclusive integer box of voxel keys.
#[derive(Debug, Clone, Copy, PartialEq)]
struct KeyBox {
    min: [i32; 3],
    max: [i32; 3],
}

impl KeyBox {
    fn of<'a>(keys: impl Iterator<Item = &'a [i32; 3]>) -> Option<KeyBox> {
        let mut b: Option<KeyBox> = None;
        for k in keys {
            let bb = b.get_or_insert(KeyBox { min: *k, max: *k });
            bb.min = std::array::from_fn(|a| bb.min[a].min(k[a]));
            bb.max = std::array::from_fn(|a| bb.max[a].max(k[a]));
        }
        b
    }

    fn contains(&self, k: &[i32; 3]) -> bool {
        (0..3).all(|a| self.min[a] <= k[a] && k[a] <= self.max[a])
    }
}

/// One submap resampled into the global grids at `t_global_submap`.
#[derive(Debug, Clone, Default)]
struct Contribution {
    cloud: HashMap<[i32; 3], CloudAcc>,
    cloud_box: Option<KeyBox>,
    occupancy: HashMap<VoxelKey, f32>,
    occupancy_box: Option<KeyBox>,
}

#[derive(Debug)]
struct Entry {
    submap: Arc<Submap>,
    t_global_submap: Isometry3<f64>,
    /// Distance of the submap's farthest point from its origin (m): turns a rotation into a
    /// displacement bound.
    radius_m: f64,
    /// The pose `contribution` was made at; `None` until first composed.
    composed: Option<(Isometry3<f64>, Contribution)>,
}

/// What one [`GlobalMap::compose`] cost.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct ComposeStats {
    /// Finished submaps whose contribution was (re)computed by this call.
    pub recomposed_submaps: usize,
    /// Finished submaps whose cached contribution was reused.
    pub cached_submaps: usize,
    /// Composed voxels re-summed because a recomposed submap touched them.
    pub dirty_cloud_voxels: usize,
    pub dirty_occupancy_voxels: usize,
    pub elapsed: Duration,
}

/// A composed map, in the global frame.
#[derive(Debug, Clone)]
pub struct Composition {
    pub cloud: VoxelCloud,
    pub occupancy: OccupancyMap,
    pub stats: ComposeStats,
}

/// Finished submaps at their graph poses and the cached composition of them.
#[derive(Debug)]
pub struct GlobalMap {
    config: GlobalMapConfig,
    entries: BTreeMap<SubmapId, Entry>,
    /// Composition of the finished submaps at their composed poses.
    cloud: HashMap<[i32; 3], CloudAcc>,
    occupancy: HashMap<VoxelKey, f32>,
    /// `occupancy` as an [`OccupancyMap`], kept up to date so that a compose clones it instead of
    /// re-inserting every leaf (0.55 s for the 3.7 M leaves of the KITTI run).
    occupancy_map: OccupancyMap,
    /// Voxels of submaps removed or replaced since the last compose, to be re-summed.
    pending_cloud: HashSet<[i32; 3]>,
    pending_occupancy: HashSet<VoxelKey>,
}

impl GlobalMap {
    pub fn new(config: GlobalMapConfig) -> GlobalMap {
        GlobalMap {
            config,
            entries: BTreeMap::new(),
            cloud: HashMap::default(),
            occupancy: HashMap::default(),
            occupancy_map: OccupancyMap::new(config.occupancy_resolution_m, config.occupancy_params),
            pending_cloud: HashSet::default(),
            pending_occupancy: HashSet::default(),
        }
    }

    pub fn config(&self) -> &GlobalMapConfig {
        &self.config
    }

    /// Adds a finished submap (own or received) at its current graph pose. A submap with the
    /// same (robot, index) is replaced.
    pub fn insert(&mut self, submap: Arc<Submap>, t_global_submap: Isometry3<f64>) {
        let id = (submap.robot_id, submap.index);
        let radius_m = submap_radius_m(&submap);
        if let Some(old) = self.entries.remove(&id) {
            self.forget(old);
        }
        self.entries.insert(id, Entry { submap, t_global_submap, radius_m, composed: None });
    }

    /// Removes a submap; returns whether it was present.
    pub fn remove(&mut self, id: SubmapId) -> bool {
        match self.entries.remove(&id) {
            Some(old) => {
                self.forget(old);
                true
            }
            None => false,
        }
    }

    /// Updates a submap's graph pose (after an optimization); returns whether it is known.
    /// Takes effect at the next [`GlobalMap::compose`] if the change is significant.
    pub fn set_pose(&mut self, id: SubmapId, t_global_submap: Isometry3<f64>) -> bool {
        match self.entries.get_mut(&id) {
            Some(e) => {
                e.t_global_submap = t_global_submap;
                true
            }
            None => false,
        }
    }

    pub fn pose(&self, id: SubmapId) -> Option<Isometry3<f64>> {
        self.entries.get(&id).map(|e| e.t_global_submap)
    }

    pub fn len(&self) -> usize {
        self.entries.len()
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Submaps in composition order.
    pub fn submaps(&self) -> impl Iterator<Item = (&Arc<Submap>, &Isometry3<f64>)> {
        self.entries.values().map(|e| (&e.submap, &e.t_global_submap))
    }

    fn forget(&mut self, old: Entry) {
        if let Some((_, c)) = old.composed {
            self.pending_cloud.extend(c.cloud.keys().copied());
            self.pending_occupancy.extend(c.occupancy.keys().copied());
        }
    }

    /// Composes all finished submaps (cached) and `current`, the robot's own unfinished submap
    /// at its pose (fresh, merged last, never cached).
    pub fn compose(&mut self, current: Option<(&Submap, &Isometry3<f64>)>) -> Composition {
        let started = Instant::now();
        let mut stats = ComposeStats::default();
        let mut dirty_cloud = std::mem::take(&mut self.pending_cloud);
        let mut dirty_occupancy = std::mem::take(&mut self.pending_occupancy);
        let config = self.config;
        for e in self.entries.values_mut() {
            let moved = match &e.composed {
                None => true,
                Some((t_composed, _)) => {
                    pose_displacement_m(t_composed, &e.t_global_submap, e.radius_m) > config.recompose_displacement_m
                }
            };
            if !moved {
                stats.cached_submaps += 1;
                continue;
            }
            stats.recomposed_submaps += 1;
            if let Some((_, old)) = e.composed.take() {
                dirty_cloud.extend(old.cloud.keys().copied());
                dirty_occupancy.extend(old.occupancy.keys().copied());
            }
            let c = contribution(&e.submap, &e.t_global_submap, &config);
            dirty_cloud.extend(c.cloud.keys().copied());
            dirty_occupancy.extend(c.occupancy.keys().copied());
            e.composed = Some((e.t_global_submap, c));
        }
        stats.dirty_cloud_voxels = dirty_cloud.len();
        stats.dirty_occupancy_voxels = dirty_occupancy.len();
        self.resum(&dirty_cloud, &dirty_occupancy);

        self.update_occupancy_map(&dirty_occupancy);

        let mut cloud = self.cloud.clone();
        let mut occupancy = self.occupancy_map.clone();
        if let Some((submap, t_global_submap)) = current {
            let c = contribution(submap, t_global_submap, &config);
            for (k, acc) in &c.cloud {
                cloud.entry(*k).or_default().add(acc);
            }
            for (k, l) in &c.occupancy {
                occupancy.add_log_odds(*k, *l);
            }
        }
        let mut keys: Vec<_> = cloud.keys().copied().collect();
        keys.sort_unstable();
        let mut out = VoxelCloud::new(config.cloud_leaf_m);
        out.points.extend(keys.iter().filter_map(|k| cloud.get(k).map(|acc| acc.point(k, config.cloud_leaf_m))));
        stats.elapsed = started.elapsed();
        Composition { cloud: out, occupancy, stats }
    }

    /// Brings `occupancy_map` in line with `occupancy` after the `dirty` voxels were re-summed. The
    /// map cannot drop a leaf, so a voxel that lost all its contributions means a rebuild.
    fn update_occupancy_map(&mut self, dirty: &HashSet<VoxelKey>) {
        if dirty.iter().all(|k| self.occupancy.contains_key(k)) {
            for k in dirty {
                if let Some(l) = self.occupancy.get(k) {
                    self.occupancy_map.set_log_odds(*k, *l);
                }
            }
        } else {
            let mut map = OccupancyMap::new(self.config.occupancy_resolution_m, self.config.occupancy_params);
            for (k, l) in &self.occupancy {
                map.set_log_odds(*k, *l);
            }
            self.occupancy_map = map;
        }
    }

    /// Recomputes the given composed voxels from all contributions, in composition order: per
    /// dirty voxel over the contributions whose box holds it when few voxels are dirty (a moved
    /// submap), else by one sweep over all contributions (first compose, big loop closure).
    fn resum(&mut self, dirty_cloud: &HashSet<[i32; 3]>, dirty_occupancy: &HashSet<VoxelKey>) {
        let (lo, hi) = (self.config.occupancy_params.min_log_odds, self.config.occupancy_params.max_log_odds);
        let contributions: Vec<&Contribution> =
            self.entries.values().filter_map(|e| e.composed.as_ref()).map(|c| &c.1).collect();
        let total_cloud: usize = contributions.iter().map(|c| c.cloud.len()).sum();
        let total_occupancy: usize = contributions.iter().map(|c| c.occupancy.len()).sum();
        for k in dirty_cloud {
            self.cloud.remove(k);
        }
        for k in dirty_occupancy {
            self.occupancy.remove(k);
        }
        if dirty_cloud.len() * contributions.len() > total_cloud {
            for c in &contributions {
                for (k, a) in &c.cloud {
                    if dirty_cloud.contains(k) {
                        self.cloud.entry(*k).or_default().add(a);
                    }
                }
            }
        } else {
            for k in dirty_cloud {
                for c in &contributions {
                    if c.cloud_box.is_some_and(|b| b.contains(k))
                        && let Some(a) = c.cloud.get(k)
                    {
                        self.cloud.entry(*k).or_default().add(a);
                    }
                }
            }
        }
        let fold = |acc: &mut f32, v: f32| *acc = (*acc + v).clamp(lo, hi);
        if dirty_occupancy.len() * contributions.len() > total_occupancy {
            for c in &contributions {
                for (k, v) in &c.occupancy {
                    if dirty_occupancy.contains(k) {
                        fold(self.occupancy.entry(*k).or_insert(0.0), *v);
                    }
                }
            }
        } else {
            for k in dirty_occupancy {
                for c in &contributions {
                    if c.occupancy_box.is_some_and(|b| b.contains(k))
                        && let Some(v) = c.occupancy.get(k)
                    {
                        fold(self.occupancy.entry(*k).or_insert(0.0), *v);
                    }
                }
            }
        }
    }
}

/// Upper bound of how far any point within `radius_m` of the origin moves between two poses.
fn pose_displacement_m(a: &Isometry3<f64>, b: &Isometry3<f64>, radius_m: f64) -> f64 {
    let d = a.inverse() * b;
    d.translation.vector.norm() + d.rotation.angle() * radius_m
}

fn submap_radius_m(submap: &Submap) -> f64 {
    let cloud_r = submap.cloud.points.iter().map(|p| p.position_m.coords.cast::<f64>().norm()).fold(0.0, f64::max);
    let occ_r = submap
        .occupancy
        .iter()
        .map(|(k, _)| {
            let c = submap.occupancy.centre_of(&k);
            (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
        })
        .fold(0.0, f64::max);
    cloud_r.max(occ_r) + submap.occupancy.resolution_m
}

/// Resamples one submap into the global grids.
fn contribution(submap: &Submap, t_global_submap: &Isometry3<f64>, config: &GlobalMapConfig) -> Contribution {
    let leaf = config.cloud_leaf_m;
    let mut cloud: HashMap<[i32; 3], CloudAcc> =
        HashMap::with_capacity_and_hasher(submap.cloud.len(), Default::default());
    for p in &submap.cloud.points {
        let g = t_global_submap * p.position_m.cast::<f64>();
        let k = [(g.x / leaf).floor() as i32, (g.y / leaf).floor() as i32, (g.z / leaf).floor() as i32];
        let acc = cloud.entry(k).or_default();
        acc.add(&CloudAcc {
            sum_m: [g.x, g.y, g.z],
            sum_intensity: u64::from(p.intensity),
            count: 1,
            obstacle: p.obstacle,
        });
    }
    let occupancy = resample_occupancy(&submap.occupancy, t_global_submap, config.occupancy_resolution_m);
    Contribution { cloud_box: KeyBox::of(cloud.keys()), cloud, occupancy_box: KeyBox::of(occupancy.keys()), occupancy }
}

/// Jessup-style resampling (see the module docs) of `source` into a grid of `resolution_m`
/// aligned with the global frame.
fn resample_occupancy(
    source: &OccupancyMap,
    t_global_submap: &Isometry3<f64>,
    resolution_m: f64,
) -> HashMap<VoxelKey, f32> {
    let r_src = source.resolution_m;
    let t_submap_global = t_global_submap.inverse();
    let mut out: HashMap<VoxelKey, f32> = HashMap::with_capacity_and_hasher(source.len(), Default::default());
    let global_centre = |k: &VoxelKey| -> Point3<f64> {
        Point3::new(
            (f64::from(k[0]) + 0.5) * resolution_m,
            (f64::from(k[1]) + 0.5) * resolution_m,
            (f64::from(k[2]) + 0.5) * resolution_m,
        )
    };
    // The global voxel centres inside a source voxel lie within its rotated cube, whose
    // half-extent along global axis a is r/2 · Σ_j |R_aj|: at most two global indices per axis
    // (one vertically for a yaw-only rotation).
    let rotation = t_global_submap.rotation.to_rotation_matrix();
    let half_extent: [f64; 3] =
        std::array::from_fn(|a| 0.5 * r_src * (0..3).map(|j| rotation[(a, j)].abs()).sum::<f64>() * (1.0 + 1e-9));
    let bricks = Bricks::of(source);
    let mut last_brick = None;
    for (src_key, _) in bricks.leaves() {
        let c = source.centre_of(&src_key);
        let centre_global = t_global_submap * Point3::new(c[0], c[1], c[2]);
        let range = |a: usize| {
            let lo = ((centre_global[a] - half_extent[a]) / resolution_m - 0.5).ceil() as i32;
            let hi = ((centre_global[a] + half_extent[a]) / resolution_m - 0.5).floor() as i32;
            lo..=hi
        };
        for kz in range(2) {
            for ky in range(1) {
                for kx in range(0) {
                    let k = [kx, ky, kz];
                    let p_submap = t_submap_global * global_centre(&k);
                    if source.key_of(p_submap.x, p_submap.y, p_submap.z) != src_key {
                        continue;
                    }
                    if let Some(l) = trilinear_known(&bricks, r_src, &p_submap, &mut last_brick) {
                        out.insert(k, l);
                    }
                }
            }
        }
    }
    out
}

/// Edge of a [`Bricks`] brick in leaves (a power of two).
const BRICK_BITS: u32 = 3;
const BRICK_EDGE: i32 = 1 << BRICK_BITS;
const BRICK_CELLS: usize = (BRICK_EDGE * BRICK_EDGE * BRICK_EDGE) as usize;

/// A copy of an occupancy grid's log-odds in dense 8×8×8 bricks (NaN = unknown). Resampling
/// looks up 8 neighbours per output voxel; in one hash map of ~0.5 M leaves each lookup is a
/// cache miss, in bricks they mostly fall into the brick just used. The values are the same,
/// so the resampled grid is too.
struct Bricks {
    index: HashMap<VoxelKey, usize>,
    cells: Vec<[f32; BRICK_CELLS]>,
    keys: Vec<VoxelKey>,
}

impl Bricks {
    fn split(k: &VoxelKey) -> (VoxelKey, usize) {
        let brick = [k[0] >> BRICK_BITS, k[1] >> BRICK_BITS, k[2] >> BRICK_BITS];
        let m = BRICK_EDGE - 1;
        let cell = ((k[2] & m) * BRICK_EDGE + (k[1] & m)) * BRICK_EDGE + (k[0] & m);
        (brick, cell as usize)
    }

    fn of(source: &OccupancyMap) -> Bricks {
        let mut b = Bricks { index: HashMap::default(), cells: Vec::new(), keys: Vec::new() };
        for (k, l) in source.iter() {
            let (brick, cell) = Bricks::split(&k);
            let i = *b.index.entry(brick).or_insert_with(|| {
                b.cells.push([f32::NAN; BRICK_CELLS]);
                b.keys.push(brick);
                b.cells.len() - 1
            });
            b.cells[i][cell] = l;
        }
        b
    }

    fn get(&self, k: &VoxelKey, last: &mut Option<(VoxelKey, usize)>) -> Option<f32> {
        let (brick, cell) = Bricks::split(k);
        let i = match *last {
            Some((b, i)) if b == brick => i,
            _ => {
                let i = *self.index.get(&brick)?;
                *last = Some((brick, i));
                i
            }
        };
        let l = self.cells[i][cell];
        (!l.is_nan()).then_some(l)
    }

    /// Known leaves, brick by brick (so neighbouring lookups stay in cache).
    fn leaves(&self) -> impl Iterator<Item = (VoxelKey, f32)> + '_ {
        self.keys.iter().zip(&self.cells).flat_map(|(brick, cells)| {
            cells.iter().enumerate().filter(|(_, l)| !l.is_nan()).map(move |(cell, l)| {
                let m = BRICK_EDGE as usize - 1;
                let (x, y, z) = (cell & m, (cell >> BRICK_BITS) & m, cell >> (2 * BRICK_BITS));
                let key = [
                    (brick[0] << BRICK_BITS) + x as i32,
                    (brick[1] << BRICK_BITS) + y as i32,
                    (brick[2] << BRICK_BITS) + z as i32,
                ];
                (key, *l)
            })
        })
    }
}

/// Trilinear interpolation of the log-odds at `p` over the known voxel centres around it.
fn trilinear_known(source: &Bricks, r: f64, p: &Point3<f64>, last: &mut Option<(VoxelKey, usize)>) -> Option<f32> {
    let u = [p.x / r - 0.5, p.y / r - 0.5, p.z / r - 0.5];
    let i0 = [u[0].floor(), u[1].floor(), u[2].floor()];
    let f = [u[0] - i0[0], u[1] - i0[1], u[2] - i0[2]];
    let (mut sum, mut weight) = (0.0f64, 0.0f64);
    for corner in 0..8u8 {
        let mut w = 1.0;
        let mut k = [0i32; 3];
        for a in 0..3 {
            let upper = (corner >> a) & 1 == 1;
            k[a] = i0[a] as i32 + i32::from(upper);
            w *= if upper { f[a] } else { 1.0 - f[a] };
        }
        if w > 0.0
            && let Some(l) = source.get(&k, last)
        {
            sum += w * f64::from(l);
            weight += w;
        }
    }
    (weight > 0.0).then(|| (sum / weight) as f32)
}
