#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Time of `ObstacleClassifier::classify` per 1024×508 depth image on one thread, on SGM depth
//! of frames rendered by the simulator (Moon preset, standing with a pan sweep, then driving),
//! against the 100 ms frame period of 10 Hz stereo. Depth comes from the on-board
//! `DepthPipeline`: its SGM is not timed (the FPGA computes it on the rover); the speckle filter
//! that follows it on the host is timed separately. Run: `cargo bench -p vision --bench obstacles`.

use std::sync::Arc;
use std::time::Instant;

use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
use sim::driver::SimSensorSource;
use sim::scenario::{ScenarioOptions, preset};
use sim::world::World;
use vision::obstacles::{ObstacleClassifier, ObstacleConfig, PixelLabels};
use vision::{DepthOptions, DepthPipeline};

const FRAMES: usize = 30;
const FRAME_PERIOD_MS: f64 = 100.0;

/// This thread's CPU time in ns (Linux schedstat), immune to other load; `None` elsewhere.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
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
    scenario.camera_rate_hz = 2.0;
    let world: Arc<World> = World::build(&scenario).unwrap();
    let mut source = SimSensorSource::new(Arc::clone(&world), 0).unwrap();
    let calibration = source.stereo_calibration().unwrap();
    let (w, h) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
    let mut stereo = DepthPipeline::new(&calibration, DepthOptions { threads: 2, ..DepthOptions::default() }).unwrap();
    let mut frame = StereoFrame::default();
    let mut inputs = Vec::new();
    while inputs.len() < FRAMES {
        match hal::sensor::next_event_with_frame(&mut source, &mut frame).unwrap() {
            Some(SensorEvent::Stereo(_)) => {
                inputs.push((frame.left.clone(), frame.right.clone(), world.t_world_cam(0, frame.stamp_ns).unwrap()));
            }
            Some(_) => {}
            None => break,
        }
    }
    let mut classifier = ObstacleClassifier::new(ObstacleConfig::default()).unwrap();
    let mut labels = PixelLabels::default();
    let (mut wall_ms, mut cpu_ms, mut speckle_ms) = (Vec::new(), Vec::new(), Vec::new());
    // Two passes; the first pass's first call sizes the buffers, the second pass allocates nothing.
    for pass in 0..2 {
        for (left, right, t_world_cam) in &inputs {
            let depth_stats = stereo.compute(left, right).unwrap();
            if pass == 1 {
                speckle_ms.push(depth_stats.speckle_ms);
            }
            let (start, cpu_start) = (Instant::now(), thread_cpu_ns());
            let stats = classifier.classify(stereo.depth(), stereo.geometry(), t_world_cam, &mut labels);
            std::hint::black_box(stats);
            if pass == 1 {
                wall_ms.push(start.elapsed().as_secs_f64() * 1e3);
                if let (Some(a), Some(b)) = (cpu_start, thread_cpu_ns()) {
                    cpu_ms.push(b.saturating_sub(a) as f64 * 1e-6);
                }
            }
        }
    }
    println!("obstacle classification bench: {} depth images {w}x{h}, one thread", inputs.len());
    for (clock, samples) in [
        ("classify, wall", &mut wall_ms),
        ("classify, thread CPU", &mut cpu_ms),
        ("speckle filter, wall", &mut speckle_ms),
    ] {
        if samples.is_empty() {
            continue;
        }
        samples.sort_by(f64::total_cmp);
        let median = samples[samples.len() / 2];
        let p95 = samples[((samples.len() - 1) as f64 * 0.95).round() as usize];
        println!(
            "{clock}: median {median:.2} ms, p95 {p95:.2} ms, max {:.2} ms; median / {FRAME_PERIOD_MS} ms frame period = {:.3}",
            samples[samples.len() - 1],
            median / FRAME_PERIOD_MS
        );
    }
}
