//! Where a mission's submap bytes go: per `.subm` file the content (images, distance, cloud
//! points, octree cells), the encoding with and without zlib, the share of the cloud and of the
//! octree, and the isolated cloud points (no other point in the 26 neighbouring voxels: the
//! speckle a noisy depth image leaves, which a surface seen from several frames does not have).
//!
//! ```text
//! cargo run --release -p mapper --example submap_bytes -- runs/demo/robot0/state/submaps/*.subm
//! ```

use std::collections::HashSet;

use mapper::exchange::{Compression, decode_submap, encode_submap_with};
use mapper::occupancy::OccupancyMap;
use mapper::submap::Submap;

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        eprintln!("usage: submap_bytes FILE.subm...");
        std::process::exit(2);
    }
    println!(
        "{:>40} {:>6} {:>6} {:>7} {:>8} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8} {:>8} {:>10}",
        "file",
        "images",
        "dist_m",
        "span_s",
        "points",
        "isolated",
        "cells",
        "file B",
        "raw B",
        "cloud B",
        "octree B",
        "B/point",
        "B/image",
        "pts/column"
    );
    for path in paths {
        let bytes = match std::fs::read(&path) {
            Ok(b) => b,
            Err(e) => {
                eprintln!("{path}: {e}");
                continue;
            }
        };
        let submap = match decode_submap(&bytes) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{path}: {e}");
                continue;
            }
        };
        let encoded = |s: &Submap, compression| {
            let mut out = Vec::new();
            encode_submap_with(s, compression, &mut out);
            out.len()
        };
        let raw = encoded(&submap, Compression::None);
        let mut cloud_only = submap.clone();
        cloud_only.occupancy = OccupancyMap::new(submap.occupancy.resolution_m, submap.occupancy.params);
        let mut octree_only = submap.clone();
        octree_only.cloud.points.clear();
        let span_s = submap.end_stamp_ns.saturating_sub(submap.start_stamp_ns) as f64 * 1e-9;
        let name = std::path::Path::new(&path).iter().rev().take(4).collect::<Vec<_>>();
        let name: Vec<_> = name.iter().rev().map(|s| s.to_string_lossy()).collect();
        println!(
            "{:>40} {:>6} {:>6.2} {:>7.1} {:>8} {:>8} {:>9} {:>9} {:>9} {:>9} {:>9} {:>8.2} {:>8.0} {:>10.2}",
            name.join("/"),
            submap.images,
            submap.distance_m,
            span_s,
            submap.cloud.len(),
            isolated_points(&submap),
            submap.occupancy.len(),
            bytes.len(),
            raw,
            encoded(&cloud_only, Compression::Smallest),
            encoded(&octree_only, Compression::Smallest),
            bytes.len() as f64 / submap.cloud.len().max(1) as f64,
            bytes.len() as f64 / f64::from(submap.images.max(1)),
            points_per_column(&submap),
        );
    }
}

/// Cloud points per occupied vertical column of voxels: about 1 for a surface seen sharply, more
/// for one smeared by depth noise or pose drift.
fn points_per_column(submap: &Submap) -> f64 {
    let cloud = &submap.cloud;
    let columns: HashSet<[i32; 2]> = cloud
        .points
        .iter()
        .map(|p| {
            let k = cloud.voxel_of(&p.position_m);
            [k[0], k[1]]
        })
        .collect();
    cloud.len() as f64 / columns.len().max(1) as f64
}

/// Cloud points with no other point in their 26 neighbouring voxels.
fn isolated_points(submap: &Submap) -> usize {
    let cloud = &submap.cloud;
    let keys: HashSet<[i32; 3]> = cloud.points.iter().map(|p| cloud.voxel_of(&p.position_m)).collect();
    keys.iter()
        .filter(|k| {
            !(-1..=1).any(|dx| {
                (-1..=1).any(|dy| {
                    (-1..=1).any(|dz| (dx, dy, dz) != (0, 0, 0) && keys.contains(&[k[0] + dx, k[1] + dy, k[2] + dz]))
                })
            })
        })
        .count()
}
