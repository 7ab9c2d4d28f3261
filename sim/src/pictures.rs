//! The pictures of `sim pictures`: a rendered left image, its depth and a top-down terrain map
//! per preset (owned by the dataset helper).
//!
//! Drawing is deliberately plain: area-averaged downsizing, a perceptual colormap for depth
//! (near bright, far dark, sky black), a hillshaded hypsometric map with the robots' paths and the
//! rocks drawn on it.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::asl::{AslError, encode_png};
use crate::render::Renderer;
use crate::scenario::{self, ScenarioOptions};
use crate::world::World;

/// An 8-bit image with `channels` samples per pixel (1 grey, 3 RGB), row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub channels: usize,
    pub pixels: Vec<u8>,
}

impl Image {
    pub fn new(width: u32, height: u32, channels: usize) -> Image {
        Image { width, height, channels, pixels: vec![0; width as usize * height as usize * channels] }
    }

    /// Sets pixel `(x, y)` to `rgb` (its first sample for grey); outside the image nothing happens.
    pub fn put(&mut self, x: i64, y: i64, rgb: [u8; 3]) {
        if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
            return;
        }
        let i = (y as usize * self.width as usize + x as usize) * self.channels;
        let n = self.channels.min(3);
        self.pixels[i..i + n].copy_from_slice(&rgb[..n]);
    }

    /// Encodes as PNG (best compression: these go into the README).
    pub fn to_png(&self) -> Result<Vec<u8>, png::EncodingError> {
        let color = if self.channels == 1 { png::ColorType::Grayscale } else { png::ColorType::Rgb };
        let mut out = Vec::new();
        encode_png(&mut out, self.width, self.height, color, &self.pixels, png::Compression::High)?;
        Ok(out)
    }

    /// Shrinks to `width` pixels wide (height in proportion) by averaging the source pixels each
    /// output pixel covers; never enlarges.
    pub fn resized_to_width(&self, width: u32) -> Image {
        let width = width.clamp(1, self.width.max(1));
        let height = ((u64::from(self.height) * u64::from(width) + u64::from(self.width) / 2)
            / u64::from(self.width.max(1)))
        .max(1) as u32;
        let mut out = Image::new(width, height, self.channels);
        let (sw, sh) = (self.width as usize, self.height as usize);
        let span = |o: usize, n_out: usize, n_src: usize| {
            let a = o * n_src / n_out;
            let b = ((o + 1) * n_src / n_out).max(a + 1).min(n_src);
            a..b
        };
        let mut sums = vec![0u32; self.channels];
        for oy in 0..height as usize {
            let rows = span(oy, height as usize, sh);
            for ox in 0..width as usize {
                let cols = span(ox, width as usize, sw);
                sums.fill(0);
                for y in rows.clone() {
                    for x in cols.clone() {
                        let i = (y * sw + x) * self.channels;
                        for (s, &v) in sums.iter_mut().zip(&self.pixels[i..i + self.channels]) {
                            *s += u32::from(v);
                        }
                    }
                }
                let count = (rows.len() * cols.len()).max(1) as u32;
                let o = (oy * width as usize + ox) * self.channels;
                for (c, s) in sums.iter().enumerate() {
                    out.pixels[o + c] = ((s + count / 2) / count) as u8;
                }
            }
        }
        out
    }
}

/// Viridis sampled at nine equal steps (matplotlib's perceptually uniform colormap, CC0).
const VIRIDIS: [[u8; 3]; 9] = [
    [0x44, 0x01, 0x54],
    [0x47, 0x2d, 0x7b],
    [0x3b, 0x52, 0x8b],
    [0x2c, 0x72, 0x8e],
    [0x21, 0x91, 0x8c],
    [0x28, 0xae, 0x80],
    [0x5e, 0xc9, 0x62],
    [0xad, 0xdc, 0x30],
    [0xfd, 0xe7, 0x25],
];

/// A hypsometric ramp: low ground slate blue, middle ochre, high ground pale sand.
const TERRAIN_RAMP: [[u8; 3]; 5] =
    [[0x3a, 0x4a, 0x6b], [0x5f, 0x7d, 0x7a], [0xa8, 0x9a, 0x6a], [0xd2, 0xb4, 0x82], [0xf4, 0xec, 0xdc]];

/// Linear interpolation in a colour table at `t` in `[0, 1]` (clamped; NaN gives the first).
pub fn ramp(table: &[[u8; 3]], t: f64) -> [u8; 3] {
    let last = table.len().saturating_sub(1);
    let Some(first) = table.first() else { return [0; 3] };
    if t.is_nan() || t <= 0.0 || last == 0 {
        return *first;
    }
    let x = t.min(1.0) * last as f64;
    let i = (x.floor() as usize).min(last - 1);
    let f = x - i as f64;
    let mut out = [0u8; 3];
    for c in 0..3 {
        let (a, b) = (f64::from(table[i][c]), f64::from(table[i + 1][c]));
        out[c] = (a + (b - a) * f).round() as u8;
    }
    out
}

pub fn viridis(t: f64) -> [u8; 3] {
    ramp(&VIRIDIS, t)
}

/// The `q`-quantile (0..=1) of the finite values, `None` if there are none.
pub fn quantile(values: impl Iterator<Item = f64>, q: f64) -> Option<f64> {
    let mut finite: Vec<f64> = values.filter(|v| v.is_finite()).collect();
    if finite.is_empty() {
        return None;
    }
    finite.sort_by(f64::total_cmp);
    let i = ((finite.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize;
    Some(finite[i])
}

/// Depth as colour: logarithmic from `near_m` (bright) to `far_m` (dark), sky (non-finite) black.
pub fn colorize_depth(depth_m: &[f32], width: u32, height: u32, near_m: f64, far_m: f64) -> Image {
    let mut image = Image::new(width, height, 3);
    let near = near_m.max(1e-3);
    let span = (far_m.max(near * 1.001) / near).ln();
    for (px, &d) in image.pixels.chunks_exact_mut(3).zip(depth_m) {
        if d.is_finite() && d > 0.0 {
            let t = (f64::from(d) / near).ln() / span;
            px.copy_from_slice(&viridis(1.0 - t));
        }
    }
    image
}

/// Draws a `thickness`-pixel line from `a` to `b` (pixel coordinates).
pub fn draw_line(image: &mut Image, a: [f64; 2], b: [f64; 2], thickness: f64, rgb: [u8; 3]) {
    let steps = ((b[0] - a[0]).abs().max((b[1] - a[1]).abs()).ceil() as usize).clamp(1, 1 << 16);
    for s in 0..=steps {
        let f = s as f64 / steps as f64;
        fill_disc(image, [a[0] + (b[0] - a[0]) * f, a[1] + (b[1] - a[1]) * f], 0.5 * thickness, rgb);
    }
}

/// Fills the disc of `radius` pixels around `centre`.
pub fn fill_disc(image: &mut Image, centre: [f64; 2], radius: f64, rgb: [u8; 3]) {
    let r = radius.max(0.5);
    let (x0, x1) = ((centre[0] - r).floor() as i64, (centre[0] + r).ceil() as i64);
    let (y0, y1) = ((centre[1] - r).floor() as i64, (centre[1] + r).ceil() as i64);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (dx, dy) = (x as f64 + 0.5 - centre[0], y as f64 + 0.5 - centre[1]);
            if dx * dx + dy * dy <= r * r {
                image.put(x, y, rgb);
            }
        }
    }
}

/// Draws a one-pixel circle of `radius` pixels.
pub fn draw_circle(image: &mut Image, centre: [f64; 2], radius: f64, rgb: [u8; 3]) {
    let steps = ((radius * 8.0).ceil() as usize).clamp(8, 4096);
    for s in 0..steps {
        let a = std::f64::consts::TAU * s as f64 / steps as f64;
        let (x, y) = (centre[0] + radius * a.cos(), centre[1] + radius * a.sin());
        image.put(x.floor() as i64, y.floor() as i64, rgb);
    }
}

/// Colours of the robots' paths (distinct from the terrain ramp).
const PATH_COLOURS: [[u8; 3]; 4] = [[0xe6, 0x19, 0x4b], [0x00, 0xc8, 0xff], [0xff, 0xe1, 0x19], [0xf0, 0x32, 0xe6]];

/// The square of the site to draw: `side_m` wide around the robots' paths (larger if the paths
/// are), inside the site.
pub fn topdown_region(world: &World, side_m: f64) -> ([f64; 2], [f64; 2]) {
    let hf = &world.terrain.heightfield;
    let site_min = hf.origin_m;
    let site_max = [
        hf.origin_m[0] + hf.cols.saturating_sub(1) as f64 * hf.resolution_m,
        hf.origin_m[1] + hf.rows.saturating_sub(1) as f64 * hf.resolution_m,
    ];
    let Some((lo, hi)) = crate::asl::path_bounds(world) else { return (site_min, site_max) };
    let side = side_m.max(hi[0] - lo[0] + 10.0).max(hi[1] - lo[1] + 10.0);
    let mut min = [0.0; 2];
    let mut max = [0.0; 2];
    for k in 0..2 {
        let centre = 0.5 * (lo[k] + hi[k]);
        // Slide the square inside the site rather than cutting it.
        let a = (centre - 0.5 * side).max(site_min[k]);
        let b = (a + side).min(site_max[k]);
        min[k] = (b - side).max(site_min[k]);
        max[k] = b;
    }
    (min, max)
}

/// A north-up map of `[min, max]` (world x, y), `width` pixels wide: heights coloured, shaded by
/// a light from the north-west, the robots' paths (start dot, end ring) and rocks (dark rings).
pub fn topdown(world: &World, min_m: [f64; 2], max_m: [f64; 2], width: u32) -> Image {
    let hf = &world.terrain.heightfield;
    let width = width.max(1);
    let m_per_px = ((max_m[0] - min_m[0]) / f64::from(width)).max(1e-6);
    let height = (((max_m[1] - min_m[1]) / m_per_px).round() as u32).max(1);
    let centre =
        |px: u32, py: u32| (min_m[0] + (f64::from(px) + 0.5) * m_per_px, max_m[1] - (f64::from(py) + 0.5) * m_per_px);
    let to_px = |x: f64, y: f64| [(x - min_m[0]) / m_per_px, (max_m[1] - y) / m_per_px];

    let mut heights = vec![f64::NAN; width as usize * height as usize];
    for py in 0..height {
        for px in 0..width {
            let (x, y) = centre(px, py);
            heights[(py * width + px) as usize] = hf.height_at(x, y).unwrap_or(f64::NAN);
        }
    }
    let low = quantile(heights.iter().copied(), 0.02).unwrap_or(0.0);
    let high = quantile(heights.iter().copied(), 0.98).unwrap_or(1.0).max(low + 1e-3);
    // Cartographic convention: light from the north-west, 45° up.
    let light = nalgebra::Vector3::new(-1.0, 1.0, 2.0f64.sqrt()).normalize();
    let at = |px: i64, py: i64| {
        let px = px.clamp(0, i64::from(width) - 1) as usize;
        let py = py.clamp(0, i64::from(height) - 1) as usize;
        heights[py * width as usize + px]
    };

    let mut image = Image::new(width, height, 3);
    for py in 0..i64::from(height) {
        for px in 0..i64::from(width) {
            let h = at(px, py);
            if !h.is_finite() {
                continue;
            }
            let dzdx = (at(px + 1, py) - at(px - 1, py)) / (2.0 * m_per_px);
            // Image rows run south, world y north.
            let dzdy = (at(px, py - 1) - at(px, py + 1)) / (2.0 * m_per_px);
            let normal = nalgebra::Vector3::new(-dzdx, -dzdy, 1.0).normalize();
            let shade = if normal.x.is_finite() { normal.dot(&light).max(0.0) } else { 1.0 };
            let base = ramp(&TERRAIN_RAMP, (h - low) / (high - low));
            let k = 0.3 + 0.7 * shade;
            // Colours in steps of 4 grey levels: invisible, and it keeps the PNG small.
            image.put(px, py, base.map(|c| ((f64::from(c) * k / 4.0).round() * 4.0).min(255.0) as u8));
        }
    }

    for rock in &world.terrain.rocks {
        let p = to_px(rock.base_m.x, rock.base_m.y);
        let r = rock.radius_m / m_per_px;
        if p[0] + r < 0.0 || p[1] + r < 0.0 || p[0] - r > f64::from(width) || p[1] - r > f64::from(height) {
            continue;
        }
        draw_circle(&mut image, p, r.max(1.5), [0x20, 0x10, 0x10]);
    }

    let thickness = (0.3 / m_per_px).clamp(1.5, 4.0);
    for (i, robot) in world.robots.iter().enumerate() {
        let colour = PATH_COLOURS[i % PATH_COLOURS.len()];
        let trajectory = &robot.trajectory;
        let (start, end) = (trajectory.start_ns(), trajectory.end_ns());
        let mut points = Vec::new();
        let mut stamp = start;
        loop {
            if let Some(state) = trajectory.state_at(stamp) {
                let p = state.t_world_body.translation.vector;
                points.push(to_px(p.x, p.y));
            }
            if stamp >= end {
                break;
            }
            stamp = stamp.saturating_add(200_000_000).min(end);
        }
        for pair in points.windows(2) {
            draw_line(&mut image, pair[0], pair[1], thickness, colour);
        }
        if let (Some(first), Some(last)) = (points.first(), points.last()) {
            fill_disc(&mut image, *first, 2.5 * thickness, colour);
            draw_circle(&mut image, *last, 3.0 * thickness, colour);
            draw_circle(&mut image, *last, 3.0 * thickness + 1.0, colour);
        }
    }
    image
}

/// One file `sim pictures` wrote.
#[derive(Debug, Clone, PartialEq)]
pub struct Picture {
    pub path: PathBuf,
    pub width: u32,
    pub height: u32,
    pub bytes: u64,
}

/// Options of `sim pictures`.
#[derive(Debug, Clone, PartialEq)]
pub struct PictureOptions {
    /// Width of every picture.
    pub width: u32,
    pub seed: u64,
    /// When the left image is taken (clamped into the run).
    pub stamp_s: f64,
    /// Edge of the top-down map's square around the paths.
    pub topdown_side_m: f64,
    /// Length of the run whose paths the map shows.
    pub duration_s: f64,
}

impl Default for PictureOptions {
    fn default() -> Self {
        PictureOptions { width: 512, seed: 1, stamp_s: 12.0, topdown_side_m: 60.0, duration_s: 300.0 }
    }
}

fn save(image: &Image, path: PathBuf) -> Result<Picture, AslError> {
    let bytes = image.to_png().map_err(|source| AslError::Png { path: path.clone(), source })?;
    crate::asl::write_bytes(&path, &bytes)?;
    Ok(Picture { path, width: image.width, height: image.height, bytes: bytes.len() as u64 })
}

/// Writes `<preset>_left.png`, `<preset>_depth.png` and `<preset>_topdown.png` for every
/// preset into `out`.
pub fn write_pictures(out: &Path, options: &PictureOptions) -> Result<Vec<Picture>, AslError> {
    let mut pictures = Vec::new();
    for &preset in scenario::PRESETS {
        let scenario_options =
            ScenarioOptions { seed: options.seed, duration_s: options.duration_s, ..ScenarioOptions::default() };
        let scenario = scenario::preset(preset, &scenario_options).map_err(|e| AslError::Invalid(e.to_string()))?;
        let world = World::build(&scenario).map_err(|e| AslError::Invalid(e.to_string()))?;
        pictures.extend(preset_pictures(&world, preset, out, options)?);
    }
    Ok(pictures)
}

/// The three pictures of one world, named `<name>_*.png`.
pub fn preset_pictures(
    world: &Arc<World>,
    name: &str,
    out: &Path,
    options: &PictureOptions,
) -> Result<Vec<Picture>, AslError> {
    let robot = world.robots.first().ok_or_else(|| AslError::Invalid(format!("{name}: the scenario has no robot")))?;
    std::fs::create_dir_all(out).map_err(crate::asl::io_error(out))?;
    let stamp_ns = ((options.stamp_s.max(0.0) * 1e9) as u64).min(world.end_ns());
    let t_world_cam = world
        .t_world_cam(0, stamp_ns)
        .ok_or_else(|| AslError::Invalid(format!("{name}: robot 0 has no pose at {stamp_ns} ns")))?;
    let camera = robot.model().camera;
    let mut renderer = Renderer::new(camera, world.scenario.sensor);
    let mut quads = Vec::new();
    world.quads_at(stamp_ns, Some(0), &mut quads);
    let scene = world.scene(&quads);
    let mut left = Image::new(camera.width_px, camera.height_px, 1);
    let mut right = vec![0u8; camera.pixels()];
    let noise_seed = crate::rng::stream_seed(world.scenario.seed, &[crate::rng::streams::IMAGE_NOISE, 0, stamp_ns]);
    renderer.render_stereo(&scene, &t_world_cam, noise_seed, &mut left.pixels, &mut right);
    let depth = renderer.depth_m();
    let near = quantile(depth.iter().map(|&d| f64::from(d)), 0.02).unwrap_or(1.0);
    let far = quantile(depth.iter().map(|&d| f64::from(d)), 0.98).unwrap_or(100.0);
    let depth_image = colorize_depth(depth, camera.width_px, camera.height_px, near, far);

    let (min_m, max_m) = topdown_region(world, options.topdown_side_m);
    let map = topdown(world, min_m, max_m, options.width);
    Ok(vec![
        save(&left.resized_to_width(options.width), out.join(format!("{name}_left.png")))?,
        save(&depth_image.resized_to_width(options.width), out.join(format!("{name}_depth.png")))?,
        save(&map, out.join(format!("{name}_topdown.png")))?,
    ])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn resize_averages_blocks() {
        let image = Image { width: 4, height: 2, channels: 1, pixels: vec![0, 10, 20, 30, 40, 50, 60, 70] };
        let small = image.resized_to_width(2);
        assert_eq!((small.width, small.height), (2, 1));
        // (0 + 10 + 40 + 50) / 4 = 25, (20 + 30 + 60 + 70) / 4 = 45.
        assert_eq!(small.pixels, vec![25, 45]);
        assert_eq!(image.resized_to_width(9), image, "never enlarges");
    }

    #[test]
    fn ramp_ends_and_middle() {
        assert_eq!(viridis(0.0), VIRIDIS[0]);
        assert_eq!(viridis(1.0), VIRIDIS[8]);
        assert_eq!(viridis(f64::NAN), VIRIDIS[0]);
        assert_eq!(viridis(0.5), VIRIDIS[4]);
        assert_eq!(ramp(&[[0, 0, 0], [100, 200, 250]], 0.5), [50, 100, 125]);
    }

    #[test]
    fn depth_colours_sky_black_and_near_bright() {
        let image = colorize_depth(&[1.0, 100.0, f32::INFINITY], 3, 1, 1.0, 100.0);
        assert_eq!(&image.pixels[0..3], &VIRIDIS[8]);
        assert_eq!(&image.pixels[3..6], &VIRIDIS[0]);
        assert_eq!(&image.pixels[6..9], &[0, 0, 0]);
    }
}
