//! The angle of repose: loose regolith does not stand steeper than about 30°, wherever relief
//! and overlapping craters would add up to more.
//!
//! [`limit`] first replaces the heights by the largest surface below them whose drop to any of
//! the eight neighbours is at most `max_tan` times their distance: crests and rims are cut back,
//! floors stay. That surface is `h'(p) = min_q h(q) + max_tan · d(p, q)` over chamfer paths, a
//! distance transform that two raster sweeps compute exactly in O(cells). Bounded drops to the
//! neighbours still allow a mesh triangle up to √2 steeper where a one-cell ridge runs across
//! the triangle split (both legs at the limit, in opposite senses), which sharp crater rims
//! produce; a worklist over the triangles then lowers the top corner of each such triangle
//! until the mesh itself is nowhere steeper than the limit.

use super::Heightfield;

/// Cuts `hf` down so that no mesh triangle is steeper than `max_tan` (up to f32 rounding);
/// returns the number of corner corrections the triangle pass made.
pub fn limit(hf: &mut Heightfield, max_tan: f64) -> usize {
    if !(max_tan.is_finite() && max_tan > 0.0) || hf.cols < 2 || hf.rows < 2 {
        return 0;
    }
    limit_neighbour_drops(hf, max_tan);
    limit_triangles(hf, max_tan)
}

/// A triangle corner: its `(column, row)` offset and its gradient weights.
type Corner = ((usize, usize), (f64, f64));

/// Corners of the two triangles of a cell square as offsets from its `(c, r)` corner, and the
/// change of the triangle's gradient (in height per cell) per unit height of each corner.
/// Lower triangle (c,r),(c+1,r),(c+1,r+1): `g = (h₁ − h₀, h₂ − h₁)`; upper (c,r),(c,r+1),
/// (c+1,r+1): `g = (h₂ − h₁, h₁ − h₀)`.
const TRIANGLES: [[Corner; 3]; 2] = [
    [((0, 0), (-1.0, 0.0)), ((1, 0), (1.0, -1.0)), ((1, 1), (0.0, 1.0))],
    [((0, 0), (0.0, -1.0)), ((0, 1), (-1.0, 1.0)), ((1, 1), (1.0, 0.0))],
];

/// Relative slack on the slope before a triangle counts as too steep: f32 heights of a few
/// metres carry about 1e-6 m of rounding, 2e-5 of a 5 cm cell.
const SLOPE_SLACK: f64 = 1e-4;

/// A worklist of triangles `(square, which)`: every triangle steeper than the limit lowers one
/// corner, and the triangles around a lowered corner are checked again. Heights only go down, so
/// the corrections spread outwards like the neighbour pass's cones and stop.
fn limit_triangles(hf: &mut Heightfield, max_tan: f64) -> usize {
    let cols = hf.cols;
    let squares_per_row = cols - 1;
    let squares = squares_per_row * (hf.rows - 1);
    let limit_cells = max_tan * hf.resolution_m;
    let mut queue: std::collections::VecDeque<(usize, usize)> = std::collections::VecDeque::new();
    for square in 0..squares {
        for which in 0..2 {
            if steepness(hf, square, which, limit_cells).is_some() {
                queue.push_back((square, which));
            }
        }
    }
    let mut corrections = 0;
    while let Some((square, which)) = queue.pop_front() {
        let Some(lowered) =
            steepness(hf, square, which, limit_cells).map(|v| correct(hf, square, which, v, limit_cells))
        else {
            continue;
        };
        corrections += 1;
        // Recheck the eight triangles of the four squares around the lowered corner.
        let (c, r) = (lowered % cols, lowered / cols);
        for sr in r.saturating_sub(1)..=r.min(hf.rows - 2) {
            for sc in c.saturating_sub(1)..=c.min(cols - 2) {
                queue.push_back((sr * squares_per_row + sc, 0));
                queue.push_back((sr * squares_per_row + sc, 1));
            }
        }
    }
    corrections
}

/// The corner heights of a triangle steeper than the limit, `None` if it is not.
fn steepness(hf: &Heightfield, square: usize, which: usize, limit_cells: f64) -> Option<[f64; 3]> {
    let cols = hf.cols;
    let (c, r) = (square % (cols - 1), square / (cols - 1));
    let hv = TRIANGLES[which].map(|((dc, dr), _)| f64::from(hf.heights_m[(r + dr) * cols + c + dc]));
    let (gx, gy) = gradient(which, &hv);
    let limit = limit_cells * (1.0 + SLOPE_SLACK);
    (gx * gx + gy * gy > limit * limit).then_some(hv)
}

fn gradient(which: usize, hv: &[f64; 3]) -> (f64, f64) {
    TRIANGLES[which].iter().zip(hv).fold((0.0, 0.0), |g, ((_, e), h)| (g.0 + e.0 * h, g.1 + e.1 * h))
}

/// Lowers one corner of a too-steep triangle with corner heights `hv`; returns its cell index.
/// Normally the top corner drops to the highest height at which the triangle is at the limit.
/// If the edge between the other two corners is itself too steep (an earlier correction made
/// it so), no height of the top corner helps: the higher end of that edge drops instead.
fn correct(hf: &mut Heightfield, square: usize, which: usize, hv: [f64; 3], limit_cells: f64) -> usize {
    let cols = hf.cols;
    let (c, r) = (square % (cols - 1), square / (cols - 1));
    let corners = TRIANGLES[which];
    let index = corners.map(|((dc, dr), _)| (r + dr) * cols + c + dc);
    let top = (0..3).fold(0, |best, k| if hv[k] > hv[best] { k } else { best });
    let (p, q) = ((top + 1) % 3, (top + 2) % 3);
    let edge_cells = {
        let (a, b) = (corners[p].0, corners[q].0);
        ((a.0 as f64 - b.0 as f64).powi(2) + (a.1 as f64 - b.1 as f64).powi(2)).sqrt()
    };
    if (hv[p] - hv[q]).abs() > limit_cells * edge_cells {
        let (high, low) = if hv[p] > hv[q] { (p, q) } else { (q, p) };
        set_below(hf, index[high], hv[low] + limit_cells * edge_cells);
        return index[high];
    }
    // g(t) = g₀ + t·e with t the top corner's height: the largest t with |g(t)| at the limit.
    let e = corners[top].1;
    let (gx, gy) = gradient(which, &hv);
    let g0 = (gx - e.0 * hv[top], gy - e.1 * hv[top]);
    let a = e.0 * e.0 + e.1 * e.1;
    let b = 2.0 * (g0.0 * e.0 + g0.1 * e.1);
    let cc = g0.0 * g0.0 + g0.1 * g0.1 - limit_cells * limit_cells;
    // The opposite edge is within the limit, so the discriminant is not negative (up to rounding).
    let t = (-b + (b * b - 4.0 * a * cc).max(0.0).sqrt()) / (2.0 * a);
    set_below(hf, index[top], t.min(hv[top]));
    index[top]
}

/// Stores `value` rounded down to f32 (never above `value`, so a corrected triangle stays
/// within the limit), and never raises the cell.
fn set_below(hf: &mut Heightfield, index: usize, value: f64) {
    let mut v = value as f32;
    if f64::from(v) > value {
        v = v.next_down();
    }
    if v < hf.heights_m[index] {
        hf.heights_m[index] = v;
    } else {
        // Rounding left it where it was: step one f32 below so the worklist makes progress.
        hf.heights_m[index] = hf.heights_m[index].next_down();
    }
}

/// The largest surface below `hf` whose drop between 8-neighbours is at most `max_tan` per metre.
fn limit_neighbour_drops(hf: &mut Heightfield, max_tan: f64) {
    let cols = hf.cols;
    let rows = hf.rows;
    let axial = (max_tan * hf.resolution_m) as f32;
    let diagonal = (max_tan * hf.resolution_m * std::f64::consts::SQRT_2) as f32;
    let h = &mut hf.heights_m;
    // Forward sweep: neighbours already visited are west, south-west, south and south-east.
    for r in 0..rows {
        for c in 0..cols {
            let i = r * cols + c;
            let mut v = h[i];
            if c > 0 {
                v = v.min(h[i - 1] + axial);
            }
            if r > 0 {
                let j = i - cols;
                v = v.min(h[j] + axial);
                if c > 0 {
                    v = v.min(h[j - 1] + diagonal);
                }
                if c + 1 < cols {
                    v = v.min(h[j + 1] + diagonal);
                }
            }
            h[i] = v;
        }
    }
    // Backward sweep: east, north-east, north and north-west.
    for r in (0..rows).rev() {
        for c in (0..cols).rev() {
            let i = r * cols + c;
            let mut v = h[i];
            if c + 1 < cols {
                v = v.min(h[i + 1] + axial);
            }
            if r + 1 < rows {
                let j = i + cols;
                v = v.min(h[j] + axial);
                if c + 1 < cols {
                    v = v.min(h[j + 1] + diagonal);
                }
                if c > 0 {
                    v = v.min(h[j - 1] + diagonal);
                }
            }
            h[i] = v;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng;

    fn random_field(cols: usize, rows: usize, seed: u64, amplitude: f64) -> Heightfield {
        let heights_m = (0..cols * rows)
            .map(|i| (amplitude * rng::hash_unit(seed, (i % cols) as i64, (i / cols) as i64)) as f32)
            .collect();
        Heightfield { resolution_m: 0.05, origin_m: [0.0, 0.0], cols, rows, heights_m }
    }

    #[test]
    fn limited_field_respects_the_bound_and_only_lowers() {
        let original = random_field(60, 45, 5, 1.0);
        let mut hf = original.clone();
        let max_tan = 30f64.to_radians().tan();
        limit(&mut hf, max_tan);
        let steepest = hf.triangle_slopes_rad().iter().flatten().fold(0f32, |a, &b| a.max(b));
        // Triangles count as too steep beyond the slack only.
        assert!(f64::from(steepest).tan() <= max_tan * (1.0 + SLOPE_SLACK), "{}°", steepest.to_degrees());
        let tol = 1e-5;
        for r in 0..hf.rows as isize {
            for c in 0..hf.cols as isize {
                let h = hf.height_at_cell(c, r);
                assert!(h <= original.height_at_cell(c, r));
                for (dc, dr) in [(1, 0), (0, 1), (1, 1), (1, -1)] {
                    let (cc, rr) = (c + dc, r + dr);
                    if cc >= hf.cols as isize || rr < 0 || rr >= hf.rows as isize {
                        continue;
                    }
                    let d = hf.resolution_m * ((dc * dc + dr * dr) as f64).sqrt();
                    let dh = f64::from((hf.height_at_cell(cc, rr) - h).abs());
                    assert!(dh <= max_tan * d + tol, "({c},{r})→({cc},{rr}): {dh} over {d}");
                }
            }
        }
    }

    #[test]
    fn a_diagonal_ridge_is_lowered_to_the_limit() {
        // A one-cell ridge across the split: both legs of the lower triangle at the limit.
        let mut hf = Heightfield {
            resolution_m: 1.0,
            origin_m: [0.0, 0.0],
            cols: 2,
            rows: 2,
            heights_m: vec![0.0, 0.5, 0.0, 0.0],
        };
        let before = hf.triangle_slopes_rad()[0][0];
        assert!(f64::from(before).tan() > 0.7);
        limit(&mut hf, 0.5);
        let after = hf.triangle_slopes_rad()[0];
        assert!((f64::from(after[0]).tan() - 0.5).abs() < 1e-4 && f64::from(after[1]).tan() <= 0.5 + 1e-5, "{after:?}");
    }

    #[test]
    fn the_neighbour_pass_is_the_largest_such_field() {
        // A single pit in a flat plane becomes a cone of the limiting slope (chamfer metric):
        // any lower result would not be the largest, any higher one would be too steep.
        let mut hf =
            Heightfield { resolution_m: 0.1, origin_m: [0.0, 0.0], cols: 41, rows: 41, heights_m: vec![0.0; 41 * 41] };
        hf.heights_m[20 * 41 + 20] = -1.0;
        limit_neighbour_drops(&mut hf, 0.5);
        assert_eq!(hf.height_at_cell(20, 20), -1.0);
        assert!((hf.height_at_cell(25, 20) - (-1.0 + 0.5 * 0.5)).abs() < 1e-5);
        let diag = -1.0 + 0.5 * 0.3 * std::f32::consts::SQRT_2;
        assert!((hf.height_at_cell(23, 23) - diag).abs() < 1e-5);
        assert_eq!(hf.height_at_cell(0, 0), 0.0);
    }
}
