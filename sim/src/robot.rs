//! Robot models: what each robot carries (camera, head, markers) and what others see of it
//! (owned by the world helper).
//!
//! Every face is a [`Quad`] listed like a tag: in the face's own frame (x to its right, y up, z
//! out of its front) the corners are `(−w, +h), (+w, +h), (+w, −h), (−w, −h)`, i.e. top-left,
//! top-right, bottom-right, bottom-left seen from the front.

use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::camera::{PanTiltHead, StereoCamera, r_flu_optical};
use crate::markers::{TAG_BLACK_CELLS, TAG_CELLS, tag36h11_code};
use crate::render::{Quad, QuadSurface};

/// Height of the rover's body origin (chassis centre) above the ground under its wheels.
pub const ROVER_CHASSIS_HEIGHT_M: f64 = 0.35;
/// Distance between the front and rear wheel axles.
pub const ROVER_WHEELBASE_M: f64 = 0.8;
/// Distance between the left and right wheels' contact lines.
pub const ROVER_TRACK_M: f64 = 0.72;
/// Half length and half width of the rover's footprint, wheels included: what must stay clear of
/// obstacles.
pub const ROVER_HALF_LENGTH_M: f64 = 0.55;
pub const ROVER_HALF_WIDTH_M: f64 = 0.42;
/// Edge of a marker's black square (the AprilTag size), and the mast height of the markers'
/// centres above the body origin.
pub const MARKER_SIZE_M: f64 = 0.16;
pub const MARKER_HEIGHT_M: f64 = 0.80;
/// Markers lean back so that their faces point this much above the horizon: both rovers (cameras
/// about 0.25 m above the markers) and flyers look at them well inside the detector's range of
/// viewing angles.
pub const MARKER_TILT_RAD: f64 = 25.0 * std::f64::consts::PI / 180.0;
/// Horizontal distance of each marker's centre from the mast axis.
const MARKER_RADIUS_M: f64 = 0.11;
/// Half edge of the white plate each tag is printed on (a white margin beyond the tag's own
/// quiet zone), and how far the plate sits behind the tag so the two never z-fight.
const PLATE_HALF_M: f64 = 0.13;
const PLATE_BEHIND_M: f64 = 0.003;
/// Height of a flyer's body centre above the ground when it stands on its legs.
pub const FLYER_REST_HEIGHT_M: f64 = 0.15;
/// Downward tilt of the flyer's fixed stereo pair.
pub const FLYER_CAMERA_TILT_RAD: f64 = std::f64::consts::FRAC_PI_4;

const CHASSIS_ALBEDO: f32 = 0.55;
const WHEEL_ALBEDO: f32 = 0.12;
const MAST_ALBEDO: f32 = 0.45;
const HEAD_ALBEDO: f32 = 0.3;
const PLATE_ALBEDO: f32 = 0.85;
const FLYER_BODY_ALBEDO: f32 = 0.2;
const FLYER_ARM_ALBEDO: f32 = 0.35;
const ROTOR_ALBEDO: f32 = 0.08;

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

impl Marker {
    /// Half the edge of the whole 10 × 10-cell tag (white border included).
    pub fn half_extent_m(&self) -> f64 {
        0.5 * self.size_m * TAG_CELLS as f64 / TAG_BLACK_CELLS as f64
    }

    /// Centre of cell `(col, row)` (row 0 at the tag's top) in the marker frame.
    pub fn cell_centre_marker_m(&self, col: usize, row: usize) -> Point3<f64> {
        let s = self.half_extent_m();
        let cell = 2.0 * s / TAG_CELLS as f64;
        Point3::new(-s + (col as f64 + 0.5) * cell, s - (row as f64 + 0.5) * cell, 0.0)
    }
}

/// An axis-aligned box in the body frame.
#[derive(Debug, Clone, Copy, PartialEq)]
struct BodyBox {
    centre: [f64; 3],
    half: [f64; 3],
    albedo: f32,
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
    ///
    /// The three markers sit around the mast at azimuths 0°, 120° and 240° from the body's x
    /// axis, facing outward and tilted up by [`MARKER_TILT_RAD`]. Indices beyond the kept tag36h11
    /// codes (robot 32 and up) get no markers.
    pub fn rover(index: u32, camera: StereoCamera) -> Self {
        let head = PanTiltHead::lru();
        let mast = head.pan_axis_body_m;
        let markers = (0..3u32)
            .filter_map(|k| {
                let tag_id = 3 * index + k;
                let code = tag36h11_code(tag_id)?;
                let azimuth = f64::from(k) * 2.0 * std::f64::consts::PI / 3.0;
                let (sa, ca) = azimuth.sin_cos();
                let (st, ct) = MARKER_TILT_RAD.sin_cos();
                let z = Vector3::new(ct * ca, ct * sa, st);
                let y = Vector3::new(-st * ca, -st * sa, ct);
                let x = y.cross(&z);
                let centre =
                    Vector3::new(mast.x + MARKER_RADIUS_M * ca, mast.y + MARKER_RADIUS_M * sa, MARKER_HEIGHT_M);
                Some(Marker { tag_id, code, size_m: MARKER_SIZE_M, t_body_marker: pose_from_axes(&centre, &x, &y, &z) })
            })
            .collect();
        RobotModel {
            kind: RobotKind::Rover,
            camera,
            head: Some(head),
            t_body_cam_fixed: Isometry3::identity(),
            markers,
        }
    }

    /// An Ardea-like flyer with a downward-tilted fixed stereo pair: the pair's centre 15 cm ahead
    /// of and 5 cm below the body origin, looking forward and [`FLYER_CAMERA_TILT_RAD`] down. It
    /// carries no markers (in the thesis, Ardea detects the rovers' markers but carries none).
    pub fn flyer(camera: StereoCamera) -> Self {
        let r_body_cam = Rotation3::from_axis_angle(&Vector3::y_axis(), FLYER_CAMERA_TILT_RAD) * r_flu_optical();
        let t = Vector3::new(0.15, 0.5 * camera.baseline_m, -0.05);
        RobotModel {
            kind: RobotKind::Flyer,
            camera,
            head: None,
            t_body_cam_fixed: Isometry3::from_parts(
                Translation3::from(t),
                UnitQuaternion::from_rotation_matrix(&r_body_cam),
            ),
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
    ///
    /// The head is drawn as a fixed box around the pan-tilt axes (its pan and tilt are not
    /// modelled in what others see).
    pub fn append_quads(&self, t_world_body: &Isometry3<f64>, out: &mut Vec<Quad>) {
        match self.kind {
            RobotKind::Rover => {
                for b in rover_boxes(self.head.as_ref()) {
                    push_box(t_world_body, &b, out);
                }
                for marker in &self.markers {
                    push_marker(t_world_body, marker, out);
                }
            }
            RobotKind::Flyer => {
                for b in FLYER_BOXES {
                    push_box(t_world_body, &b, out);
                }
                for k in 0..6 {
                    push_rotor(t_world_body, f64::from(k) * std::f64::consts::FRAC_PI_3, out);
                }
            }
        }
    }
}

/// Chassis, four wheels, mast and head of a rover.
fn rover_boxes(head: Option<&PanTiltHead>) -> [BodyBox; 7] {
    let axes = head.map_or(Vector3::new(0.30, 0.0, 1.05), |h| h.pan_axis_body_m);
    let wheel_z = -ROVER_CHASSIS_HEIGHT_M + 0.15;
    let wheel = |x: f64, y: f64| BodyBox { centre: [x, y, wheel_z], half: [0.15, 0.06, 0.15], albedo: WHEEL_ALBEDO };
    let (hx, hy) = (0.5 * ROVER_WHEELBASE_M, 0.5 * ROVER_TRACK_M);
    let mast_bottom = 0.15;
    let mast_top = axes.z - 0.05;
    [
        BodyBox { centre: [0.0, 0.0, 0.0], half: [0.5, 0.3, 0.15], albedo: CHASSIS_ALBEDO },
        wheel(hx, hy),
        wheel(hx, -hy),
        wheel(-hx, hy),
        wheel(-hx, -hy),
        BodyBox {
            centre: [axes.x, axes.y, 0.5 * (mast_bottom + mast_top)],
            half: [0.03, 0.03, 0.5 * (mast_top - mast_bottom)],
            albedo: MAST_ALBEDO,
        },
        BodyBox { centre: [axes.x, axes.y, axes.z], half: [0.06, 0.14, 0.05], albedo: HEAD_ALBEDO },
    ]
}

/// Body, battery and the six arms of a hexacopter (about 0.8 m across the rotors).
const FLYER_BOXES: [BodyBox; 3] = [
    BodyBox { centre: [0.0, 0.0, 0.0], half: [0.14, 0.14, 0.06], albedo: FLYER_BODY_ALBEDO },
    BodyBox { centre: [0.0, 0.0, -0.09], half: [0.08, 0.05, 0.03], albedo: FLYER_ARM_ALBEDO },
    BodyBox { centre: [0.0, 0.0, -0.13], half: [0.12, 0.12, 0.01], albedo: FLYER_ARM_ALBEDO },
];

const FLYER_ARM_LENGTH_M: f64 = 0.32;
const ROTOR_HALF_M: f64 = 0.1;

/// One arm and its rotor disc (a square) at azimuth `azimuth_rad`.
fn push_rotor(t_world_body: &Isometry3<f64>, azimuth_rad: f64, out: &mut Vec<Quad>) {
    let (s, c) = azimuth_rad.sin_cos();
    let radial = Vector3::new(c, s, 0.0);
    let tangent = Vector3::new(-s, c, 0.0);
    let arm_centre = radial * (0.5 * FLYER_ARM_LENGTH_M) + Vector3::new(0.0, 0.0, 0.03);
    // The arm's top face (seen from above) and bottom face (seen from below).
    push_face(t_world_body, &arm_centre, &radial, &tangent, 0.5 * FLYER_ARM_LENGTH_M, 0.015, FLYER_ARM_ALBEDO, out);
    push_face(t_world_body, &arm_centre, &tangent, &radial, 0.015, 0.5 * FLYER_ARM_LENGTH_M, FLYER_ARM_ALBEDO, out);
    let rotor_centre = radial * FLYER_ARM_LENGTH_M + Vector3::new(0.0, 0.0, 0.05);
    push_face(t_world_body, &rotor_centre, &radial, &tangent, ROTOR_HALF_M, ROTOR_HALF_M, ROTOR_ALBEDO, out);
    push_face(t_world_body, &rotor_centre, &tangent, &radial, ROTOR_HALF_M, ROTOR_HALF_M, ROTOR_ALBEDO, out);
}

/// The six faces of a box, each facing outward.
fn push_box(t_world_body: &Isometry3<f64>, b: &BodyBox, out: &mut Vec<Quad>) {
    let c = Vector3::from(b.centre);
    let [hx, hy, hz] = b.half;
    let (ex, ey, ez) = (Vector3::x(), Vector3::y(), Vector3::z());
    // (outward normal, face's right, face's up, half along right, half along up)
    let faces = [
        (ex, ey, ez, hy, hz),
        (-ex, -ey, ez, hy, hz),
        (ey, -ex, ez, hx, hz),
        (-ey, ex, ez, hx, hz),
        (ez, -ey, ex, hy, hx),
        (-ez, ey, ex, hy, hx),
    ];
    for (normal, right, up, half_right, half_up) in faces {
        let centre = c + normal.component_mul(&Vector3::new(hx, hy, hz));
        push_face(t_world_body, &centre, &right, &up, half_right, half_up, b.albedo, out);
    }
}

/// A uniform face centred at `centre_body` spanned by unit `right` and `up` (its front is
/// `right × up`).
#[allow(clippy::too_many_arguments)]
fn push_face(
    t_world_body: &Isometry3<f64>,
    centre_body: &Vector3<f64>,
    right: &Vector3<f64>,
    up: &Vector3<f64>,
    half_right: f64,
    half_up: f64,
    albedo: f32,
    out: &mut Vec<Quad>,
) {
    let corner =
        |a: f64, b: f64| t_world_body * Point3::from(centre_body + right * (a * half_right) + up * (b * half_up));
    out.push(Quad {
        corners_world_m: [corner(-1.0, 1.0), corner(1.0, 1.0), corner(1.0, -1.0), corner(-1.0, -1.0)],
        surface: QuadSurface::Uniform { albedo },
    });
}

/// A marker: its white plate, then the tag itself.
fn push_marker(t_world_body: &Isometry3<f64>, marker: &Marker, out: &mut Vec<Quad>) {
    let t_world_marker = t_world_body * marker.t_body_marker;
    let corner = |x: f64, y: f64, z: f64| t_world_marker * Point3::new(x, y, z);
    let p = PLATE_HALF_M;
    let b = -PLATE_BEHIND_M;
    out.push(Quad {
        corners_world_m: [corner(-p, p, b), corner(p, p, b), corner(p, -p, b), corner(-p, -p, b)],
        surface: QuadSurface::Uniform { albedo: PLATE_ALBEDO },
    });
    let s = marker.half_extent_m();
    out.push(Quad {
        corners_world_m: [corner(-s, s, 0.0), corner(s, s, 0.0), corner(s, -s, 0.0), corner(-s, -s, 0.0)],
        surface: QuadSurface::Tag { code: marker.code },
    });
}

/// The pose whose rotation has columns `x`, `y`, `z` (orthonormal, right-handed), at `origin`.
fn pose_from_axes(origin: &Vector3<f64>, x: &Vector3<f64>, y: &Vector3<f64>, z: &Vector3<f64>) -> Isometry3<f64> {
    let r = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_columns(&[*x, *y, *z]));
    Isometry3::from_parts(Translation3::from(*origin), UnitQuaternion::from_rotation_matrix(&r))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rover_markers_face_outward_tilted_up_with_their_ids() {
        let model = RobotModel::rover(2, StereoCamera::narrow());
        let ids: Vec<u32> = model.markers.iter().map(|m| m.tag_id).collect();
        assert_eq!(ids, vec![6, 7, 8]);
        let mast = PanTiltHead::lru().pan_axis_body_m;
        for m in &model.markers {
            let normal = m.t_body_marker.rotation * Vector3::z();
            let up = m.t_body_marker.rotation * Vector3::y();
            let centre = m.t_body_marker.translation.vector;
            let outward = Vector3::new(centre.x - mast.x, centre.y - mast.y, 0.0).normalize();
            assert!((normal.z - MARKER_TILT_RAD.sin()).abs() < 1e-12);
            assert!(normal.dot(&outward) > 0.9 * MARKER_TILT_RAD.cos());
            assert!(up.z > 0.9);
            assert!((centre.z - MARKER_HEIGHT_M).abs() < 1e-12);
            assert_eq!(Some(m.code), tag36h11_code(m.tag_id));
        }
    }

    #[test]
    fn tag_quad_corners_follow_the_contract() {
        let model = RobotModel::rover(0, StereoCamera::narrow());
        let pose = Isometry3::new(Vector3::new(3.0, -2.0, 1.0), Vector3::new(0.1, -0.05, 0.7));
        let mut quads = Vec::new();
        model.append_quads(&pose, &mut quads);
        let tags: Vec<&Quad> = quads.iter().filter(|q| matches!(q.surface, QuadSurface::Tag { .. })).collect();
        assert_eq!(tags.len(), 3);
        let m = model.markers[0];
        let s = 0.5 * m.size_m * 10.0 / 8.0;
        let t_world_marker = pose * m.t_body_marker;
        let expected = [(-s, s), (s, s), (s, -s), (-s, -s)].map(|(x, y)| t_world_marker * Point3::new(x, y, 0.0));
        for (c, e) in tags[0].corners_world_m.iter().zip(&expected) {
            assert!((c - e).norm() < 1e-12);
        }
        assert_eq!(tags[0].surface, QuadSurface::Tag { code: m.code });
        // Every uniform face of the rover's boxes comes with its opposite: 7 boxes × 6 faces, and
        // a plate per marker.
        assert_eq!(quads.len(), 7 * 6 + 3 * 2);
    }

    #[test]
    fn box_faces_point_outward() {
        let model = RobotModel::rover(0, StereoCamera::narrow());
        let mut quads = Vec::new();
        model.append_quads(&Isometry3::identity(), &mut quads);
        // The chassis is the first box, centred at the body origin: the front of every face
        // (right × up, with right = c1 − c0 and up = c0 − c3) points away from it.
        for q in &quads[..6] {
            let [c0, c1, _, c3] = q.corners_world_m;
            let front = (c1 - c0).cross(&(c0 - c3));
            let centre = (c0.coords + q.corners_world_m[2].coords) * 0.5;
            assert!(front.dot(&centre) > 0.0);
        }
    }

    #[test]
    fn flyer_camera_looks_forward_and_down() {
        let model = RobotModel::flyer(StereoCamera::wide());
        let forward = model.t_body_cam(0.3, 0.2).rotation * Vector3::z();
        let expected = Vector3::new(FLYER_CAMERA_TILT_RAD.cos(), 0.0, -FLYER_CAMERA_TILT_RAD.sin());
        assert!((forward - expected).norm() < 1e-12);
        assert!(model.markers.is_empty());
        let mut quads = Vec::new();
        model.append_quads(&Isometry3::identity(), &mut quads);
        assert_eq!(quads.len(), 3 * 6 + 6 * 4);
    }
}
