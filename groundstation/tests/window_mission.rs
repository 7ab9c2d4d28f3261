//! The real window against a running mission: Xvfb, the release-built `groundstation` binary on
//! Mesa's software GL, and a 2-robot lockstep mission (`sil::mission`) streaming its ground
//! feed over UDP to the app. Screen grabs (`xwd`) are taken every few seconds until both robots'
//! trajectories are on the map; that screenshot is asserted and kept.
//!
//! The mission uses the test-only truth loop closures (`--truth-loop-closures`): the map is drawn
//! in robot 1's frame and robot 2 appears there only once a detection or match connects it.
//! `GROUNDSTATION_SCREENSHOT_OUT=path.png` also copies the screenshot there (how the one in
//! README.md was made).
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod xvfb;

use std::net::UdpSocket;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use sil::mission::{self, MissionOptions, Runner};

/// The robots' colours in `groundstation::ui::palette` (robot 1 pink, robot 2 yellow).
const ROBOT_RGB: [(u8, [u8; 3]); 2] = [(1, [255, 80, 200]), (2, [255, 220, 0])];
/// A trajectory of a few metres plus the pose marker and its ellipse is well over this; the
/// robot's name label in the side panel (the only other use of the colour) is far below it.
const MIN_TRAJECTORY_PIXELS: usize = 250;

#[test]
fn window_shows_both_trajectories_of_a_running_mission() {
    let dir = std::env::temp_dir().join(format!("gs-window-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let x = xvfb::Xvfb::start(1400, 900);

    let port = UdpSocket::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let frame_log = dir.join("frames.log");
    let mut app = Command::new(env!("CARGO_BIN_EXE_groundstation"))
        .args(["--connect", &format!("udp://127.0.0.1:{port}"), "--exit-after", "600"])
        .env("DISPLAY", &x.display)
        .env("LIBGL_ALWAYS_SOFTWARE", "1")
        // One rasterizer thread: the mission needs the machine's two cores.
        .env("LP_NUM_THREADS", "1")
        .env("GROUNDSTATION_FRAME_LOG", &frame_log)
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(dir.join("app.log")).unwrap())
        .spawn()
        .unwrap();
    std::thread::sleep(Duration::from_secs(2));
    assert!(
        app.try_wait().unwrap().is_none(),
        "the app exited: {}",
        std::fs::read_to_string(dir.join("app.log")).unwrap()
    );

    let options = MissionOptions {
        robots: 2,
        duration_s: 45.0,
        seed: 3,
        downscale: 4,
        out: dir.join("mission"),
        runner: Runner::Lockstep,
        truth_loop_closures: true,
        // Short submaps, so that finished ones reach the ground and the map fills in.
        submap_max_distance_m: Some(1.5),
        feed: Some(format!("127.0.0.1:{port}").parse().unwrap()),
        ..MissionOptions::default()
    };
    let mission = std::thread::spawn(move || mission::run(&options));

    let started = Instant::now();
    let (image, counts) = loop {
        std::thread::sleep(Duration::from_secs(3));
        let image = x.grab();
        let counts = ROBOT_RGB.map(|(_, rgb)| image.count_near(rgb, 12));
        let done = mission.is_finished();
        println!("{:>5.1} s: robot pixels {counts:?}", started.elapsed().as_secs_f64());
        if done || counts.iter().all(|&c| c >= MIN_TRAJECTORY_PIXELS) {
            break (image, counts);
        }
        assert!(
            app.try_wait().unwrap().is_none(),
            "the app died: {}",
            std::fs::read_to_string(dir.join("app.log")).unwrap()
        );
    };
    let shot = dir.join("screenshot.png");
    image.save_png(&shot);
    if let Some(out) = std::env::var_os("GROUNDSTATION_SCREENSHOT_OUT") {
        std::fs::copy(&shot, out).unwrap();
    }
    // A rendered UI, not a blank or single-colour screen, with both trajectories on the map.
    assert!(image.distinct_colours() > 50, "only {} colours on screen", image.distinct_colours());
    for ((robot, _), count) in ROBOT_RGB.iter().zip(counts) {
        assert!(count >= MIN_TRAJECTORY_PIXELS, "robot {robot}: {count} pixels of its colour ({})", shot.display());
    }

    let report = mission.join().unwrap().unwrap();
    assert_eq!(report.robots.len(), 2);
    let _ = app.kill();
    let _ = app.wait();
    let frames = xvfb::frame_log(&std::fs::read_to_string(&frame_log).unwrap());
    assert!(frames.len() > 20, "{} frames logged", frames.len());
    println!(
        "frames {}: ui p50 {:.2} ms, eframe cpu p50 {:.2} ms p95 {:.2} ms",
        frames.len(),
        xvfb::quantile(frames.iter().map(|f| f[0]), 0.5),
        xvfb::quantile(frames.iter().map(|f| f[1]), 0.5),
        xvfb::quantile(frames.iter().map(|f| f[1]), 0.95)
    );
    std::fs::remove_dir_all(&dir).ok();
}
