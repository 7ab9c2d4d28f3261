//! Counts of one evaluation: recall of rocks, edge discs and true step cells, cluster precision,
//! the SGM disparity error, and what an approach run found.

use nalgebra::Point2;

use super::Aim;

/// Recall by range: bins of this width from the camera out to [`RADIUS_M`](super::RADIUS_M).
pub const RANGE_BIN_M: f64 = 1.0;
/// Number of range bins (the last one also holds everything beyond).
pub const RANGE_BINS: usize = 6;

/// The range bin of a horizontal distance from the camera.
pub(super) fn range_bin(distance_m: f64) -> usize {
    ((distance_m / RANGE_BIN_M).max(0.0) as usize).min(RANGE_BINS - 1)
}

/// Counts one obstacle into a (seen, found) pair.
pub(super) fn count(pair: &mut (usize, usize), hit: bool) {
    pair.0 += 1;
    pair.1 += usize::from(hit);
}

/// Adds (seen, found) pairs element by element.
fn add_pairs(into: &mut [(usize, usize)], from: &[(usize, usize)]) {
    for (a, b) in into.iter_mut().zip(from) {
        a.0 += b.0;
        a.1 += b.1;
    }
}

/// Histogram of the SGM disparity error (see [`Tally::disparity_error_bins`]): bin width.
pub const DISPARITY_BIN_PX: f64 = 0.02;
/// Histogram of the SGM disparity error: the bins span ± this.
pub const DISPARITY_SPAN_PX: f64 = 3.0;

/// Counts summed over frames (an obstacle seen from k viewpoints counts k times).
#[derive(Debug, Clone, Default)]
pub struct Tally {
    /// Frames evaluated.
    pub frames: usize,
    /// Rocks taller than h_max within 5 m in the mapped area, and those detected.
    pub rocks: usize,
    /// See [`Tally::rocks`].
    pub rocks_found: usize,
    /// Rocks by height: [h_max, h_max + 0.1), [+0.1, +0.3), ≥ +0.3; (seen, found).
    pub rock_bins: [(usize, usize); 3],
    /// Rocks and edge discs by horizontal distance from the camera to their centre, in
    /// [`RANGE_BIN_M`] bins; (seen, found).
    pub rock_ranges: [(usize, usize); RANGE_BINS],
    /// See [`Tally::rock_ranges`].
    pub edge_ranges: [(usize, usize); RANGE_BINS],
    /// Negative-edge discs within 5 m in the mapped area, and those detected.
    pub edges: usize,
    /// See [`Tally::edges`].
    pub edges_found: usize,
    /// Known cells within 5 m whose true window step exceeds h_max, and those detected.
    pub step_cells: usize,
    /// See [`Tally::step_cells`].
    pub step_cells_found: usize,
    /// Clusters of detected cells within 5 m.
    pub clusters: usize,
    /// Clusters matched by the rocks alone, by rocks and edges, by rocks, edges and terrain steps.
    pub clusters_rocks: usize,
    /// See [`Tally::clusters_rocks`].
    pub clusters_listed: usize,
    /// See [`Tally::clusters_rocks`].
    pub clusters_any: usize,
    /// Wall time of each frame's classification.
    pub classify_ms: Vec<f64>,
    /// SGM disparity minus true disparity (from the rendered depth) of pixels whose true depth is
    /// within the range cutoff: counts in bins of [`DISPARITY_BIN_PX`] over ±[`DISPARITY_SPAN_PX`],
    /// then pixels beyond that span (blunders) and pixels SGM left invalid.
    pub disparity_error_bins: Vec<u64>,
    /// See [`Tally::disparity_error_bins`].
    pub disparity_blunders: u64,
    /// See [`Tally::disparity_error_bins`].
    pub disparity_invalid: u64,
}

impl Tally {
    /// Adds `other`'s counts to these.
    pub fn add(&mut self, other: &Tally) {
        self.frames += other.frames;
        self.rocks += other.rocks;
        self.rocks_found += other.rocks_found;
        add_pairs(&mut self.rock_bins, &other.rock_bins);
        add_pairs(&mut self.rock_ranges, &other.rock_ranges);
        add_pairs(&mut self.edge_ranges, &other.edge_ranges);
        self.edges += other.edges;
        self.edges_found += other.edges_found;
        self.step_cells += other.step_cells;
        self.step_cells_found += other.step_cells_found;
        self.clusters += other.clusters;
        self.clusters_rocks += other.clusters_rocks;
        self.clusters_listed += other.clusters_listed;
        self.clusters_any += other.clusters_any;
        self.classify_ms.extend_from_slice(&other.classify_ms);
        self.disparity_error_bins.resize(other.disparity_error_bins.len().max(self.disparity_error_bins.len()), 0);
        for (a, b) in self.disparity_error_bins.iter_mut().zip(&other.disparity_error_bins) {
            *a += b;
        }
        self.disparity_blunders += other.disparity_blunders;
        self.disparity_invalid += other.disparity_invalid;
    }

    /// Quantile `q` of the signed disparity error within ±[`DISPARITY_SPAN_PX`] (bin centres).
    pub fn disparity_error_quantile_px(&self, q: f64) -> Option<f64> {
        let total: u64 = self.disparity_error_bins.iter().sum();
        let target = (q * total as f64).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (k, &n) in self.disparity_error_bins.iter().enumerate() {
            seen += n;
            if seen >= target {
                return Some((k as f64 + 0.5) * DISPARITY_BIN_PX - DISPARITY_SPAN_PX);
            }
        }
        None
    }

    /// Rocks found over rocks seen.
    pub fn rock_recall(&self) -> Option<f64> {
        ratio(self.rocks_found, self.rocks)
    }

    /// Edge discs found over edge discs seen.
    pub fn edge_recall(&self) -> Option<f64> {
        ratio(self.edges_found, self.edges)
    }

    /// True step cells detected over those known.
    pub fn step_recall(&self) -> Option<f64> {
        ratio(self.step_cells_found, self.step_cells)
    }

    /// Cluster precision against the listed obstacles only (rocks > h_max, negative edges).
    pub fn precision_listed(&self) -> Option<f64> {
        ratio(self.clusters_listed, self.clusters)
    }

    /// Cluster precision with the true terrain steps in the truth set.
    pub fn precision(&self) -> Option<f64> {
        ratio(self.clusters_any, self.clusters)
    }
}

/// `a / b`, `None` for `b = 0`.
pub fn ratio(a: usize, b: usize) -> Option<f64> {
    (b > 0).then(|| a as f64 / b as f64)
}

/// A cluster of detected cells that matches no listed obstacle (rock > h_max, negative edge), for
/// the analysis of causes.
#[derive(Debug, Clone)]
pub struct FalseCluster {
    /// Mean of the cells' centres.
    pub centre_m: Point2<f64>,
    /// Number of cells.
    pub cells: usize,
    /// Horizontal distance from the camera to the centre.
    pub camera_distance_m: f64,
    /// Largest measured `h_diff` and threshold `h_max + Δd` over the cluster's cells.
    pub h_diff_m: f32,
    /// See [`FalseCluster::h_diff_m`].
    pub threshold_m: f32,
    /// Largest true window step over the cluster's cells.
    pub true_step_m: f32,
    /// Whether a negative-edge top lies in the cluster.
    pub negative_edge: bool,
}

/// What one approach run found: whether the target was ever mapped, and the farthest camera
/// distance at which it was detected.
#[derive(Debug, Clone, Copy)]
pub struct RunOutcome {
    /// The run's [`Approach::aim`](super::Approach::aim).
    pub aim: Aim,
    /// The run's [`Approach::excess_height_m`](super::Approach::excess_height_m).
    pub excess_height_m: f64,
    /// Whether any frame mapped the target.
    pub seen: bool,
    /// The camera distance of the first (farthest) frame that detected the target.
    pub found_at_m: Option<f64>,
}
