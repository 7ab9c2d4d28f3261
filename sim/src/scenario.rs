//! Named scenarios: a site, a sun, a body, and a team with its paths (owned by the world helper).

use crate::body::Body;
use crate::imu::ImuNoise;
use crate::lighting::{Reflectance, Sun};
use crate::motion::RoverDrive;
use crate::radio::RadioConfig;
use crate::render::SensorModel;
use crate::robot::RobotModel;
use crate::terrain::TerrainConfig;
use crate::wheel::WheelOdomConfig;

/// Names `preset` accepts.
pub const PRESETS: &[&str] = &["moon", "mars"];

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
}

impl Default for ScenarioOptions {
    fn default() -> Self {
        ScenarioOptions { robots: 2, duration_s: 60.0, seed: 1, downscale: 1, world_size_m: None, flyer: false }
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
    #[error("unknown scenario `{0}` (known: moon, mars)")]
    Unknown(String),
    #[error("{0}")]
    Invalid(String),
}

/// The preset `name` with `options`.
pub fn preset(name: &str, options: &ScenarioOptions) -> Result<Scenario, ScenarioError> {
    let _ = options;
    Err(ScenarioError::Unknown(name.to_owned()))
}
