//! Top-down height and traversability picture of a cloud.
//!
//! Each cell shows the highest point in it on a blue → green → yellow → white ramp over the
//! cloud's height range; cells holding an obstacle point are red (not traversable), cells
//! without points black. North (+y) is up.

use std::io::Write;

use crate::cloud::VoxelCloud;

/// Largest picture side; a larger one is a wrong resolution rather than a map.
pub const MAX_PNG_SIDE: usize = 16384;

#[derive(Debug, thiserror::Error)]
pub enum PngExportError {
    #[error("resolution must be positive and finite, got {0} m")]
    BadResolution(f64),
    #[error("picture of {cols}×{rows} cells exceeds {MAX_PNG_SIDE} per side")]
    TooLarge { cols: usize, rows: usize },
    #[error(transparent)]
    Encoding(#[from] png::EncodingError),
}

/// The ramp from low to high, linearly interpolated.
const RAMP: [[u8; 3]; 4] = [[40, 60, 200], [40, 180, 80], [230, 220, 40], [255, 255, 255]];

pub(crate) fn ramp(t: f64) -> [u8; 3] {
    let x = t.clamp(0.0, 1.0) * (RAMP.len() - 1) as f64;
    let i = (x.floor() as usize).min(RAMP.len() - 2);
    let f = x - i as f64;
    let mut c = [0u8; 3];
    for (k, v) in c.iter_mut().enumerate() {
        *v = (f64::from(RAMP[i][k]) * (1.0 - f) + f64::from(RAMP[i + 1][k]) * f).round() as u8;
    }
    c
}

/// Obstacle marking in the picture.
pub const OBSTACLE_RGB: [u8; 3] = [255, 0, 0];
/// Cells without points.
pub const UNKNOWN_RGB: [u8; 3] = [0, 0, 0];

/// Writes an RGB PNG with one pixel per `resolution_m` cell over the cloud's x/y extent.
pub fn write_height_png(cloud: &VoxelCloud, resolution_m: f64, out: &mut impl Write) -> Result<(), PngExportError> {
    if !(resolution_m.is_finite() && resolution_m > 0.0) {
        return Err(PngExportError::BadResolution(resolution_m));
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
    for p in &cloud.points {
        for a in 0..3 {
            lo[a] = lo[a].min(f64::from(p.position_m[a]));
            hi[a] = hi[a].max(f64::from(p.position_m[a]));
        }
    }
    let (cols, rows) = if cloud.is_empty() {
        (1, 1)
    } else {
        let side = |a: usize| ((hi[a] - lo[a]) / resolution_m).floor() + 1.0;
        let (c, r) = (side(0), side(1));
        if !(c <= MAX_PNG_SIDE as f64 && r <= MAX_PNG_SIDE as f64) {
            return Err(PngExportError::TooLarge { cols: c as usize, rows: r as usize });
        }
        (c as usize, r as usize)
    };
    let mut height = vec![f64::NEG_INFINITY; cols * rows];
    let mut obstacle = vec![false; cols * rows];
    for p in &cloud.points {
        let col = ((f64::from(p.position_m.x) - lo[0]) / resolution_m).floor() as usize;
        let row_up = ((f64::from(p.position_m.y) - lo[1]) / resolution_m).floor() as usize;
        let i = (rows - 1 - row_up.min(rows - 1)) * cols + col.min(cols - 1);
        height[i] = height[i].max(f64::from(p.position_m.z));
        obstacle[i] |= p.obstacle;
    }
    let range = (hi[2] - lo[2]).max(1e-6);
    let mut rgb = Vec::with_capacity(cols * rows * 3);
    for (h, o) in height.iter().zip(&obstacle) {
        let c = if *o {
            OBSTACLE_RGB
        } else if h.is_finite() {
            ramp((h - lo[2]) / range)
        } else {
            UNKNOWN_RGB
        };
        rgb.extend_from_slice(&c);
    }
    let mut encoder = png::Encoder::new(out, cols as u32, rows as u32);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header()?.write_image_data(&rgb)?;
    Ok(())
}
