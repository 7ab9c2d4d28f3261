//! The 5 cm voxel point cloud (thesis §5.1.2 a).
//!
//! One point per occupied voxel of a grid aligned to multiples of the leaf size (as PCL's
//! VoxelGrid): the centroid of the voxel's input points (not the voxel centre), their mean
//! intensity, and an obstacle bit that is the OR over them.
//!
//! Filtering twice (per depth image, then the submap after appending, trap 14) is done with a
//! [`VoxelAccumulator`] that keeps each voxel's point count: merging two centroids weights them by
//! their counts, so the twice-filtered cloud equals the cloud filtered once from all raw points
//! (up to float rounding). A plain [`VoxelCloud`] carries no counts; re-filtering one weights each
//! of its points as a single input point (PCL's behaviour).

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use nalgebra::Point3;

/// Leaf size of the submap clouds (thesis: 5 cm).
pub const CLOUD_LEAF_M: f64 = 0.05;

/// One voxel's point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MapPoint {
    /// Centroid of the voxel's input points, in the cloud's frame.
    pub position_m: Point3<f32>,
    /// Mean grey value of the input points (the rovers' cameras are greyscale).
    pub intensity: u8,
    /// True when at least one input point was classified as an obstacle.
    pub obstacle: bool,
}

/// A voxel-filtered cloud: at most one point per `leaf_m` voxel.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct VoxelCloud {
    pub leaf_m: f64,
    pub points: Vec<MapPoint>,
}

impl VoxelCloud {
    pub fn new(leaf_m: f64) -> VoxelCloud {
        VoxelCloud { leaf_m, points: Vec::new() }
    }

    /// Index of the voxel containing `p` (grid aligned to multiples of the leaf size).
    pub fn voxel_of(&self, p: &Point3<f32>) -> [i32; 3] {
        voxel_index(self.leaf_m, p)
    }

    pub fn len(&self) -> usize {
        self.points.len()
    }

    pub fn is_empty(&self) -> bool {
        self.points.is_empty()
    }

    pub fn obstacle_count(&self) -> usize {
        self.points.iter().filter(|p| p.obstacle).count()
    }

    /// Voxel-filters `points` (each one input point) into a new cloud; a convenience for tests
    /// and one-off use. Hot paths keep a [`VoxelAccumulator`] instead.
    pub fn filtered(leaf_m: f64, points: &[MapPoint]) -> VoxelCloud {
        let mut acc = VoxelAccumulator::new(leaf_m);
        for p in points {
            acc.add(&p.position_m, p.intensity, p.obstacle);
        }
        let mut out = VoxelCloud::new(leaf_m);
        acc.write_into(&mut out);
        out
    }
}

fn voxel_index(leaf_m: f64, p: &Point3<f32>) -> [i32; 3] {
    [
        (f64::from(p.x) / leaf_m).floor() as i32,
        (f64::from(p.y) / leaf_m).floor() as i32,
        (f64::from(p.z) / leaf_m).floor() as i32,
    ]
}

/// A multiplicative hash for integer voxel keys. SipHash (std's default) costs about as much as
/// the rest of a voxel update; keys here are not attacker-controlled, so a fast hash is safe.
#[derive(Debug, Default, Clone, Copy)]
pub struct VoxelHasher(u64);

impl Hasher for VoxelHasher {
    fn finish(&self) -> u64 {
        // Fold the high bits down: hashbrown takes its bucket index from the low bits.
        self.0 ^ (self.0 >> 29)
    }

    /// Four bytes per round: `[i32; 3]` keys arrive here as one 12-byte slice, and byte by byte
    /// that was 12 dependent multiplies per key.
    fn write(&mut self, bytes: &[u8]) {
        let mut words = bytes.chunks_exact(4);
        for w in &mut words {
            if let Ok(w) = <[u8; 4]>::try_from(w) {
                self.write_u64(u64::from(u32::from_le_bytes(w)));
            }
        }
        for &b in words.remainder() {
            self.write_u64(u64::from(b));
        }
    }

    fn write_i32(&mut self, i: i32) {
        self.write_u64(u64::from(i as u32));
    }

    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x517c_c1b7_2722_0a95);
    }

    fn write_usize(&mut self, i: usize) {
        self.write_u64(i as u64);
    }
}

/// Build-hasher for maps keyed by voxel indices.
pub type VoxelBuildHasher = BuildHasherDefault<VoxelHasher>;

/// Running sums of one voxel.
#[derive(Debug, Clone, Copy, PartialEq)]
struct VoxelSums {
    key: [i32; 3],
    sum_m: [f64; 3],
    intensity_sum: u64,
    count: u64,
    obstacle: bool,
}

impl VoxelSums {
    fn point(&self) -> MapPoint {
        let n = self.count.max(1) as f64;
        MapPoint {
            position_m: Point3::new((self.sum_m[0] / n) as f32, (self.sum_m[1] / n) as f32, (self.sum_m[2] / n) as f32),
            intensity: (self.intensity_sum as f64 / n).round().min(255.0) as u8,
            obstacle: self.obstacle,
        }
    }
}

/// A reusable voxel-grid filter: sums of position and intensity, point count and obstacle OR per
/// voxel, in the order voxels were first touched (so output order is deterministic).
///
/// [`VoxelAccumulator::clear`] keeps the capacity: once warmed up, filtering a depth image of the
/// same size allocates nothing.
#[derive(Debug, Clone, Default)]
pub struct VoxelAccumulator {
    leaf_m: f64,
    index: HashMap<[i32; 3], u32, VoxelBuildHasher>,
    voxels: Vec<VoxelSums>,
}

impl VoxelAccumulator {
    pub fn new(leaf_m: f64) -> VoxelAccumulator {
        VoxelAccumulator { leaf_m, index: HashMap::default(), voxels: Vec::new() }
    }

    pub fn leaf_m(&self) -> f64 {
        self.leaf_m
    }

    /// Forgets all voxels, keeping the memory.
    pub fn clear(&mut self) {
        self.index.clear();
        self.voxels.clear();
    }

    /// Number of non-empty voxels.
    pub fn len(&self) -> usize {
        self.voxels.len()
    }

    pub fn is_empty(&self) -> bool {
        self.voxels.is_empty()
    }

    /// Adds one raw point.
    pub fn add(&mut self, position_m: &Point3<f32>, intensity: u8, obstacle: bool) {
        self.add_weighted(position_m, intensity, obstacle, 1);
    }

    /// Adds a centroid that stands for `count` input points (weight by count: trap 14). Returns
    /// the voxel's slot (insertion order), which stays valid until [`VoxelAccumulator::clear`].
    pub fn add_weighted(&mut self, position_m: &Point3<f32>, intensity: u8, obstacle: bool, count: u64) -> usize {
        let key = voxel_index(self.leaf_m, position_m);
        let n = count as f64;
        let slot = self.slot_of(key);
        let v = &mut self.voxels[slot];
        v.sum_m[0] += f64::from(position_m.x) * n;
        v.sum_m[1] += f64::from(position_m.y) * n;
        v.sum_m[2] += f64::from(position_m.z) * n;
        v.intensity_sum += u64::from(intensity) * count;
        v.count += count;
        v.obstacle |= obstacle;
        slot
    }

    fn slot_of(&mut self, key: [i32; 3]) -> usize {
        match self.index.get(&key) {
            Some(&slot) => slot as usize,
            None => {
                let slot = self.voxels.len();
                self.index.insert(key, slot as u32);
                self.voxels.push(VoxelSums { key, sum_m: [0.0; 3], intensity_sum: 0, count: 0, obstacle: false });
                slot
            }
        }
    }

    /// Adds every voxel of `other` with its count (merging two filtered clouds exactly).
    pub fn merge(&mut self, other: &VoxelAccumulator) {
        for v in &other.voxels {
            let _ = self.merge_sums(other.leaf_m, v);
        }
    }

    /// Merges the raw sums (not the rounded centroid), so the merge is exact. With equal leaves
    /// the source voxel's key is reused: a centroid rounded to f32 may sit on a voxel face.
    fn merge_sums(&mut self, other_leaf_m: f64, v: &VoxelSums) -> usize {
        let key = if other_leaf_m == self.leaf_m { v.key } else { voxel_index(self.leaf_m, &v.point().position_m) };
        let slot = self.slot_of(key);
        let d = &mut self.voxels[slot];
        for a in 0..3 {
            d.sum_m[a] += v.sum_m[a];
        }
        d.intensity_sum += v.intensity_sum;
        d.count += v.count;
        d.obstacle |= v.obstacle;
        slot
    }

    /// Merges `other` and writes the touched voxels' centroids into `cloud`, whose points must be
    /// this accumulator's output in slot order (as left by [`VoxelAccumulator::write_into`] or a
    /// previous call): only the touched points are rewritten, new voxels are appended. This is
    /// the per-submap second filter at the cost of the new frame only.
    pub fn merge_into_cloud(&mut self, other: &VoxelAccumulator, cloud: &mut VoxelCloud) {
        for v in &other.voxels {
            let dst = self.merge_sums(other.leaf_m, v);
            let p = self.voxels[dst].point();
            if dst < cloud.points.len() {
                cloud.points[dst] = p;
            } else {
                cloud.points.push(p);
            }
        }
    }

    /// Point count of the voxel at `slot`.
    pub fn count_at(&self, slot: usize) -> Option<u64> {
        self.voxels.get(slot).map(|v| v.count)
    }

    /// The centroid points, in slot order.
    pub fn points(&self) -> impl Iterator<Item = MapPoint> + '_ {
        self.voxels.iter().map(VoxelSums::point)
    }

    /// Replaces `cloud`'s points by this accumulator's centroids (capacity reused).
    pub fn write_into(&self, cloud: &mut VoxelCloud) {
        cloud.leaf_m = self.leaf_m;
        cloud.points.clear();
        cloud.points.extend(self.points());
    }

    /// Restarts from an existing filtered cloud whose counts are unknown: each point weighs one.
    pub fn reset_from(&mut self, cloud: &VoxelCloud) {
        self.leaf_m = cloud.leaf_m;
        self.clear();
        for p in &cloud.points {
            self.add(&p.position_m, p.intensity, p.obstacle);
        }
    }

    /// Whether `cloud` holds exactly this accumulator's voxels in slot order (the precondition
    /// of [`VoxelAccumulator::merge_into_cloud`]), checked by count and voxel of each point.
    pub fn is_aligned_with(&self, cloud: &VoxelCloud) -> bool {
        cloud.leaf_m == self.leaf_m
            && cloud.points.len() == self.voxels.len()
            && cloud.points.iter().zip(&self.voxels).all(|(p, v)| voxel_index(self.leaf_m, &p.position_m) == v.key)
    }
}
