//! The submap matcher (thesis §6.1): map-matching loop closures between two submap clouds.
//!
//! Pipeline (each stage in its own module):
//! 1. [`PreparedCloud::new`] (pairing side, §6.1.1 a, b, d): size check, keypoints = 0.1 m
//!    voxel centroids of the obstacle points (`keypoints`), descriptiveness check by a RANSAC
//!    3-D line (`keypoints::line_spread`).
//! 2. Features, lazily and cached per cloud (§6.1.2 a): PCA normals (`normals`), SHOT local
//!    reference frames (`lrf`), SHOT shape + greyscale histograms (`descriptor`), radius 0.2 m,
//!    support surface = the full cloud.
//! 3. Correspondences (§6.1.2 b, `correspondences`): k = 3 most similar descriptors both ways,
//!    similarity `1 − d/2` ≥ 0.5 (trap T9).
//! 4. Hough3D grouping in both directions (`hough`, trap T3) and RANSAC per cluster (`ransac`):
//!    the 2-point yaw sample of eqs. 6.5–6.7 in 4D mode, a 3-point Kabsch sample in 6D mode.
//! 5. Hypothesis filtering (§6.1.2 d, `pipeline::select`): prior gate 2·Δσ_t per axis, roll/pitch
//!    ≤ 10° (6D), supporting keypoints spread in both clouds; most supporting correspondences
//!    wins (trap T4).
//! 6. LM ICP on the full 5 cm clouds (`icp`, trap T13), 4 or 6 parameters; final checks (pairs,
//!    pair fraction, RMSE, prior gate, roll/pitch ≤ 1° in 6D) and the covariance (`covariance`).
//!
//! # Frames
//!
//! `source` and `target` are two clouds, each in its own submap frame (gravity-aligned, z up).
//! `t_target_source` maps source coordinates into target coordinates
//! (`p_target = t_target_source · p_source`). In the team graph a
//! [`crate::slam::SubmapMatch`] `{ a, b, t_a_b }` is built with a = target, b = source.
//!
//! # The match covariance (trap T12)
//!
//! This is the one place the convention is defined. The covariance is 6×6, ordered
//! `[translation, rotation]`, of the tangent δ = [ρ; φ] of the right perturbation
//! `t_target_source_true = t_target_source · Exp(δ)`, i.e. ρ and φ are expressed in the source
//! frame. That is exactly the tangent of the graph's between factor
//! `e = Log(t_a_b⁻¹ · x_a⁻¹ · x_b)` with a = target, b = source (`posegraph` docs), so it goes
//! into `SubmapMatch::covariance` unchanged.
//!
//! Derivation. ICP minimises `Σ_i |T·Δ(δ)·s_i − q_i|²` over its N final pairs (source point
//! s_i, nearest target point q_i), with δ the p = 4 (ρ, φ_z) or p = 6 (ρ, φ) estimated
//! parameters and `Δ(δ) = Exp(δ)` to first order. At the optimum, with residuals modelled as
//! independent isotropic noise of variance σ², the Gauss–Newton (Laplace) approximation gives
//!
//! ```text
//!   Σ_δ = σ² · (JᵀJ)⁻¹,    J_i = R·[I₃, −[s_i]×] (columns of the estimated parameters),
//!   σ²  = Σ_i |e_i|² / (3N − p)          (the unbiased residual variance; RMSE² · 3N/(3N−p)/3)
//! ```
//!
//! (R cancels in JᵀJ = Σ_i [I, −[s_i]×]ᵀ[I, −[s_i]×].) Neighbouring residuals are not
//! independent: the 5 cm voxel centroids of one surface patch share their stereo error and
//! their sampling offset, so N overstates the information by about the number of points per
//! correlation cell. The effective sample count N_eff is the number of distinct
//! `covariance_correlation_m` (default 0.5 m) voxels the paired source points occupy, and the
//! covariance is inflated by N / N_eff:
//!
//! ```text
//!   Σ_δ = k · σ² · (N / N_eff) · (JᵀJ)⁻¹  +  diag(floor²)
//! ```
//!
//! with k = `covariance_inflation` (1 by default; the integrator tunes it by NEES in
//! simulation) and floors `covariance_floor_translation_m` (1 cm) on x, y, z and
//! `covariance_floor_rotation_rad` (0.1°) on each estimated rotation axis, because a
//! thousand-pair ICP otherwise claims sub-millimetre precision that its systematic errors
//! (voxelisation, stereo bias) do not have. In 4D mode the ICP does not estimate roll and pitch:
//! they get the fixed variance `roll_pitch_sigma_rad`² (0.5°, the submap frames' gravity
//! alignment) and no correlation with the other axes. A singular JᵀJ (the pairs do not
//! constrain every estimated axis, e.g. only a plane overlaps) rejects the match (`IcpFailed`).
//!
//! Thesis reference values: mean 3.07 s (descriptor matching) + 2.38 s (ICP) per pair on a Xeon
//! E5-1620 (§8.4); this implementation's times are in the crate README.

#![allow(clippy::neg_cmp_op_on_partial_ord, reason = "the negated comparisons reject NaN on purpose")]

mod correspondences;
mod covariance;
mod descriptor;
pub mod diagnose;
mod hough;
mod icp;
mod keypoints;
mod lrf;
mod normals;
mod params;
mod pipeline;
mod prepared;
mod ransac;
mod report;
mod rng;
mod spatial;
#[cfg(test)]
mod tests;

pub use params::{IcpMetric, MatchMode, MatcherParams};
pub use pipeline::match_clouds;
pub use prepared::PreparedCloud;
pub use report::{MatchFound, MatchReport, Rejection, RelativePrior, StageTimes, Unsuitable};
