//! Robot markers in the vision process (thesis §6.2): tag36h11 detection on the rectified pair,
//! the marker's pose from its corners (IPPE, the better of the two planar solutions) with the
//! configured uncertainty model and the 75° gate, and one [`Message::Marker`] per accepted tag.
//!
//! The left image is searched first. With [`MarkerOptions::right_image`] the right image adds
//! the tags the left one did not give (cut by its border, or too small or too oblique to decode
//! there). A detection is expressed in the camera that saw it (`t_body_cam` of the message is the
//! right camera's pose for a right-image tag: the left camera moved by the baseline along its x),
//! so its covariance needs no transformation.
//!
//! After the first pair the detector allocates nothing; the pose's online sampling works on the
//! stack.

use std::sync::Arc;

use hal::sensor::StereoCalibration;
use msgs::{MarkerMsg, Pose};
use nalgebra::{Isometry3, Translation3};
use vision::StereoView;
use vision::apriltag::{TagDetection, TagDetector, TagDetectorConfig};
use vision::marker_pose::{MarkerLut, MarkerPose, UncertaintyModel, check_lut, estimate_marker_pose};

use super::{Message, NodeError, Outbox};

/// What the vision node does about markers.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerOptions {
    pub detector: TagDetectorConfig,
    /// Also search the right image.
    pub right_image: bool,
    /// Edge of a tag's black square.
    pub size_m: f64,
    pub model: UncertaintyModel,
    /// The camera's uncertainty table (required by the table models).
    pub lut: Option<Arc<MarkerLut>>,
}

/// Counters for the mission report.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct MarkerSummary {
    /// Pairs searched.
    pub frames: u64,
    /// Tags the detector found (left and right, before the pose).
    pub tags_detected: u64,
    /// Tags found only in the right image.
    pub right_only: u64,
    /// Tags whose rotational uncertainty exceeded the 75° gate (dropped).
    pub gated: u64,
    /// Tags without a pose (degenerate corners).
    pub pose_failures: u64,
    pub published: u64,
}

/// The marker part of the vision node (see the module documentation).
#[derive(Debug)]
pub struct MarkerStage {
    options: MarkerOptions,
    detector: TagDetector,
    /// The left image's tag ids of the current pair.
    left_ids: Vec<u32>,
    summary: MarkerSummary,
}

impl MarkerStage {
    /// A stage for the rectified `calibration`; refuses a table made for another camera or tag
    /// size, and a table model without a table.
    pub fn new(options: MarkerOptions, calibration: &StereoCalibration) -> Result<Self, String> {
        let detector = TagDetector::new(options.detector).map_err(|e| format!("marker detector: {e}"))?;
        match (&options.lut, options.model.needs_lut()) {
            (Some(lut), _) => check_lut(lut, &calibration.left.intrinsics, options.size_m)
                .map_err(|e| format!("marker table: {e} (generate one with marker-lut for this camera)"))?,
            (None, true) => {
                return Err(format!("the {} marker model needs a table (markers.lut)", options.model.name()));
            }
            (None, false) => {}
        }
        Ok(MarkerStage { options, detector, left_ids: Vec::new(), summary: MarkerSummary::default() })
    }

    pub fn summary(&self) -> MarkerSummary {
        self.summary
    }

    /// Detects, estimates and publishes the markers of a rectified pair.
    pub fn process(
        &mut self,
        pair: StereoView<'_>,
        calibration: &StereoCalibration,
        out: &mut dyn Outbox,
    ) -> Result<(), NodeError> {
        self.summary.frames += 1;
        let t_body_left = calibration.t_body_left(pair.pan_rad, pair.tilt_rad);
        let (width, height) = (pair.width_px as usize, pair.height_px as usize);
        self.left_ids.clear();
        if let Some(left) = vision::ImageView::new(width, height, pair.left) {
            let detections = self.detector.detect(left);
            self.summary.tags_detected += detections.len() as u64;
            for k in 0..detections.len() {
                let detection = self.detector.detections()[k];
                self.left_ids.push(detection.id);
                self.publish(&detection, pair.stamp_ns, &t_body_left, MarkerMsg::LEFT, calibration, out)?;
            }
        }
        if !self.options.right_image {
            return Ok(());
        }
        let Some(right) = vision::ImageView::new(width, height, pair.right) else { return Ok(()) };
        let t_body_right = t_body_left * Translation3::new(calibration.baseline_m, 0.0, 0.0);
        let count = self.detector.detect(right).len();
        self.summary.tags_detected += count as u64;
        for k in 0..count {
            let detection = self.detector.detections()[k];
            if self.left_ids.contains(&detection.id) {
                continue;
            }
            self.summary.right_only += 1;
            self.publish(&detection, pair.stamp_ns, &t_body_right, MarkerMsg::RIGHT, calibration, out)?;
        }
        Ok(())
    }

    fn publish(
        &mut self,
        detection: &TagDetection,
        capture_stamp_ns: u64,
        t_body_cam: &Isometry3<f64>,
        camera: u32,
        calibration: &StereoCalibration,
        out: &mut dyn Outbox,
    ) -> Result<(), NodeError> {
        let o = &self.options;
        let pose = match estimate_marker_pose(
            &detection.corners_px,
            &calibration.left.intrinsics,
            o.size_m,
            o.model,
            o.lut.as_deref(),
        ) {
            Ok(pose) => pose,
            Err(_) => {
                self.summary.pose_failures += 1;
                return Ok(());
            }
        };
        if !pose.gate_passed {
            self.summary.gated += 1;
            return Ok(());
        }
        out.publish(Message::Marker(&marker_message(detection, &pose, capture_stamp_ns, t_body_cam, camera)))?;
        self.summary.published += 1;
        Ok(())
    }
}

/// The message of one detection with its pose.
pub fn marker_message(
    detection: &TagDetection,
    pose: &MarkerPose,
    capture_stamp_ns: u64,
    t_body_cam: &Isometry3<f64>,
    camera: u32,
) -> MarkerMsg {
    MarkerMsg {
        capture_stamp_ns,
        t_body_cam: Pose::from_isometry(t_body_cam),
        t_cam_marker: Pose::from_isometry(&pose.t_cam_marker),
        covariance_cam: msgs::covariance_to_array(&pose.covariance()),
        corners_px: detection.corners_px.map(|[u, v]| [u as f32, v as f32]),
        tag_id: detection.id,
        hamming: detection.hamming,
        decision_margin: detection.decision_margin,
        ambiguity_ratio: pose.pnp.ratio.min(f64::from(f32::MAX)) as f32,
        distance_m: pose.view.distance_m as f32,
        tilt_rad: pose.view.tilt_rad as f32,
        camera,
        model: pose.model.code(),
    }
}
