//! Overlapping Allan deviation of a uniformly sampled series, and reading noise densities off it
//! in the manner of IEEE Std 952 (Annex C): a white-noise density is the value at τ = 1 s of the
//! slope −½ line fitted where white noise dominates, a random-walk density the value at τ = 3 s
//! of the slope +½ line fitted where the random walk dominates.

/// Why an Allan deviation could not be computed.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AllanError {
    #[error("sample rate must be positive and finite, got {0}")]
    BadRate(f64),
    #[error("cluster size {size} needs at least {} samples, got {len}", 2 * size)]
    TooShort { size: usize, len: usize },
    #[error("cluster size must be at least 1")]
    ZeroCluster,
}

/// The Allan deviation at one cluster time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AllanPoint {
    /// Cluster time τ = m / rate.
    pub tau_s: f64,
    /// Overlapping Allan deviation at τ, in the series' unit.
    pub adev: f64,
    /// Number of non-overlapping clusters of length τ in the series, `⌊N / m⌋`.
    pub clusters: usize,
}

impl AllanPoint {
    /// Relative 1σ uncertainty of `adev`, `1/√(2(K − 1))` for K clusters (IEEE Std 952 Annex C).
    ///
    /// The formula is for non-overlapping clusters; the overlapping estimator is at least as good,
    /// so this is a conservative bound.
    pub fn relative_error(&self) -> f64 {
        if self.clusters < 2 {
            return f64::INFINITY;
        }
        1.0 / (2.0 * (self.clusters - 1) as f64).sqrt()
    }
}

/// Octave-spaced cluster sizes 1, 2, 4, … up to the largest that leaves two clusters in `len`
/// samples.
pub fn octave_cluster_sizes(len: usize) -> Vec<usize> {
    std::iter::successors(Some(1usize), |m| m.checked_mul(2)).take_while(|&m| 2 * m <= len).collect()
}

/// Overlapping Allan deviation of `samples` (taken at `rate_hz`) at each cluster size in
/// `cluster_sizes` (in samples):
/// `σ²(τ) = Σₖ (θₖ₊₂ₘ − 2θₖ₊ₘ + θₖ)² / (2τ²(N + 1 − 2m))`, with `θ` the running integral.
pub fn overlapping_adev(samples: &[f64], rate_hz: f64, cluster_sizes: &[usize]) -> Result<Vec<AllanPoint>, AllanError> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(AllanError::BadRate(rate_hz));
    }
    for &size in cluster_sizes {
        if size == 0 {
            return Err(AllanError::ZeroCluster);
        }
        if 2 * size > samples.len() {
            return Err(AllanError::TooShort { size, len: samples.len() });
        }
    }
    let n = samples.len();
    // The Allan variance ignores a constant offset; removing the mean keeps the running integral
    // small, so the second differences of long series do not lose precision.
    let mean = samples.iter().sum::<f64>() / n as f64;
    let tau0_s = 1.0 / rate_hz;
    let mut theta = Vec::with_capacity(n + 1);
    theta.push(0.0);
    let mut acc = 0.0;
    for &y in samples {
        acc += (y - mean) * tau0_s;
        theta.push(acc);
    }
    Ok(cluster_sizes
        .iter()
        .map(|&m| {
            let terms = n + 1 - 2 * m;
            let sum_sq: f64 = (0..terms)
                .map(|k| {
                    let d = theta[k + 2 * m] - 2.0 * theta[k + m] + theta[k];
                    d * d
                })
                .sum();
            let tau_s = m as f64 * tau0_s;
            AllanPoint { tau_s, adev: (sum_sq / (2.0 * tau_s * tau_s * terms as f64)).sqrt(), clusters: n / m }
        })
        .collect())
}

/// Overlapping Allan deviation at octave-spaced cluster times ([`octave_cluster_sizes`]).
pub fn allan_deviation(samples: &[f64], rate_hz: f64) -> Result<Vec<AllanPoint>, AllanError> {
    overlapping_adev(samples, rate_hz, &octave_cluster_sizes(samples.len()))
}

/// The line of log-log slope `slope` fitted to the points with `τ ∈ [tau_min_s, tau_max_s]`,
/// evaluated at `tau_read_s`; `None` if no point is in range.
///
/// Each point is weighted by the inverse variance of its log deviation, `2(K − 1)`, so long
/// cluster times with few clusters count little.
pub fn line_at(points: &[AllanPoint], slope: f64, tau_min_s: f64, tau_max_s: f64, tau_read_s: f64) -> Option<f64> {
    let (weighted, total) = points
        .iter()
        .filter(|p| (tau_min_s..=tau_max_s).contains(&p.tau_s) && p.clusters >= 2 && p.adev > 0.0)
        .fold((0.0, 0.0), |(weighted, total), p| {
            let w = 2.0 * (p.clusters - 1) as f64;
            (weighted + w * (p.adev.ln() - slope * p.tau_s.ln()), total + w)
        });
    (total > 0.0).then(|| (weighted / total + slope * tau_read_s.ln()).exp())
}

/// White-noise density (unit·√s, e.g. rad/s/√Hz): the slope −½ line through the points in
/// `[tau_min_s, tau_max_s]`, read at τ = 1 s, since there `σ(τ) = N/√τ`.
pub fn white_noise_density(points: &[AllanPoint], tau_min_s: f64, tau_max_s: f64) -> Option<f64> {
    line_at(points, -0.5, tau_min_s, tau_max_s, 1.0)
}

/// Random-walk density (unit/√s, e.g. rad/s²/√Hz): the slope +½ line through the points in
/// `[tau_min_s, tau_max_s]`, read at τ = 3 s, since there `σ(τ) = K·√(τ/3)`.
pub fn random_walk_density(points: &[AllanPoint], tau_min_s: f64, tau_max_s: f64) -> Option<f64> {
    line_at(points, 0.5, tau_min_s, tau_max_s, 3.0)
}
