//! Stages 4, 5 and 8 of `SPEC.md`: winner takes all with the uniqueness test, parabolic
//! subpixel refinement, and invalid marking of matches left of the right image.

use super::AggregatedVolume;
use crate::image::{DisparityImage, INVALID};

/// The integer winner of one pixel (stage 4).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Winner {
    /// `d1`: the smallest disparity with the minimal aggregated cost.
    pub disparity: u16,
    /// `S1 = S(p, d1)`.
    pub cost: u16,
    /// False if another disparity at least 2 away from `d1` is within the uniqueness margin.
    pub unique: bool,
}

/// Winner takes all with uniqueness for the costs `S(p, ·)` of one pixel.
///
/// `d1` is the first minimum (ties go to the smaller disparity, the order a comparator chain
/// that keeps its value on `≥` produces). `S2` is the minimum over `|d − d1| ≥ 2`: the direct
/// neighbours are excluded because they belong to the same (subpixel-wide) minimum. The pixel
/// is ambiguous if `100 · S2 < (100 + U) · S1`, integer arithmetic without division.
pub fn winner_of(costs: &[u16], uniqueness_percent: u8) -> Winner {
    let mut d1 = 0usize;
    for (d, &s) in costs.iter().enumerate() {
        if s < costs[d1] {
            d1 = d;
        }
    }
    let s1 = costs[d1];
    let s2 = costs.iter().enumerate().filter(|&(d, _)| d.abs_diff(d1) >= 2).map(|(_, &s)| s).min();
    let unique = match s2 {
        None => true,
        Some(s2) => 100 * u32::from(s2) >= (100 + u32::from(uniqueness_percent)) * u32::from(s1),
    };
    Winner { disparity: d1 as u16, cost: s1, unique }
}

/// [`winner_of`] for every pixel, row-major.
pub fn winner(aggregated: &AggregatedVolume, uniqueness_percent: u8) -> Vec<Winner> {
    let mut winners = Vec::with_capacity(aggregated.width * aggregated.height);
    for y in 0..aggregated.height {
        for x in 0..aggregated.width {
            winners.push(winner_of(aggregated.pixel(x, y), uniqueness_percent));
        }
    }
    winners
}

/// Parabolic subpixel offset of one pixel in 1/16 px, `−8 ..= 8`, from
/// `a = S(d1 − 1)`, `c0 = S(d1)`, `c = S(d1 + 1)` (requires `c0 ≤ a` and `c0 ≤ c`).
///
/// The parabola through the three costs has its minimum at `(a − c) / (2 · (a + c − 2·c0))` px
/// (Hirschmüller 2008); times 16 that is `8 · (a − c) / den`. Rounded half away from zero via
/// `floor((|num| + floor(den/2)) / den)`, which equals exact half-away rounding for odd and even
/// `den` alike.
pub fn subpixel_offset(a: u16, c0: u16, c: u16) -> i32 {
    let (a, c0, c) = (i32::from(a), i32::from(c0), i32::from(c));
    let den = a + c - 2 * c0;
    let num = 8 * (a - c);
    let offset = if den == 0 { 0 } else { num.signum() * ((num.abs() + den / 2) / den) };
    // |a − c| ≤ a + c − 2·c0 already bounds the offset; the clamp is the spec's safety net.
    offset.clamp(-8, 8)
}

/// Stage 5 for one pixel: the disparity in 1/16 px. No refinement at `d1 = 0`, `d1 = D − 1`
/// (one side of the V is missing) or when `enabled` is false.
pub fn refine(costs: &[u16], d1: u16, enabled: bool) -> u16 {
    let d = usize::from(d1);
    if !enabled || d == 0 || d + 1 == costs.len() {
        return 16 * d1;
    }
    let offset = subpixel_offset(costs[d - 1], costs[d], costs[d + 1]);
    (16 * i32::from(d1) + offset) as u16
}

/// Stage 4's verdict and stage 5 for every pixel: `16 · d1 + offset`, or [`INVALID`] where the
/// winner is not unique.
pub fn subpixel(aggregated: &AggregatedVolume, winners: &[Winner], enabled: bool) -> DisparityImage {
    let (width, height) = (aggregated.width, aggregated.height);
    let mut data = Vec::with_capacity(width * height);
    for y in 0..height {
        for x in 0..width {
            let w = winners[y * width + x];
            data.push(if w.unique { refine(aggregated.pixel(x, y), w.disparity, enabled) } else { INVALID });
        }
    }
    DisparityImage { width, height, data }
}

/// Stage 8: a disparity whose match lies left of the right image (`16 · x < D16`, the
/// subpixel position included) becomes [`INVALID`].
pub fn mark_invalid(disparity: &DisparityImage) -> DisparityImage {
    let mut out = disparity.clone();
    for y in 0..out.height {
        for x in 0..out.width {
            let value = &mut out.data[y * disparity.width + x];
            if *value != INVALID && 16 * x < usize::from(*value) {
                *value = INVALID;
            }
        }
    }
    out
}
