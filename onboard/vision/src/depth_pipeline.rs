//! The on-board depth pipeline in one place: SGM (`fpga_model`'s fast matcher), the speckle
//! filter, depth from disparity. The vision node, the mapping examples and tests, and the
//! obstacle evaluation all run this sequence; keeping it in one type keeps them computing the
//! same depth images, and lets a node match images that live in shared memory without copying
//! them first.

use std::time::Instant;

use fpga_model::fast::Matcher;
use fpga_model::{DisparityImage, GrayView, INVALID, SgmConfig, SgmError};
use hal::sensor::StereoCalibration;

use crate::depth::{DepthImage, StereoGeometry, depth_sgm_config};
use crate::speckle::SpeckleFilter;

/// How a [`DepthPipeline`] matches.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DepthOptions {
    pub sgm: SgmConfig,
    /// Drop SGM's small blunder patches before depth ([`SpeckleFilter::for_image`]).
    pub despeckle: bool,
    /// Threads of the matcher (at least 1; see [`Matcher::new`] for how many it uses).
    pub threads: usize,
}

impl Default for DepthOptions {
    /// The on-board depth images ([`depth_sgm_config`] and the speckle filter) on one thread.
    fn default() -> Self {
        DepthOptions { sgm: depth_sgm_config(), despeckle: true, threads: 1 }
    }
}

/// Why a [`DepthPipeline`] could not be built or could not match a pair.
#[derive(Debug, thiserror::Error)]
pub enum DepthError {
    #[error("depth: the calibration is not rectified (rectify the pair first)")]
    NotRectified,
    #[error("depth: SGM: {0}")]
    Sgm(#[from] SgmError),
}

/// What one pair cost, for telemetry and benchmarks (wall time of each stage).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct DepthFrameStats {
    pub sgm_ms: f64,
    /// 0 without the speckle filter.
    pub speckle_ms: f64,
    pub depth_ms: f64,
    /// Pixels the speckle filter invalidated.
    pub speckle_dropped_px: usize,
}

/// SGM → speckle filter → depth for one rectified image size. Every buffer is allocated when
/// it is built, so a pair costs no allocation (beyond the matcher's scoped threads).
#[derive(Debug)]
pub struct DepthPipeline {
    matcher: Matcher,
    speckle: Option<SpeckleFilter>,
    geometry: StereoGeometry,
    width_px: usize,
    height_px: usize,
    disparity: DisparityImage,
    depth: DepthImage,
}

impl DepthPipeline {
    /// A pipeline for the pairs of a rectified calibration (the simulator's, or
    /// [`crate::Rectifier::rectified_calibration`]).
    pub fn new(calibration: &StereoCalibration, options: DepthOptions) -> Result<Self, DepthError> {
        if !calibration.rectified {
            return Err(DepthError::NotRectified);
        }
        let (width_px, height_px) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
        Self::with_geometry(StereoGeometry::from_calibration(calibration), width_px, height_px, options)
    }

    /// A pipeline for `width_px × height_px` rectified pairs of `geometry`.
    pub fn with_geometry(
        geometry: StereoGeometry,
        width_px: usize,
        height_px: usize,
        options: DepthOptions,
    ) -> Result<Self, DepthError> {
        let matcher = Matcher::new(options.sgm, width_px, height_px, options.threads)?;
        let speckle = options.despeckle.then(|| SpeckleFilter::for_image(width_px, height_px));
        let mut pipeline = DepthPipeline {
            matcher,
            speckle: None,
            geometry,
            width_px,
            height_px,
            disparity: DisparityImage { width: width_px, height: height_px, data: vec![INVALID; width_px * height_px] },
            depth: DepthImage::new(width_px, height_px),
        };
        pipeline.set_speckle_filter(speckle);
        Ok(pipeline)
    }

    /// Replaces the speckle filter (`None`: off), for experiments with its parameters.
    pub fn set_speckle_filter(&mut self, filter: Option<SpeckleFilter>) {
        self.speckle = filter.map(|mut filter| {
            filter.reserve(self.width_px * self.height_px);
            filter
        });
    }

    /// Matches a rectified pair, row-major `width_px × height_px` bytes each, read in place; then
    /// [`DepthPipeline::disparity`] and [`DepthPipeline::depth`] hold its results. On an error
    /// (wrong length) both keep the previous pair's.
    pub fn compute(&mut self, left: &[u8], right: &[u8]) -> Result<DepthFrameStats, DepthError> {
        let (w, h) = (self.width_px, self.height_px);
        let (left, right) = (GrayView::new(w, h, left)?, GrayView::new(w, h, right)?);
        let mut stats = DepthFrameStats::default();
        let start = Instant::now();
        self.matcher.compute_views_into(left, right, &mut self.disparity)?;
        stats.sgm_ms = elapsed_ms(start);
        if let Some(filter) = &mut self.speckle {
            let start = Instant::now();
            stats.speckle_dropped_px = filter.apply(&mut self.disparity);
            stats.speckle_ms = elapsed_ms(start);
        }
        let start = Instant::now();
        self.depth.fill_from_disparity(&self.disparity, &self.geometry);
        stats.depth_ms = elapsed_ms(start);
        Ok(stats)
    }

    /// The last pair's disparity (after the speckle filter), 1/16 px or [`INVALID`].
    pub fn disparity(&self) -> &DisparityImage {
        &self.disparity
    }

    /// The last pair's depth ([`DepthImage`]'s conventions).
    pub fn depth(&self) -> &DepthImage {
        &self.depth
    }

    /// The last pair's depth, for callers that mask it in place before using it; the next
    /// [`DepthPipeline::compute`] overwrites every pixel.
    pub fn depth_mut(&mut self) -> &mut DepthImage {
        &mut self.depth
    }

    pub fn geometry(&self) -> &StereoGeometry {
        &self.geometry
    }

    /// `(width, height)` of the pairs it matches, in pixels.
    pub fn size_px(&self) -> (usize, usize) {
        (self.width_px, self.height_px)
    }

    /// The matcher (its configuration, threads and instruction set, for telemetry).
    pub fn matcher(&self) -> &Matcher {
        &self.matcher
    }
}

fn elapsed_ms(start: Instant) -> f64 {
    start.elapsed().as_secs_f64() * 1e3
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: usize = 96;
    const H: usize = 40;

    fn geometry() -> StereoGeometry {
        StereoGeometry { fx_px: 100.0, fy_px: 100.0, cx_px: 48.0, cy_px: 20.0, baseline_m: 0.2 }
    }

    /// A textured pair whose right view is the left one shifted by 8 px: a fronto-parallel plane.
    fn shifted_pair() -> (Vec<u8>, Vec<u8>) {
        let texture = |x: usize, y: usize| ((x * 37 + y * 91 + (x * y) % 13 * 17) % 251) as u8;
        let left: Vec<u8> = (0..W * H).map(|i| texture(i % W, i / W)).collect();
        let right: Vec<u8> = (0..W * H).map(|i| texture(i % W + 8, i / W)).collect();
        (left, right)
    }

    #[test]
    fn compute_is_the_matcher_the_speckle_filter_and_depth_in_that_order() {
        let (left, right) = shifted_pair();
        let sgm = SgmConfig { disparities: 16, ..depth_sgm_config() };
        for despeckle in [false, true] {
            let options = DepthOptions { sgm, despeckle, threads: 2 };
            let mut pipeline = DepthPipeline::with_geometry(geometry(), W, H, options).unwrap();
            let stats = pipeline.compute(&left, &right).unwrap();

            let gray = |pixels: &[u8]| fpga_model::GrayImage::new(W, H, pixels.to_vec()).unwrap();
            let mut expected = Matcher::new(sgm, W, H, 1).unwrap().compute(&gray(&left), &gray(&right)).unwrap();
            let dropped = if despeckle { SpeckleFilter::for_image(W, H).apply(&mut expected) } else { 0 };
            let mut depth = DepthImage::new(W, H);
            depth.fill_from_disparity(&expected, &geometry());
            assert_eq!(pipeline.disparity(), &expected);
            assert_eq!(stats.speckle_dropped_px, dropped);
            // NaN != NaN: compare the bits.
            let bits = |d: &DepthImage| d.depth_m.iter().map(|z| z.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(pipeline.depth()), bits(&depth));
            assert!(pipeline.depth().depth_m.iter().any(|z| (z - 2.5).abs() < 1e-3), "8 px at f·b = 20 m·px");
        }
    }

    #[test]
    fn wrong_inputs_are_refused_and_keep_the_last_results() {
        let (left, right) = shifted_pair();
        let mut pipeline = DepthPipeline::with_geometry(
            geometry(),
            W,
            H,
            DepthOptions { sgm: SgmConfig { disparities: 16, ..depth_sgm_config() }, ..DepthOptions::default() },
        )
        .unwrap();
        pipeline.compute(&left, &right).unwrap();
        let before = pipeline.disparity().clone();
        assert!(matches!(pipeline.compute(&left, &right[1..]), Err(DepthError::Sgm(SgmError::BadImage { .. }))));
        assert_eq!(pipeline.disparity(), &before);
        let threads_zero = DepthOptions { threads: 0, ..DepthOptions::default() };
        assert!(DepthPipeline::with_geometry(geometry(), W, H, threads_zero).is_err());
    }
}
