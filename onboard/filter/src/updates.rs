//! Measurement models: relative pose between clones, wheel velocity, zero velocity, absolute pose.
//!
//! Residuals follow the `[δt; δθ]` convention of the measurements: `r_t = t_meas − t̂`,
//! `r_θ = Log(R̂ᵀ·R_meas)` (right-multiplied). The Jacobians are with respect to the global
//! attitude errors of the state (see `eskf`).

use crate::FilterError;
use crate::eskf::{Filter, IBG, IP, ITH, IV, MeasurementKind, NX, RelativePoseMeasurement, UpdateOutcome};
use crate::math::{log, skew};
use hal::sensor::WheelOdomSample;
use nalgebra::{Isometry3, Matrix3, Matrix6, SMatrix, SVector, UnitQuaternion, Vector3, Vector6};

fn finite_cov(c: &Matrix6<f64>) -> bool {
    c.iter().all(|x| x.is_finite())
}

impl Filter {
    pub(crate) fn relative_pose_update(&mut self, m: &RelativePoseMeasurement) -> Result<UpdateOutcome, FilterError> {
        if m.from_stamp_ns == m.to_stamp_ns {
            return Err(FilterError::BadInput("relative pose between a stamp and itself".into()));
        }
        if !(finite_cov(&m.covariance) && m.t_from_to.translation.vector.iter().all(|x| x.is_finite())) {
            return Err(FilterError::BadInput("non-finite relative pose".into()));
        }
        let Some(from) = self.clone_index(m.from_stamp_ns) else {
            self.health.missing_clones += 1;
            return Ok(UpdateOutcome::MissingClone);
        };
        // The `to` end: its clone, or the current state if it stands exactly at that stamp.
        let (p_t, q_t, col_p_t, col_th_t) = match self.clone_index(m.to_stamp_ns) {
            Some(j) => (self.clones[j].p, self.clones[j].q, NX + 6 * j, NX + 6 * j + 3),
            None if m.to_stamp_ns == self.stamp_ns => (self.p, self.q, IP, ITH),
            None => {
                self.health.missing_clones += 1;
                return Ok(UpdateOutcome::MissingClone);
            }
        };
        let c = self.clones[from];
        let (col_p_f, col_th_f) = (NX + 6 * from, NX + 6 * from + 3);
        let r_f_t = c.q.to_rotation_matrix().into_inner().transpose();
        let r_t_t = q_t.to_rotation_matrix().into_inner().transpose();
        let d = p_t - c.p;
        let t_pred = r_f_t * d;
        let q_pred = c.q.inverse() * q_t;
        let r_t = m.t_from_to.translation.vector - t_pred;
        let r_th = log(&(q_pred.inverse() * m.t_from_to.rotation));
        let residual = Vector6::new(r_t.x, r_t.y, r_t.z, r_th.x, r_th.y, r_th.z);

        self.clear_ht(6);
        self.add_h_block(0, col_p_t, &r_f_t);
        self.add_h_block(0, col_p_f, &(-r_f_t));
        self.add_h_block(0, col_th_f, &(r_f_t * skew(&d)));
        self.add_h_block(3, col_th_t, &r_t_t);
        self.add_h_block(3, col_th_f, &(-r_t_t));
        let noise = 0.5 * (m.covariance + m.covariance.transpose());
        let (nis, threshold, applied) = self.kalman_update(&residual, &noise);
        self.release_clone(m.to_stamp_ns);
        Ok(self.record(MeasurementKind::RelativePose, nis, threshold, applied))
    }

    pub(crate) fn wheel_update(&mut self, s: &WheelOdomSample) -> Result<UpdateOutcome, FilterError> {
        if !(s.linear_mps.iter().all(|x| x.is_finite()) && s.sigma[..3].iter().all(|x| !x.is_nan())) {
            return Err(FilterError::BadInput("non-finite wheel odometry".into()));
        }
        let floor = self.config.wheel_min_sigma_mps;
        let tau_s = self.config.wheel_error_correlation_s;
        let interval_s = match self.last_wheel_stamp_ns {
            Some(last) if s.stamp_ns > last => (s.stamp_ns - last) as f64 * 1e-9,
            _ => tau_s,
        };
        self.last_wheel_stamp_ns = Some(s.stamp_ns);
        let inflation = if tau_s > 0.0 { (tau_s / interval_s.clamp(1e-3, tau_s)).max(1.0) } else { 1.0 };
        let mut noise = SMatrix::<f64, 3, 3>::zeros();
        for i in 0..3 {
            let sigma = s.sigma[i].max(floor);
            noise[(i, i)] = sigma * sigma * inflation;
        }
        let r_t = self.q.to_rotation_matrix().into_inner().transpose();
        let residual = s.linear_mps - r_t * self.v;
        self.clear_ht(3);
        self.add_h_block(0, IV, &r_t);
        self.add_h_block(0, ITH, &(r_t * skew(&self.v)));
        let (nis, threshold, applied) = self.kalman_update(&residual, &noise);
        Ok(self.record(MeasurementKind::Wheel, nis, threshold, applied))
    }

    pub(crate) fn zero_velocity_update(&mut self) -> Result<UpdateOutcome, FilterError> {
        let sv = self.config.zupt_velocity_sigma_mps;
        let (nis, threshold, applied) = match self.last_imu {
            Some(imu) => {
                // Standing still, the gyro measures its bias plus white noise.
                let n = &self.config.imu;
                let derived = n.gyro_noise_density * self.config.imu_rate_hz.max(1.0).sqrt();
                let sg = self.config.zupt_rate_sigma_radps.unwrap_or(derived);
                let w = imu.gyro_radps - self.bg;
                let residual = SVector::<f64, 6>::new(-self.v.x, -self.v.y, -self.v.z, w.x, w.y, w.z);
                let noise = SMatrix::<f64, 6, 6>::from_diagonal(&Vector6::new(
                    sv * sv,
                    sv * sv,
                    sv * sv,
                    sg * sg,
                    sg * sg,
                    sg * sg,
                ));
                self.clear_ht(6);
                self.add_h_block(0, IV, &Matrix3::identity());
                self.add_h_block(3, IBG, &Matrix3::identity());
                self.kalman_update(&residual, &noise)
            }
            None => {
                let residual = -self.v;
                let noise = Matrix3::identity() * (sv * sv);
                self.clear_ht(3);
                self.add_h_block(0, IV, &Matrix3::identity());
                self.kalman_update(&residual, &noise)
            }
        };
        Ok(self.record(MeasurementKind::ZeroVelocity, nis, threshold, applied))
    }

    pub(crate) fn pose_update(
        &mut self,
        t_local_body: &Isometry3<f64>,
        covariance: &Matrix6<f64>,
    ) -> Result<UpdateOutcome, FilterError> {
        if !(finite_cov(covariance) && t_local_body.translation.vector.iter().all(|x| x.is_finite())) {
            return Err(FilterError::BadInput("non-finite pose".into()));
        }
        let q_meas: UnitQuaternion<f64> = t_local_body.rotation;
        let r_t = self.q.to_rotation_matrix().into_inner().transpose();
        let dp: Vector3<f64> = t_local_body.translation.vector - self.p;
        let dth = log(&(self.q.inverse() * q_meas));
        let residual = Vector6::new(dp.x, dp.y, dp.z, dth.x, dth.y, dth.z);
        self.clear_ht(6);
        self.add_h_block(0, IP, &Matrix3::identity());
        self.add_h_block(3, ITH, &r_t);
        let noise = 0.5 * (covariance + covariance.transpose());
        let (nis, threshold, applied) = self.kalman_update(&residual, &noise);
        Ok(self.record(MeasurementKind::Pose, nis, threshold, applied))
    }
}
