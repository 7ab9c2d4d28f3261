//! The stages of the SGM core, one module per stage of `SPEC.md`, each a plain function on plain
//! data. [`crate::reference`] chains them; the tests check each one against an independent naive
//! implementation.
//!
//! | `SPEC.md` stage | function |
//! |---|---|
//! | 1 census | [`census::transform`] |
//! | 2 matching cost | [`cost::horizontal_gradient`], [`cost::gradient_term`], [`cost::volume`] |
//! | 3 path aggregation | [`aggregate::path`], [`aggregate::sum`] |
//! | 4 winner takes all + uniqueness | [`select::winner`] |
//! | 5 subpixel | [`select::subpixel`] |
//! | 6 left-right check | [`lr::right_disparity`], [`lr::candidates`], [`lr::check`] |
//! | 7 3×3 median | [`median::median_of_window`], [`median::median3x3`] |
//! | 8 invalid marking | [`select::mark_invalid`] |

pub mod aggregate;
pub mod census;
pub mod cost;
pub mod lr;
pub mod median;
pub mod select;

/// A `W × H × D` volume of per-disparity values, layout `[y][x][d]` (the disparities of one
/// pixel are contiguous, as they leave the FPGA's disparity units one group after another).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Volume<T> {
    pub width: usize,
    pub height: usize,
    pub disparities: usize,
    pub data: Vec<T>,
}

/// Stage 2 output: matching costs `C(x, y, d)`, at most 255 (`SgmConfig::cost_max`: census bits
/// ≤ 64 plus the gradient term ≤ 191).
pub type CostVolume = Volume<u8>;
/// Stage 3 output of one direction: path costs `L_r(x, y, d)`, saturated to `b` bits.
pub type PathCostVolume = Volume<u16>;
/// Stage 3 output of a mode: `S(x, y, d)`, the sum of the path costs (`b + 3` bits at most).
pub type AggregatedVolume = Volume<u16>;

impl<T: Copy + Default> Volume<T> {
    /// A volume with every value `T::default()` (zero).
    pub fn zeros(width: usize, height: usize, disparities: usize) -> Self {
        Volume { width, height, disparities, data: vec![T::default(); width * height * disparities] }
    }
}

impl<T> Volume<T> {
    /// Index of `(x, y, d)` in `data`.
    #[inline]
    pub fn index(&self, x: usize, y: usize, d: usize) -> usize {
        (y * self.width + x) * self.disparities + d
    }

    /// The `D` values of pixel `(x, y)`, indexed by disparity.
    #[inline]
    pub fn pixel(&self, x: usize, y: usize) -> &[T] {
        let start = self.index(x, y, 0);
        &self.data[start..start + self.disparities]
    }

    /// The `D` values of pixel `(x, y)`, mutable.
    #[inline]
    pub fn pixel_mut(&mut self, x: usize, y: usize) -> &mut [T] {
        let start = self.index(x, y, 0);
        &mut self.data[start..start + self.disparities]
    }
}
