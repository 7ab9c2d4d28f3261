//! The whole filter as plain data, to resume it elsewhere (a restarted process, DESIGN §3.4):
//! nominal state, clones, the held IMU sample and the covariance over `[core | clones]`.
//! [`Filter::restore`] checks sizes and finiteness, so a snapshot read from disk cannot put the
//! filter into a state its own code would never reach. Health counters are not part of it.

use crate::FilterError;
use crate::eskf::{Filter, NX, PoseClone};
use hal::sensor::ImuSample;
use nalgebra::{DMatrix, Isometry3, Vector3};

/// A pose clone of a [`FilterSnapshot`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CloneSnapshot {
    pub stamp_ns: u64,
    pub t_local_body: Isometry3<f64>,
    pub keyframe: bool,
    /// Its measurement was processed (dropped at the next clone unless a keyframe).
    pub released: bool,
}

/// Everything of an initialized filter that its behaviour depends on (see the module docs).
#[derive(Debug, Clone, PartialEq)]
pub struct FilterSnapshot {
    pub stamp_ns: u64,
    pub frame_id: u32,
    pub t_local_body: Isometry3<f64>,
    pub v_local_mps: Vector3<f64>,
    pub accel_bias_mps2: Vector3<f64>,
    pub gyro_bias_radps: Vector3<f64>,
    pub last_imu: Option<ImuSample>,
    pub last_wheel_stamp_ns: Option<u64>,
    /// Oldest first, as the covariance blocks.
    pub clones: Vec<CloneSnapshot>,
    /// `(15 + 6·clones)²`, global attitude errors (the internal convention of [`Filter`]).
    pub covariance: DMatrix<f64>,
}

fn finite(v: impl IntoIterator<Item = f64>) -> bool {
    v.into_iter().all(f64::is_finite)
}

fn isometry_finite(t: &Isometry3<f64>) -> bool {
    finite(t.translation.vector.iter().copied()) && finite(t.rotation.coords.iter().copied())
}

impl Filter {
    /// The filter as data; `None` before initialization.
    pub fn snapshot(&self) -> Option<FilterSnapshot> {
        if !self.initialized {
            return None;
        }
        let n = self.dim();
        Some(FilterSnapshot {
            stamp_ns: self.stamp_ns,
            frame_id: self.frame_id,
            t_local_body: Isometry3::from_parts(self.p.into(), self.q),
            v_local_mps: self.v,
            accel_bias_mps2: self.ba,
            gyro_bias_radps: self.bg,
            last_imu: self.last_imu,
            last_wheel_stamp_ns: self.last_wheel_stamp_ns,
            clones: self
                .clones
                .iter()
                .map(|c| CloneSnapshot {
                    stamp_ns: c.stamp_ns,
                    t_local_body: Isometry3::from_parts(c.p.into(), c.q),
                    keyframe: c.keyframe,
                    released: c.released,
                })
                .collect(),
            covariance: self.cov.view((0, 0), (n, n)).into_owned(),
        })
    }

    /// Replaces the filter's state with `snapshot` (initialized afterwards). Refused, with the
    /// filter unchanged, when the covariance does not match the clones, there are more clones
    /// than `max_clones`, or a value is not finite.
    pub fn restore(&mut self, snapshot: &FilterSnapshot) -> Result<(), FilterError> {
        let n = NX + 6 * snapshot.clones.len();
        if snapshot.clones.len() > self.config.max_clones {
            return Err(FilterError::BadInput(format!(
                "{} clones in the snapshot, at most {}",
                snapshot.clones.len(),
                self.config.max_clones
            )));
        }
        if snapshot.covariance.shape() != (n, n) {
            return Err(FilterError::BadInput(format!(
                "snapshot covariance {:?} for {} clones",
                snapshot.covariance.shape(),
                snapshot.clones.len()
            )));
        }
        let vectors = [&snapshot.v_local_mps, &snapshot.accel_bias_mps2, &snapshot.gyro_bias_radps];
        let imu_finite =
            snapshot.last_imu.is_none_or(|s| finite(s.gyro_radps.iter().chain(s.accel_mps2.iter()).copied()));
        if !(isometry_finite(&snapshot.t_local_body)
            && vectors.iter().all(|v| finite(v.iter().copied()))
            && imu_finite
            && snapshot.clones.iter().all(|c| isometry_finite(&c.t_local_body))
            && finite(snapshot.covariance.iter().copied()))
        {
            return Err(FilterError::BadInput("non-finite value in the snapshot".into()));
        }
        self.initialized = true;
        self.stamp_ns = snapshot.stamp_ns;
        self.frame_id = snapshot.frame_id;
        self.p = snapshot.t_local_body.translation.vector;
        self.q = snapshot.t_local_body.rotation;
        self.v = snapshot.v_local_mps;
        self.ba = snapshot.accel_bias_mps2;
        self.bg = snapshot.gyro_bias_radps;
        self.last_imu = snapshot.last_imu;
        self.last_wheel_stamp_ns = snapshot.last_wheel_stamp_ns;
        self.clones.clear();
        self.clones.extend(snapshot.clones.iter().map(|c| PoseClone {
            stamp_ns: c.stamp_ns,
            p: c.t_local_body.translation.vector,
            q: c.t_local_body.rotation,
            keyframe: c.keyframe,
            released: c.released,
        }));
        self.cov.fill(0.0);
        self.cov.view_mut((0, 0), (n, n)).copy_from(&snapshot.covariance);
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::FilterConfig;

    fn sample(stamp_ns: u64, wz: f64) -> ImuSample {
        ImuSample { stamp_ns, gyro_radps: Vector3::new(0.001, -0.002, wz), accel_mps2: Vector3::new(0.05, 0.01, 1.62) }
    }

    fn running_filter() -> Filter {
        let mut f = Filter::new(FilterConfig::default());
        f.initialize_at_rest(0, &Vector3::new(0.0, 0.0, 1.62), &Vector3::zeros()).unwrap();
        for k in 1..=100u64 {
            f.propagate(&sample(k * 5_000_000, 0.05)).unwrap();
            if k % 20 == 0 {
                f.clone_at(k * 5_000_000).unwrap();
            }
        }
        f.mark_keyframe(100_000_000);
        f
    }

    #[test]
    fn a_restored_filter_continues_exactly_as_the_original() {
        let mut original = running_filter();
        let snapshot = original.snapshot().unwrap();
        assert_eq!(snapshot.clones.len(), original.clone_count());
        let mut restored = Filter::new(FilterConfig::default());
        restored.restore(&snapshot).unwrap();
        assert_eq!(restored.snapshot().unwrap(), snapshot);
        for k in 101..=150u64 {
            original.propagate(&sample(k * 5_000_000, -0.03)).unwrap();
            restored.propagate(&sample(k * 5_000_000, -0.03)).unwrap();
        }
        assert_eq!(restored.state(), original.state());
        assert_eq!(restored.full_covariance(), original.full_covariance());
        assert_eq!(restored.frame_id(), original.frame_id());
    }

    #[test]
    fn inconsistent_snapshots_are_refused_and_leave_the_filter_alone() {
        let snapshot = running_filter().snapshot().unwrap();
        let mut target = Filter::new(FilterConfig::default());
        let mut wrong_size = snapshot.clone();
        wrong_size.clones.pop();
        assert!(target.restore(&wrong_size).is_err());
        let mut nan = snapshot.clone();
        nan.covariance[(3, 3)] = f64::NAN;
        assert!(target.restore(&nan).is_err());
        let mut too_many = snapshot.clone();
        let extra = too_many.clones[0];
        let n = NX + 6 * (target.config().max_clones + 1);
        too_many.clones = vec![extra; target.config().max_clones + 1];
        too_many.covariance = DMatrix::identity(n, n);
        assert!(target.restore(&too_many).is_err());
        assert!(!target.is_initialized());
    }
}
