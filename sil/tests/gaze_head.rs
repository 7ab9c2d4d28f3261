#![allow(clippy::unwrap_used, clippy::expect_used)]
//! The gaze loop through one robot's firmware nodes on the lockstep runner: the vision node's
//! gaze policy commands the head on `control/head`, the driver passes the commands to the
//! simulator's head, and the stereo headers then carry the angles the head really had: the
//! look down while driving, back to the look ahead, the pan sweep at the first stop. The local
//! obstacle map's hazard messages go out once a second.

use std::sync::Arc;

use msgs::HeadCommandMsg;
use onboard::lockstep::{RobotStack, STEP_NS};
use onboard::nodes::Topic;
use onboard::record::OwnedMessage;
use onboard::sensors::sensor_setup;
use sil::mission::MissionOptions;
use sil::mission::world::{mission_world, robot_config};
use sim::driver::SimSensorSource;

#[test]
fn the_gaze_policy_points_the_simulated_head_and_the_pairs_say_where_it_looked() {
    let options =
        MissionOptions { robots: 1, duration_s: 40.0, seed: 2, downscale: 4, gaze: true, ..MissionOptions::default() };
    let world = mission_world(&options).unwrap();
    let config = robot_config(&options, &world, 0).unwrap();
    assert!(config.gaze.enabled);
    let setup = sensor_setup(&config).unwrap();
    let source = SimSensorSource::new(Arc::clone(&world), 0).unwrap();
    let mut stack = RobotStack::new(&config, &setup, Box::new(source), None, None).unwrap();
    stack.bus.tap(&[Topic::HeadCommand, Topic::Stereo, Topic::Hazards]);
    let mut commands: Vec<HeadCommandMsg> = Vec::new();
    let mut headers = Vec::new();
    let mut hazard_messages = 0;
    let end_ns = (options.duration_s * 1e9) as u64;
    let mut now_ns = 0;
    while now_ns <= end_ns && !stack.driver.finished() {
        stack.step(now_ns).unwrap();
        for message in stack.bus.take_tapped() {
            match message {
                OwnedMessage::HeadCommand(c) => commands.push(c),
                OwnedMessage::Stereo(h, _) => headers.push(h),
                OwnedMessage::Hazards(h) => {
                    assert!(h.count as usize <= msgs::HAZARD_CELLS_MAX && h.cell_size_m > 0.0);
                    hazard_messages += 1;
                }
                _ => {}
            }
        }
        now_ns += STEP_NS;
    }
    let counts = stack.driver.counts();
    assert_eq!(counts.head_commands, commands.len() as u64, "every command reached the simulated head");
    assert_eq!(counts.head_commands_ignored + counts.head_command_errors, 0);
    let modes = |mode| commands.iter().filter(|c| c.mode == mode).count();
    assert!(modes(HeadCommandMsg::LOOK_DOWN) >= 3, "{commands:?}");
    assert!(modes(HeadCommandMsg::SWEEP) >= 1, "the rover stands at its first waypoint: {commands:?}");
    // The pairs' tilt reaches the look down and comes back to the look ahead; the pan sweeps.
    let tilt_max = headers.iter().map(|h| h.tilt_rad).fold(f64::MIN, f64::max);
    let pan_max = headers.iter().map(|h| h.pan_rad.abs()).fold(0.0, f64::max);
    assert!((tilt_max - 0.55).abs() < 1e-6, "highest tilt {tilt_max}");
    assert!(pan_max > 0.9, "widest pan {pan_max}");
    let down = headers.iter().filter(|h| (h.tilt_rad - 0.55).abs() < 1e-6).count();
    let ahead = headers.iter().filter(|h| (h.tilt_rad - 0.25).abs() < 1e-6).count();
    assert!(down > 10 && ahead > down, "{down} pairs looking down, {ahead} ahead of {}", headers.len());
    // Between pairs the head moves at most at its joint rate (0.8 rad/s, 0.1 s apart).
    for w in headers.windows(2) {
        let dt_s = (w[1].stamp_ns - w[0].stamp_ns) as f64 * 1e-9;
        let moved = (w[1].tilt_rad - w[0].tilt_rad).abs().max((w[1].pan_rad - w[0].pan_rad).abs());
        assert!(moved <= 0.8 * dt_s + 1e-9, "{moved} rad in {dt_s} s");
    }
    // The odometry left the look-down pairs out (the gaze's head gate) but tracked the rest.
    let vision = stack.vision.summary();
    assert!(vision.vo_skipped_head as usize >= down, "{} skipped, {down} down", vision.vo_skipped_head);
    assert!(vision.vo_frames > 100, "{vision:?}");
    assert!((35..=41).contains(&hazard_messages), "{hazard_messages} hazard messages in 40 s");
}
