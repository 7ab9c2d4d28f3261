//! Radiance of each pixel from the z-buffer: terrain, robot faces and sky.
//!
//! The geometry pass leaves `1/z`, a surface id and the slopes of the triangle seen per pixel;
//! the world point is rebuilt from the depth along the pixel's ray, and the shadow and the albedo
//! (filtered for the pixel's footprint) are looked up there.

use nalgebra::{Matrix3, Vector3};

use super::{Quad, QuadSurface, Scene};
use crate::lighting::Reflectance;
use crate::markers::{TAG_CELLS, tag_cell_is_white};
use crate::terrain::Heightfield;

/// Albedo of a tag's white and black cells (matte print).
pub const TAG_WHITE_ALBEDO: f32 = 0.8;
pub const TAG_BLACK_ALBEDO: f32 = 0.03;
/// Albedo of the back of a tag plate.
pub const TAG_BACK_ALBEDO: f32 = 0.3;
/// Share of the sun's horizontal irradiance that reaches any surface indirectly, reflected by
/// the sunlit ground and rocks around it (times the terrain's mean albedo). Without it, shadows
/// on airless bodies would be exactly black and textureless, which real images never are.
pub const BOUNCE_FRACTION: f32 = 0.3;

/// One camera looking at the scene.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Eye {
    pub origin_world: Vector3<f64>,
    pub r_world_cam: Matrix3<f64>,
    pub f: f64,
    pub cx: f64,
    pub cy: f64,
    pub width: usize,
    pub height: usize,
}

/// Lighting of a frame, evaluated once.
#[derive(Debug, Clone, Copy)]
struct Light {
    to_sun: Vector3<f64>,
    irradiance: f32,
    sky: f32,
    /// Indirect irradiance on a surface facing straight up.
    bounce: f32,
}

impl Light {
    fn new(scene: &Scene<'_>) -> Light {
        let to_sun = scene.sun.direction_world();
        let horizontal = scene.sun.irradiance * to_sun.z.max(0.0) as f32;
        Light {
            to_sun,
            irradiance: scene.sun.irradiance,
            sky: scene.sky_radiance,
            bounce: BOUNCE_FRACTION * scene.terrain.config.albedo_mean * horizontal,
        }
    }

    /// Sky and ground light reaching a surface with upward component `n_z` of its normal: the sky
    /// fills the upper part of its hemisphere, the ground the rest (and a little of it always).
    #[inline]
    fn ambient(&self, n_z: f64) -> f32 {
        ambient(self.sky, self.bounce, n_z as f32)
    }
}

/// [`Light::ambient`] from its parts, for the vectorised pixel loop.
#[inline(always)]
fn ambient(sky: f32, bounce: f32, n_z: f32) -> f32 {
    let up = 0.5 * (1.0 + n_z);
    sky * up + bounce * (1.0 - 0.5 * up)
}

/// The full-resolution mesh, for the normals of skirt pixels (cracks between levels of detail).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Grid<'a> {
    heights_m: &'a [f32],
    cols: usize,
    origin_m: [f64; 2],
    inv_res: f64,
    /// Largest grid coordinate of a square's corner `(c, r)`, as floats for clamping.
    max_square: [f64; 2],
}

impl<'a> Grid<'a> {
    /// `None` without a single square.
    pub fn new(hf: &'a Heightfield) -> Option<Grid<'a>> {
        (hf.cols >= 2 && hf.rows >= 2 && hf.heights_m.len() >= hf.cols * hf.rows).then(|| Grid {
            heights_m: &hf.heights_m,
            cols: hf.cols,
            origin_m: hf.origin_m,
            inv_res: 1.0 / hf.resolution_m,
            max_square: [(hf.cols - 2) as f64, (hf.rows - 2) as f64],
        })
    }

    /// Slopes `(dz/dx, dz/dy)` of the mesh triangle under `(x, y)` (clamped to the grid).
    #[inline]
    pub fn slopes(&self, x_m: f64, y_m: f64) -> (f32, f32) {
        let gx = ((x_m - self.origin_m[0]) * self.inv_res).max(0.0);
        let gy = ((y_m - self.origin_m[1]) * self.inv_res).max(0.0);
        // Truncation is the floor for non-negative values, without a libm call.
        let c = gx.min(self.max_square[0]) as usize;
        let r = gy.min(self.max_square[1]) as usize;
        let (fx, fy) = (gx - c as f64, gy - r as f64);
        let i = r * self.cols + c;
        let h = self.heights_m;
        let (h00, h10, h01, h11) = (h[i], h[i + 1], h[i + self.cols], h[i + self.cols + 1]);
        // The diagonal runs from (c, r) to (c + 1, r + 1); below it (fx ≥ fy) is (c + 1, r)'s side.
        let (dzdx, dzdy) = if fx >= fy { (h10 - h00, h11 - h10) } else { (h11 - h01, h01 - h00) };
        let inv_res = self.inv_res as f32;
        (dzdx * inv_res, dzdy * inv_res)
    }
}

/// Per-row scratch of the shading passes (sized for one image row at construction), one entry
/// per terrain pixel of the row.
#[derive(Debug, Clone, Default)]
pub(crate) struct RowScratch {
    /// Which pixel of the row.
    pixel: Vec<u32>,
    /// World point.
    x_m: Vec<f64>,
    y_m: Vec<f64>,
    /// `1/z`, then the depth; the ray through the pixel (camera z = 1), world frame.
    z_m: Vec<f32>,
    dir: [Vec<f32>; 3],
    /// Slopes of the triangle seen, then the unit normal.
    normal: [Vec<f32>; 3],
    /// Unit vector towards the camera.
    to_viewer: [Vec<f32>; 3],
    footprint_m: Vec<f32>,
    /// Sun visibility, then reflected light per unit albedo.
    light: Vec<f32>,
    albedo: Vec<f32>,
}

impl RowScratch {
    pub fn new(width: usize) -> RowScratch {
        let f = || vec![0.0_f32; width];
        RowScratch {
            pixel: vec![0; width],
            x_m: vec![0.0; width],
            y_m: vec![0.0; width],
            z_m: f(),
            dir: [f(), f(), f()],
            normal: [f(), f(), f()],
            to_viewer: [f(), f(), f()],
            footprint_m: f(),
            light: f(),
            albedo: f(),
        }
    }
}

/// What the geometry pass left per pixel (see [`super::raster::Target`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pixels<'a> {
    pub inv_z: &'a [f32],
    pub surface: &'a [u32],
    pub slopes: &'a [[f32; 2]],
}

/// Fills `out` with the radiance each pixel of `eye` sees.
///
/// Row by row in short passes, each a loop of independent iterations without calls where it can
/// be (the chain of divisions and square roots of one pixel is long, so pixels must overlap in
/// the pipeline): collect terrain pixels, place them, normalise (vectorised), look up the
/// shadows, light (vectorised), then look up the albedo, all for the row's pixels at once. The normal is that of the triangle drawn: the terrain mesh itself near the camera,
/// a coarser facet where the level of detail is coarse, i.e. where a pixel spans several cells
/// and one cell's normal would alias.
pub(crate) fn shade(scene: &Scene<'_>, eye: &Eye, pixels: &Pixels<'_>, scratch: &mut RowScratch, out: &mut [f32]) {
    let light = Light::new(scene);
    let grid = Grid::new(&scene.terrain.heightfield);
    // Both models as one formula: Lambert is lunar-Lambert with no Lommel–Seeliger share.
    let lommel_seeliger = match scene.reflectance {
        Reflectance::Lambert => 0.0,
        Reflectance::LunarLambert { l } => l,
    };
    let to_sun = [light.to_sun.x as f32, light.to_sun.y as f32, light.to_sun.z as f32];
    let inv_f = 1.0 / eye.f;
    // World ray through pixel (u, v) (scaled to camera z = 1) is row_start(v) + u · du.
    let du = eye.r_world_cam * Vector3::new(inv_f, 0.0, 0.0);
    for v in 0..eye.height {
        let row_start = eye.r_world_cam * Vector3::new(-eye.cx * inv_f, (v as f64 - eye.cy) * inv_f, 1.0);
        let line = v * eye.width;
        let row = line..line + eye.width;
        let out_row = &mut out[row.clone()];
        // Sky and robots here; terrain pixels are collected for the passes below.
        let mut n = 0;
        let (inv_z, surface, slopes) = (&pixels.inv_z[row.clone()], &pixels.surface[row.clone()], &pixels.slopes[row]);
        for (u, (((o, &iz), &id), &sl)) in out_row.iter_mut().zip(inv_z).zip(surface).zip(slopes).enumerate() {
            if iz > 0.0 && (id == super::TERRAIN || id == super::SKIRT) && grid.is_some() {
                let s = &mut *scratch;
                s.pixel[n] = u as u32;
                s.z_m[n] = iz;
                (s.normal[0][n], s.normal[1][n]) = (sl[0], sl[1]);
                if id == super::SKIRT {
                    // A skirt is vertical: shade it as the mesh next to it.
                    if let Some(grid) = &grid {
                        let p = eye.origin_world + (row_start + du * u as f64) * f64::from(1.0 / iz);
                        (s.normal[0][n], s.normal[1][n]) = grid.slopes(p.x, p.y);
                    }
                }
                n += 1;
            } else if iz <= 0.0 || id == super::TERRAIN || id == super::SKIRT {
                *o = light.sky;
            } else {
                let dir = row_start + du * u as f64;
                let p = eye.origin_world + dir * (1.0 / f64::from(iz));
                *o = match scene.quads.get(id as usize - 1) {
                    Some(quad) => quad_radiance(quad, &light, eye, &p, &dir, &du),
                    None => light.sky,
                };
            }
        }
        place(scratch, n, &eye.origin_world, &row_start, &du);
        normalise(scratch, n, eye.f as f32);
        let s = &mut *scratch;
        scene.shadows.lit_many(&s.x_m[..n], &s.y_m[..n], &mut s.light[..n]);
        light_pixels(s, n, &light, to_sun, lommel_seeliger);
        scene.terrain.albedo_filtered_many(&s.x_m[..n], &s.y_m[..n], &s.footprint_m[..n], &mut s.albedo[..n]);
        for k in 0..n {
            out_row[s.pixel[k] as usize] = s.albedo[k] * s.light[k];
        }
    }
}

/// Reflected light per unit albedo of the first `n` pixels, from their sun visibility (in
/// `light` on entry), normals and view directions: [`Reflectance::factor`] in f32.
fn light_pixels(s: &mut RowScratch, n: usize, light: &Light, to_sun: [f32; 3], lommel_seeliger: f32) {
    let [nx, ny, nz] = &s.normal;
    let [vx, vy, vz] = &s.to_viewer;
    let normal = [&nx[..n], &ny[..n], &nz[..n]];
    let to_viewer = [&vx[..n], &vy[..n], &vz[..n]];
    let constants = [light.irradiance, light.sky, light.bounce, lommel_seeliger];
    reflect(normal, to_viewer, to_sun, constants, &mut s.light[..n]);
}

/// The loop of [`light_pixels`], with its slices as arguments (so the compiler knows they do
/// not overlap and vectorises it). `c` is irradiance, sky, bounce and the Lommel–Seeliger weight.
#[inline(never)]
fn reflect(n: [&[f32]; 3], v: [&[f32]; 3], to_sun: [f32; 3], c: [f32; 4], light: &mut [f32]) {
    let [irradiance, sky, bounce, l] = c;
    let len =
        light.len().min(n[0].len()).min(n[1].len()).min(n[2].len()).min(v[0].len()).min(v[1].len()).min(v[2].len());
    let ([nx, ny, nz], [vx, vy, vz]) = (n.map(|a| &a[..len]), v.map(|a| &a[..len]));
    let light = &mut light[..len];
    for k in 0..len {
        let cos_i = nx[k] * to_sun[0] + ny[k] * to_sun[1] + nz[k] * to_sun[2];
        let cos_e = nx[k] * vx[k] + ny[k] * vy[k] + nz[k] * vz[k];
        let factor = cos_i * (2.0 * l / (cos_i + cos_e) + (1.0 - l));
        let direct = irradiance * factor * light[k];
        // `&` rather than `&&`, and computed either way: a select, so that the loop vectorises.
        let direct = if (cos_i > 0.0) & (cos_e > 0.0) { direct } else { 0.0 };
        light[k] = direct + ambient(sky, bounce, nz[k]);
    }
}

/// World points and rays of the first `n` collected pixels (whose `z_m` holds `1/z` on entry).
fn place(s: &mut RowScratch, n: usize, origin: &Vector3<f64>, row_start: &Vector3<f64>, du: &Vector3<f64>) {
    let [dx, dy, dz] = &mut s.dir;
    let (pixel, z) = (&s.pixel[..n], &mut s.z_m[..n]);
    let (x_m, y_m) = (&mut s.x_m[..n], &mut s.y_m[..n]);
    let (dx, dy, dz) = (&mut dx[..n], &mut dy[..n], &mut dz[..n]);
    for d in z.iter_mut() {
        *d = 1.0 / *d;
    }
    for k in 0..n {
        let u = f64::from(pixel[k]);
        let dir = [row_start.x + du.x * u, row_start.y + du.y * u, row_start.z + du.z * u];
        let depth = f64::from(z[k]);
        (x_m[k], y_m[k]) = (origin.x + dir[0] * depth, origin.y + dir[1] * depth);
        (dx[k], dy[k], dz[k]) = (dir[0] as f32, dir[1] as f32, dir[2] as f32);
    }
}

/// Turns the first `n` slopes into unit normals, and fills the view directions and footprints.
fn normalise(s: &mut RowScratch, n: usize, f_px: f32) {
    let [nx, ny, nz] = &mut s.normal;
    let [vx, vy, vz] = &mut s.to_viewer;
    let [dx, dy, dz] = &s.dir;
    let (nx, ny, nz, vx, vy, vz) = (&mut nx[..n], &mut ny[..n], &mut nz[..n], &mut vx[..n], &mut vy[..n], &mut vz[..n]);
    let (dx, dy, dz, z, footprint) = (&dx[..n], &dy[..n], &dz[..n], &s.z_m[..n], &mut s.footprint_m[..n]);
    let inv_f = 1.0 / f_px;
    for k in 0..n {
        // Slopes (dz/dx, dz/dy) to the upward normal (-dz/dx, -dz/dy, 1), normalised.
        let inv_len = 1.0 / (1.0 + nx[k] * nx[k] + ny[k] * ny[k]).sqrt();
        let (a, b, c) = (-nx[k] * inv_len, -ny[k] * inv_len, inv_len);
        (nx[k], ny[k], nz[k]) = (a, b, c);
        let inv_dir = 1.0 / (dx[k] * dx[k] + dy[k] * dy[k] + dz[k] * dz[k]).sqrt();
        (vx[k], vy[k], vz[k]) = (-dx[k] * inv_dir, -dy[k] * inv_dir, -dz[k] * inv_dir);
        let cos_e = (a * vx[k] + b * vy[k] + c * vz[k]).max(0.05);
        // A pixel covers z² cos θ / (f² cos e) of the surface (θ off the optical axis, e from
        // the normal; cos θ = 1 / |dir|). Its square root, the geometric mean of the footprint
        // ellipse's axes, neither aliases across the view nor blurs along it too much.
        footprint[k] = z[k] * inv_f * (inv_dir / cos_e).sqrt();
    }
}

/// Front normal of a quad: out of a tag's face for the corner order top-left, top-right,
/// bottom-right, bottom-left.
#[inline]
fn quad_frame(quad: &Quad) -> (Vector3<f64>, Vector3<f64>, Vector3<f64>) {
    let c = &quad.corners_world_m;
    let e_right = c[1] - c[0];
    let e_down = c[3] - c[0];
    (e_right, e_down, e_down.cross(&e_right).normalize())
}

/// Coordinates `(a, b)` of `p` on the quad: `p = c0 + a · e_right + b · e_down`.
#[inline]
fn quad_coords(quad: &Quad, e_right: &Vector3<f64>, e_down: &Vector3<f64>, p: &Vector3<f64>) -> (f64, f64) {
    let d = p - quad.corners_world_m[0].coords;
    let (g11, g12, g22) = (e_right.dot(e_right), e_right.dot(e_down), e_down.dot(e_down));
    let (r1, r2) = (d.dot(e_right), d.dot(e_down));
    let det = g11 * g22 - g12 * g12;
    if det.abs() < 1e-30 {
        return (0.0, 0.0);
    }
    ((r1 * g22 - r2 * g12) / det, (r2 * g11 - r1 * g12) / det)
}

fn tag_albedo(code: u64, a: f64, b: f64) -> f32 {
    // Saturating truncation: negative coordinates land in the (white) quiet zone either way.
    let cell = |t: f64| (t * TAG_CELLS as f64).clamp(0.0, TAG_CELLS as f64) as usize;
    if tag_cell_is_white(code, cell(a), cell(b)) { TAG_WHITE_ALBEDO } else { TAG_BLACK_ALBEDO }
}

fn quad_radiance(
    quad: &Quad,
    light: &Light,
    eye: &Eye,
    p: &Vector3<f64>,
    dir: &Vector3<f64>,
    du: &Vector3<f64>,
) -> f32 {
    let (e_right, e_down, front) = quad_frame(quad);
    let to_viewer = -dir.normalize();
    let seen_front = front.dot(&to_viewer) >= 0.0;
    // A thin plate: the side we see is lit only if the sun is on the same side.
    let normal = if seen_front { front } else { -front };
    let albedo = match quad.surface {
        QuadSurface::Uniform { albedo } => albedo,
        QuadSurface::Tag { code } if seen_front => {
            // Box filter over the pixel (2 × 2 rays): cell edges come out grey as in a camera, which
            // is what corner refinement in tag detectors expects.
            let dv = eye.r_world_cam * Vector3::new(0.0, 1.0 / eye.f, 0.0);
            let denom_base = front.dot(&(quad.corners_world_m[0].coords - eye.origin_world));
            let mut sum = 0.0;
            for (ou, ov) in [(-0.25, -0.25), (0.25, -0.25), (-0.25, 0.25), (0.25, 0.25)] {
                let ray = dir + du * ou + dv * ov;
                let along = front.dot(&ray);
                let q = if along.abs() > 1e-12 { eye.origin_world + ray * (denom_base / along) } else { *p };
                let (a, b) = quad_coords(quad, &e_right, &e_down, &q);
                sum += tag_albedo(code, a, b);
            }
            0.25 * sum
        }
        QuadSurface::Tag { .. } => TAG_BACK_ALBEDO,
    };
    let cos_i = normal.dot(&light.to_sun).max(0.0) as f32;
    albedo * (light.irradiance * cos_i + light.ambient(normal.z))
}
