//! Named two-robot experiments in the manner of the thesis's multi-robot evaluation (§8.3.2,
//! Tab. 8.8: five LRU experiments; §8.3.1, Tab. 8.7: a pair with different cameras).
//!
//! The thesis's robots were driven by hand through a lab, its entrance and hallways. Here each
//! route is a designed loop of corners: the robots start facing each other on the start ring
//! (they detect each other's markers at once, as the thesis's robots did when they met), drive
//! loops that share a central corridor in opposite directions at different times (inter-robot
//! matches need the same ground seen by both), come back past their own start (intra-robot
//! matches), and end near the start ring, where they meet again. The seed moves every corner by
//! up to [`CORNER_JITTER_M`], so seeds give different but equally shaped runs. Rocks cover the
//! shared area too: the submap matcher needs obstacle keypoints where the paths overlap.
//!
//! Corner coordinates are world metres, x east, y north; robot 0 starts west of the origin,
//! robot 1 east (see [`super::start_position_m`]).

use super::{
    Layout, ROVER_DRIVE, RobotSetup, Scenario, ScenarioError, ScenarioOptions, assemble, rover_setup, site,
    start_position_m, towards, validate,
};
use crate::camera::StereoCamera;
use crate::motion::{MotionPlan, RoverDrive};
use crate::rng::{self, streams};

/// How far the seed moves each designed corner, per axis.
pub const CORNER_JITTER_M: f64 = 1.0;

/// Heights of the experiments' rocks (m) and the exponent of their power law. The presets'
/// rocks are mostly 0.1–0.15 m (at most a few in 100 m² stand above the obstacle classifier's
/// `h_max` = 0.15 m), so nearly every submap failed the matcher's size check (< 100 obstacle
/// points) or its descriptiveness check: measured on `lab-rocks` at half resolution, 29 of 30
/// submaps unsuitable. The thesis's experiments had large rocks in the lab and walls in the
/// hallways; here a boulder field stands in for them (half of the rocks are drawn taller than
/// 0.3 m; fewer of those fit beside the routes).
pub const BOULDER_HEIGHT_M: [f64; 2] = [0.2, 0.9];
pub const BOULDER_SIZE_EXPONENT: f64 = 1.5;

/// Half-width of the corridor along each route kept free of rocks, craters and ditches: the
/// thesis's robots were driven around obstacles, ours follow straight legs, and a rover
/// climbing a 0.5 m boulder would be neither realistic nor what the experiment is about.
pub const ROUTE_CLEAR_RADIUS_M: f64 = 1.0;

/// The rovers' drive in the experiments: the LRU's speed, a short stop at each corner (the
/// pan sweep of a stand would eat the time budget of a hand-driven run).
pub const EXPERIMENT_DRIVE: RoverDrive = RoverDrive { pause_s: 1.0, ..ROVER_DRIVE };

/// Which of the two stereo heads a robot carries (thesis Tab. 8.7: P3AT and P3DX).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Camera {
    /// 50.6° horizontal field of view, the LRU's.
    Narrow,
    /// 112.8° horizontal field of view.
    Wide,
}

/// One robot's part in an experiment: corners of a loop, driven `laps` times.
#[derive(Debug, Clone, Copy)]
pub struct RouteDesign {
    pub corners_m: &'static [[f64; 2]],
    pub laps: u32,
    pub camera: Camera,
}

/// A named experiment.
#[derive(Debug, Clone, Copy)]
pub struct Experiment {
    pub name: &'static str,
    /// `moon` or `mars`.
    pub site: &'static str,
    /// What the thesis's experiment was that this one is modelled on.
    pub after: &'static str,
    pub summary: &'static str,
    pub duration_s: f64,
    pub seed: u64,
    pub rocks_per_100m2: f64,
    pub routes: [RouteDesign; 2],
}

const NARROW: Camera = Camera::Narrow;

/// The experiments, in the thesis's order.
pub const EXPERIMENTS: &[Experiment] = &[
    Experiment {
        name: "lab-rocks",
        site: "moon",
        after: "Tab. 8.8 #1 (lab with three large rocks)",
        summary: "both rovers circle a small rock field in opposite directions, rover0 twice",
        duration_s: 300.0,
        seed: 11,
        rocks_per_100m2: 15.0,
        routes: [
            RouteDesign { corners_m: &[[-4.0, -4.0], [4.0, -4.0], [4.0, 4.0], [-4.0, 4.0]], laps: 2, camera: NARROW },
            RouteDesign { corners_m: &[[7.5, 7.5], [-7.5, 7.5], [-7.5, -7.5], [7.5, -7.5]], laps: 1, camera: NARROW },
        ],
    },
    Experiment {
        name: "loops",
        site: "moon",
        after: "Tab. 8.8 #2 (one large loop each through lab, entrance and hallways)",
        summary: "one large loop each, west and east, sharing the central corridor",
        duration_s: 600.0,
        seed: 12,
        rocks_per_100m2: 15.0,
        routes: [
            RouteDesign {
                corners_m: &[[2.0, 0.0], [2.0, 20.0], [-30.0, 20.0], [-30.0, -20.0], [-2.0, -20.0], [-2.0, -3.0]],
                laps: 1,
                camera: NARROW,
            },
            RouteDesign {
                corners_m: &[[-2.0, 0.0], [-2.0, -20.0], [30.0, -20.0], [30.0, 20.0], [2.0, 20.0], [2.0, 3.0]],
                laps: 1,
                camera: NARROW,
            },
        ],
    },
    Experiment {
        name: "loops-mars",
        site: "mars",
        after: "Tab. 8.8 #3 (like #2, other trajectories)",
        summary: "one large loop each, north and south, sharing the central corridor",
        duration_s: 600.0,
        seed: 13,
        rocks_per_100m2: 15.0,
        routes: [
            RouteDesign {
                corners_m: &[[0.0, 2.0], [-18.0, 2.0], [-18.0, 28.0], [18.0, 28.0], [18.0, -2.0], [-2.0, -2.0]],
                laps: 1,
                camera: NARROW,
            },
            RouteDesign {
                corners_m: &[[0.0, -2.0], [18.0, -2.0], [18.0, -28.0], [-18.0, -28.0], [-18.0, 2.0], [2.0, 2.0]],
                laps: 1,
                camera: NARROW,
            },
        ],
    },
    Experiment {
        name: "double-loop",
        site: "mars",
        after: "Tab. 8.8 #4 (like #2, LRU2 driving two loops through the central lab)",
        summary: "rover0 one large loop to the west; rover1 two loops through the central area",
        duration_s: 640.0,
        seed: 14,
        rocks_per_100m2: 15.0,
        routes: [
            RouteDesign {
                corners_m: &[[2.0, 0.0], [2.0, 22.0], [-32.0, 22.0], [-32.0, -22.0], [-2.0, -22.0], [-2.0, -3.0]],
                laps: 1,
                camera: NARROW,
            },
            RouteDesign {
                corners_m: &[[-2.0, 0.0], [-2.0, -12.0], [12.0, -12.0], [12.0, 12.0], [2.0, 12.0], [2.0, 3.0]],
                laps: 2,
                camera: NARROW,
            },
        ],
    },
    Experiment {
        name: "leave-reenter",
        site: "moon",
        after: "Tab. 8.8 #5 (LRU2 leaving and re-entering the building twice)",
        summary: "rover0 two loops in the central area; rover1 two loops that leave it 30 m to the east",
        duration_s: 720.0,
        seed: 15,
        rocks_per_100m2: 15.0,
        routes: [
            RouteDesign {
                corners_m: &[[2.0, 0.0], [2.0, 12.0], [-14.0, 12.0], [-14.0, -12.0], [-2.0, -12.0], [-2.0, -3.0]],
                laps: 2,
                camera: NARROW,
            },
            RouteDesign {
                corners_m: &[[-2.0, 0.0], [-2.0, -8.0], [30.0, -8.0], [30.0, 8.0], [2.0, 8.0], [2.0, 3.0]],
                laps: 2,
                camera: NARROW,
            },
        ],
    },
    Experiment {
        name: "hetero-cameras",
        site: "mars",
        after: "Tab. 8.7 (two robots with different stereo cameras)",
        summary: "narrow (50.6°) and wide (112.8°) cameras on loops sharing the central corridor",
        duration_s: 450.0,
        seed: 16,
        rocks_per_100m2: 15.0,
        routes: [
            RouteDesign {
                corners_m: &[[2.0, 0.0], [2.0, 14.0], [-20.0, 14.0], [-20.0, -14.0], [-2.0, -14.0], [-2.0, -3.0]],
                laps: 1,
                camera: Camera::Narrow,
            },
            RouteDesign {
                corners_m: &[[-2.0, 0.0], [-2.0, -14.0], [20.0, -14.0], [20.0, 14.0], [2.0, 14.0], [2.0, 3.0]],
                laps: 1,
                camera: Camera::Wide,
            },
        ],
    },
];

/// The experiment called `name`.
pub fn find(name: &str) -> Option<&'static Experiment> {
    EXPERIMENTS.iter().find(|e| e.name == name)
}

/// Every experiment's name.
pub fn names() -> Vec<&'static str> {
    EXPERIMENTS.iter().map(|e| e.name).collect()
}

/// `experiment` as a scenario. Its routes are designed for its own duration: a shorter
/// `options.duration_s` runs the beginning of it, in a longer one the rovers stand at the end.
/// `options.robots` must be 2; its rock density overrides the experiment's; the hub always has
/// rocks.
pub fn scenario(experiment: &Experiment, options: &ScenarioOptions) -> Result<Scenario, ScenarioError> {
    let site = site(experiment.site).ok_or_else(|| ScenarioError::Unknown(experiment.site.to_owned()))?;
    validate(options)?;
    if options.robots != 2 {
        return Err(ScenarioError::Invalid(format!(
            "experiment `{}` is for 2 robots, got {}",
            experiment.name, options.robots
        )));
    }
    if options.flyer {
        return Err(ScenarioError::Invalid(format!("experiment `{}` has no flyer", experiment.name)));
    }
    let layout_options = ScenarioOptions {
        rocks_per_100m2: Some(options.rocks_per_100m2.unwrap_or(experiment.rocks_per_100m2)),
        rocks_in_hub: true,
        ..options.clone()
    };
    let mut terrain = site.terrain.clone();
    terrain.rock_height_m = BOULDER_HEIGHT_M;
    terrain.rock_size_exponent = BOULDER_SIZE_EXPONENT;
    let mut layout = Layout::new(terrain, &layout_options)?;
    let mut robots = Vec::with_capacity(2);
    for (i, design) in experiment.routes.iter().enumerate() {
        let route = design_route(design, i, options.seed, layout.half_extent_m);
        layout.terrain.keep_clear_m.extend(corridor_discs(&route, ROUTE_CLEAR_RADIUS_M));
        let camera = match design.camera {
            Camera::Narrow => StereoCamera::narrow(),
            Camera::Wide => StereoCamera::wide(),
        };
        let setup =
            RobotSetup { drive: EXPERIMENT_DRIVE, ..rover_setup(i, camera.downscaled(options.downscale), route) };
        robots.push(setup);
    }
    Ok(assemble(experiment.name, &layout_options, site, layout, robots))
}

/// Robot `index`'s route: from its start a metre towards the centre (it starts facing the other
/// robot), the loop's corners `laps` times (each corner jittered once, the same on every lap),
/// and back to the start ring.
fn design_route(design: &RouteDesign, index: usize, seed: u64, half_extent_m: f64) -> Vec<[f64; 3]> {
    let mut rng = rng::stream(seed, &[streams::PATHS, index as u64]);
    let start = start_position_m(index, 2);
    let corners: Vec<[f64; 2]> = design
        .corners_m
        .iter()
        .map(|c| {
            let x = c[0] + rng.range(-CORNER_JITTER_M, CORNER_JITTER_M);
            let y = c[1] + rng.range(-CORNER_JITTER_M, CORNER_JITTER_M);
            [x.clamp(-half_extent_m, half_extent_m), y.clamp(-half_extent_m, half_extent_m)]
        })
        .collect();
    let mut route = vec![start, towards(start, [0.0, 0.0], 1.0)];
    for _ in 0..design.laps {
        route.extend_from_slice(&corners);
    }
    route.push(towards(start, [0.0, 0.0], 0.5));
    route.into_iter().map(|p| [p[0], p[1], 0.0]).collect()
}

/// Discs of `radius_m`, centred every `radius_m` along each leg of `waypoints_m`: they cover a
/// corridor at least `radius_m·√3/2` wide on each side of the route.
fn corridor_discs(waypoints_m: &[[f64; 3]], radius_m: f64) -> Vec<([f64; 2], f64)> {
    let mut discs = Vec::new();
    for leg in waypoints_m.windows(2) {
        let (a, b) = (leg[0], leg[1]);
        let steps = ((b[0] - a[0]).hypot(b[1] - a[1]) / radius_m).ceil().max(1.0) as usize;
        for k in 0..=steps {
            let t = k as f64 / steps as f64;
            discs.push(([a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])], radius_m));
        }
    }
    discs
}

/// Length of a rover route in the plane (m).
pub fn route_length_m(waypoints_m: &[[f64; 3]]) -> f64 {
    waypoints_m.windows(2).map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1])).sum()
}

/// When the rover's plan of `setup` ends (s), if it can be planned.
pub fn plan_end_s(setup: &RobotSetup) -> Option<f64> {
    let route: Vec<[f64; 2]> = setup.waypoints_m.iter().map(|w| [w[0], w[1]]).collect();
    MotionPlan::rover(&route, &setup.drive).ok().map(|p| p.end_s())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn options(experiment: &Experiment) -> ScenarioOptions {
        ScenarioOptions { duration_s: experiment.duration_s, seed: experiment.seed, ..ScenarioOptions::default() }
    }

    #[test]
    fn every_experiment_fits_its_duration_and_the_issue_s_distances() {
        for e in EXPERIMENTS {
            let s = super::super::preset(e.name, &options(e)).unwrap();
            assert_eq!(s.name, e.name);
            assert!((300.0..=900.0).contains(&e.duration_s), "{}", e.name);
            for r in &s.robots {
                let end = plan_end_s(r).unwrap();
                let length = route_length_m(&r.waypoints_m);
                // The plan must end inside the run, and not so early that the rover idles.
                assert!(end <= e.duration_s && end >= 0.8 * e.duration_s, "{} {}: ends {end:.0} s", e.name, r.name);
                assert!((45.0..=200.0).contains(&length), "{} {}: {length:.0} m", e.name, r.name);
            }
        }
    }

    /// Points every 0.5 m along the legs `legs` of a route.
    fn sampled(waypoints_m: &[[f64; 3]], legs: std::ops::Range<usize>) -> Vec<[f64; 2]> {
        let mut points = Vec::new();
        for w in &waypoints_m[legs.start..=legs.end].windows(2).collect::<Vec<_>>() {
            let steps = ((w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]) / 0.5).ceil().max(1.0) as usize;
            for k in 0..=steps {
                let t = k as f64 / steps as f64;
                points.push([w[0][0] + t * (w[1][0] - w[0][0]), w[0][1] + t * (w[1][1] - w[0][1])]);
            }
        }
        points
    }

    fn closest_m(a: &[[f64; 2]], b: &[[f64; 2]]) -> f64 {
        a.iter().flat_map(|p| b.iter().map(move |q| (p[0] - q[0]).hypot(p[1] - q[1]))).fold(f64::INFINITY, f64::min)
    }

    #[test]
    fn the_routes_share_ground_and_revisit_the_start() {
        for e in EXPERIMENTS {
            let s = super::super::preset(e.name, &options(e)).unwrap();
            let last = |r: &RobotSetup| r.waypoints_m.len() - 1;
            // The loops proper: without the legs from and back to the start ring, where the robots
            // see each other anyway.
            let loops: Vec<Vec<[f64; 2]>> = s.robots.iter().map(|r| sampled(&r.waypoints_m, 2..last(r) - 1)).collect();
            let shared = closest_m(&loops[0], &loops[1]);
            assert!(shared < 4.0, "{}: the loops come no closer than {shared:.1} m", e.name);
            for r in &s.robots {
                let start = [r.waypoints_m[0][0], r.waypoints_m[0][1]];
                let end = r.waypoints_m[last(r)];
                assert!(
                    (end[0] - start[0]).hypot(end[1] - start[1]) < 2.0,
                    "{} {} ends away from its start",
                    e.name,
                    r.name
                );
            }
        }
    }

    #[test]
    fn seeds_move_corners_and_options_are_checked() {
        let e = find("loops").unwrap();
        let a = super::super::preset(e.name, &options(e)).unwrap();
        assert_eq!(a, super::super::preset(e.name, &options(e)).unwrap());
        let b = super::super::preset(e.name, &ScenarioOptions { seed: 99, ..options(e) }).unwrap();
        assert_ne!(a.robots[0].waypoints_m, b.robots[0].waypoints_m);
        // The beginning of an experiment is the same route; another team is refused.
        let short = super::super::preset(e.name, &ScenarioOptions { duration_s: 30.0, ..options(e) }).unwrap();
        assert_eq!(short.robots, a.robots);
        assert_eq!(short.duration_s, 30.0);
        for bad in [ScenarioOptions { robots: 3, ..options(e) }, ScenarioOptions { flyer: true, ..options(e) }] {
            assert!(matches!(super::super::preset(e.name, &bad), Err(ScenarioError::Invalid(_))), "{bad:?}");
        }
    }

    /// Distance from `p` to the segment `a`–`b` in the plane.
    fn to_segment_m(p: [f64; 2], a: [f64; 3], b: [f64; 3]) -> f64 {
        let (dx, dy) = (b[0] - a[0], b[1] - a[1]);
        let t = (((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / (dx * dx + dy * dy).max(1e-12)).clamp(0.0, 1.0);
        (p[0] - a[0] - t * dx).hypot(p[1] - a[1] - t * dy)
    }

    #[test]
    fn boulders_stand_beside_the_routes_and_fill_the_shared_area() {
        let e = find("lab-rocks").unwrap();
        let s = super::super::preset(e.name, &ScenarioOptions { world_size_m: Some(40.0), ..options(e) }).unwrap();
        let terrain = crate::terrain::Terrain::generate(&s.terrain, s.seed);
        let corridor_m = ROUTE_CLEAR_RADIUS_M * 3f64.sqrt() / 2.0;
        for r in &s.robots {
            for leg in r.waypoints_m.windows(2) {
                for rock in &terrain.rocks {
                    let d = to_segment_m([rock.base_m.x, rock.base_m.y], leg[0], leg[1]);
                    assert!(d >= rock.radius_m + corridor_m - 1e-9, "rock {} on {}'s route: {d:.2} m", rock.id, r.name);
                }
            }
        }
        // The routes' 20 m × 20 m: enough rocks above the classifier's h_max (0.15 m) that a
        // submap sees several apart (keypoints off one line). Half are drawn above 0.3 m, but
        // large ones fit beside the corridors less often (seed 11: 9 of 34).
        let shared: Vec<_> =
            terrain.rocks.iter().filter(|r| r.base_m.x.abs() < 10.0 && r.base_m.y.abs() < 10.0).collect();
        let tall = shared.iter().filter(|r| r.height_m > 0.3).count();
        assert!(shared.iter().all(|r| (BOULDER_HEIGHT_M[0]..=BOULDER_HEIGHT_M[1]).contains(&r.height_m)));
        assert!(shared.len() >= 25 && tall >= 6, "{} rocks, {tall} above 0.3 m", shared.len());
    }

    #[test]
    fn the_heterogeneous_pair_carries_both_cameras() {
        let e = find("hetero-cameras").unwrap();
        let s = super::super::preset(e.name, &options(e)).unwrap();
        let hfov: Vec<f64> = s.robots.iter().map(|r| r.model.camera.hfov_rad().to_degrees()).collect();
        assert!((hfov[0] - 50.6).abs() < 0.05 && (hfov[1] - 112.8).abs() < 0.05, "{hfov:?}");
    }
}
