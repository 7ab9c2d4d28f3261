//! The keypoint descriptor: a SHOT shape histogram plus a greyscale histogram (the thesis's
//! CSHOT on greyscale cameras, §6.1.2 a), over the full cloud as support surface.
//!
//! Layout (all in the keypoint's LRF, support radius R):
//! - 32 spatial volumes: 8 azimuth sectors × 2 elevations (above/below the LRF's xy-plane) × 2
//!   radial shells (inside/outside R/2), as SHOT.
//! - Shape part, 32 × 11 = 352 bins: per volume, a histogram of the cosine between each support
//!   point's normal and the LRF's z axis, over [−1, 1]. Each point is spread over its two
//!   nearest bins in each of the four dimensions (quadrilinear interpolation, SHOT's remedy for
//!   boundary effects).
//! - Greyscale part, 32 × `intensity_bins` (default 8: 256 bins): per volume, a histogram of the
//!   point's grey value minus the support's mean grey value, over ±[`INTENSITY_RANGE`] grey
//!   levels (clamped). CSHOT bins an L1 colour distance to the keypoint's colour in 31 bins; with
//!   one channel a signed difference keeps "brighter" and "darker" apart, and subtracting the
//!   local mean (rather than a keypoint colour) makes it invariant to brightness offsets between
//!   two robots' cameras. Eight bins of 16 grey levels are coarse enough for the 5 cm voxels'
//!   averaged grey values to land in the same or a neighbouring bin on both submaps.
//! - Each part is L2-normalised, the greyscale part is scaled by `intensity_weight`, and the
//!   concatenation is L2-normalised again (so descriptor distances lie in [0, 2]).

use nalgebra::{DMatrix, Matrix3, Point3, Vector3};

use super::lrf::local_frame;
use super::params::MatcherParams;
use super::spatial::PointIndex;
use crate::cloud::VoxelCloud;

const AZIMUTH_BINS: usize = 8;
const ELEVATION_BINS: usize = 2;
const RADIAL_BINS: usize = 2;
const VOLUMES: usize = AZIMUTH_BINS * ELEVATION_BINS * RADIAL_BINS;
const COS_BINS: usize = 11;
const SHAPE_LEN: usize = VOLUMES * COS_BINS;
/// Grey-level difference mapped to the outermost bins.
pub(crate) const INTENSITY_RANGE: f32 = 64.0;

/// The described keypoints of one cloud.
#[derive(Debug, Clone)]
pub(crate) struct Features {
    /// Keypoint index (into the cloud's keypoints) of each descriptor column.
    pub keypoint: Vec<usize>,
    /// Position of each described keypoint.
    pub position: Vec<Point3<f32>>,
    /// LRF of each described keypoint (rows: axes in the cloud frame).
    pub lrf: Vec<Matrix3<f32>>,
    /// One unit-norm descriptor per column.
    pub descriptors: DMatrix<f32>,
}

impl Features {
    pub(crate) fn len(&self) -> usize {
        self.keypoint.len()
    }
}

pub(crate) fn descriptor_len(params: &MatcherParams) -> usize {
    SHAPE_LEN + VOLUMES * params.intensity_bins.max(1)
}

/// Spreads `value` at continuous bin coordinate `x` (bin centres at integers) over its two
/// nearest bins of `0..n`, clamping at the ends, or wrapping when `wrap`.
fn two_bins(x: f32, n: usize, wrap: bool) -> [(usize, f32); 2] {
    let lo = x.floor();
    let frac = x - lo;
    let lo = lo as i64;
    let n_i = n as i64;
    if wrap {
        [((lo.rem_euclid(n_i)) as usize, 1.0 - frac), (((lo + 1).rem_euclid(n_i)) as usize, frac)]
    } else if lo < 0 {
        [(0, 1.0), (0, 0.0)]
    } else if lo >= n_i - 1 {
        [((n_i - 1) as usize, 1.0), ((n_i - 1) as usize, 0.0)]
    } else {
        [(lo as usize, 1.0 - frac), (lo as usize + 1, frac)]
    }
}

/// Descriptors of `keypoints` over `cloud` (`points`: its positions, `normals`: its normals).
pub(crate) fn compute_features(
    cloud: &VoxelCloud,
    points: &[Point3<f32>],
    normals: &[Option<Vector3<f32>>],
    index: &PointIndex,
    keypoints: &[Point3<f32>],
    params: &MatcherParams,
) -> Features {
    let radius = params.descriptor_radius_m as f32;
    let intensity_bins = params.intensity_bins.max(1);
    let dim = descriptor_len(params);

    let mut supports: Vec<Vec<usize>> = Vec::with_capacity(keypoints.len());
    let mut scratch = Vec::new();
    for k in keypoints {
        index.within(k, radius, &mut scratch);
        supports.push(if scratch.len() >= params.min_support_points { scratch.clone() } else { Vec::new() });
    }

    let mut keypoint = Vec::new();
    let mut position = Vec::new();
    let mut lrfs = Vec::new();
    let mut columns: Vec<f32> = Vec::new();
    let mut hist = vec![0f32; dim];
    for (ki, (k, support)) in keypoints.iter().zip(&supports).enumerate() {
        if support.is_empty() {
            continue;
        }
        let Some(lrf) = local_frame(points, support, k, radius) else { continue };
        hist.iter_mut().for_each(|h| *h = 0.0);
        let mean_intensity =
            support.iter().map(|&j| f32::from(cloud.points[j].intensity)).sum::<f32>() / support.len() as f32;
        let z_axis: Vector3<f32> = lrf.row(2).transpose();
        for &j in support {
            let Some(normal) = normals[j] else { continue };
            let local = lrf * (points[j] - k);
            let dist = local.norm();
            if !(dist <= radius) {
                continue;
            }
            let azimuth = local.y.atan2(local.x);
            let elevation = if dist > 1e-6 { (local.z / dist).clamp(-1.0, 1.0).asin() } else { 0.0 };
            let az = two_bins(
                (azimuth + std::f32::consts::PI) / std::f32::consts::TAU * AZIMUTH_BINS as f32 - 0.5,
                AZIMUTH_BINS,
                true,
            );
            let el = two_bins(
                (elevation + std::f32::consts::FRAC_PI_2) / std::f32::consts::PI * ELEVATION_BINS as f32 - 0.5,
                ELEVATION_BINS,
                false,
            );
            let rad = two_bins(dist / radius * RADIAL_BINS as f32 - 0.5, RADIAL_BINS, false);
            let cos = normal.dot(&z_axis).clamp(-1.0, 1.0);
            let cb = two_bins((cos + 1.0) * 0.5 * COS_BINS as f32 - 0.5, COS_BINS, false);
            let diff = (f32::from(cloud.points[j].intensity) - mean_intensity).clamp(-INTENSITY_RANGE, INTENSITY_RANGE);
            let ib = two_bins(
                (diff + INTENSITY_RANGE) / (2.0 * INTENSITY_RANGE) * intensity_bins as f32 - 0.5,
                intensity_bins,
                false,
            );
            for &(a, wa) in &az {
                for &(e, we) in &el {
                    for &(r, wr) in &rad {
                        let w = wa * we * wr;
                        if w == 0.0 {
                            continue;
                        }
                        let volume = (a * ELEVATION_BINS + e) * RADIAL_BINS + r;
                        for &(c, wc) in &cb {
                            hist[volume * COS_BINS + c] += w * wc;
                        }
                        for &(i, wi) in &ib {
                            hist[SHAPE_LEN + volume * intensity_bins + i] += w * wi;
                        }
                    }
                }
            }
        }
        let (shape, grey) = hist.split_at_mut(SHAPE_LEN);
        let shape_norm = shape.iter().map(|v| v * v).sum::<f32>().sqrt();
        let grey_norm = grey.iter().map(|v| v * v).sum::<f32>().sqrt();
        if !(shape_norm > 0.0) || !(grey_norm > 0.0) {
            continue;
        }
        shape.iter_mut().for_each(|v| *v /= shape_norm);
        grey.iter_mut().for_each(|v| *v *= params.intensity_weight / grey_norm);
        let total = hist.iter().map(|v| v * v).sum::<f32>().sqrt();
        if !(total > 0.0) {
            continue;
        }
        columns.extend(hist.iter().map(|v| v / total));
        keypoint.push(ki);
        position.push(*k);
        lrfs.push(lrf);
    }
    let n = keypoint.len();
    Features { keypoint, position, lrf: lrfs, descriptors: DMatrix::from_vec(dim, n, columns) }
}
