//! Global map composition on submaps of simulated Moon terrain: caching is exact, a moved submap
//! changes only its region, resampling keeps the surface where it is.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashMap;
use std::sync::Arc;

use mapper::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
use mapper::global::{Composition, GlobalMap, GlobalMapConfig};
use mapper::occupancy::{OCTREE_RESOLUTION_M, OccupancyMap, OccupancyParams};
use mapper::submap::Submap;
use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3};
use sim::terrain::{Terrain, TerrainConfig};

#[path = "common/reference_compose.rs"]
mod reference_compose;

fn terrain() -> Terrain {
    Terrain::generate(&TerrainConfig::moon().with_size(30.0), 7)
}

fn pose(x: f64, y: f64, yaw_deg: f64) -> Isometry3<f64> {
    let z = 0.0;
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians()),
    )
}

/// A submap as a perfect sensor would build it from the terrain within `radius_m` of the origin
/// of `t_world_submap`: surface samples voxel-filtered into the cloud, the surface voxel occupied
/// and the two above it free in the octree (all in the submap frame).
fn submap_of(terrain: &Terrain, index: u32, t_world_submap: &Isometry3<f64>, radius_m: f64) -> Submap {
    let t_submap_world = t_world_submap.inverse();
    let step_m = 0.02;
    let n = (radius_m / step_m) as i32;
    let mut sums: HashMap<[i32; 3], ([f64; 3], u32)> = HashMap::new();
    let mut occupancy = OccupancyMap::new(OCTREE_RESOLUTION_M, OccupancyParams::default());
    let origin = t_world_submap.translation.vector;
    for i in -n..=n {
        for j in -n..=n {
            let (x, y) = (origin.x + f64::from(i) * step_m, origin.y + f64::from(j) * step_m);
            if f64::from(i * i + j * j) * step_m * step_m > radius_m * radius_m {
                continue;
            }
            let Some(z) = terrain.heightfield.height_at(x, y) else { continue };
            let p = t_submap_world * Point3::new(x, y, z);
            let k = [
                (p.x / CLOUD_LEAF_M).floor() as i32,
                (p.y / CLOUD_LEAF_M).floor() as i32,
                (p.z / CLOUD_LEAF_M).floor() as i32,
            ];
            let e = sums.entry(k).or_insert(([0.0; 3], 0));
            e.0[0] += p.x;
            e.0[1] += p.y;
            e.0[2] += p.z;
            e.1 += 1;
            let key = occupancy.key_of(p.x, p.y, p.z);
            occupancy.set_log_odds(key, 3.5);
            for dz in 1..=2 {
                let above = [key[0], key[1], key[2] + dz];
                if occupancy.log_odds(&above).is_none() {
                    occupancy.set_log_odds(above, -2.0);
                }
            }
        }
    }
    // A surface voxel can sit under a neighbour column's free voxel: occupied wins.
    let mut keys: Vec<_> = sums.keys().copied().collect();
    keys.sort_unstable();
    let mut cloud = VoxelCloud::new(CLOUD_LEAF_M);
    for k in keys {
        let (s, c) = sums[&k];
        let n = f64::from(c);
        cloud.points.push(MapPoint {
            position_m: Point3::new((s[0] / n) as f32, (s[1] / n) as f32, (s[2] / n) as f32),
            intensity: 100,
            obstacle: false,
        });
    }
    Submap {
        robot_id: 1,
        index,
        start_stamp_ns: 0,
        end_stamp_ns: 0,
        t_prev_this: Isometry3::identity(),
        switch_covariance: Matrix6::identity() * 1e-4,
        cloud,
        occupancy,
        images: 1,
        distance_m: 0.0,
    }
}

fn three_submaps(terrain: &Terrain) -> Vec<(Arc<Submap>, Isometry3<f64>)> {
    [pose(-4.0, 0.0, 0.0), pose(-1.0, 0.5, 33.0), pose(2.5, -0.5, -71.0)]
        .iter()
        .enumerate()
        .map(|(i, t)| (Arc::new(submap_of(terrain, i as u32, t, 3.0)), *t))
        .collect()
}

fn fresh(submaps: &[(Arc<Submap>, Isometry3<f64>)]) -> Composition {
    let mut map = GlobalMap::new(GlobalMapConfig::default());
    for (s, t) in submaps {
        map.insert(Arc::clone(s), *t);
    }
    map.compose(None)
}

fn occupancy_table(c: &Composition) -> HashMap<[i32; 3], f32> {
    c.occupancy.iter().collect()
}

#[test]
fn cached_composition_equals_composition_from_scratch() {
    let terrain = terrain();
    let submaps = three_submaps(&terrain);
    let mut map = GlobalMap::new(GlobalMapConfig::default());
    for (s, t) in &submaps {
        map.insert(Arc::clone(s), *t);
    }
    let first = map.compose(None);
    assert_eq!(first.stats.recomposed_submaps, 3);
    let second = map.compose(None);
    assert_eq!(second.stats.recomposed_submaps, 0);
    assert_eq!(second.stats.cached_submaps, 3);
    assert_eq!(second.stats.dirty_occupancy_voxels, 0);
    let scratch = fresh(&submaps);
    assert_eq!(second.cloud, scratch.cloud);
    assert_eq!(occupancy_table(&second), occupancy_table(&scratch));
    assert!(second.stats.elapsed < first.stats.elapsed, "cached compose must be cheaper");

    // A sub-threshold pose change (5 mm, 0.05° at ≤ 3 m radius) is not recomposed.
    let nudged = pose(-1.005, 0.5, 33.05);
    assert!(map.set_pose((1, 1), nudged));
    assert_eq!(map.compose(None).stats.recomposed_submaps, 0);
}

#[test]
fn moving_one_submap_changes_only_its_region() {
    let terrain = terrain();
    let mut submaps = three_submaps(&terrain);
    let mut map = GlobalMap::new(GlobalMapConfig::default());
    for (s, t) in &submaps {
        map.insert(Arc::clone(s), *t);
    }
    let before = map.compose(None);
    // A loop closure moves the last submap by 30 cm and 2°.
    let moved = pose(2.8, -0.4, -69.0);
    submaps[2].1 = moved;
    assert!(map.set_pose((1, 2), moved));
    let after = map.compose(None);
    assert_eq!(after.stats.recomposed_submaps, 1);
    assert_eq!(after.stats.cached_submaps, 2);

    // Identical to composing from scratch at the new poses.
    let scratch = fresh(&submaps);
    assert_eq!(after.cloud, scratch.cloud);
    assert_eq!(occupancy_table(&after), occupancy_table(&scratch));

    // Outside the moved submap's old and new footprints (3 m radius + a voxel), nothing changed.
    let old_centre = Point3::new(2.5, -0.5, 0.0);
    let new_centre = Point3::new(2.8, -0.4, 0.0);
    let in_region = |x: f64, y: f64| {
        let p = Point3::new(x, y, 0.0);
        (p - old_centre).norm() < 3.2 || (p - new_centre).norm() < 3.2
    };
    let (b_occ, a_occ) = (occupancy_table(&before), occupancy_table(&after));
    let (mut unchanged, mut changed_in_region) = (0, 0);
    for (k, l) in &b_occ {
        let c = after.occupancy.centre_of(k);
        if in_region(c[0], c[1]) {
            changed_in_region += usize::from(a_occ.get(k) != Some(l));
        } else {
            assert_eq!(a_occ.get(k), Some(l), "voxel {k:?} outside the moved region changed");
            unchanged += 1;
        }
    }
    for k in a_occ.keys() {
        let c = after.occupancy.centre_of(k);
        assert!(in_region(c[0], c[1]) || b_occ.contains_key(k), "new voxel {k:?} outside the region");
    }
    assert!(unchanged > 1000, "{unchanged} voxels outside the region");
    assert!(changed_in_region > 100, "the move must show: {changed_in_region} voxels changed");
    let before_points: HashMap<[i32; 3], MapPoint> = before.cloud.points.iter().map(|p| (key(p), *p)).collect();
    for p in &after.cloud.points {
        if !in_region(f64::from(p.position_m.x), f64::from(p.position_m.y)) {
            assert_eq!(before_points.get(&key(p)), Some(p));
        }
    }
}

fn key(p: &MapPoint) -> [i32; 3] {
    VoxelCloud::new(CLOUD_LEAF_M).voxel_of(&p.position_m)
}

#[test]
fn resampled_surface_stays_on_the_terrain() {
    let terrain = terrain();
    let submaps = three_submaps(&terrain);
    let c = fresh(&submaps);
    // Cloud: every composed point is on the terrain (the surface itself, re-voxelized).
    let mut worst_m: f64 = 0.0;
    for p in &c.cloud.points {
        let h = terrain.heightfield.height_at(f64::from(p.position_m.x), f64::from(p.position_m.y)).unwrap();
        worst_m = worst_m.max((f64::from(p.position_m.z) - h).abs());
    }
    assert!(worst_m < 0.05, "composed cloud off the terrain by {worst_m} m");
    // At most one point per 5 cm voxel.
    let mut seen = std::collections::HashSet::new();
    assert!(c.cloud.points.iter().all(|p| seen.insert(key(p))));

    // Occupancy: per global 10 cm column, the highest occupied voxel is the one containing the
    // terrain surface (±1 voxel for the interpolation across a rotated grid).
    let r = OCTREE_RESOLUTION_M;
    let mut top: HashMap<(i32, i32), i32> = HashMap::new();
    let params = c.occupancy.params;
    for (k, l) in c.occupancy.iter() {
        if l > params.occupied_log_odds {
            let t = top.entry((k[0], k[1])).or_insert(k[2]);
            *t = (*t).max(k[2]);
        }
    }
    // A rotated source voxel reaches up to half a diagonal into the neighbouring columns, so the
    // surface is taken over the column widened by 5 cm on each side.
    let (mut good, mut total) = (0usize, 0usize);
    for ((kx, ky), kz) in &top {
        let (x, y) = ((f64::from(*kx) + 0.5) * r, (f64::from(*ky) + 0.5) * r);
        let mut range: Option<(f64, f64)> = None;
        for i in -5..=5 {
            for j in -5..=5 {
                if let Some(h) = terrain.heightfield.height_at(x + f64::from(i) * 0.02, y + f64::from(j) * 0.02) {
                    let (lo, hi) = range.get_or_insert((h, h));
                    (*lo, *hi) = (lo.min(h), hi.max(h));
                }
            }
        }
        let Some((lo, hi)) = range else { continue };
        total += 1;
        let kz = f64::from(*kz);
        good += usize::from((lo / r).floor() - 1.0 <= kz && kz <= (hi / r).floor() + 1.0);
    }
    assert!(total > 2000, "{total} occupied columns");
    assert!(good as f64 >= 0.98 * total as f64, "{good} of {total} columns on the surface");
    // Free voxels above the surface are kept: resampling must not turn them occupied.
    let free = c.occupancy.iter().filter(|(_, l)| *l <= params.occupied_log_odds).count();
    assert!(free as f64 > 1.5 * total as f64, "{free} free voxels over {total} columns");
}

#[test]
fn current_submap_is_merged_but_never_cached() {
    let terrain = terrain();
    let submaps = three_submaps(&terrain);
    let mut map = GlobalMap::new(GlobalMapConfig::default());
    for (s, t) in &submaps[..2] {
        map.insert(Arc::clone(s), *t);
    }
    let finished_only = map.compose(None);
    let (current, t_current) = &submaps[2];
    let with_current = map.compose(Some((current, t_current)));
    assert_eq!(with_current.stats.recomposed_submaps, 0);
    assert!(with_current.cloud.len() > finished_only.cloud.len());
    // Same as if it were a finished submap (it is merged last, as the last index would be).
    assert_eq!(with_current.cloud, fresh(&submaps).cloud);
    assert_eq!(occupancy_table(&with_current), occupancy_table(&fresh(&submaps)));
    // And it left no trace in the cache.
    let again = map.compose(None);
    assert_eq!(again.cloud, finished_only.cloud);
    assert_eq!(occupancy_table(&again), occupancy_table(&finished_only));
    // Removing a submap re-sums its voxels.
    assert!(map.remove((1, 1)));
    assert_eq!(map.compose(None).cloud, fresh(&submaps[..1]).cloud);
}

/// `c` equals the plain reference composition of `submaps` (composition order), bit for bit.
fn assert_equals_reference(c: &Composition, submaps: &[(&Submap, Isometry3<f64>)]) {
    let (cloud, occupancy) = reference_compose::reference_compose(submaps, &GlobalMapConfig::default());
    assert_eq!(c.cloud.points.len(), cloud.points.len());
    for (a, b) in c.cloud.points.iter().zip(&cloud.points) {
        let bits = |p: &MapPoint| (p.position_m.coords.map(f32::to_bits), p.intensity, p.obstacle);
        assert_eq!(bits(a), bits(b));
    }
    assert_eq!(c.occupancy.len(), occupancy.len());
    for (k, l) in c.occupancy.iter() {
        assert_eq!(Some(l.to_bits()), occupancy.get(&k).map(|r| r.to_bits()), "voxel {k:?}");
    }
}

#[test]
fn composition_equals_the_plain_reference_bit_for_bit() {
    let terrain = terrain();
    let mut submaps = three_submaps(&terrain);
    // A tilted current submap: resampling then crosses bricks on every axis.
    let t_tilted = Isometry3::from_parts(
        Translation3::new(0.5, -2.0, 0.05),
        UnitQuaternion::from_euler_angles(3f64.to_radians(), -2f64.to_radians(), 118f64.to_radians()),
    );
    let current = submap_of(&terrain, 3, &t_tilted, 2.5);
    let mut map = GlobalMap::new(GlobalMapConfig::default());
    for (s, t) in &submaps {
        map.insert(Arc::clone(s), *t);
    }
    fn all<'a>(
        submaps: &'a [(Arc<Submap>, Isometry3<f64>)],
        current: &'a Submap,
        t_current: Isometry3<f64>,
    ) -> Vec<(&'a Submap, Isometry3<f64>)> {
        submaps.iter().map(|(s, t)| (s.as_ref(), *t)).chain([(current, t_current)]).collect()
    }
    let first = map.compose(Some((&current, &t_tilted)));
    assert!(first.occupancy.len() > 10_000 && first.cloud.len() > 10_000);
    assert_equals_reference(&first, &all(&submaps, &current, t_tilted));

    // One submap moved (cached re-sum of its bricks only), then one removed.
    let moved = pose(-0.7, 0.6, 35.0);
    submaps[1].1 = moved;
    assert!(map.set_pose((1, 1), moved));
    let after_move = map.compose(Some((&current, &t_tilted)));
    assert_eq!(after_move.stats.recomposed_submaps, 1);
    assert_equals_reference(&after_move, &all(&submaps, &current, t_tilted));
    assert!(map.remove((1, 0)));
    submaps.remove(0);
    assert_equals_reference(&map.compose(Some((&current, &t_tilted))), &all(&submaps, &current, t_tilted));
}
