#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Checks of the ground-truth loop-closure source (test/evaluation only; see the module docs).

use std::sync::Arc;

use nalgebra::{Isometry3, Matrix6, Point3, Vector3, Vector6};
use sim::scenario::{ScenarioOptions, preset};
use sim::se3::log as se3_log;
use sim::truth_constraints::{SubmapSpan, TruthConstraintConfig, TruthConstraints, TruthDetection};
use sim::world::World;

const S: u64 = 1_000_000_000;

/// Two rovers starting on the ring 6 m apart, 120 s (a 60 m site keeps the build fast; the
/// robots' paths stay within a few metres of the hub in 120 s anyway).
fn world() -> Arc<World> {
    let options =
        ScenarioOptions { robots: 2, duration_s: 120.0, seed: 1, world_size_m: Some(60.0), ..Default::default() };
    World::build(&preset("moon", &options).unwrap()).unwrap()
}

fn frame_stamps(world: &World) -> Vec<u64> {
    let period_ns = (1e9 / world.scenario.camera_rate_hz).round() as u64;
    (0..).map(|k| k * period_ns).take_while(|t| *t < world.end_ns()).collect()
}

fn noise_free() -> TruthConstraintConfig {
    TruthConstraintConfig {
        detection_sigma_base: [0.0; 6],
        match_sigma_translation_m: 0.0,
        match_sigma_yaw_rad: 0.0,
        match_sigma_roll_pitch_rad: 0.0,
        match_success_probability: 1.0,
        outlier_probability: 0.0,
        ..Default::default()
    }
}

fn all_detections(tc: &mut TruthConstraints, stamps: &[u64]) -> Vec<TruthDetection> {
    let mut out = Vec::new();
    for &t in stamps {
        for observer in 0..2 {
            out.extend(tc.detections_at(observer, t));
        }
    }
    out
}

fn t_true(world: &World, d: &TruthDetection) -> Isometry3<f64> {
    let a = world.robot_state(d.observer, d.stamp_ns).unwrap().t_world_body;
    let b = world.robot_state(d.observed, d.stamp_ns).unwrap().t_world_body;
    a.inverse() * b
}

fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let e = a.inverse() * b;
    e.translation.vector.norm() + e.rotation.angle()
}

#[test]
fn noise_free_detections_are_the_true_body_to_body_transform() {
    let world = world();
    let stamps = frame_stamps(&world);
    let config = TruthConstraintConfig { min_detection_interval_s: 0.0, ..noise_free() };
    let mut tc = TruthConstraints::new(world.clone(), config);
    let detections = all_detections(&mut tc, &stamps);
    let per_observer = [0, 1].map(|o| detections.iter().filter(|d| d.observer == o).count());
    println!("noise-free detections per observer over {} frames: {per_observer:?}", stamps.len());
    assert!(per_observer.iter().all(|n| *n > 20), "{per_observer:?}");
    let mut worst = 0.0f64;
    for d in &detections {
        assert_ne!(d.observer, d.observed);
        assert_eq!(d.tag_id / 3, d.observed as u32, "tag ids are 3·robot + k");
        worst = worst.max(pose_error(&d.t_observer_observed, &t_true(&world, d)));
        assert!(d.covariance.iter().all(|c| *c == 0.0));
        assert!(d.distance_m <= 7.0 && d.view_angle_rad <= 60f64.to_radians());
        // The reported distance is the marker's range from the observer's left camera.
        let cam = world.t_world_cam(d.observer, d.stamp_ns).unwrap();
        let (_, marker) =
            world.marker_poses_world(d.observed, d.stamp_ns).into_iter().find(|(id, _)| *id == d.tag_id).unwrap();
        assert!(((marker.translation.vector - cam.translation.vector).norm() - d.distance_m).abs() < 1e-9);
    }
    println!("largest noise-free error (m + rad): {worst:.2e}");
    assert!(worst < 1e-9);
}

/// The first detection (with the default, rate-limited config) over the run.
fn first_detection(world: &Arc<World>) -> TruthDetection {
    let mut tc = TruthConstraints::new(world.clone(), TruthConstraintConfig::default());
    all_detections(&mut tc, &frame_stamps(world)).into_iter().next().unwrap()
}

#[test]
fn detection_noise_matches_its_covariance() {
    let world = world();
    let d0 = first_detection(&world);
    let marker = world.robots[d0.observed].model().markers.iter().find(|m| m.tag_id == d0.tag_id).copied().unwrap();
    let (pan, tilt) = world.head_angles(d0.observer, d0.stamp_ns);
    let t_body_cam = world.robots[d0.observer].model().t_body_cam(pan, tilt);
    let truth = t_true(&world, &d0);
    let t_cam_marker = t_body_cam.inverse() * truth * marker.t_body_marker;
    let n = 2000;
    let mut nees_sum = 0.0;
    // Error of the implied marker pose in the camera's axes: centre offset and rotation vector.
    let mut sq_cam = Vector6::<f64>::zeros();
    for seed in 0..n {
        let config = TruthConstraintConfig { seed: 1000 + seed, ..Default::default() };
        let mut tc = TruthConstraints::new(world.clone(), config);
        let d = tc.detections_at(d0.observer, d0.stamp_ns).into_iter().find(|d| d.tag_id == d0.tag_id).unwrap();
        let delta = se3_log(&(truth.inverse() * d.t_observer_observed));
        nees_sum += (delta.transpose() * d.covariance.try_inverse().unwrap() * delta)[0];
        let measured = t_body_cam.inverse() * d.t_observer_observed * marker.t_body_marker;
        let dt = measured.translation.vector - t_cam_marker.translation.vector;
        let dr = (measured.rotation * t_cam_marker.rotation.inverse()).scaled_axis();
        sq_cam += Vector6::new(dt.x, dt.y, dt.z, dr.x, dr.y, dr.z).map(|v| v * v);
    }
    let nees = nees_sum / n as f64;
    // NEES of exactly Gaussian 6D noise is χ²₆: mean 6, variance 12, so the mean of 2000 draws
    // has a standard error of √(12/2000) = 0.077; 4 standard errors.
    let bound = 4.0 * (12.0 / n as f64).sqrt();
    println!("detection at {:.2} m: mean NEES over {n} draws {nees:.3} (6 ± {bound:.3})", d0.distance_m);
    assert!((nees - 6.0).abs() < bound, "NEES {nees}");
    // The model's meaning: in the camera's axes, σ = Σ_constant's σ · (1 + d) per DoF. The sample
    // standard deviation of n Gaussian draws has a relative standard error 1/√(2n) = 1.6 %; 5
    // standard errors. (The rotation error is exactly the drawn vector; the centre offset is
    // J(δφ)·δt, whose σ exceeds that of δt by about σ_φ²/4 = 0.5 % at this distance.)
    let expected =
        [0.01, 0.01, 0.01, 5e-4f64.sqrt(), 5e-4f64.sqrt(), 5e-4f64.sqrt()].map(|s| s * (1.0 + d0.distance_m));
    for i in 0..6 {
        let std = (sq_cam[i] / n as f64).sqrt();
        println!("camera-axis DoF {i}: sample σ {std:.5}, model {:.5}", expected[i]);
        assert!((std / expected[i] - 1.0).abs() < 5.0 / (2.0 * n as f64).sqrt(), "DoF {i}: {std} vs {}", expected[i]);
    }
}

#[test]
fn hidden_or_far_markers_are_not_detected_and_the_rate_limit_holds() {
    let world = world();
    let stamps = frame_stamps(&world);
    let all_config = TruthConstraintConfig { min_detection_interval_s: 0.0, ..noise_free() };
    let all = all_detections(&mut TruthConstraints::new(world.clone(), all_config), &stamps);

    // Facing away: at every detection stamp, the observed robot's markers not reported all face
    // more than 60° away from the camera or fall outside the image (here: face away, the markers
    // point 120° apart).
    let mut away = 0;
    for d in &all {
        let cam = world.t_world_cam(d.observer, d.stamp_ns).unwrap();
        for (id, marker) in world.marker_poses_world(d.observed, d.stamp_ns) {
            if all.iter().any(|e| e.stamp_ns == d.stamp_ns && e.observer == d.observer && e.tag_id == id) {
                continue;
            }
            let to_cam = (cam.translation.vector - marker.translation.vector).normalize();
            let angle = (marker.rotation * Vector3::z()).dot(&to_cam).acos();
            assert!(angle > 60f64.to_radians(), "tag {id} at {:.1}°", angle.to_degrees());
            away += 1;
        }
    }
    assert!(away > 0);

    // Beyond range and beyond the view-angle limit.
    let d0 = all[0];
    let at = |config: TruthConstraintConfig| {
        TruthConstraints::new(world.clone(), config)
            .detections_at(d0.observer, d0.stamp_ns)
            .into_iter()
            .any(|d| d.tag_id == d0.tag_id)
    };
    assert!(at(TruthConstraintConfig { max_detection_range_m: d0.distance_m + 1e-6, ..all_config }));
    assert!(!at(TruthConstraintConfig { max_detection_range_m: d0.distance_m - 1e-6, ..all_config }));
    assert!(at(TruthConstraintConfig { max_view_angle_rad: d0.view_angle_rad + 1e-6, ..all_config }));
    assert!(!at(TruthConstraintConfig { max_view_angle_rad: d0.view_angle_rad - 1e-6, ..all_config }));

    // Rate limit: per pair, stamps of consecutive detections are equal or ≥ 10 s apart, and the
    // limit does suppress frames that would have given detections.
    let limited = all_detections(&mut TruthConstraints::new(world.clone(), TruthConstraintConfig::default()), &stamps);
    for pair in [(0, 1), (1, 0)] {
        let of_pair: Vec<u64> =
            limited.iter().filter(|d| (d.observer, d.observed) == pair).map(|d| d.stamp_ns).collect();
        let unlimited = all.iter().filter(|d| (d.observer, d.observed) == pair).count();
        println!("pair {pair:?}: {} rate-limited detections, {unlimited} without the limit", of_pair.len());
        assert!(!of_pair.is_empty() && of_pair.len() < unlimited);
        for w in of_pair.windows(2) {
            assert!(w[1] == w[0] || w[1] - w[0] >= 10 * S, "{w:?}");
        }
    }
}

#[test]
fn a_terrain_bump_in_the_line_of_sight_hides_the_marker() {
    let world = world();
    let d0 = first_detection(&world);
    let cam = world.t_world_cam(d0.observer, d0.stamp_ns).unwrap().translation.vector;
    let (_, marker) =
        world.marker_poses_world(d0.observed, d0.stamp_ns).into_iter().find(|(id, _)| *id == d0.tag_id).unwrap();
    let mid = 0.5 * (cam + marker.translation.vector);
    let seen_with_bump = |top_above_ray_m: f64| {
        let mut w = World::build(&world.scenario).unwrap();
        let w_mut = Arc::get_mut(&mut w).unwrap();
        let hf = &mut w_mut.terrain.heightfield;
        // A 30 cm wide bump whose top is `top_above_ray_m` above the ray's midpoint.
        for row in 0..hf.rows {
            for col in 0..hf.cols {
                let [x, y] = hf.cell_centre_m(col, row);
                if (x - mid.x).hypot(y - mid.y) < 0.15 {
                    hf.heights_m[row * hf.cols + col] = (mid.z + top_above_ray_m) as f32;
                }
            }
        }
        let mut tc = TruthConstraints::new(w, TruthConstraintConfig::default());
        tc.detections_at(d0.observer, d0.stamp_ns).iter().any(|d| d.tag_id == d0.tag_id)
    };
    println!(
        "ray midpoint {:.2} m above the ground",
        mid.z - world.terrain.heightfield.height_at(mid.x, mid.y).unwrap()
    );
    assert!(seen_with_bump(-0.05), "a bump below the ray must not hide the marker");
    assert!(!seen_with_bump(0.05), "a bump above the ray must hide the marker");
}

#[test]
fn true_origin_is_gravity_aligned_at_the_body_position_and_yaw() {
    let world = world();
    let tc = TruthConstraints::new(world.clone(), TruthConstraintConfig::default());
    let mut max_tilt = 0.0f64;
    for robot in 0..2 {
        for t in (0..120).step_by(7) {
            let stamp = t * S;
            let body = world.robot_state(robot, stamp).unwrap().t_world_body;
            let origin = tc.true_origin(robot, stamp).unwrap();
            assert!((origin.rotation * Vector3::z() - Vector3::z()).norm() < 1e-12, "roll/pitch not zero");
            assert!((origin.translation.vector - body.translation.vector).norm() < 1e-12);
            // The body in the origin frame has zero z-y-x yaw: its x axis projects onto the
            // origin's x axis.
            let (roll, pitch, yaw) = (origin.inverse() * body).rotation.euler_angles();
            assert!(yaw.abs() < 1e-12, "yaw {yaw}");
            let (r0, p0, _) = body.rotation.euler_angles();
            assert!((roll - r0).abs() < 1e-12 && (pitch - p0).abs() < 1e-12);
            max_tilt = max_tilt.max(roll.abs().max(pitch.abs()));
        }
    }
    // The check means something only if the body does tilt.
    println!("largest body roll/pitch at the sampled stamps: {:.2}°", max_tilt.to_degrees());
    assert!(max_tilt > 0.5f64.to_radians());
}

fn span(robot: usize, index: u32, start_s: u64, end_s: u64) -> SubmapSpan {
    SubmapSpan { robot, index, start_ns: start_s * S, end_ns: end_s * S }
}

#[test]
fn matches_follow_the_truth_and_their_sigmas() {
    let world = world();
    // Robot 0's first submap and robot 1's fifth overlap; robot 0's last and robot 1's last do not.
    let (a, b) = (span(0, 0, 0, 20), span(1, 4, 80, 100));
    let (c, e) = (span(0, 5, 100, 120), span(1, 5, 100, 120));
    let mut tc = TruthConstraints::new(world.clone(), noise_free());
    let overlap = tc.overlap_m2(&a, &b);
    println!("overlap a-b {overlap:.2} m², c-e {:.2} m²", tc.overlap_m2(&c, &e));
    assert!(overlap >= 10.0);
    assert_eq!(tc.overlap_m2(&b, &a), overlap);
    assert!(tc.attempt_match(&c, &e).is_none());
    assert_eq!(tc.overlap_m2(&c, &e), 0.0);

    let truth = tc.true_origin(0, a.start_ns).unwrap().inverse() * tc.true_origin(1, b.start_ns).unwrap();
    let m = tc.attempt_match(&a, &b).unwrap();
    assert!(!m.outlier && pose_error(&m.t_a_b, &truth) < 1e-12);
    assert_eq!(m.overlap_m2, overlap);

    // Statistics over seeds: the error's tangent (posegraph convention) has the configured sigmas.
    let config =
        TruthConstraintConfig { match_success_probability: 1.0, outlier_probability: 0.0, ..Default::default() };
    // The documented defaults: 0.1 m, 0.3° roll/pitch, 1° yaw.
    let default_covariance = Matrix6::from_diagonal(&Vector6::from_fn(|i, _| {
        [0.1, 0.1, 0.1, 0.3f64.to_radians(), 0.3f64.to_radians(), 1f64.to_radians()][i].powi(2)
    }));
    let n = 2000;
    let mut sum = Vector6::<f64>::zeros();
    let mut sq = Vector6::<f64>::zeros();
    let mut in_band = 0;
    for seed in 0..n {
        let mut tc = TruthConstraints::new(world.clone(), TruthConstraintConfig { seed, ..config });
        let m = tc.attempt_match(&a, &b).unwrap();
        let delta = se3_log(&(truth.inverse() * m.t_a_b));
        sum += delta;
        sq += delta.map(|v| v * v);
        let err = (m.t_a_b.translation.vector - truth.translation.vector).norm();
        in_band += usize::from((0.1..=0.3).contains(&err));
        assert_eq!(m.covariance, default_covariance);
    }
    let sigma = match_sigmas(&config);
    for i in 0..6 {
        let mean = sum[i] / n as f64;
        let std = (sq[i] / n as f64).sqrt();
        println!("match DoF {i}: mean {mean:.2e}, σ {std:.4} (configured {:.4})", sigma[i]);
        // Sample mean: 4 standard errors σ/√n; sample σ: 5 relative standard errors 1/√(2n).
        assert!(mean.abs() < 4.0 * sigma[i] / (n as f64).sqrt());
        assert!((std / sigma[i] - 1.0).abs() < 5.0 / (2.0 * n as f64).sqrt());
    }
    // With σ = 0.1 m per axis the 3D error is in 0.1–0.3 m with probability P(1 ≤ χ²₃ ≤ 9) = 0.772;
    // 4 binomial standard errors.
    let share = in_band as f64 / n as f64;
    println!("3D match errors in 0.1–0.3 m: {:.1} %", 100.0 * share);
    assert!((share - 0.772).abs() < 4.0 * (0.772 * 0.228 / n as f64).sqrt());

    // Default success and outlier probabilities over seeds (binomial, 4 standard errors).
    let n = 4000;
    let (mut successes, mut outliers) = (0, 0);
    for seed in 0..n {
        let mut tc = TruthConstraints::new(world.clone(), TruthConstraintConfig { seed, ..Default::default() });
        if let Some(m) = tc.attempt_match(&a, &b) {
            successes += 1;
            if m.outlier {
                outliers += 1;
                let e = truth.inverse() * m.t_a_b;
                let (dist, yaw) = (e.translation.vector.norm(), e.rotation.angle().to_degrees());
                assert!((1.0..=3.0).contains(&dist) && (10.0..=30.0).contains(&yaw), "{dist} m, {yaw}°");
            }
        }
    }
    let p = successes as f64 / n as f64;
    let q = outliers as f64 / successes as f64;
    println!("success rate {p:.3}, outlier rate {q:.4}");
    assert!((p - 0.7).abs() < 4.0 * (0.21 / n as f64).sqrt());
    assert!((q - 0.02).abs() < 4.0 * (0.02 * 0.98 / successes as f64).sqrt());
}

/// Configured match sigmas in the tangent's order.
fn match_sigmas(c: &TruthConstraintConfig) -> [f64; 6] {
    let (t, rp, y) = (c.match_sigma_translation_m, c.match_sigma_roll_pitch_rad, c.match_sigma_yaw_rad);
    [t, t, t, rp, rp, y]
}

#[test]
fn seen_area_is_the_camera_footprint() {
    let world = world();
    let mut tc = TruthConstraints::new(world.clone(), TruthConstraintConfig::default());
    let a = span(0, 0, 0, 20);
    let seen = tc.seen_area_m2(&a);
    assert_eq!(tc.overlap_m2(&a, &a), seen);
    assert!(seen > 10.0);
    for other in [span(1, 4, 80, 100), span(1, 0, 0, 20), span(0, 2, 40, 60)] {
        assert!(tc.overlap_m2(&a, &other) <= seen.min(tc.seen_area_m2(&other)));
    }
    // One camera pose: the 0.5 m cell count against the footprint sampled every 5 cm. The
    // footprint (about 5 m², perimeter about 12 m) cuts about 24 cells, each counted whole or not
    // at all: σ ≈ √24 · 0.29 · 0.25 m² = 0.36 m²; 4σ.
    let camera = world.robots[0].model().camera;
    let hf = &world.terrain.heightfield;
    for t in [3u64, 17, 44, 71, 95] {
        let single = span(0, 100 + t as u32, t, t);
        let grid = tc.seen_area_m2(&single);
        let t_cam_world = world.t_world_cam(0, t * S).unwrap().inverse();
        let c = world.t_world_cam(0, t * S).unwrap().translation.vector;
        let mut fine = 0.0;
        let step = 0.05;
        for j in -100..=100 {
            for i in -100..=100 {
                let (x, y) = (c.x + i as f64 * step, c.y + j as f64 * step);
                let Some(z) = hf.height_at(x, y) else { continue };
                let p = t_cam_world * Point3::new(x, y, z);
                let r = p.coords.norm();
                let inside = camera.project(&p.coords).is_some_and(|(u, v)| {
                    u >= 0.0
                        && v >= 0.0
                        && u <= f64::from(camera.width_px) - 1.0
                        && v <= f64::from(camera.height_px) - 1.0
                });
                if (0.5..=5.0).contains(&r) && inside {
                    fine += step * step;
                }
            }
        }
        println!("t = {t} s: seen area {grid:.2} m² on the 0.5 m grid, {fine:.2} m² sampled at 5 cm");
        assert!((grid - fine).abs() < 1.44, "{grid} vs {fine}");
    }
}
