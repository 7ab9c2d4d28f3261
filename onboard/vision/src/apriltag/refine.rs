//! Edge refinement on the full-resolution image.
//!
//! A quad from the (possibly decimated) threshold image is only as good as the threshold's
//! boundary points. Each edge is therefore sampled at `max(16, length / 8)` points (the ends left
//! out, corners are the least reliable), and at each the image is searched along the edge's
//! outward normal, ±(decimation + 1) px in quarter-pixel steps, for the dark-to-light step: the
//! difference of the image one pixel further out and one further in (bilinear: the nearest
//! pixels would bias a sharp edge by an eighth of a pixel, the upstream library's error before
//! 3.4.3), kept where the outside is the brighter, weighs each offset by its square. The weighted mean offset is the edge's
//! position there; a line through those positions replaces the edge, and the corners become the
//! new lines' intersections (a corner whose lines found no edge, or are nearly parallel, stays).

use super::decode::bilinear;
use super::quad::{Line, intersect, line_from_moments};

/// Moves the corners of `p` (clockwise on screen, black inside) onto the strongest edges of
/// `image` within `decimate + 1` px of the current edges.
pub(crate) fn refine_edges(p: &mut [[f64; 2]; 4], image: &[u8], width: usize, height: usize, decimate: f64) {
    let mut lines: [Option<Line>; 4] = [None; 4];
    let range = decimate + 1.0;
    let steps = (8.0 * range).round() as i32;
    for (edge, line) in lines.iter_mut().enumerate() {
        let (a, b) = (p[edge], p[(edge + 1) % 4]);
        let (mut nx, mut ny) = (b[1] - a[1], a[0] - b[0]);
        let length = (nx * nx + ny * ny).sqrt();
        if !(length > 0.0) || !length.is_finite() {
            continue;
        }
        nx /= length;
        ny /= length;
        let samples = ((length / 8.0) as usize).max(16);
        // Moments relative to the edge's start, for precision.
        let (mut n, mut mx, mut my, mut mxx, mut mxy, mut myy) = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
        for s in 0..samples {
            let alpha = (1.0 + s as f64) / (samples as f64 + 1.0);
            let x0 = alpha * a[0] + (1.0 - alpha) * b[0];
            let y0 = alpha * a[1] + (1.0 - alpha) * b[1];
            let (mut offset_sum, mut weight_sum) = (0.0, 0.0);
            for k in 0..=steps {
                let t = -range + 0.25 * f64::from(k);
                let Some(outer) = bilinear(image, width, height, x0 + (t + 1.0) * nx, y0 + (t + 1.0) * ny) else {
                    continue;
                };
                let Some(inner) = bilinear(image, width, height, x0 + (t - 1.0) * nx, y0 + (t - 1.0) * ny) else {
                    continue;
                };
                // Only a step towards brighter outside is the tag's edge.
                if outer < inner {
                    continue;
                }
                let weight = (outer - inner) * (outer - inner);
                offset_sum += weight * t;
                weight_sum += weight;
            }
            if weight_sum == 0.0 {
                continue;
            }
            let t = offset_sum / weight_sum;
            let (x, y) = (x0 + t * nx - a[0], y0 + t * ny - a[1]);
            n += 1.0;
            mx += x;
            my += y;
            mxx += x * x;
            mxy += x * y;
            myy += y * y;
        }
        if n < 2.0 {
            continue;
        }
        let (mut l, _) = line_from_moments(n, mx, my, mxx, mxy, myy);
        l.point[0] += a[0];
        l.point[1] += a[1];
        *line = Some(l);
    }
    for i in 0..4 {
        if let (Some(l0), Some(l1)) = (&lines[i], &lines[(i + 1) % 4])
            && let Some(c) = intersect(l0, l1)
        {
            p[i] = c;
        }
    }
}
