//! A long Moon-analogue traverse (issue 7: at least 150 m) through the rover's firmware nodes on
//! the simulator: the filter alone (VO + IMU), with and without wheel odometry; prints the
//! final position error in % of the distance driven and the final orientation error.
//!
//! `cargo run --release -p sil --example sim_traverse -- [--duration S] [--downscale N] [--seed N]`

#[path = "../tests/common/sim_run.rs"]
mod sim_run;

fn arg(name: &str, default: f64) -> f64 {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let duration_s = arg("--duration", 900.0);
    let downscale = arg("--downscale", 2.0) as u32;
    let seed = arg("--seed", 1.0) as u64;
    let world = sim_run::moon_world(seed, duration_s, downscale, None);
    let (w, h) = {
        let c = world.world.robots[0].model().camera;
        (c.width_px, c.height_px)
    };
    println!("Moon preset, seed {seed}, {duration_s} s, {w}x{h} (downscale {downscale})");
    for use_wheel in [true, false] {
        let start = std::time::Instant::now();
        let run = sim_run::run(&world, sim_run::sim_config(&world, use_wheel), false, None)?;
        let s = &run.filter;
        let frames = run.vision.frames.max(1) as f64;
        println!(
            "{:<18} driven {:7.1} m  final error {:6.3} m = {:5.2} %  orientation {:5.2}°  \
             (VO {} / {} rejected, wheel {} / {}, ZUPT {}, resets {}, vision {:.1} ms/frame, filter {:.1} ms/s, \
             wall {:.0} s)",
            if use_wheel { "VO + IMU + wheels" } else { "VO + IMU" },
            run.distance_m,
            run.final_error_m,
            run.drift_percent(),
            run.final_rotation_error_deg,
            s.vo_updates_applied,
            s.vo_updates_rejected,
            s.wheel_updates_applied,
            s.wheel_updates_rejected,
            s.zupt_updates_applied,
            run.vision.vo_resets,
            run.vision_s * 1e3 / frames,
            run.filter_s * 1e3 / world.duration_s,
            start.elapsed().as_secs_f64()
        );
        let v = &run.vision;
        println!(
            "{:<18} frame switches {} (requests ignored {}), VO late {} / missing clone {} / skipped {}; \
             vision priors {} used, {} without the capture's state, {} without the keyframe's pose, \
             switches missed {}",
            "",
            s.frame_switches,
            s.switch_requests_ignored,
            s.vo_late,
            s.vo_updates_missing_clone,
            s.vo_updates_skipped,
            v.priors_used,
            v.prior_state_missing,
            v.prior_keyframe_missing,
            v.frame_switches_missed
        );
    }
    Ok(())
}
