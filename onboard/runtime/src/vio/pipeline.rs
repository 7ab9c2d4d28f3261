//! The VIO pipeline: one struct that owns every stage and its buffers (see the module docs).

use std::collections::VecDeque;
use std::time::Instant;

use filter::{
    Filter, FilterHealth, FrameSwitch, RelativePoseMeasurement, StandstillConfig, StandstillDetector, UpdateOutcome,
};
use fpga_model::{DisparityImage, GrayImage};
use hal::sensor::{ImuSample, SensorEvent, SensorSource, StereoCalibration, StereoFrame, WheelOdomSample};
use mapper::submap::SubmapPolicy;
use nalgebra::{Isometry3, Matrix3, Matrix6, Vector3};
use vision::{Rectifier, StereoOdometry, VoOutput};

use super::{VioError, VioOptions, VoUpdates};

/// ZUPTs are applied at this period while standing: consecutive IMU samples are not independent
/// evidence of standstill, and a 200 Hz ZUPT would make the filter overconfident.
const ZUPT_PERIOD_NS: u64 = 100_000_000;
/// Filter poses at capture times kept for the odometry prior (more than 5 keyframes' worth).
const CAPTURE_POSES_KEPT: usize = 64;

/// Counters and timings of a run (all times are thread time of this single-threaded pipeline,
/// measured around each stage).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VioSummary {
    pub frames: u64,
    /// Frames that arrived before the filter started (with IMU): not given to the odometry,
    /// whose first keyframe would then have no filter clone to measure against.
    pub frames_before_init: u64,
    pub keyframes: u64,
    pub vo_resets: u64,
    /// Frames for which the odometry produced a delta.
    pub vo_deltas: u64,
    pub mean_inliers: f64,
    pub min_inliers: u32,
    pub vo_updates_applied: u64,
    pub vo_updates_rejected: u64,
    pub vo_updates_missing_clone: u64,
    /// Deltas not fused under [`VoUpdates::Keyframes`].
    pub vo_updates_skipped: u64,
    pub wheel_updates_applied: u64,
    pub wheel_updates_rejected: u64,
    pub zupt_updates_applied: u64,
    pub zupt_updates_rejected: u64,
    pub frame_switches: u64,
    pub imu_samples: u64,
    pub filter_health: Option<FilterHealth>,
    /// Stamp of the filter's initialization.
    pub initialized_ns: Option<u64>,
    /// Biases at initialization and at the end.
    pub initial_gyro_bias_radps: Option<Vector3<f64>>,
    pub initial_accel_bias_mps2: Option<Vector3<f64>>,
    pub final_gyro_bias_radps: Option<Vector3<f64>>,
    pub final_accel_bias_mps2: Option<Vector3<f64>>,
    /// Sensor time covered by the processed events.
    pub data_duration_s: f64,
    pub rectify_ms_per_frame: f64,
    pub sgm_ms_per_frame: f64,
    pub vo_ms_per_frame: f64,
    pub vo_ms_max: f64,
    /// Filter CPU (propagation, clones, updates) per second of sensor data.
    pub filter_ms_per_s: f64,
}

/// The filter's pose in its current local frame at one stamp ([`VioOptions::pose_log_period_ns`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LocalPoseSample {
    pub stamp_ns: u64,
    /// The local frame `t_local_body` is in (the filter's frame id: 0, then +1 per switch).
    pub frame_id: u32,
    pub t_local_body: Isometry3<f64>,
    /// [`Filter::pose_covariance`] convention: `[δt (local frame); δθ (body, right-multiplied)]`.
    pub covariance: Matrix6<f64>,
}

/// Whether `stamp_ns` reached `*next_ns`; if so, moves `*next_ns` to the following multiple of
/// `period_ns` (a zero period fires every time).
fn reached_period(stamp_ns: u64, next_ns: &mut u64, period_ns: u64) -> bool {
    if stamp_ns < *next_ns {
        return false;
    }
    let period_ns = period_ns.max(1);
    *next_ns = (stamp_ns / period_ns).saturating_add(1).saturating_mul(period_ns);
    true
}

/// A VO result waiting for its latency to pass.
#[derive(Debug, Clone, Copy)]
struct PendingVo {
    due_ns: u64,
    capture_ns: u64,
    output: VoOutput,
}

/// SGM matcher and its buffers.
#[derive(Debug)]
struct SgmStage {
    matcher: fpga_model::fast::Matcher,
    left: GrayImage,
    right: GrayImage,
    disparity: DisparityImage,
}

/// Raw sensor events in, body trajectory out (see the module documentation).
#[derive(Debug)]
pub struct VioPipeline {
    options: VioOptions,
    rectifier: Option<Rectifier>,
    rectified: StereoFrame,
    odometry: StereoOdometry,
    sgm: Option<SgmStage>,
    filter: Option<Filter>,
    init_accel_sum: Vector3<f64>,
    init_gyro_sum: Vector3<f64>,
    init_count: u64,
    init_first_ns: Option<u64>,
    pending: VecDeque<PendingVo>,
    standstill: StandstillDetector,
    last_zupt_ns: Option<u64>,
    /// The current local frame in the first one (chained `t_old_new` of every switch).
    t_first_local: Isometry3<f64>,
    switches: Vec<FrameSwitch>,
    /// Next stamp at which the switch policy is evaluated ([`super::SwitchPolicy::period_ns`]).
    next_switch_check_ns: u64,
    /// Path length of the evaluated body positions since the last switch, and the last one.
    switch_path_m: f64,
    switch_last_position: Option<Vector3<f64>>,
    pose_log: Vec<LocalPoseSample>,
    next_pose_log_ns: u64,
    /// Filter poses (first frame) at recent capture times, for the odometry prior.
    capture_poses: VecDeque<(u64, Isometry3<f64>)>,
    /// Keyframe the odometry currently measures against (its latest keyframe).
    keyframe_ns: Option<u64>,
    /// Previous odometry pose and stamp, for the stereo speed estimate.
    last_vo: Option<(u64, Isometry3<f64>)>,
    stamps_ns: Vec<u64>,
    poses: Vec<Isometry3<f64>>,
    first_stamp_ns: Option<u64>,
    last_stamp_ns: u64,
    summary: VioSummary,
    inlier_sum: u64,
    rectify_s: f64,
    sgm_s: f64,
    vo_s: f64,
    filter_s: f64,
}

fn seconds_since(start: Instant) -> f64 {
    start.elapsed().as_secs_f64()
}

impl VioPipeline {
    /// A pipeline for a stereo head with the (raw or rectified) `calibration`.
    pub fn new(calibration: &StereoCalibration, options: VioOptions) -> Result<Self, VioError> {
        let rectifier = if calibration.rectified { None } else { Some(Rectifier::new(calibration)?) };
        let rectified_calibration = rectifier.as_ref().map_or(*calibration, Rectifier::rectified_calibration);
        let odometry = StereoOdometry::new(options.vo.clone(), &rectified_calibration)?;
        let (width, height) =
            (rectified_calibration.left.width_px as usize, rectified_calibration.left.height_px as usize);
        let sgm = if options.sgm {
            let matcher = fpga_model::fast::Matcher::new(
                fpga_model::SgmConfig::default(),
                width,
                height,
                options.sgm_threads.max(1),
            )
            .map_err(|e| VioError::Sgm(e.to_string()))?;
            let image = || GrayImage { width, height, pixels: vec![0; width * height] };
            Some(SgmStage {
                matcher,
                left: image(),
                right: image(),
                disparity: DisparityImage { width, height, data: Vec::new() },
            })
        } else {
            None
        };
        let filter = options.use_imu.then(|| Filter::new(options.filter.clone()));
        Ok(VioPipeline {
            rectifier,
            rectified: StereoFrame::default(),
            odometry,
            sgm,
            filter,
            init_accel_sum: Vector3::zeros(),
            init_gyro_sum: Vector3::zeros(),
            init_count: 0,
            init_first_ns: None,
            pending: VecDeque::new(),
            standstill: StandstillDetector::new(StandstillConfig::default()),
            last_zupt_ns: None,
            t_first_local: Isometry3::identity(),
            switches: Vec::new(),
            next_switch_check_ns: 0,
            switch_path_m: 0.0,
            switch_last_position: None,
            pose_log: Vec::new(),
            next_pose_log_ns: 0,
            capture_poses: VecDeque::with_capacity(CAPTURE_POSES_KEPT + 1),
            keyframe_ns: None,
            last_vo: None,
            stamps_ns: Vec::new(),
            poses: Vec::new(),
            first_stamp_ns: None,
            last_stamp_ns: 0,
            summary: VioSummary { min_inliers: u32::MAX, ..VioSummary::default() },
            inlier_sum: 0,
            rectify_s: 0.0,
            sgm_s: 0.0,
            vo_s: 0.0,
            filter_s: 0.0,
            options,
        })
    }

    pub fn options(&self) -> &VioOptions {
        &self.options
    }

    /// The filter (`None` without IMU).
    pub fn filter(&self) -> Option<&Filter> {
        self.filter.as_ref()
    }

    /// Starts the filter from a known pose and velocity instead of at rest (a test with ground
    /// truth, or a robot that starts moving). The pose becomes the origin of the first frame.
    pub fn initialize_with_pose(
        &mut self,
        stamp_ns: u64,
        t_local_body: &Isometry3<f64>,
        v_local_mps: &Vector3<f64>,
    ) -> Result<(), VioError> {
        let filter = self.filter.as_mut().ok_or_else(|| VioError::Input("no filter: the IMU is off".to_owned()))?;
        filter.initialize_with_pose(stamp_ns, t_local_body, v_local_mps)?;
        self.on_initialized(stamp_ns);
        Ok(())
    }

    /// The frame switches so far (each `t_old_new` with its covariance: the graph's factors).
    pub fn frame_switches(&self) -> &[FrameSwitch] {
        &self.switches
    }

    /// The logged filter poses in their local frames ([`VioOptions::pose_log_period_ns`]).
    pub fn pose_log(&self) -> &[LocalPoseSample] {
        &self.pose_log
    }

    /// The current local frame in the first one.
    pub fn t_first_local(&self) -> &Isometry3<f64> {
        &self.t_first_local
    }

    /// Output stamps and body poses in the first local frame (IMU rate with IMU, else per frame).
    pub fn trajectory(&self) -> (&[u64], &[Isometry3<f64>]) {
        (&self.stamps_ns, &self.poses)
    }

    /// Runs `source` to its end (or to [`VioOptions::end_stamp_ns`]) and finishes.
    pub fn run<S: SensorSource + ?Sized>(&mut self, source: &mut S) -> Result<VioSummary, VioError> {
        let mut frame = StereoFrame::default();
        while let Some(event) = source.next_event(&mut frame)? {
            let stamp_ns = match &event {
                SensorEvent::Stereo => frame.stamp_ns,
                SensorEvent::Imu(s) => s.stamp_ns,
                SensorEvent::WheelOdom(s) => s.stamp_ns,
            };
            if self.options.end_stamp_ns.is_some_and(|end| stamp_ns > end) {
                break;
            }
            self.process_event(&event, &frame)?;
        }
        Ok(self.finish())
    }

    /// Handles one event; `frame` holds the pair for [`SensorEvent::Stereo`].
    pub fn process_event(&mut self, event: &SensorEvent, frame: &StereoFrame) -> Result<(), VioError> {
        match event {
            SensorEvent::Stereo => self.on_stereo(frame),
            SensorEvent::Imu(sample) => self.on_imu(sample),
            SensorEvent::WheelOdom(sample) => self.on_wheel(sample),
        }
    }

    fn touch(&mut self, stamp_ns: u64) {
        self.first_stamp_ns.get_or_insert(stamp_ns);
        self.last_stamp_ns = self.last_stamp_ns.max(stamp_ns);
    }

    fn on_initialized(&mut self, stamp_ns: u64) {
        self.summary.initialized_ns = Some(stamp_ns);
        if let Some(state) = self.filter.as_ref().and_then(Filter::state) {
            self.summary.initial_gyro_bias_radps = Some(state.gyro_bias_radps);
            self.summary.initial_accel_bias_mps2 = Some(state.accel_bias_mps2);
        }
    }

    fn filter_ready(&self) -> bool {
        self.filter.as_ref().is_some_and(Filter::is_initialized)
    }

    fn on_stereo(&mut self, raw: &StereoFrame) -> Result<(), VioError> {
        self.touch(raw.stamp_ns);
        self.summary.frames += 1;
        if self.filter.is_some() && !self.filter_ready() {
            self.summary.frames_before_init += 1;
            return Ok(());
        }
        let capture_ns = raw.stamp_ns;
        let mut prior = None;
        if self.filter_ready()
            && let Some(filter) = self.filter.as_mut()
        {
            let start = Instant::now();
            let cloned = filter.clone_at(capture_ns);
            self.filter_s += seconds_since(start);
            cloned?;
            if let Some(state) = filter.state() {
                let t_first_body = self.t_first_local * state.t_local_body;
                if self.capture_poses.len() == CAPTURE_POSES_KEPT {
                    self.capture_poses.pop_front();
                }
                self.capture_poses.push_back((capture_ns, t_first_body));
                if self.options.vo_prior
                    && let Some(kf) = self.keyframe_ns
                    && let Some((_, t_first_kf)) = self.capture_poses.iter().find(|(s, _)| *s == kf)
                {
                    prior = Some(t_first_kf.inverse() * t_first_body);
                }
            }
        }

        let frame = match &self.rectifier {
            Some(rectifier) => {
                let start = Instant::now();
                rectifier.rectify(raw, &mut self.rectified)?;
                self.rectify_s += seconds_since(start);
                &self.rectified
            }
            None => raw,
        };
        let disparity = match &mut self.sgm {
            Some(sgm) => {
                let start = Instant::now();
                if frame.left.len() != sgm.left.pixels.len() || frame.right.len() != sgm.right.pixels.len() {
                    return Err(VioError::Input(format!(
                        "frame is {}x{}, SGM is set up for {}x{}",
                        frame.width_px, frame.height_px, sgm.left.width, sgm.left.height
                    )));
                }
                sgm.left.pixels.copy_from_slice(&frame.left);
                sgm.right.pixels.copy_from_slice(&frame.right);
                sgm.matcher
                    .compute_into(&sgm.left, &sgm.right, &mut sgm.disparity)
                    .map_err(|e| VioError::Sgm(e.to_string()))?;
                self.sgm_s += seconds_since(start);
                Some(&sgm.disparity)
            }
            None => None,
        };
        let start = Instant::now();
        let output = self.odometry.process(frame, disparity, prior.as_ref())?;
        let vo_s = seconds_since(start);
        self.vo_s += vo_s;
        self.summary.vo_ms_max = self.summary.vo_ms_max.max(vo_s * 1e3);
        self.record_vo(capture_ns, &output);

        if self.filter.is_some() {
            self.pending.push_back(PendingVo {
                due_ns: capture_ns.saturating_add(self.options.latency_ns),
                capture_ns,
                output,
            });
        } else {
            self.push_pose(capture_ns, output.t_odom_body);
        }
        Ok(())
    }

    fn record_vo(&mut self, capture_ns: u64, output: &VoOutput) {
        if output.new_keyframe {
            self.summary.keyframes += 1;
            self.keyframe_ns = Some(capture_ns);
        }
        if output.reset {
            self.summary.vo_resets += 1;
        }
        if let Some(delta) = &output.delta {
            self.summary.vo_deltas += 1;
            self.inlier_sum += u64::from(delta.inliers);
            self.summary.min_inliers = self.summary.min_inliers.min(delta.inliers);
            if !output.new_keyframe {
                self.keyframe_ns = Some(delta.keyframe_stamp_ns);
            }
        }
        // The stereo speed feeds the standstill detector when there is no wheel odometry.
        if let Some((previous_ns, t_previous)) = self.last_vo
            && capture_ns > previous_ns
            && output.delta.is_some()
            && !output.reset
        {
            let dt_s = (capture_ns - previous_ns) as f64 * 1e-9;
            let moved_m = (t_previous.inverse() * output.t_odom_body).translation.vector.norm();
            if !self.options.use_wheel || self.summary.wheel_updates_applied + self.summary.wheel_updates_rejected == 0
            {
                self.standstill.push_speed(capture_ns, moved_m / dt_s);
            }
        }
        self.last_vo = Some((capture_ns, output.t_odom_body));
    }

    fn push_pose(&mut self, stamp_ns: u64, pose: Isometry3<f64>) {
        if self.stamps_ns.last().is_some_and(|&last| stamp_ns <= last) {
            // Same stamp again (an update after the last sample): keep the newest estimate.
            if let (Some(&last), Some(slot)) = (self.stamps_ns.last(), self.poses.last_mut())
                && last == stamp_ns
            {
                *slot = pose;
            }
            return;
        }
        self.stamps_ns.push(stamp_ns);
        self.poses.push(pose);
    }

    fn on_imu(&mut self, sample: &ImuSample) -> Result<(), VioError> {
        self.touch(sample.stamp_ns);
        self.summary.imu_samples += 1;
        if self.filter.is_none() {
            return Ok(());
        }
        self.standstill.push_imu(sample);
        if !self.filter_ready() {
            return self.accumulate_init(sample);
        }
        let start = Instant::now();
        let result = self.update_filter(sample);
        self.filter_s += seconds_since(start);
        result
    }

    fn accumulate_init(&mut self, sample: &ImuSample) -> Result<(), VioError> {
        let first = *self.init_first_ns.get_or_insert(sample.stamp_ns);
        self.init_accel_sum += sample.accel_mps2;
        self.init_gyro_sum += sample.gyro_radps;
        self.init_count += 1;
        if sample.stamp_ns.saturating_sub(first) < self.options.init_window_ns {
            return Ok(());
        }
        let n = self.init_count as f64;
        let (accel, gyro) = (self.init_accel_sum / n, self.init_gyro_sum / n);
        if let Some(filter) = self.filter.as_mut() {
            filter.initialize_at_rest(sample.stamp_ns, &accel, &gyro)?;
        }
        self.on_initialized(sample.stamp_ns);
        self.output_filter_pose();
        Ok(())
    }

    /// Propagation and every update that is due at this IMU sample.
    fn update_filter(&mut self, sample: &ImuSample) -> Result<(), VioError> {
        let Some(filter) = self.filter.as_mut() else {
            return Ok(());
        };
        filter.propagate(sample)?;
        self.apply_due_vo(sample.stamp_ns)?;
        self.apply_zupt(sample.stamp_ns)?;
        self.apply_switch_policy()?;
        self.output_filter_pose();
        Ok(())
    }

    fn apply_due_vo(&mut self, now_ns: u64) -> Result<(), VioError> {
        while let Some(pending) = self.pending.front().copied() {
            if pending.due_ns > now_ns {
                break;
            }
            self.pending.pop_front();
            self.apply_vo(&pending)?;
        }
        Ok(())
    }

    fn apply_vo(&mut self, pending: &PendingVo) -> Result<(), VioError> {
        let Some(filter) = self.filter.as_mut() else {
            return Ok(());
        };
        // Marked first: the update releases the clone of a frame that is not a keyframe.
        if pending.output.new_keyframe {
            filter.mark_keyframe(pending.capture_ns);
        }
        let Some(delta) = &pending.output.delta else {
            filter.release_clone(pending.capture_ns);
            return Ok(());
        };
        if self.options.vo_updates == VoUpdates::Keyframes && !pending.output.new_keyframe {
            filter.release_clone(pending.capture_ns);
            self.summary.vo_updates_skipped += 1;
            return Ok(());
        }
        let measurement = RelativePoseMeasurement {
            from_stamp_ns: delta.keyframe_stamp_ns,
            to_stamp_ns: delta.stamp_ns,
            t_from_to: delta.t_keyframe_current_body,
            covariance: delta.covariance_body * self.options.vo_covariance_scale,
        };
        match filter.update_relative_pose(&measurement)? {
            UpdateOutcome::Applied { .. } => self.summary.vo_updates_applied += 1,
            UpdateOutcome::Rejected { .. } => self.summary.vo_updates_rejected += 1,
            UpdateOutcome::MissingClone => self.summary.vo_updates_missing_clone += 1,
        }
        Ok(())
    }

    fn apply_zupt(&mut self, now_ns: u64) -> Result<(), VioError> {
        if !self.options.zupt || !self.standstill.is_standing() {
            return Ok(());
        }
        if self.last_zupt_ns.is_some_and(|last| now_ns < last + ZUPT_PERIOD_NS) {
            return Ok(());
        }
        let Some(filter) = self.filter.as_mut() else {
            return Ok(());
        };
        self.last_zupt_ns = Some(now_ns);
        match filter.update_zero_velocity()? {
            UpdateOutcome::Applied { .. } => self.summary.zupt_updates_applied += 1,
            UpdateOutcome::Rejected { .. } | UpdateOutcome::MissingClone => self.summary.zupt_updates_rejected += 1,
        }
        Ok(())
    }

    fn apply_switch_policy(&mut self) -> Result<(), VioError> {
        let policy = self.options.switch;
        if policy.distance_m.is_none() && policy.sigma_m.is_none() && policy.submap.is_none() {
            return Ok(());
        }
        let Some(filter) = self.filter.as_mut() else {
            return Ok(());
        };
        let Some(state) = filter.state() else {
            return Ok(());
        };
        if let Some(period_ns) = policy.period_ns
            && !reached_period(state.stamp_ns, &mut self.next_switch_check_ns, period_ns)
        {
            return Ok(());
        }
        let p = state.t_local_body.translation.vector;
        let finite = p.iter().all(|v| v.is_finite());
        if let Some(last) = self.switch_last_position
            && finite
        {
            self.switch_path_m += (p - last).norm();
        }
        if finite {
            self.switch_last_position = Some(p);
        }
        let position_covariance: Matrix3<f64> = state.covariance.fixed_view::<3, 3>(0, 0).into_owned();
        let distance_m = p.norm();
        let sigma_m = (0..3).map(|i| position_covariance[(i, i)]).fold(0.0_f64, f64::max).sqrt();
        let far = policy.distance_m.is_some_and(|d| distance_m >= d);
        let uncertain = policy.sigma_m.is_some_and(|s| sigma_m >= s);
        // Strict comparisons and the worst-direction sigma, as the mapper decides.
        let submap = policy.submap.is_some_and(|s| {
            SubmapPolicy::position_sigma_m(&position_covariance) > s.max_position_sigma_m
                || self.switch_path_m > s.max_distance_m
        });
        if far || uncertain || submap {
            let switch = filter.switch_frame()?;
            self.t_first_local *= switch.t_old_new;
            // The path continues from the body's position, now in the new frame.
            self.switch_last_position =
                self.switch_last_position.map(|last| switch.t_old_new.inverse_transform_point(&last.into()).coords);
            self.switch_path_m = 0.0;
            self.switches.push(switch);
            self.summary.frame_switches += 1;
        }
        Ok(())
    }

    fn output_filter_pose(&mut self) {
        let Some(filter) = self.filter.as_ref() else {
            return;
        };
        let Some(state) = filter.state() else {
            return;
        };
        let covariance = self.options.pose_log_period_ns.map(|_| filter.pose_covariance());
        let pose = self.t_first_local * state.t_local_body;
        self.push_pose(state.stamp_ns, pose);
        let (Some(period_ns), Some(covariance)) = (self.options.pose_log_period_ns, covariance) else {
            return;
        };
        let sample = LocalPoseSample {
            stamp_ns: state.stamp_ns,
            frame_id: state.frame_id,
            t_local_body: state.t_local_body,
            covariance,
        };
        if reached_period(state.stamp_ns, &mut self.next_pose_log_ns, period_ns) {
            self.pose_log.push(sample);
        } else if let Some(last) = self.pose_log.last_mut()
            && last.stamp_ns == state.stamp_ns
        {
            // Updates after the logged sample at the same stamp (`finish`): keep the newest, as
            // the trajectory does.
            *last = sample;
        }
    }

    fn on_wheel(&mut self, sample: &WheelOdomSample) -> Result<(), VioError> {
        self.touch(sample.stamp_ns);
        if !self.options.use_wheel {
            return Ok(());
        }
        self.standstill.push_speed(sample.stamp_ns, sample.linear_mps.norm());
        if !self.filter_ready() {
            return Ok(());
        }
        let Some(filter) = self.filter.as_mut() else {
            return Ok(());
        };
        let start = Instant::now();
        let outcome = filter.update_wheel_odometry(sample);
        self.filter_s += seconds_since(start);
        match outcome? {
            UpdateOutcome::Applied { .. } => self.summary.wheel_updates_applied += 1,
            UpdateOutcome::Rejected { .. } | UpdateOutcome::MissingClone => self.summary.wheel_updates_rejected += 1,
        }
        Ok(())
    }

    /// Applies the VO results still in flight (the data ended before their latency passed) and
    /// completes the summary. The pipeline may continue afterwards.
    pub fn finish(&mut self) -> VioSummary {
        if self.filter_ready() {
            let start = Instant::now();
            let _ = self.apply_due_vo(u64::MAX);
            self.filter_s += seconds_since(start);
            self.output_filter_pose();
        }
        let mut summary = self.summary;
        let frames = summary.frames.max(1) as f64;
        summary.mean_inliers =
            if summary.vo_deltas > 0 { self.inlier_sum as f64 / summary.vo_deltas as f64 } else { 0.0 };
        if summary.min_inliers == u32::MAX {
            summary.min_inliers = 0;
        }
        summary.data_duration_s =
            self.first_stamp_ns.map_or(0.0, |first| self.last_stamp_ns.saturating_sub(first) as f64 * 1e-9);
        summary.rectify_ms_per_frame = self.rectify_s * 1e3 / frames;
        summary.sgm_ms_per_frame = self.sgm_s * 1e3 / frames;
        summary.vo_ms_per_frame = self.vo_s * 1e3 / frames;
        summary.filter_ms_per_s =
            if summary.data_duration_s > 0.0 { self.filter_s * 1e3 / summary.data_duration_s } else { 0.0 };
        if let Some(filter) = &self.filter {
            summary.filter_health = Some(*filter.health());
            if let Some(state) = filter.state() {
                summary.final_gyro_bias_radps = Some(state.gyro_bias_radps);
                summary.final_accel_bias_mps2 = Some(state.accel_bias_mps2);
            }
        }
        summary
    }
}
