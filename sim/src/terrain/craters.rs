//! Impact craters: a power-law population of parabolic bowls with raised rims, ejecta blankets
//! that fall off as r⁻³, and bright ejecta around fresh ones.

use super::{Crater, Heightfield, Material, NegativeObstacle, NegativeObstacleKind, TerrainConfig};
use crate::noise;
use crate::rng::Rng;

/// A crater rim is a negative obstacle where the ground inside drops by more than this...
pub const CRATER_EDGE_MIN_DROP_M: f64 = 0.3;
/// ...within this horizontal distance of the rim crest.
pub const CRATER_EDGE_RUN_M: f64 = 1.0;

/// The rim deposit reaches this many rim radii from the centre.
const OUTER_REACH: f64 = 3.0;
/// Inside this fraction of the rim radius the bowl shows freshly excavated regolith.
const BOWL_MATERIAL_FRACTION: f64 = 0.85;
/// Craters fresher than this have bright ejecta.
const EJECTA_MIN_FRESHNESS: f64 = 0.45;

#[derive(Debug, Clone, Copy)]
pub(super) struct PlacedCrater {
    pub crater: Crater,
    freshness: f64,
    ejecta_seed: u32,
}

/// Depth and rim height per rim radius: a fresh simple crater has depth/diameter ≈ 0.12 and
/// rim/diameter ≈ 0.03, a degraded one a third of that. The parabolic bowl's wall at the crest is
/// `2 (depth + rim) / R`, i.e. 10° (degraded) to 29° (fresh).
fn shape_per_radius(freshness: f64) -> (f64, f64) {
    (0.07 + 0.17 * freshness, 0.02 + 0.04 * freshness)
}

/// Draws the crater population of `config` over `grid`, oldest (largest) first.
pub(super) fn sample(config: &TerrainConfig, grid: &Heightfield, seed: u64) -> Vec<PlacedCrater> {
    let mut rng = Rng::new(seed);
    let (lo, hi) = grid.bounds_m();
    let area_km2 = (hi[0] - lo[0]) * (hi[1] - lo[1]) * 1e-6;
    let [r_min, r_max] = config.crater_radius_m;
    let b = config.crater_size_exponent;
    if !(r_min > 0.0 && r_max >= r_min && b > 0.0 && config.craters_per_km2 > 0.0) {
        return Vec::new();
    }
    let expected = config.craters_per_km2 * area_km2 * (r_min.powf(-b) - r_max.powf(-b));
    let count = expected.round() as usize;
    let freshness_exponent = 1.0 / config.crater_freshness.clamp(0.01, 1.0) - 1.0;
    let mut craters = Vec::with_capacity(count);
    for _ in 0..count {
        let u = rng.uniform();
        let radius_m = (r_min.powf(-b) - u * (r_min.powf(-b) - r_max.powf(-b))).powf(-1.0 / b);
        let centre_m = [rng.range(lo[0], hi[0]), rng.range(lo[1], hi[1])];
        // u^q with q = 1/mean − 1 has mean `crater_freshness`.
        let freshness = rng.uniform().powf(freshness_exponent);
        let ejecta_seed = (rng.next_u64() >> 32) as u32;
        if config.touches_clear_area(centre_m, OUTER_REACH * radius_m) {
            continue;
        }
        let (depth, rim) = shape_per_radius(freshness);
        craters.push(PlacedCrater {
            crater: Crater { centre_m, radius_m, depth_m: depth * radius_m, rim_height_m: rim * radius_m },
            freshness,
            ejecta_seed,
        });
    }
    // Larger craters are older: smaller ones are superposed on them.
    craters.sort_by(|a, b| b.crater.radius_m.total_cmp(&a.crater.radius_m));
    craters
}

/// Height change of `crater` at distance `r` from its centre (0 beyond [`OUTER_REACH`] radii).
fn profile_m(crater: &Crater, r: f64) -> f64 {
    let big_r = crater.radius_m;
    if r < big_r {
        let q = r / big_r;
        -crater.depth_m + (crater.depth_m + crater.rim_height_m) * q * q
    } else if r < OUTER_REACH * big_r {
        let tail = OUTER_REACH.powi(-3);
        crater.rim_height_m * ((big_r / r).powi(3) - tail) / (1.0 - tail)
    } else {
        0.0
    }
}

/// Adds the craters, in order, to the rows `first_row..` held by `heights` and `material`.
pub(super) fn apply(
    craters: &[PlacedCrater],
    grid: &Heightfield,
    first_row: usize,
    heights: &mut [f32],
    material: &mut [u8],
) {
    let cols = grid.cols;
    let band_rows = heights.len() / cols;
    let res = grid.resolution_m;
    for placed in craters {
        let c = &placed.crater;
        let reach = OUTER_REACH * c.radius_m;
        let Some((c0, c1)) = index_range(c.centre_m[0] - reach, c.centre_m[0] + reach, grid.origin_m[0], res, cols)
        else {
            continue;
        };
        let Some((r0, r1)) =
            index_range(c.centre_m[1] - reach, c.centre_m[1] + reach, grid.origin_m[1], res, grid.rows)
        else {
            continue;
        };
        let (r0, r1) = (r0.max(first_row), r1.min(first_row + band_rows - 1));
        let ejecta = placed.freshness > EJECTA_MIN_FRESHNESS;
        // Ejecta reach 1.3 to 2.3 rim radii for the freshest craters, in lumps a quarter radius wide.
        let ejecta_extent = 0.3 + (placed.freshness - EJECTA_MIN_FRESHNESS) / (1.0 - EJECTA_MIN_FRESHNESS);
        let lump_scale = 4.0 / c.radius_m;
        for row in r0..=r1 {
            let y = grid.origin_m[1] + row as f64 * res;
            let dy = y - c.centre_m[1];
            let base = (row - first_row) * cols;
            for col in c0..=c1 {
                let x = grid.origin_m[0] + col as f64 * res;
                let dx = x - c.centre_m[0];
                let r2 = dx * dx + dy * dy;
                if r2 >= reach * reach {
                    continue;
                }
                let r = r2.sqrt();
                let i = base + col;
                heights[i] = (f64::from(heights[i]) + profile_m(c, r)) as f32;
                if r < BOWL_MATERIAL_FRACTION * c.radius_m {
                    material[i] = Material::Regolith as u8;
                } else if ejecta {
                    let lump = noise::value_noise(placed.ejecta_seed, x * lump_scale, y * lump_scale);
                    if r < c.radius_m * (1.0 + ejecta_extent * (0.5 + 0.5 * lump)) {
                        material[i] = Material::Ejecta as u8;
                    }
                }
            }
        }
    }
}

/// Inclusive index range of the cells whose centres lie in `[lo, hi]`, `None` if empty.
pub(super) fn index_range(lo: f64, hi: f64, origin: f64, res: f64, n: usize) -> Option<(usize, usize)> {
    let a = ((lo - origin) / res).ceil().max(0.0);
    let b = ((hi - origin) / res).floor().min(n as f64 - 1.0);
    (b >= a).then_some((a as usize, b as usize))
}

/// Arcs of `crater`'s rim that are negative obstacles, measured on `hf`.
pub(super) fn edge_obstacles(crater: &Crater, hf: &Heightfield, out: &mut Vec<NegativeObstacle>) {
    // Later craters and the slope limit only ever reduce a crater's relief.
    if crater.depth_m + crater.rim_height_m <= CRATER_EDGE_MIN_DROP_M {
        return;
    }
    let step = 0.5 * hf.resolution_m;
    let samples = ((std::f64::consts::TAU * crater.radius_m / 0.25).ceil() as usize).clamp(16, 1024);
    let mut points: Vec<Option<([f64; 2], f64)>> = Vec::with_capacity(samples);
    for k in 0..samples {
        let theta = std::f64::consts::TAU * k as f64 / samples as f64;
        let (s, c) = theta.sin_cos();
        let at = |r: f64| hf.height_at(crater.centre_m[0] + r * c, crater.centre_m[1] + r * s);
        // The crest: the highest point near the nominal rim radius.
        let mut crest: Option<(f64, f64)> = None;
        let mut r = 0.8 * crater.radius_m;
        while r <= 1.2 * crater.radius_m {
            if let Some(h) = at(r)
                && crest.is_none_or(|(_, best)| h > best)
            {
                crest = Some((r, h));
            }
            r += step;
        }
        let edge = crest.and_then(|(r_crest, h_crest)| {
            let mut lowest = h_crest;
            let mut d = step;
            while d <= CRATER_EDGE_RUN_M && r_crest - d > 0.0 {
                lowest = lowest.min(at(r_crest - d)?);
                d += step;
            }
            let drop = h_crest - lowest;
            (drop > CRATER_EDGE_MIN_DROP_M)
                .then_some(([crater.centre_m[0] + r_crest * c, crater.centre_m[1] + r_crest * s], drop))
        });
        points.push(edge);
    }
    arcs(&points, out);
}

/// Splits the ring of samples into runs of consecutive edge points (joined across the seam).
fn arcs(points: &[Option<([f64; 2], f64)>], out: &mut Vec<NegativeObstacle>) {
    let n = points.len();
    let Some(start) = points.iter().position(Option::is_none) else {
        // The whole rim: a closed polyline.
        let mut edge: Vec<[f64; 2]> = points.iter().flatten().map(|p| p.0).collect();
        let drop_m = points.iter().flatten().map(|p| p.1).fold(0.0, f64::max);
        if let Some(&first) = edge.first() {
            edge.push(first);
        }
        out.push(NegativeObstacle { kind: NegativeObstacleKind::CraterEdge, edge_m: edge, drop_m });
        return;
    };
    let mut edge = Vec::new();
    let mut drop_m: f64 = 0.0;
    // Starting just after a gap, every run is met whole.
    for k in 1..=n {
        match points[(start + k) % n] {
            Some((p, d)) => {
                edge.push(p);
                drop_m = drop_m.max(d);
            }
            None => {
                if edge.len() >= 2 {
                    out.push(NegativeObstacle {
                        kind: NegativeObstacleKind::CraterEdge,
                        edge_m: std::mem::take(&mut edge),
                        drop_m,
                    });
                }
                edge.clear();
                drop_m = 0.0;
            }
        }
    }
}
