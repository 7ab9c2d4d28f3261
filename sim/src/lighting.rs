//! Sun, surface reflectance and cast shadows (owned by the terrain helper).

use nalgebra::Vector3;

use crate::terrain::Heightfield;
use crate::terrain::bilinear::{self, CHUNK, Taps};

/// Angular radius of the sun's disc seen from 1 AU (Earth and Moon): 0.2666°.
pub const SUN_ANGULAR_RADIUS_RAD: f64 = 0.004_653;

/// The sun as seen from the site.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sun {
    /// Azimuth from +x (east) towards +y (north).
    pub azimuth_rad: f64,
    /// Elevation above the horizon.
    pub elevation_rad: f64,
    /// Irradiance scale (1 = full sun at the body's distance).
    pub irradiance: f32,
}

impl Sun {
    /// Unit vector from the surface towards the sun, world frame.
    pub fn direction_world(&self) -> Vector3<f64> {
        let (se, ce) = self.elevation_rad.sin_cos();
        let (sa, ca) = self.azimuth_rad.sin_cos();
        Vector3::new(ce * ca, ce * sa, se)
    }
}

/// How the surface scatters light.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reflectance {
    Lambert,
    /// McEwen's lunar-Lambert blend, a common stand-in for Hapke's model: weight `l` on the
    /// Lommel–Seeliger term `2 cos i / (cos i + cos e)`, `1 − l` on Lambert's `cos i`.
    LunarLambert {
        l: f32,
    },
}

impl Reflectance {
    /// Reflected radiance factor for unit `normal`, unit `to_sun` and unit `to_viewer`
    /// (0 when the sun is below the local horizon or the viewer behind the surface). Both models
    /// give 1 for sun and viewer along the normal.
    pub fn factor(&self, normal: &Vector3<f64>, to_sun: &Vector3<f64>, to_viewer: &Vector3<f64>) -> f32 {
        let cos_i = normal.dot(to_sun);
        let cos_e = normal.dot(to_viewer);
        if cos_i <= 0.0 || cos_e <= 0.0 {
            return 0.0;
        }
        match *self {
            Reflectance::Lambert => cos_i as f32,
            Reflectance::LunarLambert { l } => {
                let l = f64::from(l);
                (l * 2.0 * cos_i / (cos_i + cos_e) + (1.0 - l) * cos_i) as f32
            }
        }
    }
}

/// Which cells see the sun: a soft visibility per cell of a heightfield (0 = shadow, 255 = lit).
#[derive(Debug, Clone, PartialEq)]
pub struct ShadowMap {
    pub resolution_m: f64,
    pub origin_m: [f64; 2],
    pub cols: usize,
    pub rows: usize,
    pub lit: Vec<u8>,
}

impl ShadowMap {
    /// Cast shadows of the terrain (rocks included, since they are part of the heightfield).
    ///
    /// A horizon sweep: rays one cell apart run across the grid away from the sun, one cell per
    /// grid line (nearest cell), so every cell lies on exactly one ray and the whole map costs
    /// O(cells). Along a ray the shadow surface `S` (the highest occluder lowered by
    /// `tan(elevation)` per metre) and the distance to that occluder are carried; a cell below
    /// `S` sees its horizon above the sun's centre. The visibility is the fraction of the sun's
    /// disc ([`SUN_ANGULAR_RADIUS_RAD`]) above that horizon, which gives penumbrae that widen
    /// with the distance to the occluder. Facets turned away from the sun are left to
    /// [`Reflectance::factor`].
    pub fn compute(heightfield: &Heightfield, sun: &Sun) -> ShadowMap {
        let mut map = ShadowMap {
            resolution_m: heightfield.resolution_m,
            origin_m: heightfield.origin_m,
            cols: heightfield.cols,
            rows: heightfield.rows,
            lit: vec![255; heightfield.cols * heightfield.rows],
        };
        let elevation = sun.elevation_rad;
        if elevation.is_nan() || elevation <= -SUN_ANGULAR_RADIUS_RAD {
            map.lit.fill(0);
            return map;
        }
        if elevation >= std::f64::consts::FRAC_PI_2 - SUN_ANGULAR_RADIUS_RAD
            || heightfield.cols == 0
            || heightfield.rows == 0
            || heightfield.heights_m.len() < heightfield.cols * heightfield.rows
        {
            return map;
        }
        sweep(heightfield, sun, &mut map.lit);
        map
    }

    /// Sun visibility in `[0, 1]` at `(x, y)`, bilinear; 1 outside the map.
    pub fn lit_at(&self, x_m: f64, y_m: f64) -> f32 {
        let mut out = [0.0];
        self.lit_many(&[x_m], &[y_m], &mut out);
        out[0]
    }

    /// [`ShadowMap::lit_at`] at many points, bit for bit the same per point, several times
    /// faster (see `terrain::bilinear`). Fills `out[i]` for `i` below the shortest length.
    pub fn lit_many(&self, x_m: &[f64], y_m: &[f64], out: &mut [f32]) {
        let n = out.len().min(x_m.len()).min(y_m.len());
        let (cols, rows) = (self.cols, self.rows);
        if cols < 2 || rows < 2 || self.lit.len() < cols * rows {
            for i in 0..n {
                out[i] = self.lit_at_small(x_m[i], y_m[i]);
            }
            return;
        }
        let level = bilinear::Level { offset: 0, cols, rows, scale: 1.0, shift: 0.0 };
        let (max_x, max_y) = ((cols - 1) as f32, (rows - 1) as f32);
        let inv_res = 1.0 / self.resolution_m;
        let (mut gx, mut gy) = ([0.0f32; CHUNK], [0.0f32; CHUNK]);
        let mut taps = Taps::new();
        for start in (0..n).step_by(CHUNK) {
            let m = (n - start).min(CHUNK);
            let (gx, gy) = (&mut gx[..m], &mut gy[..m]);
            bilinear::cell_coordinates(self.origin_m, inv_res, &x_m[start..start + m], &y_m[start..start + m], gx, gy);
            taps.on_level(&level, gx, gy);
            let out = &mut out[start..start + m];
            taps.blend(&self.lit, cols, out);
            for i in 0..m {
                // Written so that NaN is outside; `&` rather than `&&` keeps the loop branch-free.
                let inside = (gx[i] >= 0.0) & (gx[i] <= max_x) & (gy[i] >= 0.0) & (gy[i] <= max_y);
                out[i] = if inside { out[i] * (1.0 / 255.0) } else { 1.0 };
            }
        }
    }

    /// [`ShadowMap::lit_at`] for a map without a single cell square.
    fn lit_at_small(&self, x_m: f64, y_m: f64) -> f32 {
        let fx = (x_m - self.origin_m[0]) / self.resolution_m;
        let fy = (y_m - self.origin_m[1]) / self.resolution_m;
        let (max_x, max_y) = ((self.cols.max(1) - 1) as f64, (self.rows.max(1) - 1) as f64);
        if !(fx >= 0.0 && fx <= max_x && fy >= 0.0 && fy <= max_y) {
            return 1.0;
        }
        let (c, r) = (fx.round() as usize, fy.round() as usize);
        self.lit.get(r * self.cols + c).map_or(1.0, |&v| f32::from(v) * (1.0 / 255.0))
    }

    /// Sun visibility of cell `(col, row)` in `[0, 1]`, 1 outside the map.
    pub fn lit_at_cell(&self, col: usize, row: usize) -> f32 {
        if col >= self.cols || row >= self.rows {
            return 1.0;
        }
        self.lit.get(row * self.cols + col).map_or(1.0, |&v| f32::from(v) * (1.0 / 255.0))
    }
}

/// Fraction of a disc above a line `x` radii below its centre (`x` = 1: all of it).
fn disc_fraction_above(x: f64) -> f64 {
    let x = x.clamp(-1.0, 1.0);
    0.5 + (x * (1.0 - x * x).sqrt() + x.asin()) / std::f64::consts::PI
}

fn sweep(hf: &Heightfield, sun: &Sun, lit: &mut [u8]) {
    let cols = hf.cols;
    let (to_sun_y, to_sun_x) = sun.azimuth_rad.sin_cos();
    // Lines are columns when the sun is more east-west than north-south, rows otherwise. Rays
    // advance one line per step away from the sun and `slope` cells along the line.
    let x_major = to_sun_x.abs() >= to_sun_y.abs();
    let (major_dir, minor_dir) = if x_major { (-to_sun_x, -to_sun_y) } else { (-to_sun_y, -to_sun_x) };
    let slope = minor_dir / major_dir.abs();
    let (lines, along) = if x_major { (cols, hf.rows) } else { (hf.rows, cols) };
    let forward = major_dir > 0.0;
    let step_m = hf.resolution_m * (1.0 + slope * slope).sqrt();
    let drop_per_step = sun.elevation_rad.tan() * step_m;
    let tan_elevation = sun.elevation_rad.tan();
    let cos2_elevation = sun.elevation_rad.cos().powi(2);
    // Ray `i` meets line `k` at position `i + round(k · slope)` along it; the shifts grow
    // monotonically with `k`, so rays are numbered from the most negative `i` needed.
    let shift = |k: usize| (k as f64 * slope).round() as i64;
    let last_shift = shift(lines - 1);
    let ray_base = last_shift.max(0);
    let rays = along + last_shift.unsigned_abs() as usize;
    let mut shadow_top = vec![f64::NEG_INFINITY; rays];
    let mut occluder_distance = vec![0.0f64; rays];
    for k in 0..lines {
        let line = if forward { k } else { lines - 1 - k };
        let offset = ray_base - shift(k);
        for j in 0..along {
            let (col, row) = if x_major { (line, j) } else { (j, line) };
            let index = row * cols + col;
            let h = f64::from(hf.heights_m[index]);
            let ray = (j as i64 + offset) as usize;
            let top = shadow_top[ray] - drop_per_step;
            let distance = occluder_distance[ray] + step_m;
            let visibility = if top == f64::NEG_INFINITY {
                1.0
            } else {
                // The occluder subtends tan(elevation) + (top − h) / distance; near the sun's
                // disc the angular gap is that tangent gap times cos²(elevation).
                let tan_gap = (h - top) / distance;
                let gap_rad = tan_gap * cos2_elevation;
                if gap_rad >= 1.5 * SUN_ANGULAR_RADIUS_RAD {
                    1.0
                } else if gap_rad <= -1.5 * SUN_ANGULAR_RADIUS_RAD {
                    0.0
                } else {
                    let horizon = (tan_elevation - tan_gap).atan();
                    disc_fraction_above((sun.elevation_rad - horizon) / SUN_ANGULAR_RADIUS_RAD)
                }
            };
            lit[index] = (visibility * 255.0).round() as u8;
            if h >= top {
                shadow_top[ray] = h;
                occluder_distance[ray] = 0.0;
            } else {
                shadow_top[ray] = top;
                occluder_distance[ray] = distance;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn disc_fraction_runs_from_none_to_all() {
        assert_eq!(disc_fraction_above(-1.0), 0.0);
        assert!((disc_fraction_above(0.0) - 0.5).abs() < 1e-12);
        assert!((disc_fraction_above(1.0) - 1.0).abs() < 1e-12);
        assert!((disc_fraction_above(0.3) + disc_fraction_above(-0.3) - 1.0).abs() < 1e-12);
    }
}
