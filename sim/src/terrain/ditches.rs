//! Ditches: straight trenches with a floor following the ground and steep walls, the site's
//! deliberate negative obstacles.

use super::craters::index_range;
use super::{Ditch, Heightfield, TerrainConfig};
use crate::rng::Rng;

/// Wall inclination: steep, but not a vertical step the mesh could not represent.
const WALL_ANGLE_DEG: f64 = 75.0;
/// Gap kept between two ditches and between a ditch and a keep-clear area.
const CLEARANCE_M: f64 = 1.0;
const ATTEMPTS_PER_DITCH: usize = 200;
/// Points per half circle of a ditch outline's rounded ends.
const END_POINTS: usize = 8;

/// Draws `config.ditches` ditches and digs them into `hf`.
pub(super) fn place(config: &TerrainConfig, hf: &mut Heightfield, seed: u64) -> Vec<Ditch> {
    let mut rng = Rng::new(seed);
    let (lo, hi) = hf.bounds_m();
    let edge = (hi[0] - lo[0]).min(hi[1] - lo[1]);
    let mut ditches: Vec<Ditch> = Vec::with_capacity(config.ditches);
    for _ in 0..config.ditches {
        for _ in 0..ATTEMPTS_PER_DITCH {
            // On small test sites a ditch may not take more than a good part of the site.
            let length = rng.range(config.ditch_length_m[0], config.ditch_length_m[1]).min(0.4 * edge);
            let width_m = rng.range(config.ditch_width_m[0], config.ditch_width_m[1]);
            let depth_m = rng.range(config.ditch_depth_m[0], config.ditch_depth_m[1]);
            let (s, c) = rng.range(0.0, std::f64::consts::PI).sin_cos();
            let margin = 0.5 * length + width_m;
            if hi[0] - lo[0] <= 2.0 * margin || hi[1] - lo[1] <= 2.0 * margin {
                continue;
            }
            let centre = [rng.range(lo[0] + margin, hi[0] - margin), rng.range(lo[1] + margin, hi[1] - margin)];
            let half = [0.5 * length * c, 0.5 * length * s];
            let ditch = Ditch {
                start_m: [centre[0] - half[0], centre[1] - half[1]],
                end_m: [centre[0] + half[0], centre[1] + half[1]],
                width_m,
                depth_m,
            };
            let near_clear = config
                .keep_clear_m
                .iter()
                .any(|&(p, r)| distance_to_segment_m(p, &ditch) < r + 0.5 * width_m + CLEARANCE_M);
            let near_other =
                ditches.iter().any(|o| segment_distance_m(&ditch, o) < 0.5 * (width_m + o.width_m) + CLEARANCE_M);
            if !near_clear && !near_other {
                dig(hf, &ditch);
                ditches.push(ditch);
                break;
            }
        }
    }
    ditches
}

/// Fraction of the ditch's depth removed at distance `q` from its axis segment.
fn depth_fraction(ditch: &Ditch, q: f64) -> f64 {
    let half = 0.5 * ditch.width_m;
    let wall = ditch.depth_m / WALL_ANGLE_DEG.to_radians().tan();
    ((half - q) / wall).clamp(0.0, 1.0)
}

fn dig(hf: &mut Heightfield, ditch: &Ditch) {
    let reach = 0.5 * ditch.width_m;
    let (x_lo, x_hi) = (ditch.start_m[0].min(ditch.end_m[0]) - reach, ditch.start_m[0].max(ditch.end_m[0]) + reach);
    let (y_lo, y_hi) = (ditch.start_m[1].min(ditch.end_m[1]) - reach, ditch.start_m[1].max(ditch.end_m[1]) + reach);
    let res = hf.resolution_m;
    let (Some((c0, c1)), Some((r0, r1))) =
        (index_range(x_lo, x_hi, hf.origin_m[0], res, hf.cols), index_range(y_lo, y_hi, hf.origin_m[1], res, hf.rows))
    else {
        return;
    };
    for row in r0..=r1 {
        for col in c0..=c1 {
            let p = hf.cell_centre_m(col, row);
            let f = depth_fraction(ditch, distance_to_segment_m(p, ditch));
            if f > 0.0 {
                let i = row * hf.cols + col;
                hf.heights_m[i] = (f64::from(hf.heights_m[i]) - f * ditch.depth_m) as f32;
            }
        }
    }
}

/// Distance from `p` to the ditch's axis segment.
pub(super) fn distance_to_segment_m(p: [f64; 2], ditch: &Ditch) -> f64 {
    let (a, b) = (ditch.start_m, ditch.end_m);
    let ab = [b[0] - a[0], b[1] - a[1]];
    let len2 = ab[0] * ab[0] + ab[1] * ab[1];
    let t = if len2 > 0.0 { (((p[0] - a[0]) * ab[0] + (p[1] - a[1]) * ab[1]) / len2).clamp(0.0, 1.0) } else { 0.0 };
    (p[0] - a[0] - t * ab[0]).hypot(p[1] - a[1] - t * ab[1])
}

/// Distance between the axis segments of two ditches (0 if they cross).
fn segment_distance_m(d1: &Ditch, d2: &Ditch) -> f64 {
    let orient = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    let crosses = orient(d1.start_m, d1.end_m, d2.start_m) * orient(d1.start_m, d1.end_m, d2.end_m) < 0.0
        && orient(d2.start_m, d2.end_m, d1.start_m) * orient(d2.start_m, d2.end_m, d1.end_m) < 0.0;
    if crosses {
        return 0.0;
    }
    [
        distance_to_segment_m(d2.start_m, d1),
        distance_to_segment_m(d2.end_m, d1),
        distance_to_segment_m(d1.start_m, d2),
        distance_to_segment_m(d1.end_m, d2),
    ]
    .into_iter()
    .fold(f64::INFINITY, f64::min)
}

/// The closed outline of the ditch's top edge: both long sides and the rounded ends.
pub(super) fn outline(ditch: &Ditch) -> Vec<[f64; 2]> {
    let half = 0.5 * ditch.width_m;
    let (dx, dy) = (ditch.end_m[0] - ditch.start_m[0], ditch.end_m[1] - ditch.start_m[1]);
    let axis = dy.atan2(dx);
    let mut out = Vec::with_capacity(2 * END_POINTS + 3);
    // Half circles around the end (from the right side to the left) and around the start.
    for (centre, from) in
        [(ditch.end_m, axis - std::f64::consts::FRAC_PI_2), (ditch.start_m, axis + std::f64::consts::FRAC_PI_2)]
    {
        for k in 0..=END_POINTS {
            let a = from + std::f64::consts::PI * k as f64 / END_POINTS as f64;
            out.push([centre[0] + half * a.cos(), centre[1] + half * a.sin()]);
        }
    }
    if let Some(&first) = out.first() {
        out.push(first);
    }
    out
}
