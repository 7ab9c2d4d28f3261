//! Shared by the sim tests and examples: a Moon rover's firmware nodes (driver on the simulator,
//! vision, filter, mapper: [`RobotStack`], as in a mission) on the lockstep runner, the filter's
//! trajectory chained across its frame switches, scored against the simulator's ground truth.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use nalgebra::{Isometry3, Matrix3, Vector3};
use onboard::config::RoverConfig;
use onboard::lockstep::{OwnedMessage, RobotStack, STEP_NS};
use onboard::nodes::Topic;
use onboard::nodes::filter::FilterNodeSummary;
use onboard::nodes::vision::VisionNodeSummary;
use onboard::sensors::sensor_setup;
use sil::sim_source::{SimDriverConfig, configure_sim_robot};
use sim::driver::SimSensorSource;
use sim::world::World;

/// A one-rover Moon world and the settings that rebuild it.
#[derive(Debug, Clone)]
pub struct SimWorld {
    pub world: Arc<World>,
    pub sim: SimDriverConfig,
    pub duration_s: f64,
}

/// A one-rover Moon world of `duration_s`. `pause_s` shortens the stands at the waypoints (the
/// first stand must stay ≥ 0.5 s for the at-rest initialization); the preset plans its route
/// for 6 s stands, so a short run is planned over `4 × duration_s` and cut, to drive most of it.
pub fn moon_world(seed: u64, duration_s: f64, downscale: u32, pause_s: Option<f64>) -> SimWorld {
    let sim = SimDriverConfig {
        scenario: "moon".into(),
        seed,
        robots: 1,
        downscale,
        pause_s,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    SimWorld { world: sim.world(duration_s).expect("world"), sim, duration_s }
}

/// The rover's firmware configuration in `world` (the simulated IMU's noise, the site's gravity,
/// the head's calibration), with or without wheel odometry.
pub fn sim_config(world: &SimWorld, use_wheel: bool) -> RoverConfig {
    let mut config = RoverConfig::default();
    configure_sim_robot(&mut config, &world.sim, &world.world.scenario, world.duration_s).expect("sim robot");
    config.filter.use_wheel = use_wheel;
    config
}

/// What one run measured.
#[derive(Debug, Clone)]
pub struct SimRun {
    pub filter: FilterNodeSummary,
    pub vision: VisionNodeSummary,
    /// Handler time of vision and filter over the run (s).
    pub vision_s: f64,
    pub filter_s: f64,
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

/// Runs the rover of `world` with `config`. With `init_truth` the filter starts at the true pose
/// and velocity (the first local frame is the world frame) and NEES is sampled every
/// `nees_period_ns`. The trajectory is every running filter state, chained into the first local
/// frame across the frame switches the mapper asked for.
pub fn run(
    world: &SimWorld,
    config: RoverConfig,
    init_truth: bool,
    nees_period_ns: Option<u64>,
) -> Result<SimRun, String> {
    let setup = sensor_setup(&config).map_err(|e| e.to_string())?;
    let source = SimSensorSource::new(Arc::clone(&world.world), 0).map_err(|e| e.to_string())?;
    let mut stack = RobotStack::new(&config, &setup, Box::new(source), None, None).map_err(|e| e.to_string())?;
    if init_truth {
        let truth = world.world.robot_state(0, 0).expect("truth at 0");
        stack.filter.initialize_with_pose(0, &truth.t_world_body, &truth.v_world_mps).map_err(|e| e.to_string())?;
    }
    stack.bus.tap(&[Topic::FilterState, Topic::FrameSwitch]);
    let mut t_first_local = Isometry3::identity();
    let (mut stamps_ns, mut poses) = (Vec::new(), Vec::new());
    let (mut nees_position, mut nees_orientation) = (Vec::new(), Vec::new());
    let mut next_check_ns = nees_period_ns.unwrap_or(u64::MAX);
    let mut now_ns = 0;
    loop {
        for message in stack.bus.take_tapped() {
            match message {
                OwnedMessage::FrameSwitch(s) => t_first_local *= s.t_old_new.to_isometry().expect("switch"),
                OwnedMessage::FilterState(s) if s.status == msgs::FilterStateMsg::RUNNING => {
                    let pose = t_first_local * s.t_local_body.to_isometry().expect("state");
                    if stamps_ns.last() == Some(&s.stamp_ns) {
                        *poses.last_mut().expect("a pose") = pose;
                    } else {
                        stamps_ns.push(s.stamp_ns);
                        poses.push(pose);
                    }
                }
                _ => {}
            }
        }
        if let Some(state) = stack.filter.filter().state()
            && state.stamp_ns >= next_check_ns
        {
            next_check_ns += nees_period_ns.unwrap_or(u64::MAX);
            let t_true = world.world.robot_state(0, state.stamp_ns).expect("truth").t_world_body;
            let t_est = t_first_local * state.t_local_body;
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
        if stack.driver.finished() {
            break;
        }
        stack.step(now_ns).map_err(|e| e.to_string())?;
        now_ns += STEP_NS;
    }
    stack.finish(now_ns).map_err(|e| e.to_string())?;
    let gt: Vec<Isometry3<f64>> =
        stamps_ns.iter().map(|&s| world.world.robot_state(0, s).expect("truth").t_world_body).collect();
    let (Some(gt_first), Some(est_first)) = (gt.first(), poses.first()) else {
        return Err("no output".to_owned());
    };
    let t_gt_est = gt_first * est_first.inverse();
    let est: Vec<Isometry3<f64>> = poses.iter().map(|p| t_gt_est * p).collect();
    let distance_m = gt.windows(2).map(|w| (w[1].translation.vector - w[0].translation.vector).norm()).sum();
    let (last_gt, last_est) = (gt[gt.len() - 1], est[est.len() - 1]);
    let seconds = |i: usize| stack.times.seconds.get(i).copied().unwrap_or(0.0);
    Ok(SimRun {
        filter: stack.filter.summary(),
        vision: stack.vision.summary(),
        vision_s: seconds(1),
        filter_s: seconds(2),
        stamps_ns,
        final_error_m: (last_gt.translation.vector - last_est.translation.vector).norm(),
        final_rotation_error_deg: (last_gt.rotation.inverse() * last_est.rotation).angle().to_degrees(),
        est,
        gt,
        distance_m,
        nees_position,
        nees_orientation,
    })
}
