#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Worlds, robots, motion, the sensor driver and the radio model, on small worlds at low
//! resolution.

use std::sync::Arc;

use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
use nalgebra::{Isometry3, Point3, Vector3};
use sim::driver::SimSensorSource;
use sim::markers::{TAG_CELLS, tag_cells};
use sim::motion::{PhaseKind, ROVER_ACCEL_MPS2, flyer_ground_height, wheel_contact_plane};
use sim::radio::{Endpoint, connectivity, link_config};
use sim::robot::{FLYER_REST_HEIGHT_M, ROVER_CHASSIS_HEIGHT_M, ROVER_HALF_LENGTH_M, ROVER_HALF_WIDTH_M};
use sim::scenario::{Scenario, ScenarioOptions, preset};
use sim::terrain::Terrain;
use sim::world::{MAX_TRAVERSABLE_ROCK_M, World, segment_distance};

fn options(seed: u64, robots: usize, duration_s: f64, world_size_m: f64) -> ScenarioOptions {
    ScenarioOptions {
        robots,
        duration_s,
        seed,
        downscale: 4,
        world_size_m: Some(world_size_m),
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    }
}

/// Sets robot `i`'s waypoints (x, y).
fn set_route(scenario: &mut Scenario, i: usize, route: &[[f64; 2]]) {
    scenario.robots[i].waypoints_m = route.iter().map(|p| [p[0], p[1], 0.0]).collect();
}

/// Everything a source emits over the run, as bytes (f64 as bit patterns), in order.
fn event_bytes(world: &Arc<World>, robot: usize) -> Vec<u8> {
    let mut source = SimSensorSource::new(world.clone(), robot).unwrap();
    let mut frame = StereoFrame::default();
    let mut out = Vec::new();
    let put = |out: &mut Vec<u8>, v: &[f64]| v.iter().for_each(|x| out.extend_from_slice(&x.to_bits().to_le_bytes()));
    while let Some(event) = hal::sensor::next_event_with_frame(&mut source, &mut frame).unwrap() {
        match event {
            SensorEvent::Imu(s) => {
                out.push(0);
                out.extend_from_slice(&s.stamp_ns.to_le_bytes());
                put(&mut out, s.gyro_radps.as_slice());
                put(&mut out, s.accel_mps2.as_slice());
            }
            SensorEvent::WheelOdom(s) => {
                out.push(1);
                out.extend_from_slice(&s.stamp_ns.to_le_bytes());
                put(&mut out, s.linear_mps.as_slice());
                put(&mut out, s.angular_radps.as_slice());
                put(&mut out, &s.sigma);
            }
            SensorEvent::Stereo(_) => {
                out.push(2);
                out.extend_from_slice(&frame.stamp_ns.to_le_bytes());
                out.extend_from_slice(&frame.left);
                out.extend_from_slice(&frame.right);
            }
        }
    }
    out
}

/// Smallest distance, over the run sampled every 0.1 s, between robot `i`'s centre and the edge
/// of a rock taller than the traversable limit or of a ditch.
fn obstacle_clearance_m(world: &World, i: usize) -> f64 {
    let mut clearance = f64::MAX;
    let mut t_ns = 0;
    while t_ns <= world.end_ns() {
        let p = world.robot_state(i, t_ns).unwrap().t_world_body.translation.vector;
        for rock in world.terrain.rocks.iter().filter(|r| r.height_m > MAX_TRAVERSABLE_ROCK_M) {
            clearance = clearance.min((p.x - rock.base_m.x).hypot(p.y - rock.base_m.y) - rock.radius_m);
        }
        for ditch in &world.terrain.ditches {
            clearance = clearance.min(segment_distance([p.x, p.y], ditch.start_m, ditch.end_m) - 0.5 * ditch.width_m);
        }
        t_ns += 100_000_000;
    }
    clearance
}

#[test]
fn same_seed_gives_identical_event_streams() {
    let make = |seed: u64| {
        let mut s = preset("moon", &options(seed, 2, 3.0, 50.0)).unwrap();
        // A short first stand, so the rover is driving for most of the three seconds.
        for r in &mut s.robots {
            r.drive.pause_s = 0.5;
        }
        World::build(&s).unwrap()
    };
    let a = event_bytes(&make(11), 1);
    let b = event_bytes(&make(11), 1);
    assert!(a.len() > 3 * 10 * 2 * 256 * 127, "{} bytes", a.len());
    assert!(a == b, "streams of the same seed differ");
    let c = event_bytes(&make(12), 1);
    assert_eq!(a.len(), c.len());
    assert!(a != c, "another seed gives the same stream");
}

#[test]
fn events_come_in_order_at_their_rates() {
    let s = preset("mars", &ScenarioOptions { flyer: true, ..options(3, 2, 2.0, 50.0) }).unwrap();
    let world = World::build(&s).unwrap();
    for (robot, wheel_rate) in [(0, 50), (2, 0)] {
        let mut source = SimSensorSource::new(world.clone(), robot).unwrap();
        let calibration = source.stereo_calibration().unwrap();
        assert_eq!((calibration.left.width_px, calibration.left.height_px), (256, 127));
        let mut frame = StereoFrame::default();
        let mut counts = [[0u32; 3]; 2];
        let mut last = (0u64, 0usize);
        let mut sequence = 0;
        while let Some(event) = hal::sensor::next_event_with_frame(&mut source, &mut frame).unwrap() {
            let (stamp, kind) = match event {
                SensorEvent::Imu(s) => (s.stamp_ns, 0),
                SensorEvent::WheelOdom(s) => (s.stamp_ns, 1),
                SensorEvent::Stereo(_) => (frame.stamp_ns, 2),
            };
            assert!(stamp < world.end_ns());
            assert!((stamp, kind) > last || (stamp, kind) == (0, 0), "{last:?} then {:?}", (stamp, kind));
            last = (stamp, kind);
            assert_eq!(stamp % 5_000_000, 0, "off the IMU grid");
            counts[(stamp / 1_000_000_000) as usize][kind] += 1;
            if kind == 2 {
                assert_eq!(frame.sequence, sequence);
                sequence += 1;
                assert_eq!((frame.width_px, frame.height_px, frame.left.len()), (256, 127, 256 * 127));
                assert_eq!((frame.pan_rad, frame.tilt_rad), world.head_angles(robot, stamp));
                assert_eq!(source.last_depth_m().len(), 256 * 127);
            }
            let truth = source.ground_truth(stamp).unwrap();
            assert_eq!(truth.state, world.robot_state(robot, stamp).unwrap());
        }
        assert_eq!(counts, [[200, wheel_rate, 10]; 2], "robot {robot}");
    }
}

#[test]
fn rovers_drive_on_the_ground_around_obstacles() {
    for (name, seed) in [("moon", 5), ("mars", 6)] {
        let s = preset(name, &options(seed, 3, 240.0, 60.0)).unwrap();
        let world = World::build(&s).unwrap();
        let hf = &world.terrain.heightfield;
        // No part of the footprint may touch an obstacle, whatever the heading.
        let half_diagonal = ROVER_HALF_LENGTH_M.hypot(ROVER_HALF_WIDTH_M);
        let mut worst = (f64::MAX, 0.0f64, 0.0f64, 0.0f64);
        let mut driving_samples = 0;
        for (i, robot) in world.robots.iter().enumerate() {
            assert!(robot.setup.waypoints_m.len() >= 4, "{name} robot {i}: {:?}", robot.setup.waypoints_m);
            assert!(robot.trajectory.end_ns() >= world.end_ns());
            worst.0 = worst.0.min(obstacle_clearance_m(&world, i));
            let mut t_ns = 0;
            while t_ns <= world.end_ns() {
                let state = world.robot_state(i, t_ns).unwrap();
                let p = state.t_world_body.translation.vector;
                let [roll, pitch, yaw] = [state.euler_rad.x, state.euler_rad.y, state.euler_rad.z];
                let plane = wheel_contact_plane(hf, p.x, p.y, yaw).unwrap();
                let (plane_roll, plane_pitch) = plane.roll_pitch_rad();
                worst.1 = worst.1.max((p.z - plane.height_m - ROVER_CHASSIS_HEIGHT_M).abs());
                worst.2 = worst.2.max((roll - plane_roll).abs());
                worst.3 = worst.3.max((pitch - plane_pitch).abs());
                // Speed: exact within the straight part of a leg and zero while standing, away
                // from the half second the spline needs to blend one phase into the next.
                let t = t_ns as f64 * 1e-9;
                let phase = *robot.plan.phase_at(t).unwrap();
                let inside = t > phase.start_s + 0.3 && t < phase.end_s - 0.3;
                let speed = state.v_world_mps.xy().norm();
                match phase.kind {
                    PhaseKind::Stand if inside || t > robot.plan.end_s() + 0.3 => {
                        assert!(state.v_world_mps.norm() < 1e-9 && state.omega_body_radps.norm() < 1e-9, "{speed}");
                    }
                    PhaseKind::Drive if inside => {
                        let cruise = phase.end_s - phase.start_s - 2.0 * robot.setup.drive.speed_mps / ROVER_ACCEL_MPS2;
                        let ramp = robot.setup.drive.speed_mps / ROVER_ACCEL_MPS2 + 0.3;
                        if cruise > 0.0 && t > phase.start_s + ramp && t < phase.end_s - ramp {
                            assert!((speed - robot.setup.drive.speed_mps).abs() < 1e-9, "{name} {i} at {t}: {speed}");
                            driving_samples += 1;
                        }
                        assert!(speed <= robot.setup.drive.speed_mps + 1e-9);
                    }
                    _ => {}
                }
                t_ns += 100_000_000;
            }
        }
        eprintln!(
            "{name}: clearance {:.3} m, |dz| {:.4} m, |droll| {:.4} rad, |dpitch| {:.4} rad, {driving_samples} cruise samples",
            worst.0, worst.1, worst.2, worst.3
        );
        assert!(driving_samples > 1000);
        assert!(worst.0 > half_diagonal, "{name}: footprint reaches an obstacle ({:.3} m)", worst.0);
        // The spline blends six control points (0.5 s, 15 cm of travel over 5 cm terrain cells):
        // it may round off the contact pose a little, by much less than a wheel's radius or a
        // degree.
        assert!(worst.1 < 0.01 && worst.2 < 0.02 && worst.3 < 0.02, "{name}: off the ground {worst:?}");
    }
}

#[test]
fn a_rover_sees_the_other_rovers_tag_where_it_projects() {
    let mut s = preset("moon", &ScenarioOptions { downscale: 2, ..options(21, 2, 1.0, 50.0) }).unwrap();
    // Robot 0 looks east at robot 1, three metres away and facing it.
    set_route(&mut s, 0, &[[-3.0, 0.0], [5.0, 0.0]]);
    set_route(&mut s, 1, &[[0.0, 0.0], [-5.0, 0.0]]);
    let world = World::build(&s).unwrap();
    let mut source = SimSensorSource::new(world.clone(), 0).unwrap();
    let mut frame = StereoFrame::default();
    while !matches!(hal::sensor::next_event_with_frame(&mut source, &mut frame).unwrap(), Some(SensorEvent::Stereo(_)))
    {
    }
    assert_eq!(frame.stamp_ns, 0);

    let camera = world.robots[0].model().camera;
    let t_cam_world = world.t_world_cam(0, 0).unwrap().inverse();
    let (tag_id, t_world_marker) = world.marker_poses_world(1, 0)[0];
    assert_eq!(tag_id, 3);
    let marker = world.robots[1].model().markers[0];
    // The tag faces the camera.
    let normal_cam = (t_cam_world * t_world_marker).rotation * Vector3::z();
    assert!(normal_cam.z < -0.8, "{normal_cam:?}");

    let pixel = |p_marker: Point3<f64>| {
        let p_cam = t_cam_world * (t_world_marker * p_marker);
        let (u, v) = camera.project(&p_cam.coords).unwrap();
        let (u, v) = (u.round() as usize, v.round() as usize);
        assert!(u < camera.width_px as usize && v < camera.height_px as usize);
        (v * camera.width_px as usize + u, p_cam.z)
    };
    // Nothing in front of the tag: the depth at its centre is the tag's.
    let (centre, depth) = pixel(Point3::origin());
    assert!(
        (f64::from(source.last_depth_m()[centre]) - depth).abs() < 0.02,
        "{} vs {depth}",
        source.last_depth_m()[centre]
    );
    // Cells are about 3.4 px here: the pixel nearest a cell's centre sees only that cell.
    let cells = tag_cells(marker.code);
    let (mut black_max, mut white_min) = (0u8, 255u8);
    for (row, line) in cells.iter().enumerate().take(TAG_CELLS) {
        for (col, &white) in line.iter().enumerate() {
            let value = frame.left[pixel(marker.cell_centre_marker_m(col, row)).0];
            if white {
                white_min = white_min.min(value);
            } else {
                black_max = black_max.max(value);
            }
        }
    }
    eprintln!("tag cells: black up to {black_max}, white from {white_min}");
    assert!(i32::from(white_min) - i32::from(black_max) > 20, "black up to {black_max}, white from {white_min}");
}

#[test]
fn radio_links_follow_range_and_line_of_sight() {
    let mut s = preset("moon", &options(31, 2, 40.0, 60.0)).unwrap();
    // Robot 0 stays; robot 1 drives away east.
    set_route(&mut s, 0, &[[-3.0, 0.0], [-3.5, 0.0]]);
    set_route(&mut s, 1, &[[3.0, 0.0], [20.0, 0.0]]);
    s.radio.max_range_m = 12.0;
    s.radio.full_quality_range_m = 8.0;
    let world = World::build(&s).unwrap();
    let (a, b) = (Endpoint::Robot(0), Endpoint::Robot(1));
    assert!(connectivity(&world, a, b, 0));
    assert!(connectivity(&world, a, Endpoint::GroundStation, 0));
    assert!(!connectivity(&world, a, b, world.end_ns()), "the robots end 23 m apart");

    let config = link_config(&world, a, b);
    let down = |t_ms: u64| config.outages.iter().any(|&(start, end)| (start..end).contains(&t_ms));
    let mut seen = [false; 2];
    for k in 0..40u64 {
        let up = connectivity(&world, a, b, k * 1_000_000_000);
        seen[usize::from(up)] = true;
        assert_eq!(down(k * 1000), !up, "second {k}");
        assert_eq!(down(k * 1000 + 999), !up, "second {k}");
    }
    assert_eq!(seen, [true, true]);
    // Up samples reach beyond the full-quality range: more loss than the base link.
    assert!(config.loss > s.radio.base.loss && config.loss < 1.0);
    let reverse = link_config(&world, b, a);
    assert_eq!(reverse.outages, config.outages);
    assert_ne!(reverse.seed, config.seed);

    // Behind a hill: a 5 m wall between the robots cuts the link at the start, unless line of
    // sight is not required.
    let mut walled = Arc::try_unwrap(world).unwrap();
    let hf = &mut walled.terrain.heightfield;
    for row in 0..hf.rows {
        for col in 0..hf.cols {
            let x = hf.origin_m[0] + col as f64 * hf.resolution_m;
            if x.abs() < 0.5 {
                hf.heights_m[row * hf.cols + col] += 5.0;
            }
        }
    }
    assert!(!connectivity(&walled, a, b, 0));
    walled.scenario.radio.require_line_of_sight = false;
    assert!(connectivity(&walled, a, b, 0));
}

#[test]
fn head_sweeps_smoothly_while_standing() {
    let s = preset("moon", &options(41, 1, 30.0, 50.0)).unwrap();
    let world = World::build(&s).unwrap();
    let robot = &world.robots[0];
    let tilt = robot.setup.tilt_rad;
    let mut previous = world.head_angles(0, 0);
    let mut max_pan: f64 = 0.0;
    let step_ns = 10_000_000;
    let mut t_ns = step_ns;
    while t_ns <= world.end_ns() {
        let (pan, t) = world.head_angles(0, t_ns);
        assert_eq!(t, tilt);
        // Rate limit and continuity: the pan never moves faster than the sweep allows.
        assert!(
            (pan - previous.0).abs() <= sim::world::PAN_RATE_MAX_RADPS * 0.01 * (1.0 + 1e-9),
            "at {t_ns}: {pan} after {}",
            previous.0
        );
        let phase = robot.plan.phase_at(t_ns as f64 * 1e-9).unwrap();
        if phase.kind != PhaseKind::Stand {
            assert_eq!(pan, 0.0);
        }
        max_pan = max_pan.max(pan.abs());
        previous = (pan, t);
        t_ns += step_ns;
    }
    assert!(max_pan > 0.3, "{max_pan}");
    // The camera follows the head.
    let t_ns = 2_000_000_000;
    let (pan, tilt) = world.head_angles(0, t_ns);
    let expected: Isometry3<f64> =
        world.robot_state(0, t_ns).unwrap().t_world_body * robot.model().t_body_cam(pan, tilt);
    assert!((world.t_world_cam(0, t_ns).unwrap().translation.vector - expected.translation.vector).norm() < 1e-12);
}

#[test]
fn paths_through_obstacles_are_repaired() {
    // A terrain with a ditch well inside (so there is a way around it) and a tall rock.
    let (mut s, rock, ditch) = (1..20)
        .find_map(|seed| {
            let s = preset("mars", &options(seed, 1, 900.0, 60.0)).unwrap();
            let terrain = Terrain::generate(&s.terrain, s.seed);
            let inside = |p: [f64; 2]| p[0].abs() < 20.0 && p[1].abs() < 20.0;
            let ditch = *terrain.ditches.iter().find(|d| inside(d.start_m) && inside(d.end_m))?;
            let rock = *terrain
                .rocks
                .iter()
                .find(|r| r.height_m > MAX_TRAVERSABLE_ROCK_M && inside([r.base_m.x, r.base_m.y]))?;
            Some((s, rock, ditch))
        })
        .expect("a terrain with a ditch and a tall rock inside");
    // Straight through the rock, then straight across the ditch's middle.
    let start = [s.robots[0].waypoints_m[0][0], s.robots[0].waypoints_m[0][1]];
    let to_rock = [rock.base_m.x - start[0], rock.base_m.y - start[1]];
    let d = to_rock[0].hypot(to_rock[1]);
    let beyond_rock = [rock.base_m.x + 3.0 * to_rock[0] / d, rock.base_m.y + 3.0 * to_rock[1] / d];
    let mid = [0.5 * (ditch.start_m[0] + ditch.end_m[0]), 0.5 * (ditch.start_m[1] + ditch.end_m[1])];
    let along = [ditch.end_m[0] - ditch.start_m[0], ditch.end_m[1] - ditch.start_m[1]];
    let normal = [-along[1] / along[0].hypot(along[1]), along[0] / along[0].hypot(along[1])];
    let side = |k: f64| [mid[0] + k * normal[0], mid[1] + k * normal[1]];
    let route = [start, beyond_rock, side(-3.0), side(3.0)];
    set_route(&mut s, 0, &route);
    let world = World::build(&s).unwrap();
    let repaired = &world.robots[0].setup.waypoints_m;
    assert!(repaired.len() > route.len(), "no detour: {repaired:?}");
    let half_diagonal = ROVER_HALF_LENGTH_M.hypot(ROVER_HALF_WIDTH_M);
    let clearance = obstacle_clearance_m(&world, 0);
    eprintln!("repaired {} waypoints into {}, clearance {clearance:.3} m", route.len(), repaired.len());
    assert!(clearance > half_diagonal, "{clearance}");
    // The rover did get to the far side of the ditch.
    let end = world.robot_state(0, world.end_ns()).unwrap().t_world_body.translation.vector;
    let offset = (end.x - mid[0]) * normal[0] + (end.y - mid[1]) * normal[1];
    assert!(offset > 1.0, "ends {offset} m from the ditch's line");
}

#[test]
fn the_flyer_takes_off_cruises_tilted_into_its_acceleration_and_lands() {
    let s = preset("mars", &ScenarioOptions { flyer: true, ..options(51, 1, 150.0, 60.0) }).unwrap();
    let world = World::build(&s).unwrap();
    let flyer = &world.robots[1];
    let hf = &world.terrain.heightfield;
    let g = s.body.gravity_mps2();
    let height_above_reference = |t_ns: u64| {
        let p = world.robot_state(1, t_ns).unwrap().t_world_body.translation.vector;
        p.z - flyer_ground_height(hf, p.x, p.y).unwrap() - FLYER_REST_HEIGHT_M
    };
    // Standing on the ground at both ends of the run.
    for t_ns in [0, world.end_ns()] {
        let state = world.robot_state(1, t_ns).unwrap();
        assert!(height_above_reference(t_ns).abs() < 1e-9 && state.v_world_mps.norm() < 1e-9, "at {t_ns}");
    }
    let (mut worst_height, mut worst_heading, mut worst_thrust, mut max_tilt) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    let mut t_ns = 0;
    while t_ns <= world.end_ns() {
        let t = t_ns as f64 * 1e-9;
        let state = world.robot_state(1, t_ns).unwrap();
        let phase = *flyer.plan.phase_at(t).unwrap();
        if phase.kind == PhaseKind::Drive && t > phase.start_s + 0.3 && t < phase.end_s - 0.3 {
            // Cruising: between the two waypoints' heights above the ground, heading along the leg.
            let h = height_above_reference(t_ns);
            let (lo, hi) = (phase.from[2].min(phase.to[2]), phase.from[2].max(phase.to[2]));
            worst_height = worst_height.max(lo - h).max(h - hi);
            let v = state.v_world_mps;
            if v.xy().norm() > 0.3 {
                let heading = v.y.atan2(v.x);
                worst_heading = worst_heading.max(sim::motion::wrap_angle(heading - state.euler_rad.z).abs());
            }
        }
        // The body's z axis points along the thrust, a − g.
        let thrust = state.a_world_mps2 + Vector3::new(0.0, 0.0, g);
        let z_body = state.t_world_body.rotation * Vector3::z();
        worst_thrust = worst_thrust.max(z_body.angle(&thrust));
        max_tilt = max_tilt.max(z_body.angle(&Vector3::z()));
        t_ns += 50_000_000;
    }
    eprintln!(
        "flyer: height off by {worst_height:.4} m, heading off by {worst_heading:.2e} rad, body z off the thrust by {worst_thrust:.4} rad, tilt up to {max_tilt:.3} rad"
    );
    // The ground reference changes along the leg, and the spline blends half a second of it.
    assert!(worst_height < 0.05, "{worst_height}");
    assert!(worst_heading < 1e-6, "{worst_heading}");
    // Tilt control points come from second differences of the position control points. The spline
    // smooths the acceleration with a cubic kernel but the tilt with a quintic one, so the two
    // disagree while an acceleration switches on or off, by a small fraction of the tilt.
    assert!(worst_thrust < 0.1 * max_tilt, "{worst_thrust} of {max_tilt}");
    assert!(max_tilt > 0.05 && max_tilt < (2.0 * 0.5 / g).atan(), "{max_tilt}");
}
