//! The 3D point view: the model's level-of-detail points under an orbit camera, drawn as one
//! mesh of small screen-space quads (one shape, however many points).

use egui::{Color32, Mesh, Pos2, Rect, Role, Sense, Shape, Ui, WidgetInfo, pos2};

use super::palette;
use crate::view::{MapPoints, TeamView};

/// Accessible name of the 3D canvas.
pub const POINTS_LABEL: &str = "3D point view";

/// More points than this are drawn with a stride: beyond it the quads overlap anyway and the
/// mesh upload dominates the frame.
pub const MAX_DRAWN_POINTS: usize = 150_000;

const FOV_Y_RAD: f32 = 1.0;
const NEAR_M: f32 = 0.05;

/// A camera circling `target_ref_m` at `distance_m`; yaw about z, pitch above the xy plane.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OrbitCamera {
    pub target_ref_m: [f32; 3],
    pub yaw_rad: f32,
    pub pitch_rad: f32,
    pub distance_m: f32,
}

impl Default for OrbitCamera {
    fn default() -> Self {
        Self { target_ref_m: [0.0; 3], yaw_rad: -1.2, pitch_rad: 0.6, distance_m: 50.0 }
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl OrbitCamera {
    pub fn eye_ref_m(&self) -> [f32; 3] {
        let (sp, cp) = self.pitch_rad.sin_cos();
        let (sy, cy) = self.yaw_rad.sin_cos();
        let d = self.distance_m;
        [self.target_ref_m[0] + d * cp * cy, self.target_ref_m[1] + d * cp * sy, self.target_ref_m[2] + d * sp]
    }

    /// Camera basis (right, up, forward) in the reference frame.
    fn basis(&self) -> ([f32; 3], [f32; 3], [f32; 3]) {
        let (sp, cp) = self.pitch_rad.sin_cos();
        let (sy, cy) = self.yaw_rad.sin_cos();
        let forward = [-cp * cy, -cp * sy, -sp];
        // forward × z, normalised: horizontal, so the horizon stays level.
        let right = [-sy, cy, 0.0];
        // right × forward
        let up = [
            right[1] * forward[2] - right[2] * forward[1],
            right[2] * forward[0] - right[0] * forward[2],
            right[0] * forward[1] - right[1] * forward[0],
        ];
        (right, up, forward)
    }

    /// Screen position and depth (m) of a point, `None` behind the near plane.
    pub fn project(&self, p_ref_m: [f32; 3], rect: Rect) -> Option<(Pos2, f32)> {
        self.projector(rect).project(p_ref_m)
    }

    /// The projection with its trigonometry done once, for many points.
    pub fn projector(&self, rect: Rect) -> Projector {
        let (right, up, forward) = self.basis();
        Projector {
            eye: self.eye_ref_m(),
            right,
            up,
            forward,
            focal_px: 0.5 * rect.height() / (0.5 * FOV_Y_RAD).tan(),
            centre: rect.center(),
        }
    }

    /// Looks at the middle of `points` from far enough to see them all.
    pub fn frame(&mut self, points: &MapPoints) {
        let mut lo = [f32::INFINITY; 3];
        let mut hi = [f32::NEG_INFINITY; 3];
        for p in points.points_ref_m.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
        }
        if lo[0] > hi[0] {
            return;
        }
        self.target_ref_m = [0.5 * (lo[0] + hi[0]), 0.5 * (lo[1] + hi[1]), 0.5 * (lo[2] + hi[2])];
        let extent = (hi[0] - lo[0]).max(hi[1] - lo[1]).max(hi[2] - lo[2]).max(1.0);
        self.distance_m = 0.8 * extent / (0.5 * FOV_Y_RAD).tan();
    }
}

/// An [`OrbitCamera`] ready to project.
#[derive(Debug, Clone, Copy)]
pub struct Projector {
    eye: [f32; 3],
    right: [f32; 3],
    up: [f32; 3],
    forward: [f32; 3],
    focal_px: f32,
    centre: Pos2,
}

impl Projector {
    pub fn project(&self, p_ref_m: [f32; 3]) -> Option<(Pos2, f32)> {
        let d = sub(p_ref_m, self.eye);
        let z = dot(d, self.forward);
        if z <= NEAR_M || !z.is_finite() {
            return None;
        }
        let k = self.focal_px / z;
        Some((pos2(self.centre.x + dot(d, self.right) * k, self.centre.y - dot(d, self.up) * k), z))
    }
}

/// The 3D view's state between frames.
#[derive(Debug, Default)]
pub struct PointsState {
    pub camera: OrbitCamera,
    /// Revision the camera was framed for and the height range computed from.
    framed_revision: Option<u64>,
    z_range_m: (f32, f32),
}

pub fn show(ui: &mut Ui, view: &TeamView, state: &mut PointsState) {
    let points = &view.points;
    ui.label(format!(
        "{} points (revision {}); drag to orbit, scroll to zoom, double-click to re-frame",
        points.points_ref_m.len(),
        points.revision
    ));
    let (response, painter) = ui.allocate_painter(ui.available_size(), Sense::click_and_drag());
    response.widget_info(|| WidgetInfo::labeled(Role::Canvas, true, POINTS_LABEL));
    let rect = response.rect;
    painter.rect_filled(rect, 0.0, Color32::from_gray(12));

    if state.framed_revision != Some(points.revision) || response.double_clicked() {
        if state.framed_revision.is_none() || response.double_clicked() {
            state.camera.frame(points);
        }
        state.z_range_m = palette::finite_range(points.points_ref_m.iter().map(|p| p[2])).unwrap_or((0.0, 1.0));
        state.framed_revision = Some(points.revision);
    }
    let cam = &mut state.camera;
    if response.dragged() {
        let d = response.drag_delta();
        cam.yaw_rad -= d.x * 0.01;
        cam.pitch_rad = (cam.pitch_rad + d.y * 0.01).clamp(-1.5, 1.5);
    }
    if response.hovered() {
        let (scroll_y, zoom) = ui.input(|i| (i.smooth_scroll_delta.y, i.zoom_delta()));
        cam.distance_m = (cam.distance_m / zoom * (-scroll_y * 0.002).exp()).clamp(0.5, 1e5);
    }
    painter.with_clip_rect(rect).add(Shape::mesh(point_mesh(points, cam, rect, state.z_range_m)));
}

/// One quad per (strided) point, coloured by height, obstacles red; points behind the camera
/// or off the screen are skipped.
pub fn point_mesh(points: &MapPoints, cam: &OrbitCamera, rect: Rect, z_range_m: (f32, f32)) -> Mesh {
    let n = points.points_ref_m.len();
    let stride = n.div_ceil(MAX_DRAWN_POINTS).max(1);
    let mut mesh = Mesh::default();
    mesh.reserve_vertices(4 * n.min(MAX_DRAWN_POINTS));
    mesh.reserve_triangles(2 * n.min(MAX_DRAWN_POINTS));
    let visible = rect.expand(4.0);
    let inv_span = 1.0 / (z_range_m.1 - z_range_m.0).max(1e-3);
    let projector = cam.projector(rect);
    for i in (0..n).step_by(stride) {
        let p = points.points_ref_m[i];
        let Some((s, depth)) = projector.project(p) else { continue };
        if !visible.contains(s) {
            continue;
        }
        let obstacle = points.obstacle.get(i).copied().unwrap_or(false);
        let colour = if obstacle { palette::OBSTACLE } else { palette::height_colour((p[2] - z_range_m.0) * inv_span) };
        // Near points a little larger, for a sense of depth.
        let half = (40.0 / depth).clamp(0.75, 2.5);
        mesh.add_colored_rect(Rect::from_center_size(s, egui::vec2(2.0 * half, 2.0 * half)), colour);
    }
    mesh
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    fn rect() -> Rect {
        Rect::from_min_size(Pos2::ZERO, egui::vec2(800.0, 600.0))
    }

    #[test]
    fn target_projects_to_the_centre_and_up_is_up() {
        let cam = OrbitCamera { target_ref_m: [5.0, -3.0, 1.0], yaw_rad: 0.7, pitch_rad: 0.4, distance_m: 20.0 };
        let (c, depth) = cam.project([5.0, -3.0, 1.0], rect()).unwrap();
        assert!((c - rect().center()).length() < 1e-3 && (depth - 20.0).abs() < 1e-4);
        let (above, _) = cam.project([5.0, -3.0, 3.0], rect()).unwrap();
        assert!(above.y < c.y && (above.x - c.x).abs() < 1e-3);
        // Behind the eye.
        let eye = cam.eye_ref_m();
        let behind = [2.0 * eye[0] - 5.0, 2.0 * eye[1] + 3.0, 2.0 * eye[2] - 1.0];
        assert!(cam.project(behind, rect()).is_none());
    }

    #[test]
    fn yaw_rotates_the_view_about_z() {
        // From +x looking along -x with z up, +y is on the right (a right-handed frame).
        let cam = OrbitCamera { target_ref_m: [0.0; 3], yaw_rad: 0.0, pitch_rad: 0.0, distance_m: 10.0 };
        let (p, _) = cam.project([0.0, 1.0, 0.0], rect()).unwrap();
        assert!(p.x > rect().center().x + 10.0);
        // A quarter turn later (camera on +y looking along -y), +x is on the left.
        let cam = OrbitCamera { yaw_rad: std::f32::consts::FRAC_PI_2, ..cam };
        let (p, _) = cam.project([1.0, 0.0, 0.0], rect()).unwrap();
        assert!(p.x < rect().center().x - 10.0);
    }

    #[test]
    fn mesh_has_one_quad_per_visible_point_and_is_capped() {
        let cam = OrbitCamera { target_ref_m: [0.0; 3], yaw_rad: 0.3, pitch_rad: 0.8, distance_m: 30.0 };
        let points = MapPoints {
            points_ref_m: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1e6, 0.0, 0.0]],
            obstacle: vec![false, true, false],
            revision: 1,
        };
        let mesh = point_mesh(&points, &cam, rect(), (0.0, 1.0));
        assert_eq!(mesh.vertices.len(), 8);
        assert!(mesh.vertices.iter().any(|v| v.color == palette::OBSTACLE));

        let many =
            MapPoints { points_ref_m: vec![[0.0, 0.0, 0.0]; 3 * MAX_DRAWN_POINTS], obstacle: vec![], revision: 1 };
        let mesh = point_mesh(&many, &cam, rect(), (0.0, 1.0));
        assert_eq!(mesh.vertices.len(), 4 * MAX_DRAWN_POINTS);
    }
}
