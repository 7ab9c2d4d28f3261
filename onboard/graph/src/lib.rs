//! Pose-graph back-end of the on-board mapper (thesis §4.2): SE(3) variables, prior and
//! between factors with full 6×6 information and optional robust kernels, batch
//! Levenberg–Marquardt, iSAM2-style incremental updates on a Bayes tree of cliques, marginal
//! covariances, g2o import/export, and seeded synthetic torus and lattice graphs.
//!
//! Conventions (shared with the whole project):
//! - A pose `t_a_b` is frame `b` in frame `a`, as `nalgebra::Isometry3<f64>`.
//! - Tangent vectors and covariances are ordered `[translation, rotation]` (ρ, φ). Perturbations
//!   act on the right: `x ⊕ δ = x · Exp(δ)`. GTSAM orders Pose3 tangents `[rotation,
//!   translation]`; the numbers are otherwise identical (same Exp/Log, same right retraction).
//! - A between factor's error is `Log(measured⁻¹ · xᵢ⁻¹ · xⱼ)` and its cost `½ eᵀ Ω e`, exactly
//!   GTSAM's `BetweenFactor<Pose3>`; robust kernels replace `½ d²` (with `d² = eᵀ Ω e`) by
//!   `ρ(d)`, as GTSAM's `noiseModel::Robust` does.

mod anchoring;
pub mod batch;
mod bayes_tree;
pub mod dataset;
pub mod error;
pub mod factor;
pub mod g2o;
pub mod incremental;
pub mod information;
#[cfg(test)]
mod jacobian_checks;
mod linear;
#[cfg(test)]
mod numdiff;
pub mod ordering;
pub mod se3;
pub mod synthetic;
pub mod values;

pub use batch::{LmParams, LmSummary, Termination, marginal_covariances, optimize, total_cost};
pub use error::GraphError;
pub use factor::{Factor, FactorKind, Key, NoiseModel, RobustKernel};
pub use incremental::{Isam, IsamParams, UpdateStats};
pub use se3::Pose3;
pub use values::Values;
