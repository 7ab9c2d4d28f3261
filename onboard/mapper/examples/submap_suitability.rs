//! What the matcher makes of a mission's submaps: points, obstacle points, keypoints, and the
//! suitability checks of thesis §6.1.1 (a, d).
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
    println!("submap  points  obstacles  keypoints  extent_x_m  extent_y_m  keypoints_x_m  keypoints_y_m  verdict");
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
        let verdict = match prepared.suitability() {
            Ok(()) => "suitable".to_owned(),
            Err(why) => why.to_string(),
        };
        println!(
            "{:>3}/{:<3} {points:>7} {obstacles:>10} {:>10} {:>11.1} {:>11.1} {:>14.1} {:>14.1}  {verdict}",
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
