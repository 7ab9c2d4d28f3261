//! Clock synchronization of an estimate (or odometry) stream against ground truth, after RAWSEEDS
//! D2.1 §4.1.3 (spec §3.3).
//!
//! Model. GT is the reference clock. An estimate stamp `τ` maps to GT time
//! `t = t0 + drift·(τ − t0) + offset_s`, anchored at the segment start `t0` (the first GT stamp):
//! applying the drift to absolute epoch stamps (~1.4e9 s) would turn a drift of 1e-4 into a
//! shift of days (spec §8 trap 20). For every GT sample `t_k` the estimate signal is linearly
//! interpolated at `τ_k = t0 + (t_k − t0 − offset_s)/drift` (GT is noisier and sparser in
//! RAWSEEDS, so it is never interpolated, trap 22) and the cost is
//!
//! `cost = mean_k wrap(ψ_gt(t_k) − ψ_est(τ_k) − heading_offset_rad)²`
//!
//! over the overlap, which must hold a minimum number of samples: the mean rather than the sum,
//! because a sum rewards warps that shrink the overlap (trap 23).
//!
//! Search. The cost is multimodal in the heading offset and, for oscillating headings, in the
//! time offset (trap 24), so a deterministic bounded generalized pattern search (2N compass
//! directions, parameters normalized to their bounds, mesh ×2 on success and ×0.5 on failure,
//! as MATLAB's `patternsearch` which RAWSEEDS used) is run from a grid of starts over heading
//! offset × time offset on a decimated GT signal; the best few distinct minima are polished on
//! the full signal down to the mesh tolerance. Poll points are clamped to the box, so a truth on
//! or beyond a bound ends exactly on it and is flagged in [`SyncResult::at_bound`].
//!
//! Accuracy is set by the signal, not the search: with 0.5° white heading noise on a 20 Hz
//! estimate of EuRoC V1_02 (84 s) the Cramér–Rao bound is about 1.1 ms in offset, 2.3e-5 in
//! drift and 0.013° in heading offset, and the errors measured in `tests/timesync.rs` match it.
//!
//! Signals. [`SyncSignal::Yaw`] is the heading about world z of a fixed body axis; it suits
//! gravity-aligned frames and shifts exactly by the heading offset when a trajectory is rotated
//! about z. [`SyncSignal::AngularRateNorm`] (angle of consecutive relative rotations over the
//! sample interval) is invariant to any constant world or body rotation and has no heading
//! offset (trap 25).

use std::ops::RangeInclusive;

use nalgebra::{Isometry3, UnitQuaternion, Vector3};

use crate::trajectory::Trajectory;

/// The body axis whose horizontal direction defines the heading.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum HeadingAxis {
    /// Body x: the usual ZYX-Euler yaw of a ground robot or an upright camera rig.
    BodyX,
    BodyY,
    BodyZ,
    /// The body axis that is on average the most horizontal in the reference trajectory. EuRoC's
    /// IMU frame points x upwards, where the body-x heading is undefined.
    #[default]
    Auto,
}

impl HeadingAxis {
    /// The body-frame unit axis to take the heading of; `Auto` looks at `reference`'s rotations.
    pub fn resolve(self, reference: &Trajectory) -> Vector3<f64> {
        match self {
            Self::BodyX => Vector3::x(),
            Self::BodyY => Vector3::y(),
            Self::BodyZ => Vector3::z(),
            Self::Auto => {
                let axes = [Vector3::x(), Vector3::y(), Vector3::z()];
                let verticality = |axis: &Vector3<f64>| -> f64 {
                    reference.poses.iter().map(|p| (p.rotation * axis).z.abs()).sum::<f64>()
                };
                let mut best = axes[0];
                let mut best_verticality = verticality(&best);
                for axis in &axes[1..] {
                    let v = verticality(axis);
                    if v < best_verticality {
                        best = *axis;
                        best_verticality = v;
                    }
                }
                best
            }
        }
    }
}

/// Heading (rad, in (−π, π]) about world z of `body_axis` rotated into the world frame.
///
/// For any fixed axis, rotating the pose by `a` about world z adds exactly `a`, whatever the
/// roll and pitch; the heading is only ill-conditioned when the axis points near vertical.
pub fn heading_rad(rotation: &UnitQuaternion<f64>, body_axis: &Vector3<f64>) -> f64 {
    let axis_in_world = rotation * body_axis;
    axis_in_world.y.atan2(axis_in_world.x)
}

pub use crate::metrics::wrap_angle_rad;

/// The signal compared between the two streams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SyncSignal {
    /// Heading about world z of a body axis; estimates the heading offset too. Both streams must
    /// describe the same body frame: a constant body rotation between them changes the heading
    /// by an amount that varies with roll and pitch.
    Yaw { axis: HeadingAxis },
    /// Norm of the angular rate from consecutive relative rotations (rad/s). Frame-invariant:
    /// the heading offset is not estimated and is reported as 0.
    AngularRateNorm,
}

impl Default for SyncSignal {
    fn default() -> Self {
        Self::Yaw { axis: HeadingAxis::Auto }
    }
}

/// Options of [`synchronize`]. Defaults follow RAWSEEDS (bounds) and MATLAB `patternsearch`
/// (mesh factors); the start grid and overlap rule are ours.
#[derive(Debug, Clone, PartialEq)]
pub struct SyncConfig {
    pub signal: SyncSignal,
    /// Bounds of the time offset (s).
    pub offset_bounds_s: RangeInclusive<f64>,
    /// Bounds of the clock-rate ratio (dimensionless; RAWSEEDS' "%" is a typo, trap 21).
    pub drift_bounds: RangeInclusive<f64>,
    /// Bounds of the heading offset (rad); unused for frame-invariant signals.
    pub heading_offset_bounds_rad: RangeInclusive<f64>,
    /// Minimum share of GT samples that must fall inside the warped estimate.
    pub min_overlap_fraction: f64,
    /// Minimum number of GT samples in the overlap, whatever the fraction.
    pub min_overlap_samples: usize,
    /// Estimate samples further apart than this (estimate clock, s) are not interpolated across.
    pub max_gap_s: f64,
    /// Number of starting heading offsets, spread evenly over their bounds.
    pub heading_starts: usize,
    /// Number of starting time offsets, spread evenly over their bounds.
    pub offset_starts: usize,
    /// Normalized mesh size at which each coarse search from the start grid stops.
    pub coarse_mesh_tolerance: f64,
    /// The coarse searches use every n-th GT sample, with n chosen to keep about this many.
    pub coarse_reference_samples: usize,
    /// How many distinct coarse minima are polished on the full reference.
    pub polish_candidates: usize,
    /// Normalized mesh size at which the final polish stops (MATLAB's default is 1e-6).
    pub mesh_tolerance: f64,
    /// Cost evaluations allowed over all searches.
    pub max_evaluations: usize,
}

impl Default for SyncConfig {
    fn default() -> Self {
        Self {
            signal: SyncSignal::default(),
            offset_bounds_s: -1.0..=1.0,
            drift_bounds: 0.99..=1.01,
            heading_offset_bounds_rad: -std::f64::consts::PI..=std::f64::consts::PI,
            min_overlap_fraction: 0.5,
            min_overlap_samples: 20,
            max_gap_s: 0.5,
            heading_starts: 8,
            offset_starts: 5,
            coarse_mesh_tolerance: 1e-3,
            coarse_reference_samples: 2000,
            polish_candidates: 3,
            mesh_tolerance: 1e-6,
            max_evaluations: 50_000,
        }
    }
}

/// The estimated clock mapping `t_gt = anchor_s + drift·(τ_est − anchor_s) + offset_s` and
/// heading offset `ψ_gt = ψ_est + heading_offset_rad`.
#[derive(Debug, Clone, PartialEq)]
pub struct SyncResult {
    pub offset_s: f64,
    pub drift: f64,
    pub heading_offset_rad: f64,
    /// The segment anchor `t0` (s): the first GT stamp.
    pub anchor_s: f64,
    /// Mean squared signal residual over the overlap (rad² for yaw, (rad/s)² for rates).
    pub cost: f64,
    pub overlap_samples: usize,
    pub evaluations: usize,
    /// Whether the final mesh reached the tolerance before the evaluation budget ran out.
    pub converged: bool,
    /// Per parameter (offset, drift, heading offset): whether the result sits on a bound, which
    /// suggests the box is too small or the solution is degenerate.
    pub at_bound: [bool; 3],
}

impl SyncResult {
    /// GT time of an estimate stamp.
    pub fn ground_truth_time_s(&self, estimate_time_s: f64) -> f64 {
        self.anchor_s + self.drift * (estimate_time_s - self.anchor_s) + self.offset_s
    }

    /// Estimate time of a GT stamp.
    pub fn estimate_time_s(&self, ground_truth_time_s: f64) -> f64 {
        self.anchor_s + (ground_truth_time_s - self.anchor_s - self.offset_s) / self.drift
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SyncError {
    #[error("the {stream} has {samples} usable signal samples; at least 2 are needed")]
    TooFewSamples { stream: &'static str, samples: usize },
    #[error("bounds of {parameter} are empty, not finite, or (for the drift) not positive")]
    InvalidBounds { parameter: &'static str },
    #[error("invalid configuration: {reason}")]
    InvalidConfig { reason: &'static str },
    #[error("no candidate overlaps enough: best overlap {best_overlap_samples} of {required} required GT samples")]
    InsufficientOverlap { best_overlap_samples: usize, required: usize },
}

/// Estimates offset, drift and (for yaw) heading offset of `estimate` relative to `ground_truth`.
pub fn synchronize(
    estimate: &Trajectory,
    ground_truth: &Trajectory,
    config: &SyncConfig,
) -> Result<SyncResult, SyncError> {
    let prepared = Prepared::new(estimate, ground_truth, config)?;
    let full = prepared.problem(1);
    // The start grid only ranks basins, so it runs on a decimated reference: a cost 10× cheaper
    // whose minima lie within a few coarse meshes of the full one's.
    let stride = prepared.reference.stamps_s.len().div_ceil(config.coarse_reference_samples.max(1)).max(1);
    let coarse = prepared.problem(stride);

    let lower =
        [*config.offset_bounds_s.start(), *config.drift_bounds.start(), *config.heading_offset_bounds_rad.start()];
    let upper = [*config.offset_bounds_s.end(), *config.drift_bounds.end(), *config.heading_offset_bounds_rad.end()];
    let heading_active = prepared.heading_active;
    let active = [upper[0] > lower[0], upper[1] > lower[1], heading_active && upper[2] > lower[2]];
    let search = PatternSearch { lower, upper, active };
    let mut budget = Budget { left: config.max_evaluations, best_overlap_samples: 0 };

    // A frame-invariant signal has no heading offset, so its heading starts would repeat work.
    let heading_starts = if active[2] { config.heading_starts } else { 1 };
    let offset_starts = if active[0] { config.offset_starts } else { 1 };
    let drift_start = if active[1] { normalized_start(&lower, &upper, 1, 1.0) } else { 0.5 };
    let coarse_initial_mesh = 0.5 / offset_starts.max(heading_starts) as f64;
    let mut candidates: Vec<SearchOutcome> = Vec::new();
    'starts: for i in 0..heading_starts {
        for j in 0..offset_starts {
            if budget.left == 0 {
                break 'starts;
            }
            let start =
                [(j as f64 + 0.5) / offset_starts as f64, drift_start, (i as f64 + 0.5) / heading_starts as f64];
            let outcome = search.run(&coarse, &mut budget, start, coarse_initial_mesh, config.coarse_mesh_tolerance);
            if outcome.cost.is_finite() {
                candidates.push(outcome);
            }
        }
    }
    // Several starts end in the same basin; polish the best few distinct ones, since the ranking
    // on the decimated reference can swap two basins of nearly equal cost.
    candidates.sort_by(|a, b| a.cost.total_cmp(&b.cost));
    let mut distinct: Vec<SearchOutcome> = Vec::new();
    for candidate in candidates {
        let separation = 4.0 * config.coarse_mesh_tolerance;
        let seen = distinct.iter().any(|d| (0..3).all(|i| (d.point[i] - candidate.point[i]).abs() <= separation));
        if !seen && distinct.len() < config.polish_candidates.max(1) {
            distinct.push(candidate);
        }
    }
    let polish_initial_mesh = (4.0 * config.coarse_mesh_tolerance).max(config.mesh_tolerance);
    let mut best: Option<SearchOutcome> = None;
    for candidate in &distinct {
        let polished = search.run(&full, &mut budget, candidate.point, polish_initial_mesh, config.mesh_tolerance);
        if best.as_ref().is_none_or(|b| polished.cost < b.cost) {
            best = Some(polished);
        }
    }
    let Some(best) = best.filter(|b| b.cost.is_finite()) else {
        return Err(SyncError::InsufficientOverlap {
            best_overlap_samples: budget.best_overlap_samples,
            required: prepared.required,
        });
    };
    let x = search.denormalize(&best.point);
    let Evaluation::Feasible { cost, overlap_samples } = full.evaluate(&x) else {
        return Err(SyncError::InsufficientOverlap {
            best_overlap_samples: budget.best_overlap_samples,
            required: prepared.required,
        });
    };
    let at_bound = std::array::from_fn(|i| {
        active[i] && (best.point[i] <= config.mesh_tolerance || best.point[i] >= 1.0 - config.mesh_tolerance)
    });
    Ok(SyncResult {
        offset_s: x[0],
        drift: x[1],
        heading_offset_rad: if heading_active { wrap_angle_rad(x[2]) } else { 0.0 },
        anchor_s: prepared.anchor_s,
        cost,
        overlap_samples,
        evaluations: config.max_evaluations - budget.left,
        converged: best.converged,
        at_bound,
    })
}

/// The cost of [`synchronize`] at given parameters and the overlap it used; `cost` is infinite
/// when the overlap is too small. For plotting cost profiles, the visual check RAWSEEDS relied on.
pub fn sync_cost(
    estimate: &Trajectory,
    ground_truth: &Trajectory,
    config: &SyncConfig,
    offset_s: f64,
    drift: f64,
    heading_offset_rad: f64,
) -> Result<(f64, usize), SyncError> {
    let prepared = Prepared::new(estimate, ground_truth, config)?;
    let heading = if prepared.heading_active { heading_offset_rad } else { 0.0 };
    Ok(match prepared.problem(1).evaluate(&[offset_s, drift, heading]) {
        Evaluation::Feasible { cost, overlap_samples } => (cost, overlap_samples),
        Evaluation::Infeasible { overlap_samples } => (f64::INFINITY, overlap_samples),
    })
}

/// Both signals and the overlap requirement.
#[derive(Debug)]
struct Prepared {
    anchor_s: f64,
    reference: Signal,
    warped: Signal,
    heading_active: bool,
    max_gap_s: f64,
    required: usize,
}

impl Prepared {
    fn new(estimate: &Trajectory, ground_truth: &Trajectory, config: &SyncConfig) -> Result<Self, SyncError> {
        validate(config)?;
        let anchor_s =
            *ground_truth.stamps_s.first().ok_or(SyncError::TooFewSamples { stream: "ground truth", samples: 0 })?;
        let (reference, warped, heading_active) = match config.signal {
            SyncSignal::Yaw { axis } => {
                let body_axis = axis.resolve(ground_truth);
                (yaw_signal(ground_truth, &body_axis, anchor_s), yaw_signal(estimate, &body_axis, anchor_s), true)
            }
            SyncSignal::AngularRateNorm => (
                rate_signal(ground_truth, anchor_s, config.max_gap_s),
                rate_signal(estimate, anchor_s, config.max_gap_s),
                false,
            ),
        };
        if reference.stamps_s.len() < 2 {
            return Err(SyncError::TooFewSamples { stream: "ground truth", samples: reference.stamps_s.len() });
        }
        if warped.stamps_s.len() < 2 {
            return Err(SyncError::TooFewSamples { stream: "estimate", samples: warped.stamps_s.len() });
        }
        let required = config
            .min_overlap_samples
            .max((config.min_overlap_fraction * reference.stamps_s.len() as f64).ceil() as usize)
            .max(1);
        Ok(Self { anchor_s, reference, warped, heading_active, max_gap_s: config.max_gap_s, required })
    }

    /// The cost over every `stride`-th reference sample.
    fn problem(&self, stride: usize) -> CostProblem<'_> {
        CostProblem {
            reference: &self.reference,
            warped: &self.warped,
            stride,
            wrap_residual: self.heading_active,
            max_gap_s: self.max_gap_s,
            required: self.required.div_ceil(stride),
        }
    }
}

/// The estimate with its stamps mapped to GT time (poses unchanged).
pub fn map_stamps_to_ground_truth(estimate: &Trajectory, result: &SyncResult) -> Trajectory {
    Trajectory {
        stamps_s: estimate.stamps_s.iter().map(|&tau| result.ground_truth_time_s(tau)).collect(),
        poses: estimate.poses.clone(),
    }
}

/// The estimate in GT time and rotated about world z by the heading offset, so its headings
/// match GT's. Translation is left to spatial alignment.
pub fn apply_sync(estimate: &Trajectory, result: &SyncResult) -> Trajectory {
    let rotation = Isometry3::rotation(Vector3::z() * result.heading_offset_rad);
    map_stamps_to_ground_truth(estimate, result).transformed(&rotation)
}

fn validate(config: &SyncConfig) -> Result<(), SyncError> {
    let check = |range: &RangeInclusive<f64>, parameter: &'static str| {
        let (lo, hi) = (*range.start(), *range.end());
        if lo.is_finite() && hi.is_finite() && lo <= hi { Ok(()) } else { Err(SyncError::InvalidBounds { parameter }) }
    };
    check(&config.offset_bounds_s, "offset_s")?;
    check(&config.drift_bounds, "drift")?;
    check(&config.heading_offset_bounds_rad, "heading_offset_rad")?;
    if *config.drift_bounds.start() <= 0.0 {
        return Err(SyncError::InvalidBounds { parameter: "drift" });
    }
    if config.heading_starts == 0 || config.offset_starts == 0 {
        return Err(SyncError::InvalidConfig { reason: "start counts must be positive" });
    }
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if !positive(config.mesh_tolerance) || !positive(config.coarse_mesh_tolerance) || !positive(config.max_gap_s) {
        return Err(SyncError::InvalidConfig { reason: "mesh tolerances and max_gap_s must be positive" });
    }
    if !(0.0..=1.0).contains(&config.min_overlap_fraction) {
        return Err(SyncError::InvalidConfig { reason: "min_overlap_fraction must lie in [0, 1]" });
    }
    Ok(())
}

/// A scalar signal with stamps relative to the anchor (s), to keep precision with epoch stamps.
#[derive(Debug)]
struct Signal {
    stamps_s: Vec<f64>,
    values: Vec<f64>,
}

/// Unwrapped heading samples: continuous, so that interpolating between two samples either side
/// of ±π takes the short way, and so that residuals change by whole turns only rarely.
fn yaw_signal(trajectory: &Trajectory, body_axis: &Vector3<f64>, anchor_s: f64) -> Signal {
    let mut values: Vec<f64> = Vec::with_capacity(trajectory.len());
    for pose in &trajectory.poses {
        let heading = heading_rad(&pose.rotation, body_axis);
        let value = match values.last() {
            Some(&previous) => previous + wrap_angle_rad(heading - previous),
            None => heading,
        };
        values.push(value);
    }
    Signal { stamps_s: trajectory.stamps_s.iter().map(|t| t - anchor_s).collect(), values }
}

/// Angular-rate norm at the midpoints of consecutive samples no more than `max_gap_s` apart.
fn rate_signal(trajectory: &Trajectory, anchor_s: f64, max_gap_s: f64) -> Signal {
    let mut signal = Signal { stamps_s: Vec::new(), values: Vec::new() };
    for (stamps, poses) in trajectory.stamps_s.windows(2).zip(trajectory.poses.windows(2)) {
        let dt_s = stamps[1] - stamps[0];
        if dt_s > max_gap_s {
            continue;
        }
        let angle_rad = poses[0].rotation.angle_to(&poses[1].rotation);
        signal.stamps_s.push(0.5 * (stamps[0] + stamps[1]) - anchor_s);
        signal.values.push(angle_rad / dt_s);
    }
    signal
}

#[derive(Debug, Clone, Copy)]
enum Evaluation {
    Feasible { cost: f64, overlap_samples: usize },
    Infeasible { overlap_samples: usize },
}

#[derive(Debug)]
struct CostProblem<'a> {
    reference: &'a Signal,
    warped: &'a Signal,
    /// Use every `stride`-th reference sample.
    stride: usize,
    /// Yaw residuals are angles; rate residuals are not.
    wrap_residual: bool,
    max_gap_s: f64,
    required: usize,
}

impl CostProblem<'_> {
    /// Mean squared residual at `x = [offset_s, drift, heading_offset_rad]`.
    fn evaluate(&self, x: &[f64; 3]) -> Evaluation {
        let [offset_s, drift, heading_offset_rad] = *x;
        let (tau, values) = (&self.warped.stamps_s, &self.warped.values);
        let (first, last) = (tau[0], tau[tau.len() - 1]);
        let mut sum = 0.0;
        let mut count = 0usize;
        // Both headings are unwrapped, so the residual's whole turns change rarely: track them
        // instead of wrapping every sample with a division.
        let mut turns_rad = 0.0;
        // τ_k increases with t_k, so one forward walk finds every bracket.
        let mut j = 0usize;
        let samples = self.reference.stamps_s.iter().zip(&self.reference.values).step_by(self.stride);
        for (&t, &reference) in samples {
            let tau_k = (t - offset_s) / drift;
            if tau_k < first {
                continue;
            }
            if tau_k > last {
                break;
            }
            while j + 2 < tau.len() && tau[j + 1] < tau_k {
                j += 1;
            }
            let (tau0, tau1) = (tau[j], tau[j + 1]);
            if tau1 - tau0 > self.max_gap_s {
                continue;
            }
            let a = (tau_k - tau0) / (tau1 - tau0);
            let interpolated = values[j] + a * (values[j + 1] - values[j]);
            let residual = if self.wrap_residual {
                let raw = reference - interpolated - heading_offset_rad;
                let mut residual = raw - turns_rad;
                if residual.abs() > std::f64::consts::PI {
                    turns_rad = std::f64::consts::TAU * (raw / std::f64::consts::TAU).round();
                    residual = raw - turns_rad;
                }
                residual
            } else {
                // A rate in estimate seconds is `drift` times the rate in GT seconds.
                reference - interpolated / drift
            };
            sum += residual * residual;
            count += 1;
        }
        if count < self.required {
            Evaluation::Infeasible { overlap_samples: count }
        } else {
            Evaluation::Feasible { cost: sum / count as f64, overlap_samples: count }
        }
    }
}

#[derive(Debug)]
struct Budget {
    left: usize,
    best_overlap_samples: usize,
}

#[derive(Debug)]
struct SearchOutcome {
    point: [f64; 3],
    cost: f64,
    converged: bool,
}

/// Bounded generalized pattern search over the unit cube (each parameter normalized to its
/// bounds, so one mesh size means the same share of every box side).
#[derive(Debug)]
struct PatternSearch {
    lower: [f64; 3],
    upper: [f64; 3],
    active: [bool; 3],
}

impl PatternSearch {
    fn denormalize(&self, u: &[f64; 3]) -> [f64; 3] {
        std::array::from_fn(|i| self.lower[i] + u[i] * (self.upper[i] - self.lower[i]))
    }

    fn run(
        &self,
        problem: &CostProblem<'_>,
        budget: &mut Budget,
        start: [f64; 3],
        initial_mesh: f64,
        tolerance: f64,
    ) -> SearchOutcome {
        let objective = |u: &[f64; 3], budget: &mut Budget| -> f64 {
            budget.left = budget.left.saturating_sub(1);
            match problem.evaluate(&self.denormalize(u)) {
                Evaluation::Feasible { cost, .. } => cost,
                Evaluation::Infeasible { overlap_samples } => {
                    budget.best_overlap_samples = budget.best_overlap_samples.max(overlap_samples);
                    f64::INFINITY
                }
            }
        };
        let mut point = start.map(|u| u.clamp(0.0, 1.0));
        let mut cost = objective(&point, budget);
        let mut mesh = initial_mesh;
        while mesh >= tolerance {
            if budget.left == 0 {
                return SearchOutcome { point, cost, converged: false };
            }
            let mut improved = false;
            // Opportunistic polling of ±e_i in a fixed order keeps the search deterministic.
            'poll: for i in (0..3).filter(|&i| self.active[i]) {
                for sign in [1.0, -1.0] {
                    let mut candidate = point;
                    candidate[i] = (point[i] + sign * mesh).clamp(0.0, 1.0);
                    if candidate[i] == point[i] {
                        continue;
                    }
                    if budget.left == 0 {
                        break 'poll;
                    }
                    let candidate_cost = objective(&candidate, budget);
                    if candidate_cost < cost {
                        point = candidate;
                        cost = candidate_cost;
                        improved = true;
                        break 'poll;
                    }
                }
            }
            // The mesh never grows past the whole box.
            mesh = if improved { (2.0 * mesh).min(1.0) } else { 0.5 * mesh };
        }
        SearchOutcome { point, cost, converged: true }
    }
}

/// Normalized position of `value` within the bounds of parameter `i` (0.5 when fixed).
fn normalized_start(lower: &[f64; 3], upper: &[f64; 3], i: usize, value: f64) -> f64 {
    let span = upper[i] - lower[i];
    if span > 0.0 { ((value - lower[i]) / span).clamp(0.0, 1.0) } else { 0.5 }
}
