//! Stage 7 of `SPEC.md`: 3×3 median of the disparity image.

use crate::image::DisparityImage;

/// Each pixel not on the image border becomes the 5th smallest of its 3×3 neighbourhood; the
/// first and last row and column keep their value (the FPGA's two line buffers have no
/// neighbours to offer there). `INVALID = 0xFFFF` is just the largest value, so an isolated
/// invalid pixel is filled and a pixel with five or more invalid neighbours becomes invalid.
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
            window.sort_unstable();
            out.data[y * width + x] = window[4];
        }
    }
    out
}
