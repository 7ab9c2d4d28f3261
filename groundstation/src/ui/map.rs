//! The top-down map: the height grid as one texture, trajectories, poses with their 2σ
//! ellipses, submap outlines, loop-closure edges, the robots' live hazard cells (a layer the
//! toolbar's "hazards" box switches); pan, zoom, follow, and the waypoint click.

use egui::{
    Align2, Color32, ColorImage, FontId, Mesh, Painter, Pos2, Rect, Role, Sense, Shape, Stroke, TextureHandle,
    TextureOptions, Ui, Vec2, WidgetInfo, pos2, vec2,
};
use nalgebra::{Matrix2, Point3, SymmetricEigen, Vector3};

use super::UiState;
use super::palette::{self, robot_colour};
use super::transform::{MapTransform, scale_bar_m};
use crate::view::{EdgeKind, HazardView, HeightGrid, RobotView, TeamView, UiAction};

/// Accessible name of the map canvas (tests find it by this label).
pub const MAP_LABEL: &str = "Map view";

/// Trajectory points closer than this on the screen are merged: a 100k-pose track drawn at
/// fit-all zoom collapses to a few hundred vertices.
const MIN_STEP_PX: f32 = 1.5;
/// Fitting never zooms in further than this many metres across: a robot that has barely moved
/// is not blown up to fill the screen.
const MIN_FIT_SPAN_M: f64 = 10.0;
/// Hazard cells are drawn at least this wide, so a 0.1 m cell stays visible zoomed out.
pub const MIN_HAZARD_CELL_PX: f32 = 3.0;
/// Hazard cells received longer ago than this are drawn faded ([`palette::HAZARD_OLD`]): the
/// robots send them every 2 s, so three missed pictures.
pub const HAZARD_FRESH_NS: u64 = 6_000_000_000;

/// Which optional layers the map draws.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapLayers {
    pub hazards: bool,
}

impl Default for MapLayers {
    fn default() -> Self {
        MapLayers { hazards: true }
    }
}

/// `bounds` (`[min_x, min_y, max_x, max_y]`) grown about its centre to at least `span_m` per side.
fn at_least(bounds: [f64; 4], span_m: f64) -> [f64; 4] {
    let [x0, y0, x1, y1] = bounds;
    let grow = |lo: f64, hi: f64| {
        let (mid, half) = (0.5 * (lo + hi), 0.5 * (hi - lo).max(span_m));
        (mid - half, mid + half)
    };
    let ((x0, x1), (y0, y1)) = (grow(x0, x1), grow(y0, y1));
    [x0, y0, x1, y1]
}

/// The map's camera and its cached texture.
#[derive(Default)]
pub struct MapState {
    /// Centre (m) and scale (px/m); `None` until the first fit.
    view: Option<([f64; 2], f64)>,
    /// Keep this robot in the centre.
    pub follow: Option<u8>,
    /// The operator placed the camera (pan, zoom, `set_view`); until then, and again after
    /// "Fit all", the camera keeps fitting the content as the team's map grows.
    user_camera: bool,
    pub layers: MapLayers,
    texture: Option<GridTexture>,
    last_transform: Option<MapTransform>,
    /// How many times the grid texture was (re)built, for tests and the frame-time budget.
    pub texture_uploads: u64,
}

impl std::fmt::Debug for MapState {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MapState")
            .field("view", &self.view)
            .field("follow", &self.follow)
            .field("layers", &self.layers)
            .field("texture_revision", &self.texture.as_ref().map(|t| t.revision))
            .field("texture_uploads", &self.texture_uploads)
            .finish()
    }
}

impl MapState {
    /// Places the camera: `center_ref_m` in the middle of the map area, `px_per_m` points per
    /// metre. Stops following a robot.
    pub fn set_view(&mut self, center_ref_m: [f64; 2], px_per_m: f64) {
        self.view = Some((center_ref_m, px_per_m));
        self.follow = None;
        self.user_camera = true;
    }

    /// The transform the last frame was drawn with.
    pub fn last_transform(&self) -> Option<MapTransform> {
        self.last_transform
    }

    /// Fits everything, and keeps fitting as the content grows until the operator moves the
    /// camera.
    pub fn fit_all(&mut self) {
        self.view = None;
        self.follow = None;
        self.user_camera = false;
    }
}

struct GridTexture {
    revision: u64,
    handle: TextureHandle,
    /// The world box the texture covers, `[min_x, min_y, max_x, max_y]`, m.
    rect_ref_m: [f64; 4],
}

pub fn show(ui: &mut Ui, view: &TeamView, state: &mut UiState, actions: &mut Vec<UiAction>) {
    toolbar(ui, view, state);

    let (response, painter) = ui.allocate_painter(ui.available_size(), Sense::click_and_drag());
    response.widget_info(|| WidgetInfo::labeled(Role::Canvas, true, MAP_LABEL));
    let rect = response.rect;
    painter.rect_filled(rect, 0.0, Color32::from_gray(18));

    let map = &mut state.map;
    let mut t = match map.view {
        Some((center, scale)) if map.user_camera || map.follow.is_some() => MapTransform::new(center, scale, rect),
        view_before => {
            let (center, scale) = view_before.unwrap_or(([0.0, 0.0], 10.0));
            let mut t = MapTransform::new(center, scale, rect);
            if let Some(bounds) = content_bounds(view) {
                t.fit(at_least(bounds, MIN_FIT_SPAN_M), 0.05);
            }
            t
        }
    };

    if let Some(robot) = map.follow
        && let Some(pose) = view.robots.get(&robot).and_then(|r| r.t_ref_body.as_ref())
    {
        t.center_ref_m = [pose.translation.x, pose.translation.y];
    }
    if response.dragged() {
        t.pan(response.drag_delta());
        map.follow = None;
        map.user_camera = true;
    }
    if response.hovered()
        && let Some(anchor) = response.hover_pos()
    {
        let (scroll_y, zoom) = ui.input(|i| (i.smooth_scroll_delta.y, i.zoom_delta()));
        let factor = f64::from(zoom) * (f64::from(scroll_y) * 0.002).exp();
        if (factor - 1.0).abs() > 1e-6 {
            t.zoom_about(anchor, factor);
            map.user_camera = true;
        }
    }
    map.view = Some((t.center_ref_m, t.px_per_m));
    map.last_transform = Some(t);

    if response.clicked()
        && state.waypoint_armed
        && view.can_command
        && let (Some(robot), Some(click)) = (state.target_robot, response.interact_pointer_pos())
    {
        let [x_ref_m, y_ref_m] = t.screen_to_world(click);
        actions.push(UiAction::Waypoint { robot, x_ref_m, y_ref_m });
        // One click, one waypoint: a second click must be a deliberate re-arm.
        state.waypoint_armed = false;
    }

    let painter = painter.with_clip_rect(rect);
    if let Some(grid) = &view.map {
        update_texture(ui.ctx(), &mut state.map, grid);
        if let Some(tex) = &state.map.texture {
            let [x0, y0, x1, y1] = tex.rect_ref_m;
            let screen = Rect::from_two_pos(t.world_to_screen(x0, y1), t.world_to_screen(x1, y0));
            painter.image(tex.handle.id(), screen, Rect::from_min_max(pos2(0.0, 0.0), pos2(1.0, 1.0)), Color32::WHITE);
        }
    }
    for robot in view.robots.values() {
        draw_submaps(&painter, &t, robot);
    }
    draw_edges(&painter, &t, view);
    if state.map.layers.hazards {
        for robot in view.robots.values() {
            draw_hazards(&painter, &t, robot, view.now_ns);
        }
    }
    for robot in view.robots.values() {
        draw_robot(&painter, &t, robot);
    }
    draw_scale_bar(&painter, &t);
    draw_overlay_text(&painter, &t, view, state, response.hover_pos());
}

fn toolbar(ui: &mut Ui, view: &TeamView, state: &mut UiState) {
    ui.horizontal(|ui| {
        if ui.button("Fit all").clicked() {
            state.map.fit_all();
        }
        let follow_text = state.map.follow.map_or_else(|| "nobody".to_owned(), |r| format!("robot {r}"));
        egui::ComboBox::from_label("Follow").selected_text(follow_text).show_ui(ui, |ui| {
            ui.selectable_value(&mut state.map.follow, None, "nobody");
            for (&id, robot) in &view.robots {
                if robot.t_ref_body.is_some() {
                    ui.selectable_value(&mut state.map.follow, Some(id), format!("robot {id}"));
                }
            }
        });
        ui.checkbox(&mut state.map.layers.hazards, "hazards")
            .on_hover_text("the robots' latest hazard cells (0.1 m, the nearest 256 each), faded when old");
        if state.waypoint_armed
            && let Some(r) = state.target_robot
        {
            ui.colored_label(palette::STALE, format!("click the map to send robot {r} a waypoint"));
        }
    });
}

/// Everything worth seeing: the grid and every known position, `[min_x, min_y, max_x, max_y]`.
pub fn content_bounds(view: &TeamView) -> Option<[f64; 4]> {
    let mut b = [f64::INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::NEG_INFINITY];
    let mut add = |x: f64, y: f64| {
        if x.is_finite() && y.is_finite() {
            b = [b[0].min(x), b[1].min(y), b[2].max(x), b[3].max(y)];
        }
    };
    if let Some(grid) = &view.map {
        let [x0, y0, x1, y1] = grid_rect_ref_m(grid, 1);
        add(x0, y0);
        add(x1, y1);
    }
    for robot in view.robots.values() {
        for p in &robot.trajectory_ref_m {
            add(p[0], p[1]);
        }
        if let Some(pose) = &robot.t_ref_body {
            add(pose.translation.x, pose.translation.y);
        }
    }
    (b[0] <= b[2]).then_some(b)
}

fn grid_rect_ref_m(grid: &HeightGrid, stride: usize) -> [f64; 4] {
    let w = grid.width.div_ceil(stride) * stride;
    let h = grid.height.div_ceil(stride) * stride;
    let [x0, y0] = grid.origin_xy_m;
    [x0, y0, x0 + w as f64 * grid.cell_m, y0 + h as f64 * grid.cell_m]
}

fn update_texture(ctx: &egui::Context, map: &mut MapState, grid: &HeightGrid) {
    if map.texture.as_ref().is_some_and(|t| t.revision == grid.revision) {
        return;
    }
    let max_side = ctx.input(|i| i.max_texture_side).max(1);
    let Some((image, stride)) = grid_image(grid, max_side) else {
        map.texture = None;
        return;
    };
    // Cells stay crisp when zoomed in; a zoomed-out map is averaged, not aliased.
    let options = TextureOptions { magnification: egui::TextureFilter::Nearest, ..TextureOptions::LINEAR };
    let rect_ref_m = grid_rect_ref_m(grid, stride);
    match &mut map.texture {
        Some(tex) if tex.handle.size() == image.size => {
            tex.handle.set(image, options);
            tex.revision = grid.revision;
            tex.rect_ref_m = rect_ref_m;
        }
        _ => {
            let handle = ctx.load_texture("height_grid", image, options);
            map.texture = Some(GridTexture { revision: grid.revision, handle, rect_ref_m });
        }
    }
    map.texture_uploads += 1;
}

/// The grid as an image, top row = largest y, decimated by an integer stride to fit
/// `max_side`. Obstacle cells are red, unobserved cells transparent. `None` for an empty or
/// inconsistent grid.
pub fn grid_image(grid: &HeightGrid, max_side: usize) -> Option<(ColorImage, usize)> {
    let (w, h) = (grid.width, grid.height);
    let cells = w.checked_mul(h)?;
    if cells == 0
        || grid.height_m.len() != cells
        || grid.obstacle.len() != cells
        || grid.cell_m.is_nan()
        || grid.cell_m <= 0.0
    {
        return None;
    }
    let stride = w.max(h).div_ceil(max_side).max(1);
    let (iw, ih) = (w.div_ceil(stride), h.div_ceil(stride));
    let (lo, hi) = palette::finite_range(grid.height_m.iter().copied()).unwrap_or((0.0, 1.0));
    // A 256-entry ramp: a 2000 × 2000 grid is rebuilt whenever the composed map changes, and the
    // ramp's float maths per cell dominated that.
    let lut: Vec<Color32> = (0..256).map(|i| palette::height_colour(i as f32 / 255.0)).collect();
    let scale = 255.0 / (hi - lo);
    let colour = |obstacle: bool, z: f32| {
        if obstacle {
            palette::OBSTACLE
        } else if z.is_finite() {
            lut[((z - lo) * scale).clamp(0.0, 255.0) as usize]
        } else {
            Color32::TRANSPARENT
        }
    };
    let mut pixels = vec![Color32::TRANSPARENT; iw * ih];
    if stride == 1 {
        for (image_row, out) in pixels.chunks_exact_mut(iw).enumerate() {
            let row = (ih - 1 - image_row) * w;
            let (z, obstacle) = (&grid.height_m[row..row + w], &grid.obstacle[row..row + w]);
            for ((px, &z), &o) in out.iter_mut().zip(z).zip(obstacle) {
                *px = colour(o, z);
            }
        }
        return Some((ColorImage::new([iw, ih], pixels), stride));
    }
    for by in 0..ih {
        let image_row = ih - 1 - by;
        for bx in 0..iw {
            let mut obstacle = false;
            let mut top = f32::NEG_INFINITY;
            for r in by * stride..((by + 1) * stride).min(h) {
                let row = r * w;
                for c in bx * stride..((bx + 1) * stride).min(w) {
                    obstacle |= grid.obstacle[row + c];
                    let z = grid.height_m[row + c];
                    if z.is_finite() {
                        top = top.max(z);
                    }
                }
            }
            pixels[image_row * iw + bx] = colour(obstacle, top);
        }
    }
    Some((ColorImage::new([iw, ih], pixels), stride))
}

/// Screen polyline of a trajectory, merging points closer than `min_step_px`; the last point is
/// always kept so the line ends at the newest pose.
pub fn screen_polyline(points_ref_m: &[[f64; 3]], t: &MapTransform, min_step_px: f32) -> Vec<Pos2> {
    let mut out: Vec<Pos2> = Vec::new();
    let min_sq = min_step_px * min_step_px;
    let n = points_ref_m.len();
    for (i, p) in points_ref_m.iter().enumerate() {
        if !(p[0].is_finite() && p[1].is_finite()) {
            continue;
        }
        let s = t.world_to_screen(p[0], p[1]);
        match out.last_mut() {
            Some(last) if (s - *last).length_sq() < min_sq => {
                if i + 1 == n {
                    *last = s;
                }
            }
            _ => out.push(s),
        }
    }
    out
}

/// [`screen_polyline`] cut into the runs that cross `visible`: zoomed in on one robot, the rest
/// of a long trajectory is off the screen and would otherwise be tessellated anyway.
pub fn visible_runs(points_ref_m: &[[f64; 3]], t: &MapTransform, min_step_px: f32, visible: Rect) -> Vec<Vec<Pos2>> {
    let line = screen_polyline(points_ref_m, t, min_step_px);
    let mut runs = Vec::new();
    let mut run: Vec<Pos2> = Vec::new();
    for pair in line.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        if Rect::from_two_pos(a, b).intersects(visible) {
            if run.is_empty() {
                run.push(a);
            }
            run.push(b);
        } else if !run.is_empty() {
            runs.push(std::mem::take(&mut run));
        }
    }
    if run.len() >= 2 {
        runs.push(run);
    }
    runs
}

/// Offsets (m) of the `k_sigma` ellipse of a 2×2 covariance, `segments` points; `None` when the
/// covariance is not finite.
pub fn ellipse_offsets_m(cov_m2: &Matrix2<f64>, k_sigma: f64, segments: usize) -> Option<Vec<[f64; 2]>> {
    if !cov_m2.iter().all(|v| v.is_finite()) {
        return None;
    }
    let sym = (cov_m2 + cov_m2.transpose()) * 0.5;
    let eig = SymmetricEigen::new(sym);
    let a = k_sigma * eig.eigenvalues[0].max(0.0).sqrt();
    let b = k_sigma * eig.eigenvalues[1].max(0.0).sqrt();
    let (u, v) = (eig.eigenvectors.column(0), eig.eigenvectors.column(1));
    Some(
        (0..segments)
            .map(|i| {
                let th = std::f64::consts::TAU * i as f64 / segments as f64;
                let (c, s) = (a * th.cos(), b * th.sin());
                [c * u[0] + s * v[0], c * u[1] + s * v[1]]
            })
            .collect(),
    )
}

fn draw_robot(painter: &Painter, t: &MapTransform, robot: &RobotView) {
    if !robot.connected {
        return;
    }
    let colour = robot_colour(robot.robot);
    for run in visible_runs(&robot.trajectory_ref_m, t, MIN_STEP_PX, t.screen_rect.expand(4.0)) {
        painter.add(Shape::line(run, Stroke::new(1.5, colour)));
    }
    let Some(pose) = &robot.t_ref_body else { return };
    let (x, y) = (pose.translation.x, pose.translation.y);
    let centre = t.world_to_screen(x, y);
    if let Some(cov) = &robot.position_cov_xy_m2
        && let Some(offsets) = ellipse_offsets_m(cov, 2.0, 48)
    {
        let ring: Vec<Pos2> = offsets.iter().map(|o| t.world_to_screen(x + o[0], y + o[1])).collect();
        painter.add(Shape::closed_line(ring, Stroke::new(1.0, colour.gamma_multiply(0.8))));
    }
    let heading = pose.rotation * Vector3::x();
    let yaw = heading.y.atan2(heading.x) as f32;
    // Screen y points down.
    let dir = vec2(yaw.cos(), -yaw.sin());
    let side = vec2(-dir.y, dir.x);
    let tip = centre + dir * 12.0;
    let tri = vec![tip, centre - dir * 6.0 + side * 7.0, centre - dir * 6.0 - side * 7.0];
    painter.add(Shape::convex_polygon(tri, colour, Stroke::new(1.5, Color32::BLACK)));
    painter.text(centre + vec2(10.0, 10.0), Align2::LEFT_TOP, robot.robot.to_string(), FontId::monospace(12.0), colour);
}

/// Screen corners of each hazard cell (squares turned with the body's heading, at least
/// [`MIN_HAZARD_CELL_PX`] wide), skipping those off the screen.
pub fn hazard_quads(hazards: &HazardView, t: &MapTransform) -> Vec<[Pos2; 4]> {
    let half_px = (0.5 * hazards.cell_m * t.px_per_m).max(0.5 * f64::from(MIN_HAZARD_CELL_PX)) as f32;
    let (sin, cos) = (hazards.yaw_ref_rad.sin() as f32, hazards.yaw_ref_rad.cos() as f32);
    // The lattice's axes on the screen (y points down).
    let (ex, ey) = (vec2(cos, -sin) * half_px, vec2(-sin, -cos) * half_px);
    let visible = t.screen_rect.expand(2.0 * half_px);
    hazards
        .cells_ref_m
        .iter()
        .map(|c| t.world_to_screen(c[0], c[1]))
        .filter(|centre| visible.contains(*centre))
        .map(|c| [c - ex - ey, c + ex - ey, c + ex + ey, c - ex + ey])
        .collect()
}

fn draw_hazards(painter: &Painter, t: &MapTransform, robot: &RobotView, now_ns: u64) {
    let Some(hazards) = robot.hazards.as_ref().filter(|_| robot.connected) else { return };
    let fresh = now_ns.saturating_sub(hazards.received_ns) <= HAZARD_FRESH_NS;
    let colour = if fresh { palette::HAZARD } else { palette::HAZARD_OLD };
    // One mesh per robot: 256 cells are 1024 vertices, not 256 shapes.
    let mut mesh = Mesh::default();
    for quad in hazard_quads(hazards, t) {
        let first = mesh.vertices.len() as u32;
        for corner in quad {
            mesh.colored_vertex(corner, colour);
        }
        mesh.add_triangle(first, first + 1, first + 2);
        mesh.add_triangle(first, first + 2, first + 3);
    }
    if !mesh.is_empty() {
        painter.add(Shape::mesh(mesh));
    }
}

fn draw_submaps(painter: &Painter, t: &MapTransform, robot: &RobotView) {
    if !robot.connected {
        return;
    }
    let stroke = Stroke::new(1.0, robot_colour(robot.robot).gamma_multiply(0.45));
    for submap in &robot.submaps {
        let Some([x0, y0, x1, y1]) = submap.bounds_submap_m else { continue };
        let corners = [[x0, y0], [x1, y0], [x1, y1], [x0, y1]].map(|[x, y]| {
            let p = submap.t_ref_submap * Point3::new(x, y, 0.0);
            t.world_to_screen(p.x, p.y)
        });
        painter.add(Shape::closed_line(corners.to_vec(), stroke));
    }
}

fn draw_edges(painter: &Painter, t: &MapTransform, view: &TeamView) {
    for edge in &view.edges {
        let a = t.world_to_screen(edge.from_ref_m[0], edge.from_ref_m[1]);
        let b = t.world_to_screen(edge.to_ref_m[0], edge.to_ref_m[1]);
        match edge.kind {
            EdgeKind::RobotDetection => {
                painter.extend(Shape::dashed_line(&[a, b], Stroke::new(2.0, palette::DETECTION_EDGE), 6.0, 4.0));
            }
            EdgeKind::SubmapMatch => {
                painter.line_segment([a, b], Stroke::new(1.2, palette::MATCH_EDGE));
            }
        }
    }
}

fn draw_scale_bar(painter: &Painter, t: &MapTransform) {
    let len_m = scale_bar_m(t.px_per_m, 120.0);
    let len_px = (len_m * t.px_per_m) as f32;
    let start = t.screen_rect.left_bottom() + vec2(16.0, -16.0);
    let end = start + vec2(len_px, 0.0);
    let stroke = Stroke::new(2.0, Color32::WHITE);
    painter.line_segment([start, end], stroke);
    for p in [start, end] {
        painter.line_segment([p, p - vec2(0.0, 6.0)], stroke);
    }
    let text = if len_m >= 1000.0 { format!("{} km", len_m / 1000.0) } else { format!("{len_m} m") };
    painter.text(
        start + vec2(0.5 * len_px, -8.0),
        Align2::CENTER_BOTTOM,
        text,
        FontId::proportional(12.0),
        Color32::WHITE,
    );
}

fn draw_overlay_text(painter: &Painter, t: &MapTransform, view: &TeamView, state: &UiState, hover: Option<Pos2>) {
    let mut lines = Vec::new();
    if let Some(p) = hover {
        let [x, y] = t.screen_to_world(p);
        lines.push(format!("x {x:.2} m  y {y:.2} m"));
    }
    let hidden: Vec<String> = view.robots.values().filter(|r| !r.connected).map(|r| r.robot.to_string()).collect();
    if !hidden.is_empty() {
        lines.push(format!("not in this frame: robot {}", hidden.join(", ")));
    }
    if state.map.layers.hazards {
        for robot in view.robots.values().filter(|r| r.connected) {
            let Some(h) = &robot.hazards else { continue };
            let age_s = view.now_ns.saturating_sub(h.received_ns) as f64 * 1e-9;
            let more = if h.omitted > 0 { format!(" (+{} far)", h.omitted) } else { String::new() };
            let placed = if h.exact { "" } else { ", at its latest pose" };
            lines.push(format!(
                "robot {}: {} hazard cells{more}, {age_s:.0} s old{placed}",
                robot.robot,
                h.cells_ref_m.len()
            ));
        }
    }
    if view.map.is_none() && view.robots.is_empty() {
        lines.push("waiting for data".to_owned());
    }
    if state.waypoint_armed {
        lines.push("waypoint armed".to_owned());
    }
    let mut pos = t.screen_rect.right_top() + Vec2::new(-8.0, 8.0);
    for line in lines {
        let r = painter.text(pos, Align2::RIGHT_TOP, line, FontId::monospace(12.0), Color32::LIGHT_GRAY);
        pos.y = r.bottom() + 2.0;
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    fn grid(width: usize, height: usize) -> HeightGrid {
        let n = width * height;
        HeightGrid {
            origin_xy_m: [-1.0, -2.0],
            cell_m: 0.5,
            width,
            height,
            height_m: (0..n).map(|i| i as f32).collect(),
            obstacle: vec![false; n],
            revision: 1,
        }
    }

    #[test]
    fn image_is_flipped_so_north_is_up() {
        let mut g = grid(3, 2);
        g.height_m[0] = f32::NAN; // row 0 (lowest y), column 0
        g.obstacle[5] = true; // row 1 (highest y), column 2
        let (img, stride) = grid_image(&g, 64).unwrap();
        assert_eq!((img.size, stride), ([3, 2], 1));
        // Image row 0 is grid row 1.
        assert_eq!(img.pixels[2], palette::OBSTACLE);
        assert_eq!(img.pixels[3], Color32::TRANSPARENT);
        // Height 2 in [1, 5] through the 256-entry ramp.
        assert_eq!(img.pixels[5], palette::height_colour(63.0 / 255.0));
    }

    #[test]
    fn large_grid_is_decimated_below_the_texture_limit() {
        let mut g = grid(5000, 10);
        g.obstacle[4999] = true;
        let (img, stride) = grid_image(&g, 2048).unwrap();
        assert_eq!(stride, 3);
        assert_eq!(img.size, [1667, 4]);
        // The obstacle survives decimation.
        assert!(img.pixels.contains(&palette::OBSTACLE));
        assert_eq!(grid_rect_ref_m(&g, stride)[2], -1.0 + 5001.0 * 0.5);
    }

    #[test]
    fn inconsistent_grid_is_refused() {
        let mut g = grid(3, 2);
        g.height_m.pop();
        assert!(grid_image(&g, 64).is_none());
        assert!(grid_image(&grid(0, 0), 64).is_none());
    }

    #[test]
    fn polyline_is_decimated_to_screen_resolution() {
        let rect = Rect::from_min_size(Pos2::ZERO, vec2(400.0, 400.0));
        let t = MapTransform::new([0.0, 0.0], 1.0, rect);
        // 10000 points over 100 m at 1 px/m: ~67 vertices at a 1.5 px step.
        let pts: Vec<[f64; 3]> = (0..10_000).map(|i| [i as f64 * 0.01, 0.0, 0.0]).collect();
        let line = screen_polyline(&pts, &t, 1.5);
        assert!(line.len() < 80 && line.len() > 60, "{}", line.len());
        assert_eq!(*line.last().unwrap(), t.world_to_screen(99.99, 0.0));
    }

    #[test]
    fn off_screen_parts_of_a_trajectory_are_cut() {
        let rect = Rect::from_min_size(Pos2::ZERO, vec2(100.0, 100.0));
        let t = MapTransform::new([0.0, 0.0], 1.0, rect);
        // In, out to the right, back in, out again: two runs, each starting one point outside.
        let xs = [-10.0, 0.0, 10.0, 200.0, 300.0, 200.0, 20.0, 30.0, 400.0, 500.0];
        let pts: Vec<[f64; 3]> = xs.iter().map(|&x| [x, 0.0, 0.0]).collect();
        let runs = visible_runs(&pts, &t, 0.5, rect);
        assert_eq!(runs.len(), 2, "{runs:?}");
        assert_eq!(runs[0].len(), 4); // -10, 0, 10, 200 (the last segment leaves the screen)
        assert_eq!(runs[1].len(), 4); // 200, 20, 30, 400
        assert!(runs.iter().flatten().all(|p| p.x <= t.world_to_screen(400.0, 0.0).x));
    }

    #[test]
    fn fit_box_has_a_minimum_span_about_its_centre() {
        assert_eq!(at_least([1.0, 2.0, 1.5, 2.0], 10.0), [-3.75, -3.0, 6.25, 7.0]);
        assert_eq!(at_least([-20.0, 0.0, 20.0, 30.0], 10.0), [-20.0, 0.0, 20.0, 30.0]);
    }

    #[test]
    fn ellipse_axes_follow_the_covariance() {
        // σx = 2 m, σy = 0.5 m, rotated 30°.
        let th = 30f64.to_radians();
        let r = nalgebra::Rotation2::new(th).into_inner();
        let cov = r * Matrix2::new(4.0, 0.0, 0.0, 0.25) * r.transpose();
        let pts = ellipse_offsets_m(&cov, 2.0, 360).unwrap();
        let max = pts.iter().map(|p| p[0].hypot(p[1])).fold(0.0, f64::max);
        let min = pts.iter().map(|p| p[0].hypot(p[1])).fold(f64::INFINITY, f64::min);
        assert!((max - 4.0).abs() < 1e-3 && (min - 1.0).abs() < 1e-3, "{max} {min}");
        let far = pts.iter().max_by(|a, b| a[0].hypot(a[1]).total_cmp(&b[0].hypot(b[1]))).unwrap();
        let ang = far[1].atan2(far[0]).rem_euclid(std::f64::consts::PI);
        assert!((ang - th).abs() < 0.02, "{ang}");
        assert!(ellipse_offsets_m(&Matrix2::new(f64::NAN, 0.0, 0.0, 1.0), 2.0, 8).is_none());
    }
}
