#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Trajectories, the IMU model, wheel odometry and the Allan deviation.

use std::f64::consts::{FRAC_PI_2, TAU};

use hal::sensor::ImuSample;
use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};
use sim::allan::{self, AllanError};
use sim::body::Body;
use sim::imu::{ImuNoise, ImuSimulator, bias_rw_from_stability};
use sim::trajectory::{KinematicState, Trajectory, TrajectoryError};
use sim::wheel::{STANDSTILL_MPS, STANDSTILL_RADPS, WheelOdomConfig, WheelOdometer};

const KNOT_S: f64 = 0.1;

/// A spline whose control point `i` is `f((i − 2)·Δ)`: a quintic B-spline reproduces linear
/// functions exactly with that offset, so the spline follows `f` closely over `[0, duration_s]`.
fn spline_from_fn(knot_s: f64, duration_s: f64, f: impl Fn(f64) -> [f64; 6]) -> Trajectory {
    let segments = (duration_s / knot_s).round() as usize;
    let points = (0..segments + 5).map(|i| f((i as f64 - 2.0) * knot_s)).collect();
    Trajectory::new(0, knot_s, points).unwrap()
}

fn smoothstep(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * x * (10.0 - 15.0 * x + 6.0 * x * x)
}

/// Rover speed: standstill 0–4 s, ramp up, 0.3–0.5 m/s cruise, ramp down, standstill from 53 s.
fn rover_speed_mps(t: f64) -> f64 {
    let cruise = 0.4 + 0.1 * (TAU * (t - 7.0) / 11.0).sin();
    cruise * smoothstep((t - 4.0) / 3.0) * (1.0 - smoothstep((t - 50.0) / 3.0))
}

/// A 60 s curvy rover drive; terrain shape (height, roll, pitch, heading) is a function of the
/// distance driven, so the rover stands exactly still while its speed is zero. At 0.4 m/s the
/// bumps are at 0.2–1.8 Hz, a few degrees and centimetres.
fn rover_trajectory(flat: bool) -> Trajectory {
    let duration_s = 60.0;
    let t0 = -2.0 * KNOT_S;
    let n = (duration_s / KNOT_S).round() as usize + 5;
    let sub = 100;
    let dt = KNOT_S / sub as f64;
    let (mut s, mut x, mut y) = (0.0, 0.0, 0.0);
    let heading = |s: f64| 0.8 * (TAU * s / 9.0).sin() + 0.3 * (TAU * s / 3.7).sin();
    let mut points = Vec::with_capacity(n);
    for i in 0..n {
        let t = t0 + i as f64 * KNOT_S;
        if i > 0 {
            // Midpoint-rule integration of the path; its small error only changes which smooth
            // path the spline is, not the spline's exactness.
            for k in 0..sub {
                let tm = t - KNOT_S + (k as f64 + 0.5) * dt;
                let v = rover_speed_mps(tm);
                let sm = s + 0.5 * v * dt;
                x += v * heading(sm).cos() * dt;
                y += v * heading(sm).sin() * dt;
                s += v * dt;
            }
        }
        let (z, roll, pitch) = if flat {
            (0.0, 0.0, 0.0)
        } else {
            (
                0.15 * (TAU * s / 6.0).sin() + 0.02 * (TAU * s / 0.9).sin() + 0.005 * (TAU * s / 0.25).sin(),
                0.05 * (TAU * s / 2.3 + 0.5).sin() + 0.01 * (TAU * s / 0.3).sin(),
                0.04 * (TAU * s / 1.5).sin() + 0.015 * (TAU * s / 0.22 + 1.0).sin(),
            )
        };
        points.push([x, y, 0.5 + z, roll, pitch, heading(s)]);
    }
    Trajectory::new(0, KNOT_S, points).unwrap()
}

/// A 60 s flyer: several m/s, tilts up to ~20°, continuous yaw.
fn flyer_trajectory() -> Trajectory {
    spline_from_fn(KNOT_S, 60.0, |t| {
        [
            30.0 * (0.25 * t).sin(),
            15.0 * (0.2 * t + 1.0).sin(),
            5.0 + 2.0 * (0.3 * t).sin(),
            0.3 * (0.7 * t).sin(),
            0.25 * (0.5 * t + 0.3).sin(),
            0.2 * t + 0.5 * (0.4 * t).sin(),
        ]
    })
}

fn rot_x(a: f64) -> Matrix3<f64> {
    Rotation3::from_axis_angle(&Vector3::x_axis(), a).into_inner()
}
fn rot_y(a: f64) -> Matrix3<f64> {
    Rotation3::from_axis_angle(&Vector3::y_axis(), a).into_inner()
}
fn rot_z(a: f64) -> Matrix3<f64> {
    Rotation3::from_axis_angle(&Vector3::z_axis(), a).into_inner()
}

#[test]
fn trajectory_valid_span_and_linear_reproduction() {
    // 11 control points at 0.25 s: 6 segments, valid for 1.5 s.
    let start_ns = 2_000_000_000;
    let (v, w) = (Vector3::new(0.3, -0.2, 0.05), Vector3::new(0.01, -0.02, 0.3));
    let points: Vec<[f64; 6]> = (0..11)
        .map(|i| [1.0 + v.x * i as f64, v.y * i as f64, v.z * i as f64, w.x * i as f64, w.y * i as f64, w.z * i as f64])
        .collect();
    let traj = Trajectory::new(start_ns, 0.25, points).unwrap();
    assert_eq!(traj.end_ns(), start_ns + 1_500_000_000);
    assert!((traj.duration_s() - 1.5).abs() < 1e-15);
    assert!(traj.state_at(start_ns - 1).is_none());
    assert!(traj.state_at(traj.end_ns() + 1).is_none());
    assert!(traj.state_at_s(-1e-9).is_none());
    assert!(traj.state_at_s(1.5 + 1e-9).is_none());
    for stamp_ns in [start_ns, start_ns + 250_000_000, start_ns + 777_777_777, traj.end_ns()] {
        let state = traj.state_at(stamp_ns).unwrap();
        let t = (stamp_ns - start_ns) as f64 * 1e-9;
        // Linear control points c_i = a + b·i give a + b·(2 + t/Δ) (the basis's centre is 2).
        let u = 2.0 + t / 0.25;
        let expected = Vector3::new(1.0, 0.0, 0.0) + v * u;
        assert!((state.t_world_body.translation.vector - expected).norm() < 1e-12, "t = {t}");
        assert!((state.euler_rad - w * u).norm() < 1e-12);
        assert!((state.v_world_mps - v / 0.25).norm() < 1e-12);
        assert!(state.a_world_mps2.norm() < 1e-12);
        assert!((state.euler_rate_radps - w / 0.25).norm() < 1e-12);
        let same = traj.state_at_s(t).unwrap();
        assert!((same.t_world_body.translation.vector - state.t_world_body.translation.vector).norm() < 1e-12);
    }

    assert_eq!(Trajectory::new(0, 0.1, vec![[0.0; 6]; 5]), Err(TrajectoryError::TooFewKnots(5)));
    assert_eq!(Trajectory::new(0, 0.0, vec![[0.0; 6]; 6]), Err(TrajectoryError::BadInterval(0.0)));
    let mut bad = vec![[0.0; 6]; 7];
    bad[4][2] = f64::NAN;
    assert_eq!(Trajectory::new(0, 0.1, bad), Err(TrajectoryError::NotFinite(4)));
    // The minimum, 6 points, is one segment long.
    let one = Trajectory::new(0, 0.1, vec![[0.0; 6]; 6]).unwrap();
    assert_eq!(one.end_ns(), 100_000_000);
}

#[test]
fn trajectory_derivatives_match_finite_differences() {
    // Central differences with h = 1e-4 s: truncation h²/6·|f'''| is below 1e-7 for these paths
    // (|f'''| < 60 in SI units), rounding ε·|f|/h is ~1e-10; 1e-6 leaves a margin for both.
    let h = 1e-4;
    let tol = 1e-6;
    let mut checked = 0;
    for traj in [rover_trajectory(false), flyer_trajectory()] {
        let mut t = 0.013;
        while t + h < traj.duration_s() {
            let [before, now, after] = [t - h, t, t + h].map(|ts| traj.state_at_s(ts).unwrap());
            let p = |s: &KinematicState| s.t_world_body.translation.vector;
            let v_fd = (p(&after) - p(&before)) / (2.0 * h);
            assert!((v_fd - now.v_world_mps).norm() < tol, "velocity at {t}: {v_fd} vs {}", now.v_world_mps);
            let a_fd = (after.v_world_mps - before.v_world_mps) / (2.0 * h);
            assert!((a_fd - now.a_world_mps2).norm() < tol, "acceleration at {t}");
            let e_fd = (after.euler_rad - before.euler_rad) / (2.0 * h);
            assert!((e_fd - now.euler_rate_radps).norm() < tol, "euler rates at {t}");
            // Body-frame rate: R(t+h) = R(t−h)·exp(2h·ω) + O(h³).
            let q = |s: &KinematicState| s.t_world_body.rotation;
            let omega_fd = (q(&before).inverse() * q(&after)).scaled_axis() / (2.0 * h);
            assert!(
                (omega_fd - now.omega_body_radps).norm() < tol,
                "omega at {t}: {omega_fd} vs {}",
                now.omega_body_radps
            );
            // The orientation is Rz(yaw)·Ry(pitch)·Rx(roll).
            let e = now.euler_rad;
            let r = rot_z(e.z) * rot_y(e.y) * rot_x(e.x);
            assert!((q(&now).to_rotation_matrix().into_inner() - r).norm() < 1e-12);
            checked += 1;
            t += 0.1173;
        }
    }
    assert!(checked > 900, "{checked}");
}

/// Cubic Lagrange interpolation of `values` at `k + 0.5` from the four nearest samples.
fn midpoint(values: &[Vector3<f64>], k: usize) -> Vector3<f64> {
    let n = values.len();
    let (first, w) = if k == 0 {
        (0, [5.0, 15.0, -5.0, 1.0])
    } else if k + 2 >= n {
        (n - 4, [1.0, -5.0, 15.0, 5.0])
    } else {
        (k - 1, [-1.0, 9.0, 9.0, -1.0])
    };
    (0..4).map(|j| values[first + j] * (w[j] / 16.0)).sum()
}

/// Strap-down integration of the samples alone, RK4 on (q, v, p) with the samples interpolated
/// at the half steps. Returns the poses at the sample times.
fn integrate(
    samples: &[ImuSample],
    gravity: Vector3<f64>,
    q0: UnitQuaternion<f64>,
    v0: Vector3<f64>,
    p0: Vector3<f64>,
) -> Vec<(UnitQuaternion<f64>, Vector3<f64>)> {
    let gyro: Vec<_> = samples.iter().map(|s| s.gyro_radps).collect();
    let accel: Vec<_> = samples.iter().map(|s| s.accel_mps2).collect();
    let deriv = |q: &Quaternion<f64>, v: &Vector3<f64>, w: &Vector3<f64>, f: &Vector3<f64>| {
        let dq = q * Quaternion::from_imag(*w) * 0.5;
        let r = UnitQuaternion::new_normalize(*q);
        (dq, r * f + gravity, *v)
    };
    let (mut q, mut v, mut p) = (q0.into_inner(), v0, p0);
    let mut out = vec![(q0, p0)];
    for k in 0..samples.len() - 1 {
        let h = (samples[k + 1].stamp_ns - samples[k].stamp_ns) as f64 * 1e-9;
        let (wm, fm) = (midpoint(&gyro, k), midpoint(&accel, k));
        let (q1, v1, p1) = deriv(&q, &v, &gyro[k], &accel[k]);
        let (q2, v2, p2) = deriv(&(q + q1 * (h / 2.0)), &(v + v1 * (h / 2.0)), &wm, &fm);
        let (q3, v3, p3) = deriv(&(q + q2 * (h / 2.0)), &(v + v2 * (h / 2.0)), &wm, &fm);
        let (q4, v4, p4) = deriv(&(q + q3 * h), &(v + v3 * h), &gyro[k + 1], &accel[k + 1]);
        q = (q + (q1 + q2 * 2.0 + q3 * 2.0 + q4) * (h / 6.0)).normalize();
        v += (v1 + v2 * 2.0 + v3 * 2.0 + v4) * (h / 6.0);
        p += (p1 + p2 * 2.0 + p3 * 2.0 + p4) * (h / 6.0);
        out.push((UnitQuaternion::new_unchecked(q), p));
    }
    out
}

/// Max position error and final attitude error of integrating noise-free 200 Hz samples.
fn dead_reckoning_errors(traj: &Trajectory, body: Body) -> (f64, f64) {
    let rate_hz = 200.0;
    let mut imu = ImuSimulator::new(ImuNoise::noise_free(), body.gravity_world_mps2(), rate_hz, 1);
    let period_ns = 5_000_000;
    let count = (traj.end_ns() - traj.start_ns()) / period_ns + 1;
    let stamps: Vec<u64> = (0..count).map(|k| traj.start_ns() + k * period_ns).collect();
    let truth: Vec<KinematicState> = stamps.iter().map(|&s| traj.state_at(s).unwrap()).collect();
    let samples: Vec<ImuSample> = truth.iter().zip(&stamps).map(|(state, &s)| imu.sample(state, s)).collect();
    let initial = &truth[0];
    let poses = integrate(
        &samples,
        body.gravity_world_mps2(),
        initial.t_world_body.rotation,
        initial.v_world_mps,
        initial.t_world_body.translation.vector,
    );
    let max_position_error_m = poses
        .iter()
        .zip(&truth)
        .map(|((_, p), state)| (p - state.t_world_body.translation.vector).norm())
        .fold(0.0, f64::max);
    let (q_final, _) = poses[poses.len() - 1];
    let attitude_error_rad = (q_final.inverse() * truth[truth.len() - 1].t_world_body.rotation).angle();
    (max_position_error_m, attitude_error_rad)
}

#[test]
fn noise_free_imu_integrates_to_the_rover_ground_truth() {
    let traj = rover_trajectory(false);
    assert!((traj.duration_s() - 60.0).abs() < 1e-9);
    // The rover really stands still at the start and end, and cruises at 0.3–0.5 m/s.
    assert!(traj.state_at_s(1.0).unwrap().v_world_mps.norm() < 1e-12);
    assert!(traj.state_at_s(58.0).unwrap().v_world_mps.norm() < 1e-12);
    let cruise = traj.state_at_s(30.0).unwrap().v_world_mps.norm();
    assert!((0.29..0.52).contains(&cruise), "{cruise}");
    for body in [Body::Moon, Body::Mars, Body::Earth] {
        let (position_m, attitude_rad) = dead_reckoning_errors(&traj, body);
        println!(
            "rover {}: max position error {position_m:.3e} m, final attitude error {attitude_rad:.3e} rad",
            body.name()
        );
        assert!(position_m < 1e-3, "{}: {position_m}", body.name());
    }
}

#[test]
fn noise_free_imu_integrates_to_the_flyer_ground_truth() {
    let traj = flyer_trajectory();
    let speed = traj.state_at_s(10.0).unwrap().v_world_mps.norm();
    assert!(speed > 3.0, "{speed}");
    for body in [Body::Moon, Body::Mars, Body::Earth] {
        let (position_m, attitude_rad) = dead_reckoning_errors(&traj, body);
        println!(
            "flyer {}: max position error {position_m:.3e} m, final attitude error {attitude_rad:.3e} rad",
            body.name()
        );
        assert!(position_m < 1e-3, "{}: {position_m}", body.name());
    }
}

/// A body standing still at `[roll, pitch, yaw]`.
fn standing(euler: [f64; 3]) -> KinematicState {
    let traj = Trajectory::new(0, 1.0, vec![[1.0, 2.0, 3.0, euler[0], euler[1], euler[2]]; 6]).unwrap();
    traj.state_at(0).unwrap()
}

#[test]
fn mti10_values_follow_the_datasheet() {
    let n = ImuNoise::xsens_mti10();
    let g0 = 9.806_65;
    assert!((n.gyro_noise_density_radps_rthz.to_degrees() - 0.03).abs() < 1e-12);
    assert!((n.accel_noise_density_mps2_rthz / g0 * 1e6 - 60.0).abs() < 1e-9);
    // The bias-walk rule: the model's Allan curve √(N²/τ + K²τ/3) bottoms out at the in-run bias
    // stability (18 °/h, 15 µg). Scanned on a fine log grid (0.1 % steps: the minimum is flat, so
    // the grid error is ~1e-6 relative).
    let floor = |noise: f64, walk: f64| {
        (0..20_000)
            .map(|i| 10f64.powf(-1.0 + i as f64 * 1e-4 * 5.0 / 2.0))
            .fold(f64::INFINITY, |m, tau| m.min((noise * noise / tau + walk * walk * tau / 3.0).sqrt()))
    };
    let gyro_floor_dph = floor(n.gyro_noise_density_radps_rthz, n.gyro_bias_rw_radps2_rthz).to_degrees() * 3600.0;
    let accel_floor_ug = floor(n.accel_noise_density_mps2_rthz, n.accel_bias_rw_mps3_rthz) / g0 * 1e6;
    println!(
        "MTi-10: gyro RW {:.3e} rad/s²/√Hz (floor {gyro_floor_dph:.3} °/h), accel RW {:.3e} m/s³/√Hz (floor {accel_floor_ug:.3} µg)",
        n.gyro_bias_rw_radps2_rthz, n.accel_bias_rw_mps3_rthz
    );
    assert!((gyro_floor_dph - 18.0).abs() < 18.0 * 1e-4);
    assert!((accel_floor_ug - 15.0).abs() < 15.0 * 1e-4);
    assert_eq!(bias_rw_from_stability(1.0, 0.0), 0.0);
}

#[test]
fn allan_of_known_series() {
    // A linear drift y = R·t has σ(τ) = R·τ/√2 exactly.
    let rate_hz = 10.0;
    let ramp: Vec<f64> = (0..1000).map(|i| 0.02 * i as f64 / rate_hz).collect();
    let points = allan::allan_deviation(&ramp, rate_hz).unwrap();
    // Octaves up to the largest size leaving two clusters: 256 (512 would need 1024 samples).
    assert_eq!(points.iter().map(|p| p.tau_s).collect::<Vec<_>>(), [0.1, 0.2, 0.4, 0.8, 1.6, 3.2, 6.4, 12.8, 25.6]);
    for p in &points {
        assert!((p.adev - 0.02 * p.tau_s / 2f64.sqrt()).abs() < 1e-9, "{p:?}");
    }
    assert_eq!(points[8].clusters, 3);
    // An alternating series ±a has σ(τ0) = 2a / √2 = √2·a (each
    // cluster pair differs by 2a) and zero at even cluster sizes.
    let alternating: Vec<f64> = (0..64).map(|i| if i % 2 == 0 { 5.5 } else { 4.5 }).collect();
    let points = allan::overlapping_adev(&alternating, 1.0, &[1, 2, 4]).unwrap();
    assert!((points[0].adev - 2f64.sqrt() * 0.5).abs() < 1e-12);
    assert!(points[1].adev < 1e-12 && points[2].adev < 1e-12);
    assert_eq!(allan::overlapping_adev(&alternating, 0.0, &[1]), Err(AllanError::BadRate(0.0)));
    assert_eq!(allan::overlapping_adev(&alternating, 1.0, &[33]), Err(AllanError::TooShort { size: 33, len: 64 }));
    assert_eq!(allan::overlapping_adev(&alternating, 1.0, &[0]), Err(AllanError::ZeroCluster));
}

#[test]
fn allan_deviation_recovers_the_configured_densities() {
    // 12 h of a standing MTi-10 at 200 Hz. Samples are averaged into 0.1 s bins on the fly (the
    // Allan deviation at multiples of 0.1 s is the same statistic computed from bin means), so
    // memory stays small; the three axes of each sensor are pooled (independent, same noise).
    let noise = ImuNoise::xsens_mti10();
    let rate_hz = 200.0;
    let hours = 12.0;
    let bin = 20;
    let total = (hours * 3600.0 * rate_hz) as usize;
    let state = standing([0.1, -0.05, 0.7]);
    let mut imu = ImuSimulator::new(noise, Body::Mars.gravity_world_mps2(), rate_hz, 42);
    let mut gyro_bins = [Vec::new(), Vec::new(), Vec::new()];
    let mut accel_bins = [Vec::new(), Vec::new(), Vec::new()];
    let (mut gyro_acc, mut accel_acc) = (Vector3::zeros(), Vector3::zeros());
    for k in 0..total {
        let s = imu.sample(&state, k as u64 * 5_000_000);
        gyro_acc += s.gyro_radps;
        accel_acc += s.accel_mps2;
        if (k + 1) % bin == 0 {
            for (bins, acc) in
                gyro_bins.iter_mut().zip(gyro_acc.iter()).chain(accel_bins.iter_mut().zip(accel_acc.iter()))
            {
                bins.push(acc / bin as f64);
            }
            gyro_acc = Vector3::zeros();
            accel_acc = Vector3::zeros();
        }
    }
    let bin_rate_hz = rate_hz / bin as f64;
    // Pool: mean Allan variance over the axes, with three times the clusters.
    let pooled = |series: &[Vec<f64>; 3]| {
        let per_axis: Vec<_> = series.iter().map(|s| allan::allan_deviation(s, bin_rate_hz).unwrap()).collect();
        (0..per_axis[0].len())
            .map(|i| allan::AllanPoint {
                tau_s: per_axis[0][i].tau_s,
                adev: (per_axis.iter().map(|p| p[i].adev * p[i].adev).sum::<f64>() / 3.0).sqrt(),
                clusters: 3 * per_axis[0][i].clusters,
            })
            .collect::<Vec<_>>()
    };
    for (name, series, n, k) in [
        ("gyro", &gyro_bins, noise.gyro_noise_density_radps_rthz, noise.gyro_bias_rw_radps2_rthz),
        ("accel", &accel_bins, noise.accel_noise_density_mps2_rthz, noise.accel_bias_rw_mps3_rthz),
    ] {
        let points = pooled(series);
        for p in &points {
            println!("{name} τ = {:9.1} s  σ = {:.4e}  clusters {}", p.tau_s, p.adev, p.clusters);
        }
        // White noise: the −½ line over τ ∈ [0.1, 1] s, where the walk adds < 0.1 % of the
        // variance. Tolerance: 3× the relative error of the point with the fewest clusters in the
        // range (τ = 0.8 s), which bounds the error of the weighted fit.
        let white = allan::white_noise_density(&points, 0.1, 1.0).unwrap();
        let fewest = points.iter().filter(|p| p.tau_s <= 1.0).map(|p| p.relative_error()).fold(0.0, f64::max);
        let white_tol = 3.0 * fewest;
        // Random walk: read at the single octave point with the most clusters where white noise
        // is < 1 % of the variance (N²/τ < 0.01·K²τ/3, i.e. τ > √300·N/K). Tolerance: 3× that
        // point's relative error.
        let tau_rw = 300f64.sqrt() * n / k;
        let rw_point = points.iter().find(|p| p.tau_s > tau_rw).unwrap();
        let walk = allan::random_walk_density(&points, rw_point.tau_s, rw_point.tau_s).unwrap();
        let walk_tol = 3.0 * rw_point.relative_error();
        println!(
            "{name}: white {white:.4e} vs {n:.4e} ({:+.2} %, tol {:.2} %), walk {walk:.4e} vs {k:.4e} at τ = {} s ({:+.1} %, tol {:.1} %)",
            100.0 * (white / n - 1.0),
            100.0 * white_tol,
            rw_point.tau_s,
            100.0 * (walk / k - 1.0),
            100.0 * walk_tol
        );
        assert!((white / n - 1.0).abs() < white_tol, "{name} white");
        assert!((walk / k - 1.0).abs() < walk_tol, "{name} walk");
    }
}

#[test]
fn stationary_accel_mean_is_gravity_plus_bias() {
    let noise = ImuNoise::xsens_mti10();
    let rate_hz = 200.0;
    let n = 120_000; // 10 min
    let sigma_white = noise.discrete(rate_hz).accel_white_mps2;
    for (body, euler) in
        [(Body::Earth, [0.0, 0.0, 1.0]), (Body::Moon, [0.2, -0.3, 2.0]), (Body::Mars, [-0.1, 0.15, -0.5])]
    {
        let state = standing(euler);
        let mut imu = ImuSimulator::new(noise, body.gravity_world_mps2(), rate_hz, 7);
        let (mut mean_accel, mut mean_bias) = (Vector3::zeros(), Vector3::zeros());
        for k in 0..n {
            let s = imu.sample(&state, k as u64 * 5_000_000);
            mean_accel += s.accel_mps2 / n as f64;
            mean_bias += imu.biases().1 / n as f64;
        }
        // At rest the accelerometer feels the ground's push: +g up, i.e. Rᵀ·(0, 0, g) in the body.
        let up_body =
            state.t_world_body.rotation.inverse_transform_vector(&Vector3::new(0.0, 0.0, body.gravity_mps2()));
        let residual = mean_accel - up_body - mean_bias;
        // The white noise averages to σ/√n per axis; 5σ.
        let tol = 5.0 * sigma_white / (n as f64).sqrt();
        println!("{}: mean accel {mean_accel:?}, residual {:.2e} (tol {tol:.2e})", body.name(), residual.amax());
        assert!(residual.amax() < tol, "{}: {residual:?}", body.name());
        // Bias matters: without it the mean would be off by far more than the tolerance.
        assert!(mean_bias.amax() > 10.0 * tol);
        if euler[0] == 0.0 && euler[1] == 0.0 {
            assert!((mean_accel.z - mean_bias.z - body.gravity_mps2()).abs() < tol);
        }
    }
}

#[test]
fn discrete_noise_and_bias_walk_statistics() {
    let noise = ImuNoise::xsens_mti10();
    let rate_hz = 400.0;
    let d = noise.discrete(rate_hz);
    assert!((d.gyro_white_radps - noise.gyro_noise_density_radps_rthz * 20.0).abs() < 1e-15);
    assert!((d.accel_bias_step_mps2 - noise.accel_bias_rw_mps3_rthz / 20.0).abs() < 1e-15);
    let state = standing([0.3, 0.2, 0.1]);
    let mut imu = ImuSimulator::new(noise, Body::Moon.gravity_world_mps2(), rate_hz, 3);
    let (omega, f) = imu.ideal(&state);
    let n = 100_000;
    let (mut white_g, mut white_a, mut step_g, mut step_a) = (0.0, 0.0, 0.0, 0.0);
    let mut previous = imu.biases();
    for k in 0..n {
        let s = imu.sample(&state, k as u64 * 2_500_000);
        let biases = imu.biases();
        white_g += (s.gyro_radps - omega - biases.0).norm_squared();
        white_a += (s.accel_mps2 - f - biases.1).norm_squared();
        if k > 0 {
            step_g += (biases.0 - previous.0).norm_squared();
            step_a += (biases.1 - previous.1).norm_squared();
        } else {
            assert_eq!(biases, previous, "the first sample carries the turn-on biases");
        }
        previous = biases;
    }
    // Sample standard deviations over 3n (or 3(n−1)) draws; 5× the relative error 1/√(2·3n).
    let tol = 5.0 / (6.0 * n as f64).sqrt();
    for (name, sum, count, expected) in [
        ("gyro white", white_g, 3 * n, d.gyro_white_radps),
        ("accel white", white_a, 3 * n, d.accel_white_mps2),
        ("gyro bias step", step_g, 3 * (n - 1), d.gyro_bias_step_radps),
        ("accel bias step", step_a, 3 * (n - 1), d.accel_bias_step_mps2),
    ] {
        let std = (sum / count as f64).sqrt();
        println!("{name}: {std:.4e} vs {expected:.4e}");
        assert!((std / expected - 1.0).abs() < tol, "{name}: {std} vs {expected}");
    }

    // Turn-on biases across seeds.
    let seeds = 4000;
    let (mut sg, mut sa) = (0.0, 0.0);
    for seed in 0..seeds {
        let (g, a) = ImuSimulator::new(noise, Body::Moon.gravity_world_mps2(), rate_hz, seed).biases();
        sg += g.norm_squared();
        sa += a.norm_squared();
    }
    let tol = 5.0 / (6.0 * seeds as f64).sqrt();
    let std_g = (sg / (3 * seeds) as f64).sqrt();
    let std_a = (sa / (3 * seeds) as f64).sqrt();
    assert!((std_g / noise.gyro_bias_init_radps - 1.0).abs() < tol, "{std_g}");
    assert!((std_a / noise.accel_bias_init_mps2 - 1.0).abs() < tol, "{std_a}");
}

#[test]
fn imu_and_wheel_are_deterministic_per_seed() {
    let traj = rover_trajectory(false);
    let run = |seed: u64| {
        let mut imu = ImuSimulator::new(ImuNoise::xsens_mti10(), Body::Moon.gravity_world_mps2(), 200.0, seed);
        let mut wheel = WheelOdometer::new(WheelOdomConfig::default(), seed);
        let mut bytes = Vec::new();
        for k in 0..2000u64 {
            let stamp = k * 5_000_000;
            let state = traj.state_at(stamp).unwrap();
            let s = imu.sample(&state, stamp);
            bytes.extend(s.gyro_radps.iter().chain(s.accel_mps2.iter()).flat_map(|v| v.to_le_bytes()));
            if k % 4 == 0 {
                let w = wheel.sample(&state, stamp);
                bytes.extend(w.linear_mps.iter().chain(w.angular_radps.iter()).flat_map(|v| v.to_le_bytes()));
            }
        }
        bytes
    };
    assert_eq!(run(5), run(5));
    assert_ne!(run(5), run(6));
}

/// A straight drive at `speed` along world `direction` (unit, may climb) with constant attitude.
fn straight(velocity: Vector3<f64>, euler: [f64; 3]) -> Trajectory {
    spline_from_fn(1.0, 20.0, |t| [velocity.x * t, velocity.y * t, velocity.z * t, euler[0], euler[1], euler[2]])
}

#[test]
fn wheel_odometry_on_flat_ground_is_exact_without_slip_or_noise() {
    let traj = rover_trajectory(true);
    let mut wheel = WheelOdometer::new(WheelOdomConfig::ideal(), 1);
    let (mut moving, mut standing) = (0, 0);
    for k in 0..3000u64 {
        let stamp = k * 20_000_000;
        let state = traj.state_at(stamp).unwrap();
        let s = wheel.sample(&state, stamp);
        let v_body = state.t_world_body.rotation.inverse_transform_vector(&state.v_world_mps);
        assert_eq!([s.linear_mps.y, s.linear_mps.z, s.angular_radps.x, s.angular_radps.y], [0.0; 4]);
        assert_eq!(wheel.last_slip(), 0.0);
        if v_body.norm() < STANDSTILL_MPS && state.omega_body_radps.norm() < STANDSTILL_RADPS {
            // The spline's tails make the speed vanish gradually; below the encoders' threshold
            // the wheels do not turn.
            assert_eq!((s.linear_mps.x, s.angular_radps.z), (0.0, 0.0), "{k}");
            standing += 1;
        } else {
            assert!((s.linear_mps.x - v_body.x).abs() < 1e-12, "{k}");
            assert!((s.angular_radps.z - state.omega_body_radps.z).abs() < 1e-12);
        }
        if v_body.x > 0.2 {
            moving += 1;
        }
    }
    // 60 s at 50 Hz: ~4 s standing at the start, ~7 s at the end.
    assert!(moving > 2000 && standing > 400, "{moving} {standing}");
}

#[test]
fn wheel_odometry_over_reads_uphill() {
    let config = WheelOdomConfig { base_slip: 0.02, slip_per_uphill_rad: 0.6, ..WheelOdomConfig::ideal() };
    let grade = 8f64.to_radians();
    let speed = 0.4;
    let climb = Vector3::new(grade.cos(), 0.0, grade.sin()) * speed;
    let descend = Vector3::new(grade.cos(), 0.0, -grade.sin()) * speed;
    // Positive pitch turns the nose down (R = Rz·Ry·Rx).
    let cases = [
        ("forward uphill", climb, [0.0, -grade, 0.0], speed, 0.02 + 0.6 * grade),
        ("forward downhill", descend, [0.0, grade, 0.0], speed, 0.02),
        // Backing up the hill, facing down it: still uphill for the wheels.
        ("reverse uphill", Vector3::new(-climb.x, 0.0, climb.z), [0.0, grade, 0.0], -speed, 0.02 + 0.6 * grade),
        ("flat", Vector3::new(0.0, speed, 0.0), [0.0, 0.0, FRAC_PI_2], speed, 0.02),
    ];
    for (name, velocity, euler, v_forward, slip) in cases {
        let traj = straight(velocity, euler);
        let mut wheel = WheelOdometer::new(config, 9);
        let state = traj.state_at_s(7.3).unwrap();
        let s = wheel.sample(&state, 0);
        let v_body = state.t_world_body.rotation.inverse_transform_vector(&state.v_world_mps);
        assert!((v_body.x - v_forward).abs() < 1e-12 && v_body.yz().norm() < 1e-12, "{name}: {v_body}");
        assert!((wheel.last_slip() - slip).abs() < 1e-12, "{name}: slip {}", wheel.last_slip());
        assert!((s.linear_mps.x - v_forward / (1.0 - slip)).abs() < 1e-12, "{name}: {}", s.linear_mps.x);
    }
}

#[test]
fn wheel_odometry_cannot_see_side_slip() {
    // Crabbing on level ground: heading along x, sliding 0.1 m/s to the left.
    let traj = straight(Vector3::new(0.3, 0.1, 0.0), [0.0, 0.0, 0.0]);
    let mut wheel = WheelOdometer::new(WheelOdomConfig::ideal(), 2);
    let state = traj.state_at_s(3.0).unwrap();
    let s = wheel.sample(&state, 0);
    assert!((state.v_world_mps.y - 0.1).abs() < 1e-12);
    assert!((s.linear_mps.x - 0.3).abs() < 1e-12);
    assert_eq!(s.linear_mps.y, 0.0);
    // It says so: the unobserved components claim large standard deviations.
    let c = WheelOdomConfig::ideal();
    assert_eq!(
        s.sigma[1..5],
        [c.unobserved_sigma_mps, c.unobserved_sigma_mps, c.unobserved_sigma_radps, c.unobserved_sigma_radps]
    );
    assert!(s.sigma[1] > 0.1 && s.sigma[0] < s.sigma[1]);
}

#[test]
fn wheel_odometry_noise_statistics() {
    let config = WheelOdomConfig {
        speed_noise_mps: 0.01,
        yaw_rate_noise_radps: 0.004,
        base_slip: 0.3,
        slip_random_sigma: 0.03,
        slip_correlation_s: 2.0,
        ..WheelOdomConfig::ideal()
    };
    // Level, straight, 0.4 m/s: true yaw rate 0, slip = 0.3 + random part (10σ from the clamps).
    let state = straight(Vector3::new(0.4, 0.0, 0.0), [0.0, 0.0, 0.0]).state_at_s(5.0).unwrap();
    let mut wheel = WheelOdometer::new(config, 11);
    let n = 100_000; // 2000 s at 50 Hz
    let mut speed_residuals = Vec::with_capacity(n);
    let mut yaw = Vec::with_capacity(n);
    let mut slips = Vec::with_capacity(n);
    for k in 0..n {
        let s = wheel.sample(&state, k as u64 * 20_000_000);
        let slip = wheel.last_slip();
        speed_residuals.push(s.linear_mps.x - 0.4 / (1.0 - slip));
        yaw.push(s.angular_radps.z);
        slips.push(slip);
        assert!((s.sigma[0] - (0.01 + config.claimed_relative_sigma * s.linear_mps.x.abs())).abs() < 1e-15);
    }
    let mean = |x: &[f64]| x.iter().sum::<f64>() / x.len() as f64;
    let std = |x: &[f64]| {
        let m = mean(x);
        (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
    };
    // White noise: 5σ bounds on the mean (σ/√n) and on the standard deviation (σ/√(2n)).
    for (name, series, sigma) in [("speed", &speed_residuals, 0.01), ("yaw rate", &yaw, 0.004)] {
        let (m, s) = (mean(series), std(series));
        println!("{name}: mean {m:.2e}, std {s:.4e} (configured {sigma})");
        assert!(m.abs() < 5.0 * sigma / (n as f64).sqrt(), "{name} mean {m}");
        assert!((s / sigma - 1.0).abs() < 5.0 / (2.0 * n as f64).sqrt(), "{name} std {s}");
    }
    // Random slip, a Gauss–Markov process: its lag-1 autocorrelation is exp(−Δt/τ); for an AR(1)
    // with coefficient φ the estimate's standard error is √((1 − φ²)/n). Its mean and standard
    // deviation use effective sample counts: T/(2τ) = 500 for the mean (its variance is 2τσ²/T)
    // and T/τ = 1000 for the variance (its variance is 2σ⁴τ/T).
    let m = mean(&slips);
    let s = std(&slips);
    let lag1 = slips.windows(2).map(|w| (w[0] - m) * (w[1] - m)).sum::<f64>() / ((n - 1) as f64 * s * s);
    let phi = (-1.0_f64 / (50.0 * 2.0)).exp();
    let (n_eff_mean, n_eff_var): (f64, f64) = (2000.0 / (2.0 * 2.0), 2000.0 / 2.0);
    println!("slip: mean {m:.4}, std {s:.4}, lag-1 autocorrelation {lag1:.5} (expected {phi:.5})");
    assert!((m - 0.3).abs() < 5.0 * 0.03 / f64::sqrt(n_eff_mean), "mean slip {m}");
    assert!((s / 0.03 - 1.0).abs() < 5.0 / (2.0 * n_eff_var).sqrt(), "slip std {s}");
    assert!((lag1 - phi).abs() < 5.0 * ((1.0 - phi * phi) / n as f64).sqrt(), "lag-1 {lag1}");
}

#[test]
fn wheel_odometry_at_standstill_is_exactly_zero() {
    let state = standing([0.05, -0.2, 1.0]);
    let mut wheel = WheelOdometer::new(WheelOdomConfig::default(), 4);
    for k in 0..100u64 {
        let s = wheel.sample(&state, k * 20_000_000);
        assert_eq!(s.linear_mps, Vector3::zeros());
        assert_eq!(s.angular_radps, Vector3::zeros());
        assert!(s.sigma.iter().all(|&v| v > 0.0));
    }
    // A steep uphill stand still reports the slip it would have.
    assert!(wheel.last_slip() > WheelOdomConfig::default().base_slip);
}
