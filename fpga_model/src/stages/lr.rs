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

/// Keeps a pixel of `disparity` (stage 5 output) if its integer winner `d1` lands inside the
/// right image and the right view agrees within `max_diff` px: `x − d1 ≥ 0` and
/// `|d1 − dR(x − d1, y)| ≤ max_diff`. Everything else becomes [`INVALID`].
pub fn check(disparity: &DisparityImage, winners: &[Winner], right: &[u16], max_diff: u8) -> DisparityImage {
    let width = disparity.width;
    let mut out = disparity.clone();
    for y in 0..disparity.height {
        for x in 0..width {
            let i = y * width + x;
            if out.data[i] == INVALID {
                continue;
            }
            let d1 = usize::from(winners[i].disparity);
            let consistent = x >= d1 && right[y * width + (x - d1)].abs_diff(d1 as u16) <= u16::from(max_diff);
            if !consistent {
                out.data[i] = INVALID;
            }
        }
    }
    out
}
