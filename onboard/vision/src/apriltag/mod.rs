//! AprilTag detection (tag36h11): the robots' markers in a rectified greyscale image (thesis
//! §6.2).
//!
//! Our own implementation of the AprilTag 3 detector's design (Olson, ICRA 2011; Wang and Olson,
//! "AprilTag 2", IROS 2016; the upstream C library's structure), checked against the upstream C
//! library 3.4.5 on real photographs (`tests/apriltag_real.rs`):
//!
//! 1. optional decimation (keep every n-th pixel of every n-th row) for the quad search;
//! 2. adaptive threshold: 4 × 4 tile extrema, spread over 3 × 3 tiles, black / white / unknown
//!    (low contrast) — [`threshold`](self) module;
//! 3. connected components of black (4-connected) and white (8-connected) pixels, by union-find
//!    over horizontal runs;
//! 4. gradient clusters: the boundary points between each touching pair of large black and white
//!    components;
//! 5. quad fitting per cluster: points sorted by angle, cumulative weighted line-fit moments,
//!    corners at the peaks of the line-fit error, the best four under the maximum line-fit MSE,
//!    convexity, winding, critical-angle and size checks;
//! 6. edge refinement on the full image: each edge moves to the strongest dark-to-light step along
//!    its normal, the corners to the new lines' intersections;
//! 7. decoding: homography (DLT) from the tag square, planar grey-level models of the white ring
//!    and the black border, bilinear bit sampling with Laplacian sharpening, lookup among the
//!    family's codes in all four rotations with up to `max_hamming` bit errors, decision margin;
//! 8. corners re-ordered by the decoded rotation; of overlapping detections of one id the one
//!    with fewer bit errors, then the larger margin, is kept.
//!
//! # Conventions
//!
//! - **Pixels**: `(0, 0)` is the centre of the top-left pixel (OpenCV's convention), x right,
//!   y down. The upstream C library reports pixel centres at `+0.5` (pixel `i` covers
//!   `[i, i + 1]`): its coordinates are ours plus 0.5, measured on a rendered tag whose black
//!   square spans exactly `[50, 130]` px in our convention, which the C library reports as
//!   `[50.50, 130.50]` (README of this crate).
//! - **Corner order** (the upstream library's, its Python wheel's `lb-rb-rt-lt`): corner 0 is the
//!   tag's bottom-left, then bottom-right, top-right, top-left — counter-clockwise as seen in the
//!   image. "Bottom" is the tag's own: for an upright tag, corner 0 is the lower-left corner in
//!   the image (verified on a rendered upright tag).
//! - **Tag frame** (for pose estimation): x to the tag's right, y to its top, z out of its face,
//!   origin at the centre; with `s` the edge of the black square, corner `k` is at
//!   `(−s/2, −s/2), (s/2, −s/2), (s/2, s/2), (−s/2, s/2)`.
//! - **Homography**: [`TagDetection::homography`] maps tag coordinates in `[−1, 1]²` (the same
//!   axes, black square = `[−1, 1]²`) to pixels in our convention: corner `k` is the image of
//!   `(−1, −1), (1, −1), (1, 1), (−1, 1)`, the centre that of `(0, 0)`.
//!
//! # Allocation
//!
//! [`TagDetector`] owns every buffer (thresholded image, runs, union-find, clusters, quad-fit
//! scratch, quads, detections) as vectors that are cleared and refilled; after the first image of
//! a size (and content of similar complexity), [`TagDetector::detect`] allocates nothing.

// `!(x > bound)` is how this module rejects NaN along with small values: keep that form.
#![allow(clippy::neg_cmp_op_on_partial_ord, reason = "the negated comparisons reject NaN on purpose")]

mod clusters;
mod components;
mod decode;
pub mod family;
mod quad;
mod refine;
pub mod tag36h11;
mod threshold;

use nalgebra::Matrix3;

use clusters::Clusters;
use components::Components;
use decode::{Homography, decode_quad};
pub use family::{CodeIndex, Decoded, MAX_CORRECTABLE, TagFamily};
use quad::{Quad, QuadFitter, QuadParams};
pub use tag36h11::TAG36H11;
use threshold::Thresholder;

/// Settings of the detector; [`Default`] is the flight configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TagDetectorConfig {
    /// Quads are searched on an image decimated by this factor (1 = full resolution; 2 halves
    /// both sides and quarters the cost at a loss of small tags); refinement and decoding always
    /// use the full image. 1 ..= 8.
    pub quad_decimate: u32,
    /// Move the quad edges onto the strongest image edges before decoding (recommended: it
    /// brings the corners from ~0.5 px to ~0.05 px of the truth).
    pub refine_edges: bool,
    /// Weight of the Laplacian added to the sampled bit grid (upstream default 0.25).
    pub decode_sharpening: f64,
    /// Most bit errors corrected (0 ..= 3, and less than half the family's minimum distance).
    pub max_hamming: u32,
    /// Detections with a smaller decision margin (grey levels between a bit's sample and the
    /// threshold, averaged) are dropped.
    pub min_decision_margin: f32,
    /// Clusters with fewer boundary points are not fitted (upstream default 5).
    pub min_cluster_pixels: u32,
    /// Corner candidates kept per cluster, the strongest line-fit error peaks (default 10).
    pub max_nmaxima: u32,
    /// Adjacent edges must meet at more than this angle (and less than π minus it) (10°).
    pub critical_angle_rad: f64,
    /// Largest mean squared distance of an edge's points from its line, in px² (10).
    pub max_line_fit_mse: f64,
    /// Tiles whose neighbourhood spans fewer grey levels are left unknown (5).
    pub min_white_black_diff: u8,
    /// 3 × 3 closing of the thresholded image (off: no measured benefit upstream or here).
    pub deglitch: bool,
}

impl Default for TagDetectorConfig {
    /// The flight defaults, chosen on the real photographs and simulated terrain (README):
    /// full resolution (decimation 2 loses 29 % of the real tags), up to 2 corrected bits (the
    /// real sets contain 2-bit errors; zero wrong ids on real and simulated images), no margin
    /// threshold beyond the decoder's own (no false detection in any test set needed one).
    fn default() -> Self {
        TagDetectorConfig {
            quad_decimate: 1,
            refine_edges: true,
            decode_sharpening: 0.25,
            max_hamming: 2,
            min_decision_margin: 0.0,
            min_cluster_pixels: 5,
            max_nmaxima: 10,
            critical_angle_rad: 10f64.to_radians(),
            max_line_fit_mse: 10.0,
            min_white_black_diff: 5,
            deglitch: false,
        }
    }
}

/// Why a detector could not be made.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TagError {
    #[error("quad_decimate must be 1..=8, got {0}")]
    Decimate(u32),
    #[error("max_hamming {max_hamming} is more than this family can correct ({limit})")]
    MaxHamming { max_hamming: u32, limit: u32 },
    #[error("{name} = {value} is out of range ({range})")]
    OutOfRange { name: &'static str, value: f64, range: &'static str },
    #[error(
        "tag family {0} is not supported (needs nbits a multiple of 4, a normal border, a layout inside the black square)"
    )]
    UnsupportedFamily(&'static str),
}

/// One detected tag. Pixel coordinates in our convention (module docs).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TagDetection {
    pub id: u32,
    /// Bits corrected.
    pub hamming: u32,
    /// Mean distance of the bits from the decision threshold, grey levels (the smaller of the
    /// white and black bits' means).
    pub decision_margin: f32,
    pub center_px: [f64; 2],
    /// Bottom-left, bottom-right, top-right, top-left of the tag (counter-clockwise in the image).
    pub corners_px: [[f64; 2]; 4],
    /// Tag coordinates in `[−1, 1]²` (x right, y up on the tag) to pixels.
    pub homography: Matrix3<f64>,
}

/// The detector: configuration, the family's decode table and every working buffer.
#[derive(Debug)]
pub struct TagDetector {
    config: TagDetectorConfig,
    family: TagFamily,
    index: CodeIndex,
    decimated: Vec<u8>,
    thresholder: Thresholder,
    thresh: Vec<u8>,
    components: Components,
    clusters: Clusters,
    fitter: QuadFitter,
    quads: Vec<Quad>,
    detections: Vec<TagDetection>,
    keep: Vec<bool>,
}

impl TagDetector {
    /// A tag36h11 detector.
    pub fn new(config: TagDetectorConfig) -> Result<Self, TagError> {
        Self::with_family(config, TAG36H11)
    }

    /// A detector for another family of the same structure (the code is written for tag36h11).
    pub fn with_family(config: TagDetectorConfig, family: TagFamily) -> Result<Self, TagError> {
        if !family.is_supported() {
            return Err(TagError::UnsupportedFamily(family.name));
        }
        if !(1..=8).contains(&config.quad_decimate) {
            return Err(TagError::Decimate(config.quad_decimate));
        }
        let limit = MAX_CORRECTABLE.min(family.min_hamming.saturating_sub(1) / 2);
        if config.max_hamming > limit {
            return Err(TagError::MaxHamming { max_hamming: config.max_hamming, limit });
        }
        let checks: [(&'static str, f64, bool, &'static str); 5] = [
            ("decode_sharpening", config.decode_sharpening, (0.0..=4.0).contains(&config.decode_sharpening), "0 ..= 4"),
            (
                "min_decision_margin",
                f64::from(config.min_decision_margin),
                config.min_decision_margin.is_finite(),
                "finite",
            ),
            (
                "critical_angle_rad",
                config.critical_angle_rad,
                config.critical_angle_rad > 0.0 && config.critical_angle_rad < std::f64::consts::FRAC_PI_2,
                "0 < angle < π/2",
            ),
            (
                "max_line_fit_mse",
                config.max_line_fit_mse,
                config.max_line_fit_mse > 0.0 && config.max_line_fit_mse.is_finite(),
                "> 0, finite",
            ),
            ("max_nmaxima", f64::from(config.max_nmaxima), (4..=64).contains(&config.max_nmaxima), "4 ..= 64"),
        ];
        for (name, value, ok, range) in checks {
            if !ok {
                return Err(TagError::OutOfRange { name, value, range });
            }
        }
        Ok(TagDetector {
            config,
            family,
            index: CodeIndex::new(family, config.max_hamming),
            decimated: Vec::new(),
            thresholder: Thresholder::default(),
            thresh: Vec::new(),
            components: Components::default(),
            clusters: Clusters::default(),
            fitter: QuadFitter::default(),
            quads: Vec::new(),
            detections: Vec::new(),
            keep: Vec::new(),
        })
    }

    pub fn config(&self) -> &TagDetectorConfig {
        &self.config
    }

    pub fn family(&self) -> &TagFamily {
        &self.family
    }

    /// The detections of the last [`Self::detect`].
    pub fn detections(&self) -> &[TagDetection] {
        &self.detections
    }

    /// Detections in `image`, sorted by id (then position); buffers are kept between calls, so
    /// after the first image of a size nothing is allocated per frame. An image whose `data` is
    /// not `width × height` bytes has no detections.
    pub fn detect(&mut self, image: crate::image::ImageView<'_>) -> &[TagDetection] {
        self.detections.clear();
        let (width, height) = (image.width, image.height);
        if width == 0 || height == 0 || image.data.len() != width.saturating_mul(height) {
            return &self.detections;
        }
        let config = self.config;
        let factor = config.quad_decimate as usize;
        let (qw, qh) = threshold::decimate(image.data, width, height, factor, &mut self.decimated);
        let quad_image: &[u8] = if factor > 1 { &self.decimated } else { image.data };

        self.thresholder.run(quad_image, qw, qh, config.min_white_black_diff, config.deglitch, &mut self.thresh);
        self.components.run(&self.thresh, qw, qh);
        self.clusters.run(&self.thresh, &self.components);

        let params = QuadParams {
            max_nmaxima: config.max_nmaxima as usize,
            cos_critical: config.critical_angle_rad.cos(),
            max_line_fit_mse: config.max_line_fit_mse,
            min_tag_width: f64::from((self.family.width_at_border / config.quad_decimate).max(3)),
        };
        // A cluster is an outline: three points per boundary pixel at most, around the image.
        let max_cluster = 3 * (2 * qw + 2 * qh);
        self.quads.clear();
        for c in 0..self.clusters.len() {
            let n = self.clusters.cluster_len(c);
            if n < config.min_cluster_pixels as usize || n > max_cluster {
                continue;
            }
            if let Some(mut quad) = self.fitter.fit(&params, quad_image, qw, qh, self.clusters.cluster_mut(c)) {
                // Decimated pixel i stands for the block of full pixels it starts (the upstream
                // library's mapping; refinement removes the half-pixel offset this leaves).
                let offset = 0.5 * (factor as f64 - 1.0);
                for p in &mut quad.p {
                    p[0] = p[0] * factor as f64 + offset;
                    p[1] = p[1] * factor as f64 + offset;
                }
                self.quads.push(quad);
            }
        }

        for quad in &self.quads {
            let mut p = quad.p;
            if config.refine_edges {
                refine::refine_edges(&mut p, image.data, width, height, factor as f64);
            }
            let Some(h) = Homography::from_square(&p) else {
                continue;
            };
            let Some(found) =
                decode_quad(&self.family, &self.index, image.data, width, height, &h, config.decode_sharpening)
            else {
                continue;
            };
            let margin = found.margin as f32;
            if margin < config.min_decision_margin {
                continue;
            }
            self.detections.push(detection(&h, found.decoded, margin));
        }
        self.remove_overlaps();
        self.detections.sort_unstable_by(|a, b| {
            a.id.cmp(&b.id).then_with(|| {
                a.center_px[1].total_cmp(&b.center_px[1]).then_with(|| a.center_px[0].total_cmp(&b.center_px[0]))
            })
        });
        &self.detections
    }

    /// Of every two detections of one id whose outlines overlap, keeps the one with fewer bit
    /// errors, then the larger margin, then (any fixed rule) the smaller corner coordinates.
    fn remove_overlaps(&mut self) {
        let n = self.detections.len();
        self.keep.clear();
        self.keep.resize(n, true);
        for i in 0..n {
            if !self.keep[i] {
                continue;
            }
            for j in i + 1..n {
                let (a, b) = (&self.detections[i], &self.detections[j]);
                if !self.keep[j] || a.id != b.id || !polygons_overlap(&a.corners_px, &b.corners_px) {
                    continue;
                }
                if prefer_first(a, b) {
                    self.keep[j] = false;
                } else {
                    self.keep[i] = false;
                    break;
                }
            }
        }
        let mut k = 0;
        self.detections.retain(|_| {
            k += 1;
            self.keep[k - 1]
        });
    }

    /// Capacities of every buffer, for the no-allocation test.
    #[cfg(test)]
    fn capacities(&self) -> Vec<usize> {
        let mut c = vec![
            self.decimated.capacity(),
            self.thresh.capacity(),
            self.quads.capacity(),
            self.detections.capacity(),
            self.keep.capacity(),
        ];
        c.extend(self.clusters.capacities());
        c.extend(self.fitter.capacities());
        c.extend(self.components.capacities());
        c.extend(self.thresholder.capacities());
        c
    }
}

/// The detection of a decoded quad with homography `h` (tag y down, the quad's corner order).
fn detection(h: &Homography, decoded: Decoded, margin: f32) -> TagDetection {
    // The sampled word matched after `rotation` quarter turns: the tag's own frame is the quad's
    // turned by as many quarters, R(θ) = [[cos, −sin], [sin, cos]] (y down).
    let (s, c) = (f64::from(decoded.rotation) * std::f64::consts::FRAC_PI_2).sin_cos();
    let (s, c) = (s.round(), c.round());
    // ... then flip y so that the tag's y points up.
    let turned = h.then_after(&[c, s, 0.0, s, -c, 0.0, 0.0, 0.0, 1.0]);
    let corners_px = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]].map(|[x, y]| turned.project(x, y));
    let m = &turned.0;
    let scale = if m[8].abs() > f64::EPSILON { 1.0 / m[8] } else { 1.0 };
    TagDetection {
        id: decoded.id,
        hamming: decoded.hamming,
        decision_margin: margin,
        center_px: turned.project(0.0, 0.0),
        corners_px,
        homography: Matrix3::from_row_slice(m).scale(scale),
    }
}

fn prefer_first(a: &TagDetection, b: &TagDetection) -> bool {
    if a.hamming != b.hamming {
        return a.hamming < b.hamming;
    }
    if a.decision_margin != b.decision_margin {
        return a.decision_margin > b.decision_margin;
    }
    for (p, q) in a.corners_px.iter().zip(&b.corners_px) {
        for k in 0..2 {
            if p[k] != q[k] {
                return p[k] < q[k];
            }
        }
    }
    true
}

/// Whether two quadrilaterals share any area: an edge of one crosses an edge of the other, or one
/// lies inside the other.
fn polygons_overlap(a: &[[f64; 2]; 4], b: &[[f64; 2]; 4]) -> bool {
    let orient = |p: [f64; 2], q: [f64; 2], r: [f64; 2]| (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0]);
    for i in 0..4 {
        let (p1, p2) = (a[i], a[(i + 1) % 4]);
        for j in 0..4 {
            let (q1, q2) = (b[j], b[(j + 1) % 4]);
            let (d1, d2) = (orient(q1, q2, p1), orient(q1, q2, p2));
            let (d3, d4) = (orient(p1, p2, q1), orient(p1, p2, q2));
            if d1 * d2 < 0.0 && d3 * d4 < 0.0 {
                return true;
            }
        }
    }
    contains(a, b[0]) || contains(b, a[0])
}

/// Point in polygon (crossing number).
fn contains(poly: &[[f64; 2]; 4], p: [f64; 2]) -> bool {
    let mut inside = false;
    for i in 0..4 {
        let (a, b) = (poly[i], poly[(i + 1) % 4]);
        if (a[1] > p[1]) != (b[1] > p[1]) {
            let x = a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]);
            if p[0] < x {
                inside = !inside;
            }
        }
    }
    inside
}

#[cfg(test)]
mod tests;
