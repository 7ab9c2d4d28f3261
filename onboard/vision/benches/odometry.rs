#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Per-frame time of `StereoOdometry::process` at the rover's full 1024×508 resolution on one
//! thread, on frames rendered by the simulator (Moon preset, a driving rover): sparse stereo
//! mode and SGM-map mode. The SGM maps are computed beforehand and not timed (on the rover the
//! FPGA produces them). Run: `cargo bench -p vision --bench odometry`.

use std::sync::Arc;
use std::time::Instant;

use fpga_model::fast::Matcher;
use fpga_model::{DisparityImage, GrayImage, SgmConfig};
use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
use sim::driver::SimSensorSource;
use sim::scenario::{ScenarioOptions, preset};
use sim::world::World;
use vision::{StereoOdometry, VoConfig};

const FRAMES: usize = 100;
/// Frames skipped at the start (the rover stands for the first 6 s): the timed frames cover the
/// first drive and the following stop.
const SKIP: u64 = 58;

/// This thread's CPU time in ns (Linux schedstat): other processes on a busy machine do not
/// inflate it the way they inflate wall-clock time. `None` where unavailable.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

fn percentile_ms(sorted: &[f64], p: f64) -> f64 {
    let index = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[index]
}

fn main() {
    let options = ScenarioOptions {
        robots: 1,
        duration_s: 30.0,
        seed: 3,
        downscale: 1,
        world_size_m: Some(60.0),
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    let mut scenario = preset("moon", &options).unwrap();
    scenario.robots[0].pan_sweep_rad = 0.0;
    let world: Arc<World> = World::build(&scenario).unwrap();
    let mut source = SimSensorSource::new(world, 0).unwrap();
    let calibration = source.stereo_calibration().unwrap();
    let mut frame = StereoFrame::default();
    let mut frames = Vec::new();
    while frames.len() < FRAMES {
        match hal::sensor::next_event_with_frame(&mut source, &mut frame).unwrap() {
            Some(SensorEvent::Stereo(_)) if frame.sequence >= SKIP => frames.push(frame.clone()),
            Some(_) => {}
            None => break,
        }
    }
    let (w, h) = (frames[0].width_px as usize, frames[0].height_px as usize);
    let mut matcher = Matcher::new(SgmConfig::default(), w, h, 2).unwrap();
    let maps: Vec<DisparityImage> = frames
        .iter()
        .map(|f| {
            let mut map = DisparityImage { width: w, height: h, data: vec![0; w * h] };
            let left = GrayImage::new(w, h, f.left.clone()).unwrap();
            let right = GrayImage::new(w, h, f.right.clone()).unwrap();
            matcher.compute_into(&left, &right, &mut map).unwrap();
            map
        })
        .collect();
    println!("odometry bench: {} frames {w}x{h}, one thread", frames.len());
    for use_map in [false, true] {
        let mut odometry = StereoOdometry::new(VoConfig::default(), &calibration).unwrap();
        let mut times_ms = Vec::with_capacity(frames.len());
        let mut cpu_ms = Vec::with_capacity(frames.len());
        let mut keyframes = 0;
        let mut inliers = 0u64;
        for (f, map) in frames.iter().zip(&maps) {
            let (start, cpu_start) = (Instant::now(), thread_cpu_ns());
            let out = odometry.process(f, use_map.then_some(map), None).unwrap();
            times_ms.push(start.elapsed().as_secs_f64() * 1e3);
            if let (Some(a), Some(b)) = (cpu_start, thread_cpu_ns()) {
                cpu_ms.push(b.saturating_sub(a) as f64 * 1e-6);
            }
            keyframes += usize::from(out.new_keyframe);
            inliers += u64::from(out.stats.inliers);
        }
        // The first frame only builds the initial keyframe (allocations happen there).
        let mode = if use_map { "SGM map (SGM time excluded)" } else { "sparse stereo" };
        for (clock, samples) in [("wall", &times_ms), ("thread CPU", &cpu_ms)] {
            if samples.len() < 2 {
                continue;
            }
            let mut sorted: Vec<f64> = samples[1..].to_vec();
            sorted.sort_by(f64::total_cmp);
            println!(
                "process, {mode}, {clock}: median {:.2} ms, p95 {:.2} ms, max {:.2} ms",
                percentile_ms(&sorted, 0.5),
                percentile_ms(&sorted, 0.95),
                sorted[sorted.len() - 1],
            );
        }
        println!("  ({keyframes} keyframes, mean inliers {:.0})", inliers as f64 / frames.len() as f64);
    }
}
