//! Levenberg–Marquardt ICP on the full clouds (§6.1.2 e, trap T13), in 4 parameters (x, y, z,
//! yaw; roll and pitch exactly as initialised) or 6.
//!
//! Parametrisation. The estimate `T = t_target_source` is updated on the right,
//! `T ← T·Δ(δ)` with `Δ(δ) = (Rz(δ_yaw), δ_xyz)` in 4D (which keeps a gravity-aligned `T`
//! gravity-aligned: the thesis restricts roll and pitch inside the optimiser, not after it) and
//! `Δ(δ) = (Exp(δ_rot), δ_xyz)` in 6D. To first order this is the graph's retraction
//! `T·Exp([ρ; φ])`, so the normal equations at the optimum are directly in the graph's tangent
//! (see `covariance`).
//!
//! Residual ([`IcpMetric`]). Point-to-plane by default: `n_qᵀ(T·s − q)` with the target
//! point's normal. The thesis's point-to-point residual `T·s − q` is available; on terrain it
//! needs ~100 iterations where point-to-plane needs ~10 (see [`IcpMetric::PointToPoint`]).
//! Either way the reported RMSE is the point-to-point one of the final pairs, as the thesis's.
//!
//! Pairs. Each source point, moved by the current estimate, is paired with its nearest target
//! point if closer than a gate that starts at `icp_max_distance_start_m` and shrinks by
//! `icp_distance_shrink` per iteration down to `icp_max_distance_final_m`: a wide gate first so
//! that a RANSAC estimate a few decimetres off still finds its surfaces, a narrow one at the end
//! so that points without a counterpart (the non-overlapping parts) do not bias the estimate.
//! The gate is the only trimming: no robust weights, which keeps the final RMSE and the
//! covariance's residual variance the plain statistics of the inlier pairs. While the gate is
//! above its floor only every `icp_coarse_stride`-th source point is paired.
//!
//! Per pair set, LM iterates (at most [`INNER_ITERATIONS`]) with Marquardt's diagonal damping;
//! with fixed pairs the problem is nearly linear, so it mostly accepts the first Gauss–Newton
//! step. The loop ends when, at the final gate, a step moves the estimate by less than the
//! epsilons.

use std::collections::HashSet;

use nalgebra::{Isometry3, Matrix6, Point3, RowVector6, Translation3, UnitQuaternion, Vector3, Vector6};

use super::params::{IcpMetric, MatchMode, MatcherParams};
use super::prepared::PreparedCloud;
use super::spatial::PointIndex;
use crate::cloud::VoxelBuildHasher;

const INNER_ITERATIONS: usize = 5;

/// Why ICP gave no estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum IcpFailure {
    TooFewPairs,
    Degenerate,
}

#[derive(Debug, Clone, PartialEq)]
pub(crate) struct IcpResult {
    pub t_target_source: Isometry3<f64>,
    /// (source index, target index) pairs within the final gate at the final estimate.
    pub pairs: Vec<(usize, usize)>,
    /// Point-to-point RMSE over `pairs`.
    pub rmse_m: f64,
    pub iterations: usize,
}

/// The clouds and the residual of one ICP problem.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Problem<'a> {
    pub source: &'a [Point3<f32>],
    pub target: &'a [Point3<f32>],
    /// Target normals; pairs whose target point has none are not formed in point-to-plane mode.
    pub target_normals: &'a [Option<Vector3<f32>>],
    pub metric: IcpMetric,
}

impl<'a> Problem<'a> {
    /// The ICP problem of `source` into `target` with `metric` (target normals only where the
    /// residual reads them: computing them is the expensive part).
    pub(crate) fn between(source: &'a PreparedCloud, target: &'a PreparedCloud, metric: IcpMetric) -> Problem<'a> {
        Problem {
            source: source.positions(),
            target: target.positions(),
            target_normals: match metric {
                IcpMetric::PointToPlane => target.normals(),
                IcpMetric::PointToPoint => &[],
            },
            metric,
        }
    }

    /// JᵀJ, Jᵀe and Σe² over `pairs` at `t`, in the full 6-D tangent `[ρ, φ]`.
    ///
    /// With `A_i = [I, −[s_i]×]` the Jacobian of `Δ(δ)·s_i` at δ = 0, the point-to-point
    /// residual's Jacobian is `R·A_i` (R cancels in JᵀJ; Jᵀe = A_iᵀ(Rᵀe)) and the
    /// point-to-plane residual's is `n_iᵀR·A_i = [m_iᵀ, (s_i × m_i)ᵀ]` with `m_i = Rᵀn_i`.
    pub(crate) fn normal_equations(
        &self,
        t: &Isometry3<f64>,
        pairs: &[(usize, usize)],
    ) -> (Matrix6<f64>, Vector6<f64>, f64) {
        let r_t = t.rotation.inverse();
        let mut h = Matrix6::zeros();
        let mut g = Vector6::zeros();
        let mut cost = 0.0;
        for &(si, ti) in pairs {
            let s = self.source[si].coords.cast::<f64>();
            let e = t * Point3::from(s) - self.target[ti].cast::<f64>();
            match self.metric {
                IcpMetric::PointToPoint => {
                    let e_source = r_t * e;
                    let mut a = nalgebra::Matrix3x6::zeros();
                    a.fixed_view_mut::<3, 3>(0, 0).fill_with_identity();
                    a.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-s.cross_matrix()));
                    h += a.transpose() * a;
                    g += a.transpose() * e_source;
                    cost += e.norm_squared();
                }
                IcpMetric::PointToPlane => {
                    let Some(n) = self.target_normals.get(ti).copied().flatten() else { continue };
                    let n = n.cast::<f64>();
                    let r = n.dot(&e);
                    let m = r_t * n;
                    let c = s.cross(&m);
                    let row = RowVector6::new(m.x, m.y, m.z, c.x, c.y, c.z);
                    h += row.transpose() * row;
                    g += row.transpose() * r;
                    cost += r * r;
                }
            }
        }
        (h, g, cost)
    }

    fn cost(&self, t: &Isometry3<f64>, pairs: &[(usize, usize)]) -> f64 {
        pairs
            .iter()
            .map(|&(si, ti)| {
                let e = t * self.source[si].cast::<f64>() - self.target[ti].cast::<f64>();
                match self.metric {
                    IcpMetric::PointToPoint => e.norm_squared(),
                    IcpMetric::PointToPlane => {
                        self.target_normals.get(ti).copied().flatten().map_or(0.0, |n| n.cast::<f64>().dot(&e).powi(2))
                    }
                }
            })
            .sum()
    }

    fn point_rmse(&self, t: &Isometry3<f64>, pairs: &[(usize, usize)]) -> f64 {
        let sum: f64 = pairs
            .iter()
            .map(|&(si, ti)| (t * self.source[si].cast::<f64>() - self.target[ti].cast::<f64>()).norm_squared())
            .sum();
        (sum / pairs.len().max(1) as f64).sqrt()
    }

    fn pairs_within(
        &self,
        t: &Isometry3<f64>,
        index: &PointIndex,
        coverage: &Coverage,
        gate_m: f64,
        stride: usize,
        out: &mut Vec<(usize, usize)>,
    ) {
        out.clear();
        let gate2 = (gate_m * gate_m) as f32;
        let tf = t.cast::<f32>();
        let need_normal = self.metric == IcpMetric::PointToPlane;
        for si in (0..self.source.len()).step_by(stride.max(1)) {
            let moved = tf * self.source[si];
            if !coverage.near(&moved) {
                continue;
            }
            if let Some((ti, d2)) = index.nearest(&moved)
                && d2 <= gate2
                && (!need_normal || self.target_normals.get(ti).is_some_and(Option::is_some))
            {
                out.push((si, ti));
            }
        }
    }
}

/// The cells of side `cell_m` within one cell of a target point: a source point outside them has
/// no target point within `cell_m`, so its nearest-neighbour query (the most expensive kind: far
/// from the tree's points, it backtracks through many leaves) is skipped. On partially
/// overlapping submaps that is about half the source points.
#[derive(Debug)]
struct Coverage {
    cell_m: f32,
    cells: HashSet<[i32; 3], VoxelBuildHasher>,
}

impl Coverage {
    fn new(target: &[Point3<f32>], cell_m: f64) -> Coverage {
        let cell_m = cell_m.max(1e-3) as f32;
        let mut occupied: HashSet<[i32; 3], VoxelBuildHasher> = HashSet::default();
        for p in target {
            occupied.insert(Self::key(cell_m, p));
        }
        let mut cells = HashSet::with_capacity_and_hasher(occupied.len() * 4, VoxelBuildHasher::default());
        for c in &occupied {
            for n in 0..27 {
                cells.insert([c[0] + n % 3 - 1, c[1] + (n / 3) % 3 - 1, c[2] + n / 9 - 1]);
            }
        }
        Coverage { cell_m, cells }
    }

    fn key(cell_m: f32, p: &Point3<f32>) -> [i32; 3] {
        // Saturating float-to-int casts keep far or non-finite points harmless.
        [(p.x / cell_m).floor() as i32, (p.y / cell_m).floor() as i32, (p.z / cell_m).floor() as i32]
    }

    fn near(&self, p: &Point3<f32>) -> bool {
        self.cells.contains(&Self::key(self.cell_m, p))
    }
}

/// The tangent indices the mode estimates, in `[ρx, ρy, ρz, φx, φy, φz]`.
pub(crate) fn active_indices(mode: MatchMode) -> &'static [usize] {
    match mode {
        MatchMode::FourDof => &[0, 1, 2, 5],
        MatchMode::SixDof => &[0, 1, 2, 3, 4, 5],
    }
}

/// `Δ(δ)` from the full 6-vector (inactive entries zero).
fn increment(delta: &Vector6<f64>, mode: MatchMode) -> Isometry3<f64> {
    let rotation = match mode {
        MatchMode::FourDof => UnitQuaternion::from_axis_angle(&Vector3::z_axis(), delta[5]),
        MatchMode::SixDof => UnitQuaternion::from_scaled_axis(Vector3::new(delta[3], delta[4], delta[5])),
    };
    Isometry3::from_parts(Translation3::new(delta[0], delta[1], delta[2]), rotation)
}

/// Solves the damped normal equations restricted to the active indices.
fn damped_step(h: &Matrix6<f64>, g: &Vector6<f64>, lambda: f64, mode: MatchMode) -> Option<Vector6<f64>> {
    let idx = active_indices(mode);
    let n = idx.len();
    let mut a = nalgebra::DMatrix::<f64>::zeros(n, n);
    let mut b = nalgebra::DVector::<f64>::zeros(n);
    for (r, &i) in idx.iter().enumerate() {
        for (c, &j) in idx.iter().enumerate() {
            a[(r, c)] = h[(i, j)];
        }
        a[(r, r)] += lambda * h[(i, i)].max(1e-9);
        b[r] = -g[i];
    }
    let x = a.cholesky()?.solve(&b);
    let mut delta = Vector6::zeros();
    for (r, &i) in idx.iter().enumerate() {
        delta[i] = x[r];
    }
    delta.iter().all(|v| v.is_finite()).then_some(delta)
}

pub(crate) fn icp(
    problem: &Problem<'_>,
    target_index: &PointIndex,
    initial: &Isometry3<f64>,
    params: &MatcherParams,
) -> Result<IcpResult, IcpFailure> {
    let mode = params.mode;
    let min_pairs = params.icp_min_pairs.max(active_indices(mode).len());
    let final_gate = params.icp_max_distance_final_m;
    let mut t = *initial;
    let mut pairs = Vec::new();
    let mut iterations = 0;
    let mut gate = params.icp_max_distance_start_m.max(final_gate);
    let coverage = Coverage::new(problem.target, gate);
    for it in 0..params.icp_max_iterations.max(1) {
        iterations = it + 1;
        let at_final_gate = gate <= final_gate;
        let stride = if at_final_gate { 1 } else { params.icp_coarse_stride.max(1) };
        problem.pairs_within(&t, target_index, &coverage, gate, stride, &mut pairs);
        if pairs.len() * stride < min_pairs {
            return Err(IcpFailure::TooFewPairs);
        }
        let before = t;
        let mut lambda = 1e-4;
        let (mut h, mut g, mut current) = problem.normal_equations(&t, &pairs);
        for _ in 0..INNER_ITERATIONS {
            let Some(delta) = damped_step(&h, &g, lambda, mode) else { return Err(IcpFailure::Degenerate) };
            let candidate = t * increment(&delta, mode);
            let candidate_cost = problem.cost(&candidate, &pairs);
            if candidate_cost < current {
                t = candidate;
                lambda = (lambda * 0.1).max(1e-9);
                if delta.fixed_rows::<3>(0).norm() < 0.1 * params.icp_translation_epsilon_m
                    && delta.fixed_rows::<3>(3).norm() < 0.1 * params.icp_rotation_epsilon_rad
                {
                    break;
                }
                (h, g, current) = problem.normal_equations(&t, &pairs);
            } else {
                lambda *= 10.0;
                if lambda > 1e6 {
                    break;
                }
            }
        }
        let step = before.inverse() * t;
        if at_final_gate
            && step.translation.vector.norm() < params.icp_translation_epsilon_m
            && step.rotation.angle() < params.icp_rotation_epsilon_rad
        {
            break;
        }
        gate = (gate * params.icp_distance_shrink).max(final_gate);
    }
    problem.pairs_within(&t, target_index, &coverage, final_gate, 1, &mut pairs);
    if pairs.len() < min_pairs {
        return Err(IcpFailure::TooFewPairs);
    }
    let rmse_m = problem.point_rmse(&t, &pairs);
    Ok(IcpResult { t_target_source: t, pairs, rmse_m, iterations })
}
