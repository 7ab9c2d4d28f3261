//! Where the camera stands: deliberate viewpoints facing each true obstacle, random ones on open
//! ground, and straight approach runs towards each target; every body pose rests on the terrain
//! on ground the sim planner calls free, with the whole view on the terrain.

use eval::map::TrueObstacle;
use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion};
use sim::motion::wheel_contact_plane;
use sim::robot::ROVER_CHASSIS_HEIGHT_M;
use sim::world::{ObstacleMap, World};

use super::Truth;

/// Camera distances (horizontal, to the target's centre) of the deliberate viewpoints.
pub const DISTANCES_M: [f64; 3] = [2.5, 3.5, 4.5];

/// What a viewpoint was chosen for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Aim {
    /// Facing a rock taller than `h_max`.
    Rock,
    /// Facing an edge target of a negative obstacle.
    Edge,
    /// A random pose on free ground.
    Open,
}

/// One camera placement: the rover's body pose and its head tilt.
#[derive(Debug, Clone, Copy)]
pub struct Viewpoint {
    /// What the viewpoint was chosen for.
    pub aim: Aim,
    /// The body resting on the terrain, in the world.
    pub t_world_body: Isometry3<f64>,
    /// Head tilt (down positive), the robot's mounted tilt unless an experiment changes it.
    pub tilt_rad: f64,
}

/// splitmix64: a reproducible stream without a dependency.
pub(super) fn next_unit(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
}

/// Body resting on the terrain at `(x, y)` heading `yaw`, as the trajectory generator poses it.
pub(super) fn body_pose(world: &World, x: f64, y: f64, yaw: f64) -> Option<Isometry3<f64>> {
    let plane = wheel_contact_plane(&world.terrain.heightfield, x, y, yaw)?;
    let (roll, pitch) = plane.roll_pitch_rad();
    Some(Isometry3::from_parts(
        Translation3::new(x, y, plane.height_m + ROVER_CHASSIS_HEIGHT_M),
        UnitQuaternion::from_euler_angles(roll, pitch, yaw),
    ))
}

/// Whether everything the camera at `cam_xy` heading `yaw` maps (within 5 m, 50° field of view)
/// lies on the terrain: beyond its edge the void would look like a cliff.
pub(super) fn view_on_terrain(world: &World, cam_xy: [f64; 2], yaw: f64) -> bool {
    let hf = &world.terrain.heightfield;
    let (s, c) = yaw.sin_cos();
    [(0.0, 0.0), (7.0, 0.0), (7.0, 3.5), (7.0, -3.5)]
        .iter()
        .all(|&(f, l)| hf.height_at(cam_xy[0] + c * f - s * l, cam_xy[1] + s * f + c * l).is_some())
}

/// Viewpoints: up to `per_target` per rock and per edge target (camera `DISTANCES_M` away,
/// facing it, from bearings tried in turn until the body stands on free ground), then `open`
/// random poses on free ground.
pub fn viewpoints(world: &World, truth: &Truth, per_target: usize, open: usize, seed: u64) -> Vec<Viewpoint> {
    let free = ObstacleMap::build(&world.terrain);
    let robot = &world.robots[0];
    let cam = robot.model().t_body_cam(0.0, robot.setup.tilt_rad).translation.vector;
    let mut rng = seed ^ 0x5EED;
    let mut out = Vec::new();
    let targets = truth
        .rocks
        .iter()
        .map(|(o, _)| (Aim::Rock, o.centre_m))
        .chain(truth.edge_targets.iter().map(|p| (Aim::Edge, *p)));
    for (aim, target) in targets {
        let start = 2.0 * std::f64::consts::PI * next_unit(&mut rng);
        let mut taken = 0;
        for k in 0..16 {
            if taken == per_target {
                break;
            }
            let bearing = start + k as f64 * 2.0 * std::f64::consts::PI / 16.0;
            let d = DISTANCES_M[taken % DISTANCES_M.len()];
            let yaw = bearing + std::f64::consts::PI;
            let (s, c) = yaw.sin_cos();
            let cam_xy = [target.x - c * d, target.y - s * d];
            let body_xy = [cam_xy[0] - (c * cam.x - s * cam.y), cam_xy[1] - (s * cam.x + c * cam.y)];
            if free.is_blocked(body_xy) || !view_on_terrain(world, cam_xy, yaw) {
                continue;
            }
            if let Some(t_world_body) = body_pose(world, body_xy[0], body_xy[1], yaw) {
                out.push(Viewpoint { aim, t_world_body, tilt_rad: robot.setup.tilt_rad });
                taken += 1;
            }
        }
    }
    let hf = &world.terrain.heightfield;
    let span = [(hf.cols - 1) as f64 * hf.resolution_m, (hf.rows - 1) as f64 * hf.resolution_m];
    let mut placed = 0;
    let mut tries = 0;
    while placed < open && tries < 100 * open.max(1) {
        tries += 1;
        let x = hf.origin_m[0] + span[0] * next_unit(&mut rng);
        let y = hf.origin_m[1] + span[1] * next_unit(&mut rng);
        let yaw = 2.0 * std::f64::consts::PI * next_unit(&mut rng);
        let (s, c) = yaw.sin_cos();
        let cam_xy = [x + c * cam.x - s * cam.y, y + s * cam.x + c * cam.y];
        if free.is_blocked([x, y]) || !view_on_terrain(world, cam_xy, yaw) {
            continue;
        }
        if let Some(t_world_body) = body_pose(world, x, y, yaw) {
            out.push(Viewpoint { aim: Aim::Open, t_world_body, tilt_rad: robot.setup.tilt_rad });
            placed += 1;
        }
    }
    out
}

/// Camera distances (horizontal, to the target) of an approach run, far and near: from the range
/// cutoff down to where the target reaches the image's lower edge (the view's nearest
/// ground lies 2.4 m ahead at the mast's 1.24 m and 0.25 rad tilt).
pub const APPROACH_M: (f64, f64) = (5.0, 2.5);
/// Spacing of the approach frames.
pub const APPROACH_STEP_M: f64 = 0.5;
/// The approached section of a negative edge: its discs within this of the edge target.
pub const EDGE_SECTION_M: f64 = 0.5;

/// The frame distances of an approach from `far` to `near`, every [`APPROACH_STEP_M`].
pub fn approach_distances((far_m, near_m): (f64, f64)) -> impl Iterator<Item = f64> {
    let steps = ((far_m - near_m) / APPROACH_STEP_M).round().max(0.0) as usize;
    (0..=steps).map(move |i| far_m - APPROACH_STEP_M * i as f64)
}

/// A straight drive towards one target, as the rolling local map sees it.
#[derive(Debug, Clone)]
pub struct Approach {
    /// A rock or an edge target.
    pub aim: Aim,
    /// Rock height above h_max (rocks only; 0 for edges).
    pub excess_height_m: f64,
    /// The true obstacles the run is about: the rock, or the edge discs of the approached section.
    pub truth: Vec<TrueObstacle>,
    /// One pose per distance, far to near, with the distance.
    pub frames: Vec<(Viewpoint, f64)>,
}

/// What a drive aims at: each rock (with its height above `max_step_m`) and each edge target
/// (with the edge discs of its section), as (aim, point, true obstacles, excess height).
pub(super) fn targets(
    truth: &Truth,
    max_step_m: f64,
) -> impl Iterator<Item = (Aim, Point2<f64>, Vec<TrueObstacle>, f64)> + '_ {
    let rocks = truth.rocks.iter().map(move |(o, h)| (Aim::Rock, o.centre_m, vec![*o], h - max_step_m));
    rocks.chain(truth.edge_targets.iter().map(|p| {
        let section = truth.edges.iter().filter(|o| (o.centre_m - p).norm() <= EDGE_SECTION_M).copied().collect();
        (Aim::Edge, *p, section, 0.0)
    }))
}

/// One approach per rock and per edge target, from the first of 16 bearings (starting at a
/// random one) whose whole straight path keeps the body on free ground and the view on the
/// terrain. Frames every [`APPROACH_STEP_M`] from `distances_m` (far, near), the head tilted down
/// by `tilt_rad`.
pub fn approaches(
    world: &World,
    truth: &Truth,
    max_step_m: f64,
    distances_m: (f64, f64),
    tilt_rad: f64,
    seed: u64,
) -> Vec<Approach> {
    let free = ObstacleMap::build(&world.terrain);
    let robot = &world.robots[0];
    let cam = robot.model().t_body_cam(0.0, tilt_rad).translation.vector;
    let (far_m, near_m) = distances_m;
    let distances: Vec<f64> = approach_distances(distances_m).collect();
    let mut rng = seed ^ 0xA9_9A0C;
    let mut out = Vec::new();
    for (aim, target, section, excess_height_m) in targets(truth, max_step_m) {
        let start = 2.0 * std::f64::consts::PI * next_unit(&mut rng);
        for k in 0..16 {
            let yaw = start + k as f64 * 2.0 * std::f64::consts::PI / 16.0;
            let (s, c) = yaw.sin_cos();
            let body_at = |d: f64| {
                let cam_xy = [target.x - c * d, target.y - s * d];
                (cam_xy, [cam_xy[0] - (c * cam.x - s * cam.y), cam_xy[1] - (s * cam.x + c * cam.y)])
            };
            // The path between the frames too, every 0.1 m.
            let steps = ((far_m - near_m) / 0.1).round() as usize;
            let path_free = (0..=steps).all(|i| !free.is_blocked(body_at(far_m - 0.1 * i as f64).1));
            if !path_free {
                continue;
            }
            let frames: Option<Vec<(Viewpoint, f64)>> = distances
                .iter()
                .map(|&d| {
                    let (cam_xy, body_xy) = body_at(d);
                    if !view_on_terrain(world, cam_xy, yaw) {
                        return None;
                    }
                    body_pose(world, body_xy[0], body_xy[1], yaw)
                        .map(|t_world_body| (Viewpoint { aim, t_world_body, tilt_rad }, d))
                })
                .collect();
            if let Some(frames) = frames {
                out.push(Approach { aim, excess_height_m, truth: section, frames });
                break;
            }
        }
    }
    out
}
