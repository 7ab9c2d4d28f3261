//! Hypothesise-and-verify over P3P samples with an adaptive iteration count.

use super::{Correspondence, p3p};
use hal::emulator::Xoshiro256StarStar;
use hal::sensor::Pinhole;
use nalgebra::{Isometry3, Vector3};

/// Number of pixel-threshold inliers of the hypothesis `t_current_keyframe` (keyframe points into
/// the current camera).
pub fn count_inliers(
    intrinsics: &Pinhole,
    t_current_keyframe: &Isometry3<f64>,
    correspondences: &[Correspondence],
    threshold2_px2: f64,
) -> usize {
    let rotation = t_current_keyframe.rotation.to_rotation_matrix().into_inner();
    let translation = t_current_keyframe.translation.vector;
    correspondences
        .iter()
        .filter(|c| {
            let pc = rotation * c.point_keyframe_m + translation;
            if pc.z <= 1e-3 {
                return false;
            }
            let du = c.pixel_current[0] - (intrinsics.fx_px * pc.x / pc.z + intrinsics.cx_px);
            let dv = c.pixel_current[1] - (intrinsics.fy_px * pc.y / pc.z + intrinsics.cy_px);
            du * du + dv * dv <= threshold2_px2
        })
        .count()
}

/// Unit bearing (current camera frame) of an observed pixel.
pub fn bearing(intrinsics: &Pinhole, pixel: [f64; 2]) -> Vector3<f64> {
    Vector3::new(
        (pixel[0] - intrinsics.cx_px) / intrinsics.fx_px,
        (pixel[1] - intrinsics.cy_px) / intrinsics.fy_px,
        1.0,
    )
    .normalize()
}

/// Iterations needed to draw one all-inlier minimal sample with probability `confidence` when a
/// share `inlier_ratio` of the data are inliers.
pub fn required_iterations(confidence: f64, inlier_ratio: f64, sample_size: i32) -> f64 {
    let all_inliers = inlier_ratio.clamp(0.0, 1.0).powi(sample_size);
    if all_inliers >= 1.0 - 1e-12 {
        return 1.0;
    }
    if all_inliers <= 1e-12 {
        return f64::INFINITY;
    }
    ((1.0 - confidence.clamp(0.0, 1.0 - 1e-12)).ln() / (1.0 - all_inliers).ln()).max(1.0)
}

/// Best hypothesis found so far.
#[derive(Debug, Clone, Copy)]
pub struct Best {
    pub t_keyframe_current: Isometry3<f64>,
    pub inliers: usize,
}

/// Runs RANSAC; `best` may be seeded (e.g. by the prior) and is only replaced by strictly better
/// hypotheses.
pub fn run(
    intrinsics: &Pinhole,
    correspondences: &[Correspondence],
    threshold_px: f64,
    max_iterations: usize,
    confidence: f64,
    rng: &mut Xoshiro256StarStar,
    best: &mut Option<Best>,
) {
    let n = correspondences.len();
    if n < 3 {
        return;
    }
    let threshold2 = threshold_px * threshold_px;
    let mut solutions = [Isometry3::identity(); 4];
    let mut iteration = 0usize;
    while (iteration as f64) < needed(best, n, confidence).min(max_iterations as f64) {
        iteration += 1;
        let i = rng.up_to(n as u64 - 1) as usize;
        let mut j = rng.up_to(n as u64 - 2) as usize;
        if j >= i {
            j += 1;
        }
        let mut k = rng.up_to(n as u64 - 3) as usize;
        // Skip over the two taken indices in increasing order to stay uniform.
        let (lo, hi) = if i < j { (i, j) } else { (j, i) };
        if k >= lo {
            k += 1;
        }
        if k >= hi {
            k += 1;
        }
        let sample = [i, j, k];
        let points = sample.map(|s| correspondences[s].point_keyframe_m);
        let bearings = sample.map(|s| bearing(intrinsics, correspondences[s].pixel_current));
        let count = p3p::solve(&points, &bearings, &mut solutions);
        for t_current_keyframe in &solutions[..count] {
            let inliers = count_inliers(intrinsics, t_current_keyframe, correspondences, threshold2);
            if best.as_ref().is_none_or(|b| inliers > b.inliers) {
                *best = Some(Best { t_keyframe_current: t_current_keyframe.inverse(), inliers });
            }
        }
    }
}

fn needed(best: &Option<Best>, n: usize, confidence: f64) -> f64 {
    match best {
        Some(b) => required_iterations(confidence, b.inliers as f64 / n as f64, 3),
        None => f64::INFINITY,
    }
}
