//! Middlebury evaluation: the scenes the accuracy tests use, and the bad-pixel rate.
//!
//! One scoring implementation for every matcher: our core and the OpenCV comparison (whose
//! results arrive as PFM files) are scored by [`bad_pixel_rate`] on the same [`Scene`]s.
//!
//! Scenes (data under the repository's `data/stereo`, see each folder's `SOURCE.md`):
//! - `tsukuba`, `teddy`, `cones` (`middlebury_v2/`): `imL.png`/`imR.png`, ground truth
//!   `groundtruth.png` with disparity = value / scale, the scale on line 1 of `info.txt`
//!   (16, 4, 4; tsukuba's GT is a 4-bit palette PNG, decoded through its palette), value 0 =
//!   unknown; evaluated pixels: the official `nonocc.png` mask (255), threshold 1 px, as in the
//!   Middlebury v2 table. `D` = line 2 of `info.txt` (disparity levels) rounded up to 16.
//! - `Reindeer` (`middlebury_2005_2006_half/Reindeer`, half size): `view1.png`/`view5.png`, GT
//!   `disp1.png` (left) and `disp5.png` (right), disparity = value / 2, 0 = unknown. Middlebury
//!   ships no masks for the 2005 sets in this copy, so the non-occluded mask is derived the way
//!   Middlebury derives its own from the two GT maps: a left pixel is evaluated if its GT `dL`
//!   is known, its match `xr = x − round(dL)` (round half away from zero) lies in the image,
//!   the right GT `dR(xr)` is known, and the two agree: `|dL − dR(xr)| ≤ 1` px. `D` = the
//!   smallest multiple of 16 above the largest GT disparity (112 for Reindeer).

use std::fs;
use std::path::{Path, PathBuf};

use crate::image::GrayImage;
use crate::io::{self, IoError, PngValues};

/// Errors of loading or scoring a scene.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Io(#[from] IoError),
    #[error("{path}: {source}")]
    File { path: PathBuf, source: std::io::Error },
    #[error("{path}: {reason}")]
    Format { path: PathBuf, reason: String },
    #[error("scene {scene}: {reason}")]
    Scene { scene: String, reason: String },
    #[error("length mismatch: estimate {estimate}, ground truth {gt}, mask {mask}")]
    Length { estimate: usize, gt: usize, mask: usize },
}

/// A stereo pair with ground truth and the pixels to evaluate.
#[derive(Debug, Clone)]
pub struct Scene {
    pub name: String,
    pub left: GrayImage,
    pub right: GrayImage,
    /// The files `left` and `right` were read from (so another matcher can read the same ones).
    pub left_path: PathBuf,
    pub right_path: PathBuf,
    /// Left-view ground-truth disparity in pixels, row-major; NaN where unknown.
    pub gt_px: Vec<f32>,
    /// Pixels that are evaluated (non-occluded), row-major.
    pub mask: Vec<bool>,
    /// Disparities to search: a multiple of 16 covering the scene's disparity range.
    pub disparities: u16,
}

/// The Middlebury v2 scenes in this repository's data, in table order.
pub const V2_SCENES: [&str; 3] = ["tsukuba", "teddy", "cones"];

/// The stereo data folder (`data/stereo`) seen from this crate's manifest directory.
pub fn default_data_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/stereo")
}

fn read_text(path: &Path) -> Result<String, EvalError> {
    fs::read_to_string(path).map_err(|source| EvalError::File { path: path.to_owned(), source })
}

/// `n` rounded up to a multiple of 16, at least 16.
fn round_up_16(n: u32) -> u32 {
    n.div_ceil(16).max(1) * 16
}

fn check_size(scene: &str, what: &str, values: &PngValues, left: &GrayImage) -> Result<(), EvalError> {
    if values.width != left.width || values.height != left.height {
        return Err(EvalError::Scene {
            scene: scene.to_owned(),
            reason: format!(
                "{what} is {}x{} but the left image is {}x{}",
                values.width, values.height, left.width, left.height
            ),
        });
    }
    Ok(())
}

fn check_pair_size(scene: &str, left: &GrayImage, right: &GrayImage) -> Result<(), EvalError> {
    if (left.width, left.height) != (right.width, right.height) {
        return Err(EvalError::Scene {
            scene: scene.to_owned(),
            reason: format!("left is {}x{} but right is {}x{}", left.width, left.height, right.width, right.height),
        });
    }
    Ok(())
}

/// GT value → disparity in px, 0 → NaN (unknown).
fn gt_to_px(values: &[u16], scale: f32) -> Vec<f32> {
    values.iter().map(|&v| if v == 0 { f32::NAN } else { f32::from(v) / scale }).collect()
}

impl Scene {
    /// Loads a Middlebury v2 scene (`tsukuba`, `teddy`, `cones`) from `<root>/middlebury_v2/<name>`.
    pub fn load_v2(data_root: impl AsRef<Path>, name: &str) -> Result<Scene, EvalError> {
        let dir = data_root.as_ref().join("middlebury_v2").join(name);
        let info_path = dir.join("info.txt");
        let info = read_text(&info_path)?;
        let mut lines = info.lines().map(str::trim).filter(|l| !l.is_empty());
        let format_err = |reason: &str| EvalError::Format { path: info_path.clone(), reason: reason.to_owned() };
        let gt_scale: u32 = lines
            .next()
            .and_then(|l| l.parse().ok())
            .filter(|&s| s > 0)
            .ok_or_else(|| format_err("line 1 must be the GT scale (a positive integer)"))?;
        let levels: u32 = lines
            .next()
            .and_then(|l| l.parse().ok())
            .filter(|&n| n > 0)
            .ok_or_else(|| format_err("line 2 must be the number of disparity levels"))?;

        let left_path = dir.join("imL.png");
        let right_path = dir.join("imR.png");
        let left = io::read_gray_png(&left_path)?;
        let right = io::read_gray_png(&right_path)?;
        check_pair_size(name, &left, &right)?;
        let gt = io::read_png_values(dir.join("groundtruth.png"))?;
        check_size(name, "groundtruth.png", &gt, &left)?;
        let mask = io::read_png_values(dir.join("nonocc.png"))?;
        check_size(name, "nonocc.png", &mask, &left)?;

        Ok(Scene {
            name: name.to_owned(),
            gt_px: gt_to_px(&gt.values, gt_scale as f32),
            mask: mask.values.iter().map(|&v| v == 255).collect(),
            disparities: round_up_16(levels) as u16,
            left,
            right,
            left_path,
            right_path,
        })
    }

    /// Loads the half-size Reindeer scene from `<root>/middlebury_2005_2006_half/Reindeer`, with
    /// the derived non-occluded mask described in the module documentation.
    pub fn load_reindeer(data_root: impl AsRef<Path>) -> Result<Scene, EvalError> {
        const NAME: &str = "Reindeer";
        // Half-size Middlebury 2005 GT: full-resolution disparity stored, so px = value / 2.
        const GT_SCALE: f32 = 2.0;
        // Largest allowed disagreement between the left GT and the right GT at the match, px.
        const CONSISTENCY_PX: f32 = 1.0;
        let dir = data_root.as_ref().join("middlebury_2005_2006_half").join(NAME);
        let left_path = dir.join("view1.png");
        let right_path = dir.join("view5.png");
        let left = io::read_gray_png(&left_path)?;
        let right = io::read_gray_png(&right_path)?;
        check_pair_size(NAME, &left, &right)?;
        let gt_left = io::read_png_values(dir.join("disp1.png"))?;
        check_size(NAME, "disp1.png", &gt_left, &left)?;
        let gt_right = io::read_png_values(dir.join("disp5.png"))?;
        check_size(NAME, "disp5.png", &gt_right, &left)?;

        let gt_px = gt_to_px(&gt_left.values, GT_SCALE);
        let gt_right_px = gt_to_px(&gt_right.values, GT_SCALE);
        let width = left.width;
        let mask = gt_px
            .iter()
            .enumerate()
            .map(|(i, &d_left)| {
                if d_left.is_nan() {
                    return false;
                }
                let (x, y) = (i % width, i / width);
                let xr = x as i64 - d_left.round() as i64;
                if xr < 0 || xr >= width as i64 {
                    return false;
                }
                let d_right = gt_right_px[y * width + xr as usize];
                !d_right.is_nan() && (d_left - d_right).abs() <= CONSISTENCY_PX
            })
            .collect();
        let max_gt_px = gt_px.iter().chain(&gt_right_px).copied().filter(|d| !d.is_nan()).fold(0f32, f32::max);
        // Disparities searched are 0..D-1, so D must exceed the largest GT disparity.
        let disparities = round_up_16(max_gt_px.floor() as u32 + 1) as u16;
        Ok(Scene { name: NAME.to_owned(), left, right, left_path, right_path, gt_px, mask, disparities })
    }

    /// All evaluation scenes: tsukuba, teddy, cones, Reindeer.
    pub fn load_all(data_root: impl AsRef<Path>) -> Result<Vec<Scene>, EvalError> {
        let root = data_root.as_ref();
        let mut scenes = Vec::with_capacity(V2_SCENES.len() + 1);
        for name in V2_SCENES {
            scenes.push(Scene::load_v2(root, name)?);
        }
        scenes.push(Scene::load_reindeer(root)?);
        Ok(scenes)
    }

    /// Pixels that are evaluated (in the mask and with known GT).
    pub fn evaluated_pixels(&self) -> usize {
        self.mask.iter().zip(&self.gt_px).filter(|&(&m, &g)| m && gt_known(g)).count()
    }

    /// The bad-pixel rate of an estimate on this scene's mask (see [`bad_pixel_rate`]).
    pub fn bad_pixel_rate(&self, estimate_px: &[f32], threshold_px: f32) -> Result<f64, EvalError> {
        bad_pixel_rate(estimate_px, &self.gt_px, &self.mask, threshold_px)
    }
}

/// The Middlebury bad-pixel threshold of the v2 table, px.
pub const DEFAULT_THRESHOLD_PX: f32 = 1.0;

/// GT is known where it is a positive finite disparity (Middlebury stores 0 for unknown).
#[inline]
fn gt_known(gt_px: f32) -> bool {
    gt_px.is_finite() && gt_px > 0.0
}

/// Fraction (0..=1) of evaluated pixels — in `mask` with known GT (finite and > 0) — whose
/// estimate is bad: invalid (not finite, e.g. the `inf` of a PFM) or further than
/// `threshold_px` from the GT. An invalid estimate inside the mask counts as bad, as in the
/// Middlebury v2 table, so a matcher cannot improve its score by leaving pixels out.
/// 0 if no pixel is evaluated.
pub fn bad_pixel_rate(estimate_px: &[f32], gt_px: &[f32], mask: &[bool], threshold_px: f32) -> Result<f64, EvalError> {
    if estimate_px.len() != gt_px.len() || mask.len() != gt_px.len() {
        return Err(EvalError::Length { estimate: estimate_px.len(), gt: gt_px.len(), mask: mask.len() });
    }
    let mut evaluated = 0usize;
    let mut bad = 0usize;
    for ((&est, &gt), &m) in estimate_px.iter().zip(gt_px).zip(mask) {
        if !m || !gt_known(gt) {
            continue;
        }
        evaluated += 1;
        if !est.is_finite() || (est - gt).abs() > threshold_px {
            bad += 1;
        }
    }
    Ok(if evaluated == 0 { 0.0 } else { bad as f64 / evaluated as f64 })
}
