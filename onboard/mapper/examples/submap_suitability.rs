//! What the matcher makes of a mission's submaps: points, obstacle points, keypoints, the
//! suitability checks of thesis §6.1.1 (a, d), and how thick the ground is (the share of 0.25 m
//! columns whose non-obstacle points span more than 0.2 m in height: a surface seen through
//! noisy depth, or through a drifting pose, is a smear that ICP and the descriptors cannot use).
//!
//! ```text
//! cargo run --release -p mapper --example submap_suitability -- runs/demo/robot0/state/submaps/*.subm
//! ```

use std::sync::Arc;

use mapper::matching::{MatcherParams, PreparedCloud};

fn main() {
    let params = MatcherParams::default();
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        eprintln!("usage: submap_suitability FILE.subm...");
        std::process::exit(2);
    }
    println!(
        "submap  points  obstacles  keypoints  extent_x_m  extent_y_m  keypoints_x_m  keypoints_y_m  thick_ground_%  verdict"
    );
    for path in paths {
        let bytes = match std::fs::read(&path) {
            Ok(b) => b,
            Err(e) => {
                eprintln!("{path}: {e}");
                continue;
            }
        };
        let submap = match mapper::exchange::decode_submap(&bytes) {
            Ok(s) => s,
            Err(e) => {
                eprintln!("{path}: {e}");
                continue;
            }
        };
        let (mut lo, mut hi) = ([f32::MAX; 2], [f32::MIN; 2]);
        for p in &submap.cloud.points {
            lo = [lo[0].min(p.position_m.x), lo[1].min(p.position_m.y)];
            hi = [hi[0].max(p.position_m.x), hi[1].max(p.position_m.y)];
        }
        let obstacles = submap.cloud.obstacle_count();
        let points = submap.cloud.len();
        let prepared = PreparedCloud::new(Arc::new(submap.cloud), &params);
        let (mut klo, mut khi) = ([f32::MAX; 2], [f32::MIN; 2]);
        for k in prepared.keypoints() {
            klo = [klo[0].min(k.x), klo[1].min(k.y)];
            khi = [khi[0].max(k.x), khi[1].max(k.y)];
        }
        let thick_ground_percent = thick_ground_percent(prepared.cloud(), 0.25, 0.2);
        let verdict = match prepared.suitability() {
            Ok(()) => "suitable".to_owned(),
            Err(why) => why.to_string(),
        };
        println!(
            "{:>3}/{:<3} {points:>7} {obstacles:>10} {:>10} {:>11.1} {:>11.1} {:>14.1} {:>14.1} {thick_ground_percent:>15.1}  {verdict}",
            submap.robot_id,
            submap.index,
            prepared.keypoints().len(),
            hi[0] - lo[0],
            hi[1] - lo[1],
            (khi[0] - klo[0]).max(0.0),
            (khi[1] - klo[1]).max(0.0),
        );
    }
}

/// Share (%) of the `cell_m` xy columns holding non-obstacle points whose heights span more than
/// `span_m`.
fn thick_ground_percent(cloud: &mapper::VoxelCloud, cell_m: f32, span_m: f32) -> f64 {
    let mut columns: std::collections::HashMap<(i32, i32), (f32, f32)> = std::collections::HashMap::new();
    for p in cloud.points.iter().filter(|p| !p.obstacle) {
        let key = ((p.position_m.x / cell_m).floor() as i32, (p.position_m.y / cell_m).floor() as i32);
        let column = columns.entry(key).or_insert((f32::MAX, f32::MIN));
        column.0 = column.0.min(p.position_m.z);
        column.1 = column.1.max(p.position_m.z);
    }
    let thick = columns.values().filter(|(lo, hi)| hi - lo > span_m).count();
    100.0 * thick as f64 / columns.len().max(1) as f64
}
