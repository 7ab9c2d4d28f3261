//! Team model at mission scale: 4 robots mapping a 200 m × 200 m area in 10 m submaps (400
//! submaps of synthetic terrain at 5 cm, exchange-encoded and sent in chunks as the robots do),
//! the four connected by submap matches. Measures ingesting everything (decode + rasterize),
//! the first graph update + composition, and a reference change (graph rebuild + composition).
//!
//! `cargo bench -p groundstation --bench model_scale` (a smoke run without `--bench`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/model_common/mod.rs"]
mod model_common;

use std::time::Instant;

use groundstation::model::{ModelConfig, TeamModel};
use groundstation::view::UiAction;
use mapper::{MapPoint, Submap};
use model_common::*;
use nalgebra::{Isometry3, Matrix6, Point3, Translation3};

const S: u64 = 1_000_000_000;

fn terrain(x: f64, y: f64) -> f32 {
    (0.8 * (x * 0.15).sin() + 0.5 * (y * 0.11).cos() + 0.1 * ((x + y) * 0.9).sin()) as f32
}

/// Submap `index` of a robot whose frame sits at `quadrant` in the world: a 10 m square.
fn submap(robot: u8, index: u32, origin_world: [f64; 2], spacing_m: f32) -> Submap {
    let mut s =
        Submap::new(u16::from(robot), index, u64::from(index) * 10 * S, Isometry3::identity(), Matrix6::zeros());
    s.end_stamp_ns = s.start_stamp_ns + 10 * S;
    let n = (10.0 / spacing_m) as i32;
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f32 * spacing_m + 0.02, j as f32 * spacing_m + 0.02);
            let z = terrain(origin_world[0] + f64::from(x), origin_world[1] + f64::from(y));
            let obstacle = (i * 7 + j * 13) % 997 == 0;
            s.cloud.points.push(MapPoint { position_m: Point3::new(x, y, z), intensity: 80, obstacle });
        }
    }
    s
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    // Lanes of 10 m submaps per robot quadrant (100 m × 100 m when full).
    let (side, spacing) = if full { (10u32, 0.05f32) } else { (2, 0.25) };
    let quadrants = [[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]];
    let mut model = TeamModel::new(ModelConfig { auth_key: None, source: "bench".into() });
    let mut robots: Vec<SimRobot> = (1..=4).map(|r| SimRobot::new(r, None)).collect();

    // Everything the robots send, encoded before the clock starts: (step, robot, message).
    let mut payload_bytes = 0usize;
    let mut steps: Vec<Vec<(usize, u64, protocol::AnyMessage)>> = Vec::new();
    let mut now = 0u64;
    for index in 0..side * side {
        let mut step = Vec::new();
        let (row, col) = (index / side, index % side);
        let col = if row % 2 == 0 { col } else { side - 1 - col };
        let local = [f64::from(col) * 10.0, f64::from(row) * 10.0];
        for (r, quadrant) in quadrants.iter().enumerate() {
            let id = r as u8 + 1;
            let world = [quadrant[0] + local[0], quadrant[1] + local[1]];
            let s = submap(id, index, world, spacing);
            let switch = (index > 0).then(|| {
                let (prow, pcol) = ((index - 1) / side, (index - 1) % side);
                let pcol = if prow % 2 == 0 { pcol } else { side - 1 - pcol };
                Isometry3::from_parts(
                    Translation3::new(local[0] - f64::from(pcol) * 10.0, local[1] - f64::from(prow) * 10.0, 0.0),
                    Default::default(),
                )
            });
            for m in submap_messages(&s, switch) {
                if let protocol::AnyMessage::SubmapChunk(c) = &m {
                    payload_bytes += c.data.len();
                }
                step.push((r, now, m));
            }
            for k in 0..10u64 {
                let t = now + k * S;
                step.push((r, t, pose(id, t, index, &planar(k as f64, 5.0, 0.0)).into()));
            }
            if index == 0 && id > 1 {
                let offset = planar(quadrant[0], quadrant[1], 0.0);
                step.push((r, now, submap_match(id, 0, (1, 0), (id, 0), &offset).into()));
            }
        }
        steps.push(step);
        now += 10 * S;
    }

    let t0 = Instant::now();
    for (i, step) in steps.into_iter().enumerate() {
        let step_ns = i as u64 * 10 * S;
        for (r, t, m) in step {
            robots[r].send(t, m);
        }
        let mut refs: Vec<&mut SimRobot> = robots.iter_mut().collect();
        exchange(&mut model, &mut refs, step_ns + 10 * S - 1);
    }
    let ingest = t0.elapsed();

    let t1 = Instant::now();
    model.tick(now);
    let first = t1.elapsed();
    let stats = model.compose_stats();
    let view = model.view();
    let grid = view.map.clone().expect("a composed map");
    let connected = view.robots.values().filter(|r| r.connected).count();

    let t2 = Instant::now();
    model.apply(now, &UiAction::SetReference(3)).unwrap();
    model.tick(now + S);
    let rebuild = t2.elapsed();

    let t3 = Instant::now();
    let snapshot = model.view().clone();
    let clone = t3.elapsed();

    let submaps = side * side * 4;
    println!("model_scale ({}):", if full { "full" } else { "smoke" });
    println!(
        "  {submaps} submaps, {:.1} MB exchange payload, {} robots connected",
        payload_bytes as f64 / 1e6,
        connected
    );
    println!(
        "  ingest (decode + rasterize every submap): {:.2} s ({:.1} ms per submap)",
        ingest.as_secs_f64(),
        ingest.as_secs_f64() * 1e3 / f64::from(submaps)
    );
    println!("  first tick (graph update + compose):      {:.1} ms", first.as_secs_f64() * 1e3);
    println!("  reference change (rebuild + compose):     {:.1} ms", rebuild.as_secs_f64() * 1e3);
    println!("  view snapshot clone:                      {:.2} ms", clone.as_secs_f64() * 1e3);
    println!(
        "  grid {} × {} cells at {:.2} m ({:.0} m × {:.0} m), {} map points at {:.2} m voxels",
        grid.width,
        grid.height,
        grid.cell_m,
        grid.width as f64 * grid.cell_m,
        grid.height as f64 * grid.cell_m,
        stats.points,
        stats.point_leaf_m
    );
    assert_eq!(connected, 4);
    assert!(grid.width <= 2048 && grid.height <= 2048);
    assert!(stats.points <= groundstation::model::map::MAX_MAP_POINTS);
    assert!(snapshot.robots.len() == 4);
}
