//! Wheel odometry from the drives' encoders: a skid-steer (differential) model.
//!
//! The LRU steers each wheel individually; we simplify it to skid steering, where both left
//! wheels turn at `v − ω·b/2` and both right wheels at `v + ω·b/2` (`b` the track width). That is
//! exact for a differential drive and is what the simulator's odometry reports anyway (forward
//! speed and yaw rate, no lateral motion). Wheel order: front-left, front-right, rear-left,
//! rear-right.
//!
//! # Quantisation
//!
//! Positions are whole counts. Over an interval each wheel's count difference is off from the
//! true rotation by less than 1 count, so with `q = 2π·r / counts_per_rev` the distance one count
//! is worth, [`SkidSteerKinematics::twist_from_encoders`] is off by less than
//! `q / dt` in `v` (mean of four wheels, each < 1 count) and `2q / (b·dt)` in `ω` (difference of
//! the two sides' means). [`SkidSteerKinematics::twist_resolution`] gives these bounds.

use std::f64::consts::TAU;

use super::device::DEFAULT_COUNTS_PER_REV;
use super::master::{WHEELS, WheelEncoders};

/// Geometry and encoder resolution of a skid-steered four-wheel rover.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SkidSteerKinematics {
    pub wheel_radius_m: f64,
    /// Distance between the left and right wheels' contact points.
    pub track_width_m: f64,
    pub counts_per_rev: u32,
}

impl SkidSteerKinematics {
    /// Our assumption for an LRU-sized rover (the thesis gives no wheel geometry): 0.1 m wheel
    /// radius, 0.6 m track width, the drives' default 409 600 counts per wheel revolution.
    pub fn lru_like() -> Self {
        SkidSteerKinematics { wheel_radius_m: 0.1, track_width_m: 0.6, counts_per_rev: DEFAULT_COUNTS_PER_REV }
    }

    /// Wheel speeds (rad/s, wheel order) that drive the body at forward speed `v_mps` and yaw
    /// rate `omega_radps` (positive counter-clockwise seen from above).
    pub fn wheel_speeds_from_twist(&self, v_mps: f64, omega_radps: f64) -> [f64; WHEELS] {
        let half_track_m = 0.5 * self.track_width_m;
        let left = (v_mps - omega_radps * half_track_m) / self.wheel_radius_m;
        let right = (v_mps + omega_radps * half_track_m) / self.wheel_radius_m;
        [left, right, left, right]
    }

    /// Forward speed and yaw rate over `dt_s` between two cycles, from position differences
    /// (wrap-safe: correct as long as no wheel turns more than 2³¹ counts in between). `None`
    /// if `dt_s` is not positive and finite or the geometry is degenerate.
    pub fn twist_from_encoders(&self, prev: &WheelEncoders, cur: &WheelEncoders, dt_s: f64) -> Option<(f64, f64)> {
        if !(dt_s.is_finite() && dt_s > 0.0 && self.track_width_m > 0.0 && self.counts_per_rev > 0) {
            return None;
        }
        let rad_per_count = TAU / f64::from(self.counts_per_rev);
        let speed_mps = |wheel: usize| {
            let delta_counts = cur.positions_counts[wheel].wrapping_sub(prev.positions_counts[wheel]);
            f64::from(delta_counts) * rad_per_count * self.wheel_radius_m / dt_s
        };
        let left_mps = 0.5 * (speed_mps(0) + speed_mps(2));
        let right_mps = 0.5 * (speed_mps(1) + speed_mps(3));
        Some((0.5 * (left_mps + right_mps), (right_mps - left_mps) / self.track_width_m))
    }

    /// Bounds of the quantisation error of [`Self::twist_from_encoders`] over `dt_s`:
    /// `(v_mps, omega_radps)`, see the module doc.
    pub fn twist_resolution(&self, dt_s: f64) -> (f64, f64) {
        let count_m = TAU * self.wheel_radius_m / f64::from(self.counts_per_rev);
        (count_m / dt_s, 2.0 * count_m / (self.track_width_m * dt_s))
    }
}
