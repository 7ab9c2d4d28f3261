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

/// Normals of the points within `support_radius_m` of any of `centres` (None elsewhere and
/// where undefined): what the descriptors of those centres read, at a fraction of
/// [`all_normals`]'s cost on a submap whose keypoints cover a small part of it.
pub(crate) fn normals_near(
    points: &[Point3<f32>],
    index: &PointIndex,
    centres: &[Point3<f32>],
    support_radius_m: f32,
    radius_m: f32,
) -> Vec<Option<Vector3<f32>>> {
    let mut wanted = vec![false; points.len()];
    let mut scratch = Vec::new();
    for c in centres {
        index.within(c, support_radius_m, &mut scratch);
        for &j in &scratch {
            wanted[j] = true;
        }
    }
    wanted
        .iter()
        .enumerate()
        .map(|(i, &w)| if w { normal_at(points, index, i, radius_m, &mut scratch) } else { None })
        .collect()
}

/// Normals of every point (None where undefined).
pub(crate) fn all_normals(points: &[Point3<f32>], index: &PointIndex, radius_m: f32) -> Vec<Option<Vector3<f32>>> {
    let mut scratch = Vec::new();
    (0..points.len()).map(|i| normal_at(points, index, i, radius_m, &mut scratch)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A 2 m × 2 m patch of 5 cm ground with a 0.3 m step in it, as a submap has.
    fn step_patch() -> Vec<Point3<f32>> {
        let mut points = Vec::new();
        for i in 0..40 {
            for j in 0..40 {
                let (x, y) = (i as f32 * 0.05, j as f32 * 0.05);
                points.push(Point3::new(x, y, if x > 1.0 { 0.3 } else { 0.0 }));
            }
        }
        for k in 0..6 {
            for j in 0..40 {
                points.push(Point3::new(1.0, j as f32 * 0.05, k as f32 * 0.05));
            }
        }
        points
    }

    #[test]
    fn normals_near_centres_equal_the_full_computation_there_and_are_absent_elsewhere() {
        let points = step_patch();
        let index = PointIndex::new(&points);
        let all = all_normals(&points, &index, 0.2);
        let centres = [Point3::new(1.0, 1.0, 0.15), Point3::new(0.3, 0.3, 0.0)];
        let near = normals_near(&points, &index, &centres, 0.2, 0.2);
        let mut inside = 0;
        for (i, p) in points.iter().enumerate() {
            let distance = centres.iter().map(|c| (p - c).norm()).fold(f32::MAX, f32::min);
            if distance < 0.199 {
                inside += 1;
                assert_eq!(near[i], all[i], "point {i}");
            } else if distance > 0.201 {
                assert_eq!(near[i], None, "point {i} is outside every support");
            }
        }
        assert!(inside > 30 && all.iter().filter(|n| n.is_some()).count() > 10 * inside / 2, "{inside}");
    }
}
