//! Time to integrate one full-resolution (1024×508) depth image into a submap (cloud + octree)
//! on one core, against the 100 ms frame period of 10 Hz stereo.
//!
//! Depth is the simulator's rendered true depth along a Moon rover drive (downscale 1), so the
//! image content (ground from ~1 m to the horizon, sky, rocks) is what the rover sees.
//!
//! Run: `cargo bench -p mapper --bench integrate`
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;
use std::time::Instant;

use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
use mapper::integrate::{DepthIntegrator, IntegratorConfig};
use mapper::submap::Submap;
use nalgebra::{Isometry3, Matrix6};
use sim::driver::SimSensorSource;
use sim::scenario::{self, ScenarioOptions};
use sim::world::World;
use vision::depth::{DepthImage, StereoGeometry};

const FRAME_PERIOD_S: f64 = 0.1;

fn main() {
    let frames_wanted = 12;
    let options = ScenarioOptions {
        robots: 1,
        duration_s: 60.0,
        seed: 3,
        downscale: 1,
        world_size_m: None,
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    let mut scenario = scenario::preset("moon", &options).expect("moon preset");
    scenario.duration_s = 20.0;
    for robot in &mut scenario.robots {
        robot.drive.pause_s = 0.6;
    }
    let world: Arc<World> = World::build(&scenario).expect("world");
    let mut source = SimSensorSource::new(Arc::clone(&world), 0).expect("source");
    let calibration = source.stereo_calibration().expect("cameras");
    let geometry = StereoGeometry::from_calibration(&calibration);
    let (w, h) = (calibration.left.width_px as usize, calibration.left.height_px as usize);

    // Every 15th frame (1.5 s, ~0.45 m of driving) from 2 s on.
    let mut frames: Vec<(DepthImage, Vec<u8>, Isometry3<f64>)> = Vec::new();
    let mut frame = StereoFrame::default();
    let mut t_first_world: Option<Isometry3<f64>> = None;
    while frames.len() < frames_wanted {
        let Some(event) = hal::sensor::next_event_with_frame(&mut source, &mut frame).expect("event") else { break };
        if !matches!(event, SensorEvent::Stereo(_))
            || frame.stamp_ns < 2_000_000_000
            || !frame.sequence.is_multiple_of(15)
        {
            continue;
        }
        let t_world_cam = world.t_world_cam(0, frame.stamp_ns).expect("pose");
        let t_first = *t_first_world.get_or_insert_with(|| t_world_cam.inverse());
        let depth = DepthImage { width: w, height: h, depth_m: source.last_depth_m().to_vec() };
        frames.push((depth, frame.left.clone(), t_first * t_world_cam));
    }
    println!("integrate: {} frames of {w}x{h} true depth (moon, seed 3), one core", frames.len());
    println!(
        "{:>14} {:>10} {:>10} {:>9} {:>11} {:>10} {:>8}",
        "ray_pixel_step", "ms/frame", "max ms", "ratio", "cloud pts", "octree", "occ"
    );
    for step in [1usize, 2, 4] {
        let config = IntegratorConfig { ray_pixel_step: step, ..IntegratorConfig::default() };
        let mut integrator = DepthIntegrator::new(config, geometry);
        // Warm-up pass (allocations), then the timed pass into a fresh submap.
        for pass in 0..2 {
            let mut submap = Submap::new(0, pass, 0, Isometry3::identity(), Matrix6::zeros());
            let mut times = Vec::new();
            for (depth, grey, t_submap_cam) in &frames {
                let start = Instant::now();
                let stats = integrator.integrate(&mut submap, depth, None, Some(grey), t_submap_cam);
                times.push(start.elapsed().as_secs_f64());
                std::hint::black_box(stats);
            }
            if pass == 1 {
                let mean = times.iter().sum::<f64>() / times.len() as f64;
                let max = times.iter().copied().fold(0.0, f64::max);
                println!(
                    "{step:>14} {:>10.1} {:>10.1} {:>9.3} {:>11} {:>10} {:>8}",
                    mean * 1e3,
                    max * 1e3,
                    mean / FRAME_PERIOD_S,
                    submap.cloud.len(),
                    submap.occupancy.len(),
                    submap.occupancy.occupied_count()
                );
            }
        }
    }
    println!("ratio = mean time per frame / 100 ms frame period (10 Hz stereo); < 1 keeps up");
}
