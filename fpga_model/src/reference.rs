//! The reference implementation: the stages of `SPEC.md` run one after another on whole images
//! and volumes. Slow and memory-hungry (the full cost and aggregated volumes are kept) but a
//! line-by-line mirror of the spec; [`crate::fast`] must equal it bit for bit.

use crate::SgmError;
use crate::config::SgmConfig;
use crate::image::{DisparityImage, GrayImage, check_pair};
use crate::stages::select::Winner;
use crate::stages::{AggregatedVolume, CostVolume, aggregate, census, cost, lr, median, select};

/// Every intermediate result of one run, for tests and for parity checks of other
/// implementations. Stages that are switched off pass their input through unchanged.
#[derive(Debug, Clone)]
pub struct Intermediates {
    /// Stage 1: census words of the left image, row-major.
    pub census_left: Vec<u64>,
    /// Stage 1: census words of the right image, row-major.
    pub census_right: Vec<u64>,
    /// Stage 2: `C(x, y, d)`.
    pub cost: CostVolume,
    /// Stage 3: `S(x, y, d)` over the paths of the mode.
    pub aggregated: AggregatedVolume,
    /// Stage 4: integer winner, its cost and the uniqueness verdict of each pixel.
    pub winners: Vec<Winner>,
    /// Stages 4 + 5: `16 · d1 + offset`, `INVALID` where not unique.
    pub subpixel: DisparityImage,
    /// Stage 6: `dR(xr, y)`, the right view's integer disparity, row-major (computed even when
    /// the check is off, for inspection).
    pub right_disparity: Vec<u16>,
    /// Stage 6 output (the stage 5 image when `lr_check` is off).
    pub lr_checked: DisparityImage,
    /// Stage 7 output (the stage 6 image when `median` is off).
    pub median: DisparityImage,
    /// Stage 8 output: the core's result.
    pub disparity: DisparityImage,
}

/// The core's output for a rectified pair: left-view disparity in 1/16 px or `INVALID`.
pub fn compute(left: &GrayImage, right: &GrayImage, config: &SgmConfig) -> Result<DisparityImage, SgmError> {
    compute_with_intermediates(left, right, config).map(|all| all.disparity)
}

/// [`compute`], keeping every intermediate result.
pub fn compute_with_intermediates(
    left: &GrayImage,
    right: &GrayImage,
    config: &SgmConfig,
) -> Result<Intermediates, SgmError> {
    config.validate()?;
    check_image(left)?;
    check_image(right)?;
    check_pair(left, right)?;
    let window = (usize::from(config.census_width), usize::from(config.census_height));

    let census_left = census::transform(left, window.0, window.1);
    let census_right = census::transform(right, window.0, window.1);
    let cost = cost::volume(&census_left, &census_right, left, right, config);
    let aggregated = aggregate::sum(&cost, left, config);
    let winners = select::winner(&aggregated, config.uniqueness_percent);
    let subpixel = select::subpixel(&aggregated, &winners, config.subpixel);
    let right_disparity = lr::right_disparity(&aggregated);
    let lr_checked = if config.lr_check {
        lr::check(&subpixel, &winners, &right_disparity, config.lr_max_diff, config.lr_lenient)
    } else {
        subpixel.clone()
    };
    let median = if config.median { median::median3x3(&lr_checked) } else { lr_checked.clone() };
    let disparity = select::mark_invalid(&median);

    Ok(Intermediates {
        census_left,
        census_right,
        cost,
        aggregated,
        winners,
        subpixel,
        right_disparity,
        lr_checked,
        median,
        disparity,
    })
}

/// `GrayImage`'s fields are public, so an image may not have come through `GrayImage::new`.
fn check_image(image: &GrayImage) -> Result<(), SgmError> {
    if image.width == 0 || image.height == 0 || image.pixels.len() != image.width * image.height {
        return Err(SgmError::BadImage { width: image.width, height: image.height, len: image.pixels.len() });
    }
    Ok(())
}
