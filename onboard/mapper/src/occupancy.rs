//! The 10 cm probabilistic occupancy octree (thesis §5.1.2 b; OctoMap semantics).
//!
//! Leaves hold log-odds `L = ln(p / (1 − p))` (prior p = 0.5, L = 0), updated additively with
//! +0.85 for a hit and −0.4 for a miss and clamped to [−2, 3.5] (eqs. 5.7–5.9). In memory the
//! leaf level is a hash of 8×8×8-leaf dense bricks (O(1) updates for ray casting, neighbours in
//! one brick, whole bricks summed and copied by the global composition); the octree structure is
//! materialized where it matters: pruning of stable (clamped) children, the exchange encoding and
//! the OctoMap `.bt` export.
//!
//! One depth image is inserted as a scan ([`ScanBuffer`]): each ray is traversed with a 3D DDA
//! (Amanatides & Woo 1987) and its voxels are collected in sets first, so that a voxel gets at
//! most one update per scan and an occupied endpoint wins over free space crossing it (trap 16;
//! without it, grazing rays punch holes into the surface they just observed).

use std::collections::{HashMap, HashSet};

use crate::cloud::VoxelBuildHasher;

/// Integer voxel coordinates: voxel `k` spans `[k·r, (k+1)·r)` on each axis, in the map's frame.
pub type VoxelKey = [i32; 3];

/// Leaf size of the submap octrees (thesis: 10 cm).
pub const OCTREE_RESOLUTION_M: f64 = 0.1;

/// Log-odds of the inverse sensor model and the clamping bounds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OccupancyParams {
    /// Added to an endpoint voxel (thesis: 0.85, p = 0.7).
    pub hit_log_odds: f32,
    /// Added to a voxel a ray passes through (thesis: −0.4, p = 0.4).
    pub miss_log_odds: f32,
    /// Clamping bounds (thesis: −2 and 3.5, p = 0.12 and 0.97).
    pub min_log_odds: f32,
    pub max_log_odds: f32,
    /// A voxel is occupied above this log-odds (OctoMap's default: 0, p = 0.5).
    pub occupied_log_odds: f32,
}

impl Default for OccupancyParams {
    fn default() -> Self {
        OccupancyParams {
            hit_log_odds: 0.85,
            miss_log_odds: -0.4,
            min_log_odds: -2.0,
            max_log_odds: 3.5,
            occupied_log_odds: 0.0,
        }
    }
}

/// Occupancy state of a voxel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Occupancy {
    Unknown,
    Free,
    Occupied,
}

/// Edge of a brick in leaves (a power of two): leaf `k` lies in brick `k >> BRICK_BITS` per axis.
pub(crate) const BRICK_BITS: u32 = 3;
pub(crate) const BRICK_EDGE: i32 = 1 << BRICK_BITS;
pub(crate) const BRICK_CELLS: usize = (BRICK_EDGE * BRICK_EDGE * BRICK_EDGE) as usize;

/// The brick holding leaf `key` and the leaf's cell in it (x fastest).
#[inline]
pub(crate) fn brick_of(key: &VoxelKey) -> (VoxelKey, usize) {
    let brick = [key[0] >> BRICK_BITS, key[1] >> BRICK_BITS, key[2] >> BRICK_BITS];
    let m = BRICK_EDGE - 1;
    let cell = ((key[2] & m) << (2 * BRICK_BITS)) | ((key[1] & m) << BRICK_BITS) | (key[0] & m);
    (brick, cell as usize)
}

/// The leaf at `cell` of `brick` (inverse of [`brick_of`]).
#[inline]
pub(crate) fn leaf_of(brick: &VoxelKey, cell: usize) -> VoxelKey {
    let m = BRICK_EDGE as usize - 1;
    let (x, y, z) = (cell & m, (cell >> BRICK_BITS) & m, cell >> (2 * BRICK_BITS));
    [(brick[0] << BRICK_BITS) + x as i32, (brick[1] << BRICK_BITS) + y as i32, (brick[2] << BRICK_BITS) + z as i32]
}

/// 8×8×8 leaves, dense: a known bit and a log-odds value per cell (the value of an unknown cell
/// is meaningless).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Brick {
    pub(crate) known: [u64; BRICK_CELLS / 64],
    pub(crate) log_odds: [f32; BRICK_CELLS],
}

impl Brick {
    pub(crate) const EMPTY: Brick = Brick { known: [0; BRICK_CELLS / 64], log_odds: [0.0; BRICK_CELLS] };

    #[inline]
    pub(crate) fn is_known(&self, cell: usize) -> bool {
        self.known[cell / 64] >> (cell % 64) & 1 == 1
    }

    #[inline]
    pub(crate) fn get(&self, cell: usize) -> Option<f32> {
        self.is_known(cell).then(|| self.log_odds[cell])
    }

    #[inline]
    pub(crate) fn set(&mut self, cell: usize, log_odds: f32) {
        self.known[cell / 64] |= 1 << (cell % 64);
        self.log_odds[cell] = log_odds;
    }

    pub(crate) fn count(&self) -> usize {
        self.known.iter().map(|w| w.count_ones() as usize).sum()
    }

    /// Known cells with their values, in cell order.
    pub(crate) fn cells(&self) -> impl Iterator<Item = (usize, f32)> + '_ {
        self.known.iter().enumerate().flat_map(move |(w, &bits)| {
            let mut bits = bits;
            std::iter::from_fn(move || {
                (bits != 0).then(|| {
                    let cell = w * 64 + bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    (cell, self.log_odds[cell])
                })
            })
        })
    }
}

/// A sparse grid of leaf values stored in dense 8×8×8 bricks found through a hash of brick keys.
/// Neighbouring leaves share a brick, so ray casting and resampling mostly touch memory they
/// just used, and whole bricks can be summed or copied without hashing every leaf (the
/// composition of a team's map has millions of leaves). Bricks are never removed: one whose
/// cells all became unknown stays allocated and empty.
#[derive(Debug, Clone, Default)]
pub(crate) struct BrickGrid {
    index: HashMap<VoxelKey, u32, VoxelBuildHasher>,
    keys: Vec<VoxelKey>,
    bricks: Vec<Brick>,
    /// Known cells over all bricks.
    len: usize,
}

impl BrickGrid {
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// Slot of a brick, if allocated.
    #[inline]
    pub(crate) fn slot(&self, brick: &VoxelKey) -> Option<usize> {
        self.index.get(brick).map(|&i| i as usize)
    }

    /// Slot of a brick, allocated empty if new.
    #[inline]
    pub(crate) fn slot_or_insert(&mut self, brick: VoxelKey) -> usize {
        let next = self.bricks.len();
        let slot = *self.index.entry(brick).or_insert(next as u32) as usize;
        if slot == next {
            self.keys.push(brick);
            self.bricks.push(Brick::EMPTY);
        }
        slot
    }

    #[inline]
    pub(crate) fn brick(&self, slot: usize) -> &Brick {
        &self.bricks[slot]
    }

    pub(crate) fn brick_count(&self) -> usize {
        self.bricks.len()
    }

    /// Brick keys and bricks in slot order (allocation order).
    pub(crate) fn bricks(&self) -> impl Iterator<Item = (&VoxelKey, &Brick)> + '_ {
        self.keys.iter().zip(&self.bricks)
    }

    /// Changes the brick at `slot` through `f`, keeping the leaf count.
    #[inline]
    pub(crate) fn update(&mut self, slot: usize, f: impl FnOnce(&mut Brick)) {
        let b = &mut self.bricks[slot];
        let before = b.count();
        f(b);
        self.len = self.len + b.count() - before;
    }

    #[inline]
    pub(crate) fn get(&self, key: &VoxelKey) -> Option<f32> {
        let (brick, cell) = brick_of(key);
        self.bricks[self.slot(&brick)?].get(cell)
    }

    /// Sets a leaf (no clamping).
    #[inline]
    pub(crate) fn set(&mut self, key: VoxelKey, log_odds: f32) {
        let (brick, cell) = brick_of(&key);
        let slot = self.slot_or_insert(brick);
        let b = &mut self.bricks[slot];
        self.len += usize::from(!b.is_known(cell));
        b.set(cell, log_odds);
    }

    /// Sets cell `cell` of the brick at `slot` (no clamping).
    #[inline]
    pub(crate) fn set_at(&mut self, slot: usize, cell: usize, log_odds: f32) {
        let b = &mut self.bricks[slot];
        self.len += usize::from(!b.is_known(cell));
        b.set(cell, log_odds);
    }

    /// Known leaves, brick by brick.
    pub(crate) fn iter(&self) -> impl Iterator<Item = (VoxelKey, f32)> + '_ {
        self.bricks().flat_map(|(brick, b)| b.cells().map(move |(cell, l)| (leaf_of(brick, cell), l)))
    }
}

/// Leaf log-odds keyed by voxel.
#[derive(Debug, Clone, Default)]
pub struct OccupancyMap {
    pub resolution_m: f64,
    pub params: OccupancyParams,
    cells: BrickGrid,
}

/// Two maps are equal when their parameters and leaves are, whatever order the leaves were
/// inserted in (which decides the brick layout).
impl PartialEq for OccupancyMap {
    fn eq(&self, other: &OccupancyMap) -> bool {
        self.resolution_m == other.resolution_m
            && self.params == other.params
            && self.len() == other.len()
            && self.iter().all(|(k, l)| other.log_odds(&k) == Some(l))
    }
}

impl OccupancyMap {
    pub fn new(resolution_m: f64, params: OccupancyParams) -> OccupancyMap {
        OccupancyMap { resolution_m, params, cells: BrickGrid::default() }
    }

    /// A map over already clamped leaves.
    pub(crate) fn from_grid(resolution_m: f64, params: OccupancyParams, cells: BrickGrid) -> OccupancyMap {
        OccupancyMap { resolution_m, params, cells }
    }

    pub(crate) fn grid(&self) -> &BrickGrid {
        &self.cells
    }

    /// Voxel containing the point `(x, y, z)` (metres, map frame).
    pub fn key_of(&self, x: f64, y: f64, z: f64) -> VoxelKey {
        let r = self.resolution_m;
        [(x / r).floor() as i32, (y / r).floor() as i32, (z / r).floor() as i32]
    }

    /// Centre of a voxel (metres, map frame).
    pub fn centre_of(&self, key: &VoxelKey) -> [f64; 3] {
        let r = self.resolution_m;
        [(f64::from(key[0]) + 0.5) * r, (f64::from(key[1]) + 0.5) * r, (f64::from(key[2]) + 0.5) * r]
    }

    pub fn log_odds(&self, key: &VoxelKey) -> Option<f32> {
        self.cells.get(key)
    }

    pub fn occupancy(&self, key: &VoxelKey) -> Occupancy {
        match self.cells.get(key) {
            None => Occupancy::Unknown,
            Some(l) if l > self.params.occupied_log_odds => Occupancy::Occupied,
            Some(_) => Occupancy::Free,
        }
    }

    /// Sets a leaf's log-odds (clamped); used by decoders and merges.
    pub fn set_log_odds(&mut self, key: VoxelKey, log_odds: f32) {
        let l = log_odds.clamp(self.params.min_log_odds, self.params.max_log_odds);
        self.cells.set(key, l);
    }

    /// Adds `delta` to a leaf (unknown counts as 0) and clamps (eq. 5.9).
    pub fn add_log_odds(&mut self, key: VoxelKey, delta: f32) {
        let (lo, hi) = (self.params.min_log_odds, self.params.max_log_odds);
        let (brick, cell) = brick_of(&key);
        let slot = self.cells.slot_or_insert(brick);
        let l = self.cells.brick(slot).get(cell).unwrap_or(0.0);
        self.cells.set_at(slot, cell, (l + delta).clamp(lo, hi));
    }

    /// Known leaves in unspecified order.
    pub fn iter(&self) -> impl Iterator<Item = (VoxelKey, f32)> + '_ {
        self.cells.iter()
    }

    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.len() == 0
    }

    /// Allocated 8×8×8-leaf bricks (memory: about 2.1 kB each).
    pub fn brick_count(&self) -> usize {
        self.cells.brick_count()
    }

    pub fn occupied_count(&self) -> usize {
        self.iter().filter(|&(_, l)| l > self.params.occupied_log_odds).count()
    }

    /// Whether `log_odds` sits at a clamping bound: such a leaf stays put under further updates
    /// of the same sign, which is what makes pruning it lossless in OctoMap's sense.
    pub fn stable_value(&self, log_odds: f32) -> bool {
        log_odds == self.params.min_log_odds || log_odds == self.params.max_log_odds
    }

    /// The common stable value of all `8^level` leaves under the node `key` at `level` (level 0 is
    /// a leaf, level 1 the parent of 8 leaves: leaf `k` lies under node `k >> level` on each axis),
    /// or `None` if any leaf is unknown, not stable or different. Such a node can be pruned.
    pub fn stable_group_value(&self, level: u32, key: &VoxelKey) -> Option<f32> {
        if level > 20 {
            return None;
        }
        let side = 1i64 << level;
        let base = [i64::from(key[0]) << level, i64::from(key[1]) << level, i64::from(key[2]) << level];
        let mut value = None;
        for dx in 0..side {
            for dy in 0..side {
                for dz in 0..side {
                    let leaf = [
                        i32::try_from(base[0] + dx).ok()?,
                        i32::try_from(base[1] + dy).ok()?,
                        i32::try_from(base[2] + dz).ok()?,
                    ];
                    let l = self.cells.get(&leaf)?;
                    if !self.stable_value(l) || value.is_some_and(|v| v != l) {
                        return None;
                    }
                    value = Some(l);
                }
            }
        }
        value
    }

    /// The level-1 nodes (parents of 8 leaves) whose children are all known, stable and equal,
    /// with that value, sorted by key. Higher levels follow from [`OccupancyMap::stable_group_value`].
    pub fn prunable_parents(&self) -> Vec<(VoxelKey, f32)> {
        let mut parents: Vec<VoxelKey> = self
            .cells
            .iter()
            .filter(|(_, l)| self.stable_value(*l))
            .map(|(k, _)| [k[0] >> 1, k[1] >> 1, k[2] >> 1])
            .collect();
        parents.sort_unstable();
        parents.dedup();
        parents.into_iter().filter_map(|p| self.stable_group_value(1, &p).map(|l| (p, l))).collect()
    }

    /// Applies one scan: a miss to every free voxel that is not also a hit, a hit to every hit
    /// voxel, each once (eqs. 5.7–5.9). Returns (free updates, occupied updates).
    pub fn insert_scan(&mut self, scan: &ScanBuffer) -> (usize, usize) {
        let (miss, hit) = (self.params.miss_log_odds, self.params.hit_log_odds);
        let mut free = 0;
        for key in &scan.free {
            if !scan.occupied.contains(key) {
                self.add_log_odds(*key, miss);
                free += 1;
            }
        }
        for key in &scan.occupied {
            self.add_log_odds(*key, hit);
        }
        (free, scan.occupied.len())
    }
}

/// The voxels one scan touches, before they are applied: sets, so each voxel is updated once.
/// Reused across scans (clearing keeps the capacity).
#[derive(Debug, Clone, Default)]
pub struct ScanBuffer {
    resolution_m: f64,
    free: HashSet<VoxelKey, VoxelBuildHasher>,
    occupied: HashSet<VoxelKey, VoxelBuildHasher>,
}

impl ScanBuffer {
    pub fn new(resolution_m: f64) -> ScanBuffer {
        ScanBuffer { resolution_m, free: HashSet::default(), occupied: HashSet::default() }
    }

    pub fn resolution_m(&self) -> f64 {
        self.resolution_m
    }

    /// Starts a new scan (for a map of `resolution_m`), keeping the memory.
    pub fn clear(&mut self, resolution_m: f64) {
        self.resolution_m = resolution_m;
        self.free.clear();
        self.occupied.clear();
    }

    fn key_of(&self, p: &[f64; 3]) -> VoxelKey {
        let r = self.resolution_m;
        [(p[0] / r).floor() as i32, (p[1] / r).floor() as i32, (p[2] / r).floor() as i32]
    }

    /// Marks the voxel containing `p` occupied; returns whether it is new in this scan.
    pub fn mark_hit(&mut self, p_m: &[f64; 3]) -> bool {
        let key = self.key_of(p_m);
        self.occupied.insert(key)
    }

    /// Marks a voxel occupied by key; returns whether it is new in this scan.
    pub fn mark_hit_key(&mut self, key: VoxelKey) -> bool {
        self.occupied.insert(key)
    }

    /// The occupied voxels collected so far (unspecified order).
    pub fn hits(&self) -> impl Iterator<Item = &VoxelKey> + '_ {
        self.occupied.iter()
    }

    pub fn hit_count(&self) -> usize {
        self.occupied.len()
    }

    pub fn free_count(&self) -> usize {
        self.free.len()
    }

    pub fn is_free(&self, key: &VoxelKey) -> bool {
        self.free.contains(key)
    }

    pub fn is_hit(&self, key: &VoxelKey) -> bool {
        self.occupied.contains(key)
    }

    /// Casts a ray from `origin_m` to the centre of every hit voxel collected so far, marking the
    /// voxels before the endpoint free. Returns the number of voxels visited.
    pub fn cast_free_to_hits(&mut self, origin_m: &[f64; 3], centre: impl Fn(&VoxelKey) -> [f64; 3]) -> usize {
        let mut visited = 0;
        let (free, occupied) = (&mut self.free, &self.occupied);
        for end in occupied {
            traverse(self.resolution_m, origin_m, &centre(end), |key, is_end| {
                if !is_end {
                    free.insert(key);
                    visited += 1;
                }
            });
        }
        visited
    }

    /// Marks free every voxel the segment `origin → end` passes through, excluding the voxel of
    /// `end` when `include_end` is false (a hit ray: the endpoint gets the hit instead) and
    /// including it when true (a ray cut at the range limit: free all the way). Returns the
    /// number of voxels visited.
    pub fn cast_free(&mut self, origin_m: &[f64; 3], end_m: &[f64; 3], include_end: bool) -> usize {
        let mut visited = 0;
        let free = &mut self.free;
        traverse(self.resolution_m, origin_m, end_m, |key, is_end| {
            if !is_end || include_end {
                free.insert(key);
                visited += 1;
            }
        });
        visited
    }
}

/// 3D DDA (Amanatides & Woo): calls `visit(key, is_end)` for every voxel the segment
/// `a → b` passes through, in order from `a`'s voxel to `b`'s. Non-finite input visits nothing.
pub fn traverse(resolution_m: f64, a: &[f64; 3], b: &[f64; 3], mut visit: impl FnMut(VoxelKey, bool)) {
    if !(a.iter().chain(b.iter()).all(|v| v.is_finite()) && resolution_m > 0.0) {
        return;
    }
    let r = resolution_m;
    let key = |p: f64| (p / r).floor() as i32;
    let mut current = [key(a[0]), key(a[1]), key(a[2])];
    let end = [key(b[0]), key(b[1]), key(b[2])];
    let mut step = [0i32; 3];
    let mut t_max = [f64::INFINITY; 3];
    let mut t_delta = [f64::INFINITY; 3];
    for i in 0..3 {
        let d = b[i] - a[i];
        if d > 0.0 {
            step[i] = 1;
            t_max[i] = ((f64::from(current[i]) + 1.0) * r - a[i]) / d;
            t_delta[i] = r / d;
        } else if d < 0.0 {
            step[i] = -1;
            t_max[i] = (f64::from(current[i]) * r - a[i]) / d;
            t_delta[i] = -r / d;
        }
    }
    // Each step moves one voxel along one axis towards `end`: the Manhattan distance bounds the
    // walk even when rounding makes the t's disagree with the keys near a corner.
    let mut remaining: i64 = (0..3).map(|i| (i64::from(end[i]) - i64::from(current[i])).abs()).sum();
    while remaining > 0 {
        visit(current, false);
        let axis = if t_max[0] < t_max[1] {
            if t_max[0] < t_max[2] { 0 } else { 2 }
        } else if t_max[1] < t_max[2] {
            1
        } else {
            2
        };
        // Never step past the end voxel on an axis (rounding at faces).
        let axis = if current[axis] == end[axis] {
            match (0..3).find(|&i| current[i] != end[i]) {
                Some(i) => i,
                None => break,
            }
        } else {
            axis
        };
        current[axis] += step[axis];
        t_max[axis] += t_delta[axis];
        remaining -= 1;
    }
    visit(current, true);
}
