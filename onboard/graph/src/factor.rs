//! Factors: a unary prior and a binary between-factor on SE(3) poses, each with a full 6×6
//! information matrix and an optional robust kernel.

use nalgebra::{Matrix6, Vector6};

use crate::error::GraphError;
use crate::se3::{self, Pose3};

/// A variable's name in the graph. The front-end encodes robot, kind and index into it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Key(pub u64);

/// M-estimator replacing the quadratic cost `½ d²` of a factor, `d` its Mahalanobis distance.
///
/// Losses and weights are GTSAM's (`noiseModel::mEstimator`), so costs compare directly.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum RobustKernel {
    /// Plain least squares, `ρ(d) = ½ d²`.
    Quadratic,
    /// Cauchy (thesis eq. 4.10): `ρ(d) = ½ c² log(1 + d²/c²)`, weight `c² / (c² + d²)`.
    Cauchy { c: f64 },
    /// Huber: quadratic up to `|d| = k`, linear beyond; weight `min(1, k / |d|)`.
    Huber { k: f64 },
}

impl RobustKernel {
    /// A Cauchy kernel; `c` is the Mahalanobis distance up to which residuals count as inliers.
    pub fn cauchy(c: f64) -> Result<Self, GraphError> {
        Self::checked(c).map(|c| Self::Cauchy { c })
    }

    /// A Huber kernel with threshold `k` (Mahalanobis distance).
    pub fn huber(k: f64) -> Result<Self, GraphError> {
        Self::checked(k).map(|k| Self::Huber { k })
    }

    fn checked(value: f64) -> Result<f64, GraphError> {
        if value.is_finite() && value > 0.0 { Ok(value) } else { Err(GraphError::InvalidKernelParameter(value)) }
    }

    /// Cost of a residual with squared Mahalanobis distance `d2`.
    pub fn loss(&self, d2: f64) -> f64 {
        match *self {
            Self::Quadratic => 0.5 * d2,
            Self::Cauchy { c } => 0.5 * c * c * (d2 / (c * c)).ln_1p(),
            Self::Huber { k } => {
                let d = d2.sqrt();
                if d <= k { 0.5 * d2 } else { k * (d - 0.5 * k) }
            }
        }
    }

    /// Iteratively-reweighted-least-squares weight at squared distance `d2` (thesis eq. 4.11).
    pub fn weight(&self, d2: f64) -> f64 {
        match *self {
            Self::Quadratic => 1.0,
            Self::Cauchy { c } => c * c / (c * c + d2),
            Self::Huber { k } => {
                let d = d2.sqrt();
                if d <= k { 1.0 } else { k / d }
            }
        }
    }
}

/// Gaussian noise of a 6-D residual (information `Ω = Σ⁻¹`, order `[translation, rotation]`)
/// plus the robust kernel applied to its Mahalanobis distance.
#[derive(Debug, Clone, PartialEq)]
pub struct NoiseModel {
    information: Matrix6<f64>,
    /// Upper-triangular `R` with `RᵀR = Ω`: whitens residuals and Jacobians.
    sqrt_information: Matrix6<f64>,
    kernel: RobustKernel,
}

impl NoiseModel {
    /// From an information matrix; it must be finite, symmetric and positive definite.
    pub fn from_information(information: Matrix6<f64>) -> Result<Self, GraphError> {
        if information.iter().any(|v| !v.is_finite()) {
            return Err(GraphError::InvalidNoise("information has non-finite entries"));
        }
        let scale = information.amax().max(f64::MIN_POSITIVE);
        if (information - information.transpose()).amax() > 1e-9 * scale {
            return Err(GraphError::InvalidNoise("information is not symmetric"));
        }
        let symmetric = (information + information.transpose()) * 0.5;
        let chol = symmetric.cholesky().ok_or(GraphError::InvalidNoise("information is not positive definite"))?;
        Ok(Self { information: symmetric, sqrt_information: chol.l().transpose(), kernel: RobustKernel::Quadratic })
    }

    /// From a covariance matrix (finite, symmetric, positive definite).
    pub fn from_covariance(covariance: Matrix6<f64>) -> Result<Self, GraphError> {
        let chol = covariance.cholesky().ok_or(GraphError::InvalidNoise("covariance is not positive definite"))?;
        Self::from_information(chol.inverse())
    }

    /// Independent standard deviations `[x, y, z (m), rx, ry, rz (rad)]`.
    pub fn from_sigmas(sigmas: [f64; 6]) -> Result<Self, GraphError> {
        if sigmas.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(GraphError::InvalidNoise("standard deviations must be finite and positive"));
        }
        Self::from_information(Matrix6::from_diagonal(&Vector6::from_iterator(sigmas.iter().map(|s| 1.0 / (s * s)))))
    }

    /// The same noise with a robust kernel on top.
    pub fn with_kernel(mut self, kernel: RobustKernel) -> Self {
        self.kernel = kernel;
        self
    }

    pub fn information(&self) -> &Matrix6<f64> {
        &self.information
    }

    pub fn kernel(&self) -> RobustKernel {
        self.kernel
    }

    /// Squared Mahalanobis distance `eᵀ Ω e`.
    pub fn mahalanobis_squared(&self, error: &Vector6<f64>) -> f64 {
        (self.sqrt_information * error).norm_squared()
    }

    /// The factor's cost for a residual: `½ eᵀΩe`, or the kernel's `ρ(d)`.
    pub fn cost(&self, error: &Vector6<f64>) -> f64 {
        self.kernel.loss(self.mahalanobis_squared(error))
    }
}

/// What a factor measures.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FactorKind {
    /// `x ≈ measured`, error `log(measured⁻¹ · x)` (GTSAM's `PriorFactor<Pose3>`).
    Prior,
    /// `x_from⁻¹ · x_to ≈ measured`, error `log(measured⁻¹ · x_from⁻¹ · x_to)`
    /// (GTSAM's `BetweenFactor<Pose3>`).
    Between,
}

/// A measurement factor with its noise.
#[derive(Debug, Clone, PartialEq)]
pub struct Factor {
    kind: FactorKind,
    /// `[key, key]` for a prior, `[from, to]` for a between factor.
    keys: [Key; 2],
    measured: Pose3,
    noise: NoiseModel,
}

/// A factor linearized at given poses: whitened, kernel-weighted Jacobian blocks `A_k` and
/// right-hand side `b` so that the local model of the cost is `½ ‖Σ_k A_k δ_k − b‖²`.
#[derive(Debug, Clone, PartialEq)]
pub struct Linearized {
    pub jacobians: [Matrix6<f64>; 2],
    pub rhs: Vector6<f64>,
}

impl Factor {
    pub fn prior(key: Key, measured: Pose3, noise: NoiseModel) -> Self {
        Self { kind: FactorKind::Prior, keys: [key, key], measured, noise }
    }

    pub fn between(from: Key, to: Key, measured: Pose3, noise: NoiseModel) -> Self {
        Self { kind: FactorKind::Between, keys: [from, to], measured, noise }
    }

    pub fn kind(&self) -> FactorKind {
        self.kind
    }

    pub fn measured(&self) -> &Pose3 {
        &self.measured
    }

    pub fn noise(&self) -> &NoiseModel {
        &self.noise
    }

    /// The same factor with another noise model (for example with a robust kernel added).
    pub fn with_noise(mut self, noise: NoiseModel) -> Self {
        self.noise = noise;
        self
    }

    /// The variables the factor touches: one for a prior, `[from, to]` for a between factor.
    pub fn keys(&self) -> &[Key] {
        &self.keys[..self.arity()]
    }

    /// Number of variables (1 or 2).
    pub fn arity(&self) -> usize {
        match self.kind {
            FactorKind::Prior => 1,
            FactorKind::Between => 2,
        }
    }

    /// The unwhitened error at the given poses (`poses[i]` is the value of `keys()[i]`; a prior
    /// reads `poses[0]` only).
    pub fn error(&self, poses: [&Pose3; 2]) -> Vector6<f64> {
        match self.kind {
            FactorKind::Prior => se3::local(&self.measured, poses[0]),
            FactorKind::Between => se3::log(&(self.measured.inverse() * poses[0].inverse() * poses[1])),
        }
    }

    /// The factor's cost at the given poses.
    pub fn cost(&self, poses: [&Pose3; 2]) -> f64 {
        self.noise.cost(&self.error(poses))
    }

    /// Linearizes at the given poses, with the robust kernel's IRLS weight folded in.
    pub fn linearize(&self, poses: [&Pose3; 2]) -> Linearized {
        let error = self.error(poses);
        let jr_inv = se3::right_jacobian_inv(&error);
        let (j0, j1) = match self.kind {
            FactorKind::Prior => (jr_inv, Matrix6::zeros()),
            FactorKind::Between => {
                // Right perturbation of x_from enters as exp(−Ad((x_from⁻¹ x_to)⁻¹) δ) on the right.
                let relative = poses[0].inverse() * poses[1];
                (-jr_inv * se3::adjoint(&relative.inverse()), jr_inv)
            }
        };
        let whitened = self.noise.sqrt_information * error;
        let sqrt_weight = self.noise.kernel.weight(whitened.norm_squared()).sqrt();
        let r = self.noise.sqrt_information * sqrt_weight;
        Linearized { jacobians: [r * j0, r * j1], rhs: -(whitened * sqrt_weight) }
    }
}
