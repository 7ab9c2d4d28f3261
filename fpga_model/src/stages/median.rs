//! Stage 7 of `SPEC.md`: 3×3 median of the valid disparities.

use crate::image::{DisparityImage, INVALID};

/// Valid values a 3×3 window needs for its pixel to stay (or become) valid: a majority.
pub const MIN_VALID: usize = 5;

/// The output of one window of nine values: with `n` valid (non-[`INVALID`]) values, the
/// `ceil(n/2)`-th smallest of them (the lower median) if `n ≥ 5`, else [`INVALID`].
///
/// Sorting the nine values with `INVALID = 0xFFFF` as the largest, that is the element at index
/// `(n − 1) / 2`: one sorting network plus a 3-way multiplexer (index 2, 3 or 4) in hardware.
/// Taking the median of the valid values only (instead of the 5th of all nine, which for
/// `n < 9` is pulled upwards by the invalid ones) removes a bias towards large disparities,
/// i.e. towards the foreground, just where the left-right check left holes: at depth edges.
pub fn median_of_window(mut window: [u16; 9]) -> u16 {
    let valid = window.iter().filter(|&&v| v != INVALID).count();
    if valid < MIN_VALID {
        return INVALID;
    }
    window.sort_unstable();
    window[(valid - 1) / 2]
}

/// Each pixel not on the image border becomes [`median_of_window`] of its 3×3 neighbourhood;
/// the first and last row and column keep their value (the FPGA's two line buffers have no
/// neighbours to offer there). So an isolated invalid pixel is filled, and a pixel with five or
/// more invalid neighbours becomes invalid.
pub fn median3x3(disparity: &DisparityImage) -> DisparityImage {
    let (width, height) = (disparity.width, disparity.height);
    let mut out = disparity.clone();
    for y in 1..height.saturating_sub(1) {
        for x in 1..width.saturating_sub(1) {
            let mut window = [0u16; 9];
            let mut k = 0;
            for wy in y - 1..=y + 1 {
                for wx in x - 1..=x + 1 {
                    window[k] = disparity.data[wy * width + wx];
                    k += 1;
                }
            }
            out.data[y * width + x] = median_of_window(window);
        }
    }
    out
}
