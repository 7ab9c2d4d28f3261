//! Frame time of the real window on this machine's software renderer: the release
//! `groundstation` binary under Xvfb on Mesa's llvmpipe, redrawing continuously, replaying a
//! 4-robot mission over 200 m × 200 m (400 submaps of 10 m at 5 cm, composed into a 2000 × 2000
//! grid, ~200k 3D points). The reference is the budget: 33 ms per frame.
//!
//! `cargo bench -p groundstation --bench window_frame` (without `--bench`: a small map, a short
//! run, as a smoke test).
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../tests/model_common/mod.rs"]
mod model_common;
#[path = "../tests/xvfb/mod.rs"]
mod xvfb;

use std::process::{Command, Stdio};
use std::time::Duration;

use groundstation::model::{ModelConfig, TeamModel};
use hal::feedlog::FeedLogWriter;
use model_common::*;

const BUDGET_MS: f64 = 33.0;
/// Feed time between two 10 s mission steps in the log: the replay reaches the end quickly.
const STEP_FEED_NS: u64 = 20_000_000;

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (side, spacing) = if full { (10u32, 0.05f32) } else { (2, 0.25) };
    let dir = std::env::temp_dir().join(format!("gs-window-frame-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();

    // The feed the ground would have received, written as a mission's recording.
    let mission = scale_mission(side, spacing);
    let mut acker = TeamModel::new(ModelConfig { auth_key: None, source: "bench".into() });
    let mut robots: Vec<SimRobot> = (1..=4).map(|r| SimRobot::new(r, None)).collect();
    let mut log = FeedLogWriter::create(dir.join("ground_feed.log")).unwrap();
    let mut packets = 0;
    for (i, step) in mission.steps.into_iter().enumerate() {
        let step_ns = i as u64 * 10 * S;
        for (r, t, m) in step {
            robots[r].send(t, m);
        }
        let mut refs: Vec<&mut SimRobot> = robots.iter_mut().collect();
        for packet in exchange(&mut acker, &mut refs, step_ns + 10 * S - 1) {
            log.append((i as u64 + 1) * STEP_FEED_NS, 0, &packet).unwrap();
            packets += 1;
        }
    }
    log.flush().unwrap();
    drop(log);
    let feed_end_s = (side * side + 1) as f64 * STEP_FEED_NS as f64 * 1e-9;

    // Ingesting 400 submaps takes the engine thread ~5 s; frames are counted after that.
    let (run_s, settle_s) = if full { (45.0, 20.0) } else { (10.0, 4.0) };
    let x = xvfb::Xvfb::start(1600, 1000);
    let frame_log = dir.join("frames.log");
    let status = Command::new(env!("CARGO_BIN_EXE_groundstation"))
        .arg("--replay")
        .arg(&dir)
        .args(["--exit-after", &format!("{run_s}")])
        .env("DISPLAY", &x.display)
        .env("LIBGL_ALWAYS_SOFTWARE", "1")
        .env("GROUNDSTATION_FRAME_LOG", &frame_log)
        .env("GROUNDSTATION_CONTINUOUS", "1")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("app.log")).unwrap())
        .spawn()
        .and_then(|mut app| {
            std::thread::sleep(Duration::from_secs_f64(run_s - 2.0));
            let shot = x.grab();
            shot.save_png(&dir.join("screenshot.png"));
            assert!(shot.distinct_colours() > 50, "the window shows almost nothing");
            app.wait()
        })
        .unwrap();
    assert!(status.success(), "groundstation: {status}\n{}", std::fs::read_to_string(dir.join("app.log")).unwrap());

    let frames = xvfb::frame_log(&std::fs::read_to_string(&frame_log).unwrap());
    let mut elapsed_s = 0.0;
    let settled: Vec<[f64; 3]> = frames
        .iter()
        .filter(|f| {
            elapsed_s += if f[2].is_finite() { f[2] * 1e-3 } else { 0.0 };
            elapsed_s > settle_s
        })
        .copied()
        .collect();
    assert!(settled.len() > 10, "{} frames after settling", settled.len());
    let q = |k: usize, p: f64| xvfb::quantile(settled.iter().map(|f| f[k]), p);
    let (p50, p95, max) = (q(2, 0.5), q(2, 0.95), q(2, 1.0));
    println!("window_frame ({}):", if full { "full" } else { "smoke" });
    println!(
        "  replay of {} submaps from 4 robots ({:.1} MB payload, {packets} packets, feed {:.1} s), the app's 1400 × 900 window on a 1600 × 1000 Xvfb screen, llvmpipe",
        side * side * 4,
        mission.payload_bytes as f64 / 1e6,
        feed_end_s
    );
    println!(
        "  {} frames after {settle_s} s: frame interval p50 {p50:.1} ms, p95 {p95:.1} ms, max {max:.1} ms; eframe CPU p50 {:.1} ms p95 {:.1} ms; UI code p50 {:.2} ms",
        settled.len(),
        q(1, 0.5),
        q(1, 0.95),
        q(0, 0.5)
    );
    println!(
        "  budget {BUDGET_MS} ms: p50 at {:.2}× and p95 at {:.2}× of it ({:.0} frames/s)",
        p50 / BUDGET_MS,
        p95 / BUDGET_MS,
        1e3 / p50
    );
    println!("  screenshot: {}", dir.join("screenshot.png").display());
}
