//! Loop closures from ground truth: robot detections (thesis eq. 4.7) and submap matches with the
//! noise the thesis's uncertainty models predict.
//!
//! **TEST AND EVALUATION ONLY.** Nothing at runtime uses this module by default. It exists so that
//! the multi-robot SLAM front-end (`mapper::slam`) can be evaluated before the real submap matcher
//! and AprilTag detector exist. Every report built on it must say that its loop closures came from
//! ground truth.
//!
//! # What it produces
//!
//! - [`TruthDetection`]: the pose of an observed robot's body in the observer's body frame,
//!   `T̂_r0_r1 = T_r0_cam · T̂_cam_marker · T_r1_marker⁻¹` (eq. 4.7, the camera extrinsic includes
//!   the pan-tilt head at the image time), for every marker that is visible in the observer's left
//!   image.
//! - [`TruthMatch`]: the pose of submap `b`'s origin in submap `a`'s origin, as the 4D matcher
//!   would report it (§6.1.2), including occasional gross outliers.
//!
//! # Conventions
//!
//! Covariances use the posegraph convention (onboard/graph/README.md "Conventions"): tangent
//! `[translation, rotation]`, right perturbation `T·Exp(δ)` with the true SE(3) exponential
//! ([`crate::se3`], the same maps as `posegraph::se3` but written independently, so that the
//! back-end is checked against truth that does not share its code).
//!
//! # Detection noise
//!
//! The thesis's quadratic model Σ_quadratic = Σ_constant·(1 + d)² (eq. 8.2, Tab. 8.3: close to
//! its best model) gives per-DoF sigmas `detection_sigma_base · (1 + d)` with `d` the distance of
//! the marker from the camera. They are applied in the camera's axes: the marker's centre moves by
//! `ε_t` along the camera's x, y, z and the marker turns by `ε_r` about the camera's axes *around
//! its own centre* (turning about the camera origin would move a 7 m distant tag by metres, which
//! no detector does). Exactly: `T̂_cam_marker = T_cam_marker · Exp(M·ε)` with
//! `M = diag(R_cam_markerᵀ, R_cam_markerᵀ)`. Eq. 4.7 then gives
//! `T̂_r0_r1 = T_r0_r1 · Exp(Ad(T_r1_marker)·M·ε)`, exactly, so the reported covariance
//! `Ad·M·Σ·Mᵀ·Adᵀ` is the true covariance of the noise (a test checks the NEES).
//!
//! The 75° gate of §1.4.3 is applied, but never acts with these defaults: the largest rotation
//! sigma, at 7 m, is `0.0224·8 = 0.18 rad` (10°).
//!
//! # Visibility
//!
//! A marker is detected when its centre and the 4 corners of the whole tag (white border
//! included) project into the left image in front of the camera, it is within
//! `max_detection_range_m` and seen within `max_view_angle_rad` of its normal, and the line of
//! sight from the camera to its centre passes above the terrain (sampled at the heightfield's
//! resolution) and through no face of a third robot. The observer's own body is ignored, as the
//! renderer ignores it (a robot does not see itself; see the README's limits). The observed
//! robot's own body is not tested: the markers face outward, and within the 60° view-angle limit
//! the line of sight leaves away from the mast.
//!
//! # Seen area of a submap
//!
//! Ground cells of a 0.5 m world-aligned grid whose centre (on the terrain) lies in the left
//! camera's frustum between 0.5 m and 5 m, sampled at 1 Hz over the submap's span. Occlusion by
//! terrain is ignored: within 5 m of a camera 1.4 m above traversable ground little is hidden, and
//! the thesis's own pre-selection (AABB overlap > 2 m², §6.1.1) is far coarser. A match needs
//! `min_overlap_m2` of shared seen ground, more than the 2 m² AABB pre-selection because that one
//! only queues pairs, many of which then fail.
//!
//! # Determinism
//!
//! Every random draw comes from an [`crate::rng`] stream keyed by the config's seed and what is
//! drawn (detection: observer, observed, stamp, tag; match: both submaps), so results do not depend
//! on the order of calls. Only the detection rate limit depends on the call history.

use std::collections::{BTreeMap, BTreeSet};
use std::sync::Arc;

use nalgebra::{Isometry3, Matrix3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6};

use crate::rng::{self, streams};
use crate::se3::{adjoint, exp as se3_exp};
use crate::world::World;

/// Grid of the seen-area bookkeeping.
const SEEN_CELL_M: f64 = 0.5;
/// Range of ground the left camera "maps" into a submap (the dense maps' useful range).
const SEEN_MIN_RANGE_M: f64 = 0.5;
const SEEN_MAX_RANGE_M: f64 = 5.0;
/// Sampling of the camera's pose when collecting the seen area.
const SEEN_SAMPLE_NS: u64 = 1_000_000_000;
/// Detections whose rotation uncertainty exceeds this were excluded in the thesis (§1.4.3).
const UNCERTAINTY_GATE_RAD: f64 = 75.0 * std::f64::consts::PI / 180.0;
/// Sub-stream ids under [`streams::TRUTH_CONSTRAINTS`].
const DETECTION_STREAM: u64 = 0;
const MATCH_STREAM: u64 = 1;

/// Parameters of the ground-truth loop-closure source. The defaults are documented per field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthConstraintConfig {
    /// 7 m: the thesis's lookup table (and so its uncertainty model) covers 0.2–7 m (§1.4.3). The
    /// table is for 6 cm tags, which span 9 px at 7 m with f = 1080 px; our 16 cm tags span 25 px
    /// there and would be detected farther, but the model is not calibrated beyond 7 m.
    pub max_detection_range_m: f64,
    /// 60°: angle between the tag's normal and the ray to the camera. Planar-PnP ambiguities grow
    /// at grazing angles (§1.4.1); the markers are tilted 25° up so rovers see them well inside.
    pub max_view_angle_rad: f64,
    /// 10 s per (observer, observed) pair: the LRU experiments had about 27 detections in 370 m of
    /// driving (Tab. 8.8/8.9), i.e. sparse robot-pose nodes, not one per camera frame.
    pub min_detection_interval_s: f64,
    /// Σ_constant's sigmas (eq. 8.1): 1 cm and √5e-4 rad (1.3°), order `[x, y, z, roll, pitch, yaw]`
    /// in the camera's axes.
    pub detection_sigma_base: [f64; 6],
    /// 0.1 m per axis: the 3D error then has median 0.15 m and lies in 0.1–0.3 m 77 % of the
    /// time (χ₃ quantiles), as the thesis's match errors "mostly" do (§8.1.2).
    pub match_sigma_translation_m: f64,
    /// 1°: the yaw error of 4D matches in Fig. 8.8 is of this order.
    pub match_sigma_yaw_rad: f64,
    /// 0.3°: a 4D match has zero roll and pitch between gravity-aligned origins, but the 6D factor
    /// needs some variance (§3.2 of the first spec: value unspecified); small, like the filter's.
    pub match_sigma_roll_pitch_rad: f64,
    /// 10 m² of shared seen ground (see the module docs).
    pub min_overlap_m2: f64,
    /// 0.7: not every overlapping pair matches (keypoint checks, RANSAC, ICP gates of §6.1.2).
    pub match_success_probability: f64,
    /// 0.02: a wrong match with 1–3 m and 10–30° error (thesis Exp. #3 had one).
    pub outlier_probability: f64,
    pub seed: u64,
}

impl Default for TruthConstraintConfig {
    fn default() -> Self {
        let rot = 5e-4_f64.sqrt();
        TruthConstraintConfig {
            max_detection_range_m: 7.0,
            max_view_angle_rad: 60f64.to_radians(),
            min_detection_interval_s: 10.0,
            detection_sigma_base: [0.01, 0.01, 0.01, rot, rot, rot],
            match_sigma_translation_m: 0.1,
            match_sigma_yaw_rad: 1f64.to_radians(),
            match_sigma_roll_pitch_rad: 0.3f64.to_radians(),
            min_overlap_m2: 10.0,
            match_success_probability: 0.7,
            outlier_probability: 0.02,
            seed: 1,
        }
    }
}

/// One marker detection turned into a body-to-body measurement (eq. 4.7).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthDetection {
    pub observer: usize,
    pub observed: usize,
    pub tag_id: u32,
    pub stamp_ns: u64,
    /// eq. 4.7: measured pose of the observed robot's BODY in the observer's BODY frame
    pub t_observer_observed: Isometry3<f64>,
    /// 6x6 covariance in the posegraph convention: tangent [translation, rotation], right perturbation
    /// (T * Exp(delta)), i.e. expressed in the observed body frame (see onboard/graph/README.md "Conventions").
    pub covariance: Matrix6<f64>,
    /// Distance of the marker's centre from the observer's left camera.
    pub distance_m: f64,
    /// Angle between the marker's normal and the ray to the camera.
    pub view_angle_rad: f64,
}

/// A submap of one robot: its local frame started at `start_ns` and was finished at `end_ns`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct SubmapSpan {
    pub robot: usize,
    pub index: u32,
    pub start_ns: u64,
    pub end_ns: u64,
}

/// A submap match as the 4D matcher would report it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthMatch {
    pub a: SubmapSpan,
    pub b: SubmapSpan,
    /// measured pose of submap b's origin in submap a's origin frame
    pub t_a_b: Isometry3<f64>,
    /// posegraph convention, as for [`TruthDetection::covariance`]
    pub covariance: Matrix6<f64>,
    pub overlap_m2: f64,
    /// For evaluation only; the front-end must not look at it.
    pub outlier: bool,
}

/// The seen ground of one submap, cached with the span it was computed for.
#[derive(Debug, Clone)]
struct SeenArea {
    span: SubmapSpan,
    cells: BTreeSet<(i64, i64)>,
}

/// Ground-truth loop-closure source over one world (test/evaluation only, see the module docs).
#[derive(Debug)]
pub struct TruthConstraints {
    world: Arc<World>,
    config: TruthConstraintConfig,
    /// Last emitted detection stamp per `[observer][observed]`.
    last_detection_ns: Vec<Vec<Option<u64>>>,
    seen: BTreeMap<(usize, u32), SeenArea>,
}

impl TruthConstraints {
    pub fn new(world: Arc<World>, config: TruthConstraintConfig) -> Self {
        let n = world.robots.len();
        TruthConstraints { world, config, last_detection_ns: vec![vec![None; n]; n], seen: BTreeMap::new() }
    }

    pub fn config(&self) -> &TruthConstraintConfig {
        &self.config
    }

    pub fn world(&self) -> &Arc<World> {
        &self.world
    }

    /// True origin of a local frame started at `stamp_ns`: the body's position and yaw then, roll
    /// = pitch = 0 (gravity-aligned), as `filter::Filter` defines a new frame at a switch.
    ///
    /// The same function gives the filter's first frame: `initialize_at_rest` puts the body at the
    /// origin with yaw 0 and roll/pitch from gravity, so that frame too sits at the body's position
    /// with the body's yaw at the initialization stamp. The yaw is the z-y-x Euler yaw of
    /// `R_world_body` (the filter's `roll_pitch_yaw` and the trajectories' convention).
    pub fn true_origin(&self, robot: usize, stamp_ns: u64) -> Option<Isometry3<f64>> {
        let state = self.world.robot_state(robot, stamp_ns)?;
        let r = state.t_world_body.rotation.to_rotation_matrix().into_inner();
        let yaw = r[(1, 0)].atan2(r[(0, 0)]);
        Some(Isometry3::from_parts(
            Translation3::from(state.t_world_body.translation.vector),
            UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
        ))
    }

    /// Detections of every other robot's markers in `observer`'s left camera image at `stamp_ns`
    /// (a camera frame time), rate-limited per (observer, observed) pair. Several markers of one
    /// robot in one image give several detections with the same stamp.
    pub fn detections_at(&mut self, observer: usize, stamp_ns: u64) -> Vec<TruthDetection> {
        let mut out = Vec::new();
        let world = Arc::clone(&self.world);
        let Some(observer_state) = world.robot_state(observer, stamp_ns) else {
            return out;
        };
        let (pan, tilt) = world.head_angles(observer, stamp_ns);
        let t_body_cam = world.robots[observer].model().t_body_cam(pan, tilt);
        let t_world_cam = observer_state.t_world_body * t_body_cam;
        let interval_ns = (self.config.min_detection_interval_s * 1e9).max(0.0) as u64;
        for observed in 0..world.robots.len() {
            if observed == observer {
                continue;
            }
            if let Some(last) = self.last_detection_ns[observer][observed]
                && stamp_ns < last.saturating_add(interval_ns)
                && stamp_ns >= last
            {
                continue;
            }
            let Some(observed_state) = world.robot_state(observed, stamp_ns) else {
                continue;
            };
            let before = out.len();
            for marker in &world.robots[observed].model().markers {
                let t_world_marker = observed_state.t_world_body * marker.t_body_marker;
                let t_cam_marker = t_world_cam.inverse() * t_world_marker;
                let Some(geometry) = self.visible(observer, observed, stamp_ns, &t_world_cam, &t_cam_marker, marker)
                else {
                    continue;
                };
                let sigma = self.detection_sigma(geometry.distance_m);
                if sigma[3..].iter().any(|s| *s > UNCERTAINTY_GATE_RAD) {
                    continue;
                }
                let path = [
                    streams::TRUTH_CONSTRAINTS,
                    DETECTION_STREAM,
                    observer as u64,
                    observed as u64,
                    stamp_ns,
                    u64::from(marker.tag_id),
                ];
                let mut rng = rng::stream(self.config.seed, &path);
                let eps = Vector6::from_fn(|i, _| sigma[i] * rng.normal());
                let m = block_diag_rotation(&t_cam_marker.rotation.to_rotation_matrix().into_inner().transpose());
                let t_cam_marker_measured = t_cam_marker * se3_exp(&(m * eps));
                let t_observer_observed = t_body_cam * t_cam_marker_measured * marker.t_body_marker.inverse();
                let sigma_cam = Matrix6::from_diagonal(&Vector6::from_fn(|i, _| sigma[i] * sigma[i]));
                let jac = adjoint(&marker.t_body_marker) * m;
                let covariance = jac * sigma_cam * jac.transpose();
                out.push(TruthDetection {
                    observer,
                    observed,
                    tag_id: marker.tag_id,
                    stamp_ns,
                    t_observer_observed,
                    covariance: 0.5 * (covariance + covariance.transpose()),
                    distance_m: geometry.distance_m,
                    view_angle_rad: geometry.view_angle_rad,
                });
            }
            if out.len() > before {
                self.last_detection_ns[observer][observed] = Some(stamp_ns);
            }
        }
        out
    }

    /// Per-DoF sigmas of a detection at `distance_m` (Σ_quadratic, eq. 8.2).
    pub fn detection_sigma(&self, distance_m: f64) -> [f64; 6] {
        self.config.detection_sigma_base.map(|s| s * (1.0 + distance_m))
    }

    /// The marker's distance and view angle if `observer`'s left camera sees it (module docs).
    fn visible(
        &self,
        observer: usize,
        observed: usize,
        stamp_ns: u64,
        t_world_cam: &Isometry3<f64>,
        t_cam_marker: &Isometry3<f64>,
        marker: &crate::robot::Marker,
    ) -> Option<Geometry> {
        let camera = &self.world.robots[observer].model().camera;
        let centre_cam = t_cam_marker.translation.vector;
        let distance_m = centre_cam.norm();
        if !(distance_m > 0.0 && distance_m <= self.config.max_detection_range_m) {
            return None;
        }
        let normal_cam = t_cam_marker.rotation * Vector3::z();
        let view_angle_rad = normal_cam.dot(&(-centre_cam / distance_m)).clamp(-1.0, 1.0).acos();
        if view_angle_rad > self.config.max_view_angle_rad {
            return None;
        }
        let s = marker.half_extent_m();
        let points = [(0.0, 0.0), (-s, s), (s, s), (s, -s), (-s, -s)];
        let in_image = points.iter().all(|&(x, y)| {
            let p = t_cam_marker * Point3::new(x, y, 0.0);
            camera.project(&p.coords).is_some_and(|(u, v)| {
                u >= 0.0 && v >= 0.0 && u <= f64::from(camera.width_px) - 1.0 && v <= f64::from(camera.height_px) - 1.0
            })
        });
        if !in_image {
            return None;
        }
        let from = t_world_cam.translation.vector;
        let to = (t_world_cam * t_cam_marker).translation.vector;
        if self.terrain_blocks(&from, &to) || self.robots_block(observer, observed, stamp_ns, &from, &to) {
            return None;
        }
        Some(Geometry { distance_m, view_angle_rad })
    }

    /// Whether the terrain rises above the segment `from → to` (sampled at the heightfield's
    /// resolution; the last sample stays a cell short of the marker's centre).
    fn terrain_blocks(&self, from: &Vector3<f64>, to: &Vector3<f64>) -> bool {
        let hf = &self.world.terrain.heightfield;
        let length = (to - from).norm();
        let step = hf.resolution_m.max(1e-3);
        let samples = ((length - step) / step).floor().max(0.0) as usize;
        (1..=samples).any(|k| {
            let p = from + (to - from) * (k as f64 * step / length);
            hf.height_at(p.x, p.y).is_some_and(|h| h > p.z)
        })
    }

    /// Whether a face of a robot other than the observer and the observed crosses `from → to`.
    fn robots_block(
        &self,
        observer: usize,
        observed: usize,
        stamp_ns: u64,
        from: &Vector3<f64>,
        to: &Vector3<f64>,
    ) -> bool {
        let mut quads = Vec::new();
        for (i, robot) in self.world.robots.iter().enumerate() {
            if i == observer || i == observed {
                continue;
            }
            if let Some(state) = robot.trajectory.state_at(stamp_ns) {
                robot.model().append_quads(&state.t_world_body, &mut quads);
            }
        }
        quads.iter().any(|q| segment_crosses_rectangle(from, to, &q.corners_world_m))
    }

    /// Shared seen ground of two submaps (module docs), in m². A submap with itself gives its
    /// seen area.
    pub fn overlap_m2(&mut self, a: &SubmapSpan, b: &SubmapSpan) -> f64 {
        self.ensure_seen(a);
        self.ensure_seen(b);
        let (Some(sa), Some(sb)) = (self.seen.get(&(a.robot, a.index)), self.seen.get(&(b.robot, b.index))) else {
            return 0.0;
        };
        sa.cells.intersection(&sb.cells).count() as f64 * SEEN_CELL_M * SEEN_CELL_M
    }

    /// Seen ground of one submap, in m².
    pub fn seen_area_m2(&mut self, span: &SubmapSpan) -> f64 {
        self.overlap_m2(span, span)
    }

    fn ensure_seen(&mut self, span: &SubmapSpan) {
        let key = (span.robot, span.index);
        if self.seen.get(&key).is_some_and(|s| s.span == *span) {
            return;
        }
        let cells = self.collect_seen(span);
        self.seen.insert(key, SeenArea { span: *span, cells });
    }

    fn collect_seen(&self, span: &SubmapSpan) -> BTreeSet<(i64, i64)> {
        let mut cells = BTreeSet::new();
        let Some(robot) = self.world.robots.get(span.robot) else {
            return cells;
        };
        let camera = &robot.model().camera;
        let hf = &self.world.terrain.heightfield;
        let mut stamp_ns = span.start_ns;
        while stamp_ns <= span.end_ns {
            if let Some(t_world_cam) = self.world.t_world_cam(span.robot, stamp_ns) {
                let t_cam_world = t_world_cam.inverse();
                let c = t_world_cam.translation.vector;
                let lo = |v: f64| ((v - SEEN_MAX_RANGE_M) / SEEN_CELL_M).floor() as i64;
                let hi = |v: f64| ((v + SEEN_MAX_RANGE_M) / SEEN_CELL_M).ceil() as i64;
                for j in lo(c.y)..=hi(c.y) {
                    for i in lo(c.x)..=hi(c.x) {
                        let x = (i as f64 + 0.5) * SEEN_CELL_M;
                        let y = (j as f64 + 0.5) * SEEN_CELL_M;
                        let Some(z) = hf.height_at(x, y) else {
                            continue;
                        };
                        let p_cam = t_cam_world * Point3::new(x, y, z);
                        let range = p_cam.coords.norm();
                        if !(SEEN_MIN_RANGE_M..=SEEN_MAX_RANGE_M).contains(&range) {
                            continue;
                        }
                        let inside = camera.project(&p_cam.coords).is_some_and(|(u, v)| {
                            u >= 0.0
                                && v >= 0.0
                                && u <= f64::from(camera.width_px) - 1.0
                                && v <= f64::from(camera.height_px) - 1.0
                        });
                        if inside {
                            cells.insert((i, j));
                        }
                    }
                }
            }
            match stamp_ns.checked_add(SEEN_SAMPLE_NS) {
                Some(next) => stamp_ns = next,
                None => break,
            }
        }
        cells
    }

    /// A match attempt between two finished submaps (`a` before `b`; the caller excludes
    /// consecutive submaps of one robot). `None` below `min_overlap_m2` or when the attempt fails
    /// (a Bernoulli draw keyed by the seed and the pair). Otherwise the true relative pose of the
    /// origins, perturbed by `Exp(δ)` on the right with `δ ~ N(0, covariance)` (4D noise plus the
    /// small roll/pitch noise) or, with `outlier_probability`, by a gross error of 1–3 m in a
    /// random horizontal direction and ±10–30° of yaw.
    pub fn attempt_match(&mut self, a: &SubmapSpan, b: &SubmapSpan) -> Option<TruthMatch> {
        let overlap_m2 = self.overlap_m2(a, b);
        if overlap_m2 < self.config.min_overlap_m2 {
            return None;
        }
        let path = [
            streams::TRUTH_CONSTRAINTS,
            MATCH_STREAM,
            a.robot as u64,
            u64::from(a.index),
            b.robot as u64,
            u64::from(b.index),
        ];
        let mut rng = rng::stream(self.config.seed, &path);
        if rng.uniform() >= self.config.match_success_probability {
            return None;
        }
        let t_world_a = self.true_origin(a.robot, a.start_ns)?;
        let t_world_b = self.true_origin(b.robot, b.start_ns)?;
        let t_a_b_true = t_world_a.inverse() * t_world_b;
        let c = &self.config;
        let sigma = [
            c.match_sigma_translation_m,
            c.match_sigma_translation_m,
            c.match_sigma_translation_m,
            c.match_sigma_roll_pitch_rad,
            c.match_sigma_roll_pitch_rad,
            c.match_sigma_yaw_rad,
        ];
        let outlier = rng.uniform() < c.outlier_probability;
        let delta = if outlier {
            let heading = rng.range(0.0, 2.0 * std::f64::consts::PI);
            let length = rng.range(1.0, 3.0);
            let yaw = rng.range(10f64.to_radians(), 30f64.to_radians()) * if rng.uniform() < 0.5 { -1.0 } else { 1.0 };
            Vector6::new(length * heading.cos(), length * heading.sin(), 0.0, 0.0, 0.0, yaw)
        } else {
            Vector6::from_fn(|i, _| sigma[i] * rng.normal())
        };
        Some(TruthMatch {
            a: *a,
            b: *b,
            t_a_b: t_a_b_true * se3_exp(&delta),
            covariance: Matrix6::from_diagonal(&Vector6::from_fn(|i, _| sigma[i] * sigma[i])),
            overlap_m2,
            outlier,
        })
    }
}

#[derive(Debug, Clone, Copy)]
struct Geometry {
    distance_m: f64,
    view_angle_rad: f64,
}

/// Whether the segment `from → to` crosses the rectangle with corners `c0, c1, c2, c3` (in order).
fn segment_crosses_rectangle(from: &Vector3<f64>, to: &Vector3<f64>, corners: &[Point3<f64>; 4]) -> bool {
    let e1 = corners[1] - corners[0];
    let e2 = corners[3] - corners[0];
    let normal = e1.cross(&e2);
    let dir = to - from;
    let denom = normal.dot(&dir);
    if denom.abs() < 1e-12 {
        return false;
    }
    let s = normal.dot(&(corners[0].coords - from)) / denom;
    if !(0.0..=1.0).contains(&s) {
        return false;
    }
    let hit = from + dir * s - corners[0].coords;
    let a = hit.dot(&e1) / e1.norm_squared();
    let b = hit.dot(&e2) / e2.norm_squared();
    (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)
}

/// `diag(R, R)`: a rotation acting on both halves of a `[translation, rotation]` tangent.
fn block_diag_rotation(r: &Matrix3<f64>) -> Matrix6<f64> {
    let mut m = Matrix6::zeros();
    m.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    m.fixed_view_mut::<3, 3>(3, 3).copy_from(r);
    m
}
