//! Robot models: what each robot carries (camera, head, markers) and what others see of it
//! (owned by the world helper).

use nalgebra::Isometry3;

use crate::camera::{PanTiltHead, StereoCamera};
use crate::render::Quad;

/// Kind of robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RobotKind {
    /// An LRU-like ground rover on a pan-tilt head, with wheel odometry.
    Rover,
    /// An Ardea-like flyer: free 6D motion, fixed cameras, no wheel odometry.
    Flyer,
}

/// One AprilTag on a robot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Marker {
    pub tag_id: u32,
    pub code: u64,
    /// Edge of the tag's black square.
    pub size_m: f64,
    /// Pose of the marker frame (see the crate docs) in the body frame.
    pub t_body_marker: Isometry3<f64>,
}

/// A robot's hardware as the simulator models it.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotModel {
    pub kind: RobotKind,
    pub camera: StereoCamera,
    /// The rover's head; `None` for fixed cameras.
    pub head: Option<PanTiltHead>,
    /// Left camera in the body frame for fixed cameras (ignored with a head).
    pub t_body_cam_fixed: Isometry3<f64>,
    pub markers: Vec<Marker>,
}

impl RobotModel {
    /// An LRU-like rover with robot index `index` (tags `3·index ..= 3·index + 2`).
    pub fn rover(index: u32, camera: StereoCamera) -> Self {
        let _ = index;
        RobotModel {
            kind: RobotKind::Rover,
            camera,
            head: Some(PanTiltHead::lru()),
            t_body_cam_fixed: Isometry3::identity(),
            markers: Vec::new(),
        }
    }

    /// An Ardea-like flyer with a downward-tilted fixed stereo pair.
    pub fn flyer(camera: StereoCamera) -> Self {
        RobotModel {
            kind: RobotKind::Flyer,
            camera,
            head: None,
            t_body_cam_fixed: Isometry3::identity(),
            markers: Vec::new(),
        }
    }

    /// Left camera in the body frame at the given head angles.
    pub fn t_body_cam(&self, pan_rad: f64, tilt_rad: f64) -> Isometry3<f64> {
        match &self.head {
            Some(head) => head.t_body_cam(pan_rad, tilt_rad),
            None => self.t_body_cam_fixed,
        }
    }

    /// Appends the faces others' cameras see of this robot at `t_world_body`.
    pub fn append_quads(&self, t_world_body: &Isometry3<f64>, out: &mut Vec<Quad>) {
        let _ = (t_world_body, out);
    }
}
