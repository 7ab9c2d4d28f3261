//! The local reference filter as a bus node: the error-state filter (`filter::Filter`) fed by the
//! driver's IMU and wheel odometry, vision's odometry results and the mapper's switch requests.
//! Without an IMU (a dataset that has none) the node publishes the odometry's own chain instead
//! ([`odometry_chain`]).
//!
//! - **IMU**: averaged over the at-rest initialization window, then propagation, the VO results
//!   that are due (capture + [`FilterNodeOptions::latency_ns`]), a ZUPT at 10 Hz while standing;
//!   then one [`FilterStateMsg`] (also while initializing, so consumers see the IMU counters).
//!   Sequence gaps count as lost samples.
//! - **Stereo** (header only): the camera trigger, `clone_at(capture)`.
//! - **VoDelta**: queued until the IMU stream passes its due time, or applied on arrival when it
//!   arrives later than that (the process runner's vision really is late sometimes). Keyframe
//!   marking and clone release as the pipeline does.
//! - **WheelOdom**: a body-velocity update on arrival.
//! - **FrameSwitchRequest** for the current frame: `switch_frame()` and a [`FrameSwitchMsg`]; the
//!   next state is in the new frame. A request for another frame is ignored and counted.
//!
//! Bad payloads (non-finite values, a filter error on one input) are counted and skipped.
//!
//! # Restarts
//! With [`FilterNodeOptions::checkpoint_path`] the node writes a [`checkpoint`] every
//! [`FilterNodeOptions::checkpoint_period_ns`] of IMU time and right after every frame switch
//! (before the switch is published, so the mapper never sees a frame the checkpoint does not
//! know). [`FilterNode::resume`] in a restarted process restores it: same frame id and local
//! frame (the mapper's submap chain goes on), clones and covariance, the original
//! initialization stamp and the carried counters. The IMU samples published meanwhile arrive
//! from the topic's history (`crate::bus::qos`): those the checkpoint already holds are skipped
//! (`imu_replayed`), the rest are integrated. Samples older than the history are lost: counted
//! (`imu_lost`, `restart_imu_lost`), and the filter propagates over the gap with the held sample
//! and an inflated covariance ([`GAP_SPEED_MPS`], [`GAP_YAW_RATE_RADPS`]). Not restored: the VO
//! results waiting for their due time and the standstill detector's window.
//!
//! # Device outages
//! A live IMU can go away (an unplugged line, a line full of garbage): the driver then publishes
//! nothing, and the first sample
//! after a stamp jump beyond [`IMU_STREAM_GAP_NS`] grows the covariance by the same bounds over
//! the outage (`imu_stream_gaps`, `imu_gap_max_ns`). Captures during the outage are not cloned
//! (`clones_without_imu`): a clone would be the held sample extrapolated, confidently wrong.

pub mod checkpoint;
pub mod odometry_chain;

use std::collections::VecDeque;
use std::path::PathBuf;

use filter::{
    Filter, FilterConfig, FilterHealth, FrameSwitch, RelativePoseMeasurement, StandstillConfig, StandstillDetector,
    UpdateOutcome,
};
use hal::sensor::{ImuSample, WheelOdomSample};
use msgs::{FilterStateMsg, FrameSwitchMsg, FrameSwitchRequestMsg, ImuMsg, Pose, VoDeltaMsg, WheelOdomMsg};
use nalgebra::{Isometry3, Matrix6, Vector3};

use super::{Message, Node, NodeError, Outbox, Topic};
use crate::vio::{VioOptions, VoUpdates};

const NAME: &str = "filter";
/// ZUPTs while standing at this period (as the pipeline: consecutive IMU samples are not
/// independent evidence of standstill).
const ZUPT_PERIOD_NS: u64 = 100_000_000;
/// VO results waiting for their due time; beyond this (a vision far ahead of the IMU stream) the
/// oldest is dropped and counted. 2.5 s of frames at 10 Hz with the default 250 ms latency.
const PENDING_VO_MAX: usize = 32;
/// Speed bound of the rover while the filter was away (its drive speed, `sim`'s 0.3 m/s, with
/// margin): position variance grows by `(speed · gap)²`, velocity variance by `speed²`.
pub const GAP_SPEED_MPS: f64 = 0.5;
/// Turn-rate bound over a gap: yaw variance grows by `(rate · gap)²`.
pub const GAP_YAW_RATE_RADPS: f64 = 0.3;
/// Default checkpoint period (IMU time).
pub const CHECKPOINT_PERIOD_NS: u64 = 250_000_000;
/// A jump in the IMU's stamps longer than this (10 samples at 200 Hz) is a device outage: the
/// covariance grows as over a restart's gap.
pub const IMU_STREAM_GAP_NS: u64 = 50_000_000;

/// The filter node's configuration (the filter part of [`VioOptions`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FilterNodeOptions {
    /// Fuse the IMU; without, the node publishes the stereo odometry's own chain
    /// ([`odometry_chain`]).
    pub use_imu: bool,
    pub filter: FilterConfig,
    pub use_wheel: bool,
    pub zupt: bool,
    /// Sensor time between a capture and the application of its VO result.
    pub latency_ns: u64,
    pub init_window_ns: u64,
    pub vo_updates: VoUpdates,
    pub vo_covariance_scale: f64,
    /// Where the checkpoint goes (see the module docs); `None`: no checkpoints.
    pub checkpoint_path: Option<PathBuf>,
    pub checkpoint_period_ns: u64,
}

impl FilterNodeOptions {
    pub fn from_vio(options: &VioOptions) -> Self {
        FilterNodeOptions {
            use_imu: options.use_imu,
            filter: options.filter.clone(),
            use_wheel: options.use_wheel,
            zupt: options.zupt,
            latency_ns: options.latency_ns,
            init_window_ns: options.init_window_ns,
            vo_updates: options.vo_updates,
            vo_covariance_scale: options.vo_covariance_scale,
            checkpoint_path: None,
            checkpoint_period_ns: CHECKPOINT_PERIOD_NS,
        }
    }
}

/// Counters for the mission report.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FilterNodeSummary {
    pub imu_received: u64,
    /// Sum of the IMU sequence gaps.
    pub imu_lost: u64,
    /// Jumps in the IMU's stamps beyond [`IMU_STREAM_GAP_NS`] (the device was away), and the
    /// longest.
    pub imu_stream_gaps: u64,
    pub imu_gap_max_ns: u64,
    /// Samples out of order (sequence not increasing) or with non-finite values.
    pub imu_rejected: u64,
    pub initialized_ns: Option<u64>,
    pub clones: u64,
    pub clone_errors: u64,
    /// Captures during an IMU outage, not cloned.
    pub clones_without_imu: u64,
    pub vo_received: u64,
    /// Applied on arrival because the IMU stream had already passed their due time.
    pub vo_late: u64,
    pub vo_updates_applied: u64,
    pub vo_updates_rejected: u64,
    pub vo_updates_missing_clone: u64,
    pub vo_updates_skipped: u64,
    /// Dropped because too many were waiting ([`PENDING_VO_MAX`]).
    pub vo_dropped: u64,
    pub wheel_updates_applied: u64,
    pub wheel_updates_rejected: u64,
    pub zupt_updates_applied: u64,
    pub zupt_updates_rejected: u64,
    pub frame_switches: u64,
    /// Requests for a frame that is not the current one (repeated or stale), or before the start.
    pub switch_requests_ignored: u64,
    /// Messages with non-finite values, and inputs the filter refused with an error.
    pub bad_messages: u64,
    pub filter_errors: u64,
    pub filter_health: Option<FilterHealth>,
    /// Starts from a checkpoint (over all lives of the process).
    pub resumes: u64,
    /// Stamp of the checkpoint this life resumed from.
    pub resumed_from_ns: Option<u64>,
    /// Resumed: from the checkpoint's stamp to the first new IMU sample.
    pub restart_gap_ns: Option<u64>,
    /// Resumed: samples between the checkpoint and the first new one that never arrived.
    pub restart_imu_lost: u64,
    /// Resumed: samples from the topic's history that the checkpoint already held.
    pub imu_replayed: u64,
    pub checkpoints_written: u64,
    pub checkpoint_errors: u64,
}

/// A VO result waiting for its due time, in the filter's terms.
#[derive(Debug, Clone, Copy)]
struct PendingVo {
    due_ns: u64,
    capture_ns: u64,
    new_keyframe: bool,
    delta: Option<RelativePoseMeasurement>,
}

/// The previous VO result, for the stereo speed fed to the standstill detector.
#[derive(Debug, Clone, Copy)]
struct LastVo {
    capture_ns: u64,
    /// `(keyframe stamp, t_keyframe_current_body)` when the frame had a delta.
    delta: Option<(u64, Isometry3<f64>)>,
}

/// The filter process's node (see the module documentation).
#[derive(Debug)]
pub struct FilterNode {
    options: FilterNodeOptions,
    filter: Filter,
    /// Without IMU: the odometry's chain.
    chain: odometry_chain::OdometryChain,
    /// The gyro bias the at-rest initialization levelled.
    initial_gyro_bias_radps: Option<Vector3<f64>>,
    /// Capture stamp of the last odometry result applied (the ground's "VO age").
    last_vo_capture_ns: Option<u64>,
    init_accel_sum: Vector3<f64>,
    init_gyro_sum: Vector3<f64>,
    init_count: u64,
    init_first_ns: Option<u64>,
    pending: VecDeque<PendingVo>,
    standstill: StandstillDetector,
    last_zupt_ns: Option<u64>,
    last_imu_sequence: Option<u64>,
    /// Stamp of the latest propagated IMU sample.
    last_imu_ns: Option<u64>,
    last_vo: Option<LastVo>,
    summary: FilterNodeSummary,
    /// The mission epoch written into checkpoints ([`FilterNode::resume`]).
    run_id: u64,
    /// IMU stamp of the last checkpoint written.
    last_checkpoint_ns: Option<u64>,
    /// Resumed and no new IMU sample yet: older ones are history replays.
    bridging: bool,
    checkpoint_bytes: Vec<u8>,
}

impl FilterNode {
    pub fn new(options: FilterNodeOptions) -> Self {
        FilterNode {
            filter: Filter::new(options.filter.clone()),
            chain: odometry_chain::OdometryChain::new(),
            initial_gyro_bias_radps: None,
            last_vo_capture_ns: None,
            options,
            init_accel_sum: Vector3::zeros(),
            init_gyro_sum: Vector3::zeros(),
            init_count: 0,
            init_first_ns: None,
            pending: VecDeque::with_capacity(PENDING_VO_MAX + 1),
            standstill: StandstillDetector::new(StandstillConfig::default()),
            last_zupt_ns: None,
            last_imu_sequence: None,
            last_imu_ns: None,
            last_vo: None,
            summary: FilterNodeSummary::default(),
            run_id: 0,
            last_checkpoint_ns: None,
            bridging: false,
            checkpoint_bytes: Vec::new(),
        }
    }

    /// Sets the run (the mission epoch) and resumes from the checkpoint if there is one of this
    /// run. Returns the checkpoint's stamp when it resumed; `Ok(None)` for a fresh start (no
    /// checkpoint path, no file, or another run's file, which the next checkpoint replaces).
    /// A damaged file is an error; the node then starts fresh.
    pub fn resume(&mut self, run_id: u64) -> Result<Option<u64>, checkpoint::CheckpointError> {
        self.run_id = run_id;
        let Some(path) = &self.options.checkpoint_path else { return Ok(None) };
        let Some(c) = checkpoint::read(path)? else { return Ok(None) };
        if c.run_id != run_id {
            return Ok(None);
        }
        self.filter
            .restore(&c.snapshot)
            .map_err(|_| checkpoint::CheckpointError::Invalid("the filter refused the snapshot"))?;
        let k = c.counters;
        self.summary.imu_received = k.imu_received;
        self.summary.imu_lost = k.imu_lost;
        self.summary.imu_rejected = k.imu_rejected;
        self.summary.vo_received = k.vo_received;
        self.summary.vo_updates_applied = k.vo_updates_applied;
        self.summary.wheel_updates_applied = k.wheel_updates_applied;
        self.summary.frame_switches = k.frame_switches;
        self.summary.resumes = k.resumes + 1;
        self.summary.initialized_ns = Some(c.initialized_ns);
        self.summary.resumed_from_ns = Some(c.snapshot.stamp_ns);
        self.last_imu_sequence = Some(c.imu_sequence);
        self.last_imu_ns = Some(c.snapshot.last_imu.map_or(c.snapshot.stamp_ns, |s| s.stamp_ns));
        self.last_checkpoint_ns = Some(c.snapshot.stamp_ns);
        self.bridging = true;
        Ok(Some(c.snapshot.stamp_ns))
    }

    /// Writes the checkpoint now (a no-op without a path or before initialization). A failed
    /// write is counted; the previous checkpoint stays.
    fn write_checkpoint(&mut self) {
        let Some(path) = &self.options.checkpoint_path else { return };
        let Some(snapshot) = self.filter.snapshot() else { return };
        let s = &self.summary;
        let c = checkpoint::FilterCheckpoint {
            run_id: self.run_id,
            imu_sequence: self.last_imu_sequence.unwrap_or(0),
            initialized_ns: s.initialized_ns.unwrap_or(snapshot.stamp_ns),
            counters: checkpoint::CarriedCounters {
                imu_received: s.imu_received,
                imu_lost: s.imu_lost,
                imu_rejected: s.imu_rejected,
                vo_received: s.vo_received,
                vo_updates_applied: s.vo_updates_applied,
                wheel_updates_applied: s.wheel_updates_applied,
                frame_switches: s.frame_switches,
                resumes: s.resumes,
            },
            snapshot,
        };
        self.last_checkpoint_ns = Some(c.snapshot.stamp_ns);
        checkpoint::encode(&c, &mut self.checkpoint_bytes);
        match checkpoint::write_atomic(path, &self.checkpoint_bytes) {
            Ok(()) => self.summary.checkpoints_written += 1,
            Err(_) => self.summary.checkpoint_errors += 1,
        }
    }

    fn checkpoint_if_due(&mut self, stamp_ns: u64) {
        if self.options.checkpoint_path.is_some()
            && self
                .last_checkpoint_ns
                .is_none_or(|last| stamp_ns >= last.saturating_add(self.options.checkpoint_period_ns))
        {
            self.write_checkpoint();
        }
    }

    /// The first sample after a resume that the history did not deliver: the motion over the
    /// gap is unknown beyond the held sample, so the covariance grows by the rover's bounds.
    fn inflate_for_gap(&mut self, stamp_ns: u64) {
        let gap_ns = self.filter.snapshot().map_or(0, |s| stamp_ns.saturating_sub(s.stamp_ns));
        self.inflate_covariance(gap_ns as f64 * 1e-9);
    }

    /// Grows the covariance for `gap_s` of motion the IMU did not see, by the rover's bounds.
    fn inflate_covariance(&mut self, gap_s: f64) {
        let Some(mut snapshot) = self.filter.snapshot() else { return };
        let position = (GAP_SPEED_MPS * gap_s).powi(2);
        let velocity = GAP_SPEED_MPS.powi(2);
        let yaw = (GAP_YAW_RATE_RADPS * gap_s).powi(2);
        // Core error state order (δp, δv, δθ, …); δθ is global, so z is the yaw.
        for i in 0..3 {
            snapshot.covariance[(i, i)] += position;
            snapshot.covariance[(3 + i, 3 + i)] += velocity;
        }
        snapshot.covariance[(8, 8)] += yaw;
        if self.filter.restore(&snapshot).is_err() {
            self.summary.filter_errors += 1;
        }
    }

    pub fn filter(&self) -> &Filter {
        &self.filter
    }

    /// Starts the filter from a known pose and velocity instead of at rest (a test with ground
    /// truth, or a robot that starts moving); the pose becomes the first frame's origin.
    pub fn initialize_with_pose(
        &mut self,
        stamp_ns: u64,
        t_local_body: &Isometry3<f64>,
        v_local_mps: &Vector3<f64>,
    ) -> Result<(), filter::FilterError> {
        self.filter.initialize_with_pose(stamp_ns, t_local_body, v_local_mps)?;
        self.summary.initialized_ns = Some(stamp_ns);
        self.last_imu_ns = Some(stamp_ns);
        self.initial_gyro_bias_radps = self.filter.state().map(|s| s.gyro_bias_radps);
        Ok(())
    }

    /// The gyro bias the at-rest initialization levelled (`None` before it, or without IMU).
    pub fn initial_gyro_bias_radps(&self) -> Option<Vector3<f64>> {
        self.initial_gyro_bias_radps
    }

    /// The current local frame's id.
    pub fn frame_id(&self) -> u32 {
        if self.options.use_imu { self.filter.frame_id() } else { self.chain.frame_id() }
    }

    /// Checkpoints go to `path` from now on (see the module docs).
    pub fn set_checkpoint_path(&mut self, path: PathBuf) {
        self.options.checkpoint_path = Some(path);
    }

    pub fn summary(&self) -> FilterNodeSummary {
        FilterNodeSummary { filter_health: Some(*self.filter.health()), ..self.summary }
    }

    /// Applies the VO results still waiting (the data ended before their due time), as the
    /// pipeline's `finish`. Returns the state message after them, if the filter runs.
    pub fn flush(&mut self) -> Option<FilterStateMsg> {
        if !self.options.use_imu {
            return self.chain.latest().map(|s| self.chain_message(s));
        }
        if !self.filter.is_initialized() {
            return None;
        }
        self.apply_due_vo(u64::MAX);
        Some(self.state_message())
    }

    fn count_filter_result(&mut self, result: Result<UpdateOutcome, filter::FilterError>) -> Option<UpdateOutcome> {
        match result {
            Ok(outcome) => Some(outcome),
            Err(_) => {
                self.summary.filter_errors += 1;
                None
            }
        }
    }

    fn on_imu(&mut self, message: &ImuMsg, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if self.bridging && self.last_imu_sequence.is_some_and(|last| message.sequence <= last) {
            self.summary.imu_replayed += 1;
            return Ok(());
        }
        self.summary.imu_received += 1;
        let mut lost = 0;
        if let Some(last) = self.last_imu_sequence {
            if message.sequence <= last {
                self.summary.imu_rejected += 1;
                return Ok(());
            }
            lost = message.sequence - last - 1;
            self.summary.imu_lost += lost;
        }
        self.last_imu_sequence = Some(message.sequence);
        if std::mem::take(&mut self.bridging) {
            self.summary.restart_imu_lost = lost;
            self.summary.restart_gap_ns = Some(message.stamp_ns.saturating_sub(self.filter.stamp_ns()));
            if lost > 0 {
                self.inflate_for_gap(message.stamp_ns);
            }
        }
        let finite = message.gyro_radps.iter().chain(&message.accel_mps2).all(|v| v.is_finite());
        if !finite || self.last_imu_ns.is_some_and(|last| message.stamp_ns < last) {
            self.summary.imu_rejected += 1;
            return Ok(());
        }
        if self.filter.is_initialized()
            && let Some(last_ns) = self.last_imu_ns
            && message.stamp_ns.saturating_sub(last_ns) > IMU_STREAM_GAP_NS
        {
            // The device was away (an unplugged IMU, a line that carried only garbage): the
            // filter went on with the held sample, and what the IMU did not see is unknown.
            let gap_ns = message.stamp_ns - last_ns;
            self.summary.imu_stream_gaps += 1;
            self.summary.imu_gap_max_ns = self.summary.imu_gap_max_ns.max(gap_ns);
            self.inflate_covariance(gap_ns as f64 * 1e-9);
        }
        let sample = ImuSample {
            stamp_ns: message.stamp_ns,
            gyro_radps: message.gyro_radps.into(),
            accel_mps2: message.accel_mps2.into(),
        };
        self.standstill.push_imu(&sample);
        if !self.filter.is_initialized() {
            self.accumulate_init(&sample);
        } else if self.filter.propagate(&sample).is_err() {
            self.summary.filter_errors += 1;
        } else {
            self.last_imu_ns = Some(sample.stamp_ns);
            self.apply_due_vo(sample.stamp_ns);
            self.apply_zupt(sample.stamp_ns);
            self.checkpoint_if_due(sample.stamp_ns);
        }
        let state = self.state_message_at(sample.stamp_ns);
        out.publish(Message::FilterState(&state))
    }

    fn accumulate_init(&mut self, sample: &ImuSample) {
        let first = *self.init_first_ns.get_or_insert(sample.stamp_ns);
        self.init_accel_sum += sample.accel_mps2;
        self.init_gyro_sum += sample.gyro_radps;
        self.init_count += 1;
        if sample.stamp_ns.saturating_sub(first) < self.options.init_window_ns {
            return;
        }
        let n = self.init_count as f64;
        let (accel, gyro) = (self.init_accel_sum / n, self.init_gyro_sum / n);
        match self.filter.initialize_at_rest(sample.stamp_ns, &accel, &gyro) {
            Ok(()) => {
                self.summary.initialized_ns = Some(sample.stamp_ns);
                self.last_imu_ns = Some(sample.stamp_ns);
                self.initial_gyro_bias_radps = self.filter.state().map(|s| s.gyro_bias_radps);
            }
            Err(_) => self.summary.filter_errors += 1,
        }
    }

    /// The state after the latest input; while initializing, identity with the counters.
    fn state_message_at(&self, stamp_ns: u64) -> FilterStateMsg {
        if self.filter.is_initialized() {
            return self.state_message();
        }
        FilterStateMsg {
            stamp_ns,
            t_local_body: Pose::IDENTITY,
            v_local_mps: [0.0; 3],
            accel_bias_mps2: [0.0; 3],
            gyro_bias_radps: [0.0; 3],
            pose_covariance: [0.0; 36],
            imu_received: self.summary.imu_received,
            imu_lost: self.summary.imu_lost,
            frame_id: self.filter.frame_id(),
            status: FilterStateMsg::INITIALIZING,
            last_vo_capture_ns: FilterStateMsg::NEVER,
        }
    }

    fn state_message(&self) -> FilterStateMsg {
        let Some(state) = self.filter.state() else {
            return self.state_message_at(self.filter.stamp_ns());
        };
        FilterStateMsg {
            stamp_ns: state.stamp_ns,
            t_local_body: Pose::from_isometry(&state.t_local_body),
            v_local_mps: state.v_local_mps.into(),
            accel_bias_mps2: state.accel_bias_mps2.into(),
            gyro_bias_radps: state.gyro_bias_radps.into(),
            pose_covariance: msgs::covariance_to_array(&self.filter.pose_covariance()),
            imu_received: self.summary.imu_received,
            imu_lost: self.summary.imu_lost,
            frame_id: state.frame_id,
            status: FilterStateMsg::RUNNING,
            last_vo_capture_ns: self.last_vo_capture_ns.unwrap_or(FilterStateMsg::NEVER),
        }
    }

    fn apply_due_vo(&mut self, now_ns: u64) {
        while let Some(pending) = self.pending.front().copied() {
            if pending.due_ns > now_ns {
                break;
            }
            self.pending.pop_front();
            self.apply_vo(&pending);
        }
    }

    fn apply_vo(&mut self, pending: &PendingVo) {
        // Marked first: the update releases the clone of a frame that is not a keyframe.
        if pending.new_keyframe {
            self.filter.mark_keyframe(pending.capture_ns);
        }
        let Some(measurement) = &pending.delta else {
            self.filter.release_clone(pending.capture_ns);
            return;
        };
        if self.options.vo_updates == VoUpdates::Keyframes && !pending.new_keyframe {
            self.filter.release_clone(pending.capture_ns);
            self.summary.vo_updates_skipped += 1;
            return;
        }
        let result = self.filter.update_relative_pose(measurement);
        match self.count_filter_result(result) {
            Some(UpdateOutcome::Applied { .. }) => {
                self.summary.vo_updates_applied += 1;
                self.last_vo_capture_ns = Some(pending.capture_ns);
            }
            Some(UpdateOutcome::Rejected { .. }) => self.summary.vo_updates_rejected += 1,
            Some(UpdateOutcome::MissingClone) => self.summary.vo_updates_missing_clone += 1,
            None => {}
        }
    }

    fn apply_zupt(&mut self, now_ns: u64) {
        if !self.options.zupt || !self.standstill.is_standing() {
            return;
        }
        if self.last_zupt_ns.is_some_and(|last| now_ns < last + ZUPT_PERIOD_NS) {
            return;
        }
        self.last_zupt_ns = Some(now_ns);
        let result = self.filter.update_zero_velocity();
        match self.count_filter_result(result) {
            Some(UpdateOutcome::Applied { .. }) => self.summary.zupt_updates_applied += 1,
            Some(UpdateOutcome::Rejected { .. } | UpdateOutcome::MissingClone) => {
                self.summary.zupt_updates_rejected += 1;
            }
            None => {}
        }
    }

    fn on_wheel(&mut self, message: &WheelOdomMsg) {
        if !self.options.use_wheel {
            return;
        }
        let finite =
            message.linear_mps.iter().chain(&message.angular_radps).chain(&message.sigma).all(|v| v.is_finite());
        if !finite {
            self.summary.bad_messages += 1;
            return;
        }
        let sample = WheelOdomSample {
            stamp_ns: message.stamp_ns,
            linear_mps: message.linear_mps.into(),
            angular_radps: message.angular_radps.into(),
            sigma: message.sigma,
        };
        self.standstill.push_speed(sample.stamp_ns, sample.linear_mps.norm());
        if !self.filter.is_initialized() {
            return;
        }
        let result = self.filter.update_wheel_odometry(&sample);
        match self.count_filter_result(result) {
            Some(UpdateOutcome::Applied { .. }) => self.summary.wheel_updates_applied += 1,
            Some(UpdateOutcome::Rejected { .. } | UpdateOutcome::MissingClone) => {
                self.summary.wheel_updates_rejected += 1;
            }
            None => {}
        }
    }

    fn on_capture(&mut self, capture_ns: u64) {
        if !self.filter.is_initialized() {
            return;
        }
        if self.last_imu_ns.is_some_and(|last| capture_ns.saturating_sub(last) > IMU_STREAM_GAP_NS) {
            // The IMU is away: a clone would be the held sample extrapolated over the outage, a
            // pose with a confident covariance and an unknown error, and the odometry measured
            // against it would be refused (or worse, pull the state). The capture gets none; its
            // odometry result finds no clone and is skipped.
            self.summary.clones_without_imu += 1;
            return;
        }
        match self.filter.clone_at(capture_ns) {
            Ok(()) => self.summary.clones += 1,
            Err(_) => self.summary.clone_errors += 1,
        }
    }

    fn on_vo(&mut self, message: &VoDeltaMsg) {
        let has_delta = message.flags & VoDeltaMsg::HAS_DELTA != 0;
        let delta = if has_delta {
            let pose = super::vision::exact_isometry(&message.t_keyframe_current_body);
            let covariance = msgs::covariance_from_array(&message.covariance_body);
            let (Some(pose), Some(covariance)) = (pose, covariance) else {
                self.summary.bad_messages += 1;
                return;
            };
            Some((pose, covariance))
        } else {
            None
        };
        self.summary.vo_received += 1;
        let reset = message.flags & VoDeltaMsg::RESET != 0;
        self.record_vo_speed(message, delta.as_ref().map(|(pose, _)| pose), reset);
        if !self.filter.is_initialized() {
            return;
        }
        let pending = PendingVo {
            due_ns: message.capture_stamp_ns.saturating_add(self.options.latency_ns),
            capture_ns: message.capture_stamp_ns,
            new_keyframe: message.flags & VoDeltaMsg::NEW_KEYFRAME != 0,
            delta: delta.map(|(t_from_to, covariance): (Isometry3<f64>, Matrix6<f64>)| RelativePoseMeasurement {
                from_stamp_ns: message.keyframe_stamp_ns,
                to_stamp_ns: message.capture_stamp_ns,
                t_from_to,
                covariance: covariance * self.options.vo_covariance_scale,
            }),
        };
        if self.last_imu_ns.is_some_and(|now| pending.due_ns <= now) {
            self.summary.vo_late += 1;
        }
        if self.pending.len() == PENDING_VO_MAX {
            self.pending.pop_front();
            self.summary.vo_dropped += 1;
        }
        // Kept in due order: a result may overtake an older one in the process runner.
        let at = self.pending.iter().position(|p| p.due_ns > pending.due_ns).unwrap_or(self.pending.len());
        self.pending.insert(at, pending);
        if let Some(now) = self.last_imu_ns {
            self.apply_due_vo(now);
        }
    }

    /// The stereo speed feeds the standstill detector when there is no wheel odometry (as the
    /// pipeline does). The message carries keyframe-relative poses, so the motion between two
    /// frames is known when they share a keyframe or the previous one is the keyframe.
    fn record_vo_speed(&mut self, message: &VoDeltaMsg, pose: Option<&Isometry3<f64>>, reset: bool) {
        let capture_ns = message.capture_stamp_ns;
        let wheels_silent =
            !self.options.use_wheel || self.summary.wheel_updates_applied + self.summary.wheel_updates_rejected == 0;
        if let (Some(previous), Some(pose)) = (self.last_vo, pose)
            && capture_ns > previous.capture_ns
            && !reset
            && wheels_silent
        {
            let moved_m = match previous.delta {
                Some((keyframe_ns, t_kf_previous)) if keyframe_ns == message.keyframe_stamp_ns => {
                    Some((t_kf_previous.inverse() * pose).translation.vector.norm())
                }
                _ if message.keyframe_stamp_ns == previous.capture_ns => Some(pose.translation.vector.norm()),
                _ => None,
            };
            if let Some(moved_m) = moved_m {
                let dt_s = (capture_ns - previous.capture_ns) as f64 * 1e-9;
                self.standstill.push_speed(capture_ns, moved_m / dt_s);
            }
        }
        self.last_vo = Some(LastVo { capture_ns, delta: pose.map(|p| (message.keyframe_stamp_ns, *p)) });
    }

    fn on_switch_request(&mut self, request: &FrameSwitchRequestMsg, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if !self.filter.is_initialized() || request.frame_id != self.filter.frame_id() {
            self.summary.switch_requests_ignored += 1;
            return Ok(());
        }
        let switch = match self.filter.switch_frame() {
            Ok(switch) => switch,
            Err(_) => {
                self.summary.filter_errors += 1;
                return Ok(());
            }
        };
        self.summary.frame_switches += 1;
        self.write_checkpoint();
        out.publish(Message::FrameSwitch(&frame_switch_message(&switch)))
    }
}

/// The bus form of a frame switch, from the filter or the odometry chain.
fn frame_switch_message(switch: &FrameSwitch) -> FrameSwitchMsg {
    FrameSwitchMsg {
        stamp_ns: switch.stamp_ns,
        t_old_new: Pose::from_isometry(&switch.t_old_new),
        covariance: msgs::covariance_to_array(&switch.covariance),
        old_frame_id: switch.old_frame_id,
        new_frame_id: switch.new_frame_id,
    }
}

/// Without IMU ([`FilterNodeOptions::use_imu`] off): the odometry's chain.
impl FilterNode {
    fn on_message_without_imu(&mut self, message: Message<'_>, out: &mut dyn Outbox) -> Result<(), NodeError> {
        match message {
            Message::VoDelta(vo) => {
                let Some(input) = chain_input(vo) else {
                    self.summary.bad_messages += 1;
                    return Ok(());
                };
                self.summary.vo_received += 1;
                self.summary.initialized_ns.get_or_insert(vo.capture_stamp_ns);
                if vo.flags & VoDeltaMsg::HAS_DELTA != 0 {
                    self.summary.vo_updates_applied += 1;
                    self.last_vo_capture_ns = Some(vo.capture_stamp_ns);
                }
                let state = self.chain.push(&input);
                out.publish(Message::FilterState(&self.chain_message(&state)))
            }
            Message::FrameSwitchRequest(request) => {
                if request.frame_id != self.chain.frame_id() {
                    self.summary.switch_requests_ignored += 1;
                    return Ok(());
                }
                let Some(switch) = self.chain.switch_frame() else {
                    self.summary.switch_requests_ignored += 1;
                    return Ok(());
                };
                self.summary.frame_switches += 1;
                out.publish(Message::FrameSwitch(&frame_switch_message(&switch)))
            }
            Message::Imu(_) => {
                self.summary.imu_received += 1;
                Ok(())
            }
            _ => Ok(()),
        }
    }

    fn chain_message(&self, state: &odometry_chain::ChainState) -> FilterStateMsg {
        FilterStateMsg {
            stamp_ns: state.stamp_ns,
            t_local_body: Pose::from_isometry(&state.t_local_body),
            v_local_mps: [0.0; 3],
            accel_bias_mps2: [0.0; 3],
            gyro_bias_radps: [0.0; 3],
            pose_covariance: msgs::covariance_to_array(&state.covariance),
            imu_received: self.summary.imu_received,
            imu_lost: 0,
            frame_id: state.frame_id,
            status: FilterStateMsg::RUNNING,
            last_vo_capture_ns: self.last_vo_capture_ns.unwrap_or(FilterStateMsg::NEVER),
        }
    }
}

/// A VO message in the chain's terms; `None` for non-finite values.
fn chain_input(vo: &VoDeltaMsg) -> Option<odometry_chain::OdometryInput> {
    let t_odom_body = super::vision::exact_isometry(&vo.t_odom_body)?;
    let delta = if vo.flags & VoDeltaMsg::HAS_DELTA != 0 {
        let d = super::vision::exact_isometry(&vo.t_keyframe_current_body)?;
        let covariance = msgs::covariance_from_array(&vo.covariance_body)?;
        Some((vo.keyframe_stamp_ns, d, covariance))
    } else {
        None
    };
    Some(odometry_chain::OdometryInput {
        capture_ns: vo.capture_stamp_ns,
        t_odom_body,
        delta,
        new_keyframe: vo.flags & VoDeltaMsg::NEW_KEYFRAME != 0,
    })
}

impl Node for FilterNode {
    fn name(&self) -> &'static str {
        NAME
    }

    fn subscriptions(&self) -> &'static [Topic] {
        &[Topic::Imu, Topic::WheelOdom, Topic::Stereo, Topic::VoDelta, Topic::FrameSwitchRequest]
    }

    fn on_message(&mut self, message: Message<'_>, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if !self.options.use_imu {
            return self.on_message_without_imu(message, out);
        }
        match message {
            Message::Imu(imu) => self.on_imu(imu, out)?,
            Message::WheelOdom(wheel) => self.on_wheel(wheel),
            Message::Stereo(header, _) => self.on_capture(header.stamp_ns),
            Message::VoDelta(vo) => self.on_vo(vo),
            Message::FrameSwitchRequest(request) => self.on_switch_request(request, out)?,
            _ => {}
        }
        Ok(())
    }

    fn on_tick(&mut self, _now_ns: u64, _out: &mut dyn Outbox) -> Result<(), NodeError> {
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    /// Keeps the last state published.
    #[derive(Default)]
    struct LastState(Option<FilterStateMsg>);

    impl Outbox for LastState {
        fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError> {
            if let Message::FilterState(s) = message {
                self.0 = Some(*s);
            }
            Ok(())
        }
    }

    const PERIOD_NS: u64 = 5_000_000;

    /// At rest for 1 s (initialization), then accelerating and turning.
    fn imu(sequence: u64, gravity_mps2: f64) -> ImuMsg {
        let moving = sequence >= 200;
        ImuMsg {
            stamp_ns: sequence * PERIOD_NS,
            sequence,
            gyro_radps: [0.0, 0.0, if moving { 0.05 } else { 0.0 }],
            accel_mps2: [if moving { 0.1 } else { 0.0 }, 0.0, gravity_mps2],
        }
    }

    fn node(path: &std::path::Path) -> FilterNode {
        let mut options = FilterNodeOptions::from_vio(&VioOptions::default());
        options.checkpoint_path = Some(path.to_owned());
        FilterNode::new(options)
    }

    fn feed(node: &mut FilterNode, sequences: std::ops::Range<u64>, out: &mut LastState) {
        let g = node.options.filter.gravity_mps2;
        for k in sequences {
            node.on_message(Message::Imu(&imu(k, g)), out).unwrap();
        }
    }

    #[test]
    fn a_restarted_node_resumes_from_its_checkpoint_and_skips_replayed_samples() {
        let dir = std::env::temp_dir().join(format!("onboard-filter-resume-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("filter.ckpt");
        let _ = std::fs::remove_file(&path);
        let mut original = node(&path);
        assert_eq!(original.resume(77).unwrap(), None);
        let mut out = LastState::default();
        feed(&mut original, 0..400, &mut out);
        let checkpoint = checkpoint::read(&path).unwrap().unwrap();
        // Written every 0.25 s (50 samples): the last one within the last 50 samples.
        let written_at = checkpoint.imu_sequence;
        assert!((350..400).contains(&written_at), "checkpoint at sample {written_at}");

        // The original goes on to sample 499 (as if it had died, without checkpoints); a restarted
        // node gets the history 300..500.
        original.options.checkpoint_path = None;
        feed(&mut original, 400..500, &mut out);
        let expected = out.0.unwrap();
        let mut restarted = node(&path);
        assert_eq!(restarted.resume(77).unwrap(), Some(checkpoint.snapshot.stamp_ns));
        let mut out2 = LastState::default();
        feed(&mut restarted, 300..500, &mut out2);
        let s = restarted.summary();
        assert_eq!(s.imu_replayed, written_at + 1 - 300);
        assert_eq!((s.imu_received, s.imu_lost, s.restart_imu_lost, s.resumes), (500, 0, 0, 1));
        assert_eq!(s.restart_gap_ns, Some(PERIOD_NS));
        assert_eq!(s.initialized_ns, original.summary().initialized_ns);
        let resumed = out2.0.unwrap();
        assert_eq!(resumed.frame_id, expected.frame_id);
        assert_eq!(resumed.t_local_body, expected.t_local_body);
        assert_eq!(resumed.pose_covariance, expected.pose_covariance);

        // A gap beyond the history: counted, and the covariance grows for the unknown motion.
        let written_at = checkpoint::read(&path).unwrap().unwrap().imu_sequence;
        let mut gapped = node(&path);
        gapped.resume(77).unwrap();
        let mut out3 = LastState::default();
        feed(&mut gapped, 600..601, &mut out3);
        let s = gapped.summary();
        assert_eq!(s.restart_imu_lost, 600 - written_at - 1);
        assert_eq!(s.imu_lost, 600 - written_at - 1);
        let gap_s = (600 - written_at) as f64 * PERIOD_NS as f64 * 1e-9;
        let sigma_x = out3.0.unwrap().pose_covariance[0].sqrt();
        assert!(sigma_x >= GAP_SPEED_MPS * gap_s, "position sigma {sigma_x} after a {gap_s} s gap");

        // Another run's checkpoint is not resumed.
        let mut other_run = node(&path);
        assert_eq!(other_run.resume(78).unwrap(), None);
        assert!(!other_run.filter().is_initialized());
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_imu_outage_is_counted_and_grows_the_covariance_over_it() {
        let mut options = FilterNodeOptions::from_vio(&VioOptions::default());
        options.checkpoint_path = None;
        let mut node = FilterNode::new(options);
        let g = node.options.filter.gravity_mps2;
        let mut out = LastState::default();
        feed(&mut node, 0..400, &mut out);
        let sigma_before = out.0.unwrap().pose_covariance[0].sqrt();
        // The device is away for 2 s (samples 400..800 never arrive), the driver numbers what it
        // publishes contiguously: only the stamps jump.
        let mut back = imu(800, g);
        back.sequence = 400;
        node.on_message(Message::Imu(&back), &mut out).unwrap();
        let s = node.summary();
        assert_eq!((s.imu_stream_gaps, s.imu_gap_max_ns, s.imu_lost), (1, 400 * PERIOD_NS + PERIOD_NS, 0));
        let sigma_after = out.0.unwrap().pose_covariance[0].sqrt();
        let gap_s = (401 * PERIOD_NS) as f64 * 1e-9;
        assert!(sigma_after >= GAP_SPEED_MPS * gap_s, "σx {sigma_before} → {sigma_after} over a {gap_s} s outage");
        // Ten samples' silence (the gap limit) is not an outage.
        for k in 401..405 {
            let mut sample = imu(800 + (k - 400) * 10, g);
            sample.sequence = k;
            node.on_message(Message::Imu(&sample), &mut out).unwrap();
        }
        assert_eq!(node.summary().imu_stream_gaps, 1);
    }
}
