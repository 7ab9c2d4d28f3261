//! Errors of graph construction and optimization.

use crate::factor::Key;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum GraphError {
    #[error("invalid noise model: {0}")]
    InvalidNoise(&'static str),
    #[error("robust kernel parameter must be finite and positive, got {0}")]
    InvalidKernelParameter(f64),
    #[error("factor refers to variable {0:?}, which has no value")]
    UnknownVariable(Key),
    #[error("variable {0:?} already exists")]
    DuplicateVariable(Key),
    #[error("variable {0:?} is not constrained by any factor path to a prior: the system is singular")]
    Unconstrained(Key),
    #[error(
        "the linear system is not positive definite at variable {0:?} (a variable without enough constraints, or non-finite values)"
    )]
    NotPositiveDefinite(Key),
    #[error("non-finite value in the estimate of {0:?}")]
    NonFinite(Key),
    #[error("edge {from} → {to}: {reason} (g2o::parse_with names the file line and can repair it)")]
    InvalidEdgeNoise { from: u64, to: u64, reason: &'static str },
    #[error("relative eigenvalue floor must be finite and in (0, 1], got {0}")]
    InvalidEigenFloor(f64),
}
