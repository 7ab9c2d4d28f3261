//! Obstacle classification against the simulator's ground truth (thesis §5.1.1): the camera is
//! placed deliberately 2–5 m from each true obstacle of a Moon world, facing it, plus random
//! viewpoints on open terrain; each stereo pair is rendered, matched by SGM and classified with
//! the ground-truth camera pose, and the obstacle cells within [`RADIUS_M`] (5 m) are scored.
//!
//! A drive through the preset's worlds never brings a true obstacle within 5 m (the planner keeps
//! 1 m clearance and tall rocks are sparse), hence the deliberate viewpoints ([`viewpoints()`]).
//!
//! Truth ([`Truth`]): rocks taller than `h_max`, the negative obstacles' edges (discs every
//! 0.25 m), and terrain steps: cells of the classifier's 5 cm lattice whose 5 × 5 window of
//! **true** heights (the heightfield at the cell centres) spans more than `h_max`, the
//! classifier's own test without stereo error. Such a window is a step the wheel cannot climb,
//! and also a slope of at least atan(0.15 / 0.28) ≈ 28° (diagonal) to 37° (axis), beyond the 25°
//! slope limit: crater walls at the angle of repose are untraversable whatever the preset's
//! obstacle list says.
//!
//! Matching ([`MATCHING`]): a detected cell matches a true obstacle within its radius plus
//! 0.15 m (half the 5-cell step window plus one cell); detected cells closer than 0.075 m join
//! one cluster (single linkage: 8-connected 5 cm cells), and a cluster counts as matched when
//! at least half its cells match (`eval::map::evaluate_obstacles`). Recall counts the true obstacles in the mapped area; an
//! obstacle seen from k viewpoints counts k times ([`Tally`]).
//!
//! **Approach runs** ([`approaches`], [`Evaluator::drive`]): the camera drives straight at each
//! rock and each edge target from 5 m to 2.5 m ([`APPROACH_M`]), a frame every 0.5 m, on a path
//! whose body stays on free ground; a target counts as found when one frame detects it. That is
//! what the planner needs: a warning before the rover is there. A single frame is not enough
//! evidence by construction: the step threshold `h_max + Δd` grows with range, so a rock just
//! above `h_max` passes it only near, where its foot may already be below the image.
//!
//! Experiments: [`Evaluator::true_depth`] classifies the renderer's exact depth instead of SGM's
//! (the classifier's own ceiling); [`Truth::keep_steep_edges`] keeps only the edge discs where
//! the true ground drops by more than `h_max` at more than the slope limit (the sim's crater-edge
//! list also holds rims one may drive down); [`Viewpoint::tilt_rad`] tilts the head down by
//! another angle than mounted.
//!
//! The command line: `cargo run --release -p sil --example sim_obstacles -- [--seeds N]
//! [--per-target K] [--open M] [--dump]` (see the example for the other flags); the stereo
//! defaults are the on-board ones (`vision::depth_sgm_config`, `SpeckleFilter::for_image`). The
//! integration test `sil/tests/obstacles_eval.rs` uses [`Evaluator`].

use eval::map::ObstacleMatching;

mod evaluator;
pub mod report;
mod tally;
pub mod traverse;
mod truth;
mod viewpoints;

pub use evaluator::{Diagnosis, EdgeSample, Evaluator};
pub use tally::{DISPARITY_BIN_PX, DISPARITY_SPAN_PX, FalseCluster, RANGE_BIN_M, RANGE_BINS, RunOutcome, Tally, ratio};
pub use truth::{Truth, moon_world, preset_world};
pub use viewpoints::{
    APPROACH_M, APPROACH_STEP_M, Aim, Approach, DISTANCES_M, EDGE_SECTION_M, Viewpoint, approach_distances, approaches,
    viewpoints,
};

/// Evaluation radius around the camera (the "within 5 m").
pub const RADIUS_M: f64 = 5.0;
/// A detected cell matches an obstacle within its radius plus this: half the 5-cell step
/// window (the window labels cells up to two cells beyond a step) plus one cell.
pub const MATCHING: ObstacleMatching = ObstacleMatching { tolerance_m: 0.15, link_distance_m: 0.075 };

/// Why a world, an evaluator or a frame's evaluation could not be made.
#[derive(Debug, thiserror::Error)]
pub enum EvaluationError {
    /// The Moon preset refused the options.
    #[error("scenario: {0}")]
    Scenario(#[from] sim::scenario::ScenarioError),
    /// The world could not be built from the scenario.
    #[error("world: {0}")]
    World(#[from] sim::world::WorldError),
    /// The classifier refused its configuration.
    #[error("obstacle configuration: {0}")]
    Config(#[from] vision::obstacles::ObstacleConfigError),
    /// The stereo pipeline could not be built or could not match a pair.
    #[error("{0}")]
    Depth(#[from] vision::DepthError),
    /// The classifier's height map is no usable grid.
    #[error("height map: {0}")]
    HeightMap(#[from] eval::map::HeightGridError),
    /// The detections could not be scored against the truth.
    #[error("obstacle scoring: {0}")]
    Scoring(#[from] eval::map::ObstacleEvalError),
}
