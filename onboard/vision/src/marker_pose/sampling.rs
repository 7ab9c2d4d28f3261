//! Online corner-noise sampling (thesis Eq. 6.9, §6.2.3 online step 2).
//!
//! Every image coordinate `q_0 … q_7` of the four detected corners is moved by `+Δp` or `−Δp`:
//! `2⁸ = 256` corner sets (set `k` moves coordinate `i` by `+Δp` where bit `i` of `k` is set;
//! coordinate `2c` is corner `c`'s u, `2c + 1` its v). PnP (its best solution) on each, plus the
//! detection's own pose, gives 257 poses. Their mean is the arithmetic mean of the translations
//! and the Karcher mean of the rotations on SO(3) (iterated `R̄ ← Exp(mean_k Log(R_k R̄ᵀ))·R̄`
//! from the detection's rotation, never an average of Euler angles, T20). The spread per DOF is
//! the largest deviation from that mean in the module's error convention: `t_k − t̄` and
//! `Log(R_k R̄ᵀ)` in the camera frame. A flipped PnP solution among the samples deviates by about
//! twice the tilt angle, which is exactly what this step is for (T18).

use hal::sensor::Pinhole;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

use super::ippe::{PnpError, PnpOptions, solve_square};

/// Number of perturbed corner sets (`2⁸`).
pub const SAMPLE_SETS: usize = 256;

/// The result of [`sample_pose_spread`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSpread {
    /// Largest |deviation| from the mean per DOF: x, y, z (m), then rotation about the camera's
    /// x, y, z (rad), all in the camera frame.
    pub max_deviation: [f64; 6],
    /// The mean pose of the samples (translation mean, Karcher rotation mean).
    pub mean: Isometry3<f64>,
    /// Poses that entered the mean (the detection's and every perturbed set PnP solved).
    pub poses: usize,
    /// Perturbed sets PnP rejected (corners turned degenerate); they are left out.
    pub failed: usize,
}

/// Corner set `k` of Eq. 6.9 (see the module docs).
pub fn perturbed_corners(corners_px: &[[f64; 2]; 4], delta_px: f64, k: usize) -> [[f64; 2]; 4] {
    let mut out = *corners_px;
    for (i, value) in out.iter_mut().flat_map(|c| c.iter_mut()).enumerate() {
        *value += if (k >> i) & 1 == 1 { delta_px } else { -delta_px };
    }
    out
}

/// The 257-pose spread around a detection whose own PnP pose is `t_cam_marker` (see the module
/// docs). Errors only if no perturbed set can be solved at all (the detection's pose still
/// enters the mean; a single pose has no spread to report).
pub fn sample_pose_spread(
    corners_px: &[[f64; 2]; 4],
    intrinsics: &Pinhole,
    tag_size_m: f64,
    delta_px: f64,
    options: &PnpOptions,
    t_cam_marker: &Isometry3<f64>,
) -> Result<PoseSpread, PnpError> {
    let mut poses = [*t_cam_marker; SAMPLE_SETS + 1];
    let mut n = 1;
    let mut last_error = PnpError::Degenerate;
    for k in 0..SAMPLE_SETS {
        match solve_square(&perturbed_corners(corners_px, delta_px, k), intrinsics, tag_size_m, options) {
            Ok(sol) => {
                poses[n] = sol.best.t_cam_marker;
                n += 1;
            }
            Err(e) => last_error = e,
        }
    }
    if n == 1 {
        return Err(last_error);
    }
    let poses = &poses[..n];
    let mean = mean_pose(poses);
    Ok(PoseSpread { max_deviation: max_deviation(poses, &mean), mean, poses: n, failed: SAMPLE_SETS + 1 - n })
}

/// Arithmetic mean of the translations and Karcher mean of the rotations, started from the first
/// pose's rotation (the detection's). `poses` must not be empty (the identity if it is).
pub fn mean_pose(poses: &[Isometry3<f64>]) -> Isometry3<f64> {
    let Some(first) = poses.first() else { return Isometry3::identity() };
    let inv_n = 1.0 / poses.len() as f64;
    let translation = poses.iter().fold(Vector3::zeros(), |s, p| s + p.translation.vector) * inv_n;
    let mut rotation = first.rotation;
    for _ in 0..50 {
        let inverse = rotation.inverse();
        let step = poses.iter().fold(Vector3::zeros(), |s, p| s + (p.rotation * inverse).scaled_axis()) * inv_n;
        rotation = UnitQuaternion::from_scaled_axis(step) * rotation;
        if step.norm() < 1e-13 {
            break;
        }
    }
    Isometry3::from_parts(Translation3::from(translation), rotation)
}

/// Largest |deviation| per DOF of `poses` from `mean` (`t − t̄`, `Log(R R̄ᵀ)`, camera frame).
pub fn max_deviation(poses: &[Isometry3<f64>], mean: &Isometry3<f64>) -> [f64; 6] {
    let mut out = [0.0f64; 6];
    for p in poses {
        let e = super::pose_error(p, mean);
        for (o, v) in out.iter_mut().zip(e) {
            *o = o.max(v.abs());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn the_256_sets_are_all_sign_combinations() {
        let c = [[0.0; 2]; 4];
        let mut seen = std::collections::HashSet::new();
        for k in 0..SAMPLE_SETS {
            let p = perturbed_corners(&c, 0.5, k);
            assert!(p.iter().flatten().all(|v| v.abs() == 0.5));
            seen.insert(p.iter().flatten().map(|v| v.to_bits()).collect::<Vec<_>>());
        }
        assert_eq!(seen.len(), SAMPLE_SETS);
    }

    #[test]
    fn karcher_mean_is_wrap_aware() {
        // Rotations of ±170° about z: their mean is 180° about z, not the identity an Euler
        // average gives.
        let a = Isometry3::new(Vector3::zeros(), Vector3::z() * 170f64.to_radians());
        let b = Isometry3::new(Vector3::zeros(), Vector3::z() * (-170f64).to_radians());
        let m = mean_pose(&[a, b]);
        assert!((m.rotation.angle() - std::f64::consts::PI).abs() < 1e-9, "{}", m.rotation.angle());
        let d = max_deviation(&[a, b], &m);
        assert!((d[5] - 10f64.to_radians()).abs() < 1e-9 && d[3].abs() < 1e-12, "{d:?}");
    }
}
