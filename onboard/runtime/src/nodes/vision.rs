//! The vision process as a bus node: rectification, SGM, obstacle labels and keyframe stereo
//! odometry on each stereo pair.
//!
//! On a pair: rectify when the calibration is raw; SGM disparity and depth always
//! ([`vision::DepthPipeline`]: the fast matcher with [`vision::depth_sgm_config`], then the speckle
//! filter), because the mapper needs the dense map; depth and obstacle labels with the camera pose
//! from the latest filter state (the classifier needs the camera relative to gravity); then one
//! [`Message::Disparity`] with disparity and labels per pixel.
//!
//! The odometry's prior is the filter's keyframe→current motion: the filter poses at the two
//! capture stamps, chained across [`Message::FrameSwitch`] into one frame (a small ring of recent
//! filter states; a capture between two states is interpolated, as real cameras and IMUs never
//! share stamps). The state of a capture usually arrives just after the image (the filter
//! publishes it after the IMU sample of that stamp), so the odometry of a pair waits for the first
//! filter state at or after its capture, for the next pair, or for
//! [`VisionNodeOptions::prior_wait_ns`] of sensor time, whichever comes first; without the state
//! it runs without a prior (counted). The odometry stays idle until the filter runs: its first
//! keyframe needs a filter clone to be measured against. Each result is one
//! [`Message::VoDelta`] with the odometry's own covariance (the filter scales it).
//!
//! With markers configured ([`VisionNodeOptions::markers`]), each rectified pair is also searched
//! for the robots' tags ([`super::markers`]): one [`Message::Marker`] per tag, before the
//! odometry of the pair.
//!
//! Bad payloads (slice length not matching the header, another geometry than the calibration,
//! non-finite poses) are counted and skipped.
//!
//! # Zero copy
//! The pair is matched, and usually tracked, where it arrived: in the process runner the slices
//! point into the driver's iceoryx2 sample, which neither the matcher nor the odometry copies. A
//! raw pair is rectified into the node's own buffer (a transformation, not a copy). Only a
//! rectified pair whose odometry must wait for its filter state is copied out, because the sample
//! goes back to the bus when the handler returns ([`VisionNodeSummary::pairs_held`]).

use fpga_model::SgmConfig;
use hal::sensor::{StereoCalibration, StereoFrame};
use mapper::slam::{FramePose, PoseBuffer, SameStamp};
use msgs::{DisparityHeader, DisparityPixel, FilterStateMsg, FrameSwitchMsg, Pose, StereoHeader, VoDeltaMsg};
use nalgebra::Isometry3;
use vision::obstacles::{ObstacleClassifier, ObstacleConfig, PixelLabels};
use vision::{DepthOptions, DepthPipeline, Rectifier, StereoOdometry, StereoView, VoConfig, VoError, VoOutput};

use super::gaze::GazeOptions;
use super::markers::{MarkerOptions, MarkerStage, MarkerSummary};
use super::surroundings::{Surroundings, SurroundingsSummary};
use super::{Message, Node, NodeError, Outbox, Topic};
use crate::vio::VioOptions;

const NAME: &str = "vision";
/// Filter states kept for the prior (320 ms at 200 Hz: the state of a capture that arrived
/// before its image).
const STATES_KEPT: usize = 64;
/// Filter poses at capture stamps kept for the keyframe end of the prior (as the pipeline: more
/// than 5 keyframes' worth).
const CAPTURE_POSES_KEPT: usize = 64;
/// A capture between two filter states at most this far apart takes their interpolation (as the
/// mapper's depth integration does). Real devices' stamps never coincide: a camera's capture
/// falls between two IMU samples, so an exact lookup would leave the odometry without a prior.
const STATE_INTERPOLATION_GAP_NS: u64 = 20_000_000;

/// The vision node's configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct VisionNodeOptions {
    pub vo: VoConfig,
    /// Depth for the odometry from the SGM map instead of its sparse matching.
    pub sgm_depth_for_vo: bool,
    pub sgm: SgmConfig,
    /// Drop SGM's small blunder patches before depth ([`vision::SpeckleFilter::for_image`]).
    pub despeckle: bool,
    pub sgm_threads: usize,
    /// Seed the odometry with the filter's keyframe→current motion.
    pub vo_prior: bool,
    pub obstacles: ObstacleConfig,
    /// Longest wait (sensor time after the capture) for the filter state of a capture.
    pub prior_wait_ns: u64,
    /// The filter fuses the odometry (it has an IMU): the odometry starts with the filter and
    /// waits for the filter state of each capture for its prior. Without (a dataset without IMU)
    /// it runs on every pair at once, with no prior, and its chained pose is the trajectory.
    pub odometry_follows_filter: bool,
    /// Robot-marker detection (off: `None`).
    pub markers: Option<MarkerOptions>,
    /// The gaze policy commanding the pan-tilt head (off: `None`, the head stays where the
    /// driver has it).
    pub gaze: Option<GazeOptions>,
    /// The odometry skips pairs whose head pan or tilt differs by more than this from the last
    /// pair it tracked (the gaze policy's look down, the sweep at a stop), for at most
    /// [`VO_HEAD_GATE_MAX_NS`]; the mapper and the classifier still take them. `None`: every
    /// pair goes to the odometry.
    pub vo_head_gate_rad: Option<f64>,
}

/// The odometry takes a new head attitude as its reference after skipping this long.
pub const VO_HEAD_GATE_MAX_NS: u64 = 3_000_000_000;

impl VisionNodeOptions {
    pub fn from_vio(options: &VioOptions) -> Self {
        VisionNodeOptions {
            vo: options.vo.clone(),
            sgm_depth_for_vo: options.sgm,
            sgm: vision::depth_sgm_config(),
            despeckle: true,
            sgm_threads: options.sgm_threads.max(1),
            vo_prior: options.vo_prior,
            obstacles: ObstacleConfig::default(),
            prior_wait_ns: 50_000_000,
            odometry_follows_filter: options.use_imu,
            markers: None,
            gaze: None,
            vo_head_gate_rad: None,
        }
    }
}

/// Counters for the mission report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct VisionNodeSummary {
    pub frames: u64,
    /// Stereo messages whose slice or geometry did not match (skipped).
    pub bad_stereo: u64,
    /// Filter states or frame switches with non-finite poses (skipped).
    pub bad_filter_states: u64,
    pub disparity_published: u64,
    /// Pairs classified without a filter attitude (labels left empty).
    pub frames_without_attitude: u64,
    /// Pairs not given to the odometry because the filter was not running yet.
    pub frames_before_init: u64,
    pub vo_frames: u64,
    pub keyframes: u64,
    pub vo_resets: u64,
    pub vo_deltas: u64,
    /// Sum and minimum of the deltas' inlier counts.
    pub inliers_sum: u64,
    pub min_inliers: Option<u32>,
    pub priors_used: u64,
    /// The filter state of the capture did not arrive in time.
    pub prior_state_missing: u64,
    /// The keyframe's capture pose was not known (e.g. after a missed frame switch).
    pub prior_keyframe_missing: u64,
    /// Frame switches that did not continue the chained frame (a lost message).
    pub frame_switches_missed: u64,
    /// Rectification, SGM or odometry errors on one pair (the pair is skipped).
    pub errors: u64,
    /// Pairs copied out of their message to wait for their filter state (see the module docs).
    pub pairs_held: u64,
    /// Pairs the odometry skipped for their head attitude ([`VisionNodeOptions::vo_head_gate_rad`]).
    pub vo_skipped_head: u64,
    pub markers: MarkerSummary,
    pub surroundings: SurroundingsSummary,
}

/// The latest filter state, for the obstacle attitude and the filter status.
#[derive(Debug, Clone, Copy)]
struct LatestState {
    stamp_ns: u64,
    t_local_body: Isometry3<f64>,
    frame_id: u32,
    running: bool,
}

/// The vision process's node (see the module documentation).
#[derive(Debug)]
pub struct VisionNode {
    options: VisionNodeOptions,
    raw_calibration: StereoCalibration,
    calibration: StereoCalibration,
    rectifier: Option<Rectifier>,
    /// The rectified pair of a raw camera; holds the pair whose odometry waits for its filter
    /// state.
    frame: StereoFrame,
    odometry: StereoOdometry,
    /// SGM, speckle filter, depth.
    depth: DepthPipeline,
    classifier: ObstacleClassifier,
    labels: PixelLabels,
    markers: Option<MarkerStage>,
    /// Local obstacle map, hazard messages, gaze policy.
    surroundings: Surroundings,
    /// Capture stamp of the pair in `frame` whose odometry has not run yet.
    pending_capture_ns: Option<u64>,
    latest: Option<LatestState>,
    /// Frame id of the chain, and the current local frame in the chain's first frame.
    frame_id: Option<u32>,
    t_first_local: Isometry3<f64>,
    /// Recent running filter states (`t_first_body`, the chain's frame).
    states: PoseBuffer<FramePose>,
    /// The filter poses (`t_first_body`) at recent captures: the keyframe end of the prior.
    capture_poses: PoseBuffer<FramePose>,
    keyframe_ns: Option<u64>,
    /// Head angles of the last pair the odometry tracked, and since when pairs were skipped.
    vo_head: Option<(f64, f64)>,
    vo_skipping_since_ns: Option<u64>,
    summary: VisionNodeSummary,
}

fn failed(reason: String) -> NodeError {
    NodeError::Failed { node: NAME, reason }
}

/// The transform of a received pose, validated as [`Pose::to_isometry`] does, but keeping the
/// sender's quaternion bits when its norm is 1 to rounding: renormalizing it anyway changes the
/// last bits, and the odometry's discrete decisions (keyframes, inlier sets) can flip on such a
/// difference, so the two runners would not give the same numbers.
pub(crate) fn exact_isometry(pose: &Pose) -> Option<Isometry3<f64>> {
    let normalized = pose.to_isometry()?;
    let [w, x, y, z] = pose.rotation_wxyz;
    let q = nalgebra::Quaternion::new(w, x, y, z);
    if (q.norm() - 1.0).abs() > 4.0 * f64::EPSILON {
        return Some(normalized);
    }
    Some(Isometry3::from_parts(normalized.translation, nalgebra::UnitQuaternion::new_unchecked(q)))
}

/// A pose of the chained frame (one frame for all: the chain restarts after a missed switch).
fn chained(stamp_ns: u64, t_first_body: Isometry3<f64>) -> FramePose {
    FramePose { stamp_ns, frame_id: 0, pose: t_first_body, covariance: nalgebra::Matrix6::zeros() }
}

impl VisionNode {
    /// A node for a stereo head with the (raw or rectified) `calibration`.
    pub fn new(calibration: &StereoCalibration, options: VisionNodeOptions) -> Result<Self, NodeError> {
        let rectifier = if calibration.rectified {
            None
        } else {
            Some(Rectifier::new(calibration).map_err(|e| failed(e.to_string()))?)
        };
        let rectified = rectifier.as_ref().map_or(*calibration, Rectifier::rectified_calibration);
        let odometry = StereoOdometry::new(options.vo.clone(), &rectified).map_err(|e| failed(e.to_string()))?;
        let depth_options =
            DepthOptions { sgm: options.sgm, despeckle: options.despeckle, threads: options.sgm_threads.max(1) };
        let depth = DepthPipeline::new(&rectified, depth_options).map_err(|e| failed(format!("depth: {e}")))?;
        let classifier = ObstacleClassifier::new(options.obstacles).map_err(|e| failed(e.to_string()))?;
        let markers = match &options.markers {
            Some(m) => Some(MarkerStage::new(m.clone(), &rectified).map_err(failed)?),
            None => None,
        };
        let mut frame = StereoFrame::default();
        frame.resize(rectified.left.width_px, rectified.left.height_px);
        Ok(VisionNode {
            raw_calibration: *calibration,
            calibration: rectified,
            rectifier,
            frame,
            odometry,
            depth,
            classifier,
            labels: PixelLabels::default(),
            markers,
            surroundings: Surroundings::new(&options.obstacles, options.gaze),
            pending_capture_ns: None,
            latest: None,
            frame_id: None,
            t_first_local: Isometry3::identity(),
            // A later state of the same stamp (an update after the sample): the newest counts.
            states: PoseBuffer::bounded(STATES_KEPT, SameStamp::KeepLatest),
            capture_poses: PoseBuffer::bounded(CAPTURE_POSES_KEPT, SameStamp::KeepLatest),
            keyframe_ns: None,
            vo_head: None,
            vo_skipping_since_ns: None,
            summary: VisionNodeSummary::default(),
            options,
        })
    }

    pub fn summary(&self) -> VisionNodeSummary {
        VisionNodeSummary {
            markers: self.markers.as_ref().map(MarkerStage::summary).unwrap_or_default(),
            surroundings: self.surroundings.summary(),
            ..self.summary
        }
    }

    /// The rectified calibration the odometry and the disparity maps use.
    pub fn rectified_calibration(&self) -> &StereoCalibration {
        &self.calibration
    }

    /// The rolling local obstacle map (in the filter's current local frame).
    pub fn local_map(&self) -> &vision::obstacles::LocalObstacleMap {
        self.surroundings.map()
    }

    /// Per-pixel labels of the last classified pair.
    pub fn labels(&self) -> &PixelLabels {
        &self.labels
    }

    /// Runs the odometry of a pair still waiting for its filter state (end of the data).
    pub fn flush(&mut self, out: &mut dyn Outbox) -> Result<(), NodeError> {
        self.run_pending_odometry(out)
    }

    fn on_stereo(&mut self, header: &StereoHeader, bytes: &[u8], out: &mut dyn Outbox) -> Result<(), NodeError> {
        let raw = &self.raw_calibration;
        let (width, height) = (header.width_px as usize, header.height_px as usize);
        let n = width * height;
        if header.width_px != raw.left.width_px
            || header.height_px != raw.left.height_px
            || bytes.len() != 2 * n
            || !(header.pan_rad.is_finite() && header.tilt_rad.is_finite())
        {
            self.summary.bad_stereo += 1;
            return Ok(());
        }
        // The held pair is about to be replaced: it waited long enough.
        self.run_pending_odometry(out)?;
        self.summary.frames += 1;
        let (left, right) = bytes.split_at(n);
        let received = StereoView {
            stamp_ns: header.stamp_ns,
            sequence: header.sequence,
            width_px: header.width_px,
            height_px: header.height_px,
            left,
            right,
            pan_rad: header.pan_rad,
            tilt_rad: header.tilt_rad,
        };
        let rectified_here = match &self.rectifier {
            Some(rectifier) => {
                if rectifier.rectify_view(received, &mut self.frame).is_err() {
                    self.summary.errors += 1;
                    return Ok(());
                }
                true
            }
            None => false,
        };
        let pair = if rectified_here { StereoView::of(&self.frame) } else { received };
        if self.depth.compute(pair.left, pair.right).is_err() {
            self.summary.errors += 1;
            return Ok(());
        }
        self.classify(header.stamp_ns, header.pan_rad, header.tilt_rad);
        let (width_px, height_px) = self.depth.size_px();
        let disparity_header = DisparityHeader {
            stamp_ns: header.stamp_ns,
            sequence: header.sequence,
            pan_rad: header.pan_rad,
            tilt_rad: header.tilt_rad,
            width_px: width_px as u32,
            height_px: height_px as u32,
        };
        // Disparity and labels are merged straight into the message's memory.
        let (disparity, flags) = (&self.depth.disparity().data, &self.labels.flags);
        out.publish_disparity_with(&disparity_header, &|i| DisparityPixel {
            disparity_q4: disparity.get(i).copied().unwrap_or(DisparityPixel::INVALID),
            labels: flags.get(i).copied().unwrap_or(0),
            reserved: 0,
        })?;
        self.summary.disparity_published += 1;
        if let Some(markers) = &mut self.markers {
            let pair = if rectified_here { StereoView::of(&self.frame) } else { received };
            markers.process(pair, &self.calibration, out)?;
        }

        if self.skips_for_head(header) {
            self.summary.vo_skipped_head += 1;
            return Ok(());
        }
        let state_known = self.states.lookup(header.stamp_ns, STATE_INTERPOLATION_GAP_NS).is_some();
        let state_passed = self.latest.is_some_and(|l| l.stamp_ns > header.stamp_ns);
        if !self.options.odometry_follows_filter || state_known || state_passed {
            let Some(prior) = self.odometry_prior(header.stamp_ns) else { return Ok(()) };
            let disparity = self.options.sgm_depth_for_vo.then(|| self.depth.disparity());
            let pair = if rectified_here { StereoView::of(&self.frame) } else { received };
            let result = self.odometry.process_view(pair, disparity, prior.as_ref());
            return self.publish_odometry(header.stamp_ns, result, prior.is_some(), out);
        }
        // The odometry waits for the capture's filter state; the message's memory does not.
        if !rectified_here {
            self.frame.resize(header.width_px, header.height_px);
            self.frame.left.copy_from_slice(left);
            self.frame.right.copy_from_slice(right);
            self.summary.pairs_held += 1;
        }
        self.frame.stamp_ns = header.stamp_ns;
        self.frame.sequence = header.sequence;
        self.frame.pan_rad = header.pan_rad;
        self.frame.tilt_rad = header.tilt_rad;
        self.pending_capture_ns = Some(header.stamp_ns);
        Ok(())
    }

    /// Whether the odometry leaves this pair out for its head attitude (see
    /// [`VisionNodeOptions::vo_head_gate_rad`]); otherwise its angles become the reference.
    fn skips_for_head(&mut self, header: &StereoHeader) -> bool {
        let Some(gate) = self.options.vo_head_gate_rad else {
            return false;
        };
        let angles = (header.pan_rad, header.tilt_rad);
        if let Some((pan, tilt)) = self.vo_head
            && ((angles.0 - pan).abs() > gate || (angles.1 - tilt).abs() > gate)
        {
            let since = *self.vo_skipping_since_ns.get_or_insert(header.stamp_ns);
            if header.stamp_ns.saturating_sub(since) < VO_HEAD_GATE_MAX_NS {
                return true;
            }
        }
        self.vo_head = Some(angles);
        self.vo_skipping_since_ns = None;
        false
    }

    /// Obstacle labels on the pipeline's depth.
    fn classify(&mut self, stamp_ns: u64, pan_rad: f64, tilt_rad: f64) {
        // Without an IMU the filter's frame is not levelled: no attitude to classify against.
        let levelled = self.options.odometry_follows_filter;
        let (depth, geometry) = (self.depth.depth(), self.depth.geometry());
        match self.latest.filter(|l| l.running && levelled) {
            Some(latest) => {
                let t_local_cam = latest.t_local_body * self.calibration.t_body_left(pan_rad, tilt_rad);
                self.classifier.classify(depth, geometry, &t_local_cam, &mut self.labels);
                self.surroundings.integrate(
                    stamp_ns,
                    &latest.t_local_body,
                    latest.frame_id,
                    self.classifier.height_map(),
                );
            }
            None => {
                self.summary.frames_without_attitude += 1;
                self.labels.width = depth.width;
                self.labels.height = depth.height;
                self.labels.flags.clear();
                self.labels.flags.resize(depth.width * depth.height, 0);
            }
        }
    }

    fn on_filter_state(&mut self, state: &FilterStateMsg, out: &mut dyn Outbox) -> Result<(), NodeError> {
        let Some(t_local_body) = exact_isometry(&state.t_local_body) else {
            self.summary.bad_filter_states += 1;
            return Ok(());
        };
        match self.frame_id {
            Some(current) if state.frame_id < current => return Ok(()),
            Some(current) if state.frame_id > current => {
                self.summary.frame_switches_missed += 1;
                self.restart_chain(state.frame_id);
            }
            Some(_) => {}
            None => self.frame_id = Some(state.frame_id),
        }
        let running = state.status == FilterStateMsg::RUNNING;
        self.latest = Some(LatestState { stamp_ns: state.stamp_ns, t_local_body, frame_id: state.frame_id, running });
        if running {
            self.surroundings.on_state(state.stamp_ns, &t_local_body, state.v_local_mps);
            self.states.insert(chained(state.stamp_ns, self.t_first_local * t_local_body));
        }
        if self.pending_capture_ns.is_some_and(|capture| state.stamp_ns >= capture) {
            self.run_pending_odometry(out)?;
        }
        Ok(())
    }

    fn on_frame_switch(&mut self, switch: &FrameSwitchMsg) {
        let Some(t_old_new) = exact_isometry(&switch.t_old_new) else {
            self.summary.bad_filter_states += 1;
            return;
        };
        match self.frame_id {
            Some(current) if current == switch.old_frame_id => {
                self.t_first_local *= t_old_new;
                self.frame_id = Some(switch.new_frame_id);
                self.surroundings.on_frame_switch(&t_old_new, switch.new_frame_id);
            }
            Some(current) if current >= switch.new_frame_id => {}
            _ => {
                self.summary.frame_switches_missed += 1;
                self.restart_chain(switch.new_frame_id);
            }
        }
    }

    /// Poses from before a missed switch cannot be related to later ones.
    fn restart_chain(&mut self, frame_id: u32) {
        self.frame_id = Some(frame_id);
        self.t_first_local = Isometry3::identity();
        self.states.clear();
        self.capture_poses.clear();
        self.surroundings.forget();
    }

    /// The odometry of the pair held in `frame`, if one waits.
    fn run_pending_odometry(&mut self, out: &mut dyn Outbox) -> Result<(), NodeError> {
        let Some(capture_ns) = self.pending_capture_ns.take() else {
            return Ok(());
        };
        let Some(prior) = self.odometry_prior(capture_ns) else { return Ok(()) };
        let disparity = self.options.sgm_depth_for_vo.then(|| self.depth.disparity());
        let result = self.odometry.process_view(StereoView::of(&self.frame), disparity, prior.as_ref());
        self.publish_odometry(capture_ns, result, prior.is_some(), out)
    }

    /// The prior of the capture at `capture_ns` (the filter's keyframe→capture motion, `None`
    /// without one); the outer `None` when the odometry must not run yet (the filter has not
    /// started).
    fn odometry_prior(&mut self, capture_ns: u64) -> Option<Option<Isometry3<f64>>> {
        let t_first_body = if self.options.odometry_follows_filter {
            self.states.lookup(capture_ns, STATE_INTERPOLATION_GAP_NS).map(|s| s.pose)
        } else {
            None
        };
        if t_first_body.is_none() && self.options.odometry_follows_filter {
            if !self.latest.is_some_and(|l| l.running) {
                self.summary.frames_before_init += 1;
                return None;
            }
            self.summary.prior_state_missing += 1;
        }
        let mut prior = None;
        if let Some(t_first_body) = t_first_body {
            self.capture_poses.insert(chained(capture_ns, t_first_body));
            if self.options.vo_prior
                && let Some(keyframe_ns) = self.keyframe_ns
            {
                match self.capture_poses.exact(keyframe_ns) {
                    Some(keyframe) => prior = Some(keyframe.pose.inverse() * t_first_body),
                    None => self.summary.prior_keyframe_missing += 1,
                }
            }
        }
        Some(prior)
    }

    fn publish_odometry(
        &mut self,
        capture_ns: u64,
        result: Result<VoOutput, VoError>,
        prior_used: bool,
        out: &mut dyn Outbox,
    ) -> Result<(), NodeError> {
        let Ok(output) = result else {
            self.summary.errors += 1;
            return Ok(());
        };
        if prior_used {
            self.summary.priors_used += 1;
        }
        self.record_vo(capture_ns, &output);
        out.publish(Message::VoDelta(&vo_message(capture_ns, &output)))
    }

    fn record_vo(&mut self, capture_ns: u64, output: &VoOutput) {
        self.summary.vo_frames += 1;
        if output.new_keyframe {
            self.summary.keyframes += 1;
            self.keyframe_ns = Some(capture_ns);
        }
        if output.reset {
            self.summary.vo_resets += 1;
        }
        if let Some(delta) = &output.delta {
            self.summary.vo_deltas += 1;
            self.summary.inliers_sum += u64::from(delta.inliers);
            self.summary.min_inliers = Some(self.summary.min_inliers.map_or(delta.inliers, |m| m.min(delta.inliers)));
            if !output.new_keyframe {
                self.keyframe_ns = Some(delta.keyframe_stamp_ns);
            }
        }
    }
}

/// The bus form of one odometry result.
pub fn vo_message(capture_ns: u64, output: &VoOutput) -> VoDeltaMsg {
    let mut flags = 0;
    if output.new_keyframe {
        flags |= VoDeltaMsg::NEW_KEYFRAME;
    }
    if output.reset {
        flags |= VoDeltaMsg::RESET;
    }
    let mut message = VoDeltaMsg {
        capture_stamp_ns: capture_ns,
        keyframe_stamp_ns: 0,
        t_keyframe_current_body: Pose::IDENTITY,
        covariance_body: [0.0; 36],
        t_odom_body: Pose::from_isometry(&output.t_odom_body),
        inliers: 0,
        flags,
    };
    if let Some(delta) = &output.delta {
        message.flags |= VoDeltaMsg::HAS_DELTA;
        message.keyframe_stamp_ns = delta.keyframe_stamp_ns;
        message.t_keyframe_current_body = Pose::from_isometry(&delta.t_keyframe_current_body);
        message.covariance_body = msgs::covariance_to_array(&delta.covariance_body);
        message.inliers = delta.inliers;
    }
    message
}

impl Node for VisionNode {
    fn name(&self) -> &'static str {
        NAME
    }

    fn subscriptions(&self) -> &'static [Topic] {
        &[Topic::Stereo, Topic::FilterState, Topic::FrameSwitch]
    }

    fn on_message(&mut self, message: Message<'_>, out: &mut dyn Outbox) -> Result<(), NodeError> {
        match message {
            Message::Stereo(header, bytes) => self.on_stereo(header, bytes, out),
            Message::FilterState(state) => self.on_filter_state(state, out),
            Message::FrameSwitch(switch) => {
                self.on_frame_switch(switch);
                Ok(())
            }
            _ => Ok(()),
        }
    }

    fn on_tick(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        if self.pending_capture_ns.is_some_and(|capture| now_ns >= capture.saturating_add(self.options.prior_wait_ns)) {
            self.run_pending_odometry(out)?;
        }
        self.surroundings.on_tick(now_ns, out)
    }
}
