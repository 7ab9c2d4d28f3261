//! Helpers shared by the Middlebury accuracy tests.
#![allow(dead_code, clippy::unwrap_used)]

use fpga_model::eval::{DEFAULT_THRESHOLD_PX, Scene, default_data_root};
use fpga_model::{SgmConfig, fast, io};

/// The four Middlebury scenes of the repository's `data/stereo/`.
pub fn scenes() -> Vec<Scene> {
    Scene::load_all(default_data_root()).unwrap()
}

/// Our bad-pixel rate in percent with the CLI's default configuration for the scene's D.
pub fn ours_percent(scene: &Scene) -> f64 {
    let config = SgmConfig { disparities: scene.disparities, ..Default::default() };
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    let mut matcher = fast::Matcher::new(config, scene.left.width, scene.left.height, threads).unwrap();
    let disparity = matcher.compute(&scene.left, &scene.right).unwrap();
    100.0 * scene.bad_pixel_rate(&io::disparity_to_pfm_values(&disparity), DEFAULT_THRESHOLD_PX).unwrap()
}
