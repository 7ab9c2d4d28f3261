//! The triangle mesh over a heightfield's cell centres, and its text export.

use std::fmt::Write as _;

use super::Heightfield;

/// The mesh triangle under a point: the height at its `(c, r)` corner, its gradient, and the
/// point's offset from that corner.
#[derive(Debug, Clone, Copy)]
pub(super) struct Triangle {
    pub h00: f64,
    pub gx_m: f64,
    pub gy_m: f64,
    pub dx_m: f64,
    pub dy_m: f64,
}

pub(super) fn triangle_at(hf: &Heightfield, x_m: f64, y_m: f64) -> Option<Triangle> {
    if hf.cols < 2 || hf.rows < 2 || hf.heights_m.len() < hf.cols * hf.rows {
        return None;
    }
    let fx = (x_m - hf.origin_m[0]) / hf.resolution_m;
    let fy = (y_m - hf.origin_m[1]) / hf.resolution_m;
    // Written so that NaN fails too.
    if !(fx >= 0.0 && fx <= (hf.cols - 1) as f64 && fy >= 0.0 && fy <= (hf.rows - 1) as f64) {
        return None;
    }
    // The last row and column of centres belong to the squares before them.
    let c = (fx as usize).min(hf.cols - 2);
    let r = (fy as usize).min(hf.rows - 2);
    let (u, v) = (fx - c as f64, fy - r as f64);
    let at = |cc: usize, rr: usize| f64::from(hf.heights_m[rr * hf.cols + cc]);
    let (h00, h10, h01, h11) = (at(c, r), at(c + 1, r), at(c, r + 1), at(c + 1, r + 1));
    let inv = 1.0 / hf.resolution_m;
    // Lower triangle (c,r),(c+1,r),(c+1,r+1) when u ≥ v; upper (c,r),(c,r+1),(c+1,r+1) otherwise.
    let (gx_m, gy_m) =
        if u >= v { ((h10 - h00) * inv, (h11 - h10) * inv) } else { ((h11 - h01) * inv, (h01 - h00) * inv) };
    Some(Triangle { h00, gx_m, gy_m, dx_m: u * hf.resolution_m, dy_m: v * hf.resolution_m })
}

pub(super) fn triangle_slopes(hf: &Heightfield) -> Vec<[f32; 2]> {
    if hf.cols < 2 || hf.rows < 2 {
        return Vec::new();
    }
    let inv = 1.0 / hf.resolution_m;
    let mut out = Vec::with_capacity((hf.cols - 1) * (hf.rows - 1));
    for r in 0..hf.rows - 1 {
        let row0 = &hf.heights_m[r * hf.cols..(r + 1) * hf.cols];
        let row1 = &hf.heights_m[(r + 1) * hf.cols..(r + 2) * hf.cols];
        for c in 0..hf.cols - 1 {
            let (h00, h10, h01, h11) =
                (f64::from(row0[c]), f64::from(row0[c + 1]), f64::from(row1[c]), f64::from(row1[c + 1]));
            let lower = ((h10 - h00) * inv).hypot((h11 - h10) * inv).atan();
            let upper = ((h11 - h01) * inv).hypot((h01 - h00) * inv).atan();
            out.push([lower as f32, upper as f32]);
        }
    }
    out
}

pub(super) fn height_grid_text(hf: &Heightfield, min_m: [f64; 2], max_m: [f64; 2], step: usize) -> String {
    let step = step.max(1);
    // A centre exactly on a bound is inside; the tolerance absorbs the rounding of the division.
    let first = |min: f64, origin: f64| ((min - origin) / hf.resolution_m - 1e-9).ceil().max(0.0);
    let last = |max: f64, origin: f64, n: usize| ((max - origin) / hf.resolution_m + 1e-9).floor().min(n as f64 - 1.0);
    let (c0, c1) = (first(min_m[0], hf.origin_m[0]), last(max_m[0], hf.origin_m[0], hf.cols));
    let (r0, r1) = (first(min_m[1], hf.origin_m[1]), last(max_m[1], hf.origin_m[1], hf.rows));
    let count = |lo: f64, hi: f64| if hi >= lo { (hi - lo) as usize / step + 1 } else { 0 };
    let (cols, rows) = (count(c0, c1), count(r0, r1));
    let (c0, r0) = (c0 as usize, r0 as usize);
    let origin = hf.cell_centre_m(c0, r0);
    let mut out = String::with_capacity(64 + cols * rows * 8);
    let _ = writeln!(
        out,
        "HEIGHTGRID v1 {cols} {rows} {:?} {:?} {:?}",
        hf.resolution_m * step as f64,
        origin[0],
        origin[1]
    );
    for j in 0..rows {
        let r = r0 + j * step;
        for i in 0..cols {
            let h = hf.heights_m[r * hf.cols + c0 + i * step];
            let sep = if i == 0 { "" } else { " " };
            let _ = if h.is_finite() { write!(out, "{sep}{h:.3}") } else { write!(out, "{sep}nan") };
        }
        out.push('\n');
    }
    out
}
