//! 3D–2D relative pose of the current left camera to a keyframe: stereo triangulation with its
//! error model, P3P + RANSAC, robust refinement on SE(3) and the propagated-noise covariance.
//!
//! - [`p3p`]: Grunert's minimal solver (own derivation, quartic from polynomial arithmetic).
//! - [`ransac`]: P3P hypotheses with an adaptive iteration count; the caller's prior is one more
//!   hypothesis.
//! - [`refine`]: Levenberg-Marquardt over the pose and the inlier landmarks jointly (landmarks in
//!   inverse depth, tied to their stereo priors, eliminated by the Schur complement), Huber
//!   weights on whitened residuals. The pose information that remains is, to first order,
//!   `Σ Jᵀ (σ²I + J_P Σ_P J_Pᵀ)⁻¹ J`: pixel noise plus each landmark's stereo uncertainty
//!   projected into the image (thesis §4.1.1: delta poses with propagated-noise covariance).
//!
//! Conventions: see the crate documentation. Poses are `t_keyframe_current_cam` (current left
//! camera into the keyframe's left camera frame) and covariances are over `[δt; δθ]` with
//! `t ← t + δt` in the keyframe frame and `R ← R·Exp(δθ)`.

pub mod p3p;
pub mod ransac;
pub mod refine;

use hal::emulator::Xoshiro256StarStar;
use hal::sensor::Pinhole;
use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3};

/// A keyframe landmark seen in the current image.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Correspondence {
    /// Landmark in the keyframe's left-camera frame (metres), triangulated from stereo.
    pub point_keyframe_m: Vector3<f64>,
    /// Its 3x3 covariance from the stereo error model (disparity sigma, pixel sigma).
    pub point_covariance_m2: Matrix3<f64>,
    /// Observed pixel in the current left image.
    pub pixel_current: [f64; 2],
}

/// Stereo triangulation with covariance (rectified pair, left camera origin, right at +baseline x).
///
/// `Z = fx·b/d`, `X = (x − cx)·b/d`, `Y = (y − cy)·(fx/fy)·b/d`. The covariance is the first-order
/// propagation of independent noise on `x`, `y` (the tracked feature) and `d` (the stereo
/// matcher): with `σ_d = √2·σ_p` its depth part is the stereo error model's
/// `Δp_z = Δp·√2·Z²/(f·b)` (Hirschmüller 2003, spec §2.5.2). `None` for a non-positive or
/// non-finite disparity or baseline.
pub fn triangulate(
    intrinsics: &Pinhole,
    baseline_m: f64,
    x_px: f64,
    y_px: f64,
    disparity_px: f64,
    pixel_sigma_px: f64,
    disparity_sigma_px: f64,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let Pinhole { fx_px, fy_px, cx_px, cy_px } = *intrinsics;
    let finite = [fx_px, fy_px, cx_px, cy_px, baseline_m, x_px, y_px, disparity_px, pixel_sigma_px, disparity_sigma_px]
        .iter()
        .all(|v| v.is_finite());
    if !finite || disparity_px <= 0.0 || baseline_m <= 0.0 || fx_px <= 0.0 || fy_px <= 0.0 {
        return None;
    }
    let b_over_d = baseline_m / disparity_px;
    let point = Vector3::new((x_px - cx_px) * b_over_d, (y_px - cy_px) * (fx_px / fy_px) * b_over_d, fx_px * b_over_d);
    // Columns: ∂/∂x, ∂/∂y, ∂/∂d.
    let jacobian = Matrix3::new(
        b_over_d,
        0.0,
        -point.x / disparity_px,
        0.0,
        (fx_px / fy_px) * b_over_d,
        -point.y / disparity_px,
        0.0,
        0.0,
        -point.z / disparity_px,
    );
    let pixel_var = pixel_sigma_px * pixel_sigma_px;
    let noise = Matrix3::from_diagonal(&Vector3::new(pixel_var, pixel_var, disparity_sigma_px * disparity_sigma_px));
    Some((point, jacobian * noise * jacobian.transpose()))
}

/// Settings of [`PoseEstimator`].
#[derive(Debug, Clone, PartialEq)]
pub struct PoseEstimationConfig {
    /// Upper bound of RANSAC iterations, default 200.
    pub ransac_max_iterations: usize,
    /// Probability of drawing at least one all-inlier sample (adaptive stop), default 0.999.
    pub ransac_confidence: f64,
    /// Reprojection error of a RANSAC inlier, default 2 px. After refinement the same gate is
    /// applied to the residual whitened by its full covariance (scaled by `pixel_sigma_px`), so
    /// landmarks with an uncertain depth get the tolerance their projected uncertainty needs.
    pub inlier_threshold_px: f64,
    /// Fewest inliers of an accepted pose, default 12.
    pub min_inliers: usize,
    /// Measurement noise of a tracked feature, default 0.5 px.
    pub pixel_sigma_px: f64,
    /// Huber threshold of the refinement (in pixels at `pixel_sigma_px`), default 1.5 px.
    pub huber_px: f64,
    /// Seed of the RANSAC sampler; every `estimate` call restarts from it, so a result depends
    /// only on its inputs.
    pub seed: u64,
}

impl Default for PoseEstimationConfig {
    fn default() -> Self {
        PoseEstimationConfig {
            ransac_max_iterations: 200,
            ransac_confidence: 0.999,
            inlier_threshold_px: 2.0,
            min_inliers: 12,
            pixel_sigma_px: 0.5,
            huber_px: 1.5,
            seed: 0x5EED_0DD0,
        }
    }
}

/// Result of [`PoseEstimator::estimate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseEstimate {
    /// Pose of the current left camera in the keyframe's left camera frame.
    pub t_keyframe_current_cam: Isometry3<f64>,
    /// Covariance in the crate convention ([δt; δθ], translation in keyframe frame, rotation right-
    /// multiplied), propagated from pixel noise AND landmark covariances (not just J^T J of pixels).
    pub covariance: Matrix6<f64>,
    pub inliers: u32,
    /// Pixel reprojection RMS over the inliers.
    pub rms_px: f64,
}

/// Why no pose was estimated.
#[derive(Debug, thiserror::Error)]
pub enum PoseError {
    #[error("pose: {available} correspondences, at least {required} needed")]
    TooFewCorrespondences { available: usize, required: usize },
    #[error("pose: no consensus ({best_inliers} inliers, at least {required} needed)")]
    NoConsensus { best_inliers: usize, required: usize },
    #[error("pose: degenerate geometry (singular information matrix)")]
    Degenerate,
}

/// P3P-RANSAC + robust refinement; owns its scratch mask, so estimating does not allocate once
/// the mask has grown to the largest correspondence count.
#[derive(Debug)]
pub struct PoseEstimator {
    config: PoseEstimationConfig,
    mask: Vec<bool>,
    landmarks: Vec<refine::Landmark>,
}

impl PoseEstimator {
    pub fn new(config: PoseEstimationConfig) -> Self {
        PoseEstimator { config, mask: Vec::new(), landmarks: Vec::new() }
    }

    pub fn config(&self) -> &PoseEstimationConfig {
        &self.config
    }

    /// P3P-RANSAC then Levenberg-Marquardt refinement on the inliers with Huber weights.
    /// `prior` (a guess of `t_keyframe_current_cam`) is tried as an extra hypothesis.
    /// `inlier_mask` is cleared and filled with one bool per correspondence.
    pub fn estimate(
        &mut self,
        intrinsics: &Pinhole,
        correspondences: &[Correspondence],
        prior: Option<&Isometry3<f64>>,
        inlier_mask: &mut Vec<bool>,
    ) -> Result<PoseEstimate, PoseError> {
        let config = &self.config;
        inlier_mask.clear();
        inlier_mask.resize(correspondences.len(), false);
        let required = config.min_inliers.max(3);
        if correspondences.len() < required {
            return Err(PoseError::TooFewCorrespondences { available: correspondences.len(), required });
        }
        let threshold2 = config.inlier_threshold_px * config.inlier_threshold_px;
        let mut best = prior.map(|p| ransac::Best {
            t_keyframe_current: *p,
            inliers: ransac::count_inliers(intrinsics, &p.inverse(), correspondences, threshold2),
        });
        let mut rng = Xoshiro256StarStar::seed_from_u64(config.seed);
        ransac::run(
            intrinsics,
            correspondences,
            config.inlier_threshold_px,
            config.ransac_max_iterations,
            config.ransac_confidence,
            &mut rng,
            &mut best,
        );
        let best_inliers = best.as_ref().map_or(0, |b| b.inliers);
        let Some(best) = best.filter(|b| b.inliers >= required) else {
            return Err(PoseError::NoConsensus { best_inliers, required });
        };

        let sigma = config.pixel_sigma_px.max(1e-6);
        let huber_k = config.huber_px / sigma;
        let gate_chi2 = threshold2 / (sigma * sigma);
        self.mask.clear();
        self.mask.extend(correspondences.iter().map(|c| {
            refine::reprojection_error2(intrinsics, &best.t_keyframe_current, c).is_some_and(|e| e <= threshold2)
        }));
        let mut pose = best.t_keyframe_current;
        // Refine, re-select the inliers with the whitened gate at the refined pose, and refine
        // again until the set settles: later passes pick up near landmarks whose projected depth
        // uncertainty exceeds the pixel gate of RANSAC. The information must belong to the final set.
        let mut refined = None;
        for _ in 0..4 {
            let pass =
                refine::refine(intrinsics, &pose, correspondences, &self.mask, sigma, huber_k, &mut self.landmarks)
                    .ok_or(PoseError::Degenerate)?;
            pose = pass.pose;
            refined = Some(pass);
            let mut changed = false;
            for (c, m) in correspondences.iter().zip(self.mask.iter_mut()) {
                let inlier = refine::linearize(intrinsics, &pose, c, sigma).is_some_and(|l| l.chi2() <= gate_chi2);
                changed |= inlier != *m;
                *m = inlier;
            }
            if !changed {
                break;
            }
            refined = None;
        }
        let inliers = self.mask.iter().filter(|m| **m).count();
        if inliers < required {
            return Err(PoseError::NoConsensus { best_inliers: inliers, required });
        }
        let refined = match refined {
            Some(r) => r,
            None => refine::refine(intrinsics, &pose, correspondences, &self.mask, sigma, huber_k, &mut self.landmarks)
                .ok_or(PoseError::Degenerate)?,
        };
        pose = refined.pose;
        let covariance = refine::covariance(&refined.hessian).ok_or(PoseError::Degenerate)?;
        let sum2: f64 = correspondences
            .iter()
            .zip(&self.mask)
            .filter(|(_, m)| **m)
            .filter_map(|(c, _)| refine::reprojection_error2(intrinsics, &pose, c))
            .sum();
        inlier_mask.copy_from_slice(&self.mask);
        Ok(PoseEstimate {
            t_keyframe_current_cam: pose,
            covariance,
            inliers: inliers as u32,
            rms_px: (sum2 / inliers as f64).sqrt(),
        })
    }
}

/// Transforms a relative camera motion + covariance into the body frame:
/// `t_kb_cb = t_body_cam_keyframe · t_kc_cc · t_body_cam_current⁻¹` (head angles may differ), with
/// the covariance mapped accordingly (crate convention on both sides).
///
/// With `A = t_body_cam_keyframe`, `B = t_body_cam_current = (R_B, t_B)` and `w = R_Bᵀ t_B`, a
/// camera perturbation `[δt; δθ]` moves the body delta by `δt_b = R_A δt + R_A R [w]× δθ` and
/// `δθ_b = R_B δθ`.
pub fn camera_delta_to_body(
    t_keyframe_current_cam: &Isometry3<f64>,
    covariance_cam: &Matrix6<f64>,
    t_body_cam_keyframe: &Isometry3<f64>,
    t_body_cam_current: &Isometry3<f64>,
) -> (Isometry3<f64>, Matrix6<f64>) {
    let pose = t_body_cam_keyframe * t_keyframe_current_cam * t_body_cam_current.inverse();
    let jacobian = camera_to_body_jacobian(t_keyframe_current_cam, t_body_cam_keyframe, t_body_cam_current);
    let covariance = jacobian * covariance_cam * jacobian.transpose();
    (pose, 0.5 * (covariance + covariance.transpose()))
}

/// `∂[δt_b; δθ_b] / ∂[δt; δθ]` of [`camera_delta_to_body`].
pub fn camera_to_body_jacobian(
    t_keyframe_current_cam: &Isometry3<f64>,
    t_body_cam_keyframe: &Isometry3<f64>,
    t_body_cam_current: &Isometry3<f64>,
) -> Matrix6<f64> {
    let r_a = t_body_cam_keyframe.rotation.to_rotation_matrix().into_inner();
    let r = t_keyframe_current_cam.rotation.to_rotation_matrix().into_inner();
    let r_b = t_body_cam_current.rotation.to_rotation_matrix().into_inner();
    let w = r_b.transpose() * t_body_cam_current.translation.vector;
    let mut jacobian = Matrix6::zeros();
    jacobian.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_a);
    jacobian.fixed_view_mut::<3, 3>(0, 3).copy_from(&(r_a * r * w.cross_matrix()));
    jacobian.fixed_view_mut::<3, 3>(3, 3).copy_from(&r_b);
    jacobian
}
