//! Keyframe stereo visual odometry (thesis §3.2, §4.1.1).
//!
//! # Per frame
//!
//! 1. Build the left image pyramid; predict the current camera pose (the caller's prior relative
//!    to the keyframe, else constant body velocity from the last two frames, scaled by the frame
//!    interval), project every track's landmark with it and KLT-track all tracks from the previous
//!    frame into the current one from those predicted positions.
//! 2. Collect keyframe-landmark ↔ current-pixel correspondences of the active keyframe and
//!    estimate the camera motion (P3P-RANSAC, robust refinement, propagated covariance). Tracks
//!    that are outliers lose their link to that keyframe.
//! 3. Output the delta relative to the keyframe in camera and body coordinates (the body delta
//!    uses the head angles at both capture times).
//!
//! # Keyframe policy (thesis §4.1.1, "locally drift-free")
//!
//! The history holds the last [`MAX_KEYFRAMES`] keyframes; all of them share one pool of tracks
//! (see [`crate::keyframes`]), so a landmark of an older keyframe stays measurable as long as
//! its point is tracked. The estimate against the *active* keyframe is **healthy** when its
//! inliers reach both `keyframe_min_inliers` and `keyframe_inlier_fraction` of the keyframe's
//! landmarks and the inliers cover at least `min_coverage_cells` cells of a 4×4 image grid.
//!
//! - Healthy: delta to the active keyframe, no new keyframe. A standing rover keeps its keyframe
//!   indefinitely, so its deltas stay bounded (no drift by accumulation).
//! - Not healthy: the other history keyframes whose tracked support could be healthy are tried,
//!   most supported first; a healthy one becomes the active keyframe (no new keyframe). This is
//!   how a rover moving back and forth keeps measuring against the same keyframes.
//! - None healthy but the active estimate is usable (at least `loss_min_inliers`): the delta to
//!   the active keyframe is output and the current frame becomes a new keyframe
//!   (`new_keyframe = true`), replacing the least recently used slot.
//! - No usable estimate against any keyframe: **tracking loss**. `reset = true`, `delta = None`,
//!   the history is cleared and the frame starts a fresh keyframe. `t_odom_body` continues with
//!   the predicted pose (the caller's prior, else constant velocity), so the stereo-only
//!   trajectory stays continuous; the filter must not use a delta across the reset.
//!
//! The prior passed to [`StereoOdometry::process`] is relative to the keyframe of the previous
//! output (`VoStats::keyframe_stamp_ns`; the previous frame itself when it became a keyframe).

use crate::features::{FeatureConfig, FeatureDetector, Keypoint};
use crate::geometry::{
    Correspondence, PoseEstimate, PoseEstimationConfig, PoseEstimator, camera_delta_to_body, triangulate,
};
use crate::image::StereoView;
use crate::keyframes::{KeyframeHistory, Landmark, MAX_KEYFRAMES, NO_LANDMARK, Track, coverage_cells};
use crate::klt::{KltConfig, KltTracker};
use crate::pyramid::Pyramid;
use crate::stereo_match::{SparseStereo, StereoMatchConfig, disparity_from_map};
use crate::{ImageView, VoDelta};
use fpga_model::DisparityImage;
use hal::sensor::{Pinhole, StereoCalibration, StereoFrame};
use nalgebra::{Isometry3, Point3, Translation3};

/// Tuning of the odometry. `Default` is the rover set-up (1024×508, 10 Hz).
#[derive(Debug, Clone, PartialEq)]
pub struct VoConfig {
    pub features: FeatureConfig,
    pub klt: KltConfig,
    pub stereo: StereoMatchConfig,
    pub pose: PoseEstimationConfig,
    /// Pyramid levels for KLT (level 0 = full resolution).
    pub pyramid_levels: usize,
    /// Pixel noise of a keyframe feature used for triangulation.
    pub pixel_sigma_px: f64,
    /// Disparity noise of sparse (ZNCC, sub-pixel) matches.
    pub sparse_disparity_sigma_px: f64,
    /// Disparity noise of the SGM map (1/16 px quantisation, but smoothing and foreshortening).
    pub map_disparity_sigma_px: f64,
    /// Landmarks with a smaller disparity are not kept (too far to constrain translation, and a
    /// near-zero disparity error model is unreliable).
    pub min_disparity_px: f64,
    /// Healthy estimate: inliers ≥ this fraction of the keyframe's landmarks...
    pub keyframe_inlier_fraction: f64,
    /// ... and at least this many.
    pub keyframe_min_inliers: u32,
    /// Healthy estimate: the inliers occupy at least this many cells of the 4×4 image grid.
    pub min_coverage_cells: u32,
    /// Fewer inliers than this against every keyframe is a tracking loss.
    pub loss_min_inliers: u32,
    /// Hand the predicted pose to the pose estimator as an extra RANSAC hypothesis. Off by
    /// default: on the simulated drive, deltas seeded with the constant-velocity prediction were
    /// biased towards it (body-delta NEES in the hundreds, 3.6 % drift, against NEES 5 and
    /// 0.25 % without); KLT still uses the prediction.
    pub prior_hypothesis: bool,
    /// Re-acquire lost landmarks of history keyframes (KLT from the keyframe image at the
    /// predicted position) before creating a new keyframe.
    pub reacquire: bool,
}

impl Default for VoConfig {
    fn default() -> Self {
        VoConfig {
            features: FeatureConfig::default(),
            klt: KltConfig::default(),
            stereo: StereoMatchConfig::default(),
            pose: PoseEstimationConfig::default(),
            pyramid_levels: 4,
            pixel_sigma_px: 0.5,
            sparse_disparity_sigma_px: 0.3,
            map_disparity_sigma_px: 0.5,
            min_disparity_px: 1.0,
            keyframe_inlier_fraction: 0.5,
            keyframe_min_inliers: 60,
            min_coverage_cells: 5,
            loss_min_inliers: 15,
            prior_hypothesis: false,
            reacquire: true,
        }
    }
}

/// Why the odometry could not process a frame.
#[derive(Debug, thiserror::Error)]
pub enum VoError {
    /// The calibration is not a rectified pair (rectify first) or the frame does not match it.
    #[error("stereo odometry: {0}")]
    BadInput(String),
}

/// Per-frame counters, for telemetry and benchmarks.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct VoStats {
    /// Features tracked from the keyframe into this frame.
    pub tracked: u32,
    /// Tracked features with a valid depth in the keyframe.
    pub with_depth: u32,
    pub inliers: u32,
    /// Reprojection RMS of the inliers after refinement, pixels.
    pub rms_px: f64,
    /// Keyframes held in the history (at most 5).
    pub keyframes: u32,
    /// All tracks alive after this frame (every keyframe's).
    pub tracks: u32,
    /// Occupied cells of the 4×4 grid by the inliers.
    pub coverage_cells: u32,
    /// Identity of the keyframe the next frame will be measured against (increases with every
    /// keyframe created) and its capture time.
    pub keyframe_id: u64,
    pub keyframe_stamp_ns: u64,
    /// The active keyframe changed to an older history keyframe instead of creating a new one.
    pub switched_keyframe: bool,
}

/// What one frame produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoOutput {
    /// Motion relative to a keyframe; `None` for the first frame and after a tracking loss.
    pub delta: Option<VoDelta>,
    /// This frame became a keyframe (the filter keeps its clone of this capture time).
    pub new_keyframe: bool,
    /// The odometry lost track and restarted from this frame as a fresh keyframe.
    pub reset: bool,
    /// Pose of the current body in the odometry's own frame (the body frame of the first
    /// keyframe), chained through the keyframes: the stereo-only trajectory.
    pub t_odom_body: Isometry3<f64>,
    pub stats: VoStats,
}

/// Outcome of estimating against one keyframe slot.
#[derive(Debug, Clone, Copy)]
struct SlotEstimate {
    slot: usize,
    estimate: PoseEstimate,
    coverage: u32,
    with_depth: u32,
}

/// Keyframe-based stereo odometry on rectified pairs.
pub struct StereoOdometry {
    config: VoConfig,
    calibration: StereoCalibration,
    intrinsics: Pinhole,
    width: usize,
    height: usize,
    previous: Pyramid,
    current: Pyramid,
    detector: FeatureDetector,
    klt: KltTracker,
    sparse: SparseStereo,
    estimator: PoseEstimator,
    history: KeyframeHistory,
    /// Left pyramid of each keyframe slot, to re-acquire a keyframe's landmarks whose tracks were
    /// lost (the head panned away and back, the rover drove back).
    keyframe_pyramids: Vec<Pyramid>,
    active: usize,
    /// Frames processed (0 = nothing yet).
    frames: u64,
    last_stamp_ns: u64,
    last_t_odom_body: Isometry3<f64>,
    /// Body motion from the frame before the last to the last one, and its interval.
    last_motion_body: Isometry3<f64>,
    last_interval_ns: u64,
    // Per-frame scratch, capacity kept.
    points: Vec<[f32; 2]>,
    predicted: Vec<[f32; 2]>,
    tracked: Vec<Option<[f32; 2]>>,
    correspondences: Vec<Correspondence>,
    correspondence_track: Vec<u32>,
    inlier_mask: Vec<bool>,
    keypoints: Vec<Keypoint>,
    linked: Vec<bool>,
    reacquire_landmark: Vec<u32>,
}

impl std::fmt::Debug for StereoOdometry {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StereoOdometry")
            .field("width", &self.width)
            .field("height", &self.height)
            .field("frames", &self.frames)
            .field("keyframes", &self.history.live_count())
            .field("tracks", &self.history.tracks.len())
            .finish_non_exhaustive()
    }
}

impl StereoOdometry {
    /// Odometry for a rectified stereo calibration (`calibration.rectified` must hold).
    pub fn new(config: VoConfig, calibration: &StereoCalibration) -> Result<Self, VoError> {
        if !calibration.rectified {
            return Err(VoError::BadInput("calibration is not rectified (rectify the pair first)".into()));
        }
        let width = calibration.left.width_px as usize;
        let height = calibration.left.height_px as usize;
        if width < 64 || height < 64 {
            return Err(VoError::BadInput(format!("image size {width}x{height} is too small")));
        }
        let intrinsics = calibration.left.intrinsics;
        let finite = [intrinsics.fx_px, intrinsics.fy_px, intrinsics.cx_px, intrinsics.cy_px, calibration.baseline_m];
        if finite.iter().any(|v| !v.is_finite()) || intrinsics.fx_px <= 0.0 || intrinsics.fy_px <= 0.0 {
            return Err(VoError::BadInput("intrinsics must be finite with positive focal lengths".into()));
        }
        if calibration.baseline_m.abs() < 1e-6 {
            return Err(VoError::BadInput("stereo baseline must not be zero".into()));
        }
        let levels = config.pyramid_levels.max(1);
        let max_features = config.features.max_features;
        Ok(StereoOdometry {
            detector: FeatureDetector::new(config.features.clone(), width, height),
            klt: KltTracker::new(config.klt.clone()),
            sparse: SparseStereo::new(config.stereo.clone()),
            estimator: PoseEstimator::new(config.pose.clone()),
            previous: Pyramid::new(width, height, levels),
            current: Pyramid::new(width, height, levels),
            calibration: *calibration,
            intrinsics,
            width,
            height,
            history: KeyframeHistory::new(),
            keyframe_pyramids: (0..MAX_KEYFRAMES).map(|_| Pyramid::new(width, height, levels)).collect(),
            active: 0,
            frames: 0,
            last_stamp_ns: 0,
            last_t_odom_body: Isometry3::identity(),
            last_motion_body: Isometry3::identity(),
            last_interval_ns: 0,
            points: Vec::with_capacity(2 * max_features),
            predicted: Vec::with_capacity(2 * max_features),
            tracked: Vec::with_capacity(2 * max_features),
            correspondences: Vec::with_capacity(2 * max_features),
            correspondence_track: Vec::with_capacity(2 * max_features),
            inlier_mask: Vec::with_capacity(2 * max_features),
            keypoints: Vec::with_capacity(max_features),
            linked: Vec::with_capacity(2 * max_features),
            reacquire_landmark: Vec::with_capacity(2 * max_features),
            config,
        })
    }

    pub fn config(&self) -> &VoConfig {
        &self.config
    }

    /// The keyframe history (for telemetry and tests).
    pub fn history(&self) -> &KeyframeHistory {
        &self.history
    }

    /// Processes one rectified pair. `disparity` is the SGM map of this pair when the FPGA
    /// produced one (else features are matched sparsely). `prior_t_keyframe_current_body`
    /// predicts the motion (from the filter's gyro) to seed tracking; it is relative to the
    /// keyframe of the previous output (`stats.keyframe_stamp_ns`).
    pub fn process(
        &mut self,
        frame: &StereoFrame,
        disparity: Option<&DisparityImage>,
        prior_t_keyframe_current_body: Option<&Isometry3<f64>>,
    ) -> Result<VoOutput, VoError> {
        self.process_view(StereoView::of(frame), disparity, prior_t_keyframe_current_body)
    }

    /// As [`StereoOdometry::process`], reading the pair where it lies (e.g. in shared memory).
    pub fn process_view(
        &mut self,
        frame: StereoView<'_>,
        disparity: Option<&DisparityImage>,
        prior_t_keyframe_current_body: Option<&Isometry3<f64>>,
    ) -> Result<VoOutput, VoError> {
        self.check_input(frame, disparity)?;
        let (w, h) = (self.width, self.height);
        let Some(left) = ImageView::new(w, h, frame.left) else {
            return Err(VoError::BadInput("left image size".into()));
        };
        self.current.build(left);
        let t_body_cam = self.calibration.t_body_left(frame.pan_rad, frame.tilt_rad);

        if self.frames == 0 {
            let stats = self.start_fresh(frame, disparity, Isometry3::identity(), t_body_cam);
            return Ok(self.finish(frame, Isometry3::identity(), None, true, false, stats));
        }

        let t_odom_body_predicted = self.predict_body(frame.stamp_ns, prior_t_keyframe_current_body);
        let t_odom_cam_predicted = t_odom_body_predicted * t_body_cam;
        self.track_features(&t_odom_cam_predicted);

        let active = self.active;
        let first = self.estimate_slot(active, &t_odom_cam_predicted);
        if let Some(e) = first.filter(|e| self.healthy(e)) {
            return Ok(self.output_delta(frame, disparity, e, t_body_cam, false, false));
        }
        // The active keyframe's support dropped: an older keyframe that still sees enough?
        if self.config.reacquire {
            for slot in 0..MAX_KEYFRAMES {
                if slot != active && self.history.is_live(slot) {
                    self.reacquire(slot, &t_odom_cam_predicted);
                }
            }
        }
        let mut best_usable = first.filter(|e| e.estimate.inliers >= self.config.loss_min_inliers);
        let mut tried = 1u32 << active;
        while let Some(candidate) = self.best_candidate(tried) {
            tried |= 1 << candidate;
            let Some(e) = self.estimate_slot(candidate, &t_odom_cam_predicted) else {
                continue;
            };
            if self.healthy(&e) {
                self.active = e.slot;
                return Ok(self.output_delta(frame, disparity, e, t_body_cam, false, true));
            }
            if e.estimate.inliers >= self.config.loss_min_inliers
                && best_usable.is_none_or(|b| e.estimate.inliers > b.estimate.inliers)
            {
                best_usable = Some(e);
            }
        }
        match best_usable {
            Some(e) => Ok(self.output_delta(frame, disparity, e, t_body_cam, true, false)),
            None => {
                // Tracking loss: restart from this frame, continue the trajectory by prediction.
                let stats = self.start_fresh(frame, disparity, t_odom_body_predicted, t_body_cam);
                Ok(self.finish(frame, t_odom_body_predicted, None, true, true, stats))
            }
        }
    }

    fn check_input(&self, frame: StereoView<'_>, disparity: Option<&DisparityImage>) -> Result<(), VoError> {
        let (w, h) = (self.width, self.height);
        if frame.width_px as usize != w || frame.height_px as usize != h {
            return Err(VoError::BadInput(format!(
                "frame is {}x{}, calibration {w}x{h}",
                frame.width_px, frame.height_px
            )));
        }
        if frame.left.len() != w * h || frame.right.len() != w * h {
            return Err(VoError::BadInput("image buffers do not match the frame size".into()));
        }
        if let Some(map) = disparity
            && (map.width != w || map.height != h || map.data.len() != w * h)
        {
            return Err(VoError::BadInput(format!("disparity map is {}x{}, frame {w}x{h}", map.width, map.height)));
        }
        if self.frames > 0 && frame.stamp_ns <= self.last_stamp_ns {
            return Err(VoError::BadInput(format!(
                "frame stamp {} ns does not follow {} ns",
                frame.stamp_ns, self.last_stamp_ns
            )));
        }
        Ok(())
    }

    /// Predicted body pose of the current frame in the odometry frame.
    fn predict_body(&self, stamp_ns: u64, prior: Option<&Isometry3<f64>>) -> Isometry3<f64> {
        if let Some(prior) = prior {
            return self.history.keyframe(self.active).t_odom_body * prior;
        }
        let interval = stamp_ns.saturating_sub(self.last_stamp_ns);
        let motion = if self.last_interval_ns == 0 {
            Isometry3::identity()
        } else {
            scale_motion(&self.last_motion_body, interval as f64 / self.last_interval_ns as f64)
        };
        self.last_t_odom_body * motion
    }

    /// KLT-tracks every track from the previous image into the current one and drops lost ones.
    fn track_features(&mut self, t_odom_cam_predicted: &Isometry3<f64>) {
        // Where each slot's landmarks land in the predicted current camera.
        let t_inv = t_odom_cam_predicted.inverse();
        let t_current_slot: [Option<Isometry3<f64>>; MAX_KEYFRAMES] =
            std::array::from_fn(|s| self.history.is_live(s).then(|| t_inv * self.history.keyframe(s).t_odom_cam()));
        self.points.clear();
        self.predicted.clear();
        for track in &self.history.tracks {
            self.points.push(track.pixel);
            let mut guess = track.pixel;
            // Prefer the active keyframe's landmark (the one the prior is relative to).
            let order = std::iter::once(self.active).chain((0..MAX_KEYFRAMES).filter(|&s| s != self.active));
            for slot in order {
                let (index, Some(t)) = (track.landmark[slot], t_current_slot[slot]) else {
                    continue;
                };
                if index == NO_LANDMARK {
                    continue;
                }
                let landmark = &self.history.keyframe(slot).landmarks[index as usize];
                if let Some(pixel) = self.project(&(t * Point3::from(landmark.point_m))) {
                    guess = pixel;
                }
                break;
            }
            self.predicted.push(guess);
        }
        self.klt.track(&self.previous, &self.current, &self.points, Some(&self.predicted), &mut self.tracked);
        let tracked = &self.tracked;
        let mut index = 0;
        self.history.tracks.retain_mut(|track| {
            let result = tracked.get(index).copied().flatten();
            index += 1;
            match result {
                Some(pixel) => {
                    track.pixel = pixel;
                    true
                }
                None => false,
            }
        });
    }

    /// Pixel of a point in the current camera, `None` behind it or outside the image.
    fn project(&self, p: &Point3<f64>) -> Option<[f32; 2]> {
        if p.z < 0.05 {
            return None;
        }
        let x = self.intrinsics.fx_px * p.x / p.z + self.intrinsics.cx_px;
        let y = self.intrinsics.fy_px * p.y / p.z + self.intrinsics.cy_px;
        let inside = x >= 0.0 && y >= 0.0 && x <= (self.width - 1) as f64 && y <= (self.height - 1) as f64;
        inside.then_some([x as f32, y as f32])
    }

    /// Pose of the current camera relative to the keyframe in `slot`. Outlier tracks lose their
    /// link to that keyframe (tracks left without any landmark are dropped).
    fn estimate_slot(&mut self, slot: usize, t_odom_cam_predicted: &Isometry3<f64>) -> Option<SlotEstimate> {
        if !self.history.is_live(slot) {
            return None;
        }
        self.correspondences.clear();
        self.correspondence_track.clear();
        let keyframe = self.history.keyframe(slot);
        for (i, track) in self.history.tracks.iter().enumerate() {
            let index = track.landmark[slot];
            if index == NO_LANDMARK {
                continue;
            }
            let landmark = &keyframe.landmarks[index as usize];
            self.correspondences.push(Correspondence {
                point_keyframe_m: landmark.point_m,
                point_covariance_m2: landmark.covariance_m2,
                pixel_current: [f64::from(track.pixel[0]), f64::from(track.pixel[1])],
            });
            self.correspondence_track.push(i as u32);
        }
        let with_depth = self.correspondences.len() as u32;
        let prior = keyframe.t_odom_cam().inverse() * t_odom_cam_predicted;
        let result = self.estimator.estimate(
            &self.intrinsics,
            &self.correspondences,
            self.config.prior_hypothesis.then_some(&prior),
            &mut self.inlier_mask,
        );
        let estimate = match result {
            Ok(estimate) => estimate,
            Err(_) => {
                // Nothing of this keyframe can be trusted in this frame; its links go.
                for &t in &self.correspondence_track {
                    self.history.tracks[t as usize].landmark[slot] = NO_LANDMARK;
                }
                self.history.tracks.retain(Track::has_any_landmark);
                return None;
            }
        };
        let coverage = coverage_cells(
            self.correspondences
                .iter()
                .zip(&self.inlier_mask)
                .filter(|&(_, &inlier)| inlier)
                .map(|(c, _)| [c.pixel_current[0] as f32, c.pixel_current[1] as f32]),
            self.width,
            self.height,
        );
        for (&t, &inlier) in self.correspondence_track.iter().zip(&self.inlier_mask) {
            if !inlier {
                self.history.tracks[t as usize].landmark[slot] = NO_LANDMARK;
            }
        }
        self.history.tracks.retain(Track::has_any_landmark);
        Some(SlotEstimate { slot, estimate, coverage, with_depth })
    }

    fn required_inliers(&self, slot: usize) -> u32 {
        let landmarks = self.history.keyframe(slot).landmarks.len() as f64;
        ((self.config.keyframe_inlier_fraction * landmarks).ceil() as u32).max(self.config.keyframe_min_inliers)
    }

    fn healthy(&self, e: &SlotEstimate) -> bool {
        e.estimate.inliers >= self.required_inliers(e.slot) && e.coverage >= self.config.min_coverage_cells
    }

    /// The history keyframe not yet `tried` (bit mask of slots) whose tracked support could still
    /// give a healthy estimate, most supported first.
    fn best_candidate(&self, tried: u32) -> Option<usize> {
        (0..MAX_KEYFRAMES)
            .filter(|&s| tried & (1 << s) == 0 && self.history.is_live(s))
            .map(|s| (s, self.history.support(s) as u32))
            .filter(|&(s, support)| {
                support >= self.required_inliers(s)
                    && self.history.support_coverage(s, self.width, self.height) >= self.config.min_coverage_cells
            })
            .max_by_key(|&(_, support)| support)
            .map(|(s, _)| s)
    }

    /// Output of a frame with a delta against `e.slot`; with `make_keyframe` the frame then
    /// becomes a new keyframe.
    fn output_delta(
        &mut self,
        frame: StereoView<'_>,
        disparity: Option<&DisparityImage>,
        e: SlotEstimate,
        t_body_cam: Isometry3<f64>,
        make_keyframe: bool,
        switched: bool,
    ) -> VoOutput {
        let keyframe = self.history.keyframe_mut(e.slot);
        keyframe.last_used_frame = self.frames;
        let (t_kb_cb, covariance_body) = camera_delta_to_body(
            &e.estimate.t_keyframe_current_cam,
            &e.estimate.covariance,
            &keyframe.t_body_cam,
            &t_body_cam,
        );
        let delta = VoDelta {
            stamp_ns: frame.stamp_ns,
            keyframe_stamp_ns: keyframe.stamp_ns,
            t_keyframe_current_body: t_kb_cb,
            covariance_body,
            t_keyframe_current_cam: e.estimate.t_keyframe_current_cam,
            covariance_cam: e.estimate.covariance,
            inliers: e.estimate.inliers,
        };
        let t_odom_body = keyframe.t_odom_body * t_kb_cb;
        let mut stats = VoStats {
            tracked: self.history.tracks.len() as u32,
            with_depth: e.with_depth,
            inliers: e.estimate.inliers,
            rms_px: e.estimate.rms_px,
            coverage_cells: e.coverage,
            switched_keyframe: switched,
            ..VoStats::default()
        };
        if make_keyframe {
            let left = ImageView { width: self.width, height: self.height, data: frame.left };
            let right = ImageView { width: self.width, height: self.height, data: frame.right };
            let slot = self.history.begin_keyframe(frame.stamp_ns, t_odom_body, t_body_cam, self.frames, Some(e.slot));
            self.populate_keyframe(slot, left, right, disparity);
            self.active = slot;
        }
        stats.tracks = self.history.tracks.len() as u32;
        self.finish(frame, t_odom_body, Some(delta), make_keyframe, false, stats)
    }

    /// Clears the history and makes the frame the only keyframe.
    fn start_fresh(
        &mut self,
        frame: StereoView<'_>,
        disparity: Option<&DisparityImage>,
        t_odom_body: Isometry3<f64>,
        t_body_cam: Isometry3<f64>,
    ) -> VoStats {
        self.history.clear();
        let left = ImageView { width: self.width, height: self.height, data: frame.left };
        let right = ImageView { width: self.width, height: self.height, data: frame.right };
        let slot = self.history.begin_keyframe(frame.stamp_ns, t_odom_body, t_body_cam, self.frames, None);
        self.populate_keyframe(slot, left, right, disparity);
        self.active = slot;
        VoStats { tracks: self.history.tracks.len() as u32, ..VoStats::default() }
    }

    /// Gives the new keyframe in `slot` its landmarks: the tracked points with a depth now, plus
    /// new corners in image cells without a track.
    fn populate_keyframe(
        &mut self,
        slot: usize,
        left: ImageView<'_>,
        right: ImageView<'_>,
        disparity: Option<&DisparityImage>,
    ) {
        if self.config.reacquire {
            self.keyframe_pyramids[slot].build(left);
        }
        let mut landmarks = std::mem::take(&mut self.history.keyframe_mut(slot).landmarks);
        landmarks.clear();
        self.points.clear();
        for i in 0..self.history.tracks.len() {
            let pixel = self.history.tracks[i].pixel;
            self.points.push(pixel);
            if let Some(landmark) = self.landmark_at(left, right, disparity, pixel) {
                self.history.tracks[i].landmark[slot] = landmarks.len() as u32;
                landmarks.push(landmark);
            }
        }
        self.detector.detect(left, &self.points, &mut self.keypoints);
        for k in 0..self.keypoints.len() {
            let pixel = [self.keypoints[k].x, self.keypoints[k].y];
            if let Some(landmark) = self.landmark_at(left, right, disparity, pixel) {
                let mut track = Track::new(pixel);
                track.landmark[slot] = landmarks.len() as u32;
                landmarks.push(landmark);
                self.history.tracks.push(track);
            }
        }
        self.history.keyframe_mut(slot).landmarks = landmarks;
    }

    /// Starts new tracks for the landmarks of `slot` that no track follows any more but that the
    /// predicted pose puts into the current image: KLT from the keyframe's own image, seeded with
    /// the projection (forward-backward checked by the tracker, outliers left to RANSAC).
    fn reacquire(&mut self, slot: usize, t_odom_cam_predicted: &Isometry3<f64>) {
        let keyframe = self.history.keyframe(slot);
        self.linked.clear();
        self.linked.resize(keyframe.landmarks.len(), false);
        for track in &self.history.tracks {
            if let Some(l) = self.linked.get_mut(track.landmark[slot] as usize) {
                *l = true;
            }
        }
        let t_current_keyframe = t_odom_cam_predicted.inverse() * keyframe.t_odom_cam();
        let margin = self.config.klt.window_radius_px as f64 + 1.0;
        self.points.clear();
        self.predicted.clear();
        self.reacquire_landmark.clear();
        for (index, landmark) in keyframe.landmarks.iter().enumerate() {
            if self.linked[index] {
                continue;
            }
            let Some(pixel) = self.project(&(t_current_keyframe * Point3::from(landmark.point_m))) else {
                continue;
            };
            let inside = |v: f32, size: usize| f64::from(v) >= margin && f64::from(v) <= size as f64 - 1.0 - margin;
            if inside(pixel[0], self.width) && inside(pixel[1], self.height) {
                self.points.push(landmark.pixel_keyframe);
                self.predicted.push(pixel);
                self.reacquire_landmark.push(index as u32);
            }
        }
        if self.points.is_empty() {
            return;
        }
        self.klt.track(
            &self.keyframe_pyramids[slot],
            &self.current,
            &self.points,
            Some(&self.predicted),
            &mut self.tracked,
        );
        // The pool is bounded: a rover that kept losing and re-finding the same keyframes used
        // to fill it with re-acquired copies of tracked corners (each copy becomes a landmark of
        // the next keyframe and is re-acquired again): 1.2 GB and seconds per frame on seed 9.
        let room = (2 * self.config.features.max_features).saturating_sub(self.history.tracks.len());
        let found = self.tracked.iter().zip(&self.reacquire_landmark).filter_map(|(r, &i)| r.map(|p| (p, i)));
        for (pixel, index) in found.take(room) {
            let mut track = Track::new(pixel);
            track.landmark[slot] = index;
            self.history.tracks.push(track);
        }
    }

    /// Triangulated landmark at a left-image pixel of the current pair.
    fn landmark_at(
        &mut self,
        left: ImageView<'_>,
        right: ImageView<'_>,
        disparity: Option<&DisparityImage>,
        pixel: [f32; 2],
    ) -> Option<Landmark> {
        let [x, y] = pixel;
        let (d, sigma) = match disparity {
            Some(map) => (disparity_from_map(map, x, y)?, self.config.map_disparity_sigma_px),
            None => (self.sparse.match_point(left, right, x, y)?, self.config.sparse_disparity_sigma_px),
        };
        let d = f64::from(d);
        if d.is_nan() || d < self.config.min_disparity_px {
            return None;
        }
        let (point_m, covariance_m2) = triangulate(
            &self.intrinsics,
            self.calibration.baseline_m.abs(),
            f64::from(x),
            f64::from(y),
            d,
            self.config.pixel_sigma_px,
            sigma,
        )?;
        Some(Landmark { point_m, covariance_m2, pixel_keyframe: pixel })
    }

    /// Bookkeeping common to every output: motion model, pyramid swap, counters.
    fn finish(
        &mut self,
        frame: StereoView<'_>,
        t_odom_body: Isometry3<f64>,
        delta: Option<VoDelta>,
        new_keyframe: bool,
        reset: bool,
        mut stats: VoStats,
    ) -> VoOutput {
        if self.frames > 0 {
            self.last_motion_body = self.last_t_odom_body.inverse() * t_odom_body;
            self.last_interval_ns = frame.stamp_ns.saturating_sub(self.last_stamp_ns);
        }
        self.last_t_odom_body = t_odom_body;
        self.last_stamp_ns = frame.stamp_ns;
        self.frames += 1;
        std::mem::swap(&mut self.previous, &mut self.current);
        let keyframe = self.history.keyframe(self.active);
        stats.keyframes = self.history.live_count() as u32;
        stats.keyframe_id = keyframe.id;
        stats.keyframe_stamp_ns = keyframe.stamp_ns;
        VoOutput { delta, new_keyframe, reset, t_odom_body, stats }
    }
}

/// `motion` scaled to `ratio` of its length (screw-free approximation: rotation angle and
/// translation scaled independently), for a frame interval that differs from the last one.
fn scale_motion(motion: &Isometry3<f64>, ratio: f64) -> Isometry3<f64> {
    if !ratio.is_finite() || (ratio - 1.0).abs() < 1e-3 {
        return *motion;
    }
    let ratio = ratio.clamp(0.0, 5.0);
    Isometry3::from_parts(Translation3::from(motion.translation.vector * ratio), motion.rotation.powf(ratio))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    #[test]
    fn scaling_a_motion_scales_angle_and_translation() {
        let motion = Isometry3::new(Vector3::new(1.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.2));
        let double = scale_motion(&motion, 2.0);
        assert!((double.translation.vector.x - 2.0).abs() < 1e-12);
        assert!((double.rotation.angle() - 0.4).abs() < 1e-12);
        assert_eq!(scale_motion(&motion, 1.0), motion);
    }
}
