//! Poses and covariances as they travel on the wire.
//!
//! Frame convention (used throughout the project): `t_a_b` is the pose of frame `b` expressed in
//! frame `a`, i.e. it maps coordinates of a point in `b` into `a`: `p_a = t_a_b * p_b`.
//! Rotations are unit quaternions stored `[w, x, y, z]`; translations are in metres.
//! Covariances are over the tangent space, ordered `[translation (m), rotation (rad)]`
//! (x, y, z, roll, pitch, yaw for small angles). GTSAM's `Pose3` orders `[rotation, translation]`;
//! the pose graph converts at its boundary.

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

/// A rigid transform in 3D.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Pose3 {
    pub translation_m: [f64; 3],
    /// Unit quaternion `[w, x, y, z]`.
    pub rotation_wxyz: [f64; 4],
}

impl Pose3 {
    pub const IDENTITY: Pose3 = Pose3 { translation_m: [0.0; 3], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] };

    /// Whether every component is finite and the quaternion has unit norm within `1e-6`.
    /// Decoders accept any bytes; consumers call this before using a pose.
    pub fn is_valid(&self) -> bool {
        let finite = self.translation_m.iter().chain(self.rotation_wxyz.iter()).all(|v| v.is_finite());
        let norm2: f64 = self.rotation_wxyz.iter().map(|v| v * v).sum();
        finite && (norm2 - 1.0).abs() < 1e-6
    }
}

/// Number of entries of the upper triangle of a symmetric 6x6 matrix.
pub const COV6_ENTRIES: usize = 21;

/// A symmetric 6x6 covariance, upper triangle row by row, in single precision: the
/// uncertainty itself is never known to more than a few digits, so f32 halves its cost.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Cov6 {
    pub upper: [f32; COV6_ENTRIES],
}

impl Cov6 {
    /// Packs a full row-major symmetric matrix (only the upper triangle is read).
    pub fn from_full(full: &[[f64; 6]; 6]) -> Self {
        let mut upper = [0.0f32; COV6_ENTRIES];
        let mut k = 0;
        for (r, row) in full.iter().enumerate() {
            for value in &row[r..] {
                upper[k] = *value as f32;
                k += 1;
            }
        }
        Cov6 { upper }
    }

    /// Unpacks into a full row-major symmetric matrix.
    #[allow(clippy::needless_range_loop, reason = "each entry is written to (r, c) and (c, r)")]
    pub fn to_full(&self) -> [[f64; 6]; 6] {
        let mut full = [[0.0f64; 6]; 6];
        let mut entries = self.upper.iter();
        for r in 0..6 {
            for c in r..6 {
                let value = entries.next().copied().map_or(0.0, f64::from);
                full[r][c] = value;
                full[c][r] = value;
            }
        }
        full
    }

    /// A diagonal covariance from standard deviations `[x, y, z, roll, pitch, yaw]`.
    pub fn from_std_devs(sigma: [f64; 6]) -> Self {
        let mut full = [[0.0f64; 6]; 6];
        for (i, s) in sigma.iter().enumerate() {
            full[i][i] = s * s;
        }
        Self::from_full(&full)
    }

    /// Whether the matrix is finite with a positive diagonal (a cheap plausibility check;
    /// positive-definiteness is checked where the matrix is factorized).
    pub fn is_plausible(&self) -> bool {
        let full = self.to_full();
        self.upper.iter().all(|v| v.is_finite()) && (0..6).all(|i| full[i][i] > 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn covariance_packing_round_trips_symmetric_matrices() {
        let full: [[f64; 6]; 6] =
            core::array::from_fn(|r| core::array::from_fn(|c| (r.min(c) * 10 + r.max(c)) as f64 + 1.0));
        assert_eq!(Cov6::from_full(&full).to_full(), full);
    }

    #[test]
    fn pose_validity_rejects_non_unit_and_nan() {
        assert!(Pose3::IDENTITY.is_valid());
        let mut p = Pose3::IDENTITY;
        p.rotation_wxyz[0] = 2.0;
        assert!(!p.is_valid());
        p = Pose3::IDENTITY;
        p.translation_m[1] = f64::NAN;
        assert!(!p.is_valid());
    }
}
