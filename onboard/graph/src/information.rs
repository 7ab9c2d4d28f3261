//! Projection of an information matrix that is not positive definite onto the nearest one with
//! all eigenvalues above a floor, for published datasets whose edges carry indefinite information
//! (SE-Sync's cubicle has such edges; GTSAM reads it, our noise model rejects it).
//!
//! The repair symmetrizes the matrix, decomposes it `Ω = V Λ Vᵀ`, raises every eigenvalue below
//! the floor to the floor and rebuilds `V max(Λ, floor) Vᵀ`. Among matrices whose eigenvalues are
//! all ≥ floor, this is the nearest to the symmetric part in the Frobenius norm (Higham's
//! nearest-semidefinite construction, shifted by the floor); eigen-directions that were already
//! above the floor keep their information exactly.
//!
//! # The floor
//!
//! `max(relative · |λ|max, ABSOLUTE_EIGEN_FLOOR)`, relative [`DEFAULT_RELATIVE_EIGEN_FLOOR`] =
//! 10⁻⁶ by default:
//! - Relative, because information is in the units of the file (1/m², 1/rad², often scaled by
//!   4 for quaternion errors), so no absolute number means "little" for every file.
//! - 10⁻⁶ bounds the repaired matrix's condition number by 10⁶. The Cholesky factorization of the
//!   noise model and the solver's normal equations then lose at most ~6 of f64's 16 digits, and
//!   the rounding of the rebuild (~10⁻¹⁵ · |λ|max) is nine orders below the floor, so the result
//!   is positive definite in floating point, not just on paper.
//! - It is small enough not to invent confidence: a repaired direction's standard deviation is
//!   1000× that of the matrix's best-constrained direction, i.e. the edge says next to nothing
//!   there, which is all an indefinite entry can honestly be taken to mean.
//! - The absolute floor only decides for an all-zero (or vanishing) matrix, which becomes
//!   10⁻¹² · I: a standard deviation of 10⁶ m or rad, no information at all.

use nalgebra::allocator::Allocator;
use nalgebra::{DefaultAllocator, DimDiff, DimName, DimSub, Matrix3, Matrix6, OMatrix, OVector, SymmetricEigen, U1};

use crate::error::GraphError;

/// Default eigenvalue floor relative to the largest eigenvalue magnitude (module documentation).
pub const DEFAULT_RELATIVE_EIGEN_FLOOR: f64 = 1e-6;

/// Floor for matrices whose largest eigenvalue magnitude is zero or vanishing.
pub const ABSOLUTE_EIGEN_FLOOR: f64 = 1e-12;

/// Sweeps the eigen-solver may take before the matrix is declared unrepairable. Symmetric 6×6
/// matrices converge in a few dozen; the bound only turns a pathological input into an error
/// instead of an endless loop.
const MAX_EIGEN_ITERATIONS: usize = 10_000;

/// The eigenvalue floor of a repair, relative to the largest eigenvalue magnitude.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EigenFloor {
    relative: f64,
}

impl EigenFloor {
    /// A relative floor in `(0, 1]`.
    pub fn new(relative: f64) -> Result<Self, GraphError> {
        if relative.is_finite() && relative > 0.0 && relative <= 1.0 {
            Ok(Self { relative })
        } else {
            Err(GraphError::InvalidEigenFloor(relative))
        }
    }

    pub fn relative(&self) -> f64 {
        self.relative
    }

    /// The floor for a matrix whose largest eigenvalue magnitude is `largest_magnitude`.
    pub fn floor_for(&self, largest_magnitude: f64) -> f64 {
        (self.relative * largest_magnitude).max(ABSOLUTE_EIGEN_FLOOR)
    }
}

impl Default for EigenFloor {
    fn default() -> Self {
        Self { relative: DEFAULT_RELATIVE_EIGEN_FLOOR }
    }
}

/// A repaired matrix and what the repair changed.
#[derive(Debug, Clone, PartialEq)]
pub struct Repaired<M> {
    pub matrix: M,
    /// Smallest eigenvalue of the (symmetrized) input: ≤ 0 for an indefinite or semidefinite one.
    pub smallest_eigenvalue_before: f64,
    /// The floor the eigenvalues were raised to.
    pub eigen_floor: f64,
    /// `‖repaired − input‖_F`.
    pub frobenius_change: f64,
}

impl<M> Repaired<M> {
    /// The same repair with the matrix transformed (for example lifted from 3×3 to 6×6).
    pub fn map<N>(self, f: impl FnOnce(M) -> N) -> Repaired<N> {
        Repaired {
            matrix: f(self.matrix),
            smallest_eigenvalue_before: self.smallest_eigenvalue_before,
            eigen_floor: self.eigen_floor,
            frobenius_change: self.frobenius_change,
        }
    }
}

/// Why a matrix could not be repaired.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RepairError {
    #[error("information has non-finite entries")]
    NonFinite,
    #[error("the eigen-decomposition of the information did not converge")]
    NoConvergence,
    #[error("the repaired information is not positive definite (entries too large to represent)")]
    Overflow,
}

/// Nearest 6×6 matrix with every eigenvalue ≥ the floor (module documentation). Always rebuilds,
/// even an input that is already positive definite: callers that must keep such inputs bit for
/// bit (the g2o reader does) test first and repair only what fails.
pub fn repair6(information: &Matrix6<f64>, floor: EigenFloor) -> Result<Repaired<Matrix6<f64>>, RepairError> {
    repair(information, floor)
}

/// [`repair6`] for the 3×3 information of a planar (SE(2)) measurement.
pub fn repair3(information: &Matrix3<f64>, floor: EigenFloor) -> Result<Repaired<Matrix3<f64>>, RepairError> {
    repair(information, floor)
}

/// Smallest eigenvalue of the symmetric part, `None` for non-finite entries or no convergence.
pub fn smallest_eigenvalue6(information: &Matrix6<f64>) -> Option<f64> {
    eigen(information).map(|(eigen, scale)| eigen.eigenvalues.min() * scale)
}

/// [`smallest_eigenvalue6`] of a 3×3 matrix.
pub fn smallest_eigenvalue3(information: &Matrix3<f64>) -> Option<f64> {
    eigen(information).map(|(eigen, scale)| eigen.eigenvalues.min() * scale)
}

/// Eigen-decomposition of the symmetric part divided by its largest entry magnitude (returned
/// second, 0 for a zero matrix), so that neither huge nor tiny inputs overflow or lose precision
/// to subnormals inside the solver.
fn eigen<D>(information: &OMatrix<f64, D, D>) -> Option<(SymmetricEigen<f64, D>, f64)>
where
    D: DimName + DimSub<U1>,
    DefaultAllocator: Allocator<D, D> + Allocator<D> + Allocator<DimDiff<D, U1>>,
{
    if information.iter().any(|v| !v.is_finite()) {
        return None;
    }
    // Halving before adding keeps entries near f64::MAX finite.
    let symmetric = information * 0.5 + information.transpose() * 0.5;
    let scale = symmetric.amax();
    let scaled = if scale > 0.0 { &symmetric / scale } else { symmetric.clone() };
    let decomposition = SymmetricEigen::try_new(scaled, f64::EPSILON, MAX_EIGEN_ITERATIONS)?;
    Some((decomposition, scale))
}

fn repair<D>(information: &OMatrix<f64, D, D>, floor: EigenFloor) -> Result<Repaired<OMatrix<f64, D, D>>, RepairError>
where
    D: DimName + DimSub<U1>,
    DefaultAllocator: Allocator<D, D> + Allocator<D> + Allocator<DimDiff<D, U1>>,
{
    if information.iter().any(|v| !v.is_finite()) {
        return Err(RepairError::NonFinite);
    }
    let (decomposition, scale) = eigen(information).ok_or(RepairError::NoConvergence)?;
    let smallest_eigenvalue_before = decomposition.eigenvalues.min() * scale;
    let eigen_floor = floor.floor_for(decomposition.eigenvalues.amax() * scale);
    let matrix = if scale > 0.0 {
        let scaled_floor = eigen_floor / scale;
        let clamped = decomposition.eigenvalues.map(|value| value.max(scaled_floor));
        let vectors = orthonormalized(decomposition.eigenvectors, &decomposition.eigenvalues);
        let rebuilt = &vectors * OMatrix::<f64, D, D>::from_diagonal(&clamped) * vectors.transpose();
        mirror_upper(rebuilt * scale)
    } else {
        OMatrix::<f64, D, D>::identity() * eigen_floor
    };
    if matrix.iter().any(|v| !v.is_finite()) || matrix.clone().cholesky().is_none() {
        return Err(RepairError::Overflow);
    }
    // Scaled, so that a change near f64::MAX has a finite norm.
    let change = &matrix - information;
    let change_scale = change.amax();
    let frobenius_change = if change_scale > 0.0 { (change / change_scale).norm() * change_scale } else { 0.0 };
    Ok(Repaired { matrix, smallest_eigenvalue_before, eigen_floor, frobenius_change })
}

/// The eigenvectors made orthonormal to rounding, by Gram–Schmidt in order of decreasing
/// eigenvalue magnitude (twice, which is enough in floating point).
///
/// nalgebra's solver returns accurate vectors for well-separated eigenvalues but, for a cluster
/// of eigenvalues that are zero to rounding, vectors that can be far from orthogonal (0.06 seen
/// on a matrix with entries from 10¹⁶² to 10²⁶⁵). The cluster's span is right; that only never
/// mattered because those eigenvalues multiply the vectors by ~0. Raised to the floor, they
/// would rebuild a matrix with eigenvalues off the floor by up to that error. Orthonormalizing
/// keeps the large-eigenvalue vectors (already orthonormal) and replaces the cluster by an
/// orthonormal basis of the same space.
fn orthonormalized<D>(mut vectors: OMatrix<f64, D, D>, eigenvalues: &OVector<f64, D>) -> OMatrix<f64, D, D>
where
    D: DimName,
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
    let n = D::dim();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| eigenvalues[b].abs().total_cmp(&eigenvalues[a].abs()));
    for (done, &column) in order.iter().enumerate() {
        let basis = &order[..done];
        let mut candidate = vectors.column(column).clone_owned();
        let mut norm = project_out(&vectors, basis, &mut candidate);
        // A vector that was (nearly) inside the span of the previous ones is replaced by the
        // first coordinate axis that is not.
        let mut axis = 0;
        while norm < 0.5 && axis < n {
            candidate = OVector::<f64, D>::zeros();
            candidate[axis] = 1.0;
            norm = project_out(&vectors, basis, &mut candidate);
            axis += 1;
        }
        vectors.set_column(column, &(candidate / norm));
    }
    vectors
}

/// Removes from `candidate` its components along the `basis` columns of `vectors` (two passes)
/// and returns its remaining norm.
fn project_out<D>(vectors: &OMatrix<f64, D, D>, basis: &[usize], candidate: &mut OVector<f64, D>) -> f64
where
    D: DimName,
    DefaultAllocator: Allocator<D, D> + Allocator<D>,
{
    for _ in 0..2 {
        for &previous in basis {
            let along = vectors.column(previous).dot(candidate);
            candidate.axpy(-along, &vectors.column(previous), 1.0);
        }
    }
    candidate.norm()
}

/// Exactly symmetric (the g2o format stores the upper triangle only, and the noise model checks
/// symmetry), taking the upper triangle of a rebuild that rounding left slightly asymmetric.
fn mirror_upper<D>(mut matrix: OMatrix<f64, D, D>) -> OMatrix<f64, D, D>
where
    D: DimName,
    DefaultAllocator: Allocator<D, D>,
{
    let n = D::dim();
    for row in 0..n {
        for col in row + 1..n {
            matrix[(col, row)] = matrix[(row, col)];
        }
    }
    matrix
}

#[cfg(test)]
mod tests {
    use nalgebra::Vector6;

    use super::*;

    #[test]
    fn a_negative_eigenvalue_is_raised_to_the_relative_floor() {
        let information = Matrix6::from_diagonal(&Vector6::new(10.0, 10.0, 10.0, 4.0, -0.5, 4.0));
        let repaired = repair6(&information, EigenFloor::default()).unwrap();
        assert_eq!(repaired.smallest_eigenvalue_before, -0.5);
        assert!((repaired.eigen_floor - 1e-5).abs() < 1e-20);
        let mut expected = information;
        expected[(4, 4)] = 1e-5;
        assert!((repaired.matrix - expected).amax() < 1e-12, "{}", repaired.matrix);
        assert!((repaired.frobenius_change - (0.5 + 1e-5)).abs() < 1e-12);
        assert!(repaired.matrix.cholesky().is_some());
    }

    #[test]
    fn a_zero_matrix_becomes_the_absolute_floor() {
        let repaired = repair6(&Matrix6::zeros(), EigenFloor::default()).unwrap();
        assert_eq!(repaired.matrix, Matrix6::identity() * ABSOLUTE_EIGEN_FLOOR);
        assert_eq!(repaired.smallest_eigenvalue_before, 0.0);
    }

    #[test]
    fn non_finite_entries_and_bad_floors_are_errors() {
        let mut information = Matrix3::identity();
        information[(0, 1)] = f64::NAN;
        assert_eq!(repair3(&information, EigenFloor::default()), Err(RepairError::NonFinite));
        information[(0, 1)] = f64::INFINITY;
        assert_eq!(repair3(&information, EigenFloor::default()), Err(RepairError::NonFinite));
        assert_eq!(smallest_eigenvalue3(&information), None);
        for bad in [0.0, -1e-6, 1.5, f64::NAN, f64::INFINITY] {
            assert!(EigenFloor::new(bad).is_err(), "{bad}");
        }
        assert!(EigenFloor::new(1e-3).is_ok());
    }

    #[test]
    fn coupled_rotation_axes_are_repaired_along_the_mixed_direction() {
        // Rotational cross term larger than the diagonal: eigenvalues 10 and −2 along (1, ±1)/√2.
        let mut information = Matrix6::from_diagonal(&Vector6::new(1.0, 1.0, 1.0, 4.0, 4.0, 4.0));
        information[(3, 4)] = 6.0;
        information[(4, 3)] = 6.0;
        let repaired = repair6(&information, EigenFloor::default()).unwrap();
        assert!((repaired.smallest_eigenvalue_before + 2.0).abs() < 1e-12);
        let eigenvalues = repaired.matrix.symmetric_eigenvalues();
        assert!((eigenvalues.min() - 1e-5).abs() < 1e-12, "{eigenvalues}");
        assert!((eigenvalues.max() - 10.0).abs() < 1e-12, "{eigenvalues}");
        // The translation block and the yaw axis are untouched.
        assert!((repaired.matrix.fixed_view::<3, 3>(0, 0) - Matrix3::identity()).amax() < 1e-12);
        assert!((repaired.matrix[(5, 5)] - 4.0).abs() < 1e-12);
    }
}
