//! Frame-of-reference switching (thesis §4.1.2).
//!
//! The new frame `N` sits at the body's position with the body's yaw (roll = pitch = 0), so it is
//! gravity-aligned like every local frame. Everything is mapped with `T_new_old = (Rz(ψ), p)⁻¹`:
//! `p' = 0`, `v' = Rzᵀ·v`, `q' = Rzᵀ·q`, clones `p_c' = Rzᵀ·(p_c − p)`, `q_c' = Rzᵀ·q_c`; biases
//! stay. Because the new frame is defined by the *true* position and yaw, the errors of the new
//! state follow from the exact Jacobian of that map including the dependence of `Rz` on the true
//! yaw `ψ + δψ` with `δψ = J_ψ·δθ` ([`crate::math::yaw_jacobian`]):
//!
//! - `δp' = 0`,
//! - `δv' = Rzᵀ·δv + (v' × e_z)·J_ψ·δθ`,
//! - `δθ' = (Rzᵀ − e_z·J_ψ)·δθ` (its Euler-yaw part is exactly zero),
//! - `δp_c' = Rzᵀ·(δp_c − δp) + (p_c' × e_z)·J_ψ·δθ`, `δθ_c' = Rzᵀ·δθ_c − e_z·J_ψ·δθ`,
//!
//! and `P' = J·P·Jᵀ`. Position and yaw variances (and their cross terms) become zero; roll, pitch,
//! velocity, biases and clones keep their uncertainty, transformed (trap 3: no full reset).

use crate::eskf::{Filter, IBA, IBG, IP, ITH, IV, NX};
use crate::math::{yaw_jacobian, yaw_rotation};
use nalgebra::{DMatrix, Isometry3, Matrix3, Matrix6, RowVector3, UnitQuaternion, Vector3};

/// The result of a frame switch: the new local frame in the old one (x, y, z, yaw of the body at
/// switch time, roll = pitch = 0) with its covariance (`[δt; δθ]` convention). This is the
/// graph's factor between consecutive submap origins.
///
/// Covariance: `δt = δp` (old frame) and `δθ = (0, 0, δψ)` (right-multiplied, new frame) from the
/// filter's covariance of position and yaw; roll and pitch are exactly zero by construction and
/// get the configured tiny variance `switch_roll_pitch_variance_rad2` so the factor has full rank.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameSwitch {
    pub stamp_ns: u64,
    /// Id of the frame that ended and of the one that starts (`new = old + 1`).
    pub old_frame_id: u32,
    pub new_frame_id: u32,
    pub t_old_new: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

impl Filter {
    pub(crate) fn switch_frame_now(&mut self) -> FrameSwitch {
        let n = self.dim();
        let (_, _, yaw) = self.roll_pitch_yaw();
        let rz = yaw_rotation(yaw);
        let rz_t = rz.inverse().to_rotation_matrix().into_inner();
        let t_old_new = Isometry3::from_parts(self.p.into(), rz);

        // The factor's covariance, from the old covariance; roll and pitch are exact by
        // construction and get the configured tiny variance instead of zero.
        let j_factor = switch_factor_jacobian(&self.q);
        let factor = j_factor * self.pose_block(IP, ITH) * j_factor.transpose();
        let mut factor = (factor + factor.transpose()) * 0.5;
        factor[(3, 3)] = self.config.switch_roll_pitch_variance_rad2;
        factor[(4, 4)] = self.config.switch_roll_pitch_variance_rad2;

        // The state.
        let jac = self.switch_jacobian();
        for c in &mut self.clones {
            c.p = rz_t * (c.p - self.p);
            c.q = rz.inverse() * c.q;
        }
        self.p = Vector3::zeros();
        self.v = rz_t * self.v;
        self.q = rz.inverse() * self.q;
        self.q.renormalize();

        let old = self.cov.view((0, 0), (n, n)).into_owned();
        let new = &jac * old * jac.transpose();
        self.cov.view_mut((0, 0), (n, n)).copy_from(&new);
        self.symmetrize();
        self.check_covariance(true);

        let old_frame_id = self.frame_id;
        self.frame_id = self.frame_id.wrapping_add(1);
        self.health.frame_switches += 1;
        FrameSwitch {
            stamp_ns: self.stamp_ns,
            old_frame_id,
            new_frame_id: self.frame_id,
            t_old_new,
            covariance: factor,
        }
    }

    /// Jacobian of the switched error state (core and clones) with respect to the current one, at
    /// the current state (see the module docs).
    pub(crate) fn switch_jacobian(&self) -> DMatrix<f64> {
        let n = self.dim();
        let (_, _, yaw) = self.roll_pitch_yaw();
        let rz_t = yaw_rotation(yaw).inverse().to_rotation_matrix().into_inner();
        let j_psi: RowVector3<f64> = yaw_jacobian(&self.q);
        let ez = Vector3::z();
        let v_new = rz_t * self.v;
        let mut jac = DMatrix::<f64>::zeros(n, n);
        let put = |jac: &mut DMatrix<f64>, r: usize, c: usize, b: &Matrix3<f64>| {
            jac.view_mut((r, c), (3, 3)).copy_from(b);
        };
        put(&mut jac, IV, IV, &rz_t);
        put(&mut jac, IV, ITH, &(v_new.cross(&ez) * j_psi));
        put(&mut jac, ITH, ITH, &(rz_t - ez * j_psi));
        put(&mut jac, IBA, IBA, &Matrix3::identity());
        put(&mut jac, IBG, IBG, &Matrix3::identity());
        for (i, c) in self.clones.iter().enumerate() {
            let base = NX + 6 * i;
            let p_new = rz_t * (c.p - self.p);
            put(&mut jac, base, base, &rz_t);
            put(&mut jac, base, IP, &(-rz_t));
            put(&mut jac, base, ITH, &(p_new.cross(&ez) * j_psi));
            put(&mut jac, base + 3, base + 3, &rz_t);
            put(&mut jac, base + 3, ITH, &(-ez * j_psi));
        }
        jac
    }
}

/// Jacobian of the new frame `t_old_new = (p, Rz(ψ))` in `[δt; δθ]` (rotation right-multiplied)
/// with respect to `[δp, δθ]` of the state: `δt = δp`, `δθ = (0, 0, J_ψ·δθ)`.
pub(crate) fn switch_factor_jacobian(q: &UnitQuaternion<f64>) -> Matrix6<f64> {
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&Matrix3::identity());
    j.fixed_view_mut::<1, 3>(5, 3).copy_from(&yaw_jacobian(q));
    j
}
