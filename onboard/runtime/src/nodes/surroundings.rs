//! The vision process's view of the rover's surroundings: the rolling local obstacle map that a
//! planner reads (thesis §5.1.1, [`vision::obstacles::LocalObstacleMap`]), its hazard cells for
//! the ground station, and the gaze policy that points the head ([`super::gaze`]).
//!
//! The map is in the filter's current local frame, centred on the body; every classified pair
//! is blended in at its capture stamp. A frame switch moves the map into the new frame
//! ([`LocalObstacleMap::reframe`]) instead of forgetting what was just seen. About once a second
//! the hazard cells go out as one [`HazardCellsMsg`], the nearest first.

use msgs::{HAZARD_CELLS_MAX, HazardCellsMsg, HeadCommandMsg, Pose};
use nalgebra::Isometry3;
use vision::obstacles::{HeightMap, LocalObstacleMap, ObstacleConfig};

use super::gaze::{GazeOptions, GazePolicy};
use super::{Message, NodeError, Outbox};

/// 10 m × 10 m of 5 cm cells around the body: twice the classifier's 4.5 m range cutoff.
const MAP_SIDE_CELLS: usize = 200;
/// The thesis's low-pass (see [`LocalObstacleMap`]).
const MAP_TIME_CONSTANT_S: f64 = 0.5;
const HAZARDS_PERIOD_NS: u64 = 1_000_000_000;
/// The yaw rate is measured over filter states at least this far apart.
const YAW_RATE_BASE_NS: u64 = 100_000_000;

/// Counters for the mission report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SurroundingsSummary {
    pub pairs_mapped: u64,
    pub hazard_messages: u64,
    /// Hazard cells in the last message, and those that did not fit.
    pub last_hazard_cells: u64,
    pub last_hazard_cells_omitted: u64,
    pub head_commands: u64,
    pub reframes: u64,
}

/// Motion of the body from the filter states.
#[derive(Debug, Clone, Copy)]
struct Motion {
    stamp_ns: u64,
    speed_mps: f64,
    yaw_rad: f64,
    yaw_rate_radps: f64,
}

/// Local map, hazard messages and gaze (see the module documentation).
#[derive(Debug)]
pub struct Surroundings {
    map: LocalObstacleMap,
    gaze: Option<GazePolicy>,
    motion: Option<Motion>,
    /// The body in the local frame at the last mapped pair, and its frame id.
    body: Option<(u64, Isometry3<f64>, u32)>,
    hazards_sent_ns: Option<u64>,
    head_sequence: u64,
    /// Hazard cells with their squared distance in cells, reused for the nearest-first order.
    scratch: Vec<(i64, [i16; 2])>,
    /// The hazard message, filled in place (4 KiB: not on the stack, not allocated per send).
    hazards: Box<HazardCellsMsg>,
    summary: SurroundingsSummary,
}

impl Surroundings {
    pub fn new(obstacles: &ObstacleConfig, gaze: Option<GazeOptions>) -> Self {
        let cell_size_m = obstacles.cell_size_m;
        Surroundings {
            map: LocalObstacleMap::new(cell_size_m, MAP_SIDE_CELLS, MAP_TIME_CONSTANT_S)
                .releasing_unseen_edges(obstacles.release_unseen_edges),
            gaze: gaze.map(GazePolicy::new),
            motion: None,
            body: None,
            hazards_sent_ns: None,
            head_sequence: 0,
            scratch: Vec::with_capacity(MAP_SIDE_CELLS * MAP_SIDE_CELLS / 4),
            hazards: Box::new(HazardCellsMsg {
                stamp_ns: 0,
                t_local_body: Pose::from_isometry(&Isometry3::identity()),
                frame_id: 0,
                cell_size_m: cell_size_m as f32,
                origin_cell: [0; 2],
                count: 0,
                omitted: 0,
                cells: [[0; 2]; HAZARD_CELLS_MAX],
            }),
            summary: SurroundingsSummary::default(),
        }
    }

    pub fn map(&self) -> &LocalObstacleMap {
        &self.map
    }

    pub fn summary(&self) -> SurroundingsSummary {
        self.summary
    }

    /// A filter state: the motion the gaze policy reacts to.
    pub fn on_state(&mut self, stamp_ns: u64, t_local_body: &Isometry3<f64>, v_local_mps: [f64; 3]) {
        let speed_mps = v_local_mps[0].hypot(v_local_mps[1]);
        let yaw_rad = t_local_body.rotation.euler_angles().2;
        match &mut self.motion {
            Some(m) if stamp_ns < m.stamp_ns.saturating_add(YAW_RATE_BASE_NS) => m.speed_mps = speed_mps,
            Some(m) => {
                let dt_s = (stamp_ns - m.stamp_ns) as f64 * 1e-9;
                let turned = (yaw_rad - m.yaw_rad + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI)
                    - std::f64::consts::PI;
                *m = Motion { stamp_ns, speed_mps, yaw_rad, yaw_rate_radps: turned / dt_s };
            }
            None => self.motion = Some(Motion { stamp_ns, speed_mps, yaw_rad, yaw_rate_radps: 0.0 }),
        }
    }

    /// One classified pair taken at `stamp_ns` with the body at `t_local_body` of frame
    /// `frame_id`.
    pub fn integrate(&mut self, stamp_ns: u64, t_local_body: &Isometry3<f64>, frame_id: u32, cells: &HeightMap) {
        let p = t_local_body.translation.vector;
        self.map.recentre(p.x, p.y);
        self.map.integrate(cells, stamp_ns);
        self.body = Some((stamp_ns, *t_local_body, frame_id));
        self.summary.pairs_mapped += 1;
    }

    /// A frame switch: the map moves into the new frame (`t_old_new` maps new to old).
    pub fn on_frame_switch(&mut self, t_old_new: &Isometry3<f64>, new_frame_id: u32) {
        self.map.reframe(&t_old_new.inverse());
        if let Some((stamp_ns, t_local_body, _)) = self.body {
            self.body = Some((stamp_ns, t_old_new.inverse() * t_local_body, new_frame_id));
        }
        self.summary.reframes += 1;
    }

    /// A missed frame switch: the map's frame is unknown, its cells are dropped.
    pub fn forget(&mut self) {
        self.map.clear();
        self.body = None;
    }

    /// The fixed-rate part: the gaze decision and, once a second, the hazard cells.
    pub fn on_tick(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if let (Some(policy), Some(motion)) = (&mut self.gaze, self.motion)
            && let Some(target) = policy.update(now_ns, motion.speed_mps, motion.yaw_rate_radps)
        {
            let command = HeadCommandMsg {
                stamp_ns: now_ns,
                sequence: self.head_sequence,
                pan_rad: target.pan_rad,
                tilt_rad: target.tilt_rad,
                max_rate_radps: target.max_rate_radps,
                mode: target.mode,
                reserved: 0,
            };
            self.head_sequence += 1;
            self.summary.head_commands += 1;
            out.publish(Message::HeadCommand(&command))?;
        }
        if self.hazards_sent_ns.is_some_and(|t| now_ns < t.saturating_add(HAZARDS_PERIOD_NS)) {
            return Ok(());
        }
        let Some((stamp_ns, t_local_body, frame_id)) = self.body else {
            return Ok(());
        };
        self.hazards_sent_ns = Some(now_ns);
        self.fill_hazards(stamp_ns, &t_local_body, frame_id);
        self.summary.hazard_messages += 1;
        self.summary.last_hazard_cells = u64::from(self.hazards.count);
        self.summary.last_hazard_cells_omitted = u64::from(self.hazards.omitted);
        out.publish(Message::Hazards(&self.hazards))
    }

    fn fill_hazards(&mut self, stamp_ns: u64, t_local_body: &Isometry3<f64>, frame_id: u32) {
        let cell = self.map.cell_size_m();
        let p = t_local_body.translation.vector;
        let origin = ((p.x / cell).floor() as i64, (p.y / cell).floor() as i64);
        self.scratch.clear();
        for (i, j) in self.map.hazard_cells() {
            let (di, dj) = (i - origin.0, j - origin.1);
            // The map's window is 200 cells wide: offsets always fit.
            if let (Ok(a), Ok(b)) = (i16::try_from(di), i16::try_from(dj)) {
                self.scratch.push((di * di + dj * dj, [a, b]));
            }
        }
        self.scratch.sort_unstable_by_key(|&(d2, c)| (d2, c));
        let message = &mut self.hazards;
        message.stamp_ns = stamp_ns;
        message.t_local_body = Pose::from_isometry(t_local_body);
        message.frame_id = frame_id;
        message.cell_size_m = cell as f32;
        message.origin_cell = [origin.0 as i32, origin.1 as i32];
        let kept = self.scratch.len().min(HAZARD_CELLS_MAX);
        for (slot, &(_, c)) in message.cells.iter_mut().zip(&self.scratch[..kept]) {
            *slot = c;
        }
        message.count = kept as u32;
        message.omitted = (self.scratch.len() - kept) as u32;
    }
}
