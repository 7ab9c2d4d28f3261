//! Deterministic random numbers keyed by purpose, so every stream of a run is reproducible on its
//! own: the noise of robot 2's IMU does not change when robot 1 renders one more frame.
//!
//! Generators are `hal`'s xoshiro256** (implemented there, never changed by a crate upgrade),
//! seeded by [`stream_seed`] from the scenario seed and a path of integers naming the stream.

pub use hal::emulator::Xoshiro256StarStar;

/// Named streams (first element of a [`stream_seed`] path).
pub mod streams {
    pub const TERRAIN: u64 = 1;
    pub const ROCKS: u64 = 2;
    pub const CRATERS: u64 = 3;
    pub const DITCHES: u64 = 4;
    pub const ALBEDO: u64 = 5;
    pub const IMU: u64 = 10;
    pub const WHEEL: u64 = 11;
    pub const IMAGE_NOISE: u64 = 12;
    pub const PATHS: u64 = 13;
    pub const RADIO: u64 = 14;
    pub const TRUTH_CONSTRAINTS: u64 = 15;
}

/// Mixes a seed with a path of integers into a new seed (SplitMix64 finaliser per element).
pub fn stream_seed(seed: u64, path: &[u64]) -> u64 {
    let mut h = mix(seed ^ 0x5157_4D5F_5345_4544);
    for &p in path {
        h = mix(h ^ mix(p.wrapping_add(0x9E37_79B9_7F4A_7C15)));
    }
    h
}

/// A generator for the stream `path` of `seed`.
pub fn stream(seed: u64, path: &[u64]) -> Rng {
    Rng::new(stream_seed(seed, path))
}

fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A stateless hash of integer coordinates to `[0, 1)`, for procedural textures and noise that
/// must give the same value wherever and in whatever order they are evaluated.
#[inline]
pub fn hash_unit(seed: u64, x: i64, y: i64) -> f64 {
    let h = mix(
        seed ^ mix((x as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ (y as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F))
    );
    (h >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// Uniform and Gaussian draws on top of xoshiro256**.
#[derive(Debug, Clone)]
pub struct Rng {
    inner: Xoshiro256StarStar,
    spare_normal: Option<f64>,
}

impl Rng {
    pub fn new(seed: u64) -> Self {
        Rng { inner: Xoshiro256StarStar::seed_from_u64(seed), spare_normal: None }
    }

    pub fn next_u64(&mut self) -> u64 {
        self.inner.next_u64()
    }

    /// Uniform in `[0, 1)`.
    pub fn uniform(&mut self) -> f64 {
        self.inner.next_f64()
    }

    /// Uniform in `[lo, hi)`.
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }

    /// Standard normal (Marsaglia's polar method; the second value is kept for the next call).
    pub fn normal(&mut self) -> f64 {
        if let Some(z) = self.spare_normal.take() {
            return z;
        }
        loop {
            let u = 2.0 * self.uniform() - 1.0;
            let v = 2.0 * self.uniform() - 1.0;
            let s = u * u + v * v;
            if s > 0.0 && s < 1.0 {
                let k = (-2.0 * s.ln() / s).sqrt();
                self.spare_normal = Some(v * k);
                return u * k;
            }
        }
    }

    /// Three independent standard normals.
    pub fn normal3(&mut self) -> nalgebra::Vector3<f64> {
        nalgebra::Vector3::new(self.normal(), self.normal(), self.normal())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_differ_and_repeat() {
        assert_eq!(stream_seed(7, &[1, 2]), stream_seed(7, &[1, 2]));
        assert_ne!(stream_seed(7, &[1, 2]), stream_seed(7, &[2, 1]));
        assert_ne!(stream_seed(7, &[1]), stream_seed(8, &[1]));
        assert_ne!(stream_seed(7, &[1]), stream_seed(7, &[1, 0]));
    }

    #[test]
    fn normal_has_unit_variance() {
        let mut rng = stream(3, &[streams::IMU]);
        let n = 200_000;
        let draws: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        // 5 standard errors of the sample mean and variance.
        assert!(mean.abs() < 5.0 / (n as f64).sqrt(), "mean {mean}");
        assert!((var - 1.0).abs() < 5.0 * (2.0 / n as f64).sqrt(), "variance {var}");
    }

    #[test]
    fn hash_unit_is_in_range_and_spread() {
        let values: Vec<f64> = (0..10_000).map(|i| hash_unit(9, i % 100, i / 100)).collect();
        assert!(values.iter().all(|v| (0.0..1.0).contains(v)));
        let mean = values.iter().sum::<f64>() / values.len() as f64;
        assert!((mean - 0.5).abs() < 0.02, "mean {mean}");
    }
}
