//! The error-state EKF: state, public API and the generic Kalman update.
//!
//! # Error convention
//!
//! Attitude errors are global (left): `q_true = Exp(δθ) ⊗ q̂`, `δθ` in the local frame; all other
//! errors are additive (`p_true = p̂ + δp`, ...). A clone `(p_c, q_c)` carries the same 6-D error
//! `(δp_c, δθ_c)`. The global attitude error makes the frame switch clean: yaw about the local z
//! axis and position are the gauge directions of the local frame, and both live entirely in
//! `(δp, δθ)` of the local frame, independent of the body's orientation.
//!
//! The covariance is one dense matrix over `[15-D core | 6-D per clone]`, allocated once for
//! `max_clones`; adding a clone writes its rows (cloning Jacobian), removing one marginalizes it
//! (drops its rows and columns). Nothing on the per-sample path allocates.

use crate::chi2::chi2_quantile;
use crate::math::{euler_to_global_error, exp, roll_pitch_yaw};
use crate::updates::pose_jacobian;
use crate::{FilterConfig, FilterHealth, FrameSwitch};
use hal::sensor::{ImuSample, WheelOdomSample};
use nalgebra::{DMatrix, DMatrixView, DVector, Isometry3, Matrix3, Matrix6, SMatrix, SVector, UnitQuaternion, Vector3};

/// Why the filter refused an input.
#[derive(Debug, thiserror::Error)]
pub enum FilterError {
    #[error("filter: not initialized")]
    NotInitialized,
    #[error("filter: {0}")]
    BadInput(String),
}

/// A relative pose of the body between two capture times (for example a VO keyframe delta),
/// `t_from_to` = body at `to_stamp_ns` in the body frame at `from_stamp_ns`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RelativePoseMeasurement {
    pub from_stamp_ns: u64,
    pub to_stamp_ns: u64,
    pub t_from_to: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

/// Result of one measurement update.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum UpdateOutcome {
    /// Applied; `nis` is the normalized innovation squared.
    Applied { nis: f64 },
    /// Failed the chi-square gate.
    Rejected { nis: f64, threshold: f64 },
    /// No clone of a referenced capture time is held (too old or never cloned).
    MissingClone,
}

/// The filter's output at IMU rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterState {
    pub stamp_ns: u64,
    /// Id of the current local frame (incremented by every frame switch).
    pub frame_id: u32,
    pub t_local_body: Isometry3<f64>,
    pub v_local_mps: Vector3<f64>,
    pub accel_bias_mps2: Vector3<f64>,
    pub gyro_bias_radps: Vector3<f64>,
    /// Covariance of the 15-D error state (δp, δv, δθ, δb_a, δb_g); `δθ` is the global attitude
    /// error in the local frame (see the module docs; [`Filter::pose_covariance`] gives the pose
    /// block in the crate's `[δt; δθ]` convention).
    pub covariance: SMatrix<f64, 15, 15>,
}

/// Size of the core error state.
pub(crate) const NX: usize = 15;
pub(crate) const IP: usize = 0;
pub(crate) const IV: usize = 3;
pub(crate) const ITH: usize = 6;
pub(crate) const IBA: usize = 9;
pub(crate) const IBG: usize = 12;

/// A cloned pose at an image capture time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PoseClone {
    pub stamp_ns: u64,
    pub p: Vector3<f64>,
    pub q: UnitQuaternion<f64>,
    pub keyframe: bool,
    /// Its measurement was processed; dropped at the next `clone_at` unless it became a keyframe.
    pub released: bool,
}

/// Buffers of the Kalman update, sized for the largest state.
#[derive(Debug, Clone)]
pub(crate) struct Scratch {
    /// `Hᵀ` (state dimension × up to 6 measurement rows).
    pub ht: DMatrix<f64>,
    pub pht: DMatrix<f64>,
    pub gain: DMatrix<f64>,
    pub dx: DVector<f64>,
}

/// The local reference filter (`Clone` copies the whole state: what-if runs, tests).
#[derive(Debug, Clone)]
pub struct Filter {
    pub(crate) config: FilterConfig,
    pub(crate) health: FilterHealth,
    pub(crate) initialized: bool,
    pub(crate) stamp_ns: u64,
    pub(crate) frame_id: u32,
    pub(crate) p: Vector3<f64>,
    pub(crate) v: Vector3<f64>,
    pub(crate) q: UnitQuaternion<f64>,
    pub(crate) ba: Vector3<f64>,
    pub(crate) bg: Vector3<f64>,
    pub(crate) gravity: Vector3<f64>,
    pub(crate) last_imu: Option<ImuSample>,
    /// Stamp of the previous wheel odometry sample (its rate sets the correlation inflation).
    pub(crate) last_wheel_stamp_ns: Option<u64>,
    pub(crate) clones: Vec<PoseClone>,
    pub(crate) cov: DMatrix<f64>,
    /// Chi-square gates for 1..=6 degrees of freedom.
    pub(crate) gates: [f64; 6],
    pub(crate) scratch: Scratch,
}

impl Filter {
    pub fn new(config: FilterConfig) -> Self {
        let max_clones = config.max_clones.max(2);
        let n_max = NX + 6 * max_clones;
        let mut gates = [f64::INFINITY; 6];
        for (dof, gate) in gates.iter_mut().enumerate() {
            let q = chi2_quantile(dof as u32 + 1, config.gate_probability);
            // A probability of 1 (or garbage) disables gating rather than rejecting everything.
            *gate = if q.is_finite() { q } else { f64::INFINITY };
        }
        Filter {
            gravity: Vector3::new(0.0, 0.0, -config.gravity_mps2),
            config: FilterConfig { max_clones, ..config },
            health: FilterHealth::default(),
            initialized: false,
            stamp_ns: 0,
            frame_id: 0,
            p: Vector3::zeros(),
            v: Vector3::zeros(),
            q: UnitQuaternion::identity(),
            ba: Vector3::zeros(),
            bg: Vector3::zeros(),
            last_imu: None,
            last_wheel_stamp_ns: None,
            clones: Vec::with_capacity(max_clones),
            cov: DMatrix::zeros(n_max, n_max),
            gates,
            scratch: Scratch {
                ht: DMatrix::zeros(n_max, 6),
                pht: DMatrix::zeros(n_max, 6),
                gain: DMatrix::zeros(n_max, 6),
                dx: DVector::zeros(n_max),
            },
        }
    }

    pub fn config(&self) -> &FilterConfig {
        &self.config
    }

    pub fn is_initialized(&self) -> bool {
        self.initialized
    }

    /// Starts at rest: roll and pitch from the mean specific force, gyro bias from the mean
    /// rate, position and yaw zero (the first local frame).
    pub fn initialize_at_rest(
        &mut self,
        stamp_ns: u64,
        mean_accel_mps2: &Vector3<f64>,
        mean_gyro_radps: &Vector3<f64>,
    ) -> Result<(), FilterError> {
        let f = mean_accel_mps2;
        let norm = f.norm();
        if !(norm.is_finite() && mean_gyro_radps.iter().all(|w| w.is_finite())) {
            return Err(FilterError::BadInput("non-finite initial IMU mean".into()));
        }
        // A mean far from gravity means the body was not at rest (or the gravity is wrong).
        if (norm - self.config.gravity_mps2).abs() > 0.2 * self.config.gravity_mps2 {
            return Err(FilterError::BadInput(format!(
                "mean specific force {norm:.3} m/s² is not gravity {:.3} m/s²",
                self.config.gravity_mps2
            )));
        }
        let roll = f.y.atan2(f.z);
        let pitch = (-f.x).atan2((f.y * f.y + f.z * f.z).sqrt());
        let q = UnitQuaternion::from_euler_angles(roll, pitch, 0.0);
        let s = self.config.initial;
        self.reset_state(stamp_ns, Vector3::zeros(), Vector3::zeros(), q, *mean_gyro_radps);
        self.set_initial_covariance(0.0, s.velocity_mps, s.roll_pitch_rad, 0.0);
        Ok(())
    }

    /// Starts from a known pose and velocity (for example ground truth in a test), with the
    /// configured initial uncertainty.
    pub fn initialize_with_pose(
        &mut self,
        stamp_ns: u64,
        t_local_body: &Isometry3<f64>,
        v_local_mps: &Vector3<f64>,
    ) -> Result<(), FilterError> {
        let p = t_local_body.translation.vector;
        if !(p.iter().chain(v_local_mps.iter()).all(|x| x.is_finite())
            && t_local_body.rotation.coords.norm().is_finite())
        {
            return Err(FilterError::BadInput("non-finite initial pose".into()));
        }
        let s = self.config.initial;
        self.reset_state(stamp_ns, p, *v_local_mps, t_local_body.rotation, Vector3::zeros());
        self.set_initial_covariance(s.position_m, s.velocity_mps, s.roll_pitch_rad, s.yaw_rad);
        Ok(())
    }

    fn reset_state(
        &mut self,
        stamp_ns: u64,
        p: Vector3<f64>,
        v: Vector3<f64>,
        q: UnitQuaternion<f64>,
        bg: Vector3<f64>,
    ) {
        self.initialized = true;
        self.stamp_ns = stamp_ns;
        self.p = p;
        self.v = v;
        self.q = q;
        self.ba = Vector3::zeros();
        self.bg = bg;
        self.last_imu = None;
        self.last_wheel_stamp_ns = None;
        self.clones.clear();
    }

    fn set_initial_covariance(&mut self, position_m: f64, velocity_mps: f64, roll_pitch_rad: f64, yaw_rad: f64) {
        let s = self.config.initial;
        self.cov.fill(0.0);
        for i in 0..3 {
            self.cov[(IP + i, IP + i)] = position_m * position_m;
            self.cov[(IV + i, IV + i)] = velocity_mps * velocity_mps;
            self.cov[(IBA + i, IBA + i)] = s.accel_bias_mps2 * s.accel_bias_mps2;
            self.cov[(IBG + i, IBG + i)] = s.gyro_bias_radps * s.gyro_bias_radps;
        }
        // Roll/pitch/yaw sigmas are Euler-angle sigmas; map them into the global attitude error.
        let m = euler_to_global_error(&self.q);
        let euler = Matrix3::from_diagonal(&Vector3::new(
            roll_pitch_rad * roll_pitch_rad,
            roll_pitch_rad * roll_pitch_rad,
            yaw_rad * yaw_rad,
        ));
        let att = m * euler * m.transpose();
        self.cov.fixed_view_mut::<3, 3>(ITH, ITH).copy_from(&att);
    }

    /// Integrates one IMU sample (propagation of state and covariance up to its stamp).
    pub fn propagate(&mut self, imu: &ImuSample) -> Result<(), FilterError> {
        self.require_initialized()?;
        self.propagate_imu(imu)
    }

    /// Clones the pose at an image's capture time (the trigger), propagating to it first.
    pub fn clone_at(&mut self, stamp_ns: u64) -> Result<(), FilterError> {
        self.require_initialized()?;
        self.clone_pose_at(stamp_ns)
    }

    /// Keeps the clone of `stamp_ns` as a keyframe clone (VO made that frame a keyframe). Call it
    /// before the frame's own relative-pose update or at least before the next `clone_at`
    /// (released clones are dropped lazily there). Unknown stamps are ignored.
    pub fn mark_keyframe(&mut self, stamp_ns: u64) {
        self.mark_keyframe_clone(stamp_ns);
    }

    /// Releases the clone of a capture time whose measurement will not come (a frame the odometry
    /// skipped or that is not used for an update); keyframe clones stay. Unknown stamps are ignored.
    pub fn release_clone(&mut self, stamp_ns: u64) {
        self.release_clone_at(stamp_ns);
    }

    /// Relative pose between two cloned capture times (delay compensated: both may lie in the
    /// past). The clone of `to_stamp_ns` is released afterwards unless it is a keyframe.
    ///
    /// If no clone of `to_stamp_ns` is held but the state stands exactly at that stamp, the
    /// current pose is used as the `to` end.
    pub fn update_relative_pose(&mut self, m: &RelativePoseMeasurement) -> Result<UpdateOutcome, FilterError> {
        self.require_initialized()?;
        self.relative_pose_update(m)
    }

    /// Wheel odometry body velocity (apply after propagating to the sample's stamp).
    pub fn update_wheel_odometry(&mut self, sample: &WheelOdomSample) -> Result<UpdateOutcome, FilterError> {
        self.require_initialized()?;
        self.wheel_update(sample)
    }

    /// Zero velocity (and zero rotation rate, from the latest gyro sample) while standing.
    pub fn update_zero_velocity(&mut self) -> Result<UpdateOutcome, FilterError> {
        self.require_initialized()?;
        self.zero_velocity_update()
    }

    /// Absolute pose in the current local frame (tests with ground truth; a landmark), covariance
    /// in the `[δt; δθ]` convention (translation in the local frame, rotation right-multiplied).
    pub fn update_pose(
        &mut self,
        t_local_body: &Isometry3<f64>,
        covariance: &Matrix6<f64>,
    ) -> Result<UpdateOutcome, FilterError> {
        self.require_initialized()?;
        self.pose_update(t_local_body, covariance)
    }

    /// Frame-of-reference switch (thesis §4.1.2).
    pub fn switch_frame(&mut self) -> Result<FrameSwitch, FilterError> {
        self.require_initialized()?;
        Ok(self.switch_frame_now())
    }

    pub fn state(&self) -> Option<FilterState> {
        if !self.initialized {
            return None;
        }
        Some(FilterState {
            stamp_ns: self.stamp_ns,
            frame_id: self.frame_id,
            t_local_body: Isometry3::from_parts(self.p.into(), self.q),
            v_local_mps: self.v,
            accel_bias_mps2: self.ba,
            gyro_bias_radps: self.bg,
            covariance: self.cov.fixed_view::<15, 15>(0, 0).into_owned(),
        })
    }

    pub fn health(&self) -> &FilterHealth {
        &self.health
    }

    /// Stamp of the state (the latest IMU sample or clone).
    pub fn stamp_ns(&self) -> u64 {
        self.stamp_ns
    }

    pub fn frame_id(&self) -> u32 {
        self.frame_id
    }

    /// Covariance of the current pose `t_local_body` in the crate's `[δt; δθ]` convention
    /// (translation in the local frame, rotation right-multiplied in the body frame).
    pub fn pose_covariance(&self) -> Matrix6<f64> {
        self.pose_block_covariance(IP, ITH, &self.q)
    }

    /// Number of clones held (keyframes and pending frames).
    pub fn clone_count(&self) -> usize {
        self.clones.len()
    }

    /// Capture stamps of the clones held, oldest first, with whether each is a keyframe.
    pub fn clone_stamps(&self) -> impl Iterator<Item = (u64, bool)> + '_ {
        self.clones.iter().map(|c| (c.stamp_ns, c.keyframe))
    }

    /// The cloned pose of `stamp_ns` in the current local frame and its covariance (`[δt; δθ]`).
    pub fn clone_pose(&self, stamp_ns: u64) -> Option<(Isometry3<f64>, Matrix6<f64>)> {
        let i = self.clone_index(stamp_ns)?;
        let c = &self.clones[i];
        let base = NX + 6 * i;
        Some((Isometry3::from_parts(c.p.into(), c.q), self.pose_block_covariance(base, base + 3, &c.q)))
    }

    /// The whole covariance (core state and clones, global attitude errors).
    pub fn full_covariance(&self) -> DMatrixView<'_, f64> {
        let n = self.dim();
        self.cov.view((0, 0), (n, n))
    }

    pub(crate) fn require_initialized(&self) -> Result<(), FilterError> {
        if self.initialized { Ok(()) } else { Err(FilterError::NotInitialized) }
    }

    pub(crate) fn dim(&self) -> usize {
        NX + 6 * self.clones.len()
    }

    pub(crate) fn clone_index(&self, stamp_ns: u64) -> Option<usize> {
        self.clones.iter().position(|c| c.stamp_ns == stamp_ns)
    }

    /// A position/attitude block pair converted from global `δθ` to body-right `δθ_b = Rᵀ·δθ`.
    fn pose_block_covariance(&self, ip: usize, ith: usize, q: &UnitQuaternion<f64>) -> Matrix6<f64> {
        let j = pose_jacobian(q);
        j * self.pose_block(ip, ith) * j.transpose()
    }

    /// The covariance of `[δp; δθ]` from the blocks at `ip` and `ith` (global attitude error).
    pub(crate) fn pose_block(&self, ip: usize, ith: usize) -> Matrix6<f64> {
        let mut c = Matrix6::zeros();
        for (a, ia) in [ip, ip + 1, ip + 2, ith, ith + 1, ith + 2].into_iter().enumerate() {
            for (b, ib) in [ip, ip + 1, ip + 2, ith, ith + 1, ith + 2].into_iter().enumerate() {
                c[(a, b)] = self.cov[(ia, ib)];
            }
        }
        c
    }

    /// Roll, pitch and yaw of the current attitude.
    pub fn roll_pitch_yaw(&self) -> (f64, f64, f64) {
        roll_pitch_yaw(&self.q)
    }

    /// Kalman update with `Hᵀ` already in `scratch.ht[0..n, 0..M]`: gate, then correct state and
    /// covariance. Returns the NIS and whether it was applied.
    pub(crate) fn kalman_update<const M: usize>(
        &mut self,
        residual: &SVector<f64, M>,
        noise: &SMatrix<f64, M, M>,
    ) -> (f64, f64, bool) {
        let n = self.dim();
        let threshold = self.gates[M - 1];
        let Scratch { ht, pht, gain, dx } = &mut self.scratch;
        // P·Hᵀ, skipping the zero rows of Hᵀ (most of the state for any one measurement).
        for m in 0..M {
            for i in 0..n {
                pht[(i, m)] = 0.0;
            }
            for j in 0..n {
                let h = ht[(j, m)];
                if h != 0.0 {
                    for i in 0..n {
                        pht[(i, m)] += self.cov[(i, j)] * h;
                    }
                }
            }
        }
        let mut s = *noise;
        for a in 0..M {
            for b in 0..M {
                let mut acc = 0.0;
                for j in 0..n {
                    acc += ht[(j, a)] * pht[(j, b)];
                }
                s[(a, b)] += acc;
            }
        }
        s = 0.5 * (s + s.transpose());
        let Some(chol) = s.cholesky() else {
            return (f64::INFINITY, threshold, false);
        };
        let s_inv = chol.inverse();
        let nis = residual.dot(&(s_inv * residual));
        if !nis.is_finite() || nis > threshold {
            return (nis, threshold, false);
        }
        for i in 0..n {
            for m in 0..M {
                let mut acc = 0.0;
                for k in 0..M {
                    acc += pht[(i, k)] * s_inv[(k, m)];
                }
                gain[(i, m)] = acc;
            }
            let mut d = 0.0;
            for m in 0..M {
                d += gain[(i, m)] * residual[m];
            }
            dx[i] = d;
        }
        // P − K·(P·Hᵀ)ᵀ = P − P·Hᵀ·S⁻¹·H·P, then symmetrized.
        for j in 0..n {
            for i in 0..n {
                let mut acc = 0.0;
                for m in 0..M {
                    acc += gain[(i, m)] * pht[(j, m)];
                }
                self.cov[(i, j)] -= acc;
            }
        }
        self.symmetrize();
        self.inject();
        self.check_covariance(true);
        (nis, threshold, true)
    }

    /// Clears the first `rows` columns of `Hᵀ`.
    pub(crate) fn clear_ht(&mut self, rows: usize) {
        let n = self.dim();
        for m in 0..rows {
            for i in 0..n {
                self.scratch.ht[(i, m)] = 0.0;
            }
        }
    }

    /// Adds the 3×3 block `h` of `H` at measurement row `row0`, state column `col0`.
    pub(crate) fn add_h_block(&mut self, row0: usize, col0: usize, h: &Matrix3<f64>) {
        for a in 0..3 {
            for b in 0..3 {
                self.scratch.ht[(col0 + b, row0 + a)] += h[(a, b)];
            }
        }
    }

    /// Applies the correction in `scratch.dx` to the nominal state and the clones.
    pub(crate) fn inject(&mut self) {
        let dx = &self.scratch.dx;
        let v3 = |i: usize| Vector3::new(dx[i], dx[i + 1], dx[i + 2]);
        self.p += v3(IP);
        self.v += v3(IV);
        self.q = exp(&v3(ITH)) * self.q;
        self.q.renormalize();
        self.ba += v3(IBA);
        self.bg += v3(IBG);
        for (i, c) in self.clones.iter_mut().enumerate() {
            let base = NX + 6 * i;
            c.p += v3(base);
            c.q = exp(&v3(base + 3)) * c.q;
            c.q.renormalize();
        }
    }

    pub(crate) fn symmetrize(&mut self) {
        let n = self.dim();
        for j in 0..n {
            for i in (j + 1)..n {
                let m = 0.5 * (self.cov[(i, j)] + self.cov[(j, i)]);
                self.cov[(i, j)] = m;
                self.cov[(j, i)] = m;
            }
        }
    }

    /// Covariance sanity: a negative or non-finite variance (and, with `full`, any non-finite
    /// entry) is repaired and counted. A repaired negative variance becomes its magnitude: the
    /// usual cause is round-off on a variance that should be near zero.
    pub(crate) fn check_covariance(&mut self, full: bool) {
        let n = self.dim();
        let mut repaired = false;
        if full {
            for j in 0..n {
                for i in 0..n {
                    if !self.cov[(i, j)].is_finite() {
                        self.cov[(i, j)] = 0.0;
                        repaired = true;
                    }
                }
            }
        }
        for i in 0..n {
            let d = self.cov[(i, i)];
            if !d.is_finite() {
                self.cov[(i, i)] = 1.0;
                repaired = true;
            } else if d < -1e-15 {
                self.cov[(i, i)] = -d;
                repaired = true;
            }
        }
        if repaired {
            self.health.covariance_repairs += 1;
        }
    }

    /// Records the outcome of one update in the health counters.
    pub(crate) fn record(&mut self, kind: MeasurementKind, nis: f64, threshold: f64, applied: bool) -> UpdateOutcome {
        let counters = match kind {
            MeasurementKind::RelativePose => &mut self.health.relative_pose,
            MeasurementKind::Wheel => &mut self.health.wheel,
            MeasurementKind::ZeroVelocity => &mut self.health.zero_velocity,
            MeasurementKind::Pose => &mut self.health.pose,
        };
        counters.last_nis = nis;
        if applied {
            counters.applied += 1;
            self.health.updates_applied += 1;
            UpdateOutcome::Applied { nis }
        } else {
            counters.rejected += 1;
            self.health.updates_rejected += 1;
            UpdateOutcome::Rejected { nis, threshold }
        }
    }
}

/// Which health counters an update goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum MeasurementKind {
    RelativePose,
    Wheel,
    ZeroVelocity,
    Pose,
}
