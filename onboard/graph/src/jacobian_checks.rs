//! Every analytic Jacobian of the crate against central differences ([`crate::numdiff`]): the
//! SE(3)/SO(3) Jacobians and the adjoint of `se3`, the prior and between factors' whitened
//! Jacobians, and the robust kernels' IRLS weights (through the gradient of the factor cost).
//!
//! Perturbations use the crate's retraction `x·Exp(δ)` (`se3::retract`). Group-valued outputs are
//! compared through the chart `[t; Log R]` of the small difference element; any chart whose
//! derivative at the identity is `I` gives the same derivative, so the reference does not reuse
//! the `se3::log` under test.
//!
//! States are drawn by proptest with a fixed seed, rotation angles in five bands: below 1e-6, up
//! to 9e-3, straddling the 1e-2 switch to Taylor series, up to 3 rad, and within 1e-2 of π.
//! `cargo test -p posegraph jacobian -- --nocapture` prints the worst error of every check.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::f64::consts::PI;

use nalgebra::{Const, Isometry3, Matrix3, Matrix6, SMatrix, SVector, Translation3, UnitQuaternion, Vector3, Vector6};
use proptest::prelude::*;

use crate::factor::{Factor, Key, NoiseModel, RobustKernel};
use crate::numdiff::{self, Comparison, STEP, Tolerance};
use crate::se3::{self, Pose3};

const CASES: u32 = 1024;

fn run<S: Strategy>(name: &str, strategy: S, check: impl Fn(S::Value) -> Comparison)
where
    S::Value: std::fmt::Debug,
{
    numdiff::run_cases(name, CASES, strategy, check);
}

/// Rotation angles (rad) in the bands named in the module docs.
fn angle() -> impl Strategy<Value = f64> {
    prop_oneof![0.0..1e-6, 1e-6..9e-3, 9e-3..1.1e-2, 1.1e-2..3.0, (PI - 1e-2)..(PI - 1e-4)]
}

fn rotation_vector() -> impl Strategy<Value = Vector3<f64>> {
    (prop::array::uniform3(-1.0..1.0f64), angle()).prop_filter_map("axis", |(a, angle)| {
        let axis = Vector3::from(a);
        (axis.norm() > 1e-3).then(|| axis.normalize() * angle)
    })
}

fn translation(max_m: f64) -> impl Strategy<Value = Vector3<f64>> {
    prop::array::uniform3(-max_m..max_m).prop_map(Vector3::from)
}

/// A tangent vector `[ρ (m); φ (rad)]`.
fn tangent() -> impl Strategy<Value = Vector6<f64>> {
    (translation(5.0), rotation_vector()).prop_map(|(rho, phi)| stack(&rho, &phi))
}

fn pose() -> impl Strategy<Value = Pose3> {
    (translation(50.0), rotation_vector())
        .prop_map(|(t, phi)| Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(phi)))
}

/// A full information matrix: sigmas of 1 cm–1 m and 1 mrad–0.3 rad with random correlations.
fn information() -> impl Strategy<Value = Matrix6<f64>> {
    (prop::array::uniform6(0.0..1.0f64), prop::collection::vec(-0.4..0.4f64, 36)).prop_map(|(s, c)| {
        let sigmas =
            Vector6::from_fn(|i, _| if i < 3 { 10f64.powf(-2.0 + 2.0 * s[i]) } else { 10f64.powf(-3.0 + 2.5 * s[i]) });
        let mixing = Matrix6::identity() + Matrix6::from_column_slice(&c) * 0.5;
        let d = Matrix6::from_diagonal(&sigmas.map(|s| 1.0 / s));
        let omega = d * (mixing.transpose() * mixing) * d;
        (omega + omega.transpose()) * 0.5
    })
}

fn kernel() -> impl Strategy<Value = RobustKernel> {
    prop_oneof![
        Just(RobustKernel::Quadratic),
        (0.1..10.0f64).prop_map(|c| RobustKernel::Cauchy { c }),
        (0.1..10.0f64).prop_map(|k| RobustKernel::Huber { k }),
    ]
}

fn stack(top: &Vector3<f64>, bottom: &Vector3<f64>) -> Vector6<f64> {
    Vector6::new(top.x, top.y, top.z, bottom.x, bottom.y, bottom.z)
}

fn head(v: &Vector6<f64>) -> Vector3<f64> {
    v.fixed_rows::<3>(0).into_owned()
}

fn tail(v: &Vector6<f64>) -> Vector3<f64> {
    v.fixed_rows::<3>(3).into_owned()
}

/// Chart of SE(3) near the identity, `[t; Log R]` (see the module docs).
fn chart(t: &Pose3) -> Vector6<f64> {
    stack(&t.translation.vector, &numdiff::rotation_log(&t.rotation))
}

/// Its inverse, `(ρ, Exp φ)`.
fn chart_inv(delta: &Vector6<f64>) -> Pose3 {
    Isometry3::from_parts(Translation3::from(head(delta)), UnitQuaternion::from_scaled_axis(tail(delta)))
}

/// The largest magnitude among values, floor 1 (the rounding scale of [`Tolerance::central`]).
fn scale_of<'a>(values: impl IntoIterator<Item = &'a f64>) -> f64 {
    values.into_iter().fold(1.0, |m, v| m.max(v.abs()))
}

fn check<const R: usize, const C: usize>(
    analytic: &SMatrix<f64, R, C>,
    numeric: &SMatrix<f64, R, C>,
    scale: f64,
) -> Comparison {
    numdiff::compare(analytic, numeric, Tolerance::central(STEP, scale))
}

#[test]
fn so3_left_jacobian() {
    run("so3_left_jacobian", rotation_vector(), |phi| {
        let r = se3::so3_exp(&phi);
        let numeric = numdiff::jacobian(Const::<3>, STEP, |d| numdiff::left_minus(&se3::so3_exp(&(phi + d)), &r));
        check(&se3::so3_left_jacobian(&phi), &numeric, 1.0)
    });
}

#[test]
fn so3_left_jacobian_inv() {
    run("so3_left_jacobian_inv", rotation_vector(), |phi| {
        let r = se3::so3_exp(&phi);
        let numeric = numdiff::jacobian(Const::<3>, STEP, |d| se3::so3_log(&numdiff::left_plus(&r, d)) - phi);
        check(&se3::so3_left_jacobian_inv(&phi), &numeric, PI)
    });
}

#[test]
fn se3_left_jacobian() {
    run("se3::left_jacobian", tangent(), |xi| {
        let t = se3::exp(&xi);
        let numeric = numdiff::jacobian(Const::<6>, STEP, |d| chart(&(se3::exp(&(xi + d)) * t.inverse())));
        check(&se3::left_jacobian(&xi), &numeric, scale_of(xi.iter()))
    });
}

#[test]
fn se3_left_jacobian_inv() {
    run("se3::left_jacobian_inv", tangent(), |xi| {
        let t = se3::exp(&xi);
        let numeric = numdiff::jacobian(Const::<6>, STEP, |d| se3::log(&(chart_inv(d) * t)) - xi);
        check(&se3::left_jacobian_inv(&xi), &numeric, scale_of(xi.iter()))
    });
}

#[test]
fn se3_right_jacobian() {
    run("se3::right_jacobian", tangent(), |xi| {
        let t_inv = se3::exp(&xi).inverse();
        let numeric = numdiff::jacobian(Const::<6>, STEP, |d| chart(&(t_inv * se3::exp(&(xi + d)))));
        check(&se3::right_jacobian(&xi), &numeric, scale_of(xi.iter()))
    });
}

#[test]
fn se3_right_jacobian_inv() {
    run("se3::right_jacobian_inv", tangent(), |xi| {
        let t = se3::exp(&xi);
        let numeric = numdiff::jacobian(Const::<6>, STEP, |d| se3::log(&(t * chart_inv(d))) - xi);
        check(&se3::right_jacobian_inv(&xi), &numeric, scale_of(xi.iter()))
    });
}

#[test]
fn se3_adjoint() {
    run("se3::adjoint", pose(), |t| {
        let numeric = numdiff::jacobian(Const::<6>, STEP, |d| chart(&(t * chart_inv(d) * t.inverse())));
        check(&se3::adjoint(&t), &numeric, scale_of(t.translation.vector.iter()))
    });
}

/// A factor state: the poses, and the error the factor should have there (so that errors near
/// π and near zero are drawn as often as typical ones).
#[derive(Debug, Clone)]
struct FactorCase {
    x_from: Pose3,
    x_to: Pose3,
    error: Vector6<f64>,
    information: Matrix6<f64>,
    kernel: RobustKernel,
}

fn factor_case() -> impl Strategy<Value = FactorCase> {
    (pose(), pose(), tangent(), information(), kernel())
        .prop_map(|(x_from, x_to, error, information, kernel)| FactorCase { x_from, x_to, error, information, kernel })
}

impl FactorCase {
    /// The rounding of the whitened error `R·e` in units of ε: `e` is computed from poses whose
    /// translations carry `ε·|t|` each, and `R` amplifies it by up to `√λ_max(Ω)`.
    fn whitened_error_rounding(&self) -> f64 {
        let t =
            [&self.x_from, &self.x_to].iter().map(|x| x.translation.vector.amax()).fold(self.error.amax(), f64::max);
        self.information.symmetric_eigenvalues().max().sqrt() * t.max(1.0)
    }

    fn noise(&self, kernel: RobustKernel) -> NoiseModel {
        NoiseModel::from_information(self.information).unwrap().with_kernel(kernel)
    }

    /// A prior on `x_from` whose error there is `self.error`.
    fn prior(&self, kernel: RobustKernel) -> Factor {
        let measured = self.x_from * se3::exp(&self.error).inverse();
        Factor::prior(Key(0), measured, self.noise(kernel))
    }

    /// A between factor whose error at `(x_from, x_to)` is `self.error`.
    fn between(&self, kernel: RobustKernel) -> Factor {
        let measured = self.x_from.inverse() * self.x_to * se3::exp(&self.error).inverse();
        Factor::between(Key(0), Key(1), measured, self.noise(kernel))
    }
}

/// Both variables perturbed: `δ = [δ_from; δ_to]`.
fn perturbed(case: &FactorCase, d: &SVector<f64, 12>) -> [Pose3; 2] {
    let d_from: Vector6<f64> = d.fixed_rows::<6>(0).into_owned();
    let d_to: Vector6<f64> = d.fixed_rows::<6>(6).into_owned();
    [se3::retract(&case.x_from, &d_from), se3::retract(&case.x_to, &d_to)]
}

/// The whitened Jacobians `[A_from | A_to]` of `factor` against the derivative of its whitened
/// error `−b(x ⊕ δ)` (least-squares kernel: `b = −R·e` exactly, no weight). A prior reads
/// `poses[0]` only, so its `A_to` must be zero, which the derivative confirms.
fn whitened_jacobians(case: &FactorCase, factor: &Factor) -> Comparison {
    let lin = factor.linearize([&case.x_from, &case.x_to]);
    let mut analytic = SMatrix::<f64, 6, 12>::zeros();
    analytic.fixed_view_mut::<6, 6>(0, 0).copy_from(&lin.jacobians[0]);
    analytic.fixed_view_mut::<6, 6>(0, 6).copy_from(&lin.jacobians[1]);
    let numeric = numdiff::jacobian(Const::<12>, STEP, |d| {
        let [a, b] = perturbed(case, d);
        -factor.linearize([&a, &b]).rhs
    });
    check(&analytic, &numeric, case.whitened_error_rounding())
}

#[test]
fn prior_factor_jacobian() {
    run("prior factor (whitened)", factor_case(), |case| {
        whitened_jacobians(&case, &case.prior(RobustKernel::Quadratic))
    });
}

#[test]
fn between_factor_jacobians() {
    run("between factor (whitened)", factor_case(), |case| {
        whitened_jacobians(&case, &case.between(RobustKernel::Quadratic))
    });
}

/// With a robust kernel the linear model is IRLS's, `A = √w·R·J`, `b = −√w·R·e`, which is not the
/// derivative of anything; what must hold is that its gradient `−Aᵀb = w·JᵀΩe` is the gradient of
/// the robust cost `ρ(d²(x ⊕ δ))`. That checks `w = 2·dρ/d(d²)` and the Jacobians together.
///
/// The cost varies on the scale of the smallest sigma (and of `c`/`k` times it with a kernel), so
/// the step is taken in units of that length: `δ = L·u`, derivatives with respect to `u`.
fn cost_gradient(case: &FactorCase, factor: &Factor) -> Comparison {
    let lin = factor.linearize([&case.x_from, &case.x_to]);
    let kernel_scale = match case.kernel {
        RobustKernel::Quadratic => 1.0,
        RobustKernel::Cauchy { c } => c.min(1.0),
        RobustKernel::Huber { k } => k.min(1.0),
    };
    let length = kernel_scale / case.information.symmetric_eigenvalues().max().sqrt();
    let mut analytic = SMatrix::<f64, 1, 12>::zeros();
    analytic.fixed_view_mut::<1, 6>(0, 0).copy_from(&-(lin.jacobians[0].transpose() * lin.rhs).transpose());
    analytic.fixed_view_mut::<1, 6>(0, 6).copy_from(&-(lin.jacobians[1].transpose() * lin.rhs).transpose());
    let numeric = numdiff::jacobian(Const::<12>, STEP, |u| {
        let [a, b] = perturbed(case, &(u * length));
        SVector::<f64, 1>::new(factor.cost([&a, &b]))
    });
    // A cost `ρ(d)` moves by at most `d·δd` when `d` does (ρ′(d) = w·d ≤ d).
    let cost = factor.cost([&case.x_from, &case.x_to]);
    let d = NoiseModel::from_information(case.information).unwrap().mahalanobis_squared(&case.error).sqrt();
    check(&(analytic * length), &numeric, cost.max(d * case.whitened_error_rounding()))
}

/// Huber's loss has no second derivative at `d = k`; central differences straddling it are
/// first-order accurate only, so states within 1e-3 of the kink are skipped.
fn away_from_huber_kink(case: &FactorCase) -> bool {
    match case.kernel {
        RobustKernel::Huber { k } => {
            let d = NoiseModel::from_information(case.information).unwrap().mahalanobis_squared(&case.error).sqrt();
            (d - k).abs() > 1e-3
        }
        _ => true,
    }
}

#[test]
fn prior_factor_robust_gradient() {
    run("prior factor, robust cost gradient", factor_case().prop_filter("kink", away_from_huber_kink), |case| {
        cost_gradient(&case, &case.prior(case.kernel))
    });
}

#[test]
fn between_factor_robust_gradient() {
    run("between factor, robust cost gradient", factor_case().prop_filter("kink", away_from_huber_kink), |case| {
        cost_gradient(&case, &case.between(case.kernel))
    });
}

/// The IRLS weight alone: `w(d²) = 2·dρ/d(d²)` (GTSAM's `weight = ρ'(d)/d`).
#[test]
fn robust_kernel_weight_is_the_loss_derivative() {
    let strategy = (kernel(), -4.0..4.0f64).prop_map(|(kernel, log_d2)| (kernel, 10f64.powf(log_d2))).prop_filter(
        "kink",
        |(kernel, d2)| match kernel {
            RobustKernel::Huber { k } => (d2.sqrt() - k).abs() > 1e-3 * k.max(1.0),
            _ => true,
        },
    );
    run("robust kernel weight vs dρ/d(d²)", strategy, |(kernel, d2)| {
        // A relative step: d² spans eight decades.
        let step = STEP * d2;
        let numeric = numdiff::jacobian(Const::<1>, step, |d| SVector::<f64, 1>::new(2.0 * kernel.loss(d2 + d[0])));
        let analytic = SMatrix::<f64, 1, 1>::new(kernel.weight(d2));
        numdiff::compare(&analytic, &numeric, Tolerance::central(STEP, 1.0))
    });
}

/// Near π, `1 + cos θ` cancels; the coefficient of `J_l⁻¹` is computed through `cot(θ/2)`, which
/// keeps `J_l⁻¹·J_l = I` to rounding. With `(1 + cos θ)/sin θ` it was off by up to 4e-11 at
/// `π − θ = 1e-6`, and `log`'s translation carried `ε·|t|/(π − θ)` of noise (numdiff saw it).
#[test]
fn so3_left_jacobian_inv_is_accurate_near_pi() {
    for gap in [1e-2, 1e-3, 1e-4, 1e-5, 1e-6, 1e-7] {
        for i in 0..50 {
            let s = f64::from(i);
            let axis = Vector3::new((0.7 * s).sin(), (1.3 * s).cos(), 0.3 + (0.37 * s).sin()).normalize();
            let phi = axis * (PI - gap);
            let product = se3::so3_left_jacobian_inv(&phi) * se3::so3_left_jacobian(&phi);
            let error = (product - Matrix3::identity()).amax();
            assert!(error < 1e-14, "π − θ = {gap:e}: |J_l⁻¹·J_l − I| = {error:e}");
        }
    }
}
