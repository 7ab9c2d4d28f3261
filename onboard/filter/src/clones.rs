//! Stochastic cloning (eq. 4.3): pose clones at image capture times, kept for keyframes, released
//! after their update, marginalized (rows and columns dropped) when no longer needed.

use crate::FilterError;
use crate::eskf::{Filter, IBG, IP, ITH, IV, NX, PoseClone};
use crate::math::{exp, left_jacobian};
use nalgebra::{SMatrix, UnitQuaternion, Vector3};

impl Filter {
    pub(crate) fn clone_pose_at(&mut self, stamp_ns: u64) -> Result<(), FilterError> {
        if self.clone_index(stamp_ns).is_some() {
            return Ok(());
        }
        self.prune_clones(stamp_ns.max(self.stamp_ns));
        let mut lag_s = 0.0;
        if stamp_ns >= self.stamp_ns {
            self.extrapolate_to(stamp_ns)?;
        } else {
            let lag_ns = self.stamp_ns - stamp_ns;
            if lag_ns > self.config.max_clone_lag_ns {
                return Err(FilterError::BadInput(format!(
                    "clone stamp {stamp_ns} lies {lag_ns} ns before the state (max {})",
                    self.config.max_clone_lag_ns
                )));
            }
            lag_s = lag_ns as f64 * 1e-9;
        }
        let w_body_radps = self.last_imu.map(|s| s.gyro_radps - self.bg).unwrap_or_else(Vector3::zeros);
        let (p, q) = if lag_s > 0.0 {
            // Back-extrapolation over a few milliseconds: constant velocity and the latest rate;
            // the acceleration term (≤ 1 mm at 20 ms) is neglected.
            (self.p - self.v * lag_s, self.q * exp(&(-w_body_radps * lag_s)))
        } else {
            (self.p, self.q)
        };
        if self.clones.len() >= self.config.max_clones {
            let victim = self.clones.iter().position(|c| !c.keyframe).unwrap_or(0);
            self.marginalize_clone(victim);
            self.health.clones_evicted += 1;
        }
        let j = clone_jacobian(&self.q, &w_body_radps, lag_s);
        let n = self.dim();
        // New rows: J·P[core, 0..n]; corner: J·P[core, core]·Jᵀ.
        for col in 0..n {
            for a in 0..6 {
                let mut acc = 0.0;
                for k in 0..NX {
                    let jk = j[(a, k)];
                    if jk != 0.0 {
                        acc += jk * self.cov[(k, col)];
                    }
                }
                self.cov[(n + a, col)] = acc;
                self.cov[(col, n + a)] = acc;
            }
        }
        for a in 0..6 {
            for b in 0..6 {
                let mut acc = 0.0;
                for k in 0..NX {
                    let jk = j[(b, k)];
                    if jk != 0.0 {
                        acc += self.cov[(n + a, k)] * jk;
                    }
                }
                self.cov[(n + a, n + b)] = acc;
            }
        }
        self.clones.push(PoseClone { stamp_ns, p, q, keyframe: false, released: false });
        Ok(())
    }

    pub(crate) fn mark_keyframe_clone(&mut self, stamp_ns: u64) {
        let Some(i) = self.clone_index(stamp_ns) else {
            return;
        };
        self.clones[i].keyframe = true;
        self.clones[i].released = false;
        let keyframes = self.clones.iter().filter(|c| c.keyframe).count();
        if keyframes > self.config.max_keyframe_clones
            && let Some(oldest) = self.clones.iter().position(|c| c.keyframe)
        {
            self.marginalize_clone(oldest);
        }
    }

    /// Marks the clone of `stamp_ns` as processed (dropped at the next `clone_at` unless it is, or
    /// becomes, a keyframe).
    pub(crate) fn release_clone_at(&mut self, stamp_ns: u64) {
        if let Some(i) = self.clone_index(stamp_ns) {
            self.clones[i].released = true;
        }
    }

    /// Drops released non-keyframe clones and pending ones too old to be measured any more.
    fn prune_clones(&mut self, now_ns: u64) {
        let max_age = self.config.max_pending_clone_age_ns;
        let mut i = self.clones.len();
        while i > 0 {
            i -= 1;
            let c = self.clones[i];
            if !c.keyframe && (c.released || now_ns.saturating_sub(c.stamp_ns) > max_age) {
                self.marginalize_clone(i);
            }
        }
    }

    /// Removes clone `i` from the state: its 6 rows and columns are dropped (marginalization of a
    /// Gaussian), the rest shifts up and left in place.
    pub(crate) fn marginalize_clone(&mut self, i: usize) {
        let n = self.dim();
        let start = NX + 6 * i;
        for col in 0..n {
            for row in start..(n - 6) {
                self.cov[(row, col)] = self.cov[(row + 6, col)];
            }
        }
        for col in start..(n - 6) {
            for row in 0..(n - 6) {
                self.cov[(row, col)] = self.cov[(row, col + 6)];
            }
        }
        self.clones.remove(i);
    }
}

/// Jacobian of a clone `(δp_c, δθ_c)` with respect to the core error state, for a capture
/// `lag_s` before the state, back-extrapolated with the bias-corrected rate `w_body_radps`
/// (see [`Filter::clone_pose_at`]): `p_c = p − v·Δ`, `q_c = q·Exp(−(w_m − b_g)·Δ)`, so
/// `δp_c = δp − Δ·δv` and `δθ_c = δθ + R·J_l(−ω·Δ)·Δ·δb_g` (a bias error turns the back-rotation).
pub(crate) fn clone_jacobian(q: &UnitQuaternion<f64>, w_body_radps: &Vector3<f64>, lag_s: f64) -> SMatrix<f64, 6, NX> {
    let mut j = SMatrix::<f64, 6, NX>::zeros();
    for a in 0..3 {
        j[(a, IP + a)] = 1.0;
        j[(a, IV + a)] = -lag_s;
        j[(3 + a, ITH + a)] = 1.0;
    }
    if lag_s > 0.0 {
        let r = q.to_rotation_matrix().into_inner();
        j.fixed_view_mut::<3, 3>(3, IBG).copy_from(&(r * left_jacobian(&(-w_body_radps * lag_s)) * lag_s));
    }
    j
}
