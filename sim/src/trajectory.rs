//! Smooth continuous-time trajectories with analytic derivatives (owned by the IMU helper).
//!
//! CONTRACT: a uniform quintic B-spline over six channels `[x, y, z, roll, pitch, yaw]`
//! (world position, yaw-pitch-roll `R = Rz·Ry·Rx`), so position is C⁴ and the IMU's specific
//! force and angular rate come from exact derivatives, not finite differences.
//!
//! # Valid span
//!
//! Segment `i` (time `[i·Δ, (i+1)·Δ)` after the start) blends control points `i..i+6`, so `n`
//! control points give `n − 5` segments and the valid span is `[start, start + (n − 5)·Δ]`.
//! The spline does not pass through its control points (B-splines approximate them), which is
//! what keeps every derivative smooth.

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};

/// Kinematic state of a body at one instant, from a [`Trajectory`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KinematicState {
    pub t_world_body: Isometry3<f64>,
    pub v_world_mps: Vector3<f64>,
    pub a_world_mps2: Vector3<f64>,
    /// Angular velocity of the body in the body frame.
    pub omega_body_radps: Vector3<f64>,
    /// `[roll, pitch, yaw]` and their rates.
    pub euler_rad: Vector3<f64>,
    pub euler_rate_radps: Vector3<f64>,
}

/// Why a trajectory could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TrajectoryError {
    #[error("a quintic B-spline needs at least 6 control points, got {0}")]
    TooFewKnots(usize),
    #[error("knot interval must be positive and finite, got {0}")]
    BadInterval(f64),
    #[error("control point {0} is not finite")]
    NotFinite(usize),
}

/// Number of control points one segment of a quintic spline blends.
const ORDER: usize = 6;

/// Uniform quintic B-spline basis: row `p` holds the coefficients of `u^p`, column `j` belongs to
/// the segment's `j`-th control point; the weights are this matrix divided by 5! = 120. (Checked
/// against Cox–de Boor recursion.)
const BASIS_X120: [[f64; ORDER]; ORDER] = [
    [1.0, 26.0, 66.0, 26.0, 1.0, 0.0],
    [-5.0, -50.0, 0.0, 50.0, 5.0, 0.0],
    [10.0, 20.0, -60.0, 20.0, 10.0, 0.0],
    [-10.0, 20.0, 0.0, -20.0, 10.0, 0.0],
    [5.0, -20.0, 30.0, -20.0, 5.0, 0.0],
    [-1.0, 5.0, -10.0, 10.0, -5.0, 1.0],
];

/// A uniform quintic B-spline trajectory.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    start_ns: u64,
    knot_interval_s: f64,
    control_points: Vec<[f64; 6]>,
}

impl Trajectory {
    /// A spline whose valid time span starts at `start_ns`; `control_points` are
    /// `[x, y, z, roll, pitch, yaw]` (yaw unwrapped by the caller: no jumps of 2π).
    pub fn new(start_ns: u64, knot_interval_s: f64, control_points: Vec<[f64; 6]>) -> Result<Self, TrajectoryError> {
        if !(knot_interval_s.is_finite() && knot_interval_s > 0.0) {
            return Err(TrajectoryError::BadInterval(knot_interval_s));
        }
        if control_points.len() < ORDER {
            return Err(TrajectoryError::TooFewKnots(control_points.len()));
        }
        if let Some(bad) = control_points.iter().position(|cp| cp.iter().any(|c| !c.is_finite())) {
            return Err(TrajectoryError::NotFinite(bad));
        }
        Ok(Trajectory { start_ns, knot_interval_s, control_points })
    }

    pub fn start_ns(&self) -> u64 {
        self.start_ns
    }

    /// End of the valid time span: `start + (n − 5)·Δ`, rounded to the nearest nanosecond.
    pub fn end_ns(&self) -> u64 {
        self.start_ns + (self.duration_s() * 1e9).round() as u64
    }

    /// Length of the valid span, `(n − 5)·Δ`.
    pub fn duration_s(&self) -> f64 {
        self.segment_count() as f64 * self.knot_interval_s
    }

    pub fn knot_interval_s(&self) -> f64 {
        self.knot_interval_s
    }

    pub fn control_points(&self) -> &[[f64; 6]] {
        &self.control_points
    }

    /// State at `stamp_ns`, `None` outside `[start_ns, end_ns]`.
    pub fn state_at(&self, stamp_ns: u64) -> Option<KinematicState> {
        if stamp_ns < self.start_ns || stamp_ns > self.end_ns() {
            return None;
        }
        // The end stamp may lie up to half a nanosecond past the exact span; evaluating the last
        // segment's polynomial that little beyond u = 1 is harmless.
        Some(self.evaluate((stamp_ns - self.start_ns) as f64 * 1e-9))
    }

    /// State at `t_s` seconds after the start, `None` outside `[0, duration_s]`.
    pub fn state_at_s(&self, t_s: f64) -> Option<KinematicState> {
        if !(0.0..=self.duration_s()).contains(&t_s) {
            return None;
        }
        Some(self.evaluate(t_s))
    }

    fn segment_count(&self) -> usize {
        self.control_points.len() + 1 - ORDER
    }

    /// Channels and their first two time derivatives at `t_s` (not range-checked).
    fn channels(&self, t_s: f64) -> [[f64; 6]; 3] {
        let s = t_s / self.knot_interval_s;
        let segment = (s.floor().max(0.0) as usize).min(self.segment_count() - 1);
        let u = s - segment as f64;

        // Weights of the segment's control points for the value and its first two time
        // derivatives: the basis rows, weighted by u^p and its derivatives, accumulated per power.
        let inv_dt = 1.0 / self.knot_interval_s;
        let mut weights = [[0.0; ORDER]; 3];
        let mut u_pow = [0.0; ORDER];
        let mut up = 1.0;
        for value in u_pow.iter_mut() {
            *value = up;
            up *= u;
        }
        for (p, row) in BASIS_X120.iter().enumerate() {
            let pf = p as f64;
            let d0 = u_pow[p] / 120.0;
            let d1 = if p >= 1 { pf * u_pow[p - 1] * inv_dt / 120.0 } else { 0.0 };
            let d2 = if p >= 2 { pf * (pf - 1.0) * u_pow[p - 2] * inv_dt * inv_dt / 120.0 } else { 0.0 };
            for (j, m) in row.iter().enumerate() {
                weights[0][j] += m * d0;
                weights[1][j] += m * d1;
                weights[2][j] += m * d2;
            }
        }

        let mut out = [[0.0; 6]; 3];
        let points = &self.control_points[segment..segment + ORDER];
        for (row, w) in out.iter_mut().zip(&weights) {
            for (wj, cp) in w.iter().zip(points) {
                for (value, c) in row.iter_mut().zip(cp) {
                    *value += wj * c;
                }
            }
        }
        out
    }

    fn evaluate(&self, t_s: f64) -> KinematicState {
        let [value, rate, accel] = self.channels(t_s);
        let (roll, pitch, yaw) = (value[3], value[4], value[5]);
        let (roll_rate, pitch_rate, yaw_rate) = (rate[3], rate[4], rate[5]);
        // nalgebra's from_euler_angles(roll, pitch, yaw) is exactly Rz(yaw)·Ry(pitch)·Rx(roll).
        let q_world_body = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
        let (sr, cr) = roll.sin_cos();
        let (sp, cp) = pitch.sin_cos();
        // ω_body = ṙ·x + Rx(r)ᵀ·ṗ·y + (Ry(p)·Rx(r))ᵀ·ẏ·z, summed.
        let omega_body_radps = Vector3::new(
            roll_rate - yaw_rate * sp,
            pitch_rate * cr + yaw_rate * cp * sr,
            -pitch_rate * sr + yaw_rate * cp * cr,
        );
        KinematicState {
            t_world_body: Isometry3::from_parts(Translation3::new(value[0], value[1], value[2]), q_world_body),
            v_world_mps: Vector3::new(rate[0], rate[1], rate[2]),
            a_world_mps2: Vector3::new(accel[0], accel[1], accel[2]),
            omega_body_radps,
            euler_rad: Vector3::new(roll, pitch, yaw),
            euler_rate_radps: Vector3::new(roll_rate, pitch_rate, yaw_rate),
        }
    }
}
