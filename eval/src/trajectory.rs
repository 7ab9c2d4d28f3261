//! Stamped pose sequences and interpolation on SE(3).

use nalgebra::{Isometry3, Translation3, UnitQuaternion};

/// Poses `t_world_body` at increasing stamps (seconds).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trajectory {
    pub stamps_s: Vec<f64>,
    pub poses: Vec<Isometry3<f64>>,
}

impl Trajectory {
    /// Builds a trajectory; stamps must be finite and strictly increasing.
    pub fn new(stamps_s: Vec<f64>, poses: Vec<Isometry3<f64>>) -> Result<Self, TrajectoryError> {
        if stamps_s.len() != poses.len() {
            return Err(TrajectoryError::LengthMismatch { stamps: stamps_s.len(), poses: poses.len() });
        }
        for (i, w) in stamps_s.windows(2).enumerate() {
            // `partial_cmp` rather than `!(w[1] > w[0])` (clippy::neg_cmp_op_on_partial_ord); a NaN pair fails too.
            if w[1].partial_cmp(&w[0]) != Some(core::cmp::Ordering::Greater) {
                return Err(TrajectoryError::NotIncreasing { index: i + 1 });
            }
        }
        if let Some(i) = stamps_s.iter().position(|t| !t.is_finite()) {
            return Err(TrajectoryError::NonFinite { index: i });
        }
        Ok(Self { stamps_s, poses })
    }

    pub fn len(&self) -> usize {
        self.poses.len()
    }

    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// Cumulative path length (m) at every pose, starting at 0.
    pub fn distances_m(&self) -> Vec<f64> {
        let mut out = Vec::with_capacity(self.len());
        let mut total = 0.0;
        for (i, pose) in self.poses.iter().enumerate() {
            if i > 0 {
                total += (pose.translation.vector - self.poses[i - 1].translation.vector).norm();
            }
            out.push(total);
        }
        out
    }

    /// Total path length (m).
    pub fn length_m(&self) -> f64 {
        self.distances_m().last().copied().unwrap_or(0.0)
    }

    /// Pose at time `t` by interpolation between the bracketing samples (linear in translation,
    /// spherical in rotation, i.e. along the SE(3) geodesic's rotation part); `None` outside the
    /// covered interval or when the bracketing samples are more than `max_gap_s` apart.
    pub fn interpolate(&self, t: f64, max_gap_s: f64) -> Option<Isometry3<f64>> {
        let (first, last) = (*self.stamps_s.first()?, *self.stamps_s.last()?);
        if !(t >= first && t <= last) {
            return None;
        }
        let upper = self.stamps_s.partition_point(|&s| s < t);
        if self.stamps_s[upper] == t {
            return Some(self.poses[upper]);
        }
        let lower = upper - 1;
        let (t0, t1) = (self.stamps_s[lower], self.stamps_s[upper]);
        if t1 - t0 > max_gap_s {
            return None;
        }
        let a = (t - t0) / (t1 - t0);
        Some(interpolate_pose(&self.poses[lower], &self.poses[upper], a))
    }

    /// Transforms every pose: `t_new_body = transform * t_world_body`.
    pub fn transformed(&self, transform: &Isometry3<f64>) -> Self {
        Self { stamps_s: self.stamps_s.clone(), poses: self.poses.iter().map(|p| transform * p).collect() }
    }
}

/// Interpolates between two poses at fraction `a ∈ [0, 1]`.
pub fn interpolate_pose(p0: &Isometry3<f64>, p1: &Isometry3<f64>, a: f64) -> Isometry3<f64> {
    let translation = p0.translation.vector.lerp(&p1.translation.vector, a);
    // Samples half a turn apart have no unique geodesic: take the nearer endpoint rather than panic.
    let rotation: UnitQuaternion<f64> =
        p0.rotation.try_slerp(&p1.rotation, a, 1e-12).unwrap_or(if a < 0.5 { p0.rotation } else { p1.rotation });
    Isometry3::from_parts(Translation3::from(translation), rotation)
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrajectoryError {
    #[error("{stamps} stamps but {poses} poses")]
    LengthMismatch { stamps: usize, poses: usize },
    #[error("stamp {index} is not later than the one before")]
    NotIncreasing { index: usize },
    #[error("stamp {index} is not finite")]
    NonFinite { index: usize },
}
