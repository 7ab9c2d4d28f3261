//! Ground-truth fusion by an extended Kalman smoother (EKF forward pass + Rauch–Tung–Striebel
//! backward pass), after RAWSEEDS D2.1 §4.1.4 in the corrected form of spec §4.3.
//!
//! Model. The state is the planar pose `x = (x, y, θ)` in the GT world frame on a fixed time grid
//! `t_k = t_start + k·grid_step_s`. Odometry is the control: `u_k` is the SE(2) increment, in the
//! robot frame, from the odometry pose at `t_{k−1}` to the one at `t_k` ([`se2_between`]), so the
//! odometry's own frame never matters. The process is the composition (spec §8 trap 15)
//!
//! `x_k = x_{k−1} ⊕ u_k + w`,  `Q_k = G_u Q_u G_uᵀ`,
//!
//! with `F = ∂(x ⊕ u)/∂x` and `G_u = ∂(x ⊕ u)/∂u` at the previous filtered mean, and `Q_u`
//! diagonal in the robot frame from [`OdometryNoise`]. Every GT stream measures the pose
//! directly, `y = x + v` (`H = I`), `v ~ N(0, R)` with its own `R = diag(σ_xy², σ_xy², σ_θ²)`;
//! two streams at one epoch are applied as sequential updates (the same as stacking them, since
//! their noises are independent).
//!
//! The corrections to the document's equations (trap 11–16): `Kᵀ` carries `Hᵀ`
//! (`K = P Hᵀ S⁻¹`), the covariance update uses the Joseph form, the smoother gain is
//! `A = P_{k|k} Fᵀ P_{k+1|k}⁻¹` (the document drops `Fᵀ`), and every heading innovation and
//! every smoother difference `x_{k+1|T} ⊖ x_{k+1|k}` is wrapped to (−π, π].
//!
//! Resampling (trap 17). Streams are linearly interpolated onto the grid (shortest arc in
//! heading), never across two samples more than the stream's `max_gap_s` apart, so a dropout
//! yields no measurement rather than a fabricated one. Interpolating a 5 Hz stream onto a
//! 100 Hz grid repeats one sample's information about 20 times; [`StreamSampling`] either
//! inflates `R` by that factor or uses each real sample once, at its nearest grid epoch.
//!
//! Gating. With `gate_chi2` set, a measurement whose squared Mahalanobis distance
//! `νᵀ (P + R)⁻¹ ν` exceeds the threshold is rejected and counted. The gate uses the stream's
//! marginal `R`, not the inflated one: inflation accounts for repeated information, not for a
//! larger error, and a gate on the inflated `R` would let gross outliers of slow streams through.
//!
//! The generic core, [`filter_and_smooth`], runs any [`ProcessModel`] with linear measurements;
//! [`LinearProcess`] makes it a plain linear Kalman filter and RTS smoother.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Vector3};

use crate::timesync::{HeadingAxis, wrap_angle_rad};
use crate::trajectory::Trajectory;

// ---------------------------------------------------------------------------------------------
// Generic Kalman filter and RTS smoother.

/// A Gaussian belief.
#[derive(Debug, Clone, PartialEq)]
pub struct Gaussian {
    pub mean: DVector<f64>,
    pub covariance: DMatrix<f64>,
}

/// One process step into an epoch, linearized at the previous filtered mean.
#[derive(Debug, Clone, PartialEq)]
pub struct Transition {
    /// `f(x_{k−1})`.
    pub mean: DVector<f64>,
    /// `F = ∂f/∂x` at `x_{k−1|k−1}`.
    pub jacobian: DMatrix<f64>,
    /// Process noise covariance in state coordinates.
    pub noise: DMatrix<f64>,
}

/// The process model of [`filter_and_smooth`].
pub trait ProcessModel {
    /// The step from epoch `epoch − 1` to `epoch` (`epoch ≥ 1`) at the previous filtered mean.
    fn transition(&self, epoch: usize, previous_mean: &DVector<f64>) -> Transition;

    /// State components that are angles: wrapped after every update and in smoother differences.
    fn angle_components(&self) -> &[usize] {
        &[]
    }
}

/// A linear measurement `value = H x + v`, `v ~ N(0, noise)`.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    pub value: DVector<f64>,
    /// `H`.
    pub observation: DMatrix<f64>,
    /// Marginal noise covariance `R`, used by the gate.
    pub noise: DMatrix<f64>,
    /// The update uses `R·noise_inflation` (≥ 1) to discount repeated, correlated information.
    pub noise_inflation: f64,
    /// Residual components that are angles and are wrapped.
    pub angle_components: Vec<usize>,
    /// Caller's tag, e.g. the stream index.
    pub source: usize,
}

/// What became of one measurement.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MeasurementOutcome {
    Used { mahalanobis_sq: f64 },
    Rejected { mahalanobis_sq: f64 },
}

/// Beliefs at every epoch; `outcomes[k][i]` belongs to `measurements[k][i]`.
#[derive(Debug, Clone, PartialEq)]
pub struct SmootherOutput {
    /// `x_{k|k−1}`; the prior at epoch 0.
    pub predicted: Vec<Gaussian>,
    /// `x_{k|k}`.
    pub filtered: Vec<Gaussian>,
    /// `x_{k|T}`.
    pub smoothed: Vec<Gaussian>,
    pub outcomes: Vec<Vec<MeasurementOutcome>>,
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FusionError {
    #[error("no epochs to filter")]
    NoEpochs,
    #[error("dimension mismatch in {what} at epoch {epoch}")]
    DimensionMismatch { epoch: usize, what: &'static str },
    #[error("{what} is not positive definite at epoch {epoch}")]
    NotPositiveDefinite { epoch: usize, what: &'static str },
    #[error("odometry has {samples} samples; at least 2 are needed")]
    TooFewOdometrySamples { samples: usize },
    #[error("no ground-truth stream given")]
    NoStreams,
    #[error("no ground-truth measurement falls inside the odometry's time span")]
    NoOverlap,
    #[error("odometry cannot be interpolated at {at_s} s (outside its span or across a gap)")]
    OdometryGap { at_s: f64 },
    #[error("invalid configuration: {reason}")]
    InvalidConfig { reason: &'static str },
}

/// Runs the EKF forward over `measurements.len()` epochs from `prior` (the belief at epoch 0,
/// before its measurements), then the RTS smoother backward. `gate_chi2` rejects measurements
/// whose squared Mahalanobis distance exceeds it.
pub fn filter_and_smooth(
    model: &impl ProcessModel,
    prior: &Gaussian,
    measurements: &[Vec<Measurement>],
    gate_chi2: Option<f64>,
) -> Result<SmootherOutput, FusionError> {
    let epochs = measurements.len();
    if epochs == 0 {
        return Err(FusionError::NoEpochs);
    }
    let dim = prior.mean.len();
    if prior.covariance.shape() != (dim, dim) {
        return Err(FusionError::DimensionMismatch { epoch: 0, what: "prior covariance" });
    }
    let angles = model.angle_components();
    let mut predicted = Vec::with_capacity(epochs);
    let mut filtered: Vec<Gaussian> = Vec::with_capacity(epochs);
    let mut jacobians = Vec::with_capacity(epochs.saturating_sub(1));
    let mut outcomes = Vec::with_capacity(epochs);

    for (epoch, epoch_measurements) in measurements.iter().enumerate() {
        let belief = match filtered.last() {
            None => prior.clone(),
            Some(previous) => {
                let transition = model.transition(epoch, &previous.mean);
                if transition.mean.len() != dim
                    || transition.jacobian.shape() != (dim, dim)
                    || transition.noise.shape() != (dim, dim)
                {
                    return Err(FusionError::DimensionMismatch { epoch, what: "transition" });
                }
                let mut mean = transition.mean;
                wrap_components(&mut mean, angles);
                let covariance = symmetrized(
                    &transition.jacobian * &previous.covariance * transition.jacobian.transpose() + transition.noise,
                );
                jacobians.push(transition.jacobian);
                Gaussian { mean, covariance }
            }
        };
        predicted.push(belief.clone());
        let mut belief = belief;
        let mut epoch_outcomes = Vec::with_capacity(epoch_measurements.len());
        for measurement in epoch_measurements {
            epoch_outcomes.push(update(&mut belief, measurement, angles, gate_chi2, epoch)?);
        }
        outcomes.push(epoch_outcomes);
        filtered.push(belief);
    }

    let mut smoothed = filtered.clone();
    for epoch in (0..epochs - 1).rev() {
        let (current, next_predicted) = (&filtered[epoch], &predicted[epoch + 1]);
        let jacobian = &jacobians[epoch];
        let cholesky = next_predicted
            .covariance
            .clone()
            .cholesky()
            .ok_or(FusionError::NotPositiveDefinite { epoch: epoch + 1, what: "predicted covariance" })?;
        // A = P_{k|k} Fᵀ P_{k+1|k}⁻¹, computed as Aᵀ = P_{k+1|k}⁻¹ (F P_{k|k}) with both symmetric.
        let gain = cholesky.solve(&(jacobian * &current.covariance)).transpose();
        let mut difference = &smoothed[epoch + 1].mean - &next_predicted.mean;
        wrap_components(&mut difference, angles);
        let mut mean = &current.mean + &gain * difference;
        wrap_components(&mut mean, angles);
        let covariance = symmetrized(
            &current.covariance
                + &gain * (&smoothed[epoch + 1].covariance - &next_predicted.covariance) * gain.transpose(),
        );
        smoothed[epoch] = Gaussian { mean, covariance };
    }
    Ok(SmootherOutput { predicted, filtered, smoothed, outcomes })
}

/// One measurement update in Joseph form.
fn update(
    belief: &mut Gaussian,
    measurement: &Measurement,
    angles: &[usize],
    gate_chi2: Option<f64>,
    epoch: usize,
) -> Result<MeasurementOutcome, FusionError> {
    let dim = belief.mean.len();
    let rows = measurement.value.len();
    if measurement.observation.shape() != (rows, dim)
        || measurement.noise.shape() != (rows, rows)
        || measurement.angle_components.iter().any(|&i| i >= rows)
    {
        return Err(FusionError::DimensionMismatch { epoch, what: "measurement" });
    }
    let h = &measurement.observation;
    let mut residual = &measurement.value - h * &belief.mean;
    wrap_components(&mut residual, &measurement.angle_components);
    let projected = h * &belief.covariance * h.transpose();
    let not_pd = FusionError::NotPositiveDefinite { epoch, what: "innovation covariance" };
    let marginal = (&projected + &measurement.noise).cholesky().ok_or(not_pd.clone())?;
    let mahalanobis_sq = residual.dot(&marginal.solve(&residual));
    // A NaN distance fails the gate too.
    if gate_chi2.is_some_and(|gate| mahalanobis_sq.is_nan() || mahalanobis_sq > gate) {
        return Ok(MeasurementOutcome::Rejected { mahalanobis_sq });
    }
    let inflation = measurement.noise_inflation.max(1.0);
    let noise = &measurement.noise * inflation;
    let innovation = if inflation == 1.0 { marginal } else { (projected + &noise).cholesky().ok_or(not_pd)? };
    // K = P Hᵀ S⁻¹, computed as Kᵀ = S⁻¹ (H P) with P and S symmetric.
    let gain = innovation.solve(&(h * &belief.covariance)).transpose();
    belief.mean += &gain * residual;
    wrap_components(&mut belief.mean, angles);
    let i_minus_kh = DMatrix::identity(dim, dim) - &gain * h;
    belief.covariance =
        symmetrized(&i_minus_kh * &belief.covariance * i_minus_kh.transpose() + &gain * noise * gain.transpose());
    Ok(MeasurementOutcome::Used { mahalanobis_sq })
}

fn wrap_components(vector: &mut DVector<f64>, components: &[usize]) {
    for &i in components {
        if let Some(value) = vector.get_mut(i) {
            *value = wrap_angle_rad(*value);
        }
    }
}

fn symmetrized(matrix: DMatrix<f64>) -> DMatrix<f64> {
    (&matrix + matrix.transpose()) * 0.5
}

/// One step of a linear process `x_k = F x_{k−1} + control + w`, `w ~ N(0, noise)`.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearStep {
    pub transition: DMatrix<f64>,
    pub control: DVector<f64>,
    pub noise: DMatrix<f64>,
}

/// A linear process; `steps[k − 1]` leads into epoch `k`.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearProcess {
    pub steps: Vec<LinearStep>,
}

impl ProcessModel for LinearProcess {
    fn transition(&self, epoch: usize, previous_mean: &DVector<f64>) -> Transition {
        match self.steps.get(epoch.wrapping_sub(1)) {
            Some(step) => Transition {
                mean: &step.transition * previous_mean + &step.control,
                jacobian: step.transition.clone(),
                noise: step.noise.clone(),
            },
            // Missing steps are empty matrices, which the filter reports as a dimension error.
            None => Transition { mean: DVector::zeros(0), jacobian: DMatrix::zeros(0, 0), noise: DMatrix::zeros(0, 0) },
        }
    }
}

// ---------------------------------------------------------------------------------------------
// SE(2) ground-truth fusion.

/// Planar pose `(x, y, θ)` of a 3-D pose: its position's x and y and the heading of `body_axis`.
pub fn planar_pose(pose: &Isometry3<f64>, body_axis: &Vector3<f64>) -> Vector3<f64> {
    let heading = crate::timesync::heading_rad(&pose.rotation, body_axis);
    Vector3::new(pose.translation.vector.x, pose.translation.vector.y, heading)
}

/// `x ⊕ u`: the increment `u` (robot frame) applied to pose `x`.
pub fn se2_compose(x: &Vector3<f64>, u: &Vector3<f64>) -> Vector3<f64> {
    let (sin, cos) = x.z.sin_cos();
    Vector3::new(x.x + cos * u.x - sin * u.y, x.y + sin * u.x + cos * u.y, wrap_angle_rad(x.z + u.z))
}

/// The increment from `a` to `b` in `a`'s frame: the `u` with `a ⊕ u = b`.
pub fn se2_between(a: &Vector3<f64>, b: &Vector3<f64>) -> Vector3<f64> {
    let (sin, cos) = a.z.sin_cos();
    let (dx, dy) = (b.x - a.x, b.y - a.y);
    Vector3::new(cos * dx + sin * dy, -sin * dx + cos * dy, wrap_angle_rad(b.z - a.z))
}

/// Jacobians `(F, G_u)` of `x ⊕ u` with respect to `x` and `u` (spec §4.3).
pub fn se2_compose_jacobians(x: &Vector3<f64>, u: &Vector3<f64>) -> (Matrix3<f64>, Matrix3<f64>) {
    let (sin, cos) = x.z.sin_cos();
    #[rustfmt::skip]
    let f = Matrix3::new(
        1.0, 0.0, -sin * u.x - cos * u.y,
        0.0, 1.0, cos * u.x - sin * u.y,
        0.0, 0.0, 1.0,
    );
    #[rustfmt::skip]
    let g = Matrix3::new(
        cos, -sin, 0.0,
        sin, cos, 0.0,
        0.0, 0.0, 1.0,
    );
    (f, g)
}

/// Odometry increment noise in the robot frame, per grid step of `dt` seconds moving `|δp|`
/// metres and turning `|δθ|` radians:
/// `σ²_x = σ²_y = xy_m_per_sqrt_s²·dt + xy_m_per_sqrt_m²·|δp|`,
/// `σ²_θ = heading_rad_per_sqrt_s²·dt + heading_rad_per_sqrt_rad²·|δθ|`.
/// Variances grow linearly with time and motion, so the total does not depend on the grid step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct OdometryNoise {
    pub xy_m_per_sqrt_s: f64,
    pub xy_m_per_sqrt_m: f64,
    pub heading_rad_per_sqrt_s: f64,
    pub heading_rad_per_sqrt_rad: f64,
}

impl Default for OdometryNoise {
    /// A wheeled robot's odometry: 2 cm per √m, 1° per √rad, with small floors.
    fn default() -> Self {
        Self {
            xy_m_per_sqrt_s: 0.002,
            xy_m_per_sqrt_m: 0.02,
            heading_rad_per_sqrt_s: 0.001,
            heading_rad_per_sqrt_rad: 1f64.to_radians(),
        }
    }
}

impl OdometryNoise {
    /// Robot-frame covariance `Q_u` of the increment `u` over `dt_s`.
    pub fn covariance(&self, u: &Vector3<f64>, dt_s: f64) -> Matrix3<f64> {
        let xy = self.xy_m_per_sqrt_s.powi(2) * dt_s + self.xy_m_per_sqrt_m.powi(2) * u.xy().norm();
        let heading = self.heading_rad_per_sqrt_s.powi(2) * dt_s + self.heading_rad_per_sqrt_rad.powi(2) * u.z.abs();
        Matrix3::from_diagonal(&Vector3::new(xy, xy, heading))
    }
}

/// How a stream is resampled onto the grid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StreamSampling {
    /// Each real sample once, interpolated to its nearest grid epoch: no repeated information.
    /// A stream faster than the grid contributes one measurement per epoch.
    #[default]
    NearestEpoch,
    /// A measurement at every grid epoch the stream covers, with `R` inflated by the local
    /// oversampling factor `max(1, sample spacing / grid step)`.
    EveryEpoch,
}

/// A ground-truth stream and its noise.
#[derive(Debug, Clone, PartialEq)]
pub struct GtStream {
    pub name: String,
    /// Poses in the GT world frame; only x, y and the heading are used.
    pub trajectory: Trajectory,
    /// Per-axis position noise (m): RAWSEEDS GT-laser ≈ 0.016, GT-vision ≈ 0.089 (spec §4.3).
    pub sigma_xy_m: f64,
    /// Heading noise (rad): GT-laser 1.56°, GT-vision 2.16°.
    pub sigma_theta_rad: f64,
    /// Known mean heading error (measured − true), removed before use: GT-vision −0.80°.
    pub heading_bias_rad: f64,
    /// Samples further apart than this are not interpolated across (dropouts, robot outside).
    pub max_gap_s: f64,
}

#[derive(Debug, Clone, PartialEq)]
pub struct FusionConfig {
    pub grid_step_s: f64,
    /// Which body axis defines the heading of every stream and the odometry; `Auto` picks it from
    /// the odometry's rotations.
    pub heading_axis: HeadingAxis,
    pub odometry_noise: OdometryNoise,
    /// Odometry samples further apart than this are not interpolated across.
    pub odometry_max_gap_s: f64,
    pub sampling: StreamSampling,
    /// Gate on the squared Mahalanobis distance of a 3-D pose measurement; 16.27 keeps 99.9 % of
    /// Gaussian measurements. `None` uses every measurement.
    pub gate_chi2: Option<f64>,
    /// Prior standard deviations around the first measurement.
    pub initial_sigma_xy_m: f64,
    pub initial_sigma_theta_rad: f64,
}

impl Default for FusionConfig {
    fn default() -> Self {
        Self {
            grid_step_s: 0.01,
            heading_axis: HeadingAxis::BodyX,
            odometry_noise: OdometryNoise::default(),
            odometry_max_gap_s: 0.5,
            sampling: StreamSampling::default(),
            gate_chi2: Some(16.27),
            initial_sigma_xy_m: 10.0,
            initial_sigma_theta_rad: std::f64::consts::PI,
        }
    }
}

/// A planar belief at a grid epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanarState {
    pub stamp_s: f64,
    /// `(x, y, θ)` in m, m, rad.
    pub mean: Vector3<f64>,
    pub covariance: Matrix3<f64>,
}

/// What a stream contributed at one grid epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StreamOutcome {
    /// No measurement: outside the stream's span, inside a gap, or not a sample epoch.
    NoSample,
    Used,
    Rejected,
}

#[derive(Debug, Clone, PartialEq)]
pub struct StreamReport {
    pub name: String,
    pub used: usize,
    pub rejected: usize,
    /// One per grid epoch.
    pub outcomes: Vec<StreamOutcome>,
}

#[derive(Debug, Clone, PartialEq)]
pub struct Fused {
    /// The body axis whose heading is θ.
    pub body_axis: Vector3<f64>,
    pub smoothed: Vec<PlanarState>,
    pub filtered: Vec<PlanarState>,
    /// In the order of the input streams.
    pub streams: Vec<StreamReport>,
}

/// Fuses `streams` with `odometry` as the control on a grid spanning the odometry and the first
/// to the last GT measurement.
pub fn fuse(odometry: &Trajectory, streams: &[GtStream], config: &FusionConfig) -> Result<Fused, FusionError> {
    validate(streams, config)?;
    if odometry.len() < 2 {
        return Err(FusionError::TooFewOdometrySamples { samples: odometry.len() });
    }
    let body_axis = config.heading_axis.resolve(odometry);
    let odometry_series = PlanarSeries::new(odometry, &body_axis);
    let stream_series: Vec<PlanarSeries> =
        streams.iter().map(|stream| PlanarSeries::new(&stream.trajectory, &body_axis)).collect();

    let (odometry_start, odometry_end) = odometry_series.span().ok_or(FusionError::NoOverlap)?;
    let streams_start = stream_series.iter().filter_map(|s| s.span()).map(|(a, _)| a).fold(f64::INFINITY, f64::min);
    let streams_end = stream_series.iter().filter_map(|s| s.span()).map(|(_, b)| b).fold(f64::NEG_INFINITY, f64::max);
    let start_s = odometry_start.max(streams_start);
    let end_s = odometry_end.min(streams_end);
    if end_s.is_nan() || start_s.is_nan() || end_s < start_s {
        return Err(FusionError::NoOverlap);
    }
    let step_s = config.grid_step_s;
    // The small slack keeps an end that lies on the grid from being lost to rounding.
    let grid_len = ((end_s - start_s) / step_s + 1e-9).floor() as usize + 1;
    let grid_s = |k: usize| start_s + k as f64 * step_s;

    let mut measurements: Vec<Vec<Measurement>> = vec![Vec::new(); grid_len];
    for (source, (stream, series)) in streams.iter().zip(&stream_series).enumerate() {
        let noise = Matrix3::from_diagonal(&Vector3::new(
            stream.sigma_xy_m.powi(2),
            stream.sigma_xy_m.powi(2),
            stream.sigma_theta_rad.powi(2),
        ));
        let mut add = |k: usize, value: Vector3<f64>, inflation: f64| {
            let unbiased = Vector3::new(value.x, value.y, wrap_angle_rad(value.z - stream.heading_bias_rad));
            measurements[k].push(Measurement {
                value: DVector::from_column_slice(unbiased.as_slice()),
                observation: DMatrix::identity(3, 3),
                noise: DMatrix::from_column_slice(3, 3, noise.as_slice()),
                noise_inflation: inflation,
                angle_components: vec![2],
                source,
            });
        };
        match config.sampling {
            StreamSampling::EveryEpoch => {
                for k in 0..grid_len {
                    if let Some((value, spacing_s)) = series.at(grid_s(k), stream.max_gap_s) {
                        add(k, value, (spacing_s / step_s).max(1.0));
                    }
                }
            }
            StreamSampling::NearestEpoch => {
                let mut last_epoch = None;
                for &sample_s in &series.stamps_s {
                    let k = ((sample_s - start_s) / step_s).round();
                    if !(k >= 0.0 && k < grid_len as f64) {
                        continue;
                    }
                    let k = k as usize;
                    if last_epoch == Some(k) {
                        continue;
                    }
                    last_epoch = Some(k);
                    if let Some((value, _)) = series.at(grid_s(k), stream.max_gap_s) {
                        add(k, value, 1.0);
                    }
                }
            }
        }
    }

    // Start at the first measurement: its value is the prior mean, so the first linearization is
    // good, and the loose prior covariance lets the measurement itself set the uncertainty.
    let first = measurements.iter().position(|m| !m.is_empty()).ok_or(FusionError::NoOverlap)?;
    let measurements = measurements.split_off(first);
    let stamps_s: Vec<f64> = (first..grid_len).map(grid_s).collect();
    // The most precise stream present at the first epoch sets the prior mean.
    let prior_mean = measurements[0]
        .iter()
        .min_by(|a, b| a.noise.trace().total_cmp(&b.noise.trace()))
        .map(|m| m.value.clone())
        .ok_or(FusionError::NoOverlap)?;
    let prior = Gaussian {
        mean: prior_mean,
        covariance: DMatrix::from_diagonal(&DVector::from_vec(vec![
            config.initial_sigma_xy_m.powi(2),
            config.initial_sigma_xy_m.powi(2),
            config.initial_sigma_theta_rad.powi(2),
        ])),
    };

    let mut odometry_poses = Vec::with_capacity(stamps_s.len());
    for &t in &stamps_s {
        let (pose, _) = odometry_series.at(t, config.odometry_max_gap_s).ok_or(FusionError::OdometryGap { at_s: t })?;
        odometry_poses.push(pose);
    }
    let model = PlanarOdometryModel {
        increments: odometry_poses.windows(2).map(|w| se2_between(&w[0], &w[1])).collect(),
        noise: config.odometry_noise,
        step_s,
    };
    let output = filter_and_smooth(&model, &prior, &measurements, config.gate_chi2)?;

    let mut reports: Vec<StreamReport> = streams
        .iter()
        .map(|s| StreamReport {
            name: s.name.clone(),
            used: 0,
            rejected: 0,
            outcomes: vec![StreamOutcome::NoSample; stamps_s.len()],
        })
        .collect();
    for (k, (epoch_measurements, epoch_outcomes)) in measurements.iter().zip(&output.outcomes).enumerate() {
        for (measurement, outcome) in epoch_measurements.iter().zip(epoch_outcomes) {
            if let Some(report) = reports.get_mut(measurement.source) {
                match outcome {
                    MeasurementOutcome::Used { .. } => {
                        report.used += 1;
                        report.outcomes[k] = StreamOutcome::Used;
                    }
                    MeasurementOutcome::Rejected { .. } => {
                        report.rejected += 1;
                        report.outcomes[k] = StreamOutcome::Rejected;
                    }
                }
            }
        }
    }
    let to_planar = |beliefs: &[Gaussian]| -> Vec<PlanarState> {
        beliefs
            .iter()
            .zip(&stamps_s)
            .map(|(belief, &stamp_s)| PlanarState {
                stamp_s,
                mean: Vector3::from_iterator(belief.mean.iter().copied()),
                covariance: Matrix3::from_iterator(belief.covariance.iter().copied()),
            })
            .collect()
    };
    Ok(Fused {
        body_axis,
        smoothed: to_planar(&output.smoothed),
        filtered: to_planar(&output.filtered),
        streams: reports,
    })
}

fn validate(streams: &[GtStream], config: &FusionConfig) -> Result<(), FusionError> {
    if streams.is_empty() {
        return Err(FusionError::NoStreams);
    }
    let positive = |v: f64| v.is_finite() && v > 0.0;
    if !positive(config.grid_step_s) || !positive(config.odometry_max_gap_s) {
        return Err(FusionError::InvalidConfig { reason: "grid_step_s and odometry_max_gap_s must be positive" });
    }
    if !positive(config.initial_sigma_xy_m) || !positive(config.initial_sigma_theta_rad) {
        return Err(FusionError::InvalidConfig { reason: "initial sigmas must be positive" });
    }
    let noise = &config.odometry_noise;
    if [noise.xy_m_per_sqrt_s, noise.xy_m_per_sqrt_m, noise.heading_rad_per_sqrt_s, noise.heading_rad_per_sqrt_rad]
        .iter()
        .any(|v| !(v.is_finite() && *v >= 0.0))
    {
        return Err(FusionError::InvalidConfig { reason: "odometry noise must be finite and non-negative" });
    }
    if noise.xy_m_per_sqrt_s == 0.0 || noise.heading_rad_per_sqrt_s == 0.0 {
        // Without the time terms a standing robot gets Q = 0, and the RTS gain needs P_{k+1|k}⁻¹.
        return Err(FusionError::InvalidConfig { reason: "odometry noise needs positive per-√s terms" });
    }
    for stream in streams {
        if !positive(stream.sigma_xy_m) || !positive(stream.sigma_theta_rad) || !positive(stream.max_gap_s) {
            return Err(FusionError::InvalidConfig { reason: "stream sigmas and max_gap_s must be positive" });
        }
        if !stream.heading_bias_rad.is_finite() {
            return Err(FusionError::InvalidConfig { reason: "stream heading bias must be finite" });
        }
    }
    if config.gate_chi2.is_some_and(|gate| !positive(gate)) {
        return Err(FusionError::InvalidConfig { reason: "gate_chi2 must be positive" });
    }
    Ok(())
}

/// Odometry composition on the grid.
#[derive(Debug)]
struct PlanarOdometryModel {
    /// `increments[k − 1]` leads into epoch `k`.
    increments: Vec<Vector3<f64>>,
    noise: OdometryNoise,
    step_s: f64,
}

impl ProcessModel for PlanarOdometryModel {
    fn transition(&self, epoch: usize, previous_mean: &DVector<f64>) -> Transition {
        let previous = Vector3::new(previous_mean[0], previous_mean[1], previous_mean[2]);
        let u = self.increments.get(epoch.wrapping_sub(1)).copied().unwrap_or_else(Vector3::zeros);
        let mean = se2_compose(&previous, &u);
        let (f, g) = se2_compose_jacobians(&previous, &u);
        // Q_u is in the robot frame; G_u rotates it into the world frame (trap 15).
        let noise = g * self.noise.covariance(&u, self.step_s) * g.transpose();
        Transition {
            mean: DVector::from_column_slice(mean.as_slice()),
            jacobian: DMatrix::from_column_slice(3, 3, f.as_slice()),
            noise: DMatrix::from_column_slice(3, 3, noise.as_slice()),
        }
    }

    fn angle_components(&self) -> &[usize] {
        &[2]
    }
}

/// Planar poses of a trajectory with interpolation.
#[derive(Debug)]
struct PlanarSeries {
    stamps_s: Vec<f64>,
    poses: Vec<Vector3<f64>>,
}

impl PlanarSeries {
    fn new(trajectory: &Trajectory, body_axis: &Vector3<f64>) -> Self {
        Self {
            stamps_s: trajectory.stamps_s.clone(),
            poses: trajectory.poses.iter().map(|pose| planar_pose(pose, body_axis)).collect(),
        }
    }

    fn span(&self) -> Option<(f64, f64)> {
        Some((*self.stamps_s.first()?, *self.stamps_s.last()?))
    }

    /// The pose at `t` by linear interpolation (shortest arc in heading) and the spacing of the
    /// bracketing samples; `None` outside the span or across a gap longer than `max_gap_s`.
    fn at(&self, t: f64, max_gap_s: f64) -> Option<(Vector3<f64>, f64)> {
        let len = self.stamps_s.len();
        if len < 2 || !(t >= self.stamps_s[0] && t <= self.stamps_s[len - 1]) {
            return None;
        }
        // The bracket [s_i, s_{i+1}) with s_i ≤ t; the last sample closes the last bracket, so
        // every t gets the same kind of bracket and the same oversampling factor.
        let upper = self.stamps_s.partition_point(|&s| s <= t).clamp(1, len - 1);
        let lower = upper - 1;
        let spacing_s = self.stamps_s[upper] - self.stamps_s[lower];
        if spacing_s > max_gap_s {
            return None;
        }
        let a = (t - self.stamps_s[lower]) / spacing_s;
        let (p0, p1) = (&self.poses[lower], &self.poses[upper]);
        let heading = wrap_angle_rad(p0.z + a * wrap_angle_rad(p1.z - p0.z));
        Some((Vector3::new(p0.x + a * (p1.x - p0.x), p0.y + a * (p1.y - p0.y), heading), spacing_s))
    }
}
