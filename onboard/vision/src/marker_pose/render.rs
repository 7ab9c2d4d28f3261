//! Our own tag renderer for the look-up table (the thesis used POV-Ray, T23): a tag's 10 × 10
//! cells on its white plate, seen by a pinhole camera, anti-aliased, blurred and exposed with
//! sensor noise.
//!
//! 1. **Geometry.** A ray through image point `(u, v)` meets the tag plane at
//!    `(x, y, 1) ∝ H⁻¹ · ((u − cx)/fx, (v − cy)/fy, 1)` with `H = [r₁ r₂ t]` of `t_cam_marker`
//!    (a positive third component = in front of the camera). Cell `(col, row)` (row 0 at the
//!    tag's top) covers `x ∈ [−S + col·c, −S + (col + 1)·c]`, `y ∈ [S − (row + 1)·c, S − row·c]`
//!    with `S` = half the 10-cell extent (`1.25 ×` half the tag size) and `c = 2S / 10`: the
//!    simulator's layout (`sim::robot::Marker::cell_centre_marker_m`). Beyond the tag, a plate of
//!    half edge [`RenderConfig::plate_half_per_tag_size`] `×` the tag size; beyond that, a uniform
//!    background.
//! 2. **Anti-aliasing.** A pixel (centre at integer coordinates, covering ±0.5 px) whose four
//!    corners fall into one convex region (one cell, one straight strip of the plate, one
//!    half-plane outside the plate) takes that region's level exactly: a perspective map keeps the
//!    pixel inside the convex hull of its corners. Any other pixel is the mean of an `n × n` grid
//!    of samples ([`RenderConfig::supersampling`]), i.e. area coverage to `1/n²`.
//! 3. **Blur** (defocus): a separable Gaussian of σ = [`RenderConfig::blur_sigma_px`], on the
//!    region of interest (the plate's bounding box plus 3σ; outside it the image is the
//!    background level, which the blur leaves unchanged).
//! 4. **Exposure**: the simulator's sensor model (`sim::render::SensorModel`): shot noise of
//!    variance `dn · 255 / full_well_e` plus read noise, each pixel's deviate a pure function of
//!    `(seed, pixel index)` (Irwin-Hall sum of four bytes of a SplitMix64 hash, as the simulator
//!    draws it), rounding and clamping to 8 bits.

use hal::sensor::Pinhole;
use nalgebra::{Isometry3, Matrix3, Vector3};

/// Cells along a rendered tag's edge (white border included) and along its black square.
pub const TAG_CELLS: usize = 10;
pub const TAG_BLACK_CELLS: usize = 8;

/// A tag's 10 × 10 cells, row-major from the top-left, `true` = white.
pub type TagCells = [[bool; TAG_CELLS]; TAG_CELLS];

/// tag36h11 id 0 (code `0xD7E00984B`, the AprilTag library's bit layout), the tag the table is
/// rendered with; `'.'` white, `'#'` black. Checked against `sim::markers::tag_cells` in
/// `tests/marker_pose.rs`.
pub const TAG36H11_ID0_PATTERN: [&str; TAG_CELLS] = [
    "..........",
    ".########.",
    ".#..#.#.#.",
    ".##...#.#.",
    ".##..####.",
    ".#.#.####.",
    ".##.#..##.",
    ".####.###.",
    ".########.",
    "..........",
];

/// The cells of a pattern written as [`TAG36H11_ID0_PATTERN`] (anything but `'#'` is white).
pub fn cells_from_pattern(pattern: &[&str; TAG_CELLS]) -> TagCells {
    let mut cells = [[true; TAG_CELLS]; TAG_CELLS];
    for (line, text) in cells.iter_mut().zip(pattern) {
        for (cell, ch) in line.iter_mut().zip(text.chars()) {
            *cell = ch != '#';
        }
    }
    cells
}

/// An undistorted pinhole camera with its image size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraModel {
    pub width_px: u32,
    pub height_px: u32,
    pub intrinsics: Pinhole,
}

impl CameraModel {
    pub fn pixels(&self) -> usize {
        self.width_px as usize * self.height_px as usize
    }
}

/// Appearance of the rendered tag (grey values before noise, 0–255).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RenderConfig {
    pub white_dn: f32,
    pub black_dn: f32,
    pub plate_dn: f32,
    pub background_dn: f32,
    /// Half edge of the plate as a multiple of the tag size (the simulator's rovers: 0.13 m for a
    /// 0.16 m tag).
    pub plate_half_per_tag_size: f64,
    /// Gaussian blur (defocus), pixels; 0 = none.
    pub blur_sigma_px: f64,
    /// Read noise (grey values) and full-well capacity (electrons; 0 = no shot noise).
    pub read_noise_dn: f64,
    pub full_well_e: f64,
    /// Samples per pixel edge where a pixel straddles an edge.
    pub supersampling: u32,
}

impl Default for RenderConfig {
    /// Tuned to the simulator's rendered markers (`renderer_matches_the_simulators_markers` in
    /// `tests/marker_pose.rs` measures them; README section "Robot markers"): the grey levels
    /// of a sunlit, unsaturated rover marker on the Moon and Mars presets, the background at the
    /// auto-exposure's target mean, no blur (the simulator models no defocus and its 2 × 2 ray
    /// box filter gives edges *sharper* (10–90 % rise 0.62 px) than our 4 × 4 pixel-area
    /// coverage alone (0.79 px)), its sensor noise (`sim::render::SensorModel::default()`).
    fn default() -> Self {
        RenderConfig {
            white_dn: 150.0,
            black_dn: 6.0,
            plate_dn: 158.0,
            background_dn: 110.0,
            plate_half_per_tag_size: 0.13 / 0.16,
            blur_sigma_px: 0.0,
            read_noise_dn: 1.0,
            full_well_e: 10_000.0,
            supersampling: 4,
        }
    }
}

/// Why a tag could not be rendered.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum RenderError {
    #[error("output buffer has {got} pixels, the camera {expected}")]
    BufferSize { expected: usize, got: usize },
    #[error("camera, tag size or render configuration is not finite and positive")]
    InvalidParameters,
}

/// Renders a tag of edge `tag_size_m` (the black square) with cells `cells` at `t_cam_marker`
/// into `out` (`width × height`, row-major). Deterministic in `noise_seed`.
pub fn render_tag(
    camera: &CameraModel,
    tag_size_m: f64,
    cells: &TagCells,
    t_cam_marker: &Isometry3<f64>,
    config: &RenderConfig,
    noise_seed: u64,
    out: &mut [u8],
) -> Result<(), RenderError> {
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    if out.len() != camera.pixels() {
        return Err(RenderError::BufferSize { expected: camera.pixels(), got: out.len() });
    }
    let k = camera.intrinsics;
    let valid =
        [k.fx_px, k.fy_px, tag_size_m, config.plate_half_per_tag_size].iter().all(|v| v.is_finite() && *v > 0.0)
            && [k.cx_px, k.cy_px, config.blur_sigma_px, config.read_noise_dn, config.full_well_e]
                .iter()
                .all(|v| v.is_finite() && *v >= 0.0)
            && [config.white_dn, config.black_dn, config.plate_dn, config.background_dn].iter().all(|v| v.is_finite())
            && (1..=16).contains(&config.supersampling)
            && w > 0
            && h > 0;
    if !valid {
        return Err(RenderError::InvalidParameters);
    }
    let scene = Scene::new(camera, tag_size_m, cells, t_cam_marker, config).ok_or(RenderError::InvalidParameters)?;
    let blur_radius = if config.blur_sigma_px > 0.0 { (3.0 * config.blur_sigma_px).ceil() as usize } else { 0 };
    let roi = scene.roi(camera, config, blur_radius + 2);
    let mut radiance = vec![config.background_dn; roi.width() * roi.height()];
    scene.shade(&roi, config, &mut radiance);
    if blur_radius > 0 {
        blur(&mut radiance, roi.width(), roi.height(), config.blur_sigma_px, blur_radius, config.background_dn);
    }
    expose(camera, config, &roi, &radiance, noise_seed, out);
    Ok(())
}

/// A pixel rectangle `[x0, x1) × [y0, y1)`.
#[derive(Debug, Clone, Copy)]
struct Roi {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

impl Roi {
    fn width(&self) -> usize {
        self.x1 - self.x0
    }
    fn height(&self) -> usize {
        self.y1 - self.y0
    }
}

/// What a point of the image shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Region {
    /// Cell `row · 10 + col` of the tag.
    Cell(u8),
    /// The plate, in the strip beyond the tag's left, right, top or bottom edge (the four strips
    /// overlap at the plate's corners; each is convex).
    Plate(u8),
    /// Beyond the plate's left, right, top or bottom edge (each a half-plane).
    Outside(u8),
    /// Ray parallel to or meeting the plane behind the camera; or a plate corner, which is in two
    /// strips: resolved by sampling.
    Mixed,
}

struct Scene<'a> {
    /// Normalised image point → plane (x, y, w).
    h_inv: Matrix3<f64>,
    k: Pinhole,
    half_tag_m: f64,
    half_plate_m: f64,
    cell_m: f64,
    cells: &'a TagCells,
    corners_plane: [[f64; 2]; 4],
    t_cam_marker: Isometry3<f64>,
}

impl<'a> Scene<'a> {
    fn new(
        camera: &CameraModel,
        tag_size_m: f64,
        cells: &'a TagCells,
        t_cam_marker: &Isometry3<f64>,
        config: &RenderConfig,
    ) -> Option<Self> {
        let r = t_cam_marker.rotation.to_rotation_matrix().into_inner();
        let hm = Matrix3::from_columns(&[
            r.column(0).into_owned(),
            r.column(1).into_owned(),
            t_cam_marker.translation.vector,
        ]);
        let half_tag_m = 0.5 * tag_size_m * TAG_CELLS as f64 / TAG_BLACK_CELLS as f64;
        let half_plate_m = (config.plate_half_per_tag_size * tag_size_m).max(half_tag_m);
        let p = half_plate_m;
        Some(Scene {
            h_inv: hm.try_inverse()?,
            k: camera.intrinsics,
            half_tag_m,
            half_plate_m,
            cell_m: 2.0 * half_tag_m / TAG_CELLS as f64,
            cells,
            corners_plane: [[-p, -p], [p, -p], [p, p], [-p, p]],
            t_cam_marker: *t_cam_marker,
        })
    }

    /// The plate's bounding box in the image plus `margin` pixels, clipped; the whole image if a
    /// plate corner is at or behind the camera plane.
    fn roi(&self, camera: &CameraModel, _config: &RenderConfig, margin: usize) -> Roi {
        let full = Roi { x0: 0, y0: 0, x1: camera.width_px as usize, y1: camera.height_px as usize };
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for [x, y] in self.corners_plane {
            let p = self.t_cam_marker * nalgebra::Point3::new(x, y, 0.0);
            if p.z <= 1e-6 {
                return full;
            }
            let uv = [self.k.fx_px * p.x / p.z + self.k.cx_px, self.k.fy_px * p.y / p.z + self.k.cy_px];
            for i in 0..2 {
                lo[i] = lo[i].min(uv[i]);
                hi[i] = hi[i].max(uv[i]);
            }
        }
        let m = margin as f64;
        let clip = |v: f64, max: usize| v.clamp(0.0, max as f64) as usize;
        let x0 = clip((lo[0] - m).floor(), full.x1);
        let y0 = clip((lo[1] - m).floor(), full.y1);
        let x1 = clip((hi[0] + m).ceil() + 1.0, full.x1);
        let y1 = clip((hi[1] + m).ceil() + 1.0, full.y1);
        if x0 >= x1 || y0 >= y1 {
            return Roi { x0: 0, y0: 0, x1: 0, y1: 0 };
        }
        Roi { x0, y0, x1, y1 }
    }

    /// Plane coordinates of image point `(u, v)`; `None` if the ray misses the plane in front.
    #[inline]
    fn plane_point(&self, u: f64, v: f64) -> Option<[f64; 2]> {
        let r = Vector3::new((u - self.k.cx_px) / self.k.fx_px, (v - self.k.cy_px) / self.k.fy_px, 1.0);
        let q = self.h_inv * r;
        (q.z > 1e-12).then(|| [q.x / q.z, q.y / q.z])
    }

    #[inline]
    fn region(&self, p: Option<[f64; 2]>) -> Region {
        let Some([x, y]) = p else { return Region::Mixed };
        let (s, pl) = (self.half_tag_m, self.half_plate_m);
        if x.abs() < s && y.abs() < s {
            let col = (((x + s) / self.cell_m) as usize).min(TAG_CELLS - 1);
            let row = (((s - y) / self.cell_m) as usize).min(TAG_CELLS - 1);
            return Region::Cell((row * TAG_CELLS + col) as u8);
        }
        if x.abs() < pl && y.abs() < pl {
            // In exactly one strip unless at a plate corner (|x| ≥ s and |y| ≥ s).
            return match (x.abs() >= s, y.abs() >= s) {
                (true, false) => Region::Plate(if x < 0.0 { 0 } else { 1 }),
                (false, true) => Region::Plate(if y > 0.0 { 2 } else { 3 }),
                _ => Region::Mixed,
            };
        }
        if x <= -pl {
            Region::Outside(0)
        } else if x >= pl {
            Region::Outside(1)
        } else if y >= pl {
            Region::Outside(2)
        } else {
            Region::Outside(3)
        }
    }

    #[inline]
    fn level(&self, config: &RenderConfig, p: Option<[f64; 2]>) -> f32 {
        let Some([x, y]) = p else { return config.background_dn };
        let (s, pl) = (self.half_tag_m, self.half_plate_m);
        if x.abs() < s && y.abs() < s {
            let col = (((x + s) / self.cell_m) as usize).min(TAG_CELLS - 1);
            let row = (((s - y) / self.cell_m) as usize).min(TAG_CELLS - 1);
            if self.cells[row][col] { config.white_dn } else { config.black_dn }
        } else if x.abs() < pl && y.abs() < pl {
            config.plate_dn
        } else {
            config.background_dn
        }
    }

    fn region_level(&self, config: &RenderConfig, region: Region) -> f32 {
        match region {
            Region::Cell(i) => {
                let i = usize::from(i);
                if self.cells[i / TAG_CELLS][i % TAG_CELLS] { config.white_dn } else { config.black_dn }
            }
            Region::Plate(_) => config.plate_dn,
            Region::Outside(_) | Region::Mixed => config.background_dn,
        }
    }

    /// Fills the region of interest with the anti-aliased grey levels.
    fn shade(&self, roi: &Roi, config: &RenderConfig, out: &mut [f32]) {
        let (rw, rh) = (roi.width(), roi.height());
        if rw == 0 || rh == 0 {
            return;
        }
        // Regions at the pixel corners, (rw + 1) × (rh + 1), one row at a time.
        let corner_row = |y: usize, buf: &mut Vec<Region>| {
            buf.clear();
            let v = roi.y0 as f64 + y as f64 - 0.5;
            for x in 0..=rw {
                let u = roi.x0 as f64 + x as f64 - 0.5;
                buf.push(self.region(self.plane_point(u, v)));
            }
        };
        let (mut top, mut bottom) = (Vec::with_capacity(rw + 1), Vec::with_capacity(rw + 1));
        corner_row(0, &mut top);
        let n = config.supersampling as usize;
        let inv = 1.0 / (n * n) as f32;
        for y in 0..rh {
            corner_row(y + 1, &mut bottom);
            let v = (roi.y0 + y) as f64;
            for x in 0..rw {
                let c = top[x];
                let uniform = c != Region::Mixed && top[x + 1] == c && bottom[x] == c && bottom[x + 1] == c;
                out[y * rw + x] = if uniform {
                    self.region_level(config, c)
                } else {
                    let u = (roi.x0 + x) as f64;
                    let mut sum = 0.0;
                    for j in 0..n {
                        let ov = (j as f64 + 0.5) / n as f64 - 0.5;
                        for i in 0..n {
                            let ou = (i as f64 + 0.5) / n as f64 - 0.5;
                            sum += self.level(config, self.plane_point(u + ou, v + ov));
                        }
                    }
                    sum * inv
                };
            }
            std::mem::swap(&mut top, &mut bottom);
        }
    }
}

/// Separable Gaussian blur in place; pixels beyond the buffer are `outside`.
fn blur(img: &mut [f32], w: usize, h: usize, sigma: f64, radius: usize, outside: f32) {
    let kernel: Vec<f32> = {
        let raw: Vec<f64> =
            (0..=2 * radius).map(|i| (-((i as f64 - radius as f64).powi(2)) / (2.0 * sigma * sigma)).exp()).collect();
        let sum: f64 = raw.iter().sum();
        raw.iter().map(|v| (v / sum) as f32).collect()
    };
    let mut line = Vec::new();
    for pass in 0..2 {
        let (len, count) = if pass == 0 { (w, h) } else { (h, w) };
        for l in 0..count {
            let idx = |i: usize| if pass == 0 { l * w + i } else { i * w + l };
            line.clear();
            line.extend(std::iter::repeat_n(outside, radius));
            line.extend((0..len).map(|i| img[idx(i)]));
            line.extend(std::iter::repeat_n(outside, radius));
            for i in 0..len {
                img[idx(i)] = line[i..i + kernel.len()].iter().zip(&kernel).map(|(a, b)| a * b).sum();
            }
        }
    }
}

/// SplitMix64's finaliser.
#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A standard normal deviate for pixel `index`: Irwin-Hall sum of four bytes of a hash, scaled
/// to unit variance (the simulator's image-noise draw).
#[inline]
fn gaussian(seed: u64, index: u64) -> f32 {
    let hash = mix64(seed ^ index.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    let sum = (hash & 0xFF) + ((hash >> 8) & 0xFF) + ((hash >> 16) & 0xFF) + ((hash >> 24) & 0xFF);
    ((sum as f32 + 2.0) * (1.0 / 256.0) - 2.0) * 3.0_f32.sqrt()
}

/// Writes the 8-bit image: the region of interest's levels, the background elsewhere, with noise.
fn expose(camera: &CameraModel, config: &RenderConfig, roi: &Roi, radiance: &[f32], seed: u64, out: &mut [u8]) {
    let w = camera.width_px as usize;
    let shot = if config.full_well_e > 0.0 { (255.0 / config.full_well_e) as f32 } else { 0.0 };
    let read_var = (config.read_noise_dn * config.read_noise_dn) as f32;
    let noisy = shot > 0.0 || read_var > 0.0;
    let key = mix64(seed ^ 0x6D61_726B_6572_4C55);
    for (i, o) in out.iter_mut().enumerate() {
        let (x, y) = (i % w, i / w);
        let dn = if x >= roi.x0 && x < roi.x1 && y >= roi.y0 && y < roi.y1 {
            radiance[(y - roi.y0) * roi.width() + (x - roi.x0)]
        } else {
            config.background_dn
        };
        let value = if noisy { dn + (dn.max(0.0) * shot + read_var).sqrt() * gaussian(key, i as u64) } else { dn };
        *o = (value + 0.5).clamp(0.0, 255.0) as u8;
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::needless_range_loop)]
    use super::*;

    #[test]
    fn pattern_has_a_white_ring_and_a_black_border() {
        let cells = cells_from_pattern(&TAG36H11_ID0_PATTERN);
        for i in 0..TAG_CELLS {
            assert!(cells[0][i] && cells[9][i] && cells[i][0] && cells[i][9]);
        }
        for i in 1..TAG_CELLS - 1 {
            assert!(!cells[1][i] && !cells[8][i] && !cells[i][1] && !cells[i][8]);
        }
    }
}
