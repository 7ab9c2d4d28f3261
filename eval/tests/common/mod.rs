//! Helpers shared by the integration tests: real trajectories and deterministic noise.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)]

use eval::{Trajectory, io};

/// A file of the repository's test data folder (`data/`).
pub fn data(path: &str) -> String {
    format!("{}/../data/{path}", env!("CARGO_MANIFEST_DIR"))
}

/// EuRoC ground truth CSV through the crate's reader.
pub fn load_euroc_csv(path: &str) -> Trajectory {
    io::parse_euroc(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// TUM trajectory through the crate's reader.
pub fn load_tum(path: &str) -> Trajectory {
    io::parse_tum(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// splitmix64 with Box–Muller normals: deterministic noise without a dependency.
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in (0, 1).
    pub fn uniform(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    pub fn normal(&mut self) -> f64 {
        let (u1, u2) = (self.uniform(), self.uniform());
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }

    /// Student-t with 4 degrees of freedom (variance 2): heavy tails like GT-vision's errors.
    pub fn student_t4(&mut self) -> f64 {
        let chi2: f64 = (0..4).map(|_| self.normal().powi(2)).sum();
        self.normal() / (chi2 / 4.0).sqrt()
    }
}
