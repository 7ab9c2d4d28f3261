//! A synthetic team for the SLAM front-end's tests: true planar paths, filter estimates that drift
//! like a visual-inertial filter's (errors grow with distance, reset in position and yaw at each
//! frame switch), and detections and matches from the truth with the thesis's noise models.
//! No rendering: these tests are about what enters the graph, not about vision.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used)]

use mapper::slam::{FilterPose, Measurement, RobotDetection, RobotId, SubmapId, SubmapMatch, SubmapSwitch};
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};

/// A small deterministic generator (splitmix64 + Box–Muller).
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng(seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) ^ 0x5851_f42d_4c95_7f2d)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn gaussian(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

pub const STEP_NS: u64 = 100_000_000;
/// Drift per metre driven (1σ): 1 % in position, 0.3°/m in yaw (a VIO filter's order).
const DRIFT_POS_PER_M: f64 = 0.01;
const DRIFT_YAW_PER_M: f64 = 0.3 * std::f64::consts::PI / 180.0;
const ROLL_PITCH_SIGMA: f64 = 0.002;
const SUBMAP_LENGTH_M: f64 = 7.0;

fn yaw_of(q: &UnitQuaternion<f64>) -> f64 {
    q.euler_angles().2
}

fn gravity_aligned(t: &Isometry3<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(t.translation, UnitQuaternion::from_euler_angles(0.0, 0.0, yaw_of(&t.rotation)))
}

/// One robot's data.
pub struct RobotRun {
    pub robot: RobotId,
    pub stamps_ns: Vec<u64>,
    pub truth: Vec<Isometry3<f64>>,
    pub poses: Vec<FilterPose>,
    pub switches: Vec<SubmapSwitch>,
    /// True origin of every submap, by index.
    pub true_origins: Vec<Isometry3<f64>>,
}

/// A robot driving loops of `radius_m` around `centre` (with a slow drift of the loop centre so
/// later loops cover new ground), 0.3 m/s, for `steps` 10 Hz samples.
pub fn robot_run(robot: RobotId, centre: [f64; 2], radius_m: f64, phase: f64, steps: usize, seed: u64) -> RobotRun {
    let mut rng = Rng::new(seed ^ (u64::from(robot) << 32));
    let speed = 0.3;
    let dt = STEP_NS as f64 * 1e-9;
    let omega = speed / radius_m;
    let mut truth = Vec::with_capacity(steps);
    let mut stamps_ns = Vec::with_capacity(steps);
    for i in 0..steps {
        let t = i as f64 * dt;
        let a = phase + omega * t;
        let c = [centre[0] + 0.02 * t, centre[1] + 0.01 * t];
        let p = Vector3::new(c[0] + radius_m * a.cos(), c[1] + radius_m * a.sin(), 0.2 * (0.3 * t).sin());
        let yaw = a + std::f64::consts::FRAC_PI_2;
        let q = UnitQuaternion::from_euler_angles(0.02 * (0.5 * t).sin(), 0.03 * (0.4 * t).cos(), yaw);
        truth.push(Isometry3::from_parts(Translation3::from(p), q));
        stamps_ns.push(i as u64 * STEP_NS);
    }
    // The filter: the estimate in the current frame drifts by a random walk in x, y, z, yaw.
    let mut poses = Vec::with_capacity(steps);
    let mut switches = Vec::new();
    let mut true_origins = vec![gravity_aligned(&truth[0])];
    let mut origin_true = true_origins[0];
    let mut err_p = Vector3::zeros();
    let mut err_yaw = 0.0;
    let mut since_m = 0.0;
    let mut index = 0u32;
    for i in 0..steps {
        if i > 0 {
            let step_m = (truth[i].translation.vector - truth[i - 1].translation.vector).norm();
            since_m += step_m;
            err_p += Vector3::new(rng.gaussian(), rng.gaussian(), rng.gaussian()) * DRIFT_POS_PER_M * step_m.sqrt();
            err_yaw += rng.gaussian() * DRIFT_YAW_PER_M * step_m.sqrt();
        }
        let t_origin_body_true = origin_true.inverse() * truth[i];
        // Position error in the local frame, yaw error about the vertical (the filter's shape).
        let t_origin_body = Isometry3::from_parts(
            Translation3::from(t_origin_body_true.translation.vector + err_p),
            UnitQuaternion::from_euler_angles(0.0, 0.0, err_yaw) * t_origin_body_true.rotation,
        );
        let var_p = (DRIFT_POS_PER_M * DRIFT_POS_PER_M * since_m).max(0.0);
        let var_yaw = DRIFT_YAW_PER_M * DRIFT_YAW_PER_M * since_m;
        let rp = ROLL_PITCH_SIGMA * ROLL_PITCH_SIGMA;
        let covariance = Matrix6::from_diagonal(&Vector6::new(var_p, var_p, var_p, rp, rp, var_yaw));
        if since_m >= SUBMAP_LENGTH_M {
            // Frame switch: the new origin is the estimated body, gravity-aligned.
            let t_old_new = gravity_aligned(&t_origin_body);
            switches.push(SubmapSwitch {
                robot,
                stamp_ns: stamps_ns[i],
                from_index: index,
                t_old_new,
                covariance: Matrix6::from_diagonal(&Vector6::new(var_p, var_p, var_p, 1e-10, 1e-10, var_yaw)),
            });
            index += 1;
            origin_true = gravity_aligned(&truth[i]);
            true_origins.push(origin_true);
            err_p = Vector3::zeros();
            err_yaw = 0.0;
            since_m = 0.0;
            let t_origin_body = origin_true.inverse() * truth[i];
            poses.push(FilterPose {
                robot,
                stamp_ns: stamps_ns[i],
                submap_index: index,
                t_submap_body: t_origin_body,
                covariance: Matrix6::from_diagonal(&Vector6::new(0.0, 0.0, 0.0, rp, rp, 0.0)),
            });
            continue;
        }
        poses.push(FilterPose {
            robot,
            stamp_ns: stamps_ns[i],
            submap_index: index,
            t_submap_body: t_origin_body,
            covariance,
        });
    }
    RobotRun { robot, stamps_ns, truth, poses, switches, true_origins }
}

/// A pose perturbed on the right by `sigmas` (graph convention), with its covariance.
pub fn noisy(t: &Isometry3<f64>, sigmas: [f64; 6], rng: &mut Rng) -> (Isometry3<f64>, Matrix6<f64>) {
    let xi = Vector6::from_iterator(sigmas.iter().map(|s| s * rng.gaussian()));
    let delta = posegraph::se3::exp(&xi);
    let cov = Matrix6::from_diagonal(&Vector6::from_iterator(sigmas.iter().map(|s| s * s)));
    (t * delta, cov)
}

/// Detections between every pair of robots closer than 5 m, at most every 20 s per pair, with
/// the thesis's quadratic model (1 cm, 1.3° × (1 + d)).
pub fn detections(runs: &[RobotRun], seed: u64) -> Vec<RobotDetection> {
    let mut rng = Rng::new(seed ^ 0xdead_beef);
    let mut out = Vec::new();
    let mut last: std::collections::BTreeMap<(RobotId, RobotId), u64> = Default::default();
    for a in runs {
        for b in runs {
            if a.robot == b.robot {
                continue;
            }
            for i in (0..a.truth.len().min(b.truth.len())).step_by(10) {
                let d = (a.truth[i].translation.vector - b.truth[i].translation.vector).norm();
                let stamp = a.stamps_ns[i];
                if d > 5.0 || last.get(&(a.robot, b.robot)).is_some_and(|&t| stamp < t + 20_000_000_000) {
                    continue;
                }
                last.insert((a.robot, b.robot), stamp);
                let s = 1.0 + d;
                let sigmas = [0.01 * s, 0.01 * s, 0.01 * s, 0.0224 * s, 0.0224 * s, 0.0224 * s];
                let (t, cov) = noisy(&(a.truth[i].inverse() * b.truth[i]), sigmas, &mut rng);
                out.push(RobotDetection {
                    observer: a.robot,
                    observed: b.robot,
                    tag_id: 0,
                    stamp_ns: stamp,
                    t_observer_observed: t,
                    covariance: cov,
                });
            }
        }
    }
    out
}

/// Matches between every two non-consecutive submaps whose true origins are within
/// `max_distance_m` (the matcher's overlap stand-in), 8 cm and 1° per axis.
pub fn matches(runs: &[RobotRun], max_distance_m: f64, seed: u64) -> Vec<SubmapMatch> {
    let mut rng = Rng::new(seed ^ 0x0bad_cafe);
    let mut all: Vec<(SubmapId, Isometry3<f64>)> = Vec::new();
    for run in runs {
        for (i, o) in run.true_origins.iter().enumerate() {
            all.push((SubmapId::new(run.robot, i as u32), *o));
        }
    }
    let mut out = Vec::new();
    for (i, (a, ta)) in all.iter().enumerate() {
        for (b, tb) in &all[i + 1..] {
            let consecutive = a.robot == b.robot && a.index.abs_diff(b.index) <= 1;
            if consecutive || (ta.translation.vector - tb.translation.vector).norm() > max_distance_m {
                continue;
            }
            let sigmas = [0.08, 0.08, 0.08, 0.005, 0.005, 0.0175];
            let (t, cov) = noisy(&(ta.inverse() * tb), sigmas, &mut rng);
            out.push(SubmapMatch { a: *a, b: *b, t_a_b: t, covariance: cov });
        }
    }
    out
}

/// Everything a robot would receive, in time order (matches after the later submap finished).
pub fn all_measurements(
    runs: &[RobotRun],
    detections: &[RobotDetection],
    matches: &[SubmapMatch],
) -> Vec<(u64, Measurement)> {
    let mut out: Vec<(u64, Measurement)> = Vec::new();
    for run in runs {
        for p in &run.poses {
            out.push((p.stamp_ns, Measurement::FilterPose(*p)));
        }
        for s in &run.switches {
            out.push((s.stamp_ns, Measurement::SubmapSwitch(*s)));
        }
    }
    for d in detections {
        out.push((d.stamp_ns, Measurement::Detection(*d)));
    }
    let finished = |id: SubmapId| -> u64 {
        runs.iter()
            .find(|r| r.robot == id.robot)
            .and_then(|r| r.switches.get(id.index as usize))
            .map_or(u64::MAX - 1, |s| s.stamp_ns)
    };
    for m in matches {
        out.push((finished(m.a).max(finished(m.b)), Measurement::Match(*m)));
    }
    // A frame switch reaches the graph before the first filter pose of the new frame.
    out.sort_by_key(|(t, m)| (*t, !matches!(m, Measurement::SubmapSwitch(_))));
    out
}

pub fn drift_pos_per_m() -> f64 {
    DRIFT_POS_PER_M
}
