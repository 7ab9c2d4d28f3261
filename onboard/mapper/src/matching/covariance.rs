//! The match covariance from the final ICP alignment (§6.1.2 f, trap T12); the derivation is in
//! the module documentation of [`super`].

use std::collections::HashSet;

use nalgebra::{Isometry3, Matrix6, Point3};

use super::icp::{Problem, active_indices};
use super::params::IcpMetric;
use super::params::{MatchMode, MatcherParams};
use crate::cloud::VoxelBuildHasher;

/// Number of distinct `cell_m` voxels the paired source points occupy: the effective number of
/// independent residuals.
pub(crate) fn effective_samples(source: &[Point3<f32>], pairs: &[(usize, usize)], cell_m: f64) -> usize {
    if !(cell_m > 0.0) {
        return pairs.len();
    }
    let cells: HashSet<[i64; 3], VoxelBuildHasher> = pairs
        .iter()
        .map(|&(si, _)| {
            let p = source[si];
            [
                (f64::from(p.x) / cell_m).floor() as i64,
                (f64::from(p.y) / cell_m).floor() as i64,
                (f64::from(p.z) / cell_m).floor() as i64,
            ]
        })
        .collect();
    cells.len().max(1)
}

/// 6×6 covariance, `[translation, rotation]`, of the right perturbation of `t_target_source`.
/// None when the normal equations are singular (the pairs do not constrain every estimated
/// degree of freedom, e.g. a single plane).
pub(crate) fn match_covariance(
    t_target_source: &Isometry3<f64>,
    problem: &Problem<'_>,
    pairs: &[(usize, usize)],
    params: &MatcherParams,
) -> Option<Matrix6<f64>> {
    let idx = active_indices(params.mode);
    let p = idx.len();
    let n = pairs.len();
    // Scalar residuals per pair.
    let per_pair = match problem.metric {
        IcpMetric::PointToPoint => 3,
        IcpMetric::PointToPlane => 1,
    };
    if n * per_pair <= p {
        return None;
    }
    let (h, _, cost) = problem.normal_equations(t_target_source, pairs);
    let sigma2 = cost / (per_pair * n - p) as f64;
    let correlation = n as f64 / effective_samples(problem.source, pairs, params.covariance_correlation_m) as f64;
    let mut h_active = nalgebra::DMatrix::<f64>::zeros(p, p);
    for (r, &i) in idx.iter().enumerate() {
        for (c, &j) in idx.iter().enumerate() {
            h_active[(r, c)] = h[(i, j)];
        }
    }
    // Relative conditioning check: a plane leaves a direction with (near) zero information.
    let eig = nalgebra::SymmetricEigen::new(h_active.clone());
    let (min_e, max_e) = eig.eigenvalues.iter().fold((f64::INFINITY, 0f64), |(lo, hi), &v| (lo.min(v), hi.max(v)));
    if !(min_e > 1e-9 * max_e) {
        return None;
    }
    let inverse = h_active.cholesky()?.inverse();
    let scale = params.covariance_inflation * sigma2 * correlation;
    let mut cov = Matrix6::zeros();
    for (r, &i) in idx.iter().enumerate() {
        for (c, &j) in idx.iter().enumerate() {
            cov[(i, j)] = scale * inverse[(r, c)];
        }
    }
    for i in 0..3 {
        cov[(i, i)] += params.covariance_floor_translation_m.powi(2);
    }
    for &i in idx.iter().filter(|&&i| i >= 3) {
        cov[(i, i)] += params.covariance_floor_rotation_rad.powi(2);
    }
    if params.mode == MatchMode::FourDof {
        cov[(3, 3)] = params.roll_pitch_sigma_rad.powi(2);
        cov[(4, 4)] = params.roll_pitch_sigma_rad.powi(2);
    }
    let cov = (cov + cov.transpose()) * 0.5;
    cov.iter().all(|v| v.is_finite()).then_some(cov)
}
