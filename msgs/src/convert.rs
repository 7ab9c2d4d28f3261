//! Conversions between the payloads and nalgebra / the algorithm crates' plain types.

use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};

use crate::{Covariance6, Pose};

/// Largest deviation of a received quaternion's norm from 1 that is accepted (it is renormalized).
const MAX_QUATERNION_NORM_ERROR: f64 = 1e-6;

impl Pose {
    pub const IDENTITY: Pose = Pose { translation_m: [0.0; 3], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] };

    pub fn from_isometry(t: &Isometry3<f64>) -> Pose {
        let q = t.rotation.quaternion();
        Pose { translation_m: t.translation.vector.into(), rotation_wxyz: [q.w, q.i, q.j, q.k] }
    }

    /// The transform, or `None` when the bytes in shared memory are not a pose (non-finite values,
    /// a quaternion that is not of unit norm).
    pub fn to_isometry(&self) -> Option<Isometry3<f64>> {
        let [w, x, y, z] = self.rotation_wxyz;
        let finite = self.translation_m.iter().chain(self.rotation_wxyz.iter()).all(|v| v.is_finite());
        let q = Quaternion::new(w, x, y, z);
        if !finite || (q.norm() - 1.0).abs() > MAX_QUATERNION_NORM_ERROR {
            return None;
        }
        let [tx, ty, tz] = self.translation_m;
        Some(Isometry3::from_parts(Translation3::new(tx, ty, tz), UnitQuaternion::new_normalize(q)))
    }
}

/// Row-major array of a 6×6 matrix.
pub fn covariance_to_array(m: &Matrix6<f64>) -> Covariance6 {
    let mut out = [0.0; 36];
    for r in 0..6 {
        for c in 0..6 {
            out[r * 6 + c] = m[(r, c)];
        }
    }
    out
}

/// The matrix of a row-major array, or `None` when a value is not finite.
pub fn covariance_from_array(a: &Covariance6) -> Option<Matrix6<f64>> {
    a.iter().all(|v| v.is_finite()).then(|| Matrix6::from_row_slice(a))
}
