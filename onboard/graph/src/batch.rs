//! Batch Levenberg–Marquardt on the manifold, over a multifrontal Cholesky factorization with a
//! minimum-degree ordering computed once per problem.

use nalgebra::{Matrix6, Vector6};

use crate::anchoring::Anchoring;
use crate::bayes_tree::BayesTree;
use crate::error::GraphError;
use crate::factor::{Factor, Key};
use crate::linear::{Damping, LinearFactor};
use crate::ordering;
use crate::se3::{self, Pose3};
use crate::values::Values;

/// Stopping rules and damping schedule. Defaults match GTSAM's `LevenbergMarquardtParams`
/// where they mean the same thing (tolerances, iteration cap of 100).
#[derive(Debug, Clone, PartialEq)]
pub struct LmParams {
    pub max_iterations: usize,
    /// Stop when an accepted step lowers the cost by less than this fraction.
    pub relative_tolerance: f64,
    /// Stop when an accepted step lowers the cost by less than this.
    pub absolute_tolerance: f64,
    /// Initial damping, relative to the information's diagonal (Marquardt scaling). It is
    /// divided by 10 after each successful step and multiplied by 10 after a failed one.
    pub initial_lambda: f64,
    /// Give up raising the damping beyond this.
    pub max_lambda: f64,
    /// Threads of the numeric factorization. With 2 or more, two independent subtrees of the
    /// elimination tree are factored concurrently when that saves at least
    /// [`MIN_THREADED_FLOPS`] (larger counts currently also use two). 1 is the sequential path.
    /// Results are bit-identical for every value.
    pub threads: usize,
}

/// Estimated flops a two-thread factorization must take off the calling thread before it is
/// used: below this, spawning and joining the thread costs more than it saves. smallGrid3D
/// (125 poses, 1.4e6 flops saved per factorization) lost 0.15 ms per factorization on two
/// threads; see `BENCHMARKS.md`, "Two threads".
pub const MIN_THREADED_FLOPS: f64 = 1.0e7;

/// The default thread count: the available parallelism, capped at 2.
pub fn default_threads() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get().min(2))
}

impl Default for LmParams {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            relative_tolerance: 1e-5,
            absolute_tolerance: 1e-5,
            initial_lambda: 1e-5,
            max_lambda: 1e10,
            threads: default_threads(),
        }
    }
}

/// Why the optimizer stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Termination {
    /// The cost decrease fell below a tolerance.
    Converged,
    /// `max_iterations` linearizations done.
    MaxIterations,
    /// No step lowered the cost even at the largest damping.
    NoProgress,
}

/// Result of a batch optimization.
#[derive(Debug, Clone, PartialEq)]
pub struct LmSummary {
    pub initial_cost: f64,
    pub final_cost: f64,
    /// Linearizations (outer iterations), as GTSAM counts them.
    pub iterations: usize,
    /// Factorizations, including those of rejected steps.
    pub factorizations: usize,
    /// Factorizations that ran on two threads.
    pub threaded_factorizations: usize,
    pub termination: Termination,
    /// Time spent on the fill-reducing ordering (part of the total), reported apart as GTSAM
    /// reports its COLAMD.
    pub ordering_ms: f64,
}

/// Dense variable indices of every factor; errors on a key without a value.
pub(crate) fn factor_indices(factors: &[Factor], values: &Values) -> Result<Vec<[usize; 2]>, GraphError> {
    factors
        .iter()
        .map(|f| {
            let mut out = [0usize; 2];
            for (k, &key) in f.keys().iter().enumerate() {
                out[k] = values.index_of(key).ok_or(GraphError::UnknownVariable(key))?;
            }
            if f.arity() == 1 {
                out[1] = out[0];
            }
            Ok(out)
        })
        .collect()
}

/// Total cost `Σ ρ_i` of the factors at the given values (GTSAM's `graph.error(values)`).
pub fn total_cost(factors: &[Factor], values: &Values) -> Result<f64, GraphError> {
    let indices = factor_indices(factors, values)?;
    Ok(cost_at(factors, &indices, values.poses()))
}

pub(crate) fn cost_at(factors: &[Factor], indices: &[[usize; 2]], poses: &[Pose3]) -> f64 {
    factors.iter().zip(indices).map(|(f, &[a, b])| f.cost([&poses[a], &poses[b]])).sum()
}

pub(crate) fn linearize_into(factor: &Factor, vars: [usize; 2], poses: &[Pose3]) -> LinearFactor {
    let lin = factor.linearize([&poses[vars[0]], &poses[vars[1]]]);
    LinearFactor { vars, arity: factor.arity(), jacobians: lin.jacobians, rhs: lin.rhs }
}

/// Checks that the graph is positive definite in structure: every variable is reachable from
/// a prior through factors (otherwise its gauge is free and Cholesky would fail).
pub(crate) fn check_anchored(factors: &[Factor], indices: &[[usize; 2]], values: &Values) -> Result<(), GraphError> {
    let mut anchoring = Anchoring::new(values.len());
    for (f, &[a, b]) in factors.iter().zip(indices) {
        anchoring.join(a, if f.arity() == 1 { anchoring.anchor() } else { b });
    }
    if let Some(v) = (0..values.len()).find(|&v| !anchoring.is_anchored(v)) {
        return Err(GraphError::Unconstrained(values.keys()[v]));
    }
    Ok(())
}

/// A factored problem: ordering and symbolic structure computed once, reused by every
/// iteration and by the marginals.
#[derive(Debug)]
pub(crate) struct Factored {
    pub tree: BayesTree,
    symbolic: Vec<crate::bayes_tree::SymbolicClique>,
    /// Clique ids in postorder once the tree is committed.
    postorder: Vec<usize>,
    pub ordering_ms: f64,
    threads: usize,
    /// Where the factorization splits over two threads, if it pays.
    split: Option<crate::bayes_tree::ParallelSplit>,
}

impl Factored {
    pub fn analyse(indices: &[[usize; 2]], arities: &[usize], n: usize, lin: &[LinearFactor], threads: usize) -> Self {
        let edges: Vec<&[usize]> = indices.iter().zip(arities).map(|(v, &a)| &v[..a]).collect();
        let started = std::time::Instant::now();
        let order = ordering::order(n, edges.iter().copied(), &[]);
        let ordering_ms = started.elapsed().as_secs_f64() * 1e3;
        let mut tree = BayesTree::default();
        tree.ensure_vars(n);
        tree.assign_positions(&order);
        let all: Vec<usize> = (0..lin.len()).collect();
        let symbolic = tree.symbolic(&order, &all, lin, &[]);
        Self { tree, symbolic, postorder: Vec::new(), ordering_ms, threads, split: None }
    }

    /// Factors the whole system (optionally damped) and stores it in the tree. Returns whether
    /// it ran on two threads.
    pub fn factor(&mut self, lin: &[LinearFactor], damping: Option<Damping<'_>>) -> Result<bool, usize> {
        if self.postorder.is_empty() {
            // Commit the structure with empty buffers so that every factorization, the first
            // included, takes the same (possibly threaded) refactoring path.
            let empty = vec![Default::default(); self.symbolic.len()];
            self.postorder = self.tree.commit(&[], std::mem::take(&mut self.symbolic), empty);
            if self.threads >= 2 {
                self.split = self.tree.plan_split().filter(|s| s.saved_flops >= MIN_THREADED_FLOPS);
            }
        }
        match &self.split {
            Some(split) => self.tree.refactor_split(split, lin, damping).map(|()| true),
            None => self.tree.refactor(&self.postorder, lin, damping).map(|()| false),
        }
        .map_err(|e| e.var)
    }
}

/// Optimizes `values` in place. The problem must be anchored (every variable connected to a
/// prior); see [`GraphError::Unconstrained`].
pub fn optimize(factors: &[Factor], values: &mut Values, params: &LmParams) -> Result<LmSummary, GraphError> {
    let indices = factor_indices(factors, values)?;
    check_anchored(factors, &indices, values)?;
    let n = values.len();
    let arities: Vec<usize> = factors.iter().map(Factor::arity).collect();
    let mut lin: Vec<LinearFactor> =
        factors.iter().zip(&indices).map(|(f, &v)| linearize_into(f, v, values.poses())).collect();
    let mut factored = Factored::analyse(&indices, &arities, n, &lin, params.threads);

    let initial_cost = cost_at(factors, &indices, values.poses());
    let mut cost = initial_cost;
    let mut lambda = params.initial_lambda;
    let mut iterations = 0;
    let mut factorizations = 0;
    let mut threaded_factorizations = 0;
    let mut delta = vec![Vector6::zeros(); n];
    let mut diagonal = vec![Vector6::zeros(); n];
    let mut trial: Vec<Pose3> = values.poses().to_vec();
    let mut termination = Termination::MaxIterations;
    while iterations < params.max_iterations {
        iterations += 1;
        for (l, (f, &v)) in lin.iter_mut().zip(factors.iter().zip(&indices)) {
            *l = linearize_into(f, v, values.poses());
        }
        information_diagonal(&lin, &mut diagonal);
        let mut accepted = false;
        let mut converged = false;
        while lambda <= params.max_lambda {
            factorizations += 1;
            match factored.factor(&lin, Some(Damping { lambda, diagonal: &diagonal })) {
                Ok(threaded) => threaded_factorizations += usize::from(threaded),
                Err(_) => {
                    lambda = (lambda * 10.0).max(params.initial_lambda);
                    continue;
                }
            }
            factored.tree.solve_all(&mut delta);
            for (t, (x, d)) in trial.iter_mut().zip(values.poses().iter().zip(&delta)) {
                *t = se3::retract(x, d);
            }
            let new_cost = cost_at(factors, &indices, &trial);
            let predicted: f64 = lin.iter().map(|l| l.model_decrease(&delta)).sum();
            let actual = cost - new_cost;
            if new_cost.is_finite() && actual > 0.0 && predicted > 0.0 {
                // Long chains have eigenvalues near 1/n² of the diagonal, so any damping that
                // lingers slows Gauss–Newton's quadratic convergence: shrink it fast on success.
                lambda = if actual > 0.25 * predicted { lambda / 10.0 } else { lambda };
                if lambda < 1e-15 {
                    lambda = 0.0;
                }
                values.poses_mut().copy_from_slice(&trial);
                converged = actual < params.absolute_tolerance || actual < params.relative_tolerance * cost;
                cost = new_cost;
                accepted = true;
                break;
            }
            if actual.abs() <= params.absolute_tolerance.min(params.relative_tolerance * cost) {
                // The model says we are at the minimum to within the tolerances.
                converged = true;
                break;
            }
            lambda = (lambda * 10.0).max(params.initial_lambda);
        }
        if converged {
            termination = Termination::Converged;
            break;
        }
        if !accepted {
            termination = Termination::NoProgress;
            break;
        }
    }
    Ok(LmSummary {
        initial_cost,
        final_cost: cost,
        iterations,
        factorizations,
        threaded_factorizations,
        termination,
        ordering_ms: factored.ordering_ms,
    })
}

/// Diagonal of the information matrix per variable, clamped as Ceres does so that damping
/// never vanishes on a weakly observed direction.
fn information_diagonal(lin: &[LinearFactor], diagonal: &mut [Vector6<f64>]) {
    for d in diagonal.iter_mut() {
        *d = Vector6::zeros();
    }
    for l in lin {
        for k in 0..l.arity {
            let j: &Matrix6<f64> = &l.jacobians[k];
            for (d, column) in diagonal[l.vars[k]].iter_mut().zip(j.column_iter()) {
                *d += column.norm_squared();
            }
        }
    }
    for d in diagonal.iter_mut() {
        d.apply(|x| *x = x.clamp(1e-6, 1e32));
    }
}

/// Marginal covariances of `keys` at `values` (undamped linearization), tangent order
/// `[translation, rotation]`, without forming the inverse of the full information matrix.
pub fn marginal_covariances(
    factors: &[Factor],
    values: &Values,
    keys: &[Key],
) -> Result<Vec<Matrix6<f64>>, GraphError> {
    let indices = factor_indices(factors, values)?;
    check_anchored(factors, &indices, values)?;
    let vars: Vec<usize> =
        keys.iter().map(|&k| values.index_of(k).ok_or(GraphError::UnknownVariable(k))).collect::<Result<_, _>>()?;
    let arities: Vec<usize> = factors.iter().map(Factor::arity).collect();
    let lin: Vec<LinearFactor> =
        factors.iter().zip(&indices).map(|(f, &v)| linearize_into(f, v, values.poses())).collect();
    let mut factored = Factored::analyse(&indices, &arities, values.len(), &lin, 1);
    factored.factor(&lin, None).map_err(|v| GraphError::NotPositiveDefinite(values.keys()[v]))?;
    Ok(factored.tree.marginals(&vars))
}

#[cfg(test)]
mod tests {
    use nalgebra::{DMatrix, DVector};

    use super::*;
    use crate::factor::NoiseModel;

    /// A small loop-rich graph with noisy initial values.
    fn grid_problem() -> (Vec<Factor>, Values) {
        let mut values = Values::new();
        let mut factors = Vec::new();
        let noise = NoiseModel::from_sigmas([0.1, 0.1, 0.1, 0.05, 0.05, 0.05]).unwrap();
        let pose = |i: usize| {
            let (x, y) = ((i % 4) as f64, (i / 4) as f64);
            se3::exp(&Vector6::new(x, y, 0.1 * x * y, 0.1 * x, -0.05 * y, 0.3 * (x + y)))
        };
        for i in 0..16 {
            let noise_vec = Vector6::from_fn(|r, _| (((i * 7 + r * 13) % 11) as f64 - 5.0) * 0.02);
            values.insert(Key(i as u64), se3::retract(&pose(i), &noise_vec)).unwrap();
        }
        factors.push(Factor::prior(Key(0), pose(0), noise.clone()));
        for i in 0..16 {
            for j in [i + 1, i + 4] {
                if j < 16 && (j != i + 1 || i % 4 != 3) {
                    factors.push(Factor::between(
                        Key(i as u64),
                        Key(j as u64),
                        pose(i).inverse() * pose(j),
                        noise.clone(),
                    ));
                }
            }
        }
        (factors, values)
    }

    #[test]
    fn multifrontal_step_equals_dense_solve() {
        let (factors, values) = grid_problem();
        let indices = factor_indices(&factors, &values).unwrap();
        let arities: Vec<usize> = factors.iter().map(Factor::arity).collect();
        let lin: Vec<LinearFactor> =
            factors.iter().zip(&indices).map(|(f, &v)| linearize_into(f, v, values.poses())).collect();
        let n = values.len();
        let mut h = DMatrix::<f64>::zeros(6 * n, 6 * n);
        let mut r = DVector::<f64>::zeros(6 * n);
        for l in &lin {
            for a in 0..l.arity {
                let mut ra = r.fixed_rows_mut::<6>(6 * l.vars[a]);
                ra += l.jacobians[a].transpose() * l.rhs;
                for b in 0..l.arity {
                    let mut block = h.fixed_view_mut::<6, 6>(6 * l.vars[a], 6 * l.vars[b]);
                    block += l.jacobians[a].transpose() * l.jacobians[b];
                }
            }
        }
        let dense = h.clone().cholesky().unwrap().solve(&r);
        let mut factored = Factored::analyse(&indices, &arities, n, &lin, 1);
        factored.factor(&lin, None).unwrap();
        let mut delta = vec![Vector6::zeros(); n];
        factored.tree.solve_all(&mut delta);
        for (v, step) in delta.iter().enumerate() {
            let expected = dense.fixed_rows::<6>(6 * v).into_owned();
            assert!((step - expected).amax() < 1e-9, "variable {v}: {step} vs {expected}");
        }
        // Marginals against the dense inverse.
        let inverse = h.try_inverse().unwrap();
        let vars: Vec<usize> = (0..n).collect();
        let marginals = factored.tree.marginals(&vars);
        for (v, marginal) in marginals.iter().enumerate() {
            let expected = inverse.fixed_view::<6, 6>(6 * v, 6 * v).into_owned();
            assert!((marginal - expected).amax() < 1e-9 * expected.amax(), "variable {v}");
        }
    }
}
