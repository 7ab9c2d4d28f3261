//! Exchange encoding: lossless round trip (property tests on random and on simulated submaps)
//! and a total decoder (arbitrary bytes, mutated valid encodings).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashMap;

use mapper::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
use mapper::exchange::{CENTROID_QUANTA, Compression, ExchangeError, decode_submap, encode_submap, encode_submap_with};
use mapper::occupancy::{OCTREE_RESOLUTION_M, OccupancyMap, OccupancyParams, VoxelKey};
use mapper::submap::Submap;
use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

/// Checks `decoded` against `original` under the documented notion of lossless.
fn assert_lossless(original: &Submap, decoded: &Submap) {
    assert_eq!(decoded.robot_id, original.robot_id);
    assert_eq!(decoded.index, original.index);
    assert_eq!(decoded.start_stamp_ns, original.start_stamp_ns);
    assert_eq!(decoded.end_stamp_ns, original.end_stamp_ns);
    assert_eq!(decoded.images, original.images);
    assert_eq!(decoded.distance_m.to_bits(), original.distance_m.to_bits());
    assert_eq!(decoded.t_prev_this, original.t_prev_this);
    assert_eq!(decoded.switch_covariance, original.switch_covariance);
    // Octree: leaf set and every log-odds bit for bit, resolution and parameters.
    assert_eq!(decoded.occupancy, original.occupancy);
    // Cloud: same voxels, exact intensity and obstacle bit, centroid within half a quantum.
    let cloud = &original.cloud;
    assert_eq!(decoded.cloud.leaf_m, cloud.leaf_m);
    let by_key: HashMap<[i32; 3], &MapPoint> =
        cloud.points.iter().map(|p| (cloud.voxel_of(&p.position_m), p)).collect();
    assert_eq!(decoded.cloud.len(), by_key.len());
    let half_quantum = cloud.leaf_m / f64::from(CENTROID_QUANTA) / 2.0;
    for p in &decoded.cloud.points {
        let key = decoded.cloud.voxel_of(&p.position_m);
        let q = by_key.get(&key).unwrap_or_else(|| panic!("decoded voxel {key:?} not in the original"));
        assert_eq!(p.intensity, q.intensity);
        assert_eq!(p.obstacle, q.obstacle);
        for a in 0..3 {
            let d = (f64::from(p.position_m[a]) - f64::from(q.position_m[a])).abs();
            // f32 rounding of coordinates up to ~100 m adds at most ~4 µm.
            assert!(d <= half_quantum + 1e-5, "axis {a}: centroid moved {d} m");
        }
    }
}

fn round_trip(submap: &Submap, compression: Compression) -> (Submap, usize) {
    let mut bytes = Vec::new();
    encode_submap_with(submap, compression, &mut bytes);
    (decode_submap(&bytes).expect("decode"), bytes.len())
}

/// Log-odds values the integrator produces: sums of hits and misses, clamped (in f32).
fn reachable_log_odds(params: &OccupancyParams) -> Vec<f32> {
    let mut values = vec![0.0f32];
    let mut frontier = vec![0.0f32];
    for _ in 0..12 {
        let mut next = Vec::new();
        for &v in &frontier {
            for d in [params.hit_log_odds, params.miss_log_odds] {
                let n = (v + d).clamp(params.min_log_odds, params.max_log_odds);
                if !values.iter().any(|x| x.to_bits() == n.to_bits()) {
                    values.push(n);
                    next.push(n);
                }
            }
        }
        frontier = next;
    }
    values
}

prop_compose! {
    fn arb_header()(
        robot_id in any::<u16>(), index in any::<u32>(), start in any::<u64>(), len in 0u64..1 << 40,
        images in any::<u32>(), distance_m in 0.0f64..100.0,
        t in prop::array::uniform3(-50.0f64..50.0), axis_angle in prop::array::uniform3(-3.0f64..3.0),
        cov in prop::collection::vec(-1.0f64..1.0, 36),
    ) -> Submap {
        let rotation = UnitQuaternion::from_scaled_axis(Vector3::from(axis_angle));
        let mut s = Submap::new(robot_id, index, start, Isometry3::from_parts(Translation3::from(Vector3::from(t)), rotation),
            Matrix6::from_column_slice(&cov));
        s.end_stamp_ns = start.saturating_add(len);
        s.images = images;
        s.distance_m = distance_m;
        s
    }
}

prop_compose! {
    fn arb_submap()(
        mut submap in arb_header(),
        offset in prop::array::uniform3(-1500i32..1500),
        points in prop::collection::vec((prop::array::uniform3(-40i32..40), prop::array::uniform3(0.0f64..1.0), any::<u8>(), any::<bool>()), 0..400),
        cells in prop::collection::vec((prop::array::uniform3(-30i32..30), 0usize..64), 0..300),
        blocks in prop::collection::vec((prop::array::uniform3(-4i32..4), 1u32..4, 0usize..64), 0..4),
    ) -> Submap {
        let leaf = CLOUD_LEAF_M;
        for (k, frac, intensity, obstacle) in points {
            let p = Point3::new(
                ((f64::from(k[0] + offset[0]) + frac[0]) * leaf) as f32,
                ((f64::from(k[1] + offset[1]) + frac[1]) * leaf) as f32,
                ((f64::from(k[2] + offset[2]) + frac[2]) * leaf) as f32,
            );
            submap.cloud.points.push(MapPoint { position_m: p, intensity, obstacle });
        }
        // A valid cloud has one point per voxel.
        let cloud = &mut submap.cloud;
        let mut seen = std::collections::HashSet::new();
        let keys: Vec<_> = cloud.points.iter().map(|p| cloud.voxel_of(&p.position_m)).collect();
        let mut i = 0;
        cloud.points.retain(|_| { i += 1; seen.insert(keys[i - 1]) });
        let values = reachable_log_odds(&submap.occupancy.params);
        for (k, v) in cells {
            let key = [k[0] + offset[0], k[1] + offset[1], k[2] + offset[2]];
            submap.occupancy.set_log_odds(key, values[v % values.len()]);
        }
        // Aligned uniform blocks exercise the pruned nodes.
        for (corner, level, v) in blocks {
            let side = 1 << level;
            for dz in 0..side { for dy in 0..side { for dx in 0..side {
                let key = [corner[0] * side + dx + offset[0] * 8, corner[1] * side + dy, corner[2] * side + dz];
                submap.occupancy.set_log_odds(key, values[v % values.len()]);
            }}}
        }
        submap
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn random_submaps_round_trip_losslessly(submap in arb_submap()) {
        for compression in [Compression::None, Compression::Zlib, Compression::Smallest] {
            let (decoded, _) = round_trip(&submap, compression);
            assert_lossless(&submap, &decoded);
        }
    }

    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..2000)) {
        let _ = decode_submap(&bytes);
        // Also behind a valid header, so the body parsers see the arbitrary bytes.
        let mut framed = Vec::new();
        encode_submap_with(&Submap::new(1, 2, 3, Isometry3::identity(), Matrix6::identity()), Compression::None, &mut framed);
        // Empty body: cloud leaf and count (12 bytes), octree resolution, params and counts (36).
        let header_len = framed.len() - 48;
        framed.truncate(header_len);
        framed.extend_from_slice(&bytes);
        let _ = decode_submap(&framed);
    }

    #[test]
    fn mutated_encodings_never_panic(
        submap in arb_submap(),
        mutations in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..6),
        cut in any::<prop::sample::Index>(),
        zlib in any::<bool>(),
    ) {
        let mut bytes = Vec::new();
        encode_submap_with(&submap, if zlib { Compression::Zlib } else { Compression::None }, &mut bytes);
        let mut mutated = bytes.clone();
        for (at, value) in &mutations {
            let i = at.index(mutated.len());
            mutated[i] = *value;
        }
        let _ = decode_submap(&mutated);
        let _ = decode_submap(&bytes[..cut.index(bytes.len())]);
    }
}

#[test]
fn empty_submap_round_trips_and_header_errors_are_specific() {
    let submap = Submap::new(7, 0, 42, Isometry3::identity(), Matrix6::identity() * 0.01);
    let mut bytes = Vec::new();
    encode_submap(&submap, &mut bytes);
    assert_eq!(decode_submap(&bytes).unwrap(), submap);
    let mut bad = bytes.clone();
    bad[0] = b'X';
    assert_eq!(decode_submap(&bad), Err(ExchangeError::BadMagic));
    let mut bad = bytes.clone();
    bad[4] = 99;
    assert_eq!(decode_submap(&bad), Err(ExchangeError::UnsupportedVersion(99)));
    assert_eq!(decode_submap(&bytes[..bytes.len() - 1]), Err(ExchangeError::Truncated));
    let mut long = bytes.clone();
    long.push(0);
    assert_eq!(decode_submap(&long), Err(ExchangeError::TrailingBytes(1)));
}

#[test]
fn centroid_at_voxel_edges_stays_in_its_voxel() {
    let mut submap = Submap::new(0, 0, 0, Isometry3::identity(), Matrix6::zeros());
    let leaf = CLOUD_LEAF_M;
    let below = |k: i32| ((f64::from(k) + 1.0) * leaf) as f32;
    for (i, k) in [-1000i32, -1, 0, 1, 999].into_iter().enumerate() {
        let p = Point3::new(below(k).next_down(), (f64::from(k) * leaf) as f32, 0.0);
        submap.cloud.points.push(MapPoint { position_m: p, intensity: i as u8, obstacle: i % 2 == 0 });
    }
    submap.cloud.points.retain(|p| p.position_m.x.is_finite());
    let (decoded, _) = round_trip(&submap, Compression::None);
    assert_lossless(&submap, &decoded);
}

#[test]
fn octree_blocks_are_pruned_and_palette_is_bit_exact() {
    // 8×8×8 free block at the clamp plus one odd value: 512 cells, 2 distinct values.
    let mut map = OccupancyMap::new(OCTREE_RESOLUTION_M, OccupancyParams::default());
    for z in 0..8 {
        for y in 0..8 {
            for x in 0..8 {
                map.set_log_odds([x, y, z], -2.0);
            }
        }
    }
    let odd = 0.85f32 + 0.85 - 0.4; // not representable as a short decimal: must stay bit exact
    map.set_log_odds([9, 0, 0], odd);
    let mut submap = Submap::new(0, 0, 0, Isometry3::identity(), Matrix6::zeros());
    submap.occupancy = map;
    let (decoded, size) = round_trip(&submap, Compression::None);
    let mut empty = Vec::new();
    encode_submap_with(&Submap::new(0, 0, 0, Isometry3::identity(), Matrix6::zeros()), Compression::None, &mut empty);
    assert_eq!(decoded.occupancy.log_odds(&[9, 0, 0]).map(f32::to_bits), Some(odd.to_bits()));
    assert_eq!(decoded.occupancy, submap.occupancy);
    // Pruned: a palette, a few structure bytes and two records, not 512 leaf records.
    let body = size - empty.len();
    assert!(body < 100, "octree body is {body} bytes");
}

/// Builds a submap from a few simulated depth frames of a Moon drive with the real integrator.
fn simulated_submap() -> Submap {
    use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
    use mapper::integrate::{DepthIntegrator, IntegratorConfig};
    use sim::driver::SimSensorSource;
    use sim::scenario::{self, ScenarioOptions};
    use sim::world::World;
    use std::sync::Arc;
    use vision::depth::{DepthImage, StereoGeometry};

    let options = ScenarioOptions {
        robots: 1,
        duration_s: 20.0,
        seed: 5,
        downscale: 2,
        world_size_m: None,
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    let scenario = scenario::preset("moon", &options).expect("moon preset");
    let world = World::build(&scenario).expect("world");
    let mut source = SimSensorSource::new(Arc::clone(&world), 0).expect("source");
    let calibration = source.stereo_calibration().expect("cameras");
    let geometry = StereoGeometry::from_calibration(&calibration);
    let (w, h) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
    let mut integrator = DepthIntegrator::new(IntegratorConfig::default(), geometry);
    let mut submap = Submap::new(0, 3, 0, Isometry3::translation(1.0, 2.0, 0.1), Matrix6::identity() * 1e-3);
    let mut frame = StereoFrame::default();
    let mut t_first_world = None;
    while submap.images < 6 {
        let Some(event) = hal::sensor::next_event_with_frame(&mut source, &mut frame).expect("event") else { break };
        if !matches!(event, SensorEvent::Stereo(_))
            || frame.stamp_ns < 2_000_000_000
            || !frame.sequence.is_multiple_of(20)
        {
            continue;
        }
        let t_world_cam = world.t_world_cam(0, frame.stamp_ns).expect("pose");
        let t_first: Isometry3<f64> = *t_first_world.get_or_insert_with(|| t_world_cam.inverse());
        let depth = DepthImage { width: w, height: h, depth_m: source.last_depth_m().to_vec() };
        integrator.integrate(&mut submap, &depth, None, Some(&frame.left), &(t_first * t_world_cam));
        submap.end_stamp_ns = frame.stamp_ns;
    }
    submap
}

#[test]
fn simulated_submap_round_trips_and_compression_pays() {
    let submap = simulated_submap();
    let (points, cells) = (submap.cloud.len(), submap.occupancy.len());
    assert!(
        points > 1000 && cells > 1000,
        "sim submap too small: {points} points, {cells} cells, {} images",
        submap.images
    );
    let (raw, raw_bytes) = round_trip(&submap, Compression::None);
    assert_lossless(&submap, &raw);
    let (zlib, zlib_bytes) = round_trip(&submap, Compression::Zlib);
    assert_lossless(&submap, &zlib);
    assert!(zlib_bytes < raw_bytes, "zlib {zlib_bytes} B vs raw {raw_bytes} B");
    // Far below the naive 16 bytes per point and 16 per octree leaf.
    let naive = 16 * (submap.cloud.len() + submap.occupancy.len());
    assert!(zlib_bytes * 4 < naive, "{zlib_bytes} B vs naive {naive} B");
    let _: VoxelKey = [0, 0, 0];
    let _ = VoxelCloud::new(CLOUD_LEAF_M);
}
