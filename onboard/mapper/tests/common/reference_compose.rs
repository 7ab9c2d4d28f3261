//! The composition of `mapper::global` written the plain way, from its module docs: no caching,
//! no bricks, no threads; one hash map per grid, the 8 neighbours of an interpolation looked up
//! one by one, the sums taken in composition order. Slow and simple: the fast composition must
//! equal it bit for bit. `#[path]`-included by `tests/global.rs` and `benches/compose.rs`.
#![allow(dead_code, reason = "each includer uses its own part")]

use std::collections::HashMap;

use mapper::cloud::{MapPoint, VoxelCloud};
use mapper::global::GlobalMapConfig;
use mapper::occupancy::{OccupancyMap, VoxelKey};
use mapper::submap::Submap;
use nalgebra::{Isometry3, Point3};

/// Point sums of one cloud voxel.
#[derive(Clone, Copy, Default)]
struct Sums {
    sum_m: [f64; 3],
    intensity: u64,
    count: u32,
    obstacle: bool,
}

impl Sums {
    fn add(&mut self, o: &Sums) {
        for a in 0..3 {
            self.sum_m[a] += o.sum_m[a];
        }
        self.intensity += o.intensity;
        self.count += o.count;
        self.obstacle |= o.obstacle;
    }
}

/// The composed cloud (sorted by voxel) and occupancy leaves of `submaps`, which are given in
/// composition order ((robot, index) order, the current submap last).
pub fn reference_compose(
    submaps: &[(&Submap, Isometry3<f64>)],
    config: &GlobalMapConfig,
) -> (VoxelCloud, HashMap<VoxelKey, f32>) {
    let leaf = config.cloud_leaf_m;
    let mut cloud: HashMap<[i32; 3], Sums> = HashMap::new();
    let mut occupancy: HashMap<VoxelKey, f32> = HashMap::new();
    let (lo, hi) = (config.occupancy_params.min_log_odds, config.occupancy_params.max_log_odds);
    for (submap, t) in submaps {
        // Voxel-filter the transformed points of this submap alone, then add its sums.
        let mut own: HashMap<[i32; 3], Sums> = HashMap::new();
        for p in &submap.cloud.points {
            let g = t * p.position_m.cast::<f64>();
            let k = [(g.x / leaf).floor() as i32, (g.y / leaf).floor() as i32, (g.z / leaf).floor() as i32];
            own.entry(k).or_default().add(&Sums {
                sum_m: [g.x, g.y, g.z],
                intensity: u64::from(p.intensity),
                count: 1,
                obstacle: p.obstacle,
            });
        }
        for (k, s) in &own {
            cloud.entry(*k).or_default().add(s);
        }
        for (k, l) in resample(&submap.occupancy, t, config.occupancy_resolution_m) {
            let acc = occupancy.entry(k).or_insert(0.0);
            *acc = (*acc + l).clamp(lo, hi);
        }
    }
    let mut keys: Vec<_> = cloud.keys().copied().collect();
    keys.sort_unstable();
    let mut out = VoxelCloud::new(leaf);
    out.points = keys.iter().map(|k| point(&cloud[k], k, leaf)).collect();
    (out, occupancy)
}

/// The centroid, nudged back into its voxel after rounding to f32.
fn point(s: &Sums, key: &[i32; 3], leaf: f64) -> MapPoint {
    let n = f64::from(s.count.max(1));
    let coord = |a: usize| {
        let mut c = (s.sum_m[a] / n) as f32;
        for _ in 0..4 {
            let k = (f64::from(c) / leaf).floor() as i32;
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
        intensity: (s.intensity / u64::from(s.count.max(1))).min(255) as u8,
        obstacle: s.obstacle,
    }
}

/// Every global voxel whose centre lies in a known source voxel gets the trilinear
/// interpolation over the known source voxel centres around that centre.
fn resample(source: &OccupancyMap, t_global_submap: &Isometry3<f64>, resolution_m: f64) -> Vec<(VoxelKey, f32)> {
    let r = source.resolution_m;
    let t_submap_global = t_global_submap.inverse();
    let rotation = t_global_submap.rotation.to_rotation_matrix();
    // Candidates: the global centres within the rotated source cube's axis-aligned extent.
    let half_extent: [f64; 3] =
        std::array::from_fn(|a| 0.5 * r * (0..3).map(|j| rotation[(a, j)].abs()).sum::<f64>() * (1.0 + 1e-9));
    let mut out = Vec::new();
    for (src_key, _) in source.iter() {
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
                    let centre = Point3::new(
                        (f64::from(k[0]) + 0.5) * resolution_m,
                        (f64::from(k[1]) + 0.5) * resolution_m,
                        (f64::from(k[2]) + 0.5) * resolution_m,
                    );
                    let p = t_submap_global * centre;
                    if source.key_of(p.x, p.y, p.z) != src_key {
                        continue;
                    }
                    let u = [p.x / r - 0.5, p.y / r - 0.5, p.z / r - 0.5];
                    let i0 = [u[0].floor(), u[1].floor(), u[2].floor()];
                    let f = [u[0] - i0[0], u[1] - i0[1], u[2] - i0[2]];
                    let (mut sum, mut weight) = (0.0f64, 0.0f64);
                    for corner in 0..8u8 {
                        let mut w = 1.0;
                        let mut n = [0i32; 3];
                        for a in 0..3 {
                            let upper = (corner >> a) & 1 == 1;
                            n[a] = i0[a] as i32 + i32::from(upper);
                            w *= if upper { f[a] } else { 1.0 - f[a] };
                        }
                        if w > 0.0
                            && let Some(l) = source.log_odds(&n)
                        {
                            sum += w * f64::from(l);
                            weight += w;
                        }
                    }
                    if weight > 0.0 {
                        out.push((k, (sum / weight) as f32));
                    }
                }
            }
        }
    }
    out
}
