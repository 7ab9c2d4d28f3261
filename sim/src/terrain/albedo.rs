//! The albedo texture: the material's mean albedo times value noise octaves from 4 m down to
//! 1.8 mm, so that stereo finds texture at 1 m range (1.4 mm pixels) and at 30 m (3 cm pixels)
//! alike.
//!
//! The texture is the product of two factors, for speed (evaluating all octaves everywhere cost
//! 55 ns a lookup, half of a frame's time):
//!
//! - the **base**: material mean × the four coarse octaves (4 m to 15 cm), sampled at the cell
//!   centres when the terrain is generated and kept with box-filtered coarser levels
//!   ([`super::albedo_base`]); read bilinearly, from the level that fits the footprint;
//! - the **detail**: the four fine octaves (5 cm to 1.8 mm) evaluated where asked, each only
//!   where the footprint keeps it (it fades out between wavelengths of four and two footprints).
//!
//! Far pixels cost a grid lookup, near ones that and two or three octaves of value noise. Each
//! factor is floored at √0.2, so the texture never goes below a fifth of the mean. Lookups run
//! in chunks of neighbouring points (an image row), eight at a time in SIMD lanes.

use super::Terrain;
use super::bilinear::CHUNK;
use crate::noise::{self, OCTAVE_ROTATIONS, VALUE_NOISE_STD};
use crate::rng::{self, streams};

/// Octaves in all; the first [`BASE_OCTAVES`] are baked into the base.
const OCTAVES: usize = 8;
/// Coarse octaves baked per cell: the finest of them (15 cm) has three cell centres per
/// wavelength, enough for bilinear interpolation to keep its shape.
const BASE_OCTAVES: usize = 4;
const DETAIL_OCTAVES: usize = OCTAVES - BASE_OCTAVES;

/// Coarsest texture wavelength; each octave is three times finer: lacunarity 3 spans 4 m to
/// 1.8 mm in eight octaves.
const COARSEST_WAVELENGTH_M: f64 = 4.0;
const WAVELENGTHS_M: [f64; OCTAVES] = {
    let mut w = [COARSEST_WAVELENGTH_M; OCTAVES];
    let mut k = 1;
    while k < OCTAVES {
        w[k] = w[k - 1] / 3.0;
        k += 1;
    }
    w
};
/// Per octave: rotation `(cos, sin)` over the wavelength, so each octave's lattice is turned
/// differently and no grid direction shows in the sum.
const ROTATION_OVER_WAVELENGTH: [(f32, f32); OCTAVES] = {
    let mut r = [(0.0, 0.0); OCTAVES];
    let mut k = 0;
    while k < OCTAVES {
        let (c, s) = OCTAVE_ROTATIONS[k + 1];
        r[k] = ((c / WAVELENGTHS_M[k]) as f32, (s / WAVELENGTHS_M[k]) as f32);
        k += 1;
    }
    r
};
/// The detail octaves' wavelengths, halved: an octave fades out between wavelengths of four and
/// two footprints (Nyquist), i.e. it is dropped where `footprint ≥ λ / 2`.
const DETAIL_HALF_WAVELENGTHS_M: [f32; DETAIL_OCTAVES] = {
    let mut h = [0.0; DETAIL_OCTAVES];
    let mut k = 0;
    while k < DETAIL_OCTAVES {
        h[k] = (0.5 * WAVELENGTHS_M[BASE_OCTAVES + k]) as f32;
        k += 1;
    }
    h
};
/// Equal-variance octaves summed and scaled to unit standard deviation (√8 octaves).
const NORMALISATION: f32 = (1.0 / (VALUE_NOISE_STD * 2.828_427_124_746_19)) as f32;
/// Neither factor darkens a surface below √0.2 of its mean, so the texture never goes below a
/// fifth of it.
const FACTOR_FLOOR: f32 = 0.447_213_6;
const MIN_ALBEDO: f32 = 1e-4;
const MAX_ALBEDO: f32 = 0.98;

/// Lattice seeds of the octaves of a terrain seed's texture.
pub(super) fn octave_seeds(terrain_seed: u64) -> [u32; OCTAVES] {
    let base_seed = noise::seed32(rng::stream_seed(terrain_seed, &[streams::ALBEDO]));
    std::array::from_fn(|k| base_seed.wrapping_add((k as u32).wrapping_mul(0x9e37_79b9)))
}

/// Sum of the base octaves at `N` points (each of standard deviation [`VALUE_NOISE_STD`]): what
/// the base bakes per cell centre.
#[inline]
pub(super) fn base_octaves<const N: usize>(seeds: &[u32; OCTAVES], x_m: &[f32; N], y_m: &[f32; N]) -> [f32; N] {
    let mut sum = [0.0f32; N];
    for (k, &seed) in seeds.iter().enumerate().take(BASE_OCTAVES) {
        let (u, v) = rotate(k, x_m, y_m);
        let n = noise::value_noise_n(seed, &u, &v);
        for i in 0..N {
            sum[i] += n[i];
        }
    }
    sum
}

/// The base's texture factor for a sum of base octaves and a contrast.
#[inline]
pub(super) fn base_factor(octave_sum: f32, contrast: f32) -> f32 {
    (1.0 + contrast * NORMALISATION * octave_sum).max(FACTOR_FLOOR)
}

#[inline(always)]
fn rotate<const N: usize>(k: usize, x_m: &[f32; N], y_m: &[f32; N]) -> ([f32; N], [f32; N]) {
    let (c, s) = ROTATION_OVER_WAVELENGTH[k];
    let (mut u, mut v) = ([0.0f32; N], [0.0f32; N]);
    for i in 0..N {
        u[i] = c * x_m[i] - s * y_m[i];
        v[i] = s * x_m[i] + c * y_m[i];
    }
    (u, v)
}

/// The detail factor at `N` points with their footprints. Octaves that no lane keeps are not
/// evaluated; that changes no lane's value (their weight is exactly 0 there), so a point's
/// albedo does not depend on its neighbours in a batch.
#[inline(always)]
fn detail_factor<const N: usize>(
    seeds: &[u32; OCTAVES],
    contrast: f32,
    x_m: &[f64; N],
    y_m: &[f64; N],
    footprint_m: &[f32; N],
) -> [f32; N] {
    // f32 keeps the finest octave's lattice position to 1/250 of a cell 100 m from the origin.
    let (mut x, mut y) = ([0.0f32; N], [0.0f32; N]);
    let mut inv_footprint = [0.0f32; N];
    let mut max_inv_footprint = 0.0f32;
    for i in 0..N {
        (x[i], y[i]) = (x_m[i] as f32, y_m[i] as f32);
        // A zero or negative footprint keeps every octave (infinite inverse); NaN keeps none.
        inv_footprint[i] = if footprint_m[i] > 0.0 { 1.0 / footprint_m[i] } else { f32::INFINITY };
        if footprint_m[i].is_nan() {
            inv_footprint[i] = 0.0;
        }
        max_inv_footprint = max_inv_footprint.max(inv_footprint[i]);
    }
    let mut sum = [0.0f32; N];
    for (j, &half_wavelength) in DETAIL_HALF_WAVELENGTHS_M.iter().enumerate() {
        // Weights fall with the wavelength: once no lane keeps an octave, none keeps a finer one.
        if half_wavelength * max_inv_footprint - 1.0 <= 0.0 {
            break;
        }
        let k = BASE_OCTAVES + j;
        let (u, v) = rotate(k, &x, &y);
        let n = noise::value_noise_n(seeds[k], &u, &v);
        for i in 0..N {
            let weight = (half_wavelength * inv_footprint[i] - 1.0).clamp(0.0, 1.0);
            sum[i] += weight * n[i];
        }
    }
    let mut factor = [0.0f32; N];
    for i in 0..N {
        factor[i] = (1.0 + contrast * NORMALISATION * sum[i]).max(FACTOR_FLOOR);
    }
    factor
}

/// One point: a batch of one, so bit for bit what [`filtered_many`] gives it.
pub(super) fn filtered(terrain: &Terrain, x_m: f64, y_m: f64, footprint_m: f64) -> f32 {
    let mut out = [0.0];
    filtered_many(terrain, &[x_m], &[y_m], &[footprint_m as f32], &mut out);
    out[0]
}

/// Points per detail batch: two SSE registers of f32.
const BATCH: usize = 8;

/// Albedo at many points: base lookups chunk by chunk, the detail of eight points at a time.
pub(super) fn filtered_many(terrain: &Terrain, x_m: &[f64], y_m: &[f64], footprint_m: &[f32], out: &mut [f32]) {
    let n = out.len().min(x_m.len()).min(y_m.len()).min(footprint_m.len());
    let base = terrain.albedo_base.levels(terrain);
    let seeds = octave_seeds(terrain.seed);
    let contrast = terrain.config.albedo_contrast;
    for start in (0..n).step_by(CHUNK) {
        let end = (start + CHUNK).min(n);
        let (x, y, f, out) = (&x_m[start..end], &y_m[start..end], &footprint_m[start..end], &mut out[start..end]);
        base.sample_many(x, y, f, out);
        let full = out.len() / BATCH * BATCH;
        for (((x, y), f), o) in x[..full]
            .chunks_exact(BATCH)
            .zip(y[..full].chunks_exact(BATCH))
            .zip(f[..full].chunks_exact(BATCH))
            .zip(out[..full].chunks_exact_mut(BATCH))
        {
            let (Ok(x), Ok(y), Ok(f)) =
                (<&[f64; BATCH]>::try_from(x), <&[f64; BATCH]>::try_from(y), <&[f32; BATCH]>::try_from(f))
            else {
                continue;
            };
            let detail = detail_factor(&seeds, contrast, x, y, f);
            for k in 0..BATCH {
                o[k] = (o[k] * detail[k]).clamp(MIN_ALBEDO, MAX_ALBEDO);
            }
        }
        for i in full..out.len() {
            let detail = detail_factor::<1>(&seeds, contrast, &[x[i]], &[y[i]], &[f[i]]);
            out[i] = (out[i] * detail[0]).clamp(MIN_ALBEDO, MAX_ALBEDO);
        }
    }
}
