//! Procedural noise for terrain relief and albedo texture (owned by the terrain helper).
//!
//! Every function here is a pure function of a seed and coordinates: lattice values come from a
//! stateless integer hash, so a value is the same wherever, in whatever order and on whichever
//! thread it is evaluated, and the pattern never repeats within any terrain we generate.

use std::f64::consts::FRAC_1_SQRT_2;

/// Wellons' "lowbias32" finaliser: a bijection on `u32` with near-ideal avalanche, two
/// multiplications, cheap enough for per-pixel texture.
#[inline]
pub fn mix32(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^= x >> 15;
    x = x.wrapping_mul(0x846c_a68b);
    x ^= x >> 16;
    x
}

/// Folds a 64-bit seed (e.g. from [`crate::rng::stream_seed`]) into a 32-bit noise seed.
#[inline]
pub fn seed32(seed: u64) -> u32 {
    mix32((seed as u32) ^ mix32((seed >> 32) as u32 ^ 0x2545_f491))
}

/// Hash of the lattice point `(ix, iy)` under `seed`. Coordinates wrap at 2³², far beyond any
/// lattice a terrain uses.
#[inline]
pub fn hash2(seed: u32, ix: i64, iy: i64) -> u32 {
    mix32((ix as u32).wrapping_mul(0x9e37_79b1) ^ (iy as u32).wrapping_mul(0x85eb_ca77) ^ seed)
}

/// `(floor(v), v - floor(v))`, without the libm call `f64::floor` costs on baseline x86-64.
#[inline]
pub fn floor_frac(v: f64) -> (i64, f64) {
    let i = v as i64;
    let i = if (i as f64) > v { i - 1 } else { i };
    (i, v - i as f64)
}

#[inline]
fn smoothstep(t: f64) -> f64 {
    t * t * (3.0 - 2.0 * t)
}

#[inline]
fn quintic(t: f64) -> f64 {
    t * t * t * (t * (t * 6.0 - 15.0) + 10.0)
}

#[inline]
fn signed_unit(h: u32) -> f64 {
    f64::from(h) * (2.0 / 4_294_967_296.0) - 1.0
}

/// Standard deviation of [`value_noise`] averaged over the plane: lattice values are uniform in
/// `[-1, 1]` (variance 1/3), and smoothstep-bilinear weights keep `(∫ s² + (1 − s)² du)² = 0.5518`
/// of it.
pub const VALUE_NOISE_STD: f64 = 0.428_89;

/// Value noise in `[-1, 1]` with unit lattice spacing: uniform lattice values blended with
/// smoothstep weights (C¹). Mean 0, standard deviation [`VALUE_NOISE_STD`].
#[inline]
pub fn value_noise(seed: u32, x: f64, y: f64) -> f64 {
    let (ix, fx) = floor_frac(x);
    let (iy, fy) = floor_frac(y);
    let (sx, sy) = (smoothstep(fx), smoothstep(fy));
    let v00 = signed_unit(hash2(seed, ix, iy));
    let v10 = signed_unit(hash2(seed, ix + 1, iy));
    let v01 = signed_unit(hash2(seed, ix, iy + 1));
    let v11 = signed_unit(hash2(seed, ix + 1, iy + 1));
    let a = v00 + sx * (v10 - v00);
    let b = v01 + sx * (v11 - v01);
    a + sy * (b - a)
}

/// Sixteen unit gradients, evenly spread in angle, so no direction is favoured.
const GRADIENTS: [(f64, f64); 16] = [
    (1.0, 0.0),
    (0.923_879_5, 0.382_683_4),
    (FRAC_1_SQRT_2, FRAC_1_SQRT_2),
    (0.382_683_4, 0.923_879_5),
    (0.0, 1.0),
    (-0.382_683_4, 0.923_879_5),
    (-FRAC_1_SQRT_2, FRAC_1_SQRT_2),
    (-0.923_879_5, 0.382_683_4),
    (-1.0, 0.0),
    (-0.923_879_5, -0.382_683_4),
    (-FRAC_1_SQRT_2, -FRAC_1_SQRT_2),
    (-0.382_683_4, -0.923_879_5),
    (0.0, -1.0),
    (0.382_683_4, -0.923_879_5),
    (FRAC_1_SQRT_2, -FRAC_1_SQRT_2),
    (0.923_879_5, -0.382_683_4),
];

#[inline]
fn grad_dot(seed: u32, ix: i64, iy: i64, dx: f64, dy: f64) -> f64 {
    // The top bits of the hash are the best mixed.
    let (gx, gy) = GRADIENTS[(hash2(seed, ix, iy) >> 28) as usize];
    gx * dx + gy * dy
}

/// Perlin gradient noise with unit lattice spacing and quintic fade (C²): zero at lattice
/// points, mean 0, standard deviation about 0.2, range within ±0.75. Its spectrum peaks near
/// wavelength 1 with little energy far above or below, which makes octave sums well behaved.
#[inline]
pub fn gradient_noise(seed: u32, x: f64, y: f64) -> f64 {
    let (ix, fx) = floor_frac(x);
    let (iy, fy) = floor_frac(y);
    let (sx, sy) = (quintic(fx), quintic(fy));
    let n00 = grad_dot(seed, ix, iy, fx, fy);
    let n10 = grad_dot(seed, ix + 1, iy, fx - 1.0, fy);
    let n01 = grad_dot(seed, ix, iy + 1, fx, fy - 1.0);
    let n11 = grad_dot(seed, ix + 1, iy + 1, fx - 1.0, fy - 1.0);
    let a = n00 + sx * (n10 - n00);
    let b = n01 + sx * (n11 - n01);
    a + sy * (b - a)
}

/// Exact rotations (Pythagorean triples `(cos, sin)`) applied per octave, so the lattices of
/// successive octaves are not aligned and no grid direction shows in the sum.
pub const OCTAVE_ROTATIONS: [(f64, f64); 16] = [
    (1.0, 0.0),
    (0.6, 0.8),
    (5.0 / 13.0, -12.0 / 13.0),
    (-8.0 / 17.0, 15.0 / 17.0),
    (24.0 / 25.0, 7.0 / 25.0),
    (-20.0 / 29.0, -21.0 / 29.0),
    (12.0 / 37.0, 35.0 / 37.0),
    (40.0 / 41.0, -9.0 / 41.0),
    (-28.0 / 53.0, 45.0 / 53.0),
    (11.0 / 61.0, -60.0 / 61.0),
    (-33.0 / 65.0, -56.0 / 65.0),
    (48.0 / 73.0, 55.0 / 73.0),
    (-84.0 / 85.0, 13.0 / 85.0),
    (36.0 / 85.0, -77.0 / 85.0),
    (-39.0 / 89.0, -80.0 / 89.0),
    (65.0 / 97.0, 72.0 / 97.0),
];

/// Fractional Brownian motion from [`gradient_noise_lanes`]: octave `k` has wavelength
/// `base_wavelength_m / 2^k` and amplitude `amplitude_m · 2^(−k · hurst)`, each rotated by
/// [`OCTAVE_ROTATIONS`] and keyed by its own seed. A Hurst exponent near 1 keeps the slope
/// contribution of every octave about equal.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fbm {
    pub seed: u32,
    pub base_wavelength_m: f64,
    pub amplitude_m: f64,
    pub hurst: f64,
    /// At most [`OCTAVE_ROTATIONS`]`.len()`.
    pub octaves: usize,
}

impl Fbm {
    /// The number of octaves from `base_wavelength_m` down to `min_wavelength_m`.
    pub fn octaves_down_to(base_wavelength_m: f64, min_wavelength_m: f64) -> usize {
        if !(base_wavelength_m > 0.0 && min_wavelength_m > 0.0) || min_wavelength_m > base_wavelength_m {
            return 1;
        }
        ((base_wavelength_m / min_wavelength_m).log2().floor() as usize + 1).min(OCTAVE_ROTATIONS.len())
    }

    /// The sum at [`LANES`] points `(x[k], y[k])`, with [`gradient_noise_lanes`]: what terrain
    /// generation uses. Each lane's result depends on its own point only.
    #[inline]
    pub fn at_lanes(&self, x_m: &[f64; LANES], y_m: &[f64; LANES]) -> [f32; LANES] {
        let mut sum = [0.0f32; LANES];
        let mut inv_wavelength = 1.0 / self.base_wavelength_m;
        let mut amplitude = self.amplitude_m;
        let gain = (-self.hurst * std::f64::consts::LN_2).exp();
        for (k, &(c, s)) in OCTAVE_ROTATIONS.iter().enumerate().take(self.octaves) {
            let (mut u, mut v) = ([0.0f32; LANES], [0.0f32; LANES]);
            for lane in 0..LANES {
                u[lane] = ((c * x_m[lane] - s * y_m[lane]) * inv_wavelength) as f32;
                v[lane] = ((s * x_m[lane] + c * y_m[lane]) * inv_wavelength) as f32;
            }
            let seeds = [self.seed.wrapping_add((k as u32).wrapping_mul(0x632b_e5ab)); LANES];
            let n = gradient_noise_lanes(&seeds, &u, &v);
            for lane in 0..LANES {
                sum[lane] += amplitude as f32 * n[lane];
            }
            inv_wavelength *= 2.0;
            amplitude *= gain;
        }
        sum
    }
}

/// Points evaluated together by the lane functions: written as plain loops over arrays of this
/// length, they compile to SIMD on any target without `unsafe` or target features.
pub const LANES: usize = 8;

/// A cheaper finaliser than [`mix32`] (one multiplication) for per-pixel texture: its upper
/// bits, the ones [`value_noise_lanes`] uses, are well mixed.
#[inline(always)]
fn mix32_fast(mut x: u32) -> u32 {
    x ^= x >> 16;
    x = x.wrapping_mul(0x7feb_352d);
    x ^ (x >> 15)
}

/// 1.5 · 2²³: adding it to an f32 below 2²² in magnitude rounds to an integer, which then sits
/// in the low mantissa bits.
const ROUNDING_MAGIC: f32 = 12_582_912.0;

/// `(floor(u), u − floor(u))` for one lane, for `|u| < 2²²`. Float adds, a compare and a bit
/// cast: unlike `as i32`, which saturates and is scalar code on x86-64, this vectorises.
#[inline(always)]
fn floor_lane(u: f32) -> (i32, f32) {
    let nearest = (u + ROUNDING_MAGIC) - ROUNDING_MAGIC;
    let floor = if nearest > u { nearest - 1.0 } else { nearest };
    let i = (floor + ROUNDING_MAGIC).to_bits() as i32 - ROUNDING_MAGIC.to_bits() as i32;
    (i, u - floor)
}

/// The lattice hash inputs of a cell's four corners: `(a, a + P₁)` along x, `(b, b')` along y.
#[inline(always)]
fn corner_keys(seed: u32, iu: i32, iv: i32) -> (u32, u32, u32, u32) {
    let a = (iu as u32).wrapping_mul(0x9e37_79b1);
    let b = (iv as u32).wrapping_mul(0x85eb_ca77);
    (a, a.wrapping_add(0x9e37_79b1), b ^ seed, b.wrapping_add(0x85eb_ca77) ^ seed)
}

/// One lane of [`value_noise_lanes`] and [`value_noise_n`].
#[inline(always)]
fn value_noise_lane(seed: u32, u: f32, v: f32) -> f32 {
    let (iu, fx) = floor_lane(u);
    let (iv, fy) = floor_lane(v);
    let sx = fx * fx * (3.0 - 2.0 * fx);
    let sy = fy * fy * (3.0 - 2.0 * fy);
    let (a0, a1, b0, b1) = corner_keys(seed, iu, iv);
    // The top 24 bits as a signed integer: exact in f32, and the best mixed bits.
    let value = |h: u32| (mix32_fast(h) >> 8) as i32 as f32;
    let (v00, v10, v01, v11) = (value(a0 ^ b0), value(a1 ^ b0), value(a0 ^ b1), value(a1 ^ b1));
    let p = v00 + sx * (v10 - v00);
    let q = v01 + sx * (v11 - v01);
    (p + sy * (q - p)) * (2.0 / 16_777_216.0) - 1.0
}

/// [`value_noise`]'s lane-parallel f32 sibling (its own lattice values, same statistics: mean 0,
/// standard deviation [`VALUE_NOISE_STD`], range `[-1, 1]`), each lane with its own seed and
/// coordinates. Coordinates must stay within ±2²² lattice cells.
#[inline]
pub fn value_noise_lanes(seeds: &[u32; LANES], u: &[f32; LANES], v: &[f32; LANES]) -> [f32; LANES] {
    let mut out = [0.0f32; LANES];
    for k in 0..LANES {
        out[k] = value_noise_lane(seeds[k], u[k], v[k]);
    }
    out
}

/// [`value_noise_lanes`] with one seed for any number of lanes: lane `k` is bit for bit
/// `value_noise_lanes(&[seed; LANES], ..)` at `(u[k], v[k])`, whatever `N` (1 for a single
/// point, a multiple of four to fill SIMD registers).
#[inline(always)]
pub fn value_noise_n<const N: usize>(seed: u32, u: &[f32; N], v: &[f32; N]) -> [f32; N] {
    let mut out = [0.0f32; N];
    for k in 0..N {
        out[k] = value_noise_lane(seed, u[k], v[k]);
    }
    out
}

/// Gradient noise, lane-parallel in f32: like [`gradient_noise`] (zero on the lattice, quintic
/// fade) but with gradients drawn uniformly from the square `[-1, 1]²`, which needs no table
/// lookup; standard deviation about 0.18 (see the tests), range within ±1.
#[inline]
pub fn gradient_noise_lanes(seeds: &[u32; LANES], u: &[f32; LANES], v: &[f32; LANES]) -> [f32; LANES] {
    let mut out = [0.0f32; LANES];
    for k in 0..LANES {
        let (iu, fx) = floor_lane(u[k]);
        let (iv, fy) = floor_lane(v[k]);
        let sx = fx * fx * fx * (fx * (fx * 6.0 - 15.0) + 10.0);
        let sy = fy * fy * fy * (fy * (fy * 6.0 - 15.0) + 10.0);
        let (a0, a1, b0, b1) = corner_keys(seeds[k], iu, iv);
        let dot = |h: u32, dx: f32, dy: f32| {
            let h = mix32(h);
            let gx = (h >> 16) as u16 as i16 as f32;
            let gy = h as u16 as i16 as f32;
            (gx * dx + gy * dy) * (1.0 / 32_768.0)
        };
        let n00 = dot(a0 ^ b0, fx, fy);
        let n10 = dot(a1 ^ b0, fx - 1.0, fy);
        let n01 = dot(a0 ^ b1, fx, fy - 1.0);
        let n11 = dot(a1 ^ b1, fx - 1.0, fy - 1.0);
        let p = n00 + sx * (n10 - n00);
        let q = n01 + sx * (n11 - n01);
        out[k] = p + sy * (q - p);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn stats(values: &[f64]) -> (f64, f64) {
        let n = values.len() as f64;
        let mean = values.iter().sum::<f64>() / n;
        let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n;
        (mean, var.sqrt())
    }

    #[test]
    fn value_noise_has_the_documented_moments() {
        // 200 × 200 lattice cells, 16 samples each: the standard error of the mean of 40 000
        // independent cells is about 0.43 / 200 ≈ 0.002.
        let values: Vec<f64> = (0..640_000)
            .map(|i| value_noise(7, (i % 800) as f64 * 0.25 + 0.1, (i / 800) as f64 * 0.25 + 0.1))
            .collect();
        let (mean, std) = stats(&values);
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((std - VALUE_NOISE_STD).abs() < 0.01, "std {std}");
        assert!(values.iter().all(|v| (-1.0..=1.0).contains(v)));
    }

    #[test]
    fn gradient_noise_vanishes_on_the_lattice_and_is_continuous() {
        for i in -5..5 {
            for j in -5..5 {
                assert_eq!(gradient_noise(3, f64::from(i), f64::from(j)), 0.0);
            }
        }
        // Continuity across a lattice line: the two sides agree to first order in the step.
        let eps = 1e-7;
        for k in 0..100 {
            let y = k as f64 * 0.137;
            let a = gradient_noise(3, 4.0 - eps, y);
            let b = gradient_noise(3, 4.0 + eps, y);
            assert!((a - b).abs() < 1e-6, "{a} vs {b}");
        }
        let values: Vec<f64> =
            (0..250_000).map(|i| gradient_noise(11, (i % 500) as f64 * 0.31, (i / 500) as f64 * 0.31)).collect();
        let (mean, std) = stats(&values);
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((0.15..0.25).contains(&std), "std {std}");
        assert!(values.iter().all(|v| v.abs() < 0.75));
    }

    #[test]
    fn seeds_give_unrelated_fields() {
        let a: Vec<f64> = (0..10_000).map(|i| value_noise(1, (i % 100) as f64 * 0.7, (i / 100) as f64 * 0.7)).collect();
        let b: Vec<f64> = (0..10_000).map(|i| value_noise(2, (i % 100) as f64 * 0.7, (i / 100) as f64 * 0.7)).collect();
        let (_, sa) = stats(&a);
        let (_, sb) = stats(&b);
        let corr = a.iter().zip(&b).map(|(x, y)| x * y).sum::<f64>() / (a.len() as f64 * sa * sb);
        // About 5 standard errors of a correlation of 10 000 samples of a field correlated over
        // a couple of samples.
        assert!(corr.abs() < 0.08, "correlation {corr}");
    }

    /// 800 × 500 samples `step` apart from the lattice point (−37, 11).
    type LaneNoise = fn(&[u32; LANES], &[f32; LANES], &[f32; LANES]) -> [f32; LANES];

    fn lane_field(f: LaneNoise, step: f32) -> Vec<f64> {
        let mut out = Vec::new();
        for j in 0..500 {
            for i in (0..800).step_by(LANES) {
                let u: [f32; LANES] = std::array::from_fn(|k| (i + k) as f32 * step - 37.0);
                let v = [j as f32 * step + 11.0; LANES];
                out.extend(f(&[9; LANES], &u, &v).iter().map(|&x| f64::from(x)));
            }
        }
        out
    }

    #[test]
    fn lane_value_noise_has_the_documented_moments_and_no_lattice_correlation() {
        let values = lane_field(value_noise_lanes, 0.25);
        let (mean, std) = stats(&values);
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((std - VALUE_NOISE_STD).abs() < 0.01, "std {std}");
        assert!(values.iter().all(|v| (-1.0..=1.0).contains(v)));
        // Lattice values (every fourth sample) one cell apart along x, along y and diagonally are
        // uncorrelated: a weak hash would show structure here. 5 standard errors of 25 000 pairs.
        let at = |i: usize, j: usize| values[j * 800 + i];
        for (di, dj) in [(4, 0), (0, 4), (4, 4)] {
            let (mut sxy, mut n) = (0.0, 0.0);
            for j in (0..496).step_by(4) {
                for i in (0..796).step_by(4) {
                    sxy += at(i, j) * at(i + di, j + dj);
                    n += 1.0;
                }
            }
            let corr = sxy / n / (1.0 / 3.0);
            assert!(corr.abs() < 5.0 / n.sqrt(), "lag ({di}, {dj}): correlation {corr}");
        }
    }

    #[test]
    fn lane_gradient_noise_vanishes_on_the_lattice_and_has_moments() {
        let on_lattice = gradient_noise_lanes(&[4; LANES], &std::array::from_fn(|k| k as f32 - 3.0), &[7.0; LANES]);
        assert!(on_lattice.iter().all(|&v| v == 0.0));
        let values = lane_field(gradient_noise_lanes, 0.31);
        let (mean, std) = stats(&values);
        assert!(mean.abs() < 0.01, "mean {mean}");
        assert!((0.14..0.22).contains(&std), "std {std}");
        assert!(values.iter().all(|v| v.abs() <= 1.0));
    }

    #[test]
    fn lane_noises_are_continuous_across_lattice_lines() {
        // Both sides of the lines u = 4 and v = 7 (f32 steps of 1e-3 cells): a lattice key
        // that differed between neighbouring cells would jump here.
        for f in [value_noise_lanes, gradient_noise_lanes] {
            for seed in [0, 1, 0xdead_beef] {
                let along: [f32; LANES] = std::array::from_fn(|k| k as f32 * 0.61 - 2.3);
                let jump_u = |d: f32| f(&[seed; LANES], &[4.0 + d; LANES], &along);
                let jump_v = |d: f32| f(&[seed; LANES], &along, &[7.0 + d; LANES]);
                for (a, b) in [(jump_u(-1e-3), jump_u(1e-3)), (jump_v(-1e-3), jump_v(1e-3))] {
                    for k in 0..LANES {
                        // The slope of either noise is below 4 per cell.
                        assert!((a[k] - b[k]).abs() < 8e-3, "seed {seed}, lane {k}: {} vs {}", a[k], b[k]);
                    }
                }
            }
        }
    }

    #[test]
    fn lane_floor_is_floor() {
        for u in [-4_000_000.5f32, -3.0, -2.5, -1e-7, 0.0, 1e-7, 0.5, 0.999_999_9, 1.0, 2.5, 3.5, 4_194_303.5] {
            let (i, f) = floor_lane(u);
            assert_eq!(i as f32, u.floor(), "{u}");
            // Just below an integer the fraction may round up to 1, which is harmless: both
            // cells agree on the shared edge.
            assert!(
                (0.0..=1.0).contains(&f) && (i as f32 + f - u).abs() <= f32::EPSILON * u.abs().max(1.0),
                "{u}: {i} + {f}"
            );
        }
    }

    #[test]
    fn lanes_are_independent() {
        let f = Fbm { seed: 5, base_wavelength_m: 16.0, amplitude_m: 1.0, hurst: 0.9, octaves: 6 };
        let xs: [f64; LANES] = std::array::from_fn(|k| k as f64 * 0.37 - 1.0);
        let ys: [f64; LANES] = std::array::from_fn(|k| 2.0 - k as f64 * 0.11);
        let all = f.at_lanes(&xs, &ys);
        for k in 0..LANES {
            let alone = f.at_lanes(&[xs[k]; LANES], &[ys[k]; LANES]);
            assert_eq!(alone[0].to_bits(), all[k].to_bits());
        }
    }

    #[test]
    fn octave_rotations_are_rotations() {
        for (c, s) in OCTAVE_ROTATIONS {
            assert!((c * c + s * s - 1.0).abs() < 1e-12);
        }
        assert_eq!(Fbm::octaves_down_to(64.0, 0.2), 9);
    }
}
