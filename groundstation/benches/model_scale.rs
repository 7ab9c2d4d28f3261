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
use model_common::*;

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (side, spacing) = if full { (10u32, 0.05f32) } else { (2, 0.25) };
    let ScaleMission { steps, payload_bytes, end_ns: now } = scale_mission(side, spacing);
    let mut model = TeamModel::new(ModelConfig { auth_key: None, source: "bench".into() });
    let mut robots: Vec<SimRobot> = (1..=4).map(|r| SimRobot::new(r, None)).collect();

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
