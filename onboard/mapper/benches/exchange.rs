//! Bytes per submap of the exchange encoding on realistic content, against the thesis's 700 KB
//! average (spec §4.3), with and without zlib, and the encode/decode times.
//!
//! Content: the simulator's rendered true depth (full 1024×508, Moon preset, seed 3) along the
//! ground-truth camera poses, integrated by the real `DepthIntegrator` (default config: cloud
//! plus octree with free-space ray casting) at 5 Hz (every 2nd stereo frame), one submap per
//! 7 m of driving (the thesis's later distance threshold).
//!
//! Run: `cargo bench -p mapper --bench exchange` (`SUBMAPS=n` for more than 2 submaps).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;
use std::time::Instant;

use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
use mapper::exchange::{Compression, decode_submap, encode_submap_with};
use mapper::export::write_bt;
use mapper::integrate::{DepthIntegrator, IntegratorConfig};
use mapper::submap::Submap;
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion};
use sim::driver::SimSensorSource;
use sim::scenario::{self, ScenarioOptions};
use sim::world::World;
use vision::depth::{DepthImage, StereoGeometry};

/// The thesis's average submap (spec §4.3: 700 KB per submap).
const THESIS_BYTES: f64 = 700e3;
const SUBMAP_DISTANCE_M: f64 = 7.0;

fn main() {
    // `cargo bench` passes `--bench`; `cargo test --all-targets` runs this as a smoke test: one
    // submap of a few images instead of two 7 m submaps (about 4 minutes).
    let full = std::env::args().any(|arg| arg == "--bench");
    let default_submaps = if full { 2 } else { 1 };
    let smoke_images: Option<u32> = (!full).then_some(4);
    let submaps_wanted: usize = std::env::var("SUBMAPS").ok().and_then(|s| s.parse().ok()).unwrap_or(default_submaps);
    let options = ScenarioOptions {
        robots: 1,
        duration_s: 600.0,
        seed: 3,
        downscale: 1,
        world_size_m: None,
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    let scenario = scenario::preset("moon", &options).expect("moon preset");
    let world: Arc<World> = World::build(&scenario).expect("world");
    let mut source = SimSensorSource::new(Arc::clone(&world), 0).expect("source");
    let calibration = source.stereo_calibration().expect("cameras");
    let geometry = StereoGeometry::from_calibration(&calibration);
    let (w, h) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
    let mut integrator = DepthIntegrator::new(IntegratorConfig::default(), geometry);

    println!("exchange: moon seed 3, {w}x{h} true depth at 5 Hz, one submap per {SUBMAP_DISTANCE_M} m");
    println!("cloud B / octree B: the zlib encoding with only that grid (each includes the ~430 B header)");
    println!(
        "{:>3} {:>6} {:>8} {:>8} {:>8} {:>10} {:>10} {:>9} {:>9} {:>9} {:>8} {:>8} {:>9}",
        "#",
        "images",
        "points",
        "cells",
        "occ",
        "raw B",
        "zlib B",
        "cloud B",
        "octree B",
        "bt B",
        "enc ms",
        "dec ms",
        "700KB/x"
    );
    let mut frame = StereoFrame::default();
    let mut t_origin_world: Option<Isometry3<f64>> = None;
    let mut last_position = None;
    let mut distance_m = 0.0;
    let mut submap = Submap::new(0, 0, 0, Isometry3::identity(), Matrix6::identity() * 1e-4);
    let mut sizes = Vec::new();
    let mut depth = DepthImage { width: w, height: h, depth_m: Vec::new() };
    while sizes.len() < submaps_wanted {
        let Some(event) = hal::sensor::next_event_with_frame(&mut source, &mut frame).expect("event") else { break };
        if !matches!(event, SensorEvent::Stereo(_)) || !frame.sequence.is_multiple_of(2) {
            continue;
        }
        let t_world_cam = world.t_world_cam(0, frame.stamp_ns).expect("pose");
        let body = world.robot_state(0, frame.stamp_ns).expect("state");
        let position = body.t_world_body.translation.vector;
        if let Some(last) = last_position.replace(position) {
            distance_m += (position - last).norm();
        }
        // The submap origin is gravity aligned: the body position and heading at its start.
        let t_origin = *t_origin_world.get_or_insert_with(|| {
            let yaw = UnitQuaternion::from_euler_angles(0.0, 0.0, body.euler_rad.z);
            Isometry3::from_parts(Translation3::from(position), yaw).inverse()
        });
        depth.depth_m.clear();
        depth.depth_m.extend_from_slice(source.last_depth_m());
        integrator.integrate(&mut submap, &depth, None, Some(&frame.left), &(t_origin * t_world_cam));
        submap.end_stamp_ns = frame.stamp_ns;
        submap.distance_m = distance_m;
        if distance_m < SUBMAP_DISTANCE_M && smoke_images.is_none_or(|n| submap.images < n) {
            continue;
        }
        let finished = std::mem::replace(
            &mut submap,
            Submap::new(0, sizes.len() as u32 + 1, frame.stamp_ns, Isometry3::identity(), Matrix6::identity() * 1e-4),
        );
        t_origin_world = None;
        distance_m = 0.0;
        sizes.push(report(sizes.len(), &finished));
    }
    let n = sizes.len().max(1) as f64;
    let mean_zlib = sizes.iter().map(|s| s.1 as f64).sum::<f64>() / n;
    let mean_raw = sizes.iter().map(|s| s.0 as f64).sum::<f64>() / n;
    println!(
        "mean over {} submaps: {:.1} KB with zlib ({:.1} KB raw, zlib saves {:.0} %); thesis 700 KB / ours = {:.1}x (target >= 5x)",
        sizes.len(),
        mean_zlib / 1e3,
        mean_raw / 1e3,
        100.0 * (1.0 - mean_zlib / mean_raw),
        THESIS_BYTES / mean_zlib
    );
}

/// Prints one submap's sizes and times; returns (raw, zlib) bytes.
fn report(index: usize, submap: &Submap) -> (usize, usize) {
    let mut raw = Vec::new();
    encode_submap_with(submap, Compression::None, &mut raw);
    let mut zlib = Vec::new();
    let start = Instant::now();
    encode_submap_with(submap, Compression::Zlib, &mut zlib);
    let encode_ms = start.elapsed().as_secs_f64() * 1e3;
    let start = Instant::now();
    let decoded = decode_submap(&zlib).expect("decode");
    let decode_ms = start.elapsed().as_secs_f64() * 1e3;
    assert_eq!(decoded.occupancy, submap.occupancy);
    // Share of each grid: the same submap with only one of them (zlib).
    let part = |cloud: bool| {
        let mut only = submap.clone();
        if cloud {
            only.occupancy =
                mapper::occupancy::OccupancyMap::new(submap.occupancy.resolution_m, submap.occupancy.params);
        } else {
            only.cloud.points.clear();
        }
        let mut bytes = Vec::new();
        encode_submap_with(&only, Compression::Zlib, &mut bytes);
        bytes.len()
    };
    let (cloud_bytes, octree_bytes) = (part(true), part(false));
    let mut bt = Vec::new();
    write_bt(&submap.occupancy, &mut bt).expect("bt");
    println!(
        "{:>3} {:>6} {:>8} {:>8} {:>8} {:>10} {:>10} {:>9} {:>9} {:>9} {:>8.1} {:>8.1} {:>9.1}",
        index,
        submap.images,
        submap.cloud.len(),
        submap.occupancy.len(),
        submap.occupancy.occupied_count(),
        raw.len(),
        zlib.len(),
        cloud_bytes,
        octree_bytes,
        bt.len(),
        encode_ms,
        decode_ms,
        THESIS_BYTES / zlib.len() as f64
    );
    (raw.len(), zlib.len())
}
