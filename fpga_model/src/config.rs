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
    /// Weight `w` of the absolute difference of horizontal intensity gradients added to the
    /// census cost: `C = Hamming + min(w · |GL(x) − GR(x − d)|, gradient_cost_truncation)`.
    /// 0 = census only.
    pub gradient_cost_weight: u8,
    /// Truncation `T` of the weighted gradient difference (0 also disables the term).
    pub gradient_cost_truncation: u8,
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
    /// OpenCV's lenient check: a pixel passes if either integer neighbour of its subpixel
    /// disparity (floor or ceil) passes, instead of only its integer winner.
    pub lr_lenient: bool,
    pub subpixel: bool,
    pub median: bool,
}

impl Default for SgmConfig {
    /// The configuration the `sgm` CLI and the host-side matcher use by default. P1, P2, the P2
    /// gradient scale, the uniqueness margin and the gradient term of the cost are tuned on the
    /// Middlebury scenes, the LR check's leniency and the median of the valid values chosen there
    /// (see `PARITY.md`). The FPGA flies the same data path with [`PathMode::Four`] (the only
    /// mode whose buffers fit on-chip, see `README.md`).
    fn default() -> Self {
        SgmConfig {
            census_width: 9,
            census_height: 7,
            gradient_cost_weight: 4,
            gradient_cost_truncation: 32,
            disparities: 128,
            paths: PathMode::Eight,
            p1: 40,
            p2: 160,
            p2_gradient_scale: 64,
            path_cost_bits: 7,
            uniqueness_percent: 0,
            lr_check: true,
            lr_max_diff: 2,
            lr_lenient: true,
            subpixel: true,
            median: true,
        }
    }
}

/// Disparity counts the hardware supports; the model accepts any multiple of 16 up to 256.
pub const MAX_DISPARITIES: u16 = 256;
/// Largest `gradient_cost_weight`: a 4-bit factor (shift-and-add in fabric, no DSP).
pub const MAX_GRADIENT_COST_WEIGHT: u8 = 15;
/// Largest `gradient_cost_truncation`: with at most 64 census bits the matching cost stays
/// within a byte.
pub const MAX_GRADIENT_COST_TRUNCATION: u8 = 255 - 64;
/// Largest `|GL − GR|`: two gradients of `−255 ..= 255`.
pub const MAX_GRADIENT_DIFFERENCE: u16 = 510;

impl SgmConfig {
    /// Bits of a census word: the window without its centre.
    pub fn census_bits(&self) -> u32 {
        u32::from(self.census_width) * u32::from(self.census_height) - 1
    }

    /// The largest value of the gradient term, `min(510 · w, T)` (0 when disabled).
    pub fn gradient_cost_max(&self) -> u16 {
        // In u32: an unvalidated weight up to 255 times 510 overflows a u16.
        let weighted = u32::from(MAX_GRADIENT_DIFFERENCE) * u32::from(self.gradient_cost_weight);
        weighted.min(u32::from(self.gradient_cost_truncation)) as u16
    }

    /// The largest matching cost, `w·h − 1 + gradient_cost_max`: also the cost where `x − d < 0`
    /// (no right pixel). At most 64 + 191 = 255 for a valid configuration, so a cost fits a byte.
    pub fn cost_max(&self) -> u16 {
        self.census_bits() as u16 + self.gradient_cost_max()
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
        if self.gradient_cost_weight > MAX_GRADIENT_COST_WEIGHT
            || self.gradient_cost_truncation > MAX_GRADIENT_COST_TRUNCATION
        {
            return bad(format!(
                "gradient_cost_weight {} must be <= {MAX_GRADIENT_COST_WEIGHT} and gradient_cost_truncation {} <= \
                 {MAX_GRADIENT_COST_TRUNCATION}",
                self.gradient_cost_weight, self.gradient_cost_truncation
            ));
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
