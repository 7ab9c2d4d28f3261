//! Named scenarios: a site, a sun, a body, and a team with its paths (owned by the world helper).
//!
//! The team starts on a ring around the world origin, every robot facing the centre, so they see
//! each other's markers from the first frame. Each rover then explores a rosette of seeded
//! "petals": out from a hub near the origin to two points at a petal radius and back, petal
//! after petal turned by the golden angle. Every return to the hub revisits the robot's own
//! earlier map and crosses the other robots' petals, which is where loop closures come from.
//! Petals are added while the whole plan (driving, turning, pauses) fits the duration.
//! Obstacles are unknown here; [`crate::world::World::build`] repairs the paths on the generated
//! terrain.

use std::f64::consts::PI;

use crate::body::Body;
use crate::camera::StereoCamera;
use crate::imu::ImuNoise;
use crate::lighting::{Reflectance, Sun};
use crate::motion::{MotionPlan, RoverDrive};
use crate::radio::RadioConfig;
use crate::render::SensorModel;
use crate::rng::{self, Rng, streams};
use crate::robot::RobotModel;
use crate::terrain::TerrainConfig;
use crate::wheel::WheelOdomConfig;

pub mod experiments;

/// Names `preset` accepts.
pub const PRESETS: &[&str] = &["moon", "mars"];

/// Largest team (three tag36h11 markers per rover out of the 96 kept codes).
pub const MAX_ROBOTS: usize = 32;
/// Spacing of the robots on the start ring.
pub const START_SPACING_M: f64 = 3.0;
/// The start ring's smallest radius.
const MIN_RING_RADIUS_M: f64 = 3.0;
/// Radius kept clear of rocks around each start with [`ScenarioOptions::rocks_in_hub`].
const START_CLEAR_RADIUS_M: f64 = 1.5;
/// Paths keep this far inside the terrain's edge.
pub const EDGE_MARGIN_M: f64 = 3.0;
/// Smallest terrain edge a preset accepts.
pub const MIN_WORLD_SIZE_M: f64 = 20.0;
/// Head tilt while driving: the ground from about 2.7 m to the horizon's edge is in view, and
/// so are other rovers' markers (about 0.25 m below the cameras) from 2 m on.
pub const ROVER_TILT_RAD: f64 = 0.25;
/// Pan sweep amplitude while standing (the world limits it further by the pan rate).
pub const ROVER_PAN_SWEEP_RAD: f64 = 1.0;
/// Rovers' drive: LRU-like speed, a pause at each waypoint long enough for a slow look around.
pub const ROVER_DRIVE: RoverDrive = RoverDrive { speed_mps: 0.3, pause_s: 6.0, knot_interval_s: 0.1 };
/// The flyer's drive: faster, short hovers.
pub const FLYER_DRIVE: RoverDrive = RoverDrive { speed_mps: 1.0, pause_s: 2.0, knot_interval_s: 0.1 };
/// The flyer's cruise heights above ground.
const FLYER_HEIGHT_M: [f64; 2] = [3.0, 5.0];
/// Golden angle: consecutive petals never line up, so the rosette fills the circle evenly.
const GOLDEN_ANGLE_RAD: f64 = 2.399_963_229_728_653;

/// Knobs of a preset that a user or a test sets.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioOptions {
    pub robots: usize,
    pub duration_s: f64,
    pub seed: u64,
    /// Render at `1 / factor` of 1024×508 (1 = full resolution).
    pub downscale: u32,
    /// Override the preset's terrain edge length (fast tests).
    pub world_size_m: Option<f64>,
    /// Add one flyer to the team.
    pub flyer: bool,
    /// Override the preset's rock density (rocks per 100 m²; the thesis's arena and Etna
    /// boulder fields are denser than the presets' open plains).
    pub rocks_per_100m2: Option<f64>,
    /// Let the rock field cover the shared hub of the routes too (only a disc around each start
    /// and the ground station stays clear). The presets keep the hub bare so that the robots
    /// see each other from the start; the submap matcher needs rocks where the routes overlap.
    pub rocks_in_hub: bool,
}

impl Default for ScenarioOptions {
    fn default() -> Self {
        ScenarioOptions {
            robots: 2,
            duration_s: 60.0,
            seed: 1,
            downscale: 1,
            world_size_m: None,
            flyer: false,
            rocks_per_100m2: None,
            rocks_in_hub: false,
        }
    }
}

/// One robot of the team.
#[derive(Debug, Clone, PartialEq)]
pub struct RobotSetup {
    pub id: u8,
    pub name: String,
    pub model: RobotModel,
    /// World (x, y) waypoints; for a flyer the third value is the height above ground.
    pub waypoints_m: Vec<[f64; 3]>,
    pub drive: RoverDrive,
    /// Head tilt while driving (positive looks down) and the pan sweep amplitude while standing.
    pub tilt_rad: f64,
    pub pan_sweep_rad: f64,
}

/// A complete description of a run; [`crate::world::World::build`] makes it real.
#[derive(Debug, Clone, PartialEq)]
pub struct Scenario {
    pub name: String,
    pub seed: u64,
    pub body: Body,
    pub terrain: TerrainConfig,
    pub sun: Sun,
    pub reflectance: Reflectance,
    pub sky_radiance: f32,
    pub duration_s: f64,
    pub camera_rate_hz: f64,
    pub imu_rate_hz: f64,
    pub imu_noise: ImuNoise,
    pub wheel: WheelOdomConfig,
    pub sensor: SensorModel,
    pub radio: RadioConfig,
    pub robots: Vec<RobotSetup>,
}

/// Why a scenario could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ScenarioError {
    #[error("unknown scenario `{0}` (known: moon, mars, {known})", known = experiments::names().join(", "))]
    Unknown(String),
    #[error("{0}")]
    Invalid(String),
}

/// What differs between the presets.
struct Site {
    body: Body,
    terrain: TerrainConfig,
    sun: Sun,
    reflectance: Reflectance,
    sky_radiance: f32,
}

fn site(name: &str) -> Option<Site> {
    match name {
        // A low sun throws long shadows across an airless, black sky; regolith scatters close to
        // Lommel–Seeliger (McEwen's lunar-Lambert weight near 1 at moderate phase angles).
        "moon" => Some(Site {
            body: Body::Moon,
            terrain: TerrainConfig::moon(),
            sun: Sun { azimuth_rad: 150f64.to_radians(), elevation_rad: 20f64.to_radians(), irradiance: 1.0 },
            reflectance: Reflectance::LunarLambert { l: 0.9 },
            sky_radiance: 0.0,
        }),
        // A higher sun through a dusty sky that adds a dim diffuse light; dust scatters closer
        // to Lambert.
        "mars" => Some(Site {
            body: Body::Mars,
            terrain: TerrainConfig::mars(),
            sun: Sun { azimuth_rad: 210f64.to_radians(), elevation_rad: 42f64.to_radians(), irradiance: 0.6 },
            reflectance: Reflectance::LunarLambert { l: 0.3 },
            sky_radiance: 0.05,
        }),
        _ => None,
    }
}

fn validate(options: &ScenarioOptions) -> Result<(), ScenarioError> {
    if !(1..=MAX_ROBOTS).contains(&options.robots) {
        return Err(ScenarioError::Invalid(format!("robots must be 1..={MAX_ROBOTS}, got {}", options.robots)));
    }
    if !(options.duration_s.is_finite() && options.duration_s > 0.0) {
        return Err(ScenarioError::Invalid(format!("duration must be positive, got {} s", options.duration_s)));
    }
    if options.rocks_per_100m2.is_some_and(|d| !(d.is_finite() && (0.0..=100.0).contains(&d))) {
        return Err(ScenarioError::Invalid("rock density must be 0 to 100 per 100 m²".to_owned()));
    }
    if options.downscale < 1 {
        return Err(ScenarioError::Invalid("downscale must be at least 1".to_owned()));
    }
    if let Some(size) = options.world_size_m
        && !(size.is_finite() && size >= MIN_WORLD_SIZE_M)
    {
        return Err(ScenarioError::Invalid(format!("world size must be at least {MIN_WORLD_SIZE_M} m, got {size}")));
    }
    Ok(())
}

/// Radius of the start ring for `robots` robots.
pub fn ring_radius_m(robots: usize) -> f64 {
    (START_SPACING_M * robots as f64 / (2.0 * PI)).max(MIN_RING_RADIUS_M)
}

/// Start of robot `index` of `robots` on the ring (robot 0 to the west, counter-clockwise).
pub fn start_position_m(index: usize, robots: usize) -> [f64; 2] {
    let angle = PI + 2.0 * PI * index as f64 / robots as f64;
    let r = ring_radius_m(robots);
    [r * angle.cos(), r * angle.sin()]
}

/// The preset or experiment `name` with `options` (an experiment: see [`experiments`]).
pub fn preset(name: &str, options: &ScenarioOptions) -> Result<Scenario, ScenarioError> {
    if let Some(experiment) = experiments::find(name) {
        return experiments::scenario(experiment, options);
    }
    let site = site(name).ok_or_else(|| ScenarioError::Unknown(name.to_owned()))?;
    validate(options)?;
    let layout = Layout::new(site.terrain.clone(), options)?;
    let n = options.robots;
    let half_extent = layout.half_extent_m;
    let camera = StereoCamera::narrow().downscaled(options.downscale);
    // Petals grow with the distance a rover can drive, within the site.
    let petal_radius =
        (ROVER_DRIVE.speed_mps * options.duration_s * 0.5 / 6.0).clamp(2.0, (0.8 * half_extent).max(2.0));
    let mut robots = Vec::with_capacity(n + usize::from(options.flyer));
    for i in 0..n {
        let mut rng = rng::stream(options.seed, &[streams::PATHS, i as u64]);
        let start = start_position_m(i, n);
        let route = rover_route(&mut rng, start, petal_radius, half_extent, options.duration_s);
        robots.push(rover_setup(i, camera, route));
    }
    if options.flyer {
        let mut rng = rng::stream(options.seed, &[streams::PATHS, n as u64]);
        let route = flyer_route(&mut rng, layout.flyer_start_m, 1.5 * petal_radius, half_extent, options.duration_s);
        // Ardea's virtual pinholes cover about 80° horizontally on a 12 cm baseline (thesis §7.1).
        let flyer_camera =
            StereoCamera::with_hfov(crate::camera::FULL_WIDTH_PX, crate::camera::FULL_HEIGHT_PX, 80.0, 0.12)
                .downscaled(options.downscale);
        robots.push(RobotSetup {
            id: n as u8,
            name: "flyer".to_owned(),
            model: RobotModel::flyer(flyer_camera),
            waypoints_m: route,
            drive: FLYER_DRIVE,
            tilt_rad: 0.0,
            pan_sweep_rad: 0.0,
        });
    }
    Ok(assemble(name, options, site, layout, robots))
}

/// The site's terrain cleared for a team of `options.robots` (and a flyer), with the ground
/// station's place.
struct Layout {
    terrain: TerrainConfig,
    half_extent_m: f64,
    ground_station_m: [f64; 3],
    flyer_start_m: [f64; 2],
}

impl Layout {
    fn new(mut terrain: TerrainConfig, options: &ScenarioOptions) -> Result<Layout, ScenarioError> {
        if let Some(size) = options.world_size_m {
            terrain = terrain.with_size(size);
        }
        if let Some(density) = options.rocks_per_100m2 {
            terrain.rocks_per_100m2 = density;
        }
        let half_extent_m = 0.5 * terrain.size_m[0].min(terrain.size_m[1]) - EDGE_MARGIN_M;
        let n = options.robots;
        let ring = ring_radius_m(n);
        let ground_station_m = [0.0, -(ring + 4.0), 2.0];
        let flyer_start_m = [0.0, ring + 3.0];
        if ring + 4.0 > half_extent_m {
            return Err(ScenarioError::Invalid(format!(
                "a team of {n} needs a world of at least {:.0} m",
                2.0 * (ring + 4.0 + EDGE_MARGIN_M)
            )));
        }
        terrain = if options.rocks_in_hub {
            (0..n).fold(terrain, |t, i| t.with_clear_area(start_position_m(i, n), START_CLEAR_RADIUS_M))
        } else {
            terrain.with_clear_area([0.0, 0.0], ring + 2.5)
        };
        terrain = terrain.with_clear_area([ground_station_m[0], ground_station_m[1]], 2.0);
        if options.flyer {
            terrain = terrain.with_clear_area(flyer_start_m, 2.0);
        }
        Ok(Layout { terrain, half_extent_m, ground_station_m, flyer_start_m })
    }
}

/// Rover `index` of the team with `camera` on its head, driving `waypoints_m`.
fn rover_setup(index: usize, camera: StereoCamera, waypoints_m: Vec<[f64; 3]>) -> RobotSetup {
    RobotSetup {
        id: index as u8,
        name: format!("rover{index}"),
        model: RobotModel::rover(index as u32, camera),
        waypoints_m,
        drive: ROVER_DRIVE,
        tilt_rad: ROVER_TILT_RAD,
        pan_sweep_rad: ROVER_PAN_SWEEP_RAD,
    }
}

fn assemble(name: &str, options: &ScenarioOptions, site: Site, layout: Layout, robots: Vec<RobotSetup>) -> Scenario {
    Scenario {
        name: name.to_owned(),
        seed: options.seed,
        body: site.body,
        terrain: layout.terrain,
        sun: site.sun,
        reflectance: site.reflectance,
        sky_radiance: site.sky_radiance,
        duration_s: options.duration_s,
        camera_rate_hz: 10.0,
        imu_rate_hz: 200.0,
        imu_noise: ImuNoise::xsens_mti10(),
        wheel: WheelOdomConfig::default(),
        sensor: SensorModel::default(),
        radio: RadioConfig {
            max_range_m: 150.0,
            full_quality_range_m: 50.0,
            require_line_of_sight: true,
            ground_station_m: layout.ground_station_m,
            base: hal::emulator::EmulatorConfig::lossy_wifi(),
            outages_ms: Vec::new(),
        },
        robots,
    }
}

fn clamp_to(p: [f64; 2], half_extent: f64) -> [f64; 2] {
    [p[0].clamp(-half_extent, half_extent), p[1].clamp(-half_extent, half_extent)]
}

fn towards(from: [f64; 2], to: [f64; 2], distance: f64) -> [f64; 2] {
    let (dx, dy) = (to[0] - from[0], to[1] - from[1]);
    let d = dx.hypot(dy);
    if d < 1e-9 { from } else { [from[0] + dx / d * distance, from[1] + dy / d * distance] }
}

/// Petal `k` of a rosette: two outer points and the next hub visit.
fn petal(rng: &mut Rng, theta: f64, radius_m: f64, half_extent: f64) -> [[f64; 2]; 3] {
    let hub = [rng.range(-1.5, 1.5), rng.range(-1.5, 1.5)];
    let r = radius_m * rng.range(0.7, 1.0);
    let half_width = rng.range(0.35, 0.6);
    let outer = |a: f64| clamp_to([hub[0] + r * a.cos(), hub[1] + r * a.sin()], half_extent);
    let back = [rng.range(-1.5, 1.5), rng.range(-1.5, 1.5)];
    [outer(theta - half_width), outer(theta + half_width), back]
}

/// A rover's rosette from `start`: a metre towards the centre (so it starts facing it), then
/// petals while the plan fits `duration_s`.
fn rover_route(rng: &mut Rng, start: [f64; 2], radius_m: f64, half_extent: f64, duration_s: f64) -> Vec<[f64; 3]> {
    let first = towards(start, [0.0, 0.0], 1.0);
    let mut route = vec![start, first];
    // The first petal lies across the hub from the start.
    let base = start[1].atan2(start[0]) + PI + rng.range(-0.3, 0.3);
    let fits = |route: &[[f64; 2]]| MotionPlan::rover(route, &ROVER_DRIVE).is_ok_and(|p| p.end_s() <= duration_s);
    'petals: for k in 0..10_000 {
        for p in petal(rng, base + k as f64 * GOLDEN_ANGLE_RAD, radius_m, half_extent) {
            route.push(p);
            if !fits(&route) {
                route.pop();
                break 'petals;
            }
        }
    }
    route.into_iter().map(|p| [p[0], p[1], 0.0]).collect()
}

/// The flyer's rosette at cruise heights from `start`: petals while the flight (take-off and
/// landing included) fits `duration_s`.
fn flyer_route(rng: &mut Rng, start: [f64; 2], radius_m: f64, half_extent: f64, duration_s: f64) -> Vec<[f64; 3]> {
    let height = |rng: &mut Rng| rng.range(FLYER_HEIGHT_M[0], FLYER_HEIGHT_M[1]);
    let h0 = height(rng);
    let mut route = vec![[start[0], start[1], h0], [0.0, 0.0, h0]];
    let base = rng.range(0.0, 2.0 * PI);
    let fits = |route: &[[f64; 3]]| MotionPlan::flyer(route, &FLYER_DRIVE).is_ok_and(|p| p.end_s() <= duration_s);
    'petals: for k in 0..10_000 {
        for p in petal(rng, base + k as f64 * GOLDEN_ANGLE_RAD, radius_m, half_extent) {
            let h = height(rng);
            route.push([p[0], p[1], h]);
            if !fits(&route) {
                route.pop();
                break 'petals;
            }
        }
    }
    route
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn options_are_validated() {
        let ok = ScenarioOptions::default();
        assert!(preset("moon", &ok).is_ok());
        assert!(matches!(preset("venus", &ok), Err(ScenarioError::Unknown(_))));
        for bad in [
            ScenarioOptions { robots: 0, ..ok.clone() },
            ScenarioOptions { robots: 33, ..ok.clone() },
            ScenarioOptions { duration_s: 0.0, ..ok.clone() },
            ScenarioOptions { duration_s: f64::NAN, ..ok.clone() },
            ScenarioOptions { downscale: 0, ..ok.clone() },
            ScenarioOptions { world_size_m: Some(5.0), ..ok.clone() },
        ] {
            assert!(matches!(preset("mars", &bad), Err(ScenarioError::Invalid(_))), "{bad:?}");
        }
    }

    #[test]
    fn rocks_in_hub_fill_the_hub_and_spare_the_starts() {
        let options = ScenarioOptions { world_size_m: Some(30.0), rocks_per_100m2: Some(12.0), ..Default::default() };
        let hub_radius = ring_radius_m(options.robots) + 2.5;
        let rocks_within = |scenario: &Scenario, centre: [f64; 2], radius: f64| {
            let terrain = crate::terrain::Terrain::generate(&scenario.terrain, scenario.seed);
            terrain
                .rocks
                .iter()
                .filter(|r| (r.base_m.x - centre[0]).hypot(r.base_m.y - centre[1]) < radius + r.radius_m)
                .count()
        };
        let bare = preset("mars", &options).unwrap();
        assert_eq!(rocks_within(&bare, [0.0, 0.0], hub_radius), 0);
        let rocky = preset("mars", &ScenarioOptions { rocks_in_hub: true, ..options.clone() }).unwrap();
        let in_hub = rocks_within(&rocky, [0.0, 0.0], hub_radius);
        // 12 per 100 m² over the hub's ~100 m², less the starts' discs.
        assert!(in_hub >= 5, "{in_hub} rocks in the hub");
        for i in 0..options.robots {
            assert_eq!(rocks_within(&rocky, start_position_m(i, options.robots), START_CLEAR_RADIUS_M), 0);
        }
    }

    #[test]
    fn routes_fit_the_duration_and_stay_inside() {
        let options = ScenarioOptions {
            robots: 3,
            duration_s: 300.0,
            world_size_m: Some(60.0),
            flyer: true,
            ..Default::default()
        };
        let s = preset("moon", &options).unwrap();
        assert_eq!(s.robots.len(), 4);
        for r in &s.robots {
            let route: Vec<[f64; 2]> = r.waypoints_m.iter().map(|w| [w[0], w[1]]).collect();
            let end = if r.model.head.is_some() {
                MotionPlan::rover(&route, &r.drive).unwrap().end_s()
            } else {
                MotionPlan::flyer(&r.waypoints_m, &r.drive).unwrap().end_s()
            };
            assert!(end <= 300.0 && end > 200.0, "{}: plan ends at {end} s", r.name);
            assert!(r.waypoints_m.iter().all(|w| w[0].abs() <= 27.0 && w[1].abs() <= 27.0));
        }
        // Same seed, same plan; another seed, another.
        assert_eq!(preset("moon", &options).unwrap(), s);
        assert_ne!(preset("moon", &ScenarioOptions { seed: 2, ..options }).unwrap().robots, s.robots);
    }
}
