//! Shared helpers of the dataset tests.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)]

use posegraph::dataset::{self, Problem};
use posegraph::{Key, Pose3, Values, g2o, se3};

/// The pose-graph benchmark folder (`data/posegraph` in the repository).
pub fn data_path(name: &str) -> String {
    format!("{}/../../data/posegraph/{name}", env!("CARGO_MANIFEST_DIR"))
}

pub fn load(name: &str) -> Problem {
    let text = std::fs::read_to_string(data_path(name)).unwrap();
    dataset::from_g2o(&g2o::parse(&text).unwrap(), None).unwrap()
}

/// Ground-truth poses of sphere2500: its ground-truth file holds exact edges only.
pub fn sphere_ground_truth() -> Vec<Pose3> {
    let text = std::fs::read_to_string(data_path("sphere2500_groundtruth.g2o")).unwrap();
    let poses = g2o::parse(&text).unwrap().initial_from_edges().unwrap();
    (0..2500u64).map(|id| poses[&id]).collect()
}

/// Translation RMSE (m) and rotation RMSE (rad) of `values` against ground truth, unaligned.
pub fn rmse_against(values: &Values, truth: &[Pose3]) -> (f64, f64) {
    let mut translation = 0.0;
    let mut rotation = 0.0;
    for (i, gt) in truth.iter().enumerate() {
        let estimate = values.get(Key(i as u64)).unwrap();
        translation += (estimate.translation.vector - gt.translation.vector).norm_squared();
        rotation += se3::so3_log(&(gt.rotation.inverse() * estimate.rotation)).norm_squared();
    }
    let n = truth.len() as f64;
    ((translation / n).sqrt(), (rotation / n).sqrt())
}
