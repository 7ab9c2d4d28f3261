//! Exact ray casting against the terrain mesh: the ground truth the rasteriser is checked against.
//!
//! A 2D DDA walks the grid squares the ray passes over, in order; each square's two triangles are
//! intersected exactly (Möller–Trumbore in `f64`), so the first square with a hit holds the
//! nearest one.

use nalgebra::{Isometry3, Vector3};

use crate::camera::StereoCamera;
use crate::terrain::{Heightfield, Terrain};

/// Distance along `dir` from `origin` to triangle `(a, b, c)` (either side), with the edges
/// included so that a ray through a shared edge hits one of its triangles.
fn ray_triangle(
    origin: &Vector3<f64>,
    dir: &Vector3<f64>,
    a: &Vector3<f64>,
    b: &Vector3<f64>,
    c: &Vector3<f64>,
) -> Option<f64> {
    const EDGE_EPS: f64 = 1e-12;
    let e1 = b - a;
    let e2 = c - a;
    let p = dir.cross(&e2);
    let det = e1.dot(&p);
    if det.abs() < 1e-300 {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - a;
    let u = s.dot(&p) * inv;
    if !(-EDGE_EPS..=1.0 + EDGE_EPS).contains(&u) {
        return None;
    }
    let q = s.cross(&e1);
    let v = dir.dot(&q) * inv;
    if v < -EDGE_EPS || u + v > 1.0 + EDGE_EPS {
        return None;
    }
    let t = e2.dot(&q) * inv;
    (t > 0.0).then_some(t)
}

/// Nearest hit of the ray `origin + t · dir` (`t > 0`) with the heightfield's mesh.
pub(crate) fn raycast(hf: &Heightfield, origin: &Vector3<f64>, dir: &Vector3<f64>) -> Option<f64> {
    if hf.cols < 2 || hf.rows < 2 {
        return None;
    }
    let res = hf.resolution_m;
    // Grid coordinates: vertex (c, r) at (c, r); square (c, r) spans [c, c + 1] × [r, r + 1].
    let g0 = [(origin.x - hf.origin_m[0]) / res, (origin.y - hf.origin_m[1]) / res];
    let gd = [dir.x / res, dir.y / res];
    let hi = [(hf.cols - 1) as f64, (hf.rows - 1) as f64];
    let (mut t_enter, mut t_exit) = (0.0_f64, f64::INFINITY);
    for k in 0..2 {
        if gd[k] == 0.0 {
            if g0[k] < 0.0 || g0[k] > hi[k] {
                return None;
            }
        } else {
            let (ta, tb) = ((0.0 - g0[k]) / gd[k], (hi[k] - g0[k]) / gd[k]);
            t_enter = t_enter.max(ta.min(tb));
            t_exit = t_exit.min(ta.max(tb));
        }
    }
    if t_enter > t_exit {
        return None;
    }
    let square = |k: usize, t: f64| (g0[k] + t * gd[k]).floor().clamp(0.0, hi[k] - 1.0) as i64;
    let mut cell = [square(0, t_enter), square(1, t_enter)];
    let mut step = [0_i64; 2];
    let mut t_next = [f64::INFINITY; 2];
    let mut t_delta = [f64::INFINITY; 2];
    for k in 0..2 {
        if gd[k] > 0.0 {
            step[k] = 1;
            t_next[k] = (cell[k] as f64 + 1.0 - g0[k]) / gd[k];
            t_delta[k] = 1.0 / gd[k];
        } else if gd[k] < 0.0 {
            step[k] = -1;
            t_next[k] = (cell[k] as f64 - g0[k]) / gd[k];
            t_delta[k] = -1.0 / gd[k];
        }
    }
    let mut t_a = t_enter;
    loop {
        let t_b = t_next[0].min(t_next[1]).min(t_exit);
        if let Some(t) = hit_square(hf, origin, dir, cell[0] as usize, cell[1] as usize, t_a, t_b) {
            return Some(t);
        }
        if t_b >= t_exit {
            return None;
        }
        let k = if t_next[0] < t_next[1] { 0 } else { 1 };
        cell[k] += step[k];
        t_a = t_next[k];
        t_next[k] += t_delta[k];
        if cell[k] < 0 || cell[k] as f64 > hi[k] - 1.0 {
            return None;
        }
    }
}

fn hit_square(
    hf: &Heightfield,
    origin: &Vector3<f64>,
    dir: &Vector3<f64>,
    c: usize,
    r: usize,
    t_a: f64,
    t_b: f64,
) -> Option<f64> {
    let h = |c: usize, r: usize| f64::from(hf.heights_m[r * hf.cols + c]);
    let (h00, h10, h01, h11) = (h(c, r), h(c + 1, r), h(c, r + 1), h(c + 1, r + 1));
    // Skip squares the ray passes entirely above (the common case far from the hit).
    let z_low = (origin.z + t_a * dir.z).min(origin.z + t_b * dir.z);
    if z_low > h00.max(h10).max(h01).max(h11) + 1e-9 {
        return None;
    }
    let (x0, y0) = (hf.origin_m[0] + c as f64 * hf.resolution_m, hf.origin_m[1] + r as f64 * hf.resolution_m);
    let (x1, y1) = (x0 + hf.resolution_m, y0 + hf.resolution_m);
    let v00 = Vector3::new(x0, y0, h00);
    let v10 = Vector3::new(x1, y0, h10);
    let v01 = Vector3::new(x0, y1, h01);
    let v11 = Vector3::new(x1, y1, h11);
    let lower = ray_triangle(origin, dir, &v00, &v10, &v11);
    let upper = ray_triangle(origin, dir, &v00, &v11, &v01);
    match (lower, upper) {
        (Some(a), Some(b)) => Some(a.min(b)),
        (a, b) => a.or(b),
    }
}

/// Exact z-depth of the terrain mesh (robots ignored) seen through pixel `(u, v)` of the camera
/// at `t_world_cam`, by ray casting; `None` when the ray leaves the terrain.
pub fn raycast_depth_m(
    terrain: &Terrain,
    camera: &StereoCamera,
    t_world_cam: &Isometry3<f64>,
    u: f64,
    v: f64,
) -> Option<f64> {
    // The ray has camera z = 1, so its parameter at the hit is the z-depth.
    let dir = t_world_cam.rotation * camera.ray(u, v);
    raycast(&terrain.heightfield, &t_world_cam.translation.vector, &dir)
}
