//! Stage 2 of `SPEC.md`: the matching cost, Hamming distance of census words.

use super::CostVolume;

/// The cost volume `C(x, y, d) = popcount(cL(x, y) XOR cR(x − d, y))`, layout `[y][x][d]`.
///
/// Where `x − d < 0` there is no right pixel to match; the cost is `census_bits`, the worst a
/// real match can score, so that such disparities never win over a real one by being cheap.
/// `census_bits` is `w·h − 1` of the census window (at most 64, so a cost fits a `u8`).
pub fn volume(
    census_left: &[u64],
    census_right: &[u64],
    width: usize,
    height: usize,
    disparities: usize,
    census_bits: u32,
) -> CostVolume {
    let no_right_pixel_cost = census_bits as u8;
    let mut cost = CostVolume::zeros(width, height, disparities);
    for y in 0..height {
        for x in 0..width {
            let left_word = census_left[y * width + x];
            let costs = cost.pixel_mut(x, y);
            for (d, c) in costs.iter_mut().enumerate() {
                *c = if x >= d {
                    let right_word = census_right[y * width + (x - d)];
                    (left_word ^ right_word).count_ones() as u8
                } else {
                    no_right_pixel_cost
                };
            }
        }
    }
    cost
}
