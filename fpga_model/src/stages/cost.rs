//! Stage 2 of `SPEC.md`: the matching cost, Hamming distance of census words plus a truncated,
//! weighted absolute difference of horizontal intensity gradients.

use super::CostVolume;
use crate::config::SgmConfig;
use crate::image::GrayImage;

/// The horizontal central difference `G(x, y) = I(clamp(x + 1), y) − I(clamp(x − 1), y)` of
/// every pixel, row-major, `−255 ..= 255` (9 bits signed); coordinates clamped as in the census.
///
/// A difference of neighbours is blind to a brightness offset between the cameras, which the
/// census is built to ignore too; the intensity itself is not (see `PARITY.md`).
pub fn horizontal_gradient(image: &GrayImage) -> Vec<i16> {
    let mut gradient = Vec::with_capacity(image.width * image.height);
    for y in 0..image.height as isize {
        for x in 0..image.width as isize {
            gradient.push(i16::from(image.clamped(x + 1, y)) - i16::from(image.clamped(x - 1, y)));
        }
    }
    gradient
}

/// The pixel-wise term of the cost: `min(weight · |left − right|, truncation)` for two
/// gradients of [`horizontal_gradient`].
///
/// The census word describes a 9×7 neighbourhood, so near a depth edge it sees the foreground
/// in both views and drags the edge outwards ("fattening"); the gradient at the pixel itself
/// barely straddles the edge. The truncation keeps a single strong edge (specularity, noise)
/// from outweighing the census.
pub fn gradient_term(left: i16, right: i16, weight: u8, truncation: u8) -> u8 {
    // |left − right| ≤ 510, times a weight ≤ 255: within a u32.
    let weighted = u32::from(left.abs_diff(right)) * u32::from(weight);
    weighted.min(u32::from(truncation)) as u8
}

/// The cost volume, layout `[y][x][d]`:
/// `C(x, y, d) = popcount(cL(x, y) XOR cR(x − d, y)) + gradient_term(GL(x, y), GR(x − d, y))`.
///
/// Where `x − d < 0` there is no right pixel to match; the cost is [`SgmConfig::cost_max`], the
/// worst a real match can score, so that such disparities never win over a real one by being
/// cheap. Uses `disparities`, `gradient_cost_weight` and `gradient_cost_truncation` of `config`
/// and its census width for `cost_max`; the census words are those of `left` and `right`.
pub fn volume(
    census_left: &[u64],
    census_right: &[u64],
    left: &GrayImage,
    right: &GrayImage,
    config: &SgmConfig,
) -> CostVolume {
    let (width, height, disparities) = (left.width, left.height, usize::from(config.disparities));
    let (weight, truncation) = (config.gradient_cost_weight, config.gradient_cost_truncation);
    let (gradient_left, gradient_right) = (horizontal_gradient(left), horizontal_gradient(right));
    // ≤ 64 + 191 for a valid configuration (`SgmConfig::validate`), so every cost fits a `u8`.
    let no_right_pixel_cost = config.cost_max() as u8;
    let mut cost = CostVolume::zeros(width, height, disparities);
    for y in 0..height {
        for x in 0..width {
            let i = y * width + x;
            let costs = cost.pixel_mut(x, y);
            for (d, c) in costs.iter_mut().enumerate() {
                *c = if x >= d {
                    let hamming = (census_left[i] ^ census_right[i - d]).count_ones() as u8;
                    hamming + gradient_term(gradient_left[i], gradient_right[i - d], weight, truncation)
                } else {
                    no_right_pixel_cost
                };
            }
        }
    }
    cost
}
