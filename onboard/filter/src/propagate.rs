//! IMU propagation of the nominal state and the covariance.
//!
//! Between two samples the measured rate and specific force are taken as linear in time (the
//! trapezoid of the two samples): rotation by the mean rate, velocity by the trapezoid of the
//! rotated specific forces, position by the exact double integral of a linear acceleration. When
//! the state must reach a stamp beyond the latest sample (a clone at an image trigger), the latest
//! sample is held; the next sample then continues from the value interpolated at the state's stamp.
//! Steps use the stamps' differences (jitter and gaps are fine).
//!
//! The covariance uses a first-order discrete transition `F ≈ I + A·dt` (plus the `dt²` terms that
//! couple position to attitude and biases) and the noise densities integrated over `dt`.

use crate::FilterError;
use crate::config::GYRO_SCALE_CORRELATION_S;
use crate::eskf::{Filter, IBA, IBG, IP, ITH, IV, NX};
use crate::math::{exp, skew};
use hal::sensor::ImuSample;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// Gaps between IMU samples longer than this are counted in the health.
const IMU_GAP_NS: u64 = 50_000_000;

impl Filter {
    pub(crate) fn propagate_imu(&mut self, imu: &ImuSample) -> Result<(), FilterError> {
        if !(imu.gyro_radps.iter().chain(imu.accel_mps2.iter()).all(|x| x.is_finite())) {
            return Err(FilterError::BadInput("non-finite IMU sample".into()));
        }
        self.health.imu_samples += 1;
        let Some(prev) = self.last_imu else {
            // First sample: hold it back to the state's stamp.
            if imu.stamp_ns > self.stamp_ns {
                self.integrate(imu.stamp_ns, &imu.gyro_radps, &imu.accel_mps2, &imu.gyro_radps, &imu.accel_mps2);
            }
            self.last_imu = Some(*imu);
            return Ok(());
        };
        if imu.stamp_ns <= prev.stamp_ns {
            self.health.imu_out_of_order += 1;
            return Ok(());
        }
        if imu.stamp_ns - prev.stamp_ns > IMU_GAP_NS {
            self.health.imu_gaps += 1;
        }
        if imu.stamp_ns > self.stamp_ns {
            // The sample values at the state's stamp (later than `prev` after a clone).
            let span = (imu.stamp_ns - prev.stamp_ns) as f64;
            let alpha = (self.stamp_ns.saturating_sub(prev.stamp_ns) as f64 / span).clamp(0.0, 1.0);
            let w0 = prev.gyro_radps + (imu.gyro_radps - prev.gyro_radps) * alpha;
            let a0 = prev.accel_mps2 + (imu.accel_mps2 - prev.accel_mps2) * alpha;
            self.integrate(imu.stamp_ns, &w0, &a0, &imu.gyro_radps, &imu.accel_mps2);
        }
        // A sample at or before the state's stamp (the state was extrapolated to a clone beyond
        // it) only becomes the held sample.
        self.last_imu = Some(*imu);
        Ok(())
    }

    /// Extrapolates with the latest sample held up to `stamp_ns`.
    pub(crate) fn extrapolate_to(&mut self, stamp_ns: u64) -> Result<(), FilterError> {
        if stamp_ns <= self.stamp_ns {
            return Ok(());
        }
        let Some(held) = self.last_imu else {
            return Err(FilterError::BadInput("cannot propagate: no IMU sample yet".into()));
        };
        self.integrate(stamp_ns, &held.gyro_radps, &held.accel_mps2, &held.gyro_radps, &held.accel_mps2);
        Ok(())
    }

    /// One step from the state's stamp to `t1_ns` with the measurements linear between
    /// `(w0, a0)` at the start and `(w1, a1)` at the end.
    fn integrate(&mut self, t1_ns: u64, w0: &Vector3<f64>, a0: &Vector3<f64>, w1: &Vector3<f64>, a1: &Vector3<f64>) {
        let dt = (t1_ns - self.stamp_ns) as f64 * 1e-9;
        let step = self.integrate_nominal(dt, w0, a0, w1, a1);
        self.propagate_covariance(dt, &step);
        self.stamp_ns = t1_ns;
    }

    /// The nominal state over `dt` (s); returns what the transition matrix needs.
    pub(crate) fn integrate_nominal(
        &mut self,
        dt: f64,
        w0: &Vector3<f64>,
        a0: &Vector3<f64>,
        w1: &Vector3<f64>,
        a1: &Vector3<f64>,
    ) -> StepLinearization {
        let w_mid = 0.5 * (w0 + w1) - self.bg;
        let f0 = a0 - self.ba;
        let f1 = a1 - self.ba;
        let r0 = self.q.to_rotation_matrix().into_inner();
        let q1 = self.q * exp(&(w_mid * dt));
        let r1 = q1.to_rotation_matrix().into_inner();
        let acc0 = r0 * f0 + self.gravity;
        let acc1 = r1 * f1 + self.gravity;
        self.p += self.v * dt + (2.0 * acc0 + acc1) * (dt * dt / 6.0);
        self.v += 0.5 * (acc0 + acc1) * dt;
        self.q = q1;
        self.q.renormalize();

        let r_mid = (self.q * exp(&(-0.5 * w_mid * dt))).to_rotation_matrix().into_inner();
        StepLinearization { r_mid_local_body: r_mid, f_local_mps2: 0.5 * (r0 * f0 + r1 * f1), w_body_radps: w_mid }
    }

    fn propagate_covariance(&mut self, dt: f64, step: &StepLinearization) {
        let f = transition_matrix(dt, step);
        let w = &step.w_body_radps;
        let n = &self.config.imu;
        let qa = n.accel_noise_density * n.accel_noise_density * dt;
        // Scale and misalignment errors rotate the attitude in proportion to the turn: spread as
        // white rate noise over their correlation time (see `FilterConfig::gyro_scale_sigma`).
        let scale = self.config.gyro_scale_sigma;
        let qg = (n.gyro_noise_density * n.gyro_noise_density
            + scale * scale * w.norm_squared() * GYRO_SCALE_CORRELATION_S)
            * dt;
        let qba = n.accel_random_walk * n.accel_random_walk * dt;
        let qbg = n.gyro_random_walk * n.gyro_random_walk * dt;
        let pxx: SMatrix<f64, NX, NX> = self.cov.fixed_view::<NX, NX>(0, 0).into_owned();
        let mut new = f * pxx * f.transpose();
        for i in 0..3 {
            new[(IP + i, IP + i)] += qa * dt * dt / 3.0;
            new[(IP + i, IV + i)] += qa * dt / 2.0;
            new[(IV + i, IP + i)] += qa * dt / 2.0;
            new[(IV + i, IV + i)] += qa;
            new[(ITH + i, ITH + i)] += qg;
            new[(IBA + i, IBA + i)] += qba;
            new[(IBG + i, IBG + i)] += qbg;
        }
        let new = 0.5 * (new + new.transpose());
        self.cov.fixed_view_mut::<NX, NX>(0, 0).copy_from(&new);
        for k in 0..self.clones.len() {
            let c = NX + 6 * k;
            let pxc: SMatrix<f64, NX, 6> = self.cov.fixed_view::<NX, 6>(0, c).into_owned();
            let moved = f * pxc;
            self.cov.fixed_view_mut::<NX, 6>(0, c).copy_from(&moved);
            self.cov.fixed_view_mut::<6, NX>(c, 0).copy_from(&moved.transpose());
        }
        for i in 0..NX {
            let d = self.cov[(i, i)];
            if !d.is_finite() || d < 0.0 {
                self.check_covariance(true);
                break;
            }
        }
    }
}

/// The nominal step's values the error-state transition is linearized at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StepLinearization {
    /// Attitude at the middle of the step.
    pub r_mid_local_body: Matrix3<f64>,
    /// Mean specific force over the step, in the local frame.
    pub f_local_mps2: Vector3<f64>,
    /// Bias-corrected rate over the step.
    pub w_body_radps: Vector3<f64>,
}

/// Error-state transition over `dt` (s) for the global attitude error: `F = I + A·dt` plus the
/// `dt²/2` terms through which attitude and accelerometer bias reach position and the gyro bias
/// reaches velocity.
/// It equals the exact Jacobian of [`Filter::integrate_nominal`] up to `O(dt³)` and to the
/// `O(dt²·|a₁ − a₀|)` of the samples' change within the step (checked in `jacobian_checks`).
pub(crate) fn transition_matrix(dt: f64, step: &StepLinearization) -> SMatrix<f64, NX, NX> {
    let i3 = Matrix3::identity();
    let r = &step.r_mid_local_body;
    let fx = skew(&step.f_local_mps2);
    let dt2 = 0.5 * dt * dt;
    let mut f = SMatrix::<f64, NX, NX>::identity();
    f.fixed_view_mut::<3, 3>(IP, IV).copy_from(&(i3 * dt));
    f.fixed_view_mut::<3, 3>(IP, ITH).copy_from(&(-fx * dt2));
    f.fixed_view_mut::<3, 3>(IP, IBA).copy_from(&(-r * dt2));
    f.fixed_view_mut::<3, 3>(IV, ITH).copy_from(&(-fx * dt));
    f.fixed_view_mut::<3, 3>(IV, IBA).copy_from(&(-r * dt));
    f.fixed_view_mut::<3, 3>(IV, IBG).copy_from(&(fx * r * dt2));
    f.fixed_view_mut::<3, 3>(ITH, IBG).copy_from(&(-r * dt));
    f
}
