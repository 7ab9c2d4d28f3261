//! SHOT-style local reference frames (Tombari et al. 2010, "Unique signatures of histograms for
//! local surface description"): eigenvectors of a distance-weighted covariance about the
//! keypoint, each sign chosen so that most support points lie on its positive side.

use nalgebra::{Matrix3, Point3, SymmetricEigen, Vector3};

/// The LRF of the support `support` (indices into `points`) about `center`: rows are the x, y, z
/// axes in the cloud frame (so `R · (p − center)` is `p` in the LRF). None when the covariance
/// is degenerate (too few or coincident points).
pub(crate) fn local_frame(
    points: &[Point3<f32>],
    support: &[usize],
    center: &Point3<f32>,
    radius_m: f32,
) -> Option<Matrix3<f32>> {
    let c = center.coords.cast::<f64>();
    let r = f64::from(radius_m);
    let mut cov = Matrix3::<f64>::zeros();
    let mut weight_sum = 0.0;
    for &j in support {
        let d = points[j].coords.cast::<f64>() - c;
        // Far points weigh less: they are the first to change with clutter and occlusion.
        let w = (r - d.norm()).max(0.0);
        cov += d * d.transpose() * w;
        weight_sum += w;
    }
    if !(weight_sum > 0.0) {
        return None;
    }
    let eig = SymmetricEigen::new(cov / weight_sum);
    let mut order = [0usize, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let (l0, l1, l2) = (eig.eigenvalues[order[0]], eig.eigenvalues[order[1]], eig.eigenvalues[order[2]]);
    // Nearly equal eigenvalues make the axes arbitrary; such a frame would only add noise votes.
    if !(l0 > 1e-10) || !(l0 - l1 > 1e-3 * l0) || !(l1 - l2 > 1e-3 * l0) {
        return None;
    }
    let mut x: Vector3<f64> = eig.eigenvectors.column(order[0]).into_owned();
    let mut z: Vector3<f64> = eig.eigenvectors.column(order[2]).into_owned();
    let positive_side = |axis: &Vector3<f64>| {
        let mut balance = 0i64;
        for &j in support {
            let s = (points[j].coords.cast::<f64>() - c).dot(axis);
            balance += if s >= 0.0 { 1 } else { -1 };
        }
        balance
    };
    if positive_side(&x) < 0 {
        x = -x;
    }
    if positive_side(&z) < 0 {
        z = -z;
    }
    let y = z.cross(&x);
    let rows = Matrix3::from_rows(&[x.transpose(), y.transpose(), z.transpose()]);
    rows.iter().all(|v| v.is_finite()).then(|| rows.cast::<f32>())
}
