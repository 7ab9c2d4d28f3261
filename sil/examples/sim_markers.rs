//! Robot detections as the mission's robots make them (issue 25): every robot of a 2-robot
//! mission world renders its stereo pairs along its route (the simulator's driver, the frames the
//! firmware gets); the firmware's detector runs on each left image and every tag gets a pose
//! and a covariance from each of the five uncertainty models (thesis Tab. 8.3). Each detection
//! is compared with the simulator's true marker pose in the camera: count, distance range,
//! position and rotation error, and the NEES of each model (6 DoF, `eᵀ Σ⁻¹ e`; a consistent
//! model averages 6, a conservative one less).
//!
//! Also timed, one thread: the detector per frame and the pose with each model per tag (the
//! online sampling, 256 extra PnP solutions, runs for every model: it feeds the 75° gate).
//!
//! `cargo run --release -p sil --example sim_markers -- [--seeds N] [--duration S] [--downscale K]`

use std::path::PathBuf;
use std::time::Instant;

use hal::sensor::{SensorEvent, SensorSource};
use nalgebra::{Matrix6, Vector6};
use sil::mission::MissionOptions;
use sil::mission::world::mission_world;
use sil::sim_source::sim_marker_lut;
use sim::driver::SimSensorSource;
use vision::ImageView;
use vision::apriltag::{TagDetector, TagDetectorConfig};
use vision::marker_pose::{MarkerLut, UncertaintyModel, estimate_marker_pose, pose_error};

fn arg(name: &str, default: f64) -> f64 {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

#[derive(Default)]
struct Tally {
    nees: Vec<f64>,
    gated: usize,
}

fn median(values: &mut [f64]) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[values.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let seeds = arg("--seeds", 5.0) as u64;
    let duration_s = arg("--duration", 120.0);
    let downscale = arg("--downscale", 2.0) as u32;
    let mut detector = TagDetector::new(TagDetectorConfig::default())?;
    let (mut frames, mut missed_ids) = (0usize, 0usize);
    let (mut distances, mut position_errors, mut rotation_errors_deg) = (Vec::new(), Vec::new(), Vec::new());
    let mut tallies: Vec<(UncertaintyModel, Tally)> =
        UncertaintyModel::ALL.iter().map(|m| (*m, Tally::default())).collect();
    let mut lut: Option<MarkerLut> = None;
    let (mut detect_s, mut pose_s, mut poses) = (0.0, 0.0, 0usize);
    for seed in 1..=seeds {
        let options = MissionOptions { robots: 2, duration_s, seed, downscale, ..MissionOptions::default() };
        let world = mission_world(&options)?;
        for robot in 0..2 {
            let mut source = SimSensorSource::new(world.clone(), robot)?;
            let calibration = source.stereo_calibration().ok_or("no camera")?;
            let (width, height) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
            if lut.is_none() {
                let path: PathBuf =
                    sim_marker_lut(width as u32, height as u32, 0.16).ok_or("no table for this camera")?;
                lut = Some(MarkerLut::decode(&std::fs::read(&path)?)?);
            }
            let (mut left, mut right) = (vec![0u8; width * height], vec![0u8; width * height]);
            while let Some(event) = source.next_event()? {
                let SensorEvent::Stereo(info) = event else { continue };
                source.read_stereo(&mut left, &mut right)?;
                frames += 1;
                let Some(state) = world.robot_state(robot, info.stamp_ns) else { continue };
                let t_world_cam = state.t_world_body * calibration.t_body_left(info.pan_rad, info.tilt_rad);
                let markers: Vec<_> =
                    (0..2).filter(|&r| r != robot).flat_map(|r| world.marker_poses_world(r, info.stamp_ns)).collect();
                let view = ImageView::new(width, height, &left).ok_or("image size")?;
                let start = Instant::now();
                let detections = detector.detect(view).to_vec();
                detect_s += start.elapsed().as_secs_f64();
                for detection in &detections {
                    let Some((_, t_world_marker)) = markers.iter().find(|(id, _)| *id == detection.id) else {
                        missed_ids += 1;
                        continue;
                    };
                    let truth = t_world_cam.inverse() * t_world_marker;
                    let mut first = true;
                    for (model, tally) in &mut tallies {
                        let start = Instant::now();
                        let pose = estimate_marker_pose(
                            &detection.corners_px,
                            &calibration.left.intrinsics,
                            0.16,
                            *model,
                            lut.as_ref(),
                        )?;
                        pose_s += start.elapsed().as_secs_f64();
                        poses += 1;
                        if !pose.gate_passed {
                            tally.gated += 1;
                            continue;
                        }
                        let e = Vector6::from(pose_error(&pose.t_cam_marker, &truth));
                        let covariance: Matrix6<f64> = pose.covariance();
                        let Some(information) = covariance.try_inverse() else { continue };
                        tally.nees.push((e.transpose() * information * e)[(0, 0)]);
                        if first {
                            first = false;
                            distances.push(truth.translation.vector.norm());
                            position_errors.push(e.fixed_rows::<3>(0).norm());
                            rotation_errors_deg.push(e.fixed_rows::<3>(3).norm().to_degrees());
                        }
                    }
                }
            }
        }
        println!("seed {seed}: {frames} frames so far, {} detections", distances.len());
    }
    let (near, far) = distances.iter().fold((f64::INFINITY, 0.0f64), |(a, b), d| (a.min(*d), b.max(*d)));
    println!(
        "\n{seeds} seeds × 2 robots × {duration_s} s at downscale {downscale}: {frames} frames, {} detections of the \
         other robot's markers ({missed_ids} of tags the other robot does not carry), distance {near:.2}–{far:.2} m",
        distances.len()
    );
    println!(
        "error of the chosen pose: position median {:.3} m, p90 {:.3} m; rotation median {:.2}°, p90 {:.2}°",
        median(&mut position_errors.clone()),
        {
            position_errors.sort_by(f64::total_cmp);
            position_errors.get(position_errors.len() * 9 / 10).copied().unwrap_or(f64::NAN)
        },
        median(&mut rotation_errors_deg.clone()),
        {
            rotation_errors_deg.sort_by(f64::total_cmp);
            rotation_errors_deg.get(rotation_errors_deg.len() * 9 / 10).copied().unwrap_or(f64::NAN)
        },
    );
    println!(
        "time: detector {:.2} ms per frame, pose + sampling + model {:.2} ms per tag",
        1e3 * detect_s / frames.max(1) as f64,
        1e3 * pose_s / poses.max(1) as f64
    );
    println!(
        "\n| model | detections (gated) | mean NEES (6 DoF; 6 = consistent) | median NEES | NEES > 12.59 (χ²₆ 95 %) |"
    );
    println!("|---|---|---|---|---|");
    for (model, tally) in &mut tallies {
        let n = tally.nees.len();
        let mean = tally.nees.iter().sum::<f64>() / n.max(1) as f64;
        let over = tally.nees.iter().filter(|v| **v > 12.59).count();
        println!(
            "| {} | {n} ({}) | {mean:.2} | {:.2} | {:.1} % |",
            model.name(),
            tally.gated,
            median(&mut tally.nees),
            100.0 * over as f64 / n.max(1) as f64
        );
    }
    Ok(())
}
