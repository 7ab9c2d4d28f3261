//! The albedo texture: the material's mean albedo, blended between cells, times a sum of value
//! noise octaves from 4 m down to 1.8 mm, so that stereo finds texture at 1 m range (1.4 mm
//! pixels) and at 30 m (3 cm pixels) alike.

use super::{Material, Terrain};
use crate::noise::{self, LANES, OCTAVE_ROTATIONS, VALUE_NOISE_STD};
use crate::rng::{self, streams};

/// Coarsest texture wavelength; each octave is three times finer: lacunarity 3 spans 4 m to
/// 1.8 mm in eight octaves, one SIMD-friendly block of [`LANES`].
const COARSEST_WAVELENGTH_M: f64 = 4.0;
const WAVELENGTHS_M: [f64; LANES] = {
    let mut w = [COARSEST_WAVELENGTH_M; LANES];
    let mut k = 1;
    while k < LANES {
        w[k] = w[k - 1] / 3.0;
        k += 1;
    }
    w
};
/// Per octave: rotation `(cos, sin)` over the wavelength, so each octave's lattice is turned
/// differently and no grid direction shows in the sum.
const ROTATION_OVER_WAVELENGTH: [(f32, f32); LANES] = {
    let mut r = [(0.0, 0.0); LANES];
    let mut k = 0;
    while k < LANES {
        let (c, s) = OCTAVE_ROTATIONS[k + 1];
        r[k] = ((c / WAVELENGTHS_M[k]) as f32, (s / WAVELENGTHS_M[k]) as f32);
        k += 1;
    }
    r
};
/// Equal-variance octaves summed and scaled to unit standard deviation (√8 octaves).
const NORMALISATION: f32 = (1.0 / (VALUE_NOISE_STD * 2.828_427_124_746_19)) as f32;
/// The texture never darkens a surface below this fraction of its mean albedo.
const MIN_FRACTION: f32 = 0.2;
const MAX_ALBEDO: f32 = 0.98;

pub(super) fn filtered(terrain: &Terrain, x_m: f64, y_m: f64, footprint_m: f64) -> f32 {
    let config = &terrain.config;
    let mean = config.albedo_mean * material_factor(terrain, x_m, y_m);
    let base_seed = noise::seed32(rng::stream_seed(terrain.seed, &[streams::ALBEDO]));
    let seeds: [u32; LANES] = std::array::from_fn(|k| base_seed.wrapping_add((k as u32).wrapping_mul(0x9e37_79b9)));
    // f32 keeps the finest octave's lattice position to 1/500 of a cell 100 m from the origin.
    let (x, y) = (x_m as f32, y_m as f32);
    let mut u = [0.0f32; LANES];
    let mut v = [0.0f32; LANES];
    for k in 0..LANES {
        let (c, s) = ROTATION_OVER_WAVELENGTH[k];
        u[k] = c * x - s * y;
        v[k] = s * x + c * y;
    }
    let n = noise::value_noise_lanes(&seeds, &u, &v);
    // An octave fades out between wavelengths of four and two footprints (Nyquist), keeping its
    // zero mean.
    let inv_two_footprints = if footprint_m > 0.0 { 0.5 / footprint_m } else { f64::INFINITY };
    let mut sum = 0.0f32;
    for k in 0..LANES {
        let weight = ((WAVELENGTHS_M[k] * inv_two_footprints - 1.0) as f32).clamp(0.0, 1.0);
        sum += weight * n[k];
    }
    let texture = 1.0 + config.albedo_contrast * NORMALISATION * sum;
    (mean * texture.max(MIN_FRACTION)).clamp(1e-4, MAX_ALBEDO)
}

/// The material albedo factor, bilinear between the four surrounding cell centres, so that a
/// rock's edge is not a staircase of 5 cm cells.
fn material_factor(terrain: &Terrain, x_m: f64, y_m: f64) -> f32 {
    let hf = &terrain.heightfield;
    let cols = hf.cols;
    if cols < 2 || hf.rows < 2 {
        return 1.0;
    }
    let inv_res = 1.0 / hf.resolution_m;
    let fx = ((x_m - hf.origin_m[0]) * inv_res).clamp(0.0, (cols - 1) as f64);
    let fy = ((y_m - hf.origin_m[1]) * inv_res).clamp(0.0, (hf.rows - 1) as f64);
    if fx.is_nan() || fy.is_nan() {
        return 1.0;
    }
    let c = (fx as usize).min(cols - 2);
    let r = (fy as usize).min(hf.rows - 2);
    let i = r * cols + c;
    let (Some(&[m00, m10]), Some(&[m01, m11])) =
        (terrain.material.get(i..i + 2), terrain.material.get(i + cols..i + cols + 2))
    else {
        return 1.0;
    };
    let config = &terrain.config;
    let factor = |m: u8| match Material::from_u8(m) {
        Material::Regolith => 1.0,
        Material::Rock => config.rock_albedo_factor,
        Material::Ejecta => config.ejecta_albedo_factor,
    };
    // Most of the ground is one material over a whole cell square.
    if m00 == m10 && m00 == m01 && m00 == m11 {
        return factor(m00);
    }
    let (ax, ay) = ((fx - c as f64) as f32, (fy - r as f64) as f32);
    let a = factor(m00) + ax * (factor(m10) - factor(m00));
    let b = factor(m01) + ax * (factor(m11) - factor(m01));
    a + ay * (b - a)
}
