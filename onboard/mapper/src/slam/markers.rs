//! Robot detections from AprilTags (thesis §6.2, eq. 4.7): which robot carries a tag, and a
//! detected tag's pose turned into the detection factor between the observer's and the observed
//! robot's bodies.
//!
//! The team shares one rover design: the robot with configuration id `j` carries tags
//! `tags_per_robot · j + k`, tag `k` at `t_body_marker[k]` on its body (the simulator's rovers:
//! three 16 cm tags around the mast, ids `3j … 3j + 2`).
//!
//! **Covariance (trap T21).** The marker pose comes with a covariance in the camera's axes,
//! `[δt; δθ]` with `t_true = t̂ + δt` and `R_true = Exp(δθ)·R̂` (`vision::marker_pose`). The
//! factor `T_r0_r1 = T_r0_cam · T_cam_m · T_m_r1` perturbs on the right in the graph,
//! `T_r0_r1·Exp([ρ; φ])` ([`super::covariance`]). To first order
//! `φ = R_c1ᵀ·δθ` and `ρ = R_c1ᵀ·(δt − [p]×·δθ)`, with `R_c1` the observed body's rotation in the
//! camera and `p = R_cm·t_m1` the lever from the tag to the observed body's origin in the
//! camera's axes: a rotation error of the tag swings the body around it.

use nalgebra::{Isometry3, Matrix3, Matrix6};

use super::covariance::symmetric;
use super::ids::RobotId;
use super::measurements::RobotDetection;

/// Where the tags sit on every robot of the team.
#[derive(Debug, Clone, PartialEq)]
pub struct TeamMarkers {
    pub tags_per_robot: u32,
    /// Pose of tag `k` in the carrying robot's body frame.
    pub t_body_marker: Vec<Isometry3<f64>>,
}

/// A tag resolved to the robot that carries it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TagOwner {
    /// The robot's configuration id (not its protocol id).
    pub robot: u32,
    pub t_body_marker: Isometry3<f64>,
}

impl TeamMarkers {
    /// The robot and mounting of `tag_id`; `None` for a tag no robot of this design carries.
    pub fn owner(&self, tag_id: u32) -> Option<TagOwner> {
        if self.tags_per_robot == 0 {
            return None;
        }
        let k = (tag_id % self.tags_per_robot) as usize;
        let t_body_marker = *self.t_body_marker.get(k)?;
        Some(TagOwner { robot: tag_id / self.tags_per_robot, t_body_marker })
    }
}

/// One detected tag as the vision process reports it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MarkerObservation {
    pub stamp_ns: u64,
    pub tag_id: u32,
    /// The observer's left camera in its body frame at the capture.
    pub t_body_cam: Isometry3<f64>,
    pub t_cam_marker: Isometry3<f64>,
    /// `[δt; δθ]` in the camera's axes (see the module docs).
    pub covariance_cam: Matrix6<f64>,
}

/// The Jacobian from the camera-frame marker error `[δt; δθ]` to the graph's right perturbation
/// of `T_r0_r1` (module docs).
pub fn camera_to_detection_jacobian(t_cam_marker: &Isometry3<f64>, t_marker_body: &Isometry3<f64>) -> Matrix6<f64> {
    let t_cam_body = t_cam_marker * t_marker_body;
    let r_c1_t: Matrix3<f64> = t_cam_body.rotation.to_rotation_matrix().matrix().transpose();
    let lever = t_cam_marker.rotation * t_marker_body.translation.vector;
    let mut j = Matrix6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&r_c1_t);
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-r_c1_t * lever.cross_matrix()));
    j.fixed_view_mut::<3, 3>(3, 3).copy_from(&r_c1_t);
    j
}

/// Eq. 4.7 for a tag of robot `observed`'s, seen by `observer`: `T_r0_r1 = T_r0_cam · T_cam_m ·
/// T_r1_m⁻¹` with its covariance in the graph's convention.
pub fn robot_detection(
    observer: RobotId,
    observed: RobotId,
    observation: &MarkerObservation,
    t_body_marker: &Isometry3<f64>,
) -> RobotDetection {
    let t_marker_body = t_body_marker.inverse();
    let j = camera_to_detection_jacobian(&observation.t_cam_marker, &t_marker_body);
    RobotDetection {
        observer,
        observed,
        tag_id: observation.tag_id,
        stamp_ns: observation.stamp_ns,
        t_observer_observed: observation.t_body_cam * observation.t_cam_marker * t_marker_body,
        covariance: symmetric(&(j * observation.covariance_cam * j.transpose())),
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use crate::slam::covariance::numdiff::{self, STEP, Tolerance};
    use nalgebra::{Const, Translation3, UnitQuaternion, Vector3, Vector6};

    fn pose(t: [f64; 3], axis: [f64; 3], angle: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(t[0], t[1], t[2]),
            UnitQuaternion::from_scaled_axis(Vector3::from(axis).normalize() * angle),
        )
    }

    #[test]
    fn tags_resolve_to_their_robot_and_mounting() {
        let mounts: Vec<_> =
            (0..3).map(|k| pose([0.1 * k as f64, 0.0, 0.8], [0.0, 0.0, 1.0], 2.1 * k as f64)).collect();
        let team = TeamMarkers { tags_per_robot: 3, t_body_marker: mounts.clone() };
        let owner = team.owner(7).unwrap();
        assert_eq!(owner.robot, 2);
        assert_eq!(owner.t_body_marker, mounts[1]);
        assert_eq!(team.owner(0).unwrap().robot, 0);
        let partial = TeamMarkers { tags_per_robot: 3, t_body_marker: mounts[..2].to_vec() };
        assert!(partial.owner(5).is_none(), "tag k = 2 has no mounting");
        assert!(TeamMarkers { tags_per_robot: 0, t_body_marker: mounts }.owner(1).is_none());
    }

    #[test]
    fn the_detection_is_eq_4_7() {
        let t_body_cam = pose([0.3, 0.05, 1.1], [0.2, 1.0, -0.3], 1.9);
        let t_cam_marker = pose([0.4, -0.2, 3.5], [0.1, 0.9, 0.2], 2.8);
        let t_body_marker = pose([0.11, 0.0, 0.8], [0.3, -0.4, 1.0], 1.2);
        let obs =
            MarkerObservation { stamp_ns: 5, tag_id: 4, t_body_cam, t_cam_marker, covariance_cam: Matrix6::identity() };
        let d = robot_detection(1, 2, &obs, &t_body_marker);
        // The observed robot's tag, seen through the detection, is where the camera saw it.
        let seen = t_body_cam * t_cam_marker;
        let via = d.t_observer_observed * t_body_marker;
        assert!((seen.translation.vector - via.translation.vector).norm() < 1e-12);
        assert!(seen.rotation.angle_to(&via.rotation) < 1e-12);
        assert_eq!((d.observer, d.observed, d.tag_id, d.stamp_ns), (1, 2, 4, 5));
    }

    /// The covariance is `J·Σ·Jᵀ` with `J` the derivative of the graph's error
    /// `Log(T̂⁻¹·T(δ))` (chart `[t; Log R]`) under the camera-frame perturbation, by central
    /// differences, over tags near and far, straight on and oblique, rotations up to near π.
    #[test]
    fn the_jacobian_matches_central_differences() {
        let mut worst = numdiff::Comparison::none();
        for (i, angle) in [0.0, 1e-6, 0.5, 2.0, std::f64::consts::PI - 1e-3].into_iter().enumerate() {
            let s = i as f64;
            let t_cam_marker = pose([0.3 * s - 0.5, 0.2 - 0.1 * s, 0.5 + 1.5 * s], [s.sin(), 1.0, 0.3], angle);
            let t_body_marker = pose([0.11, -0.05 * s, 0.8], [0.4, 0.1 * s, 1.0], 0.7 + angle);
            let t_marker_body = t_body_marker.inverse();
            let nominal = t_cam_marker * t_marker_body;
            let numeric = numdiff::jacobian(Const::<6>, STEP, |d: &Vector6<f64>| {
                let perturbed_marker = Isometry3::from_parts(
                    Translation3::from(t_cam_marker.translation.vector + d.fixed_rows::<3>(0)),
                    numdiff::left_plus(&t_cam_marker.rotation, &d.fixed_rows::<3>(3).into_owned()),
                );
                let diff = nominal.inverse() * (perturbed_marker * t_marker_body);
                let log = numdiff::rotation_log(&diff.rotation);
                Vector6::new(diff.translation.x, diff.translation.y, diff.translation.z, log.x, log.y, log.z)
            });
            let analytic = camera_to_detection_jacobian(&t_cam_marker, &t_marker_body);
            // The lever (up to ~1 m) scales the rotation columns' entries.
            let comparison = numdiff::compare(&analytic, &numeric, Tolerance::central(STEP, 10.0));
            assert!(comparison.passes(), "angle {angle}: {comparison:?}");
            worst = worst.worse(comparison);
        }
        println!("markers: detection Jacobian vs central differences, worst |error| {:.1e}", worst.max_abs_error);
    }
}
