//! On-board vision: everything between the stereo camera and the filter and mapper.
//!
//! - [`rectify`]: raw pinhole + radial-tangential pairs into the canonical rectified pair.
//! - [`pyramid`], [`features`], [`klt`]: image pyramids, grid-bucketed corner detection and
//!   pyramidal Lucas-Kanade tracking in the left image.
//! - [`stereo_match`]: depth of a feature from the SGM disparity map or sparse matching.
//! - [`geometry`]: P3P + RANSAC 3D–2D pose, nonlinear refinement, propagated-noise covariance.
//! - [`odometry`]: keyframe stereo visual odometry (thesis §3.2, §4.1.1) producing [`VoDelta`]s.
//! - [`depth`], [`obstacles`]: depth images and obstacle classification on them (thesis §5.1.1):
//!   negative edges, stereo-error-adaptive steps on a 5 cm height map, the rolling local map.
//! - [`depth_pipeline`]: the one SGM → speckle filter → depth sequence ([`DepthPipeline`]).
//! - [`apriltag`]: tag36h11 detection of the robots' markers ([`apriltag::TagDetector`]).
//! - [`marker_pose`]: a marker's pose from its corners (IPPE, both planar solutions) and its
//!   uncertainty (thesis §6.2.3: constant, quadratic, look-up table, online sampling).
//!
//! # Frames and conventions
//!
//! Body and camera frames are those of `hal::sensor`: body x forward, y left, z up (= IMU frame);
//! camera = the left rectified camera's optical frame (x right, y down, z forward). A pose
//! `t_a_b` maps coordinates in frame `b` into frame `a`.
//!
//! **Relative-pose covariance** (used by [`VoDelta`] and `filter`): 6×6 over the perturbation
//! `ξ = [δt; δθ]` (translation first, then rotation, metres and radians) of `t_a_b` with
//! `t_true = t̂ + δt` (in frame `a`) and `R_true = R̂ · Exp(δθ)` (δθ in frame `b`).
//!
//! This crate does no I/O: images come in as borrowed slices ([`ImageView`], [`StereoView`]), results
//! go out as values. (The `cli` feature, on by default and off in the firmware, adds
//! `image_file`, PNG/JPEG reading for the tools, tests and benchmarks.)

pub mod apriltag;
pub mod delta;
pub mod depth;
pub mod depth_pipeline;
pub mod features;
pub mod geometry;
pub mod image;
#[cfg(feature = "cli")]
pub mod image_file;
pub mod keyframes;
pub mod klt;
pub mod marker_pose;
pub mod obstacles;
pub mod odometry;
pub mod pyramid;
pub mod rectify;
pub mod speckle;
pub mod stereo_match;

pub use delta::VoDelta;
pub use depth::{DEPTH_UNIQUENESS_PERCENT, DepthImage, StereoGeometry, depth_sgm_config};
pub use depth_pipeline::{DepthError, DepthFrameStats, DepthOptions, DepthPipeline};
pub use image::{ImageView, StereoView};
pub use odometry::{StereoOdometry, VoConfig, VoError, VoOutput, VoStats};
pub use rectify::{Rectifier, RectifyError};
pub use speckle::SpeckleFilter;
