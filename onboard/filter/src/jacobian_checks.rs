//! Every analytic Jacobian of the filter against central differences ([`crate::numdiff`]): the
//! IMU transition and noise input, the cloning Jacobian, the `H` of every update as the update
//! assembles it over the whole state (relative pose between clones and to the current state,
//! wheel velocity, zero velocity with and without a gyro sample, absolute pose, which is also the
//! global→body conversion of `pose_covariance`), the frame switch's state map and its factor, and
//! the Euler-angle maps of `math`.
//!
//! The numeric side runs the filter's own nominal code on a copy whose state is perturbed with the
//! documented error convention (`p + δp`, `Exp(δθ)·q`, for clones too), and reads errors back
//! with its inverse; measurement errors use the measurements' `[δt; δθ]` (rotation right-
//! multiplied) through the updates' own residual. States are drawn by proptest with a fixed seed,
//! rotation angles in bands near 0, generic and within 1e-2 of π.
//! `cargo test -p filter jacobian -- --nocapture` prints the worst error of every check.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::f64::consts::PI;

use hal::sensor::{ImuSample, WheelOdomSample};
use nalgebra::{
    Const, DMatrix, DVector, Dyn, Isometry3, Matrix6, SMatrix, SVector, Translation3, UnitQuaternion, Vector3,
};
use proptest::prelude::*;

use crate::FilterConfig;
use crate::clones::clone_jacobian;
use crate::eskf::{Filter, IBA, IBG, IP, ITH, IV, NX, PoseClone, RelativePoseMeasurement};
use crate::math::{euler_to_global_error, exp, left_jacobian, yaw_jacobian};
use crate::numdiff::{self, Comparison, STEP, Tolerance};
use crate::propagate::transition_matrix;
use crate::switch::switch_factor_jacobian;
use crate::updates::{pose_residual, relative_pose_model, wheel_model, zero_velocity_model};

const CASES: u32 = 512;
const STAMP_NS: u64 = 1_000_000_000_000;
/// Clones every 100 ms before the state.
const CLONE_SPACING_NS: u64 = 100_000_000;

fn run<S: Strategy>(name: &str, strategy: S, check: impl Fn(S::Value) -> Comparison)
where
    S::Value: std::fmt::Debug,
{
    numdiff::run_cases(name, CASES, strategy, check);
}

fn angle() -> impl Strategy<Value = f64> + Clone {
    prop_oneof![0.0..1e-6, 1e-6..1e-2, 1e-2..3.0, (PI - 1e-2)..(PI - 1e-4)]
}

fn rotation() -> impl Strategy<Value = UnitQuaternion<f64>> + Clone {
    (prop::array::uniform3(-1.0..1.0f64), angle()).prop_filter_map("axis", |(a, angle)| {
        let axis = Vector3::from(a);
        (axis.norm() > 1e-3).then(|| UnitQuaternion::from_scaled_axis(axis.normalize() * angle))
    })
}

/// Attitudes a frame switch can meet: any yaw (also near ±π and 0), roll and pitch within ±69°
/// (yaw is singular at ±90° pitch, which a rover does not reach), with some exactly level.
fn switch_attitude() -> impl Strategy<Value = UnitQuaternion<f64>> + Clone {
    let tilt = prop_oneof![Just(0.0), -1e-6..1e-6, -1.2..1.2f64];
    let yaw = prop_oneof![-1e-6..1e-6, (PI - 1e-4)..PI, -PI..(-PI + 1e-4), -PI..PI];
    (tilt.clone(), tilt, yaw).prop_map(|(roll, pitch, yaw)| UnitQuaternion::from_euler_angles(roll, pitch, yaw))
}

fn vector(max: f64) -> impl Strategy<Value = Vector3<f64>> {
    prop::array::uniform3(-max..max).prop_map(Vector3::from)
}

/// A filter state: core and up to three clones (positions in m, within 100 m of the origin).
#[derive(Debug, Clone)]
struct State {
    p: Vector3<f64>,
    v: Vector3<f64>,
    q: UnitQuaternion<f64>,
    ba: Vector3<f64>,
    bg: Vector3<f64>,
    clones: Vec<(Vector3<f64>, UnitQuaternion<f64>)>,
}

fn state_with(attitude: impl Strategy<Value = UnitQuaternion<f64>> + Clone) -> impl Strategy<Value = State> {
    let clones = prop::collection::vec((vector(100.0), attitude.clone()), 0..=3);
    (vector(100.0), vector(3.0), attitude, vector(0.2), vector(0.02), clones)
        .prop_map(|(p, v, q, ba, bg, clones)| State { p, v, q, ba, bg, clones })
}

fn state() -> impl Strategy<Value = State> {
    state_with(rotation())
}

impl State {
    fn filter(&self) -> Filter {
        // Few clone slots: every perturbed copy clones the covariance buffer.
        let mut f = Filter::new(FilterConfig { max_clones: 4, ..FilterConfig::default() });
        let pose = Isometry3::from_parts(Translation3::from(self.p), self.q);
        f.initialize_with_pose(STAMP_NS, &pose, &self.v).unwrap();
        f.ba = self.ba;
        f.bg = self.bg;
        let n = self.clones.len() as u64;
        for (k, (p, q)) in self.clones.iter().enumerate() {
            let stamp_ns = STAMP_NS - (n - k as u64) * CLONE_SPACING_NS;
            f.clones.push(PoseClone { stamp_ns, p: *p, q: *q, keyframe: true, released: false });
        }
        f
    }
}

/// `x ⊕ δ` with the filter's documented error convention, over core and clones.
fn perturb(f: &Filter, d: &DVector<f64>) -> Filter {
    let v3 = |i: usize| Vector3::new(d[i], d[i + 1], d[i + 2]);
    let mut g = f.clone();
    g.p += v3(IP);
    g.v += v3(IV);
    g.q = numdiff::left_plus(&g.q, &v3(ITH));
    g.ba += v3(IBA);
    g.bg += v3(IBG);
    for (i, c) in g.clones.iter_mut().enumerate() {
        let base = NX + 6 * i;
        c.p += v3(base);
        c.q = numdiff::left_plus(&c.q, &v3(base + 3));
    }
    g
}

/// `a ⊖ b`, the inverse of [`perturb`].
fn difference(a: &Filter, b: &Filter) -> DVector<f64> {
    let mut d = DVector::zeros(a.dim());
    let mut put = |i: usize, v: Vector3<f64>| d.fixed_rows_mut::<3>(i).copy_from(&v);
    put(IP, a.p - b.p);
    put(IV, a.v - b.v);
    put(ITH, numdiff::left_minus(&a.q, &b.q));
    put(IBA, a.ba - b.ba);
    put(IBG, a.bg - b.bg);
    for (i, (ca, cb)) in a.clones.iter().zip(&b.clones).enumerate() {
        put(NX + 6 * i, ca.p - cb.p);
        put(NX + 6 * i + 3, numdiff::left_minus(&ca.q, &cb.q));
    }
    d
}

/// Jacobian of `map(x ⊕ δ)` over the whole error state of `f`.
fn state_jacobian(f: &Filter, mut map: impl FnMut(&Filter) -> DVector<f64>) -> DMatrix<f64> {
    numdiff::jacobian(Dyn(f.dim()), STEP, |d| map(&perturb(f, d)))
}

/// Positions reach 100 m, so rounding is ~100 times that of unit values.
const POSITION_SCALE: f64 = 100.0;

#[test]
fn inject_is_the_documented_retraction() {
    run("inject = p + δp, Exp(δθ)·q", (state(), prop::collection::vec(-0.1..0.1f64, NX + 18)), |(s, d)| {
        let f = s.filter();
        let d = DVector::from_vec(d).rows(0, f.dim()).into_owned();
        let mut g = f.clone();
        g.scratch.dx.rows_mut(0, f.dim()).copy_from(&d);
        g.inject();
        let expected = difference(&perturb(&f, &d), &f);
        let got = difference(&g, &f);
        numdiff::compare(&got, &expected, Tolerance { abs: 1e-13, rel: 0.0 })
    });
}

/// One IMU step: state, the two samples and the step length.
#[derive(Debug, Clone)]
struct ImuStep {
    state: State,
    w0: Vector3<f64>,
    a0: Vector3<f64>,
    w1: Vector3<f64>,
    a1: Vector3<f64>,
    dt: f64,
}

/// Rates up to 2 rad/s, specific forces up to 12 m/s² per axis, steps of 1–20 ms; half of the
/// steps with a constant sample (as `extrapolate_to` and the first sample integrate).
fn imu_step() -> impl Strategy<Value = ImuStep> {
    let samples = (vector(2.0), vector(12.0), vector(2.0), vector(12.0), any::<bool>());
    (state_with(rotation()), samples, 1e-3..2e-2f64).prop_map(|(state, (w0, a0, w1, a1, constant), dt)| {
        let (w1, a1) = if constant { (w0, a0) } else { (w0 + 0.05 * w1, a0 + 0.2 * a1) };
        ImuStep { state: State { clones: Vec::new(), ..state }, w0, a0, w1, a1, dt }
    })
}

impl ImuStep {
    fn after(&self, f: &Filter) -> Filter {
        let mut g = f.clone();
        let _ = g.integrate_nominal(self.dt, &self.w0, &self.a0, &self.w1, &self.a1);
        g
    }

    /// How far the documented first-order transition may lie from the exact Jacobian of the
    /// discrete step: the dropped terms are `O(dt³)` (e.g. `∂p/∂b_g = R·[f]×·dt³/6`, the
    /// `|ω|²dt³/8` of the mid-point rotation) and `O(dt²·|a₁ − a₀|)` (`F` uses the mean specific
    /// force where the step weights the two samples 2:1 in position and 1:1 with the end rotation
    /// in `∂v/∂b_g`). A wrong `dt²` term errs by ~`|f|·dt²/2`, `1/(dt·(1+|ω|)²)` times more.
    fn model_bound(&self) -> f64 {
        let f = self.a0.amax().max(self.a1.amax()) * 3f64.sqrt() + self.state.ba.norm();
        let w = self.w0.norm().max(self.w1.norm()) + self.state.bg.norm();
        let dt = self.dt;
        dt.powi(3) * (f * (1.0 + w) + w * w) + dt * dt * (self.a1 - self.a0).norm() / 4.0
    }

    fn tolerance(&self) -> Tolerance {
        let t = Tolerance::central(STEP, POSITION_SCALE);
        Tolerance { abs: t.abs + self.model_bound(), rel: t.rel }
    }
}

#[test]
fn transition_matrix_is_the_step_jacobian() {
    run("propagation F (vs exact step, O(dt³) bound)", imu_step(), |step| {
        let f = step.state.filter();
        let mut g = f.clone();
        let lin = g.integrate_nominal(step.dt, &step.w0, &step.a0, &step.w1, &step.a1);
        let analytic = transition_matrix(step.dt, &lin);
        let numeric = state_jacobian(&f, |x| difference(&step.after(x), &g));
        numdiff::compare(&analytic, &numeric, step.tolerance())
    });
}

/// The dropped terms are third order: halving the step divides the difference by ~8 (a wrong
/// second-order term would give 4).
#[test]
fn transition_matrix_error_is_third_order() {
    let state = State {
        p: Vector3::new(10.0, -3.0, 0.5),
        v: Vector3::new(0.8, 0.1, -0.05),
        q: UnitQuaternion::from_euler_angles(0.1, -0.2, 2.0),
        ba: Vector3::new(0.05, -0.02, 0.1),
        bg: Vector3::new(0.003, -0.002, 0.001),
        clones: Vec::new(),
    };
    let (w, a) = (Vector3::new(0.3, -0.5, 1.2), Vector3::new(0.7, -0.4, 9.6));
    let error = |dt: f64| {
        let step = ImuStep { state: state.clone(), w0: w, a0: a, w1: w, a1: a, dt };
        let f = state.filter();
        let mut g = f.clone();
        let lin = g.integrate_nominal(dt, &w, &a, &w, &a);
        let numeric = state_jacobian(&f, |x| difference(&step.after(x), &g));
        (transition_matrix(dt, &lin) - numeric).amax()
    };
    let (e20, e10, e5) = (error(0.04), error(0.02), error(0.01));
    println!("F − exact step Jacobian: {e20:.2e} (40 ms), {e10:.2e} (20 ms), {e5:.2e} (10 ms)");
    for (coarse, fine) in [(e20, e10), (e10, e5)] {
        let ratio = coarse / fine;
        assert!((6.5..9.5).contains(&ratio), "halving dt divided the error by {ratio:.2}, not ~8");
    }
}

/// IMU measurement errors enter the step as the biases do with the opposite sign (`f = a − b_a`,
/// `ω = w − b_g`): the noise input Jacobian `G` the process noise assumes is `−F[:, b_a | b_g]`.
#[test]
fn noise_jacobian_is_minus_the_bias_columns() {
    run("propagation noise input G = −F[:, b]", imu_step(), |step| {
        let f = step.state.filter();
        let mut g = f.clone();
        let lin = g.integrate_nominal(step.dt, &step.w0, &step.a0, &step.w1, &step.a1);
        // Measurement noise does not move the biases themselves (their walk is separate).
        let mut analytic: SMatrix<f64, NX, 6> = -transition_matrix(step.dt, &lin).fixed_columns::<6>(IBA).into_owned();
        analytic.fixed_rows_mut::<6>(IBA).fill(0.0);
        let numeric = numdiff::jacobian(Const::<6>, STEP, |n: &SVector<f64, 6>| {
            let (na, nw) = (n.fixed_rows::<3>(0).into_owned(), n.fixed_rows::<3>(3).into_owned());
            let mut x = f.clone();
            let _ = x.integrate_nominal(step.dt, &(step.w0 + nw), &(step.a0 + na), &(step.w1 + nw), &(step.a1 + na));
            SVector::<f64, NX>::from_iterator(difference(&x, &g).iter().copied())
        });
        numdiff::compare(&analytic, &numeric, step.tolerance())
    });
}

#[test]
fn clone_jacobian_matches() {
    let lag = prop_oneof![Just(0u64), 1u64..=20_000_000];
    run("clone J (p − v·Δ, q·Exp(−ω·Δ))", (state(), lag, vector(2.0)), |(s, lag_ns, w)| {
        let mut f = State { clones: Vec::new(), ..s }.filter();
        f.last_imu = Some(ImuSample { stamp_ns: STAMP_NS, gyro_radps: w, accel_mps2: Vector3::new(0.0, 0.0, 1.62) });
        let reference = reference_clone(&f, lag_ns);
        let numeric = numdiff::jacobian(Const::<NX>, STEP, |d: &SVector<f64, NX>| {
            let mut x = perturb(&f, &DVector::from_column_slice(d.as_slice()));
            x.clone_pose_at(STAMP_NS - lag_ns).unwrap();
            let c = x.clones[0];
            let (dp, dq) = (c.p - reference.p, numdiff::left_minus(&c.q, &reference.q));
            SVector::<f64, 6>::new(dp.x, dp.y, dp.z, dq.x, dq.y, dq.z)
        });
        let analytic = clone_jacobian(&f.q, &(w - f.bg), lag_ns as f64 * 1e-9);
        numdiff::compare(&analytic, &numeric, Tolerance::central(STEP, POSITION_SCALE))
    });
}

fn reference_clone(f: &Filter, lag_ns: u64) -> PoseClone {
    let mut x = f.clone();
    x.clone_pose_at(STAMP_NS - lag_ns).unwrap();
    x.clones[0]
}

/// `Hᵀ` as the last update left it in the scratch buffer, as `H` (rows × state dimension).
fn assembled_h(f: &Filter, rows: usize) -> DMatrix<f64> {
    f.scratch.ht.view((0, 0), (f.dim(), rows)).transpose()
}

/// Runs `h_and_numeric` (the assembled `H` and its numeric counterpart) on drawn states.
fn check_h(
    name: &str,
    strategy: impl Strategy<Value = State>,
    h_and_numeric: impl Fn(&Filter) -> (DMatrix<f64>, DMatrix<f64>),
) {
    run(name, strategy, |s| {
        let (analytic, numeric) = h_and_numeric(&s.filter());
        numdiff::compare(&analytic, &numeric, Tolerance::central(STEP, POSITION_SCALE))
    });
}

fn pose_of(t: &Vector3<f64>, q: &UnitQuaternion<f64>) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::from(*t), *q)
}

/// `H` of a relative-pose update from clone `from` to clone `to` (`None`: the current state) as
/// the update assembles it, and `−∂r/∂δ` of the update's residual `r` for a measurement equal to
/// the prediction, where `r(x ⊕ δ) = −(ẑ(x ⊕ δ) ⊖ ẑ(x))` exactly.
fn relative_pose_h(f: &Filter, from: usize, to: Option<usize>) -> (DMatrix<f64>, DMatrix<f64>) {
    let ends = |x: &Filter| {
        let c = x.clones[from];
        let (p_t, q_t) = match to {
            Some(j) => (x.clones[j].p, x.clones[j].q),
            None => (x.p, x.q),
        };
        relative_pose_model(&c.p, &c.q, &p_t, &q_t)
    };
    let (t0, q0, _) = ends(f);
    let measured = pose_of(&t0, &q0);
    let mut g = f.clone();
    let m = RelativePoseMeasurement {
        from_stamp_ns: f.clones[from].stamp_ns,
        to_stamp_ns: to.map_or(f.stamp_ns, |j| f.clones[j].stamp_ns),
        t_from_to: measured,
        covariance: Matrix6::identity() * 1e-4,
    };
    g.update_relative_pose(&m).unwrap();
    let numeric = state_jacobian(f, |x| {
        let (t, q, _) = ends(x);
        -DVector::from_column_slice(pose_residual(&t, &q, &measured).as_slice())
    });
    (assembled_h(&g, 6), numeric)
}

#[test]
fn relative_pose_h_between_clones() {
    let strategy = state().prop_filter("two clones", |s| s.clones.len() >= 2);
    check_h("relative pose H (clone → clone)", strategy, |f| {
        let n = f.clones.len();
        relative_pose_h(f, n - 2, Some(n - 1))
    });
    check_h("relative pose H (older clone → clone)", state().prop_filter("3 clones", |s| s.clones.len() == 3), |f| {
        relative_pose_h(f, 0, Some(2))
    });
}

#[test]
fn relative_pose_h_to_current_state() {
    let strategy = state().prop_filter("a clone", |s| !s.clones.is_empty());
    check_h("relative pose H (clone → current state)", strategy, |f| relative_pose_h(f, 0, None));
}

#[test]
fn wheel_h() {
    check_h("wheel odometry H", state(), |f| {
        let (v_body, _) = wheel_model(&f.v, &f.q);
        let sample = WheelOdomSample {
            stamp_ns: f.stamp_ns,
            linear_mps: v_body,
            angular_radps: Vector3::zeros(),
            sigma: [0.05; 6],
        };
        let mut g = f.clone();
        g.update_wheel_odometry(&sample).unwrap();
        let numeric = state_jacobian(f, |x| DVector::from_column_slice(wheel_model(&x.v, &x.q).0.as_slice()));
        (assembled_h(&g, 3), numeric)
    });
}

#[test]
fn zero_velocity_h() {
    for with_gyro in [true, false] {
        let name = if with_gyro { "zero-velocity H (velocity + rate)" } else { "zero-velocity H (velocity only)" };
        check_h(name, state(), |f| {
            let mut g = f.clone();
            if with_gyro {
                g.last_imu = Some(ImuSample { stamp_ns: f.stamp_ns, gyro_radps: f.bg, accel_mps2: Vector3::z() });
            }
            g.update_zero_velocity().unwrap();
            let rows = if with_gyro { 6 } else { 3 };
            let numeric = state_jacobian(f, |x| {
                DVector::from_column_slice(&zero_velocity_model(&x.v, &x.bg).0.as_slice()[..rows])
            });
            (assembled_h(&g, rows), numeric)
        });
    }
}

#[test]
fn pose_h() {
    check_h("absolute pose H (= pose_covariance's J)", state(), |f| {
        let measured = pose_of(&f.p, &f.q);
        let mut g = f.clone();
        g.update_pose(&measured, &(Matrix6::identity() * 1e-4)).unwrap();
        let numeric =
            state_jacobian(f, |x| -DVector::from_column_slice(pose_residual(&x.p, &x.q, &measured).as_slice()));
        (assembled_h(&g, 6), numeric)
    });
}

fn switched(f: &Filter) -> (Filter, Isometry3<f64>) {
    let mut g = f.clone();
    let switch = g.switch_frame_now();
    (g, switch.t_old_new)
}

#[test]
fn frame_switch_state_jacobian() {
    run("frame switch J (core + clones)", state_with(switch_attitude()), |s| {
        let f = s.filter();
        let (after, _) = switched(&f);
        let numeric = state_jacobian(&f, |x| difference(&switched(x).0, &after));
        numdiff::compare(&f.switch_jacobian(), &numeric, Tolerance::central(STEP, POSITION_SCALE))
    });
}

#[test]
fn frame_switch_factor_jacobian() {
    run("frame switch factor J ([δt; δθ] of t_old_new)", state_with(switch_attitude()), |s| {
        let f = State { clones: Vec::new(), ..s }.filter();
        let (_, t0) = switched(&f);
        let numeric = state_jacobian(&f, |x| {
            let (_, t) = switched(x);
            let (dt, dth) =
                (t.translation.vector - t0.translation.vector, numdiff::right_minus(&t.rotation, &t0.rotation));
            DVector::from_column_slice(&[dt.x, dt.y, dt.z, dth.x, dth.y, dth.z])
        });
        let mut analytic = DMatrix::zeros(6, NX);
        let j = switch_factor_jacobian(&f.q);
        analytic.view_mut((0, IP), (6, 3)).copy_from(&j.fixed_columns::<3>(0));
        analytic.view_mut((0, ITH), (6, 3)).copy_from(&j.fixed_columns::<3>(3));
        numdiff::compare(&analytic, &numeric, Tolerance::central(STEP, POSITION_SCALE))
    });
}

#[test]
fn so3_left_jacobian() {
    let phi = (prop::array::uniform3(-1.0..1.0f64), angle()).prop_filter_map("axis", |(a, angle)| {
        let axis = Vector3::from(a);
        (axis.norm() > 1e-3).then(|| axis.normalize() * angle)
    });
    run("math::left_jacobian", phi, |phi| {
        let r = exp(&phi);
        let numeric = numdiff::jacobian(Const::<3>, STEP, |d: &Vector3<f64>| numdiff::left_minus(&exp(&(phi + d)), &r));
        numdiff::compare(&left_jacobian(&phi), &numeric, Tolerance::central(STEP, 1.0))
    });
}

/// Yaw differences across ±π.
fn wrap(angle: f64) -> f64 {
    (angle + PI).rem_euclid(2.0 * PI) - PI
}

#[test]
fn yaw_jacobian_and_euler_map() {
    run("math::yaw_jacobian", switch_attitude(), |q| {
        let yaw = |q: &UnitQuaternion<f64>| q.euler_angles().2;
        let numeric = numdiff::jacobian(Const::<3>, STEP, |d: &Vector3<f64>| {
            SVector::<f64, 1>::new(wrap(yaw(&numdiff::left_plus(&q, d)) - yaw(&q)))
        });
        numdiff::compare(&yaw_jacobian(&q), &numeric, Tolerance::central(STEP, PI))
    });
    run("math::euler_to_global_error", switch_attitude(), |q| {
        let (roll, pitch, yaw) = q.euler_angles();
        let numeric = numdiff::jacobian(Const::<3>, STEP, |d: &Vector3<f64>| {
            numdiff::left_minus(&UnitQuaternion::from_euler_angles(roll + d.x, pitch + d.y, yaw + d.z), &q)
        });
        numdiff::compare(&euler_to_global_error(&q), &numeric, Tolerance::central(STEP, PI))
    });
}
