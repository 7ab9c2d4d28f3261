//! Radio links between robots and to the ground station, through `hal`'s link emulator:
//! range- and line-of-sight-dependent connectivity and outages (owned by the world helper).
//!
//! A link is up while its two antennas are within `max_range_m` and, if required, the straight
//! line between them clears the terrain. [`link_config`] samples that every second of the run
//! and holds each sample for the following second, turning the down periods into the emulator's
//! outages.

use hal::emulator::EmulatorConfig;
use nalgebra::Point3;

use crate::rng::{self, streams};
use crate::robot::{ROVER_CHASSIS_HEIGHT_M, RobotKind};
use crate::world::World;

/// Rovers' and the ground station's antennas are this high above the ground.
pub const ANTENNA_HEIGHT_M: f64 = 1.5;
/// A flyer's antenna sits this far above its body origin.
const FLYER_ANTENNA_M: f64 = 0.1;
/// The line of sight is checked at this spacing (a few terrain cells: ridges that block a link
/// are wider than that).
const LOS_STEP_M: f64 = 0.25;
/// Connectivity sampling period of [`link_config`].
pub const SAMPLE_PERIOD_MS: u64 = 1_000;
/// Loss added at `max_range_m` on top of the base loss (growing linearly from
/// `full_quality_range_m`).
const RANGE_LOSS_AT_MAX: f64 = 0.5;

/// Radio parameters of a scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct RadioConfig {
    /// Beyond this range (or without line of sight, if required) a link is down.
    pub max_range_m: f64,
    /// Within this range the link has only `base.loss`.
    pub full_quality_range_m: f64,
    pub require_line_of_sight: bool,
    /// Where the lander / ground-station relay stands (world x, y, height above ground).
    pub ground_station_m: [f64; 3],
    /// Bandwidth, latency, framing and base loss of every link.
    pub base: EmulatorConfig,
    /// Extra outages of every link, `[start, end)` in ms of mission time.
    pub outages_ms: Vec<(u64, u64)>,
}

/// One end of a radio link.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Endpoint {
    Robot(usize),
    GroundStation,
}

impl Endpoint {
    fn key(self) -> u64 {
        match self {
            Endpoint::Robot(i) => i as u64,
            Endpoint::GroundStation => u64::MAX,
        }
    }
}

/// World position of an endpoint's antenna at `stamp_ns` (`None` for an unknown robot or a
/// station off the terrain).
pub fn antenna_position(world: &World, endpoint: Endpoint, stamp_ns: u64) -> Option<Point3<f64>> {
    match endpoint {
        Endpoint::Robot(i) => {
            let robot = world.robots.get(i)?;
            let stamp = stamp_ns.min(robot.trajectory.end_ns());
            let state = robot.trajectory.state_at(stamp)?;
            let above = match robot.model().kind {
                RobotKind::Rover => ANTENNA_HEIGHT_M - ROVER_CHASSIS_HEIGHT_M,
                RobotKind::Flyer => FLYER_ANTENNA_M,
            };
            let p = state.t_world_body.translation.vector;
            Some(Point3::new(p.x, p.y, p.z + above))
        }
        Endpoint::GroundStation => {
            let [x, y, h] = world.scenario.radio.ground_station_m;
            let ground = world.terrain.heightfield.height_at(x, y)?;
            Some(Point3::new(x, y, ground + h.max(ANTENNA_HEIGHT_M)))
        }
    }
}

/// Whether the straight line between `a` and `b` stays above the terrain (points off the
/// terrain do not block).
pub fn line_of_sight(world: &World, a: &Point3<f64>, b: &Point3<f64>) -> bool {
    let d = (b - a).norm();
    let steps = (d / LOS_STEP_M).ceil().max(1.0) as usize;
    (1..steps).all(|k| {
        let p = a + (b - a) * (k as f64 / steps as f64);
        world.terrain.heightfield.height_at(p.x, p.y).is_none_or(|h| h < p.z)
    })
}

/// Whether the link between `a` and `b` is up at `stamp_ns`.
pub fn connectivity(world: &World, a: Endpoint, b: Endpoint, stamp_ns: u64) -> bool {
    link_range_m(world, a, b, stamp_ns).is_some()
}

/// The range of an up link at `stamp_ns`, `None` when it is down.
fn link_range_m(world: &World, a: Endpoint, b: Endpoint, stamp_ns: u64) -> Option<f64> {
    let pa = antenna_position(world, a, stamp_ns)?;
    let pb = antenna_position(world, b, stamp_ns)?;
    let radio = &world.scenario.radio;
    let range = (pb - pa).norm();
    let up = range <= radio.max_range_m && (!radio.require_line_of_sight || line_of_sight(world, &pa, &pb));
    up.then_some(range)
}

/// The emulator configuration of the link from `a` to `b` over the run: the scenario's base
/// link, outages wherever a once-a-second sample finds the link down (each sample holds until
/// the next), the scenario's extra outages, and a loss growing with the mean range of the up
/// samples beyond `full_quality_range_m`. Seeded from the scenario seed and the ordered pair, so
/// the two directions lose different packets.
pub fn link_config(world: &World, a: Endpoint, b: Endpoint) -> EmulatorConfig {
    let radio = &world.scenario.radio;
    let end_ms = world.end_ns().div_ceil(1_000_000);
    let mut outages: Vec<(u64, u64)> = Vec::new();
    let mut range_sum = 0.0;
    let mut up_samples = 0usize;
    let mut t_ms = 0;
    while t_ms < end_ms.max(1) {
        let until = t_ms + SAMPLE_PERIOD_MS;
        match link_range_m(world, a, b, t_ms * 1_000_000) {
            Some(range) => {
                range_sum += range;
                up_samples += 1;
            }
            None => match outages.last_mut() {
                Some(last) if last.1 == t_ms => last.1 = until,
                _ => outages.push((t_ms, until)),
            },
        }
        t_ms = until;
    }
    outages.extend_from_slice(&radio.outages_ms);

    let mean_range = if up_samples > 0 { range_sum / up_samples as f64 } else { 0.0 };
    let span = (radio.max_range_m - radio.full_quality_range_m).max(1e-9);
    let excess = ((mean_range - radio.full_quality_range_m) / span).clamp(0.0, 1.0);
    let base_loss = radio.base.loss.clamp(0.0, 1.0);
    let loss = 1.0 - (1.0 - base_loss) * (1.0 - RANGE_LOSS_AT_MAX * excess);

    let seed = rng::stream_seed(world.scenario.seed, &[streams::RADIO, a.key(), b.key()]);
    EmulatorConfig { loss, outages, seed, ..radio.base.clone() }
}
