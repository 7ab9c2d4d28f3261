//! A scenario made real: terrain, shadows, every robot's trajectory (owned by the world helper).
//!
//! [`World::build`] generates the terrain, then repairs each rover's planned path against it
//! (see [`ObstacleMap`]): waypoints on obstacles move to the nearest free spot, legs through
//! obstacles are replaced by a grid search around them, and the path is cut back to what fits the
//! run. The repaired waypoints replace the scenario's in [`SimRobot::setup`].

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::Arc;

use nalgebra::Isometry3;

use crate::lighting::ShadowMap;
use crate::motion::{self, MotionPlan, PhaseKind};
use crate::render::{Quad, Scene};
use crate::robot::{RobotKind, RobotModel};
use crate::scenario::{RobotSetup, Scenario};
use crate::terrain::Terrain;
use crate::trajectory::{KinematicState, Trajectory};

/// Rocks at least this tall are obstacles; smaller ones are driven over.
pub const MAX_TRAVERSABLE_ROCK_M: f64 = 0.25;
/// Craters deeper than this (floor below the surroundings) are obstacles.
pub const MAX_TRAVERSABLE_CRATER_DEPTH_M: f64 = 0.25;
/// Steeper ground (over the rover's footprint) is an obstacle.
pub const MAX_SLOPE_RAD: f64 = 25.0 * std::f64::consts::PI / 180.0;
/// How far a rover's centre keeps from an obstacle's edge: the footprint's half diagonal
/// (0.69 m) plus a safety margin.
pub const OBSTACLE_CLEARANCE_M: f64 = 1.0;
/// Resolution of the planning grid.
const GRID_M: f64 = 0.25;
/// Spacing of the samples that check a straight leg against the grid.
const LEG_STEP_M: f64 = 0.05;
/// Half the baseline of the slope estimate (about the rover's wheelbase).
const SLOPE_HALF_BASE_M: f64 = 0.4;
/// Fastest pan of the head's sweep while standing.
pub const PAN_RATE_MAX_RADPS: f64 = 0.8;

/// One robot in the world.
#[derive(Debug, Clone)]
pub struct SimRobot {
    pub setup: RobotSetup,
    pub trajectory: Trajectory,
    /// The timed plan behind the trajectory (times from the start of the run).
    pub plan: MotionPlan,
}

impl SimRobot {
    pub fn model(&self) -> &RobotModel {
        &self.setup.model
    }
}

/// Why a world could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum WorldError {
    #[error("robot {robot}: {reason}")]
    Robot { robot: usize, reason: String },
}

/// Terrain, light and robots of a run; immutable once built, shared by the robots' drivers.
#[derive(Debug)]
pub struct World {
    pub scenario: Scenario,
    pub terrain: Terrain,
    pub shadows: ShadowMap,
    pub robots: Vec<SimRobot>,
}

impl World {
    /// Builds the world of `scenario` (deterministic for its seed).
    pub fn build(scenario: &Scenario) -> Result<Arc<World>, WorldError> {
        let terrain = Terrain::generate(&scenario.terrain, scenario.seed);
        let shadows = ShadowMap::compute(&terrain.heightfield, &scenario.sun);
        let end_ns = duration_ns(scenario.duration_s);
        let needs_map = scenario.robots.iter().any(|r| r.model.kind == RobotKind::Rover);
        let obstacles = needs_map.then(|| ObstacleMap::build(&terrain));
        let mut robots = Vec::with_capacity(scenario.robots.len());
        for (index, setup) in scenario.robots.iter().enumerate() {
            let fail = |reason: String| WorldError::Robot { robot: index, reason };
            let mut setup = setup.clone();
            let (plan, trajectory) = match (setup.model.kind, &obstacles) {
                (RobotKind::Rover, Some(obstacles)) => {
                    let route: Vec<[f64; 2]> = setup.waypoints_m.iter().map(|w| [w[0], w[1]]).collect();
                    let repaired = obstacles.repair(&route);
                    let plan = fit_duration(repaired, &setup, scenario.duration_s).map_err(|e| fail(e.to_string()))?;
                    setup.waypoints_m = plan.1.iter().map(|p| [p[0], p[1], 0.0]).collect();
                    let trajectory =
                        motion::rover_trajectory_from_plan(&terrain, &plan.0, setup.drive.knot_interval_s, 0, end_ns)
                            .map_err(|e| fail(e.to_string()))?;
                    (plan.0, trajectory)
                }
                _ => {
                    let plan = MotionPlan::flyer(&setup.waypoints_m, &setup.drive).map_err(|e| fail(e.to_string()))?;
                    let trajectory = motion::flyer_trajectory_from_plan(
                        &terrain,
                        &plan,
                        setup.drive.knot_interval_s,
                        scenario.body.gravity_mps2(),
                        0,
                        end_ns,
                    )
                    .map_err(|e| fail(e.to_string()))?;
                    (plan, trajectory)
                }
            };
            robots.push(SimRobot { setup, trajectory, plan });
        }
        Ok(Arc::new(World { scenario: scenario.clone(), terrain, shadows, robots }))
    }

    /// End of the run.
    pub fn end_ns(&self) -> u64 {
        duration_ns(self.scenario.duration_s)
    }

    /// True state of robot `robot` at `stamp_ns`.
    pub fn robot_state(&self, robot: usize, stamp_ns: u64) -> Option<KinematicState> {
        self.robots.get(robot)?.trajectory.state_at(stamp_ns)
    }

    /// Pan and tilt of robot `robot`'s head at `stamp_ns`: the configured tilt throughout, and
    /// while standing a pan sweep to one side, to the other and back, `0 → +A → −A → 0`, whose
    /// value and rate are zero at both ends of the stand (C¹ everywhere). The amplitude `A` is
    /// `pan_sweep_rad`, reduced so that the pan rate stays within [`PAN_RATE_MAX_RADPS`].
    /// `(0, 0)` for robots without a head.
    pub fn head_angles(&self, robot: usize, stamp_ns: u64) -> (f64, f64) {
        let Some(r) = self.robots.get(robot) else {
            return (0.0, 0.0);
        };
        if r.model().head.is_none() {
            return (0.0, 0.0);
        }
        let t = stamp_ns as f64 * 1e-9;
        let tilt = r.setup.tilt_rad;
        let phases = r.plan.phases();
        let Some(i) = r.plan.phase_index_at(t) else {
            return (0.0, tilt);
        };
        let phase = &phases[i];
        if phase.kind != PhaseKind::Stand {
            return (0.0, tilt);
        }
        // The final stand lasts to the end of the run.
        let (start, end) = if i + 1 == phases.len() {
            (phase.start_s, phase.end_s.max(self.end_ns() as f64 * 1e-9))
        } else {
            (phase.start_s, phase.end_s)
        };
        let duration = end - start;
        if duration <= 0.0 || t <= start || t >= end {
            return (0.0, tilt);
        }
        let amplitude = r.setup.pan_sweep_rad.abs().min(PAN_RATE_MAX_RADPS * duration / SWEEP_PEAK_RATE);
        (amplitude * sweep_shape((t - start) / duration), tilt)
    }

    /// Pose of robot `robot`'s left camera at `stamp_ns`.
    pub fn t_world_cam(&self, robot: usize, stamp_ns: u64) -> Option<Isometry3<f64>> {
        let state = self.robot_state(robot, stamp_ns)?;
        let (pan, tilt) = self.head_angles(robot, stamp_ns);
        Some(state.t_world_body * self.robots[robot].model().t_body_cam(pan, tilt))
    }

    /// World poses of robot `robot`'s markers at `stamp_ns`, with their tag ids.
    pub fn marker_poses_world(&self, robot: usize, stamp_ns: u64) -> Vec<(u32, Isometry3<f64>)> {
        let Some(state) = self.robot_state(robot, stamp_ns) else {
            return Vec::new();
        };
        self.robots[robot].model().markers.iter().map(|m| (m.tag_id, state.t_world_body * m.t_body_marker)).collect()
    }

    /// The faces of every robot except `exclude` at `stamp_ns`, appended to `out`.
    pub fn quads_at(&self, stamp_ns: u64, exclude: Option<usize>, out: &mut Vec<Quad>) {
        for (i, robot) in self.robots.iter().enumerate() {
            if Some(i) == exclude {
                continue;
            }
            if let Some(state) = robot.trajectory.state_at(stamp_ns) {
                robot.model().append_quads(&state.t_world_body, out);
            }
        }
    }

    /// The scene for rendering with the given robot faces.
    pub fn scene<'a>(&'a self, quads: &'a [Quad]) -> Scene<'a> {
        Scene {
            terrain: &self.terrain,
            shadows: &self.shadows,
            sun: self.scenario.sun,
            reflectance: self.scenario.reflectance,
            sky_radiance: self.scenario.sky_radiance,
            quads,
        }
    }
}

fn duration_ns(duration_s: f64) -> u64 {
    (duration_s * 1e9).round() as u64
}

/// `sin(2πs)·(1 − cos(2πs))/2`, normalised to a peak of 1: zero with zero slope at both ends.
fn sweep_shape(s: f64) -> f64 {
    let a = 2.0 * std::f64::consts::PI * s;
    a.sin() * (1.0 - a.cos()) * 0.5 / SWEEP_PEAK
}

/// Peak of `sin(a)·(1 − cos a)/2` (at `a = 2π/3`): `3√3/8`.
const SWEEP_PEAK: f64 = 0.649_519_052_838_329;
/// Peak slope of [`sweep_shape`] per unit of `s`: the derivative `π·(cos a − cos 2a)/SWEEP_PEAK`
/// is largest in magnitude at `a = π` (the swing through the centre).
const SWEEP_PEAK_RATE: f64 = 2.0 * std::f64::consts::PI / SWEEP_PEAK;

/// The longest prefix of `route` (at least two waypoints) whose plan fits `duration_s`.
fn fit_duration(
    mut route: Vec<[f64; 2]>,
    setup: &RobotSetup,
    duration_s: f64,
) -> Result<(MotionPlan, Vec<[f64; 2]>), motion::MotionError> {
    loop {
        let plan = MotionPlan::rover(&route, &setup.drive)?;
        if plan.end_s() <= duration_s || route.len() <= 2 {
            return Ok((plan, route));
        }
        route.pop();
    }
}

/// Where a rover may not go: a grid over the terrain marking cells whose centre is closer than
/// [`OBSTACLE_CLEARANCE_M`] to a rock taller than [`MAX_TRAVERSABLE_ROCK_M`], a ditch, a crater
/// deeper than [`MAX_TRAVERSABLE_CRATER_DEPTH_M`] or a negative obstacle's edge, or within half a
/// metre of ground steeper than [`MAX_SLOPE_RAD`]; and a border of [`crate::scenario::EDGE_MARGIN_M`]
/// less a metre.
#[derive(Debug, Clone)]
pub struct ObstacleMap {
    origin_m: [f64; 2],
    cols: usize,
    rows: usize,
    /// Per cell: [`FREE`], [`NEAR`] (within [`NEAR_MARGIN_M`] of a blocked zone) or [`BLOCKED`].
    cells: Vec<u8>,
}

const FREE: u8 = 0;
const NEAR: u8 = 1;
const BLOCKED: u8 = 2;
/// Grid searches pay extra for cells this close to a blocked zone, so detours keep some room
/// and shortcutting them leaves few waypoints (each of which is a stop).
const NEAR_MARGIN_M: f64 = 0.75;
const NEAR_COST_FACTOR: f64 = 4.0;

impl ObstacleMap {
    pub fn build(terrain: &Terrain) -> Self {
        let hf = &terrain.heightfield;
        let min = hf.origin_m;
        let max = [min[0] + (hf.cols - 1) as f64 * hf.resolution_m, min[1] + (hf.rows - 1) as f64 * hf.resolution_m];
        let cols = ((max[0] - min[0]) / GRID_M).floor() as usize + 1;
        let rows = ((max[1] - min[1]) / GRID_M).floor() as usize + 1;
        let mut map = ObstacleMap { origin_m: min, cols, rows, cells: vec![FREE; cols * rows] };
        let border = (crate::scenario::EDGE_MARGIN_M - 1.0).max(SLOPE_HALF_BASE_M + GRID_M);
        let c = OBSTACLE_CLEARANCE_M;

        // Steep ground, then grown by half a metre.
        let mut steep = vec![false; cols * rows];
        let max_gradient = MAX_SLOPE_RAD.tan();
        for row in 0..rows {
            for col in 0..cols {
                let [x, y] = map.centre(col, row);
                let h = |dx: f64, dy: f64| hf.height_at(x + dx, y + dy);
                let s = SLOPE_HALF_BASE_M;
                if let (Some(e), Some(w), Some(n), Some(so)) = (h(s, 0.0), h(-s, 0.0), h(0.0, s), h(0.0, -s)) {
                    let gx = (e - w) / (2.0 * s);
                    let gy = (n - so) / (2.0 * s);
                    steep[row * cols + col] = gx.hypot(gy) > max_gradient;
                }
            }
        }
        for row in 0..rows {
            for col in 0..cols {
                if steep[row * cols + col] {
                    map.block_disc(map.centre(col, row), 0.5);
                }
            }
        }
        for rock in terrain.rocks.iter().filter(|r| r.height_m > MAX_TRAVERSABLE_ROCK_M) {
            map.block_disc([rock.base_m.x, rock.base_m.y], rock.radius_m + c);
        }
        for ditch in &terrain.ditches {
            map.block_capsule(ditch.start_m, ditch.end_m, 0.5 * ditch.width_m + c);
        }
        for crater in terrain.craters.iter().filter(|k| k.depth_m > MAX_TRAVERSABLE_CRATER_DEPTH_M) {
            map.block_disc(crater.centre_m, crater.radius_m + c);
        }
        for obstacle in terrain.negative_obstacles() {
            for edge in obstacle.edge_m.windows(2) {
                map.block_capsule(edge[0], edge[1], c);
            }
        }
        for row in 0..rows {
            for col in 0..cols {
                let [x, y] = map.centre(col, row);
                if x < min[0] + border || x > max[0] - border || y < min[1] + border || y > max[1] - border {
                    map.cells[row * cols + col] = BLOCKED;
                }
            }
        }
        map
    }

    fn centre(&self, col: usize, row: usize) -> [f64; 2] {
        [self.origin_m[0] + col as f64 * GRID_M, self.origin_m[1] + row as f64 * GRID_M]
    }

    /// The cell nearest to `p`, `None` off the grid.
    fn cell(&self, p: [f64; 2]) -> Option<(usize, usize)> {
        let c = ((p[0] - self.origin_m[0]) / GRID_M).round();
        let r = ((p[1] - self.origin_m[1]) / GRID_M).round();
        (c >= 0.0 && r >= 0.0 && (c as usize) < self.cols && (r as usize) < self.rows)
            .then_some((c as usize, r as usize))
    }

    /// Whether the point `(x, y)` is blocked (off the grid counts as blocked).
    pub fn is_blocked(&self, p: [f64; 2]) -> bool {
        self.cell(p).is_none_or(|(c, r)| self.cells[r * self.cols + c] == BLOCKED)
    }

    /// Blocks the cells within `radius` of a shape (`distance` from a point to it, over the
    /// shape's bounding box `lo..hi`), and marks those a little farther out as near.
    fn block_where(&mut self, lo: [f64; 2], hi: [f64; 2], radius: f64, distance: impl Fn([f64; 2]) -> f64) {
        let m = radius + NEAR_MARGIN_M;
        let (lo, hi) = ([lo[0] - m, lo[1] - m], [hi[0] + m, hi[1] + m]);
        let c0 = ((lo[0] - self.origin_m[0]) / GRID_M).floor().max(0.0) as usize;
        let r0 = ((lo[1] - self.origin_m[1]) / GRID_M).floor().max(0.0) as usize;
        let c1 = (((hi[0] - self.origin_m[0]) / GRID_M).ceil().max(0.0) as usize).min(self.cols - 1);
        let r1 = (((hi[1] - self.origin_m[1]) / GRID_M).ceil().max(0.0) as usize).min(self.rows - 1);
        for row in r0..=r1 {
            for col in c0..=c1 {
                let d = distance(self.centre(col, row));
                let cell = &mut self.cells[row * self.cols + col];
                if d <= radius {
                    *cell = BLOCKED;
                } else if d <= m {
                    *cell = (*cell).max(NEAR);
                }
            }
        }
    }

    fn block_disc(&mut self, centre: [f64; 2], radius: f64) {
        self.block_where(centre, centre, radius, |p| (p[0] - centre[0]).hypot(p[1] - centre[1]));
    }

    fn block_capsule(&mut self, a: [f64; 2], b: [f64; 2], radius: f64) {
        let lo = [a[0].min(b[0]), a[1].min(b[1])];
        let hi = [a[0].max(b[0]), a[1].max(b[1])];
        self.block_where(lo, hi, radius, |p| segment_distance(p, a, b));
    }

    /// Whether the straight leg from `a` to `b` crosses no blocked cell.
    pub fn leg_is_free(&self, a: [f64; 2], b: [f64; 2]) -> bool {
        let d = (b[0] - a[0]).hypot(b[1] - a[1]);
        let steps = (d / LEG_STEP_M).ceil().max(1.0) as usize;
        (0..=steps).all(|k| {
            let f = k as f64 / steps as f64;
            !self.is_blocked([a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f])
        })
    }

    /// The free cell centre nearest to `p` (searching outward ring by ring), `None` if there is
    /// none within 20 m.
    fn nearest_free(&self, p: [f64; 2]) -> Option<[f64; 2]> {
        if !self.is_blocked(p) {
            return Some(p);
        }
        let c = ((p[0] - self.origin_m[0]) / GRID_M).round() as i64;
        let r = ((p[1] - self.origin_m[1]) / GRID_M).round() as i64;
        let max_ring = (20.0 / GRID_M) as i64;
        for ring in 1..=max_ring {
            let mut best: Option<(f64, [f64; 2])> = None;
            for dr in -ring..=ring {
                for dc in -ring..=ring {
                    if dr.abs() != ring && dc.abs() != ring {
                        continue;
                    }
                    let (cc, rr) = (c + dc, r + dr);
                    if cc < 0 || rr < 0 || cc >= self.cols as i64 || rr >= self.rows as i64 {
                        continue;
                    }
                    if self.cells[rr as usize * self.cols + cc as usize] == BLOCKED {
                        continue;
                    }
                    let q = self.centre(cc as usize, rr as usize);
                    let d = (q[0] - p[0]).hypot(q[1] - p[1]);
                    if best.is_none_or(|(bd, _)| d < bd) {
                        best = Some((d, q));
                    }
                }
            }
            if let Some((_, q)) = best {
                return Some(q);
            }
        }
        None
    }

    /// A* over the 8-connected free cells from `a` to `b` (`a`'s own cell may be blocked: a
    /// robot may have to leave where it stands). `None` when `b` is unreachable.
    fn search(&self, a: [f64; 2], b: [f64; 2]) -> Option<Vec<[f64; 2]>> {
        let start = self.cell(a)?;
        let goal = self.cell(b)?;
        let index = |(c, r): (usize, usize)| r * self.cols + c;
        let heuristic = |(c, r): (usize, usize)| {
            let dx = c.abs_diff(goal.0) as f64;
            let dy = r.abs_diff(goal.1) as f64;
            // Octile distance: exact on an empty 8-connected grid, so the search stays optimal.
            (dx.max(dy) + (std::f64::consts::SQRT_2 - 1.0) * dx.min(dy)) * GRID_M
        };
        let mut cost = vec![f64::INFINITY; self.cols * self.rows];
        let mut parent = vec![usize::MAX; self.cols * self.rows];
        let mut open = BinaryHeap::new();
        cost[index(start)] = 0.0;
        // Keys in micrometres: integer ordering, ties broken by cell index, so the result never
        // depends on float comparison quirks.
        let key = |f: f64| (f * 1e6) as u64;
        open.push(Reverse((key(heuristic(start)), index(start))));
        while let Some(Reverse((_, i))) = open.pop() {
            let here = (i % self.cols, i / self.cols);
            if here == goal {
                let mut path = vec![b];
                let mut j = parent[i];
                while j != usize::MAX && j != index(start) {
                    path.push(self.centre(j % self.cols, j / self.cols));
                    j = parent[j];
                }
                path.push(a);
                path.reverse();
                return Some(path);
            }
            for (dc, dr) in [(-1i64, -1i64), (0, -1), (1, -1), (-1, 0), (1, 0), (-1, 1), (0, 1), (1, 1)] {
                let (nc, nr) = (here.0 as i64 + dc, here.1 as i64 + dr);
                if nc < 0 || nr < 0 || nc >= self.cols as i64 || nr >= self.rows as i64 {
                    continue;
                }
                let next = (nc as usize, nr as usize);
                let j = index(next);
                if self.cells[j] == BLOCKED && next != goal {
                    continue;
                }
                let step = if dc != 0 && dr != 0 { std::f64::consts::SQRT_2 * GRID_M } else { GRID_M };
                let step = if self.cells[j] == NEAR { step * NEAR_COST_FACTOR } else { step };
                let c = cost[i] + step;
                if c < cost[j] {
                    cost[j] = c;
                    parent[j] = i;
                    open.push(Reverse((key(c + heuristic(next)), j)));
                }
            }
        }
        None
    }

    /// `path` with every node dropped that a free straight leg can skip.
    fn shortcut(&self, path: &[[f64; 2]]) -> Vec<[f64; 2]> {
        let Some(&first) = path.first() else {
            return Vec::new();
        };
        let mut out = vec![first];
        let mut i = 0;
        while i + 1 < path.len() {
            let mut j = path.len() - 1;
            while j > i + 1 && !self.leg_is_free(path[i], path[j]) {
                j -= 1;
            }
            out.push(path[j]);
            i = j;
        }
        out
    }

    /// `route` made drivable: blocked waypoints (except the start) move to the nearest free
    /// spot; blocked legs detour along a shortest grid path; unreachable waypoints are dropped.
    pub fn repair(&self, route: &[[f64; 2]]) -> Vec<[f64; 2]> {
        let Some(&start) = route.first() else {
            return Vec::new();
        };
        let mut out = vec![start];
        for &target in &route[1..] {
            let Some(target) = self.nearest_free(target) else {
                continue;
            };
            let Some(&here) = out.last() else {
                continue;
            };
            if (target[0] - here[0]).hypot(target[1] - here[1]) < 1e-6 {
                continue;
            }
            if self.leg_is_free(here, target) {
                out.push(target);
            } else if let Some(path) = self.search(here, target) {
                out.extend(self.shortcut(&path).into_iter().skip(1));
            }
        }
        out
    }
}

/// Distance from `p` to the segment `a–b`.
pub fn segment_distance(p: [f64; 2], a: [f64; 2], b: [f64; 2]) -> f64 {
    let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
    let len2 = dx * dx + dy * dy;
    let t = if len2 > 0.0 { (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2).clamp(0.0, 1.0) } else { 0.0 };
    (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sweep_is_c1_with_unit_peak() {
        assert!(sweep_shape(0.0).abs() < 1e-15 && sweep_shape(1.0).abs() < 1e-12);
        let h = 1e-6;
        assert!((sweep_shape(h) / h).abs() < 1e-4);
        let peak = (0..=10_000).map(|i| sweep_shape(f64::from(i) / 1e4)).fold(f64::MIN, f64::max);
        assert!((peak - 1.0).abs() < 1e-6);
        let rate = (0..10_000)
            .map(|i| (sweep_shape(f64::from(i + 1) / 1e4) - sweep_shape(f64::from(i) / 1e4)) * 1e4)
            .fold(0.0, |m: f64, r| m.max(r.abs()));
        assert!((rate - SWEEP_PEAK_RATE).abs() < 1e-3 * SWEEP_PEAK_RATE, "{rate}");
    }

    #[test]
    fn segment_distance_clamps_to_the_ends() {
        assert!((segment_distance([0.0, 1.0], [-1.0, 0.0], [1.0, 0.0]) - 1.0).abs() < 1e-12);
        assert!((segment_distance([3.0, 4.0], [-1.0, 0.0], [0.0, 0.0]) - 5.0).abs() < 1e-12);
    }
}
