//! Point normals by PCA of the neighbourhood (thesis: radius 0.2 m), oriented toward +z.
//!
//! Terrain submaps are seen from above by a ground robot's cameras, so +z is the side every
//! surface was observed from, except for overhangs, which are rare and small: orienting by the
//! view point would need the camera poses, which a submap's cloud does not carry.

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};

use super::spatial::PointIndex;

/// Fewest neighbours (the point included) that define a plane.
const MIN_NORMAL_NEIGHBOURS: usize = 3;

/// Unit normal at `points[i]` from the points within `radius_m`, or None when there are too
/// few of them or they are collinear.
pub(crate) fn normal_at(
    points: &[Point3<f32>],
    index: &PointIndex,
    i: usize,
    radius_m: f32,
    scratch: &mut Vec<usize>,
) -> Option<Vector3<f32>> {
    index.within(&points[i], radius_m, scratch);
    if scratch.len() < MIN_NORMAL_NEIGHBOURS {
        return None;
    }
    let n = scratch.len() as f64;
    let mean = scratch.iter().fold(Vector3::<f64>::zeros(), |acc, &j| acc + points[j].coords.cast::<f64>()) / n;
    let mut cov = Matrix3::<f64>::zeros();
    for &j in scratch.iter() {
        let d = points[j].coords.cast::<f64>() - mean;
        cov += d * d.transpose();
    }
    let eig = SymmetricEigen::new(cov / n);
    let (mut smallest, mut middle) = (0, 0);
    for k in 0..3 {
        if eig.eigenvalues[k] < eig.eigenvalues[smallest] {
            smallest = k;
        }
    }
    for k in 0..3 {
        if k != smallest && (middle == smallest || eig.eigenvalues[k] < eig.eigenvalues[middle]) {
            middle = k;
        }
    }
    // A line's two smallest eigenvalues are equal: its "normal" is an arbitrary direction.
    if !(eig.eigenvalues[middle] > 4.0 * eig.eigenvalues[smallest].max(0.0) + 1e-12) {
        return None;
    }
    let mut normal: Vector3<f32> = eig.eigenvectors.column(smallest).into_owned().cast::<f32>();
    if normal.z < 0.0 {
        normal = -normal;
    }
    let len = normal.norm();
    (len > 0.5).then(|| normal / len)
}

/// Normals of every point (None where undefined).
pub(crate) fn all_normals(points: &[Point3<f32>], index: &PointIndex, radius_m: f32) -> Vec<Option<Vector3<f32>>> {
    let mut scratch = Vec::new();
    (0..points.len()).map(|i| normal_at(points, index, i, radius_m, &mut scratch)).collect()
}
