//! Sun, surface reflectance and cast shadows (owned by the terrain helper).

use nalgebra::Vector3;

use crate::terrain::Heightfield;

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
    /// (0 when the sun is below the local horizon).
    pub fn factor(&self, normal: &Vector3<f64>, to_sun: &Vector3<f64>, to_viewer: &Vector3<f64>) -> f32 {
        let _ = (normal, to_sun, to_viewer);
        0.0
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
    pub fn compute(heightfield: &Heightfield, sun: &Sun) -> ShadowMap {
        let _ = sun;
        ShadowMap {
            resolution_m: heightfield.resolution_m,
            origin_m: heightfield.origin_m,
            cols: heightfield.cols,
            rows: heightfield.rows,
            lit: vec![255; heightfield.cols * heightfield.rows],
        }
    }

    /// Sun visibility in `[0, 1]` at `(x, y)`, bilinear; 1 outside the map.
    pub fn lit_at(&self, x_m: f64, y_m: f64) -> f32 {
        let _ = (x_m, y_m);
        1.0
    }
}
