//! Test support: central-difference Jacobians on manifolds, compared with analytic ones.
//!
//! Shared source, not a dependency: `posegraph` declares it as a `#[cfg(test)]` module and the
//! `filter` and `mapper` crates include this same file with `#[path]` in their unit tests, so no
//! crate gains a dependency and none exports it.
//!
//! The caller's closure takes a tangent step `δ` and returns a tangent vector: it applies the
//! retraction its analytic code assumes (`x·Exp(δ)` in the graph, `Exp(δθ)·q` and `p + δp` in the
//! filter) and expresses the result in the output's tangent space at the unperturbed value (the
//! `⊖` matching that retraction), so the derivative at `δ = 0` is what the analytic matrix claims
//! to be. The rotation helpers below cover both rotation conventions of the project;
//! [`run_cases`] runs a check over proptest-drawn states (proptest is a dev-dependency of all
//! three crates) and prints the worst case.
#![allow(dead_code)] // each of the three crates uses a subset

use std::cell::RefCell;

use nalgebra::allocator::Allocator;
use nalgebra::{DefaultAllocator, Dim, Matrix, OMatrix, OVector, Storage, UnitQuaternion, Vector3};
use proptest::strategy::Strategy;
use proptest::test_runner::{Config, RngAlgorithm, TestCaseError, TestRng, TestRunner};

/// The step used unless a test says otherwise (m, rad, m/s: inputs of order one). Central
/// differences err by `h²/6·|f‴|` (truncation) plus about `ε·|f|/h` (rounding of `f(x ± h)`);
/// the sum is smallest near `h = (3ε)^(1/3) ≈ 1e-5`, where both are ~1e-11 for `|f|, |f‴| ~ 1`.
pub const STEP: f64 = 1e-5;

/// Allowed error per element: `abs + rel·|analytic|`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Tolerance {
    pub abs: f64,
    pub rel: f64,
}

impl Tolerance {
    /// From the step and the magnitude `scale` of the function's values (≥ 1; e.g. 100 for
    /// positions of 100 m, whose rounding is 100 times that of unit values).
    ///
    /// Central differences err by `h²/6·|f‴|` (truncation) plus `ε·|f|/h` (rounding of
    /// `f(x ± h)`, see [`STEP`]). Rounding depends on the size of `f`, not of the entry, so it goes
    /// into `abs` with `scale`; truncation goes with the size of the derivatives, so into `rel`.
    /// The factor 100 covers third derivatives up to ~600 times the first (rotations near π, long
    /// lever arms) and the rounding of the tens of operations in one evaluation. At `h = 1e-5`
    /// both are ~1.2e-8 for unit scale, while a real mistake (a sign, a transpose, a missing
    /// coupling) errs by the order of the entry itself.
    pub fn central(step: f64, scale: f64) -> Self {
        let truncation = step * step;
        let rounding = f64::EPSILON / step;
        Self { abs: 100.0 * (truncation + rounding * scale.max(1.0)), rel: 100.0 * (truncation + rounding) }
    }
}

/// Jacobian `∂f/∂δ` at `δ = 0` by central differences: `(f(+h·e_j) − f(−h·e_j)) / 2h`.
/// `input_dim` is the tangent dimension (`Const::<N>` or `Dyn(n)`).
pub fn jacobian<M: Dim, N: Dim>(
    input_dim: N,
    step: f64,
    mut f: impl FnMut(&OVector<f64, N>) -> OVector<f64, M>,
) -> OMatrix<f64, M, N>
where
    DefaultAllocator: Allocator<N> + Allocator<M> + Allocator<M, N>,
{
    let mut delta = OVector::<f64, N>::zeros_generic(input_dim, nalgebra::U1);
    let rows = f(&delta).shape_generic().0;
    let mut out = OMatrix::<f64, M, N>::zeros_generic(rows, input_dim);
    for j in 0..input_dim.value() {
        delta[j] = step;
        let plus = f(&delta);
        delta[j] = -step;
        let minus = f(&delta);
        delta[j] = 0.0;
        out.column_mut(j).copy_from(&((plus - minus) / (2.0 * step)));
    }
    out
}

/// The worst element of a comparison.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Comparison {
    /// Largest `|analytic − numeric|` over all elements.
    pub max_abs_error: f64,
    /// Largest error divided by its allowed error (≤ 1 passes).
    pub worst_ratio: f64,
    /// Row and column of the element with the worst ratio, and its two values.
    pub at: (usize, usize),
    pub analytic: f64,
    pub numeric: f64,
}

impl Comparison {
    pub fn passes(&self) -> bool {
        self.worst_ratio <= 1.0
    }

    /// The worse of two comparisons (by ratio); for accumulating over many states.
    pub fn worse(self, other: Self) -> Self {
        let mut out = if other.worst_ratio > self.worst_ratio { other } else { self };
        out.max_abs_error = self.max_abs_error.max(other.max_abs_error);
        out
    }

    /// A comparison that anything is worse than.
    pub fn none() -> Self {
        Self { max_abs_error: 0.0, worst_ratio: 0.0, at: (0, 0), analytic: 0.0, numeric: 0.0 }
    }
}

/// Element-wise comparison; a shape mismatch or a non-finite element counts as infinitely wrong.
/// The two may differ in how their sizes are typed (static or dynamic).
pub fn compare<R1: Dim, C1: Dim, S1: Storage<f64, R1, C1>, R2: Dim, C2: Dim, S2: Storage<f64, R2, C2>>(
    analytic: &Matrix<f64, R1, C1, S1>,
    numeric: &Matrix<f64, R2, C2, S2>,
    tolerance: Tolerance,
) -> Comparison {
    let mut out = Comparison::none();
    if analytic.shape() != numeric.shape() {
        out.worst_ratio = f64::INFINITY;
        return out;
    }
    for j in 0..analytic.ncols() {
        for i in 0..analytic.nrows() {
            let (a, n) = (analytic[(i, j)], numeric[(i, j)]);
            let error = (a - n).abs();
            let ratio =
                if error.is_finite() { error / (tolerance.abs + tolerance.rel * a.abs()) } else { f64::INFINITY };
            out.max_abs_error = out.max_abs_error.max(error);
            if ratio > out.worst_ratio {
                out = Comparison { worst_ratio: ratio, at: (i, j), analytic: a, numeric: n, ..out };
            }
        }
    }
    out
}

/// Runs `check` on `cases` values drawn by proptest with a fixed seed (so the printed worst
/// errors are reproducible), prints the worst comparison under `name` and panics on any miss
/// with proptest's minimal failing input.
pub fn run_cases<S: Strategy>(name: &str, cases: u32, strategy: S, check: impl Fn(S::Value) -> Comparison)
where
    S::Value: std::fmt::Debug,
{
    let worst = RefCell::new(Comparison::none());
    let config = Config { cases, failure_persistence: None, ..Config::default() };
    let mut runner = TestRunner::new_with_rng(config, TestRng::deterministic_rng(RngAlgorithm::ChaCha));
    let result = runner.run(&strategy, |value| {
        let c = check(value);
        let merged = worst.borrow().worse(c);
        *worst.borrow_mut() = merged;
        if c.passes() { Ok(()) } else { Err(TestCaseError::fail(format!("{c:?}"))) }
    });
    let w = worst.into_inner();
    println!(
        "{name:<46} worst |analytic − numeric| {:.1e}, worst error/tolerance {:.1e} at {:?}",
        w.max_abs_error, w.worst_ratio, w.at
    );
    if let Err(e) = result {
        panic!("{name}: {e}");
    }
}

/// `Log` of a rotation as a rotation vector (angle in [0, π]).
pub fn rotation_log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    q.scaled_axis()
}

/// Global (left) retraction `Exp(δθ)·q`: the filter's attitude error.
pub fn left_plus(q: &UnitQuaternion<f64>, delta: &Vector3<f64>) -> UnitQuaternion<f64> {
    UnitQuaternion::from_scaled_axis(*delta) * q
}

/// The inverse of [`left_plus`]: `Log(a·b⁻¹)`.
pub fn left_minus(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> Vector3<f64> {
    rotation_log(&(a * b.inverse()))
}

/// Local (right) retraction `q·Exp(δθ)`: the graph's and the measurements' convention.
pub fn right_plus(q: &UnitQuaternion<f64>, delta: &Vector3<f64>) -> UnitQuaternion<f64> {
    q * UnitQuaternion::from_scaled_axis(*delta)
}

/// The inverse of [`right_plus`]: `Log(b⁻¹·a)`.
pub fn right_minus(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>) -> Vector3<f64> {
    rotation_log(&(b.inverse() * a))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use nalgebra::{Const, Matrix2x3, Vector2};

    #[test]
    fn recovers_a_known_jacobian_and_flags_a_wrong_one() {
        let x0 = Vector3::new(0.3, -1.2, 2.0);
        let f = |d: &Vector3<f64>| {
            let x = x0 + d;
            Vector2::new(x.x * x.y, x.z.sin() + x.x * x.x * x.x)
        };
        let exact = Matrix2x3::new(x0.y, x0.x, 0.0, 3.0 * x0.x * x0.x, 0.0, x0.z.cos());
        let numeric = jacobian(Const::<3>, STEP, f);
        let tol = Tolerance::central(STEP, 2.0);
        assert!(compare(&exact, &numeric, tol).passes(), "{:?}", compare(&exact, &numeric, tol));
        let mut wrong = exact;
        wrong[(1, 2)] = -wrong[(1, 2)];
        let c = compare(&wrong, &numeric, tol);
        assert!(!c.passes() && c.at == (1, 2), "{c:?}");
    }

    #[test]
    fn rotation_helpers_invert_each_other() {
        let q = UnitQuaternion::from_scaled_axis(Vector3::new(0.4, -2.0, 1.1));
        let d = Vector3::new(1e-3, -2e-3, 5e-4);
        assert!((left_minus(&left_plus(&q, &d), &q) - d).norm() < 1e-15);
        assert!((right_minus(&right_plus(&q, &d), &q) - d).norm() < 1e-15);
    }
}
