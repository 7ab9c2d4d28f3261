//! The 10 cm probabilistic occupancy octree (thesis §5.1.2 b; OctoMap semantics).
//!
//! Leaves hold log-odds `L = ln(p / (1 − p))` (prior p = 0.5, L = 0), updated additively with
//! +0.85 for a hit and −0.4 for a miss and clamped to [−2, 3.5] (eqs. 5.7–5.9). In memory the
//! leaf level is a hash of voxel keys (O(1) updates for ray casting); the octree structure is
//! materialized where it matters: pruning of stable (clamped) children, the exchange encoding and
//! the OctoMap `.bt` export.

use std::collections::HashMap;

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

/// Leaf log-odds keyed by voxel.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OccupancyMap {
    pub resolution_m: f64,
    pub params: OccupancyParams,
    cells: HashMap<VoxelKey, f32>,
}

impl OccupancyMap {
    pub fn new(resolution_m: f64, params: OccupancyParams) -> OccupancyMap {
        OccupancyMap { resolution_m, params, cells: HashMap::new() }
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
        self.cells.get(key).copied()
    }

    pub fn occupancy(&self, key: &VoxelKey) -> Occupancy {
        match self.cells.get(key) {
            None => Occupancy::Unknown,
            Some(&l) if l > self.params.occupied_log_odds => Occupancy::Occupied,
            Some(_) => Occupancy::Free,
        }
    }

    /// Sets a leaf's log-odds (clamped); used by decoders and merges.
    pub fn set_log_odds(&mut self, key: VoxelKey, log_odds: f32) {
        let l = log_odds.clamp(self.params.min_log_odds, self.params.max_log_odds);
        self.cells.insert(key, l);
    }

    /// Adds `delta` to a leaf (unknown counts as 0) and clamps (eq. 5.9).
    pub fn add_log_odds(&mut self, key: VoxelKey, delta: f32) {
        let (lo, hi) = (self.params.min_log_odds, self.params.max_log_odds);
        let l = self.cells.entry(key).or_insert(0.0);
        *l = (*l + delta).clamp(lo, hi);
    }

    /// Known leaves in unspecified order.
    pub fn iter(&self) -> impl Iterator<Item = (VoxelKey, f32)> + '_ {
        self.cells.iter().map(|(k, l)| (*k, *l))
    }

    pub fn len(&self) -> usize {
        self.cells.len()
    }

    pub fn is_empty(&self) -> bool {
        self.cells.is_empty()
    }

    pub fn occupied_count(&self) -> usize {
        self.cells.values().filter(|&&l| l > self.params.occupied_log_odds).count()
    }
}
