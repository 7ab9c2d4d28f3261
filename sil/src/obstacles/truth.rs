//! The true obstacles of a world: rocks taller than `h_max` and the negative obstacles' edges as
//! discs, and the Moon worlds they come from.

use std::sync::Arc;

use eval::map::TrueObstacle;
use nalgebra::Point2;
use sim::scenario::{ScenarioOptions, preset};
use sim::world::World;

use super::EvaluationError;

/// Negative-obstacle edges become discs of this radius every [`EDGE_SPACING_M`] along the edge.
const EDGE_DISC_M: f64 = 0.1;
const EDGE_SPACING_M: f64 = 0.25;
/// Edge targets are taken every this far along a negative obstacle's edge.
const EDGE_TARGET_SPACING_M: f64 = 3.0;

/// The listed true obstacles of one world.
#[derive(Debug, Clone)]
pub struct Truth {
    /// Rocks taller than `h_max`, with their heights.
    pub rocks: Vec<(TrueObstacle, f64)>,
    /// The negative obstacles' edges as discs of 0.1 m every 0.25 m.
    pub edges: Vec<TrueObstacle>,
    /// Points along the edges where edge viewpoints aim.
    pub edge_targets: Vec<Point2<f64>>,
}

impl Truth {
    /// The rocks of `world` taller than `max_step_m`, and its negative obstacles' edges with an
    /// edge target every 3 m along them.
    pub fn of(world: &World, max_step_m: f64) -> Truth {
        let rocks = world
            .terrain
            .rocks
            .iter()
            .filter(|r| r.height_m > max_step_m)
            .map(|r| (TrueObstacle { centre_m: Point2::new(r.base_m.x, r.base_m.y), radius_m: r.radius_m }, r.height_m))
            .collect();
        let mut edges = Vec::new();
        let mut edge_targets = Vec::new();
        for obstacle in world.terrain.negative_obstacles() {
            let mut along_m = 0.0;
            for segment in obstacle.edge_m.windows(2) {
                let (a, b) = (Point2::from(segment[0]), Point2::from(segment[1]));
                let length = (b - a).norm();
                let steps = (length / EDGE_SPACING_M).ceil().max(1.0) as usize;
                for k in 0..steps {
                    let centre_m = a + (b - a) * (k as f64 / steps as f64);
                    edges.push(TrueObstacle { centre_m, radius_m: EDGE_DISC_M });
                    let s = along_m + length * k as f64 / steps as f64;
                    if edge_targets.is_empty() || s.rem_euclid(EDGE_TARGET_SPACING_M) < length / steps as f64 {
                        edge_targets.push(centre_m);
                    }
                }
                along_m += length;
            }
        }
        Truth { rocks, edges, edge_targets }
    }

    /// Keeps only the edge discs where the true ground falls at least `min_drop_m` below the
    /// disc's centre within 1 m in some direction (the "≥ 0.3 m drop" sections).
    pub fn keep_drops(&mut self, world: &World, min_drop_m: f64) {
        self.edges.retain(|o| ground_falls(world, o.centre_m, |drop_m, _| drop_m >= min_drop_m));
        let edges = &self.edges;
        self.edge_targets.retain(|t| edges.iter().any(|o| (o.centre_m - t).norm() <= 1e-9));
    }

    /// Keeps only the edge discs where the true ground drops by more than `max_step_m` at a mean
    /// slope steeper than `max_slope_rad` (within 1 m, in any of 16 directions from the disc
    /// centre): the cliffs the rover can neither step nor drive down. The sim's crater-edge rule
    /// (0.3 m within 1 m of the crest, 17°) also lists rims the slope limit lets the rover descend.
    pub fn keep_steep_edges(&mut self, world: &World, max_step_m: f64, max_slope_rad: f64) {
        let slope = max_slope_rad.tan();
        self.edges.retain(|o| {
            ground_falls(world, o.centre_m, |drop_m, distance_m| drop_m > max_step_m && drop_m > slope * distance_m)
        });
        let edges = &self.edges;
        self.edge_targets.retain(|t| edges.iter().any(|o| (o.centre_m - t).norm() <= 1e-9));
    }
}

/// Whether the true ground, sampled every 0.05 m out to 1 m in 16 directions from `p`, falls
/// below `p` somewhere by a drop `falls(drop_m, distance_m)` accepts.
pub(super) fn ground_falls(world: &World, p: Point2<f64>, falls: impl Fn(f64, f64) -> bool) -> bool {
    let hf = &world.terrain.heightfield;
    let Some(top) = hf.height_at(p.x, p.y) else { return false };
    (0..16).any(|k| {
        let (s, c) = (k as f64 * std::f64::consts::TAU / 16.0).sin_cos();
        (1..=20).any(|i| {
            let d = 0.05 * i as f64;
            hf.height_at(p.x + c * d, p.y + s * d).is_some_and(|z| falls(top - z, d))
        })
    })
}

/// The Moon preset's world for `seed` on a square of `size_m`.
pub fn moon_world(seed: u64, size_m: f64) -> Result<Arc<World>, EvaluationError> {
    preset_world("moon", seed, size_m)
}

/// The world of scenario preset `name` (`moon`, `mars`) for `seed` on a square of `size_m`.
pub fn preset_world(name: &str, seed: u64, size_m: f64) -> Result<Arc<World>, EvaluationError> {
    let options = ScenarioOptions {
        robots: 1,
        duration_s: 20.0,
        seed,
        downscale: 1,
        world_size_m: Some(size_m),
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    Ok(World::build(&preset(name, &options)?)?)
}
