//! Radio links between robots and to the ground station, through `hal`'s link emulator:
//! range- and line-of-sight-dependent connectivity and outages (owned by the world helper).

use hal::emulator::EmulatorConfig;

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
