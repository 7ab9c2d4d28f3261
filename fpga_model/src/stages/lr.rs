//! Stage 6 of `SPEC.md`: the left-right consistency check, with the right view's disparity
//! taken from the same aggregated volume (no second matching pass, as in the FPGA).

use super::AggregatedVolume;
use super::select::Winner;
use crate::image::{DisparityImage, INVALID};

/// `dR(xr, y)`: the smallest `d` with `xr + d < W` minimising `S((xr + d, y), d)`, row-major.
///
/// The right pixel `xr` seen at disparity `d` is the left pixel `xr + d`, so the right view's
/// costs are a diagonal walk through the left view's volume.
pub fn right_disparity(aggregated: &AggregatedVolume) -> Vec<u16> {
    let (width, height, disparities) = (aggregated.width, aggregated.height, aggregated.disparities);
    let mut right = Vec::with_capacity(width * height);
    for y in 0..height {
        for xr in 0..width {
            let mut best_d = 0usize;
            let mut best_cost = aggregated.pixel(xr, y)[0];
            for d in 1..disparities {
                if xr + d >= width {
                    break;
                }
                let s = aggregated.pixel(xr + d, y)[d];
                if s < best_cost {
                    best_cost = s;
                    best_d = d;
                }
            }
            right.push(best_d as u16);
        }
    }
    right
}

/// The integer disparities whose right-view match stage 6 consults for a left pixel with integer
/// winner `d1` and stage-5 value `d16` (1/16 px): `{d1}`, or with `lenient` the floor and the
/// ceiling of `d16 / 16` (both `d1` when the subpixel offset is 0; `d1` and its neighbour on the
/// side the offset points to otherwise).
pub fn candidates(d1: u16, d16: u16, lenient: bool) -> [u16; 2] {
    if lenient { [d16 / 16, d16.div_ceil(16)] } else { [d1, d1] }
}

/// Keeps a pixel of `disparity` (stage 5 output) if one of its [`candidates`] `d` lands inside
/// the right image and the right view agrees within `max_diff` px: `x − d ≥ 0` and
/// `|d − dR(x − d, y)| ≤ max_diff`. Everything else becomes [`INVALID`].
///
/// With `lenient` (OpenCV's rule) a pixel whose subpixel disparity lies between two integers is
/// also kept when the right pixel next to `x − d1` confirms the other integer: at a slanted or
/// finely textured surface the right view's winner of one of the two columns is often the
/// other integer, and the strict check punches holes there that the median cannot close.
pub fn check(
    disparity: &DisparityImage,
    winners: &[Winner],
    right: &[u16],
    max_diff: u8,
    lenient: bool,
) -> DisparityImage {
    let width = disparity.width;
    let mut out = disparity.clone();
    for y in 0..disparity.height {
        for x in 0..width {
            let i = y * width + x;
            if out.data[i] == INVALID {
                continue;
            }
            let consistent = candidates(winners[i].disparity, out.data[i], lenient).iter().any(|&d| {
                let d = usize::from(d);
                x >= d && right[y * width + (x - d)].abs_diff(d as u16) <= u16::from(max_diff)
            });
            if !consistent {
                out.data[i] = INVALID;
            }
        }
    }
    out
}
