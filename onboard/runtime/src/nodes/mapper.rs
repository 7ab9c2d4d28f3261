//! The mapper node: submaps from disparity and filter states, the multi-robot pose graph
//! ([`TeamGraph`]), the composed global map, the team exchange and the state that survives a
//! crash.
//!
//! | in | what happens |
//! |---|---|
//! | `filter/state` | ring of recent states; [`Submapper`] policy → one `frame_switch_request` per frame; own pose into the graph and to peers every `pose_period_ns` |
//! | `vision/disparity` | the filter state at the capture stamp (exact, or interpolated over ≤ `max_interpolation_gap_ns`) → depth integrated at `t_local_body · t_body_cam(pan, tilt)`; a sample of the online trajectory |
//! | `filter/frame_switch` | finished submap: persisted, then queued to peers as `SubmapHeader` + `SubmapChunk`s (the header carries the switch into it); switch into the graph |
//! | `comms/to_mapper` | a peer's `protocol` packet: poses, constraints, match attempts, submaps (reassembled, CRC-checked, decoded, placed once connected) |
//! | tick | at most one graph update; global-map poses refreshed; up to `max_chunks_per_tick` submap chunks sent |
//!
//! The switch out of a submap reaches the peers with the *next* submap's header (the protocol
//! has no stand-alone frame-switch message): until then a peer's newest submap hangs off the
//! graph only through detections.
//!
//! Persistence (`state_dir`): see [`journal`]. A restarted mapper has every finished own
//! submap, every received submap and the whole graph again, plus its online trajectory; the
//! unfinished current submap is lost (its images are not journaled).

pub mod journal;
mod wire;

use std::collections::{BTreeMap, BTreeSet, VecDeque};
use std::fs::{self, File};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use hal::sensor::StereoCalibration;
use mapper::Submap;
use mapper::global::{GlobalMap, GlobalMapConfig};
use mapper::integrate::{DepthIntegrator, IntegratorConfig};
use mapper::scheduler::{MatchScheduler, SchedulerConfig};
use mapper::slam::{
    self, FilterPose, FramePose, GraphSize, InsertOutcome, Measurement, NodeId, PoseBuffer, SameStamp, SubmapPair,
    SubmapSwitch, TeamEstimate, TeamGraph, TeamGraphConfig, TeamMarkers,
};
use mapper::submap::{SubmapPolicy, Submapper};
use msgs::{
    DisparityHeader, DisparityPixel, FilterStateMsg, FrameSwitchMsg, FrameSwitchRequestMsg, MarkerMsg, TeamHeader,
};
use nalgebra::{Isometry3, Matrix3, Matrix6};
use protocol::message::{ConstraintId, SubmapEncoding, SubmapHeader};
use protocol::{AnyMessage, MAX_PACKET_BYTES, NodeId as WireNode, RobotId as WireRobot, SubmapId as WireSubmap};
use vision::depth::{DepthImage, StereoGeometry};
use vision::obstacles::PixelLabels;

use super::{Message, Node, NodeError, Outbox, Topic};
use journal::{Record, StateDir};

/// `SubmapEncoding` of [`mapper::exchange::encode_submap`] payloads.
pub const SUBMAP_ENCODING_EXCHANGE_V1: SubmapEncoding = SubmapEncoding(1);

/// Everything the mapper is configured with.
#[derive(Debug, Clone)]
pub struct MapperConfig {
    /// Own robot id (must fit the protocol's `u8` robot ids).
    pub robot_id: u16,
    /// The rectified stereo head: disparity geometry and `t_body_cam(pan, tilt)`.
    pub calibration: StereoCalibration,
    pub policy: SubmapPolicy,
    pub integrator: IntegratorConfig,
    pub graph: TeamGraphConfig,
    pub global: GlobalMapConfig,
    /// Own filter poses enter the graph and go to the peers at this period.
    pub pose_period_ns: u64,
    /// Recent filter states kept for the capture-stamp lookup (200 Hz: 1024 ≈ 5 s).
    pub state_ring_len: usize,
    /// Two neighbouring states at most this far apart are interpolated.
    pub max_interpolation_gap_ns: u64,
    /// Own poses at camera stamps kept to answer detections (10 Hz: 36 000 = 1 h).
    pub pose_history_len: usize,
    /// Filter states of a newer frame than the current submap for this long mean the frame
    /// switch message was lost (a restart while a switch was in flight): the submapper jumps.
    pub lost_switch_timeout_ns: u64,
    /// Submap chunks handed to comms per tick.
    pub max_chunks_per_tick: usize,
    /// Received submaps reassembled at once, and their largest payload.
    pub max_partial_submaps: usize,
    pub max_submap_payload_bytes: usize,
    /// Cell size of `map.png`.
    pub png_resolution_m: f64,
    /// Where finished submaps and the journal are kept; `None`: nothing is persisted.
    pub state_dir: Option<PathBuf>,
    /// The team's tag mountings: detected tags become robot detections (`None`: markers are
    /// ignored).
    pub markers: Option<TeamMarkers>,
    /// One image's detections of a robot per this interval enter the graph; farther tags are
    /// not used.
    pub marker_min_interval_ns: u64,
    pub marker_max_distance_m: f64,
    /// The submap matcher (`None`: no map-matching loop closures).
    pub matching: Option<SchedulerConfig>,
}

impl MapperConfig {
    /// The defaults (LRU multi-robot submap policy, 1 s pose period, no persistence).
    pub fn new(robot_id: u16, calibration: StereoCalibration) -> MapperConfig {
        MapperConfig {
            robot_id,
            calibration,
            policy: SubmapPolicy::default(),
            integrator: IntegratorConfig::default(),
            graph: TeamGraphConfig::default(),
            global: GlobalMapConfig::default(),
            pose_period_ns: 1_000_000_000,
            state_ring_len: 1024,
            max_interpolation_gap_ns: 20_000_000,
            pose_history_len: 36_000,
            lost_switch_timeout_ns: 2_000_000_000,
            max_chunks_per_tick: 64,
            max_partial_submaps: 16,
            max_submap_payload_bytes: 32 << 20,
            png_resolution_m: 0.1,
            state_dir: None,
            markers: None,
            marker_min_interval_ns: 10_000_000_000,
            marker_max_distance_m: 7.0,
            matching: None,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum MapperError {
    #[error("robot id {0} is not a protocol robot id (1..=239)")]
    RobotId(u16),
    #[error("state directory {path}: {source}")]
    StateDir { path: PathBuf, source: io::Error },
    #[error("writing {path}: {source}")]
    Output { path: PathBuf, source: io::Error },
    #[error("map picture: {0}")]
    Png(#[from] mapper::export::PngExportError),
    #[error("pose graph: {0}")]
    Graph(#[from] slam::SlamError),
}

/// What the mapper counted (since this process started; restored state is counted separately).
/// Wall time spent in one of the mapper's steps: how often, in total, at most (the thesis's
/// runtime table, Tab. 8.11).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct StepTime {
    pub count: u64,
    pub total_s: f64,
    pub max_s: f64,
}

impl StepTime {
    fn add(&mut self, since: Instant) {
        let s = since.elapsed().as_secs_f64();
        self.count += 1;
        self.total_s += s;
        self.max_s = self.max_s.max(s);
    }

    pub fn mean_s(&self) -> Option<f64> {
        (self.count > 0).then(|| self.total_s / self.count as f64)
    }
}

/// The mapper's timed steps. The matcher's own stages run on its background thread and are
/// timed per attempt in its reports.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct MapperStepTimes {
    /// Graph optimization after new measurements (iSAM2 update).
    pub graph_update: StepTime,
    /// One depth image into the current submap.
    pub integration: StepTime,
    /// The matcher's share of the mapper's thread: new submaps prepared, pairs ranked with the
    /// graph's marginals, finished attempts taken in.
    pub matcher_poll: StepTime,
    /// The global map composed from the placed submaps (at the outputs).
    pub composition: StepTime,
}

#[derive(Debug, Clone, Default, PartialEq)]
pub struct MapperCounters {
    /// Protocol bytes and messages handed to comms, by message type name.
    pub bytes_sent: BTreeMap<&'static str, u64>,
    pub messages_sent: BTreeMap<&'static str, u64>,
    pub switch_requests: u64,
    pub submaps_finished: u64,
    pub submaps_sent: u64,
    pub submaps_received: u64,
    pub images_integrated: u64,
    /// Disparity maps without a filter state at their capture stamp.
    pub images_without_state: u64,
    /// Disparity maps from a frame older than the previous one.
    pub images_frame_mismatch: u64,
    /// Disparity maps with a size or head angles that do not fit.
    pub images_rejected: u64,
    /// Filter states not used: initializing, non-finite, or from a frame not yet switched to.
    pub states_skipped: u64,
    pub states_rejected: u64,
    pub switches_rejected: u64,
    /// Jumps of the submapper to the filter's frame after a lost switch (chain broken there).
    pub frame_resyncs: u64,
    /// `to_mapper` payloads that are not protocol packets.
    pub packets_rejected: u64,
    /// Packets that decoded but whose content is unusable (invalid pose, inconsistent submap…),
    /// and graph inserts rejected.
    pub messages_rejected: u64,
    /// Decoded packets of types the mapper does not use (heartbeats, telemetry, claims, echoes).
    pub messages_ignored: u64,
    pub submaps_rejected: u64,
    /// Own measurements that cannot be sent (robot ids beyond the protocol's range).
    pub unsendable: u64,
    pub graph_errors: u64,
    pub persist_errors: u64,
    pub journal_records_restored: u64,
    pub journal_bytes_ignored: u64,
    pub submap_files_ignored: u64,
    pub submaps_restored: u64,
    /// Tags from the vision process, the robot detections made of them, and tags refused: no
    /// team markers configured, a tag no robot carries or the robot's own, an unusable pose or
    /// covariance.
    pub markers_received: u64,
    pub marker_detections: u64,
    pub markers_refused: u64,
    /// Tags left out by the interval or the distance limit.
    pub markers_skipped: u64,
}

/// Paths and sizes of [`MapperNode::write_outputs`].
#[derive(Debug, Clone, PartialEq)]
pub struct MapperOutputs {
    pub graph_g2o: PathBuf,
    pub map_ply: PathBuf,
    pub map_bt: PathBuf,
    pub map_png: PathBuf,
    pub map_points: usize,
    pub occupied_voxels: usize,
    pub submaps_in_map: usize,
    pub graph: GraphSize,
    pub counters: MapperCounters,
}

/// An own finished submap on its way to comms.
#[derive(Debug)]
struct Outgoing {
    index: u32,
    payload: Arc<Vec<u8>>,
    next_chunk: usize,
}

/// The mapper node (see the module docs).
pub struct MapperNode {
    config: MapperConfig,
    own: slam::RobotId,
    /// Capture stamp of the last image whose tags of a robot entered the graph, per robot.
    marker_last_ns: BTreeMap<slam::RobotId, u64>,
    own_wire: WireRobot,
    geometry: StereoGeometry,
    submapper: Submapper,
    graph: TeamGraph,
    global: GlobalMap,
    /// Finished submaps (own and received) whose graph pose is not known yet.
    unplaced: BTreeMap<slam::SubmapId, Arc<Submap>>,
    own_finished: BTreeMap<u32, Arc<Submap>>,
    /// Recent filter states (pose in the local frame, filter-convention covariance).
    states: PoseBuffer<FramePose>,
    /// The switch into the current submap: `(new frame id, t_old_new)`.
    last_switch: Option<(u32, Isometry3<f64>)>,
    ahead_since_ns: Option<u64>,
    requested_frame: Option<u32>,
    next_pose_ns: u64,
    own_poses: BTreeMap<u64, FilterPose>,
    online: Vec<(u64, Isometry3<f64>)>,
    /// Every graph insert with the count of graph updates before it, when a harness asked for
    /// them (`log_graph_inserts`; the firmware never does): the back-end's whole input, for
    /// replaying it into other graph variants.
    insert_log: Option<Vec<(u64, Measurement)>>,
    graph_updates: u64,
    outgoing: VecDeque<Outgoing>,
    reassembler: wire::Reassembler,
    match_ids: BTreeMap<SubmapPair, ConstraintId>,
    packet_seq: u32,
    constraint_seq: u32,
    state_dir: Option<StateDir>,
    dirty: bool,
    depth: DepthImage,
    labels: PixelLabels,
    /// An image whose depth and labels are in `depth`/`labels` but whose filter state has not
    /// arrived yet (without an IMU the odometry's state follows the image).
    parked: Option<ParkedImage>,
    counters: MapperCounters,
    /// The submap matcher (`config.matching`).
    matcher: Option<MatchScheduler>,
    step_times: MapperStepTimes,
}

/// The capture of the image waiting in the mapper's depth buffers.
#[derive(Debug, Clone, Copy)]
struct ParkedImage {
    stamp_ns: u64,
    pan_rad: f64,
    tilt_rad: f64,
}

/// How long (sensor time after its capture) an image waits for its filter state.
const MAX_STATE_WAIT_NS: u64 = 1_000_000_000;

impl std::fmt::Debug for MapperNode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MapperNode")
            .field("robot_id", &self.own)
            .field("current_submap", &self.submapper.current().index)
            .field("finished", &self.own_finished.len())
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

impl MapperNode {
    /// A mapper; with a `state_dir` that holds a previous run's state, that state is restored.
    pub fn new(config: MapperConfig) -> Result<MapperNode, MapperError> {
        let own = config.robot_id;
        let own_wire = u8::try_from(own)
            .ok()
            .map(WireRobot)
            .filter(|r| WireNode::from(*r).is_robot())
            .ok_or(MapperError::RobotId(own))?;
        let geometry = StereoGeometry::from_calibration(&config.calibration);
        let integrator = DepthIntegrator::new(config.integrator, geometry);
        let mut node = MapperNode {
            own,
            marker_last_ns: BTreeMap::new(),
            own_wire,
            geometry,
            submapper: Submapper::new(own, config.policy, integrator),
            graph: TeamGraph::new(own, config.graph.clone()),
            global: GlobalMap::new(config.global),
            unplaced: BTreeMap::new(),
            own_finished: BTreeMap::new(),
            states: PoseBuffer::bounded(config.state_ring_len, SameStamp::KeepFirst),
            last_switch: None,
            ahead_since_ns: None,
            requested_frame: None,
            next_pose_ns: 0,
            own_poses: BTreeMap::new(),
            online: Vec::new(),
            insert_log: None,
            graph_updates: 0,
            outgoing: VecDeque::new(),
            reassembler: wire::Reassembler::new(config.max_partial_submaps, config.max_submap_payload_bytes),
            match_ids: BTreeMap::new(),
            packet_seq: 0,
            constraint_seq: 0,
            state_dir: None,
            dirty: false,
            depth: DepthImage::default(),
            labels: PixelLabels::default(),
            parked: None,
            counters: MapperCounters::default(),
            matcher: config.matching.clone().map(|c| MatchScheduler::new(own, c)),
            step_times: MapperStepTimes::default(),
            config,
        };
        if let Some(dir) = node.config.state_dir.clone() {
            let (state_dir, restored) =
                StateDir::open(&dir).map_err(|source| MapperError::StateDir { path: dir.clone(), source })?;
            node.restore(restored);
            node.state_dir = Some(state_dir);
        }
        Ok(node)
    }

    /// Rebuilds submaps, graph and online trajectory from a previous run's state.
    fn restore(&mut self, restored: journal::Restored) {
        self.counters.submap_files_ignored += restored.foreign_files as u64;
        for (index, bytes) in restored.submaps {
            match mapper::exchange::decode_submap(&bytes) {
                Ok(submap) if submap.robot_id == self.own && submap.index == index => {
                    let submap = Arc::new(submap);
                    self.unplaced.insert(slam::SubmapId::new(self.own, index), Arc::clone(&submap));
                    self.offer_to_matcher(&submap);
                    self.own_finished.insert(index, submap);
                    self.counters.submaps_restored += 1;
                }
                _ => self.counters.submap_files_ignored += 1,
            }
        }
        self.counters.journal_bytes_ignored += restored.journal.ignored_bytes as u64;
        let mut sent = BTreeSet::new();
        for record in restored.journal.records {
            self.counters.journal_records_restored += 1;
            match record {
                Record::OwnSwitch { stamp_ns, from_index, t_old_new, covariance } => {
                    let switch = filter::FrameSwitch {
                        stamp_ns,
                        old_frame_id: from_index,
                        new_frame_id: from_index.wrapping_add(1),
                        t_old_new,
                        covariance,
                    };
                    self.resync_to(from_index, stamp_ns);
                    if self.submapper.current().index == from_index {
                        self.submapper.on_frame_switch(&switch);
                        self.last_switch = Some((switch.new_frame_id, t_old_new));
                    }
                    self.insert(&Measurement::SubmapSwitch(self.graph_switch(&switch)));
                }
                Record::OwnPose { stamp_ns, submap_index, t_submap_body, covariance } => {
                    let pose = FilterPose { robot: self.own, stamp_ns, submap_index, t_submap_body, covariance };
                    self.next_pose_ns = self.next_pose_ns.max(stamp_ns.saturating_add(self.config.pose_period_ns));
                    self.remember_pose(pose);
                    self.insert(&Measurement::FilterPose(pose));
                }
                Record::Packet(bytes) => match protocol::decode(&bytes) {
                    Ok(packet) => {
                        if let AnyMessage::Constraint(c) = &packet.message
                            && c.id.robot == self.own_wire
                        {
                            self.constraint_seq = self.constraint_seq.max(c.id.seq.wrapping_add(1));
                        }
                        // Without an outbox nothing is published, so nothing can fail.
                        let _ = self.apply(&packet.message, None);
                    }
                    Err(_) => self.counters.packets_rejected += 1,
                },
                Record::SubmapSent(index) => {
                    sent.insert(index);
                }
                Record::Online { stamp_ns, t_global_body } => self.online.push((stamp_ns, t_global_body)),
            }
        }
        for (index, submap) in &self.own_finished {
            if !sent.contains(index) {
                let mut payload = Vec::new();
                mapper::exchange::encode_submap(submap, &mut payload);
                self.outgoing.push_back(Outgoing { index: *index, payload: Arc::new(payload), next_chunk: 0 });
            }
        }
        self.update_graph();
    }

    pub fn config(&self) -> &MapperConfig {
        &self.config
    }

    /// The own robot's online pose in its own global frame at every integrated camera stamp, as
    /// the graph gave it then (thesis ch. 8).
    pub fn online_trajectory(&self) -> &[(u64, Isometry3<f64>)] {
        &self.online
    }

    /// From now on, keep every graph insert (see [`MapperNode::graph_inserts`]). For harnesses:
    /// the log grows with the mission.
    pub fn log_graph_inserts(&mut self) {
        self.insert_log.get_or_insert_with(Vec::new);
    }

    /// The graph inserts since [`MapperNode::log_graph_inserts`], each with the number of graph
    /// updates before it: inserts with the same number went into the same update.
    pub fn graph_inserts(&self) -> &[(u64, Measurement)] {
        self.insert_log.as_deref().unwrap_or(&[])
    }

    pub fn team_estimate(&self) -> TeamEstimate {
        self.graph.estimate()
    }

    pub fn graph_size(&self) -> GraphSize {
        self.graph.size()
    }

    pub fn graph(&self) -> &TeamGraph {
        &self.graph
    }

    /// The graph's marginal covariance of every submap origin (an evaluation's prior; the
    /// matcher computes its own when it ranks).
    pub fn submap_marginals(&mut self) -> Result<Vec<(slam::SubmapId, nalgebra::Matrix6<f64>)>, slam::SlamError> {
        self.graph.submap_marginals()
    }

    /// The submap matcher's state, log and counters (`None` when matching is off).
    pub fn matcher(&self) -> Option<&MatchScheduler> {
        self.matcher.as_ref()
    }

    pub fn global_map(&self) -> &GlobalMap {
        &self.global
    }

    /// How long the mapper's steps took so far.
    pub fn step_times(&self) -> &MapperStepTimes {
        &self.step_times
    }

    pub fn counters(&self) -> &MapperCounters {
        &self.counters
    }

    /// The submap being built.
    pub fn current_submap(&self) -> &Submap {
        self.submapper.current()
    }

    /// Own finished submaps, by index.
    pub fn own_submaps(&self) -> impl Iterator<Item = &Arc<Submap>> {
        self.own_finished.values()
    }

    /// Finished submaps (own and received) not in the global map yet (not connected).
    pub fn unplaced_submaps(&self) -> usize {
        self.unplaced.len()
    }

    /// An own loop-closure measurement (robot detection, landmark observation, submap match,
    /// match attempt): into the graph, and to the peers as a protocol `Constraint` or
    /// `MatchAttempt`. The own filter pose at a detection's stamp is entered and sent with it.
    pub fn insert_measurement(&mut self, m: &Measurement, out: &mut dyn Outbox) -> Result<InsertOutcome, NodeError> {
        let stamp_ns = m.stamp_ns().unwrap_or_else(|| self.states.latest().map_or(0, |s| s.stamp_ns));
        match m {
            Measurement::Detection(d) if d.observer == self.own || d.observed == self.own => {
                self.ensure_own_pose(d.stamp_ns, out)?;
            }
            Measurement::Landmark(l) if l.robot == self.own => self.ensure_own_pose(l.stamp_ns, out)?,
            Measurement::FilterPose(p) if p.robot == self.own => {
                return self.insert_own_pose(*p, out);
            }
            _ => {}
        }
        let outcome = self.insert(m);
        let id = ConstraintId { robot: self.own_wire, seq: self.constraint_seq };
        let Some(message) = wire::constraint_message(m, id, &self.match_ids) else {
            self.counters.unsendable += 1;
            return Ok(outcome);
        };
        if let Measurement::Match(s) = m {
            self.match_ids.insert(s.pair(), id);
        }
        if matches!(message, AnyMessage::Constraint(_)) {
            self.constraint_seq = self.constraint_seq.wrapping_add(1);
        }
        self.send(&message, stamp_ns, true, out)?;
        Ok(outcome)
    }

    /// Composes the map and writes `graph.g2o`, `map.ply`, `map.bt` and `map.png` into `dir`.
    pub fn write_outputs(&mut self, dir: &Path) -> Result<MapperOutputs, MapperError> {
        let output_error = |path: &Path| {
            let path = path.to_path_buf();
            move |source| MapperError::Output { path, source }
        };
        fs::create_dir_all(dir).map_err(output_error(dir))?;
        self.update_graph();
        let (factors, values) = self.graph.optimizer_state();
        let mut g2o_text = String::new();
        // Writing into a String cannot fail.
        let _ = posegraph::g2o::write(&posegraph::dataset::to_g2o(factors, &values), &mut g2o_text);
        let graph_g2o = dir.join("graph.g2o");
        fs::write(&graph_g2o, g2o_text).map_err(output_error(&graph_g2o))?;

        let current = self.submapper.current();
        let t_global_current = self.graph.online_pose(&FilterPose {
            robot: self.own,
            stamp_ns: current.start_stamp_ns,
            submap_index: current.index,
            t_submap_body: Isometry3::identity(),
            covariance: Matrix6::zeros(),
        });
        let start = Instant::now();
        let composition = self.global.compose(t_global_current.as_ref().map(|t| (self.submapper.current(), t)));
        self.step_times.composition.add(start);

        let map_ply = dir.join("map.ply");
        let mut file = BufWriter::new(File::create(&map_ply).map_err(output_error(&map_ply))?);
        mapper::export::write_ply(&composition.cloud, mapper::export::PlyFormat::BinaryLittleEndian, None, &mut file)
            .and_then(|()| file.flush())
            .map_err(output_error(&map_ply))?;
        let map_bt = dir.join("map.bt");
        let mut file = BufWriter::new(File::create(&map_bt).map_err(output_error(&map_bt))?);
        mapper::export::write_bt(&composition.occupancy, &mut file)
            .and_then(|()| file.flush())
            .map_err(output_error(&map_bt))?;
        let map_png = dir.join("map.png");
        let mut file = BufWriter::new(File::create(&map_png).map_err(output_error(&map_png))?);
        mapper::export::write_height_png(&composition.cloud, self.config.png_resolution_m, &mut file)?;
        file.flush().map_err(output_error(&map_png))?;

        Ok(MapperOutputs {
            graph_g2o,
            map_ply,
            map_bt,
            map_png,
            map_points: composition.cloud.len(),
            occupied_voxels: composition.occupancy.occupied_count(),
            submaps_in_map: self.global.len(),
            graph: self.graph.size(),
            counters: self.counters.clone(),
        })
    }

    fn graph_switch(&self, switch: &filter::FrameSwitch) -> SubmapSwitch {
        SubmapSwitch {
            robot: self.own,
            stamp_ns: switch.stamp_ns,
            from_index: switch.old_frame_id,
            t_old_new: switch.t_old_new,
            covariance: slam::covariance::from_filter(&switch.t_old_new, &switch.covariance),
        }
    }

    fn insert(&mut self, m: &Measurement) -> InsertOutcome {
        if let Some(log) = self.insert_log.as_mut() {
            log.push((self.graph_updates, *m));
        }
        let outcome = self.graph.insert(m);
        match outcome {
            InsertOutcome::Added | InsertOutcome::Pending => self.dirty = true,
            InsertOutcome::Rejected(_) => self.counters.messages_rejected += 1,
            InsertOutcome::Duplicate => {}
        }
        outcome
    }

    fn update_graph(&mut self) {
        if self.dirty {
            self.dirty = false;
            self.graph_updates += 1;
            let start = Instant::now();
            if self.graph.update().is_err() {
                self.counters.graph_errors += 1;
            }
            self.step_times.graph_update.add(start);
        }
        self.place_submaps();
    }

    /// Moves finished submaps to their current graph poses; those newly connected enter the map.
    fn place_submaps(&mut self) {
        for (node, pose) in self.graph.estimates() {
            let NodeId::Submap(id) = node else { continue };
            if self.global.set_pose((id.robot, id.index), pose) {
                continue;
            }
            if let Some(submap) = self.unplaced.remove(&id) {
                self.global.insert(submap, pose);
            }
        }
    }

    fn journal(&mut self, record: &Record) {
        if let Some(dir) = &mut self.state_dir
            && dir.append(record).is_err()
        {
            self.counters.persist_errors += 1;
        }
    }

    /// Encodes one protocol message and hands it to comms (journaling the packet first when it
    /// is a graph input).
    fn send(
        &mut self,
        message: &AnyMessage,
        stamp_ns: u64,
        journal: bool,
        out: &mut dyn Outbox,
    ) -> Result<(), NodeError> {
        let mut buf = [0u8; MAX_PACKET_BYTES];
        let seq = self.packet_seq;
        let Ok(len) = protocol::encode(message, WireNode::from(self.own_wire), WireNode::BROADCAST, seq, &mut buf)
        else {
            self.counters.unsendable += 1;
            return Ok(());
        };
        self.packet_seq = seq.wrapping_add(1);
        let bytes = &buf[..len];
        if journal {
            self.journal(&Record::Packet(bytes.to_vec()));
        }
        let header = TeamHeader { stamp_ns, robot_id: TeamHeader::BROADCAST, message_key: u32::from(message.key().0) };
        out.publish(Message::ToComms(&header, bytes))?;
        let name = message.type_name();
        *self.counters.bytes_sent.entry(name).or_default() += len as u64;
        *self.counters.messages_sent.entry(name).or_default() += 1;
        Ok(())
    }

    fn remember_pose(&mut self, pose: FilterPose) {
        self.own_poses.insert(pose.stamp_ns, pose);
        while self.own_poses.len() > self.config.pose_history_len {
            self.own_poses.pop_first();
        }
    }

    /// An own filter pose: into the graph, the journal and to the peers.
    fn insert_own_pose(&mut self, pose: FilterPose, out: &mut dyn Outbox) -> Result<InsertOutcome, NodeError> {
        let outcome = self.insert(&Measurement::FilterPose(pose));
        if outcome != InsertOutcome::Added {
            return Ok(outcome);
        }
        self.remember_pose(pose);
        self.journal(&Record::OwnPose {
            stamp_ns: pose.stamp_ns,
            submap_index: pose.submap_index,
            t_submap_body: pose.t_submap_body,
            covariance: pose.covariance,
        });
        match wire::pose_estimate(&pose) {
            Some(estimate) => self.send(&estimate.into(), pose.stamp_ns, false, out)?,
            None => self.counters.unsendable += 1,
        }
        Ok(outcome)
    }

    /// Makes sure the graph has the own pose at `stamp_ns` (a detection refers to it).
    fn ensure_own_pose(&mut self, stamp_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if self.graph.pose_buffer(self.own).is_some_and(|b| b.range(stamp_ns, stamp_ns).next().is_some()) {
            return Ok(());
        }
        let pose = self.own_poses.get(&stamp_ns).copied().or_else(|| {
            self.state_at(stamp_ns).map(|s| FilterPose {
                robot: self.own,
                stamp_ns,
                submap_index: s.frame_id,
                t_submap_body: s.pose,
                covariance: slam::covariance::from_filter(&s.pose, &s.covariance),
            })
        });
        if let Some(pose) = pose {
            self.insert_own_pose(pose, out)?;
        }
        Ok(())
    }

    /// The filter state at `stamp_ns`: exact, or interpolated between neighbours of one frame no
    /// more than `max_interpolation_gap_ns` apart.
    /// The filter state at `stamp_ns`, exact or interpolated (see [`PoseBuffer::lookup`]).
    fn state_at(&self, stamp_ns: u64) -> Option<FramePose> {
        self.states.lookup(stamp_ns, self.config.max_interpolation_gap_ns)
    }

    /// Advances the submapper to `frame_id` without switch transforms (their messages were lost):
    /// the skipped submaps' content is dropped and the own chain is broken there.
    fn resync_to(&mut self, frame_id: u32, stamp_ns: u64) {
        while self.submapper.current().index < frame_id {
            let index = self.submapper.current().index;
            self.submapper.on_frame_switch(&filter::FrameSwitch {
                stamp_ns,
                old_frame_id: index,
                new_frame_id: index + 1,
                t_old_new: Isometry3::identity(),
                covariance: Matrix6::zeros(),
            });
            self.last_switch = None;
            self.counters.frame_resyncs += 1;
        }
    }

    fn on_filter_state(&mut self, m: &FilterStateMsg, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if m.status != FilterStateMsg::RUNNING {
            self.counters.states_skipped += 1;
            return Ok(());
        }
        let (Some(t_local_body), Some(covariance)) =
            (m.t_local_body.to_isometry(), msgs::covariance_from_array(&m.pose_covariance))
        else {
            self.counters.states_rejected += 1;
            return Ok(());
        };
        if self.states.latest().is_some_and(|s| s.stamp_ns >= m.stamp_ns) {
            self.counters.states_rejected += 1;
            return Ok(());
        }
        self.states.insert(FramePose { stamp_ns: m.stamp_ns, frame_id: m.frame_id, pose: t_local_body, covariance });
        self.integrate_parked();
        let current = self.submapper.current().index;
        if m.frame_id > current {
            // The switch message may still be on its way (another topic); only a long wait
            // means it was lost.
            let since = *self.ahead_since_ns.get_or_insert(m.stamp_ns);
            if m.stamp_ns.saturating_sub(since) <= self.config.lost_switch_timeout_ns {
                self.counters.states_skipped += 1;
                return Ok(());
            }
            self.resync_to(m.frame_id, m.stamp_ns);
        } else if m.frame_id < current {
            self.counters.states_skipped += 1;
            return Ok(());
        }
        self.ahead_since_ns = None;
        let position_covariance: Matrix3<f64> = covariance.fixed_view::<3, 3>(0, 0).into_owned();
        if self.submapper.on_filter_state(m.stamp_ns, &t_local_body, &position_covariance).is_some()
            && self.requested_frame != Some(m.frame_id)
        {
            self.requested_frame = Some(m.frame_id);
            self.counters.switch_requests += 1;
            let request = FrameSwitchRequestMsg { stamp_ns: m.stamp_ns, frame_id: m.frame_id, reserved: 0 };
            out.publish(Message::FrameSwitchRequest(&request))?;
        }
        if m.stamp_ns >= self.next_pose_ns {
            self.next_pose_ns = m.stamp_ns.saturating_add(self.config.pose_period_ns);
            let pose = FilterPose {
                robot: self.own,
                stamp_ns: m.stamp_ns,
                submap_index: m.frame_id,
                t_submap_body: t_local_body,
                covariance: slam::covariance::from_filter(&t_local_body, &covariance),
            };
            self.insert_own_pose(pose, out)?;
        }
        Ok(())
    }

    fn on_disparity(&mut self, h: &DisparityHeader, pixels: &[DisparityPixel]) {
        let (w, hgt) = (h.width_px as usize, h.height_px as usize);
        let calibration = &self.config.calibration.left;
        if w.checked_mul(hgt) != Some(pixels.len())
            || h.width_px != calibration.width_px
            || h.height_px != calibration.height_px
            || !h.pan_rad.is_finite()
            || !h.tilt_rad.is_finite()
        {
            self.counters.images_rejected += 1;
            return;
        }
        self.drop_parked();
        let fb_q4 = (self.geometry.fx_px * self.geometry.baseline_m * 16.0) as f32;
        self.depth.width = w;
        self.depth.height = hgt;
        self.depth.depth_m.clear();
        self.depth.depth_m.extend(pixels.iter().map(|p| match p.disparity_q4 {
            DisparityPixel::INVALID => f32::NAN,
            0 => f32::INFINITY,
            d => fb_q4 / f32::from(d),
        }));
        self.labels.width = w;
        self.labels.height = hgt;
        self.labels.flags.clear();
        self.labels.flags.extend(pixels.iter().map(|p| p.labels));
        let image = ParkedImage { stamp_ns: h.stamp_ns, pan_rad: h.pan_rad, tilt_rad: h.tilt_rad };
        if self.states.latest().is_none_or(|newest| newest.stamp_ns < h.stamp_ns) {
            // Its state is still to come.
            self.parked = Some(image);
            return;
        }
        self.integrate(image);
    }

    /// An image parked for its state is given up (a newer image, or it waited too long).
    fn drop_parked(&mut self) {
        if self.parked.take().is_some() {
            self.counters.images_without_state += 1;
        }
    }

    /// The parked image, once a state at or after its capture exists.
    fn integrate_parked(&mut self) {
        if let Some(image) = self.parked
            && self.states.latest().is_some_and(|newest| newest.stamp_ns >= image.stamp_ns)
        {
            self.parked = None;
            self.integrate(image);
        }
    }

    /// Integrates the depth and labels in the buffers (captured at `image`) with the filter
    /// state of the capture.
    fn integrate(&mut self, image: ParkedImage) {
        let Some(state) = self.state_at(image.stamp_ns) else {
            self.counters.images_without_state += 1;
            return;
        };
        let current = self.submapper.current().index;
        let t_local_body = if state.frame_id == current {
            state.pose
        } else {
            // Captured just before the switch into the current frame: carried across it.
            match self.last_switch {
                Some((new_frame, t_old_new)) if new_frame == current && state.frame_id + 1 == current => {
                    t_old_new.inverse() * state.pose
                }
                _ => {
                    self.counters.images_frame_mismatch += 1;
                    return;
                }
            }
        };
        let t_local_cam = t_local_body * self.config.calibration.t_body_left(image.pan_rad, image.tilt_rad);
        let start = Instant::now();
        self.submapper.integrate(image.stamp_ns, &self.depth, Some(&self.labels), None, &t_local_cam);
        self.step_times.integration.add(start);
        self.counters.images_integrated += 1;

        let pose = FilterPose {
            robot: self.own,
            stamp_ns: image.stamp_ns,
            submap_index: state.frame_id,
            t_submap_body: state.pose,
            covariance: slam::covariance::from_filter(&state.pose, &state.covariance),
        };
        self.remember_pose(pose);
        if let Some(t_global_body) = self.graph.online_pose(&pose) {
            self.online.push((image.stamp_ns, t_global_body));
            self.journal(&Record::Online { stamp_ns: image.stamp_ns, t_global_body });
        }
    }

    /// A tag from the vision process: eq. 4.7 between this robot and the tag's carrier, into the
    /// graph and to the team like any constraint.
    fn on_marker(&mut self, m: &MarkerMsg, out: &mut dyn Outbox) -> Result<(), NodeError> {
        self.counters.markers_received += 1;
        let Some(detection) = self.marker_detection(m) else {
            self.counters.markers_refused += 1;
            return Ok(());
        };
        let last = self.marker_last_ns.get(&detection.observed).copied();
        // Every tag of the image that opened an interval goes in (they share the robot poses).
        let due = last.is_none_or(|l| {
            m.capture_stamp_ns == l || m.capture_stamp_ns >= l.saturating_add(self.config.marker_min_interval_ns)
        });
        // A NaN distance is out of range too.
        let in_range = f64::from(m.distance_m) <= self.config.marker_max_distance_m;
        if !due || !in_range {
            self.counters.markers_skipped += 1;
            return Ok(());
        }
        self.marker_last_ns.insert(detection.observed, m.capture_stamp_ns);
        self.counters.marker_detections += 1;
        self.insert_measurement(&Measurement::Detection(detection), out).map(|_| ())
    }

    fn marker_detection(&self, m: &MarkerMsg) -> Option<slam::RobotDetection> {
        let owner = self.config.markers.as_ref()?.owner(m.tag_id)?;
        let observed = crate::stack::protocol_robot_id(u16::try_from(owner.robot).ok()?);
        // A carrier beyond the protocol's robot ids could never hear about it.
        let wire = u8::try_from(observed).ok().map(WireRobot)?;
        if observed == self.own || !WireNode::from(wire).is_robot() {
            return None;
        }
        let covariance_cam = msgs::covariance_from_array(&m.covariance_cam)?;
        if !slam::covariance::is_valid(&covariance_cam) {
            return None;
        }
        let observation = slam::MarkerObservation {
            stamp_ns: m.capture_stamp_ns,
            tag_id: m.tag_id,
            t_body_cam: m.t_body_cam.to_isometry()?,
            t_cam_marker: m.t_cam_marker.to_isometry()?,
            covariance_cam,
        };
        Some(slam::markers::robot_detection(self.own, observed, &observation, &owner.t_body_marker))
    }

    fn on_frame_switch(&mut self, m: &FrameSwitchMsg) -> Result<(), NodeError> {
        let current = self.submapper.current().index;
        if m.new_frame_id <= current {
            return Ok(());
        }
        let (Some(t_old_new), Some(covariance)) =
            (m.t_old_new.to_isometry(), msgs::covariance_from_array(&m.covariance))
        else {
            self.counters.switches_rejected += 1;
            return Ok(());
        };
        if m.new_frame_id != m.old_frame_id.wrapping_add(1) {
            self.counters.switches_rejected += 1;
            return Ok(());
        }
        self.resync_to(m.old_frame_id, m.stamp_ns);
        let switch = filter::FrameSwitch {
            stamp_ns: m.stamp_ns,
            old_frame_id: m.old_frame_id,
            new_frame_id: m.new_frame_id,
            t_old_new,
            covariance,
        };
        let finished = Arc::new(self.submapper.on_frame_switch(&switch));
        self.last_switch = Some((m.new_frame_id, t_old_new));
        self.counters.submaps_finished += 1;
        let mut payload = Vec::new();
        mapper::exchange::encode_submap(&finished, &mut payload);
        // Persisted before anything else knows of it, so no peer can hold a submap we lost.
        if let Some(dir) = &self.state_dir
            && dir.write_submap(finished.index, &payload).is_err()
        {
            self.counters.persist_errors += 1;
        }
        self.journal(&Record::OwnSwitch { stamp_ns: m.stamp_ns, from_index: m.old_frame_id, t_old_new, covariance });
        self.insert(&Measurement::SubmapSwitch(self.graph_switch(&switch)));
        self.unplaced.insert(slam::SubmapId::new(self.own, finished.index), Arc::clone(&finished));
        self.offer_to_matcher(&finished);
        self.outgoing.push_back(Outgoing { index: finished.index, payload: Arc::new(payload), next_chunk: 0 });
        self.own_finished.insert(finished.index, finished);
        Ok(())
    }

    /// Hands up to `max_chunks_per_tick` chunks of queued own submaps to comms.
    fn send_chunks(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        let mut budget = self.config.max_chunks_per_tick;
        while budget > 0 {
            let Some(job) = self.outgoing.front() else { break };
            let (index, payload, next) = (job.index, Arc::clone(&job.payload), job.next_chunk);
            let id = WireSubmap { robot: self.own_wire, index };
            if next == 0 {
                let Some(submap) = self.own_finished.get(&index).cloned() else {
                    self.outgoing.pop_front();
                    continue;
                };
                let Some((payload_bytes, chunk_count, payload_crc32)) = wire::payload_fields(&payload) else {
                    self.counters.unsendable += 1;
                    self.outgoing.pop_front();
                    continue;
                };
                let switch = (index > 0).then(|| {
                    let covariance = slam::covariance::from_filter(&submap.t_prev_this, &submap.switch_covariance);
                    wire::frame_switch(&submap.t_prev_this, &covariance)
                });
                let header = SubmapHeader {
                    submap: id,
                    started_stamp_ns: submap.start_stamp_ns,
                    finished_stamp_ns: submap.end_stamp_ns,
                    switch,
                    encoding: SUBMAP_ENCODING_EXCHANGE_V1,
                    payload_bytes,
                    chunk_count,
                    payload_crc32,
                };
                self.send(&header.into(), now_ns, false, out)?;
            }
            match wire::chunk(id, &payload, next) {
                Some(chunk) => {
                    self.send(&chunk.into(), now_ns, false, out)?;
                    budget -= 1;
                    if let Some(job) = self.outgoing.front_mut() {
                        job.next_chunk += 1;
                    }
                }
                None => {
                    self.outgoing.pop_front();
                    self.counters.submaps_sent += 1;
                    self.journal(&Record::SubmapSent(index));
                }
            }
        }
        Ok(())
    }

    fn on_to_mapper(&mut self, bytes: &[u8], out: &mut dyn Outbox) -> Result<(), NodeError> {
        let packet = match protocol::decode(bytes) {
            Ok(packet) => packet,
            Err(_) => {
                self.counters.packets_rejected += 1;
                return Ok(());
            }
        };
        if packet.header.source == WireNode::from(self.own_wire) {
            self.counters.messages_ignored += 1;
            return Ok(());
        }
        if matches!(
            packet.message,
            AnyMessage::PoseEstimate(_)
                | AnyMessage::Constraint(_)
                | AnyMessage::MatchAttempt(_)
                | AnyMessage::SubmapHeader(_)
                | AnyMessage::SubmapChunk(_)
        ) {
            self.journal(&Record::Packet(bytes.to_vec()));
        }
        self.apply(&packet.message, Some(out))
    }

    /// A team message (received, or replayed from the journal with `out = None`).
    fn apply(&mut self, message: &AnyMessage, out: Option<&mut dyn Outbox>) -> Result<(), NodeError> {
        match message {
            AnyMessage::PoseEstimate(p) if u16::from(p.robot.0) != self.own => match wire::filter_pose(p) {
                Ok(pose) => {
                    self.insert(&Measurement::FilterPose(pose));
                }
                Err(_) => self.counters.messages_rejected += 1,
            },
            AnyMessage::Constraint(c) => match wire::constraint_measurement(c) {
                Ok(m) => {
                    // A detection of us: answer with our pose at its stamp.
                    let own_stamp = match m {
                        Measurement::Detection(d) if d.observed == self.own || d.observer == self.own => {
                            Some(d.stamp_ns)
                        }
                        _ => None,
                    };
                    if let (Some(stamp_ns), Some(out)) = (own_stamp, out) {
                        self.ensure_own_pose(stamp_ns, out)?;
                    }
                    if let Measurement::Match(s) = m {
                        self.match_ids.insert(s.pair(), c.id);
                    }
                    self.insert(&m);
                }
                Err(_) => self.counters.messages_rejected += 1,
            },
            AnyMessage::MatchAttempt(a) => match wire::attempt_measurement(a) {
                Some(m) => {
                    self.insert(&m);
                }
                None => self.counters.messages_ignored += 1,
            },
            AnyMessage::SubmapHeader(h) => {
                if h.encoding != SUBMAP_ENCODING_EXCHANGE_V1 || h.submap.robot == self.own_wire {
                    self.counters.messages_ignored += 1;
                    return Ok(());
                }
                match wire::header_switch(h) {
                    Ok(Some(switch)) => {
                        self.insert(&Measurement::SubmapSwitch(switch));
                    }
                    Ok(None) => {}
                    Err(_) => {
                        self.counters.messages_rejected += 1;
                        return Ok(());
                    }
                }
                if self.reassembler.start(h).is_err() {
                    self.counters.messages_rejected += 1;
                }
            }
            AnyMessage::SubmapChunk(c) => match self.reassembler.add(c) {
                Ok(Some((header, payload))) => self.accept_submap(&header, &payload),
                Ok(None) => {}
                Err(_) => self.counters.submaps_rejected += 1,
            },
            _ => self.counters.messages_ignored += 1,
        }
        Ok(())
    }

    /// A finished submap (own or received) to the matcher, if it runs.
    fn offer_to_matcher(&mut self, submap: &Submap) {
        if let Some(matcher) = &mut self.matcher {
            let start = Instant::now();
            matcher.add_submap(slam::SubmapId::new(submap.robot_id, submap.index), Arc::new(submap.cloud.clone()));
            self.step_times.matcher_poll.add(start);
        }
    }

    /// The matcher's finished attempt and match (if any) into the graph and to the team.
    fn run_matcher(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        let Some(matcher) = &mut self.matcher else {
            return Ok(());
        };
        let start = Instant::now();
        let found = matcher.poll(now_ns, &mut self.graph);
        self.step_times.matcher_poll.add(start);
        for m in found {
            self.insert_measurement(&m, out)?;
        }
        Ok(())
    }

    fn accept_submap(&mut self, header: &SubmapHeader, payload: &[u8]) {
        let id = wire::slam_submap(header.submap);
        match mapper::exchange::decode_submap(payload) {
            Ok(submap) if submap.robot_id == id.robot && submap.index == id.index => {
                self.counters.submaps_received += 1;
                let submap = Arc::new(submap);
                self.offer_to_matcher(&submap);
                match self.graph.node_pose(NodeId::Submap(id)) {
                    Some(pose) => self.global.insert(submap, pose),
                    None => {
                        self.unplaced.insert(id, submap);
                    }
                }
            }
            _ => self.counters.submaps_rejected += 1,
        }
    }
}

impl Node for MapperNode {
    fn name(&self) -> &'static str {
        "mapper"
    }

    fn subscriptions(&self) -> &'static [Topic] {
        &[Topic::FilterState, Topic::Disparity, Topic::FrameSwitch, Topic::Marker, Topic::ToMapper]
    }

    fn on_message(&mut self, message: Message<'_>, out: &mut dyn Outbox) -> Result<(), NodeError> {
        match message {
            Message::FilterState(m) => self.on_filter_state(m, out),
            Message::Disparity(h, pixels) => {
                self.on_disparity(h, pixels);
                Ok(())
            }
            Message::FrameSwitch(m) => self.on_frame_switch(m),
            Message::Marker(m) => self.on_marker(m, out),
            Message::ToMapper(_, bytes) => self.on_to_mapper(bytes, out),
            _ => Ok(()),
        }
    }

    fn on_tick(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if self.parked.is_some_and(|p| now_ns > p.stamp_ns.saturating_add(MAX_STATE_WAIT_NS)) {
            self.drop_parked();
        }
        self.update_graph();
        self.run_matcher(now_ns, out)?;
        self.send_chunks(now_ns, out)
    }
}
