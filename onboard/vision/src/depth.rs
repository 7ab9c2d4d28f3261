//! Depth images: per-pixel depth along the left rectified camera's optical axis.

use fpga_model::{DisparityImage, SgmConfig};
use hal::sensor::StereoCalibration;

/// SGM's uniqueness margin for the on-board depth images (mapping and obstacle classification).
///
/// The matcher's default (0, off) is tuned for Middlebury's textured scenes. On the simulated
/// Moon the black shadows in craters, ditches and behind rocks are sensor noise, and SGM's paths
/// agree on some disparity there that both the LR check and a 0 % margin accept: 1.7 % of the
/// pixels within the classifier's range were off by more than 3 px, and their patches made most
/// of the false obstacles. Measured with `sil`'s `sim_obstacles` example (seed 1, 264 viewpoints),
/// without the speckle filter: margin 0 / 10 / 20 % gave blunders 1.71 / 0.43 / 0.27 %, invalid
/// pixels 6.2 / 8.3 / 9.1 %, cluster precision 70.5 / 80.1 / 91.5 %, rock recall 82.9 / 82.9 /
/// 80.0 %. With the speckle filter, 10 / 15 / 20 % gave precision 87.0 / 88.7 / 91.1 % and rock
/// recall 82.9 / 82.9 / 80.0 % (the 15 and 20 % runs also bridged unmatched rows in the
/// negative-edge test, worth about +0.4 points and not kept): 15 % is the largest margin that
/// lost no rock.
pub const DEPTH_UNIQUENESS_PERCENT: u8 = 15;

/// The SGM configuration of the on-board depth images: the matcher's default with
/// [`DEPTH_UNIQUENESS_PERCENT`]. Follow it with [`crate::SpeckleFilter::for_image`].
pub fn depth_sgm_config() -> SgmConfig {
    SgmConfig { uniqueness_percent: DEPTH_UNIQUENESS_PERCENT, ..SgmConfig::default() }
}

/// Intrinsics of the rectified left camera and the stereo baseline.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoGeometry {
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
    pub baseline_m: f64,
}

impl StereoGeometry {
    /// The left camera's intrinsics and the baseline of a calibration; meaningful for a
    /// rectified pair (the simulator's, or [`crate::Rectifier::rectified_calibration`]).
    pub fn from_calibration(calibration: &StereoCalibration) -> StereoGeometry {
        let k = calibration.left.intrinsics;
        StereoGeometry {
            fx_px: k.fx_px,
            fy_px: k.fy_px,
            cx_px: k.cx_px,
            cy_px: k.cy_px,
            baseline_m: calibration.baseline_m,
        }
    }

    /// Back-projects pixel `(u, v)` at depth `z` into the left camera frame (x right, y down,
    /// z forward).
    pub fn point_at(&self, u: f64, v: f64, z_m: f64) -> [f64; 3] {
        [(u - self.cx_px) * z_m / self.fx_px, (v - self.cy_px) * z_m / self.fy_px, z_m]
    }
}

/// Depth per pixel, row-major. Conventions (thesis trap 11): `NaN` = invalid (no match),
/// `f32::INFINITY` = zero disparity (a point at infinity: valid for negative-edge detection, no
/// 3D point).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct DepthImage {
    pub width: usize,
    pub height: usize,
    pub depth_m: Vec<f32>,
}

impl DepthImage {
    pub fn new(width: usize, height: usize) -> DepthImage {
        DepthImage { width, height, depth_m: vec![f32::NAN; width * height] }
    }

    /// Fills from a disparity map: `z = f·b / d`; zero disparity → infinity, invalid → NaN.
    /// Reuses the buffer (no allocation once sized).
    pub fn fill_from_disparity(&mut self, disparity: &DisparityImage, geometry: &StereoGeometry) {
        self.width = disparity.width;
        self.height = disparity.height;
        self.depth_m.resize(disparity.width * disparity.height, f32::NAN);
        let fb = (geometry.fx_px * geometry.baseline_m) as f32;
        for y in 0..disparity.height {
            for x in 0..disparity.width {
                self.depth_m[y * disparity.width + x] = match disparity.get_px(x, y) {
                    None => f32::NAN,
                    Some(d) if d <= 0.0 => f32::INFINITY,
                    Some(d) => fb / d,
                };
            }
        }
    }

    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.depth_m[y * self.width + x]
    }
}
