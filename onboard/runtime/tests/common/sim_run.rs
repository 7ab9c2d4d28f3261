//! Shared by the sim tests and examples: a Moon rover run through the VIO pipeline, straight on
//! `SimSensorSource` (no files), scored against the simulator's ground truth.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
use nalgebra::{Isometry3, Matrix3, Vector3};
use onboard::vio::{VioError, VioOptions, VioPipeline, VioSummary};
use sim::driver::SimSensorSource;
use sim::scenario::{self, ScenarioOptions};
use sim::world::World;

/// A one-rover Moon world of `duration_s`. `pause_s` shortens the stands at the waypoints (the
/// first stand must stay ≥ 0.5 s for the at-rest initialization); the preset plans its route
/// for 6 s stands, so a short run is planned over `4 × duration_s` and cut, to drive most of it.
pub fn moon_world(seed: u64, duration_s: f64, downscale: u32, pause_s: Option<f64>) -> Arc<World> {
    let plan_s = if pause_s.is_some() { 4.0 * duration_s } else { duration_s };
    let options = ScenarioOptions { robots: 1, duration_s: plan_s, seed, downscale, world_size_m: None, flyer: false };
    let mut scenario = scenario::preset("moon", &options).expect("moon preset");
    scenario.duration_s = duration_s;
    if let Some(pause_s) = pause_s {
        for robot in &mut scenario.robots {
            robot.drive.pause_s = pause_s;
        }
    }
    World::build(&scenario).expect("world")
}

/// Filter tuning for the simulated IMU and the site's gravity (the library's one copy).
pub fn sim_options(world: &World, use_wheel: bool) -> VioOptions {
    onboard::team_record::sim_vio_options(world, use_wheel)
}

/// What one run measured.
#[derive(Debug, Clone)]
pub struct SimRun {
    pub summary: VioSummary,
    pub stamps_ns: Vec<u64>,
    /// Estimate anchored at the first ground-truth pose, and the ground truth.
    pub est: Vec<Isometry3<f64>>,
    pub gt: Vec<Isometry3<f64>>,
    pub distance_m: f64,
    pub final_error_m: f64,
    pub final_rotation_error_deg: f64,
    /// Per-check NEES of position and orientation (3 DoF each), when sampled.
    pub nees_position: Vec<f64>,
    pub nees_orientation: Vec<f64>,
}

impl SimRun {
    pub fn drift_percent(&self) -> f64 {
        100.0 * self.final_error_m / self.distance_m.max(1e-9)
    }
}

/// Runs robot 0 of `world` through the pipeline. With `init_truth` the filter starts at the
/// true pose and velocity (the first local frame is the world frame) and NEES is sampled every
/// `nees_period_ns`.
pub fn run(
    world: &Arc<World>,
    options: VioOptions,
    init_truth: bool,
    nees_period_ns: Option<u64>,
) -> Result<SimRun, VioError> {
    let mut source = SimSensorSource::new(Arc::clone(world), 0)?;
    let calibration = source.stereo_calibration().expect("sim cameras");
    let mut pipeline = VioPipeline::new(&calibration, options)?;
    if init_truth {
        let truth = source.ground_truth(0).expect("truth at 0");
        pipeline.initialize_with_pose(0, &truth.state.t_world_body, &truth.state.v_world_mps)?;
    }
    let mut frame = StereoFrame::default();
    let (mut nees_position, mut nees_orientation) = (Vec::new(), Vec::new());
    let mut next_check_ns = nees_period_ns.unwrap_or(u64::MAX);
    while let Some(event) = source.next_event(&mut frame)? {
        pipeline.process_event(&event, &frame)?;
        if let SensorEvent::Imu(sample) = event
            && sample.stamp_ns >= next_check_ns
            && let Some(state) = pipeline.filter().and_then(|f| f.state())
        {
            next_check_ns += nees_period_ns.unwrap_or(u64::MAX);
            let truth = source.ground_truth(state.stamp_ns).expect("truth");
            let t_true = truth.state.t_world_body;
            let t_est = pipeline.t_first_local() * state.t_local_body;
            let e_p = t_true.translation.vector - t_est.translation.vector;
            // Orientation error in the filter's convention (global error): R_true = Exp(δθ) · R̂.
            let e_r = (t_true.rotation * t_est.rotation.inverse()).scaled_axis();
            let p_pp: Matrix3<f64> = state.covariance.fixed_view::<3, 3>(0, 0).into();
            let p_rr: Matrix3<f64> = state.covariance.fixed_view::<3, 3>(6, 6).into();
            let nees = |e: &Vector3<f64>, p: &Matrix3<f64>| p.try_inverse().map(|inv| (e.transpose() * inv * e)[0]);
            if let (Some(np), Some(nr)) = (nees(&e_p, &p_pp), nees(&e_r, &p_rr)) {
                nees_position.push(np);
                nees_orientation.push(nr);
            }
        }
    }
    let summary = pipeline.finish();
    let (stamps, poses) = pipeline.trajectory();
    let gt: Vec<Isometry3<f64>> =
        stamps.iter().map(|&s| source.ground_truth(s).expect("truth").state.t_world_body).collect();
    let (Some(gt_first), Some(est_first)) = (gt.first(), poses.first()) else {
        return Err(VioError::Input("no output".to_owned()));
    };
    let t_gt_est = gt_first * est_first.inverse();
    let est: Vec<Isometry3<f64>> = poses.iter().map(|p| t_gt_est * p).collect();
    let distance_m = gt.windows(2).map(|w| (w[1].translation.vector - w[0].translation.vector).norm()).sum();
    let (last_gt, last_est) = (gt[gt.len() - 1], est[est.len() - 1]);
    Ok(SimRun {
        summary,
        stamps_ns: stamps.to_vec(),
        final_error_m: (last_gt.translation.vector - last_est.translation.vector).norm(),
        final_rotation_error_deg: (last_gt.rotation.inverse() * last_est.rotation).angle().to_degrees(),
        est,
        gt,
        distance_m,
        nees_position,
        nees_orientation,
    })
}
