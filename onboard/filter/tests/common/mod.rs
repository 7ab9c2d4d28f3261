//! Shared simulation for the filter tests: a rover-like spline trajectory on the Moon, the
//! simulator's IMU model, and keyframe VO deltas drawn from ground truth.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use filter::{Filter, FilterConfig, ImuNoise, InitialSigmas, RelativePoseMeasurement};
use nalgebra::{Isometry3, Matrix6, UnitQuaternion, Vector3};
use sim::imu::ImuSimulator;
use sim::rng::Rng;
use sim::trajectory::Trajectory;

pub const MOON_G: f64 = 1.62;
pub const IMU_RATE_HZ: f64 = 200.0;
pub const IMU_PERIOD_NS: u64 = 5_000_000;
pub const CAMERA_PERIOD_NS: u64 = 100_000_000;
pub const KEYFRAME_EVERY: u64 = 10;
pub const VO_DELAY_NS: u64 = 250_000_000;
pub const START_NS: u64 = 1_000_000_000;

/// A rover drive: ~0.4 m/s, heading wandering by a few degrees per second, ±3° roll/pitch and
/// ±0.2 m height from the terrain. Knots every second.
pub fn rover_trajectory(seed: u64, duration_s: f64) -> Trajectory {
    let mut rng = Rng::new(seed ^ 0x5eed_0f7a_1ec7);
    let n = duration_s.ceil() as usize + 6;
    let (mut x, mut y, mut yaw) = (0.0, 0.0, rng.range(-3.0, 3.0));
    let mut points = Vec::with_capacity(n);
    for _ in 0..n {
        let speed = 0.4 + 0.1 * rng.normal();
        yaw += 0.08 * rng.normal();
        x += speed * f64::cos(yaw);
        y += speed * f64::sin(yaw);
        let z = 0.1 * rng.normal();
        let roll = 0.05 * rng.normal();
        let pitch = 0.05 * rng.normal();
        points.push([x, y, z, roll, pitch, yaw]);
    }
    Trajectory::new(START_NS, 1.0, points).unwrap()
}

pub fn sim_noise() -> sim::imu::ImuNoise {
    sim::imu::ImuNoise::xsens_mti10()
}

/// The filter's view of the simulator's IMU noise (the same model, so the filter is "tuned right").
pub fn filter_config() -> FilterConfig {
    let n = sim_noise();
    let imu = ImuNoise {
        gyro_noise_density: n.gyro_noise_density_radps_rthz,
        gyro_random_walk: n.gyro_bias_rw_radps2_rthz,
        accel_noise_density: n.accel_noise_density_mps2_rthz,
        accel_random_walk: n.accel_bias_rw_mps3_rthz,
    };
    let mut config = FilterConfig::from_imu_noise(imu, MOON_G);
    config.initial = InitialSigmas {
        position_m: 0.0,
        velocity_mps: 0.01,
        roll_pitch_rad: 0.2_f64.to_radians(),
        yaw_rad: 0.0,
        accel_bias_mps2: n.accel_bias_init_mps2,
        gyro_bias_radps: n.gyro_bias_init_radps,
    };
    config
}

/// VO noise: 3 mm + 0.5 % of the motion per translation axis, 0.1° per rotation axis (a good
/// keyframe stereo odometry over ≤ 1 s of rover motion).
pub fn vo_covariance(t_from_to: &Isometry3<f64>) -> Matrix6<f64> {
    let st = 0.003 + 0.005 * t_from_to.translation.vector.norm();
    let sr = 0.1_f64.to_radians();
    Matrix6::from_diagonal(&nalgebra::Vector6::new(st * st, st * st, st * st, sr * sr, sr * sr, sr * sr))
}

/// `truth ⊞ n` with `n ~ N(0, Σ)` (diagonal Σ), in the `[δt; δθ]` convention.
pub fn noisy(truth: &Isometry3<f64>, cov: &Matrix6<f64>, rng: &mut Rng) -> Isometry3<f64> {
    let n: Vec<f64> = (0..6).map(|i| cov[(i, i)].sqrt() * rng.normal()).collect();
    let t = truth.translation.vector + Vector3::new(n[0], n[1], n[2]);
    let r = truth.rotation * UnitQuaternion::from_scaled_axis(Vector3::new(n[3], n[4], n[5]));
    Isometry3::from_parts(t.into(), r)
}

/// One simulated run, stepped sample by sample.
pub struct SimRun {
    pub trajectory: Trajectory,
    pub imu: ImuSimulator,
    pub filter: Filter,
    pub rng: Rng,
    pub stamp_ns: u64,
    pub frame: u64,
    /// Capture stamps of the frames and whether each is a keyframe.
    pub last_keyframe_ns: u64,
    /// Measurements waiting for their delivery time: (deliver at, measurement, is keyframe).
    pub pending: Vec<(u64, RelativePoseMeasurement, bool)>,
    pub applied: usize,
    pub vo_enabled: bool,
    pub delay_ns: u64,
}

impl SimRun {
    pub fn new(seed: u64, duration_s: f64) -> SimRun {
        let trajectory = rover_trajectory(seed, duration_s);
        let imu = ImuSimulator::new(sim_noise(), Vector3::new(0.0, 0.0, -MOON_G), IMU_RATE_HZ, seed);
        let config = filter_config();
        let mut rng = Rng::new(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 17);
        let s0 = trajectory.state_at(START_NS).unwrap();
        // Initial state drawn from the initial covariance (roll, pitch, velocity; the biases are
        // drawn by the IMU simulator around the filter's zero).
        let rp = config.initial.roll_pitch_rad;
        let tilt = UnitQuaternion::from_euler_angles(rp * rng.normal(), rp * rng.normal(), 0.0);
        let (r, p, y) = s0.t_world_body.rotation.euler_angles();
        let (dr, dp, _) = tilt.euler_angles();
        let start_pose =
            Isometry3::from_parts(s0.t_world_body.translation, UnitQuaternion::from_euler_angles(r + dr, p + dp, y));
        let v0 = s0.v_world_mps + rng.normal3() * config.initial.velocity_mps;
        let mut filter = Filter::new(config);
        filter.initialize_with_pose(START_NS, &start_pose, &v0).unwrap();
        SimRun {
            trajectory,
            imu,
            filter,
            rng,
            stamp_ns: START_NS,
            frame: 0,
            last_keyframe_ns: START_NS,
            pending: Vec::new(),
            applied: 0,
            vo_enabled: true,
            delay_ns: VO_DELAY_NS,
        }
    }

    pub fn truth(&self, stamp_ns: u64) -> Isometry3<f64> {
        self.trajectory.state_at(stamp_ns).unwrap().t_world_body
    }

    pub fn end_ns(&self) -> u64 {
        self.trajectory.end_ns()
    }

    /// One IMU period: the sample, the camera trigger (clone) if due, and due VO deltas.
    pub fn step(&mut self) {
        let state = self.trajectory.state_at(self.stamp_ns).unwrap();
        let sample = self.imu.sample(&state, self.stamp_ns);
        self.filter.propagate(&sample).unwrap();
        if self.vo_enabled && (self.stamp_ns - START_NS).is_multiple_of(CAMERA_PERIOD_NS) {
            self.trigger();
        }
        self.deliver_due();
        self.stamp_ns += IMU_PERIOD_NS;
    }

    fn trigger(&mut self) {
        let t = self.stamp_ns;
        self.filter.clone_at(t).unwrap();
        if self.frame == 0 {
            // The first frame is the first keyframe; nothing to measure yet.
            self.filter.mark_keyframe(t);
        } else {
            let truth = self.truth(self.last_keyframe_ns).inverse() * self.truth(t);
            let cov = vo_covariance(&truth);
            let z = noisy(&truth, &cov, &mut self.rng);
            let m = RelativePoseMeasurement {
                from_stamp_ns: self.last_keyframe_ns,
                to_stamp_ns: t,
                t_from_to: z,
                covariance: cov,
            };
            let keyframe = self.frame.is_multiple_of(KEYFRAME_EVERY);
            self.pending.push((t + self.delay_ns, m, keyframe));
            if keyframe {
                self.last_keyframe_ns = t;
            }
        }
        self.frame += 1;
    }

    fn deliver_due(&mut self) {
        while let Some(&(due, m, keyframe)) = self.pending.first() {
            if due > self.stamp_ns {
                break;
            }
            self.pending.remove(0);
            if keyframe {
                self.filter.mark_keyframe(m.to_stamp_ns);
            }
            self.filter.update_relative_pose(&m).unwrap();
            self.applied += 1;
        }
    }

    pub fn run_until(&mut self, stamp_ns: u64) {
        while self.stamp_ns <= stamp_ns {
            self.step();
        }
    }
}

/// Position and orientation NEES of the current state against the truth (global attitude error).
pub fn nees(filter: &Filter, truth: &Isometry3<f64>) -> (f64, f64) {
    let s = filter.state().unwrap();
    let ep = truth.translation.vector - s.t_local_body.translation.vector;
    let et = (truth.rotation * s.t_local_body.rotation.inverse()).scaled_axis();
    let pp = s.covariance.fixed_view::<3, 3>(0, 0).into_owned();
    let pt = s.covariance.fixed_view::<3, 3>(6, 6).into_owned();
    let np = ep.dot(&(pp.try_inverse().unwrap() * ep));
    let nt = et.dot(&(pt.try_inverse().unwrap() * et));
    (np, nt)
}
