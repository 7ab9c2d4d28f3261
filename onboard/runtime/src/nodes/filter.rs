//! The local reference filter as a bus node: [`crate::vio::VioPipeline`]'s filter logic, fed by
//! messages instead of one in-process event stream.
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

use std::collections::VecDeque;

use filter::{
    Filter, FilterConfig, FilterHealth, RelativePoseMeasurement, StandstillConfig, StandstillDetector, UpdateOutcome,
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

/// The filter node's configuration (the filter part of [`VioOptions`]).
#[derive(Debug, Clone, PartialEq)]
pub struct FilterNodeOptions {
    pub filter: FilterConfig,
    pub use_wheel: bool,
    pub zupt: bool,
    /// Sensor time between a capture and the application of its VO result.
    pub latency_ns: u64,
    pub init_window_ns: u64,
    pub vo_updates: VoUpdates,
    pub vo_covariance_scale: f64,
}

impl FilterNodeOptions {
    pub fn from_vio(options: &VioOptions) -> Self {
        FilterNodeOptions {
            filter: options.filter.clone(),
            use_wheel: options.use_wheel,
            zupt: options.zupt,
            latency_ns: options.latency_ns,
            init_window_ns: options.init_window_ns,
            vo_updates: options.vo_updates,
            vo_covariance_scale: options.vo_covariance_scale,
        }
    }
}

/// Counters for the mission report.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FilterNodeSummary {
    pub imu_received: u64,
    /// Sum of the IMU sequence gaps.
    pub imu_lost: u64,
    /// Samples out of order (sequence not increasing) or with non-finite values.
    pub imu_rejected: u64,
    pub initialized_ns: Option<u64>,
    pub clones: u64,
    pub clone_errors: u64,
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
}

impl FilterNode {
    pub fn new(options: FilterNodeOptions) -> Self {
        FilterNode {
            filter: Filter::new(options.filter.clone()),
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
        }
    }

    pub fn filter(&self) -> &Filter {
        &self.filter
    }

    pub fn summary(&self) -> FilterNodeSummary {
        FilterNodeSummary { filter_health: Some(*self.filter.health()), ..self.summary }
    }

    /// Applies the VO results still waiting (the data ended before their due time), as the
    /// pipeline's `finish`. Returns the state message after them, if the filter runs.
    pub fn flush(&mut self) -> Option<FilterStateMsg> {
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
        self.summary.imu_received += 1;
        if let Some(last) = self.last_imu_sequence {
            if message.sequence <= last {
                self.summary.imu_rejected += 1;
                return Ok(());
            }
            self.summary.imu_lost += message.sequence - last - 1;
        }
        self.last_imu_sequence = Some(message.sequence);
        let finite = message.gyro_radps.iter().chain(&message.accel_mps2).all(|v| v.is_finite());
        if !finite || self.last_imu_ns.is_some_and(|last| message.stamp_ns < last) {
            self.summary.imu_rejected += 1;
            return Ok(());
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
            Some(UpdateOutcome::Applied { .. }) => self.summary.vo_updates_applied += 1,
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
        let message = FrameSwitchMsg {
            stamp_ns: switch.stamp_ns,
            t_old_new: Pose::from_isometry(&switch.t_old_new),
            covariance: msgs::covariance_to_array(&switch.covariance),
            old_frame_id: switch.old_frame_id,
            new_frame_id: switch.new_frame_id,
        };
        out.publish(Message::FrameSwitch(&message))
    }
}

impl Node for FilterNode {
    fn name(&self) -> &'static str {
        NAME
    }

    fn subscriptions(&self) -> &'static [Topic] {
        &[Topic::Imu, Topic::WheelOdom, Topic::Stereo, Topic::VoDelta, Topic::FrameSwitchRequest]
    }

    fn on_message(&mut self, message: Message<'_>, out: &mut dyn Outbox) -> Result<(), NodeError> {
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
