//! Parameters of the obstacle classification, with the choices the thesis leaves open.

use super::stereo_error::StereoErrorModel;

/// Why a configuration was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ObstacleConfigError {
    #[error("{field} must be finite and positive (got {value})")]
    NotPositive { field: &'static str, value: f64 },
    #[error("the step window must be 3 to 6 cells wide (got {0})")]
    Window(usize),
    #[error("the step support must be 1 to 3 cells (got {0})")]
    Support(usize),
    #[error("the maximum slope must lie in (0°, 90°) (got {0} rad)")]
    Slope(f64),
}

/// Obstacle classification parameters for an LRU-like 40 kg rover (thesis §5.1.1).
///
/// The thesis gives neither the maximum step height nor the maximum slope (spec trap 26). Our
/// choices, for four individually driven wheels of about 0.3 m diameter and no rocker-bogie:
/// - `max_step_m` = 0.15 m, half a wheel diameter: a driven wheel climbs a step up to about
///   its radius before the contact point is above the axle and the wheel only pushes against the
///   step; the chassis clearance (≈ 0.2 m under the sim's LRU-like body) is larger, so the wheel
///   is the limit. Lower values make every crater rim an obstacle at our stereo noise.
/// - `max_slope_rad` = 25°: wheeled rovers on loose regolith slip heavily beyond 20–25°, and the
///   simulator's planner uses the same limit, so the negative-edge test and the ground truth
///   agree on what is a cliff.
/// - `window_cells` = 5 (0.25 m): odd, so the window is centred on its cell, and about the size
///   of a wheel's contact patch plus the step it climbs.
/// - `max_depth_error_m` = 0.15 m: the thesis's bound (Fig. 5.2), 4.5 m for the narrow camera.
/// - `min_edge_pixels` = 10: a negative edge counts only as an 8-connected line of at least
///   this many top pixels. A rim 10 cm long spans 24 px at the 4.5 m range cutoff (f = 1083 px);
///   SGM blunders next to good pixels (on the simulated Moon mostly in black shadows) make
///   isolated one- to few-pixel "cliffs" whose floating top looks exactly like a rim.
/// - `pixel_error_px` = 0.5 (the thesis's Δp), kept after measuring: the fpga_model SGM on the
///   simulated Moon images (`sim_obstacles` example, 3 seeds, 637 frames, 1.1·10⁸ pixels with a
///   true depth ≤ 4.5 m) has a disparity error core of σ ≈ 0.21 px (1.4826·MAD; 15.9/84.1 %
///   quantiles −0.21/+0.19 px), i.e. 0.15 px per image coordinate, so 0.5 px (0.71 px of
///   disparity) already covers the core 3.4σ wide. The false steps come from the tails instead
///   (about 1.7 % of pixels off by more than 3 px, spatially clustered in black shadows), which
///   no Gaussian Δp describes; raising Δp would only blind the classifier at range. The matcher's
///   uniqueness margin and the speckle filter (`crate::depth_sgm_config`) cut that tail to
///   0.12 %, leaving the core unchanged (1.4826·MAD 0.18 px).
/// - `step_support_cells` = 2: the window's extremes are its second-highest and second-lowest
///   cells. A single cell mean pulled away by an SGM blunder patch no longer makes a step, while
///   a real step (a rock's flank, a ditch wall) puts many cells on each side of the window.
///   Obstacles narrower than two cells (10 cm) are lost; every rock the sim lists taller than
///   h_max is at least twice as wide. Measured on seed 1: false clusters 827 → 310, cluster
///   precision 64.4 → 70.5 %, rock recall unchanged, negative-edge recall 34.5 → 23.9 % (the
///   far wall of a ditch seen as a thin band is lost with the noise); 3 gave 72.3 % precision
///   at lower recall.
/// - `min_step_cluster_cells` = 1 (off): dropping 8-connected step groups under 4 cells removed
///   single-cell false clusters but barely moved precision (70.5 → 70.8 %, seed 1) and lost a rock.
/// - `min_points_per_cell` = 3: a cell's mean from one or two pixels is an SGM outlier as often
///   as not; near cells hold hundreds of points, cells at the range cutoff still dozens.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ObstacleConfig {
    /// `Δp` of the stereo error model (eqs. 5.2–5.4).
    pub pixel_error_px: f64,
    /// `h_max`: the largest step the rover drives over.
    pub max_step_m: f64,
    /// Negative edges with a minimal slope `s_min` steeper than this are obstacles.
    pub max_slope_rad: f64,
    /// Depth jump between vertically adjacent pixels that starts a negative-edge test (0.2 m).
    pub edge_jump_m: f64,
    /// Points with a larger depth error `Δp_z` are not classified (flagged `TOO_FAR`).
    pub max_depth_error_m: f64,
    /// Height map cell edge (0.05 m).
    pub cell_size_m: f64,
    /// Edge of the square step window in cells (3–6).
    pub window_cells: usize,
    /// Half the edge of the height map around the camera; points farther away are dropped. Must
    /// exceed the range cutoff's horizontal reach.
    pub map_half_extent_m: f64,
    pub min_points_per_cell: u32,
    /// Smallest 8-connected group of negative-edge top pixels that is kept.
    pub min_edge_pixels: usize,
    /// The step window's extremes are its k-th highest and k-th lowest cells (1 = max − min).
    pub step_support_cells: usize,
    /// Step cells count only in 8-connected groups of at least this many cells.
    pub min_step_cluster_cells: usize,
    /// Unknown beyond a rim: the negative-edge test also pairs a pixel with the nearest valid
    /// pixel below it across at most this many unmatched pixels of its column (0 = the
    /// thesis's rule, adjacent pixels only). See [`super::negative_edges`].
    pub bridge_invalid_px: usize,
    /// Beyond the thesis: a rim whose next ground seen up the column is more than this (and
    /// `h_max`, plus the far point's depth error) lower is an edge whatever the slope between
    /// ([`super::negative_edges::hidden_drop`]); 0 = off.
    pub hidden_drop_m: f64,
    /// With `bridge_invalid_px > 0`: a rim followed up its column by unmatched pixels hiding
    /// more than this much ground (horizontally, up to the next ground seen) is an edge: a gap
    /// the wheel would cross blind (a wheel's diameter, 0.3 m).
    pub max_unseen_gap_m: f64,
    /// In the rolling local map: edges that only the hidden-drop or unseen-gap rules marked are
    /// low-passed again once a view sees the cell without an edge; measured edges stay held
    /// ([`super::LocalObstacleMap::releasing_unseen_edges`]).
    pub release_unseen_edges: bool,
}

impl Default for ObstacleConfig {
    fn default() -> Self {
        ObstacleConfig {
            pixel_error_px: 0.5,
            max_step_m: 0.15,
            max_slope_rad: 25f64.to_radians(),
            edge_jump_m: 0.2,
            max_depth_error_m: 0.15,
            cell_size_m: 0.05,
            window_cells: 5,
            map_half_extent_m: 6.0,
            min_points_per_cell: 3,
            min_edge_pixels: 10,
            step_support_cells: 2,
            min_step_cluster_cells: 1,
            bridge_invalid_px: 0,
            hidden_drop_m: 0.0,
            max_unseen_gap_m: 0.3,
            release_unseen_edges: false,
        }
    }
}

impl ObstacleConfig {
    pub fn validate(&self) -> Result<(), ObstacleConfigError> {
        for (field, value) in [
            ("pixel_error_px", self.pixel_error_px),
            ("max_step_m", self.max_step_m),
            ("edge_jump_m", self.edge_jump_m),
            ("max_depth_error_m", self.max_depth_error_m),
            ("cell_size_m", self.cell_size_m),
            ("map_half_extent_m", self.map_half_extent_m),
            ("max_unseen_gap_m", self.max_unseen_gap_m),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(ObstacleConfigError::NotPositive { field, value });
            }
        }
        if !(3..=6).contains(&self.window_cells) {
            return Err(ObstacleConfigError::Window(self.window_cells));
        }
        if !(1..=super::height_map::MAX_SUPPORT).contains(&self.step_support_cells) {
            return Err(ObstacleConfigError::Support(self.step_support_cells));
        }
        if !(self.max_slope_rad > 0.0 && self.max_slope_rad < std::f64::consts::FRAC_PI_2) {
            return Err(ObstacleConfigError::Slope(self.max_slope_rad));
        }
        Ok(())
    }

    pub fn error_model(&self, f_px: f64, baseline_m: f64) -> StereoErrorModel {
        StereoErrorModel { pixel_error_px: self.pixel_error_px, f_px, baseline_m }
    }
}
