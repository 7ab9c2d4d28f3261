//! Measurement models: relative pose between clones, wheel velocity, zero velocity, absolute pose.
//!
//! Residuals follow the `[δt; δθ]` convention of the measurements: `r_t = t_meas − t̂`,
//! `r_θ = Log(R̂ᵀ·R_meas)` (right-multiplied). The Jacobians are with respect to the global
//! attitude errors of the state (see `eskf`).

use crate::FilterError;
use crate::eskf::{Filter, IBG, IP, ITH, IV, MeasurementKind, NX, RelativePoseMeasurement, UpdateOutcome};
use crate::math::{log, skew};
use hal::sensor::WheelOdomSample;
use nalgebra::{Isometry3, Matrix3, Matrix6, SMatrix, UnitQuaternion, Vector3, Vector6};

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
        let (t_pred, q_pred, h) = relative_pose_model(&c.p, &c.q, &p_t, &q_t);
        let residual = pose_residual(&t_pred, &q_pred, &m.t_from_to);
        self.clear_ht(6);
        for (block, col) in [NX + 6 * from, NX + 6 * from + 3, col_p_t, col_th_t].into_iter().enumerate() {
            for row in [0, 3] {
                self.add_h_block(row, col, &h.fixed_view::<3, 3>(row, 3 * block).into_owned());
            }
        }
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
        let (v_body, h) = wheel_model(&self.v, &self.q);
        let residual = s.linear_mps - v_body;
        self.clear_ht(3);
        self.add_h_block(0, IV, &h.fixed_view::<3, 3>(0, 0).into_owned());
        self.add_h_block(0, ITH, &h.fixed_view::<3, 3>(0, 3).into_owned());
        let (nis, threshold, applied) = self.kalman_update(&residual, &noise);
        Ok(self.record(MeasurementKind::Wheel, nis, threshold, applied))
    }

    pub(crate) fn zero_velocity_update(&mut self) -> Result<UpdateOutcome, FilterError> {
        let sv = self.config.zupt_velocity_sigma_mps;
        let (predicted, h) = zero_velocity_model(&self.v, &self.bg);
        let h_v = h.fixed_view::<3, 3>(0, 0).into_owned();
        let (nis, threshold, applied) = match self.last_imu {
            Some(imu) => {
                // Standing still, the gyro measures its bias plus white noise.
                let n = &self.config.imu;
                let derived = n.gyro_noise_density * self.config.imu_rate_hz.max(1.0).sqrt();
                let sg = self.config.zupt_rate_sigma_radps.unwrap_or(derived);
                let w = imu.gyro_radps;
                let residual = Vector6::new(0.0, 0.0, 0.0, w.x, w.y, w.z) - predicted;
                let noise = SMatrix::<f64, 6, 6>::from_diagonal(&Vector6::new(
                    sv * sv,
                    sv * sv,
                    sv * sv,
                    sg * sg,
                    sg * sg,
                    sg * sg,
                ));
                self.clear_ht(6);
                self.add_h_block(0, IV, &h_v);
                self.add_h_block(3, IBG, &h.fixed_view::<3, 3>(3, 3).into_owned());
                self.kalman_update(&residual, &noise)
            }
            None => {
                let residual = -predicted.fixed_rows::<3>(0).into_owned();
                let noise = Matrix3::identity() * (sv * sv);
                self.clear_ht(3);
                self.add_h_block(0, IV, &h_v);
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
        let residual = pose_residual(&self.p, &self.q, t_local_body);
        let h = pose_jacobian(&self.q);
        self.clear_ht(6);
        self.add_h_block(0, IP, &h.fixed_view::<3, 3>(0, 0).into_owned());
        self.add_h_block(3, ITH, &h.fixed_view::<3, 3>(3, 3).into_owned());
        let noise = 0.5 * (covariance + covariance.transpose());
        let (nis, threshold, applied) = self.kalman_update(&residual, &noise);
        Ok(self.record(MeasurementKind::Pose, nis, threshold, applied))
    }
}

/// Residual `z ⊖ ẑ` of a pose measurement in the `[δt; δθ]` convention:
/// `(t_meas − t̂, Log(R̂ᵀ·R_meas))`.
pub(crate) fn pose_residual(
    t_pred: &Vector3<f64>,
    q_pred: &UnitQuaternion<f64>,
    measured: &Isometry3<f64>,
) -> Vector6<f64> {
    let r_t = measured.translation.vector - t_pred;
    let r_th = log(&(q_pred.inverse() * measured.rotation));
    Vector6::new(r_t.x, r_t.y, r_t.z, r_th.x, r_th.y, r_th.z)
}

/// Predicted `t_from_to` (translation, rotation) of two poses in the local frame and its
/// Jacobian with respect to `[δp_from, δθ_from, δp_to, δθ_to]` (global attitude errors).
pub(crate) fn relative_pose_model(
    p_from: &Vector3<f64>,
    q_from: &UnitQuaternion<f64>,
    p_to: &Vector3<f64>,
    q_to: &UnitQuaternion<f64>,
) -> (Vector3<f64>, UnitQuaternion<f64>, SMatrix<f64, 6, 12>) {
    let r_from_t = q_from.to_rotation_matrix().into_inner().transpose();
    let r_to_t = q_to.to_rotation_matrix().into_inner().transpose();
    let d = p_to - p_from;
    let mut h = SMatrix::<f64, 6, 12>::zeros();
    h.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-r_from_t));
    h.fixed_view_mut::<3, 3>(0, 3).copy_from(&(r_from_t * skew(&d)));
    h.fixed_view_mut::<3, 3>(0, 6).copy_from(&r_from_t);
    h.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-r_to_t));
    h.fixed_view_mut::<3, 3>(3, 9).copy_from(&r_to_t);
    (r_from_t * d, q_from.inverse() * q_to, h)
}

/// Predicted body-frame velocity `Rᵀ·v` and its Jacobian with respect to `[δv, δθ]`.
pub(crate) fn wheel_model(v_local_mps: &Vector3<f64>, q: &UnitQuaternion<f64>) -> (Vector3<f64>, SMatrix<f64, 3, 6>) {
    let r_t = q.to_rotation_matrix().into_inner().transpose();
    let mut h = SMatrix::<f64, 3, 6>::zeros();
    h.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_t);
    h.fixed_view_mut::<3, 3>(0, 3).copy_from(&(r_t * skew(v_local_mps)));
    (r_t * v_local_mps, h)
}

/// Jacobian of an absolute pose measurement with respect to `[δp, δθ]`: the body-right rotation
/// error of a global one is `Rᵀ·δθ`.
pub(crate) fn pose_jacobian(q: &UnitQuaternion<f64>) -> Matrix6<f64> {
    let mut h = Matrix6::zeros();
    h.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::identity());
    h.fixed_view_mut::<3, 3>(3, 3).copy_from(&q.to_rotation_matrix().into_inner().transpose());
    h
}

/// Zero-velocity prediction `[v; b_g]` (at rest the gyro reads its bias) and its Jacobian with
/// respect to `[δv, δb_g]`.
pub(crate) fn zero_velocity_model(
    v_local_mps: &Vector3<f64>,
    gyro_bias_radps: &Vector3<f64>,
) -> (Vector6<f64>, Matrix6<f64>) {
    let v = v_local_mps;
    let b = gyro_bias_radps;
    (Vector6::new(v.x, v.y, v.z, b.x, b.y, b.z), Matrix6::identity())
}
