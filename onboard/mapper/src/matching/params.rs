//! Every threshold of the matcher, with the thesis's values where it gives them (trap T15: the
//! experiment series used different, partly unpublished, values, so nothing is hard-coded).

/// Degrees of freedom the RANSAC sampler and the ICP estimate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum MatchMode {
    /// The thesis's proposed matcher: 2-point gravity-constrained RANSAC (eqs. 6.5–6.7) and a
    /// 4-parameter (x, y, z, yaw) Levenberg–Marquardt ICP; roll and pitch stay exactly zero.
    #[default]
    FourDof,
    /// The 6D baseline of §8.1.2: 3-point SVD RANSAC and 6-parameter ICP, with roll/pitch
    /// plausibility gates ([`MatcherParams::max_roll_pitch_ransac_rad`] after RANSAC,
    /// [`MatcherParams::max_roll_pitch_icp_rad`] after ICP).
    SixDof,
}

/// The ICP's residual.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum IcpMetric {
    /// The source point's distance to its target point's tangent plane (target normal from
    /// the 0.2 m PCA). Converges in a few iterations where point-to-point slides.
    #[default]
    PointToPlane,
    /// The thesis's (PCL `IterativeClosestPointNonLinear`) point-to-point distance. On terrain
    /// whose smooth ground outnumbers the rocks it converges slowly: every ground pair pulls
    /// its point back to the nearest sample, so each iteration closes only about the rock
    /// points' share of the remaining error (measured ~3 % per iteration on the test terrain).
    PointToPoint,
}

/// Parameters of [`super::PreparedCloud::new`] and [`super::match_clouds`].
///
/// Descriptor parameters (radii, bins) are read when a cloud's features are first computed:
/// the ones passed to [`super::PreparedCloud::new`] are kept in the cloud, so two clouds
/// prepared with different values must not be matched against each other.
#[derive(Debug, Clone, PartialEq)]
pub struct MatcherParams {
    pub mode: MatchMode,

    // --- §6.1.1 (a): size check ---
    /// Fewer cloud points than this: unsuitable (thesis: 1000).
    pub min_points: usize,
    /// Fewer obstacle points than this: unsuitable (thesis: 100).
    pub min_obstacle_points: usize,

    // --- §6.1.1 (b, d): keypoints and their distribution ---
    /// Voxel size of the obstacle-point centroid filter that yields the keypoints (thesis: 0.1 m).
    pub keypoint_voxel_m: f64,
    /// Keypoints farther than this from the RANSAC line, measured in xy, count as spread
    /// (thesis: 0.5 m).
    pub line_spread_distance_m: f64,
    /// At least this many spread keypoints make a cloud descriptive (thesis: 10).
    pub min_spread_keypoints: usize,
    /// Inlier distance of the 3-D line RANSAC. Unspecified in the thesis; a wall's keypoints
    /// scatter about one keypoint voxel around its median line, so two voxels keep a straight
    /// wall on the line while a second wall a metre away falls outside.
    pub line_inlier_m: f64,
    /// Line RANSAC samples (unspecified in the thesis). With a dominant line holding even 20 %
    /// of the keypoints, 200 two-point samples miss it with probability 0.96^200 ≈ 3e-4.
    pub line_iterations: usize,

    // --- §6.1.2 (a): features ---
    /// Radius of the normals' PCA (thesis: 0.2 m).
    pub normal_radius_m: f64,
    /// Radius of the local reference frames and the descriptor support (thesis: 0.2 m).
    pub descriptor_radius_m: f64,
    /// Keypoints with fewer cloud points than this inside the descriptor radius get no
    /// descriptor: their LRF's eigenvectors are noise.
    pub min_support_points: usize,
    /// Bins of the greyscale part of the descriptor per spatial volume (see `descriptor`).
    pub intensity_bins: usize,
    /// Weight of the greyscale part relative to the shape part before the final L2
    /// normalisation (CSHOT weighs its two unit-norm parts equally: 1.0).
    pub intensity_weight: f32,

    // --- §6.1.2 (b): correspondences ---
    /// Nearest descriptors taken per keypoint, in both directions (thesis: 3).
    pub k_neighbours: usize,
    /// Minimum similarity `1 − d/2` (d: L2 distance of the unit descriptors) of a
    /// correspondence (thesis: 0.5; trap T9).
    pub min_similarity: f32,
    /// Fewer correspondences than this: rejected before the Hough stage.
    pub min_correspondences: usize,

    // --- §6.1.2 (c): Hough3D + RANSAC ---
    /// Edge of the Hough accumulator's cubic bins. Unspecified in the thesis (PCL default 1.0 m);
    /// a vote's error is about |reference vector| × LRF angle error, metres on 10 m submaps.
    pub hough_bin_m: f64,
    /// A local maximum of the accumulator becomes a cluster when it holds at least this many
    /// (interpolated) votes…
    pub hough_min_votes: f64,
    /// …and at least this fraction of the accumulator's global maximum.
    pub hough_relative_threshold: f64,
    /// At most this many clusters per direction, strongest first.
    pub hough_max_clusters: usize,
    /// Distance of a correspondence's transformed source keypoint to its target keypoint below
    /// which it supports a RANSAC model. Unspecified in the thesis; 2.5 keypoint voxels.
    pub ransac_inlier_m: f64,
    /// RANSAC samples per cluster (a cluster with fewer distinct samples is enumerated).
    pub ransac_iterations: usize,
    /// Seed of every random choice of the matcher (results are deterministic).
    pub seed: u64,
    /// 6D mode: hypotheses with |roll| or |pitch| above this are dropped (thesis: 10°).
    pub max_roll_pitch_ransac_rad: f64,

    // --- §6.1.2 (d): hypothesis filtering ---
    /// Gate of the prior check: a translation axis off the prior by more than this many Δσ_t
    /// rejects (thesis: 2).
    pub prior_sigma_factor: f64,
    /// The supporting keypoints of a hypothesis must have at least this many beyond
    /// [`MatcherParams::line_spread_distance_m`] of their line, in each cloud (thesis: the
    /// descriptiveness check's 10, inferred).
    pub hypothesis_min_spread: usize,

    // --- §6.1.2 (e): ICP ---
    /// Residual of the ICP cost (the reported RMSE is point-to-point in both cases).
    pub icp_metric: IcpMetric,
    /// While the pair gate is above its floor, only every n-th source point is paired: the
    /// coarse iterations only need the estimate to move in the right direction.
    pub icp_coarse_stride: usize,
    /// Pair distance gate of the first ICP iteration…
    pub icp_max_distance_start_m: f64,
    /// …shrunk by this factor per iteration…
    pub icp_distance_shrink: f64,
    /// …down to this floor (three 5 cm voxels: the residual of a correct alignment of two
    /// independently voxelised clouds is about one voxel).
    pub icp_max_distance_final_m: f64,
    /// Correspondence-search iterations at most.
    pub icp_max_iterations: usize,
    /// Converged when, at the final gate, an iteration moves the estimate by less than this…
    pub icp_translation_epsilon_m: f64,
    /// …and rotates it by less than this.
    pub icp_rotation_epsilon_rad: f64,
    /// Fewer ICP pairs than this: IcpFailed.
    pub icp_min_pairs: usize,
    /// ICP pairs over the smaller cloud's size below this: IcpFailed (the overlap is too thin).
    pub icp_min_pair_fraction: f64,
    /// Final point-to-point RMSE above this: IcpFailed.
    pub icp_max_rmse_m: f64,
    /// 6D mode: |roll| or |pitch| of the ICP result above this rejects (thesis: 1°).
    pub max_roll_pitch_icp_rad: f64,

    // --- §6.1.2 (f): covariance (see the module documentation) ---
    /// Residuals of points closer than this are treated as one independent sample.
    pub covariance_correlation_m: f64,
    /// Multiplies the whole covariance (tuned by NEES in simulation).
    pub covariance_inflation: f64,
    /// Standard deviation added in quadrature to each translation axis.
    pub covariance_floor_translation_m: f64,
    /// Standard deviation added in quadrature to each estimated rotation axis.
    pub covariance_floor_rotation_rad: f64,
    /// 4D mode: standard deviation of roll and pitch, which the matcher does not estimate (the
    /// submap frames' gravity alignment error).
    pub roll_pitch_sigma_rad: f64,
}

impl Default for MatcherParams {
    fn default() -> Self {
        MatcherParams {
            mode: MatchMode::FourDof,
            min_points: 1000,
            min_obstacle_points: 100,
            keypoint_voxel_m: 0.1,
            line_spread_distance_m: 0.5,
            min_spread_keypoints: 10,
            line_inlier_m: 0.2,
            line_iterations: 200,
            normal_radius_m: 0.2,
            descriptor_radius_m: 0.2,
            min_support_points: 10,
            intensity_bins: 8,
            intensity_weight: 1.0,
            k_neighbours: 3,
            min_similarity: 0.5,
            min_correspondences: 10,
            hough_bin_m: 1.0,
            hough_min_votes: 3.0,
            hough_relative_threshold: 0.3,
            hough_max_clusters: 8,
            ransac_inlier_m: 0.25,
            ransac_iterations: 1000,
            seed: 0x5eed_6a7c_4d11_2019,
            max_roll_pitch_ransac_rad: 10f64.to_radians(),
            prior_sigma_factor: 2.0,
            hypothesis_min_spread: 10,
            icp_metric: IcpMetric::PointToPlane,
            icp_coarse_stride: 4,
            icp_max_distance_start_m: 0.6,
            icp_distance_shrink: 0.6,
            icp_max_distance_final_m: 0.15,
            icp_max_iterations: 30,
            icp_translation_epsilon_m: 1e-4,
            icp_rotation_epsilon_rad: 1e-5,
            icp_min_pairs: 300,
            icp_min_pair_fraction: 0.1,
            icp_max_rmse_m: 0.1,
            max_roll_pitch_icp_rad: 1f64.to_radians(),
            covariance_correlation_m: 0.5,
            covariance_inflation: 1.0,
            covariance_floor_translation_m: 0.01,
            covariance_floor_rotation_rad: 0.1f64.to_radians(),
            roll_pitch_sigma_rad: 0.5f64.to_radians(),
        }
    }
}

impl MatcherParams {
    /// Default parameters in the given mode.
    pub fn with_mode(mode: MatchMode) -> MatcherParams {
        MatcherParams { mode, ..MatcherParams::default() }
    }
}
