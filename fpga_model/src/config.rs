//! Parameters of the SGM core (see `SPEC.md` for what each one does, bit for bit).

use crate::SgmError;

/// Which paths are aggregated.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PathMode {
    /// Left, top-left, top, top-right: one raster pass, what a streaming FPGA with line buffers does.
    Four,
    /// The four above plus their opposites in a second, reverse raster pass.
    Eight,
}

impl PathMode {
    pub fn count(self) -> usize {
        match self {
            PathMode::Four => 4,
            PathMode::Eight => 8,
        }
    }
}

/// Configuration of the core. `validate` checks every range of `SPEC.md`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SgmConfig {
    pub census_width: u8,
    pub census_height: u8,
    pub disparities: u16,
    pub paths: PathMode,
    pub p1: u8,
    pub p2: u8,
    /// 0 disables the adaptation of P2 to the intensity step along the path.
    pub p2_gradient_scale: u8,
    /// Stored width of a path cost; path costs saturate at `2^bits - 1`.
    pub path_cost_bits: u8,
    pub uniqueness_percent: u8,
    pub lr_check: bool,
    pub lr_max_diff: u8,
    pub subpixel: bool,
    pub median: bool,
}

impl Default for SgmConfig {
    /// The configuration the `sgm` CLI and the host-side matcher use by default. P1, P2, the P2
    /// gradient scale and the uniqueness margin are tuned on the Middlebury scenes (see
    /// `PARITY.md`). The FPGA flies the same data path with [`PathMode::Four`] (the only mode
    /// whose buffers fit on-chip, see `README.md`).
    fn default() -> Self {
        SgmConfig {
            census_width: 9,
            census_height: 7,
            disparities: 128,
            paths: PathMode::Eight,
            p1: 24,
            p2: 200,
            p2_gradient_scale: 8,
            path_cost_bits: 7,
            uniqueness_percent: 0,
            lr_check: true,
            lr_max_diff: 2,
            subpixel: true,
            median: true,
        }
    }
}

/// Disparity counts the hardware supports; the model accepts any multiple of 16 up to 256.
pub const MAX_DISPARITIES: u16 = 256;

impl SgmConfig {
    /// Bits of a census word: the window without its centre.
    pub fn census_bits(&self) -> u32 {
        u32::from(self.census_width) * u32::from(self.census_height) - 1
    }

    /// The saturation value of a stored path cost.
    pub fn path_cost_max(&self) -> u16 {
        (1u16 << self.path_cost_bits) - 1
    }

    pub fn validate(&self) -> Result<(), SgmError> {
        let bad = |reason: String| Err(SgmError::InvalidConfig(reason));
        if self.census_width.is_multiple_of(2) || self.census_height.is_multiple_of(2) {
            return bad(format!("census window {}x{} must be odd", self.census_width, self.census_height));
        }
        if self.census_width == 0 || self.census_height == 0 || self.census_bits() > 64 {
            return bad(format!("census window {}x{} must have 1..=64 bits", self.census_width, self.census_height));
        }
        if self.disparities < 16 || self.disparities > MAX_DISPARITIES || !self.disparities.is_multiple_of(16) {
            return bad(format!("disparities {} must be a multiple of 16 in 16..=256", self.disparities));
        }
        if self.p1 == 0 || self.p1 > self.p2 {
            return bad(format!("penalties must satisfy 1 <= p1 <= p2 (p1 {}, p2 {})", self.p1, self.p2));
        }
        if !(6..=12).contains(&self.path_cost_bits) {
            return bad(format!("path_cost_bits {} must be in 6..=12", self.path_cost_bits));
        }
        if self.uniqueness_percent > 100 {
            return bad(format!("uniqueness_percent {} must be <= 100", self.uniqueness_percent));
        }
        Ok(())
    }
}
