//! The filter node's mode without an IMU (a dataset such as KITTI or EuRoC MH_01's excerpt):
//! the local frame's pose is the stereo odometry's own chained pose, re-expressed in the current
//! local frame, with a covariance compounded from the keyframe deltas.
//!
//! Covariance (filter convention `[δt local; δθ body]`, the odometry's deltas in the same
//! convention relative to their keyframe): for `T = T_kf · D` with `D = (R_D, d)`,
//! `δt = δt_kf − R_kf [d]× δθ_kf + R_kf δd` and `δθ = R_Dᵀ δθ_kf + δθ_D`, the keyframe's and
//! the delta's errors taken as independent (first order).
//!
//! A frame switch puts the new frame at the latest pose, in full 6-DoF (there is no gravity to
//! keep level against); its transform carries the pose's covariance. The keyframes still in use
//! are re-expressed in the new frame and taken as exact there: the error this leaves out is at
//! most the covariance of one keyframe delta.

use std::collections::VecDeque;

use filter::FrameSwitch;
use nalgebra::{Isometry3, Matrix3, Matrix6};

/// Keyframes kept for compounding (the odometry keeps five; a few more cover re-acquisition).
const KEYFRAMES_KEPT: usize = 16;
/// Variance added to a switch's covariance so that a switch right at the frame's origin still
/// gives the graph a full-rank factor.
const SWITCH_VARIANCE_FLOOR: f64 = 1e-12;

/// One odometry result in the chain's terms.
#[derive(Debug, Clone, Copy)]
pub struct OdometryInput {
    pub capture_ns: u64,
    pub t_odom_body: Isometry3<f64>,
    /// `(keyframe stamp, t_keyframe_current_body, covariance)` when the frame had a delta.
    pub delta: Option<(u64, Isometry3<f64>, Matrix6<f64>)>,
    pub new_keyframe: bool,
}

/// The chain's estimate after an input.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChainState {
    pub stamp_ns: u64,
    pub frame_id: u32,
    pub t_local_body: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

/// See the module documentation.
#[derive(Debug, Clone, Default)]
pub struct OdometryChain {
    frame_id: u32,
    /// The current local frame's origin in the odometry frame.
    t_odom_local: Isometry3<f64>,
    latest: Option<ChainState>,
    /// `(stamp, t_local_keyframe, covariance)` of recent keyframes.
    keyframes: VecDeque<(u64, Isometry3<f64>, Matrix6<f64>)>,
    /// The odometry's pose at the latest input (a switch starts the new frame there).
    t_odom_latest: Isometry3<f64>,
}

fn skew(v: &nalgebra::Vector3<f64>) -> Matrix3<f64> {
    v.cross_matrix()
}

impl OdometryChain {
    pub fn new() -> OdometryChain {
        OdometryChain::default()
    }

    pub fn latest(&self) -> Option<&ChainState> {
        self.latest.as_ref()
    }

    pub fn frame_id(&self) -> u32 {
        self.frame_id
    }

    /// Takes one odometry result; returns the new state.
    pub fn push(&mut self, input: &OdometryInput) -> ChainState {
        let t_local_body = self.t_odom_local.inverse() * input.t_odom_body;
        let keyframe = input.delta.and_then(|(keyframe_ns, d, sigma_d)| {
            self.keyframes.iter().rev().find(|k| k.0 == keyframe_ns).map(|k| (k.1, k.2, d, sigma_d))
        });
        let covariance = match keyframe {
            Some((t_local_kf, sigma_kf, d, sigma_d)) => {
                let r_kf = t_local_kf.rotation.to_rotation_matrix().into_inner();
                let r_d = d.rotation.to_rotation_matrix().into_inner();
                let mut j_kf = Matrix6::identity();
                j_kf.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-r_kf * skew(&d.translation.vector)));
                j_kf.fixed_view_mut::<3, 3>(3, 3).copy_from(&r_d.transpose());
                let mut j_d = Matrix6::identity();
                j_d.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_kf);
                let c = j_kf * sigma_kf * j_kf.transpose() + j_d * sigma_d * j_d.transpose();
                0.5 * (c + c.transpose())
            }
            // The first frame, a reset or a keyframe no longer held: the uncertainty so far.
            None => self.latest.map_or_else(Matrix6::zeros, |s| s.covariance),
        };
        if input.new_keyframe {
            if self.keyframes.len() == KEYFRAMES_KEPT {
                self.keyframes.pop_front();
            }
            self.keyframes.push_back((input.capture_ns, t_local_body, covariance));
        }
        let state = ChainState { stamp_ns: input.capture_ns, frame_id: self.frame_id, t_local_body, covariance };
        self.latest = Some(state);
        self.t_odom_latest = input.t_odom_body;
        state
    }

    /// Starts a new local frame at the latest pose; `None` before the first input.
    pub fn switch_frame(&mut self) -> Option<FrameSwitch> {
        let latest = self.latest?;
        let t_old_new = latest.t_local_body;
        let switch = FrameSwitch {
            stamp_ns: latest.stamp_ns,
            old_frame_id: self.frame_id,
            new_frame_id: self.frame_id + 1,
            t_old_new,
            covariance: latest.covariance + Matrix6::identity() * SWITCH_VARIANCE_FLOOR,
        };
        self.frame_id += 1;
        self.t_odom_local = self.t_odom_latest;
        let t_new_old = t_old_new.inverse();
        for keyframe in &mut self.keyframes {
            keyframe.1 = t_new_old * keyframe.1;
            keyframe.2 = Matrix6::zeros();
        }
        self.latest = Some(ChainState {
            stamp_ns: latest.stamp_ns,
            frame_id: self.frame_id,
            t_local_body: Isometry3::identity(),
            covariance: Matrix6::zeros(),
        });
        Some(switch)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    fn pose(x: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(Vector3::new(x, 0.1 * x, 0.0).into(), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw))
    }

    #[test]
    fn the_chain_is_the_odometry_pose_and_its_uncertainty_grows() {
        let mut chain = OdometryChain::new();
        let sigma = Matrix6::identity() * 1e-4;
        let s0 =
            chain.push(&OdometryInput { capture_ns: 0, t_odom_body: pose(0.0, 0.0), delta: None, new_keyframe: true });
        assert_eq!(s0.covariance, Matrix6::zeros());
        let mut previous_trace = 0.0;
        for k in 1..6u64 {
            let t_odom_body = pose(k as f64, 0.1 * k as f64);
            let keyframe = pose((k - 1) as f64, 0.1 * (k - 1) as f64);
            let input = OdometryInput {
                capture_ns: k,
                t_odom_body,
                delta: Some((k - 1, keyframe.inverse() * t_odom_body, sigma)),
                new_keyframe: true,
            };
            let s = chain.push(&input);
            assert!((s.t_local_body.translation.vector - t_odom_body.translation.vector).norm() < 1e-12);
            assert!(s.covariance.trace() > previous_trace);
            previous_trace = s.covariance.trace();
        }
    }

    #[test]
    fn a_switch_starts_the_new_frame_at_the_latest_pose() {
        let mut chain = OdometryChain::new();
        chain.push(&OdometryInput { capture_ns: 0, t_odom_body: pose(0.0, 0.0), delta: None, new_keyframe: true });
        let p1 = pose(2.0, 0.3);
        let sigma = Matrix6::identity() * 1e-4;
        chain.push(&OdometryInput { capture_ns: 1, t_odom_body: p1, delta: Some((0, p1, sigma)), new_keyframe: false });
        let switch = chain.switch_frame().unwrap();
        assert_eq!((switch.old_frame_id, switch.new_frame_id), (0, 1));
        assert!((switch.t_old_new.translation.vector - p1.translation.vector).norm() < 1e-12);
        assert!(switch.covariance.trace() > 0.0);
        let p2 = pose(3.0, 0.5);
        let s = chain.push(&OdometryInput {
            capture_ns: 2,
            t_odom_body: p2,
            delta: Some((0, p2, sigma)),
            new_keyframe: false,
        });
        assert_eq!(s.frame_id, 1);
        // Chained through the switch, the new frame's pose is the odometry's again.
        let chained = switch.t_old_new * s.t_local_body;
        assert!((chained.translation.vector - p2.translation.vector).norm() < 1e-12);
        assert!(chained.rotation.angle_to(&p2.rotation) < 1e-12);
    }
}
