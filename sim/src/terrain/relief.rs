//! The natural relief before craters: fractal undulation and, where configured, wind ripples.

use super::{Heightfield, TerrainConfig};
use crate::noise::{self, Fbm, LANES};

/// Wavelength of the noise that decides where ripple fields lie, and of the one that bends
/// their crests.
const RIPPLE_PATCH_WAVELENGTH_M: f64 = 40.0;
const RIPPLE_WARP_WAVELENGTH_M: f64 = 12.0;

#[derive(Debug, Clone, Copy)]
pub(super) struct Relief {
    fbm: Fbm,
    ripples: Option<Ripples>,
}

#[derive(Debug, Clone, Copy)]
struct Ripples {
    amplitude_m: f64,
    /// Unit vector across the crests divided by the wavelength, times 2π.
    wave_x: f64,
    wave_y: f64,
    /// Threshold on the patch noise above which ripples appear.
    patch_threshold: f64,
    patch_seed: u32,
    warp_seed: u32,
}

impl Relief {
    pub fn new(config: &TerrainConfig, seed: u64) -> Relief {
        let seed = noise::seed32(seed);
        let fbm = Fbm {
            seed,
            base_wavelength_m: config.relief_wavelength_m,
            amplitude_m: config.relief_amplitude_m,
            hurst: config.relief_hurst,
            octaves: Fbm::octaves_down_to(config.relief_wavelength_m, config.relief_min_wavelength_m),
        };
        let ripples = (config.ripple_amplitude_m > 0.0 && config.ripple_coverage > 0.0).then(|| {
            // The prevailing wind is part of the site, so it comes from the seed.
            let azimuth = f64::from(noise::mix32(seed ^ 0x5eed_0001)) / 4_294_967_296.0 * std::f64::consts::PI;
            let k = std::f64::consts::TAU / config.ripple_wavelength_m;
            Ripples {
                amplitude_m: config.ripple_amplitude_m,
                wave_x: k * azimuth.cos(),
                wave_y: k * azimuth.sin(),
                patch_threshold: patch_threshold(config.ripple_coverage),
                patch_seed: noise::mix32(seed ^ 0x5eed_0002),
                warp_seed: noise::mix32(seed ^ 0x5eed_0003),
            }
        });
        Relief { fbm, ripples }
    }

    /// Heights of the rows `first_row..` that `heights` holds (whole rows of `grid`), [`LANES`]
    /// cells at a time (the lanes of a row's last block beyond its end are computed and dropped).
    pub fn fill(&self, grid: &Heightfield, first_row: usize, heights: &mut [f32]) {
        for (i, row) in heights.chunks_mut(grid.cols).enumerate() {
            let y = grid.origin_m[1] + (first_row + i) as f64 * grid.resolution_m;
            for (block, out) in row.chunks_mut(LANES).enumerate() {
                let xs: [f64; LANES] =
                    std::array::from_fn(|k| grid.origin_m[0] + (block * LANES + k) as f64 * grid.resolution_m);
                let mut h = self.fbm.at_lanes(&xs, &[y; LANES]);
                if let Some(r) = &self.ripples {
                    r.add(&xs, y, &mut h);
                }
                out.copy_from_slice(&h[..out.len()]);
            }
        }
    }
}

impl Ripples {
    fn add(&self, xs: &[f64; LANES], y: f64, h: &mut [f32; LANES]) {
        let scaled = |wavelength: f64| -> ([f32; LANES], [f32; LANES]) {
            (std::array::from_fn(|k| (xs[k] / wavelength) as f32), [(y / wavelength) as f32; LANES])
        };
        let (u, v) = scaled(RIPPLE_PATCH_WAVELENGTH_M);
        let patch = noise::value_noise_lanes(&[self.patch_seed; LANES], &u, &v);
        if patch.iter().all(|&p| f64::from(p) <= self.patch_threshold) {
            return;
        }
        let (u, v) = scaled(RIPPLE_WARP_WAVELENGTH_M);
        let warp = noise::value_noise_lanes(&[self.warp_seed; LANES], &u, &v);
        for k in 0..LANES {
            let strength = ((f64::from(patch[k]) - self.patch_threshold) / 0.15).clamp(0.0, 1.0);
            if strength > 0.0 {
                let phase = self.wave_x * xs[k] + self.wave_y * y + 4.0 * f64::from(warp[k]);
                // A second harmonic sharpens the crests and flattens the troughs, as on real ripples.
                let profile = phase.sin() - 0.25 * (2.0 * phase).cos();
                h[k] += (self.amplitude_m * strength * strength * (3.0 - 2.0 * strength) * profile) as f32;
            }
        }
    }
}

/// The patch-noise level exceeded on about `coverage` of the plane. Value noise is roughly
/// normal with standard deviation [`noise::VALUE_NOISE_STD`]; a logistic approximation of the
/// inverse normal is plenty for a coverage knob.
fn patch_threshold(coverage: f64) -> f64 {
    let p = coverage.clamp(0.01, 0.99);
    let z = ((1.0 - p) / p).ln() / 1.702;
    z * noise::VALUE_NOISE_STD
}
