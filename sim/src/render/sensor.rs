//! Image formation: exposure gain, shot and read noise, quantisation to 8 bits.
//!
//! The noise of a pixel is a pure function of the frame's noise seed, the camera and the pixel
//! index (a counter-based hash), so it does not depend on the order pixels are evaluated in.

use super::SensorModel;
use crate::rng::{stream_seed, streams};

/// Splitmix64's finaliser: a bijection on `u64` with full avalanche.
#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Key of the noise of camera `camera` (0 left, 1 right) for a frame's `noise_seed`.
pub(crate) fn noise_key(noise_seed: u64, camera: u64) -> u64 {
    stream_seed(noise_seed, &[streams::IMAGE_NOISE, camera])
}

/// Standard normal deviates for the pixel pair `2·pair, 2·pair + 1`: each the sum of four 8-bit
/// uniforms of one 64-bit hash, scaled to unit variance (Irwin–Hall, n = 4). Their quantiles are
/// within 0.05 σ of the normal's up to 2.5 σ and they are bounded at ±3.46 σ, which for image
/// noise is indistinguishable, at a fraction of the cost of a logarithm and a cosine per pixel.
#[inline]
fn gaussian_pair(key: u64, pair: u64) -> [f32; 2] {
    let h = mix64(key ^ pair.wrapping_mul(0x9E37_79B9_7F4A_7C15));
    // Bytes summed in parallel: 16-bit lanes of byte pairs, then 32-bit lanes of four bytes.
    let pairs = (h & 0x00FF_00FF_00FF_00FF) + ((h >> 8) & 0x00FF_00FF_00FF_00FF);
    let quads = (pairs & 0x0000_FFFF_0000_FFFF) + ((pairs >> 16) & 0x0000_FFFF_0000_FFFF);
    // Each 8-bit value is read as the centre of its bin, so a sum has mean exactly 2.
    let deviate = |sum: u64| ((sum as f32 + 2.0) * (1.0 / 256.0) - 2.0) * 3.0_f32.sqrt();
    [deviate(quads & 0xFFFF_FFFF), deviate(quads >> 32)]
}

/// The standard normal deviate of pixel `index` (see [`gaussian_pair`]).
#[inline]
pub(crate) fn gaussian(key: u64, index: u64) -> f32 {
    gaussian_pair(key, index / 2)[(index % 2) as usize]
}

/// Rounds and clamps a grey value (`as` saturates to 0..=255; no libm call for the rounding).
#[inline]
fn to_u8(dn: f32) -> u8 {
    (dn + 0.5) as u8
}

/// Gain (digital numbers per unit radiance) that brings the mean of `radiance` to the target.
pub(crate) fn exposure_gain(sensor: &SensorModel, radiance: &[f32]) -> f32 {
    let sum: f64 = radiance.iter().map(|&l| f64::from(l)).sum();
    let mean = sum / radiance.len().max(1) as f64;
    // A black frame stays black whatever the gain.
    if mean > 0.0 { (f64::from(sensor.target_mean_dn) / mean) as f32 } else { 1.0 }
}

/// Converts radiance to 8-bit grey values with `gain`, adding noise if the model asks for it.
/// `deviates` is scratch of the image's size (the noise is drawn first, then applied in a loop
/// the compiler vectorises).
pub(crate) fn expose(
    sensor: &SensorModel,
    radiance: &[f32],
    gain: f32,
    key: u64,
    out: &mut [u8],
    deviates: &mut [f32],
) {
    let n = out.len().min(radiance.len());
    let (out, radiance) = (&mut out[..n], &radiance[..n]);
    if !sensor.noise {
        for (o, &l) in out.iter_mut().zip(radiance) {
            *o = to_u8(gain * l);
        }
        return;
    }
    if deviates.len() < n {
        // Without scratch (never in the renderer): pixel by pixel.
        noisy(sensor, radiance, gain, key, out);
        return;
    }
    let deviates = &mut deviates[..n];
    for (pair, d) in (0u64..).zip(deviates.chunks_exact_mut(2)) {
        d.copy_from_slice(&gaussian_pair(key, pair));
    }
    if n % 2 == 1 {
        deviates[n - 1] = gaussian(key, n as u64 - 1);
    }
    let (shot, read_var) = noise_variances(sensor);
    for ((o, &l), &g) in out.iter_mut().zip(radiance).zip(deviates.iter()) {
        let dn = gain * l;
        *o = to_u8(dn + (dn.max(0.0) * shot + read_var).sqrt() * g);
    }
}

/// Shot noise: a signal of `dn` grey values is dn · full_well / 255 electrons, whose Poisson
/// variance is that many electrons, i.e. dn · 255 / full_well in grey values squared; read noise
/// adds its own. Returns (variance per grey value, read variance).
fn noise_variances(sensor: &SensorModel) -> (f32, f32) {
    let shot = if sensor.full_well_e > 0.0 { 255.0 / sensor.full_well_e } else { 0.0 };
    (shot, sensor.read_noise_dn * sensor.read_noise_dn)
}

/// [`expose`] with noise, pixel by pixel (same values).
fn noisy(sensor: &SensorModel, radiance: &[f32], gain: f32, key: u64, out: &mut [u8]) {
    let (shot, read_var) = noise_variances(sensor);
    for (i, (o, &l)) in out.iter_mut().zip(radiance).enumerate() {
        let dn = gain * l;
        *o = to_u8(dn + (dn.max(0.0) * shot + read_var).sqrt() * gaussian(key, i as u64));
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn deviates_have_unit_variance_and_are_independent_of_order() {
        let n = 200_000u64;
        let draws: Vec<f64> = (0..n).map(|i| f64::from(gaussian(77, i))).collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        // Five standard errors of the sample mean and variance.
        assert!(mean.abs() < 5.0 / (n as f64).sqrt(), "mean {mean}");
        assert!((var - 1.0).abs() < 5.0 * (2.0 / n as f64).sqrt(), "variance {var}");
        // Neighbouring pixels are uncorrelated (lag-1 correlation within 5 standard errors).
        let lag: f64 = draws.windows(2).map(|w| (w[0] - mean) * (w[1] - mean)).sum::<f64>() / (n - 1) as f64;
        assert!((lag / var).abs() < 5.0 / (n as f64).sqrt(), "lag-1 correlation {}", lag / var);
        assert_eq!(gaussian(77, 12_345), gaussian(77, 12_345));
        assert_ne!(gaussian(77, 12_345), gaussian(78, 12_345));
    }

    #[test]
    fn noise_has_the_shot_and_read_variance_of_the_model() {
        let sensor = SensorModel { target_mean_dn: 100.0, full_well_e: 5_000.0, read_noise_dn: 2.0, noise: true };
        let radiance = vec![0.5_f32; 100_000];
        let gain = exposure_gain(&sensor, &radiance);
        assert!((gain - 200.0).abs() < 1e-3);
        let mut out = vec![0u8; radiance.len()];
        let mut scratch = vec![0.0; radiance.len()];
        expose(&sensor, &radiance, gain, noise_key(3, 0), &mut out, &mut scratch);
        // Without scratch, pixel by pixel: the same image.
        let mut again = vec![0u8; radiance.len()];
        expose(&sensor, &radiance, gain, noise_key(3, 0), &mut again, &mut []);
        assert_eq!(out, again);
        let mean = out.iter().map(|&v| f64::from(v)).sum::<f64>() / out.len() as f64;
        let var = out.iter().map(|&v| (f64::from(v) - mean).powi(2)).sum::<f64>() / (out.len() - 1) as f64;
        // 100 · 255 / 5000 + 2² = 9.1 DN², plus 1/12 DN² of rounding.
        let expected = 100.0 * 255.0 / 5_000.0 + 4.0 + 1.0 / 12.0;
        assert!((mean - 100.0).abs() < 0.05, "mean {mean}");
        assert!((var - expected).abs() < 0.03 * expected, "variance {var}, expected {expected}");
    }
}
