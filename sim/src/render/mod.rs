//! Stereo rendering of the terrain and the robots (owned by the renderer helper).
//!
//! CONTRACT: [`Renderer::render_stereo`] fills a rectified 8-bit pair for the left camera pose
//! `t_world_cam` (right camera at `+baseline` along the left camera's x); the left camera's
//! z-depth of the same render is then available from [`Renderer::depth_m`] (`f32::INFINITY` where
//! the sky is seen). [`raycast_depth_m`] is the exact, slow ground truth for one pixel.
//!
//! How a frame is made, all on the calling thread and without allocating:
//!
//! 1. Geometry (`raster.rs`): the terrain is drawn as a chunked level-of-detail mesh (`lod.rs`):
//!    chunks outside the pair's view frustum are skipped, the others drawn at the coarsest level
//!    whose deviation from the full 5 cm mesh projects below [`LodConfig::max_error_px`] (level 0,
//!    the terrain mesh itself, within [`LodConfig::full_resolution_m`] of the camera), with skirts
//!    where levels meet. Robot quads go into the same z-buffer. Each vertex is transformed once
//!    for both cameras, and a pixel keeps the slopes of the triangle it shows. Small mesh squares
//!    (most of a distant chunk) are rasterised in one pass for both their triangles.
//! 2. Shading (`shade.rs`): from each pixel's depth, the world point; the normal of the triangle
//!    drawn there (the terrain mesh's own within `full_resolution_m`, a coarser facet only where
//!    the mesh is coarse, i.e. where one 5 cm facet per pixel would alias); there the albedo
//!    filtered for the pixel's footprint ([`Terrain::albedo_filtered_many`]), the sun through
//!    [`Reflectance::factor`] (in f32) and [`ShadowMap::lit_many`], and indirect light. A row's
//!    terrain pixels go through each step together, in loops the compiler vectorises.
//! 3. Image formation (`sensor.rs`): one exposure gain from the left image's mean radiance for
//!    both images, shot and read noise from a counter-based hash, rounding to `u8`.

mod lod;
mod raster;
mod raycast;
mod sensor;
mod shade;

pub use raycast::raycast_depth_m;

use nalgebra::{Isometry3, Matrix3, Point3, Vector3};

use crate::camera::StereoCamera;
use crate::lighting::{Reflectance, ShadowMap, Sun};
use crate::terrain::{Heightfield, Terrain};
use lod::{CHUNK_CELLS, EAST, LEVELS, MAX_AXIS, NORTH, SOUTH, TerrainLod, WEST};
use raster::{Fragment, Pinhole, ScreenVertex, Target};

pub use shade::{BOUNCE_FRACTION, TAG_BACK_ALBEDO, TAG_BLACK_ALBEDO, TAG_WHITE_ALBEDO};

/// A flat four-cornered face of a robot (chassis, mast, marker plate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Quad {
    /// Corners in the world frame, counter-clockwise seen from the front. For a tag: top-left,
    /// top-right, bottom-right, bottom-left of the whole 10 × 10-cell tag (white border included).
    pub corners_world_m: [Point3<f64>; 4],
    pub surface: QuadSurface,
}

/// What a quad looks like.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum QuadSurface {
    Uniform {
        albedo: f32,
    },
    /// A tag36h11 code drawn over the quad (`crate::markers::tag_cell_is_white`).
    Tag {
        code: u64,
    },
}

/// Everything a camera can see.
#[derive(Debug, Clone, Copy)]
pub struct Scene<'a> {
    pub terrain: &'a Terrain,
    pub shadows: &'a ShadowMap,
    pub sun: Sun,
    pub reflectance: Reflectance,
    /// Radiance of the sky (0 on airless bodies).
    pub sky_radiance: f32,
    pub quads: &'a [Quad],
}

/// Image formation: exposure control and sensor noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SensorModel {
    /// Auto-exposure aims the mean grey value of the left image here.
    pub target_mean_dn: f32,
    /// Electrons at full scale (photon shot noise) and read noise in digital numbers.
    pub full_well_e: f32,
    pub read_noise_dn: f32,
    /// Apply noise at all (false for noise-free test renders).
    pub noise: bool,
}

impl Default for SensorModel {
    fn default() -> Self {
        SensorModel { target_mean_dn: 110.0, full_well_e: 10_000.0, read_noise_dn: 1.0, noise: true }
    }
}

/// How finely the terrain is meshed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LodConfig {
    /// Largest vertical deviation of a chunk's simplified mesh from the full-resolution mesh,
    /// projected at the chunk's nearest distance, in pixels.
    pub max_error_px: f64,
    /// Chunks closer than this are always drawn at full resolution (the mesh the ray caster and
    /// the terrain contract define), whatever their error.
    pub full_resolution_m: f64,
}

impl Default for LodConfig {
    /// Exact within 6 m, beyond the 2.5–5 m the thesis's robots map from (§5.2); a pixel of
    /// geometric error further out, a small fraction of the stereo error there. What this costs
    /// and buys: `BENCHMARKS.md` and the depth tests in `tests/render.rs`.
    fn default() -> Self {
        LodConfig { max_error_px: 1.0, full_resolution_m: 6.0 }
    }
}

/// What the last frame drew.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct RenderStats {
    /// Terrain chunks ([`LOD_CHUNK_CELLS`]² cells) drawn at each level of detail (level `k`
    /// uses every `2^k`-th vertex).
    pub chunks_per_level: [u32; LEVELS],
    /// Terrain triangles submitted (skirts included), counted once for both cameras.
    pub terrain_triangles: u64,
    /// Grey values per unit radiance of the last pair (1 for depth-only renders).
    pub exposure_gain: f32,
}

/// Cells along the edge of a level-of-detail chunk.
pub const LOD_CHUNK_CELLS: usize = CHUNK_CELLS;

/// A reusable renderer for one camera: all buffers allocated at construction (the level-of-detail
/// tables once per terrain, on its first frame).
#[derive(Debug)]
pub struct Renderer {
    camera: StereoCamera,
    sensor: SensorModel,
    lod_config: LodConfig,
    depth_m: Vec<f32>,
    /// Per camera: `1/z` of the nearest surface (0 = sky) and which surface ([`TERRAIN`],
    /// [`SKIRT`] or `i + 1` for quad `i`); both valid where `1/z > 0`.
    inv_z: [Vec<f32>; 2],
    surface: [Vec<u32>; 2],
    /// Per camera: slopes of the terrain triangle seen (for the shading normal).
    slopes: [Vec<[f32; 2]>; 2],
    radiance: Vec<f32>,
    /// Scratch for the image noise.
    deviates: Vec<f32>,
    shade_scratch: shade::RowScratch,
    /// Scratch vertices of one chunk.
    mesh: Vec<MeshVertex>,
    lod: Option<TerrainLod>,
    /// Level each chunk is drawn at this frame, [`CULLED`] if not at all.
    chunk_level: Vec<u8>,
    stats: RenderStats,
}

const CULLED: u8 = u8::MAX;

impl Renderer {
    pub fn new(camera: StereoCamera, sensor: SensorModel) -> Self {
        Self::with_lod(camera, sensor, LodConfig::default())
    }

    pub fn with_lod(camera: StereoCamera, sensor: SensorModel, lod_config: LodConfig) -> Self {
        let n = camera.pixels();
        Renderer {
            camera,
            sensor,
            lod_config,
            depth_m: vec![f32::INFINITY; n],
            inv_z: [vec![0.0; n], vec![0.0; n]],
            surface: [vec![0; n], vec![0; n]],
            slopes: [vec![[0.0; 2]; n], vec![[0.0; 2]; n]],
            radiance: vec![0.0; n],
            deviates: vec![0.0; n],
            shade_scratch: shade::RowScratch::new(camera.width_px as usize),
            mesh: vec![MeshVertex::default(); MAX_AXIS * MAX_AXIS],
            lod: None,
            chunk_level: Vec::new(),
            stats: RenderStats::default(),
        }
    }

    pub fn camera(&self) -> &StereoCamera {
        &self.camera
    }

    pub fn sensor(&self) -> &SensorModel {
        &self.sensor
    }

    pub fn lod_config(&self) -> &LodConfig {
        &self.lod_config
    }

    pub fn set_lod_config(&mut self, lod_config: LodConfig) {
        self.lod_config = lod_config;
    }

    /// What the last render drew.
    pub fn stats(&self) -> &RenderStats {
        &self.stats
    }

    /// Renders the pair into `left` and `right` (each `width × height`). `noise_seed` keys the
    /// image noise (deterministic).
    ///
    /// # Panics
    /// If `left` or `right` does not have `width × height` pixels.
    pub fn render_stereo(
        &mut self,
        scene: &Scene<'_>,
        t_world_cam: &Isometry3<f64>,
        noise_seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) {
        let n = self.camera.pixels();
        assert!(left.len() == n && right.len() == n, "images must have {n} pixels");
        self.draw_geometry(scene, t_world_cam, 2);
        self.resolve_depth();
        let mut gain = 1.0;
        for (camera, out) in [left, right].into_iter().enumerate() {
            let eye = self.eye(t_world_cam, camera);
            let pixels = shade::Pixels {
                inv_z: &self.inv_z[camera],
                surface: &self.surface[camera],
                slopes: &self.slopes[camera],
            };
            shade::shade(scene, &eye, &pixels, &mut self.shade_scratch, &mut self.radiance);
            // Both sensors are triggered and exposed together, so the left image sets the gain.
            if camera == 0 {
                gain = sensor::exposure_gain(&self.sensor, &self.radiance);
            }
            let key = sensor::noise_key(noise_seed, camera as u64);
            sensor::expose(&self.sensor, &self.radiance, gain, key, out, &mut self.deviates);
        }
        self.stats.exposure_gain = gain;
    }

    /// Left-camera z-depth of the last [`Renderer::render_stereo`] (or [`Renderer::render_depth`]).
    pub fn depth_m(&self) -> &[f32] {
        &self.depth_m
    }

    /// Renders only the left camera's depth (terrain and robots).
    pub fn render_depth(&mut self, scene: &Scene<'_>, t_world_cam: &Isometry3<f64>) -> &[f32] {
        self.draw_geometry(scene, t_world_cam, 1);
        self.resolve_depth();
        self.stats.exposure_gain = 1.0;
        &self.depth_m
    }

    fn eye(&self, t_world_cam: &Isometry3<f64>, camera: usize) -> shade::Eye {
        let offset = Vector3::new(camera as f64 * self.camera.baseline_m, 0.0, 0.0);
        shade::Eye {
            origin_world: t_world_cam.translation.vector + t_world_cam.rotation * offset,
            r_world_cam: *t_world_cam.rotation.to_rotation_matrix().matrix(),
            f: self.camera.f_px,
            cx: self.camera.cx_px,
            cy: self.camera.cy_px,
            width: self.camera.width_px as usize,
            height: self.camera.height_px as usize,
        }
    }

    fn resolve_depth(&mut self) {
        for (d, &iz) in self.depth_m.iter_mut().zip(&self.inv_z[0]) {
            *d = if iz > 0.0 { 1.0 / iz } else { f32::INFINITY };
        }
    }

    /// Fills the z-buffers and surface ids of the first `cameras` cameras.
    fn draw_geometry(&mut self, scene: &Scene<'_>, t_world_cam: &Isometry3<f64>, cameras: usize) {
        self.stats = RenderStats::default();
        // Ids and slopes are read only where a triangle won the depth test, which wrote them.
        for inv_z in &mut self.inv_z[..cameras] {
            inv_z.fill(0.0);
        }
        let view = View::new(&self.camera, t_world_cam, cameras);
        self.draw_terrain(scene.terrain, &view);
        let Renderer { inv_z, surface, slopes, .. } = self;
        let mut targets = targets(&self.camera, inv_z, surface, slopes);
        for (i, quad) in scene.quads.iter().enumerate() {
            let c = quad.corners_world_m.map(|p| view.vertex(&p.coords));
            let fragment = Fragment { surface: i as u32 + 1, slopes: [0.0; 2] };
            view.triangle(&mut targets, &c[0], &c[1], &c[2], &fragment, true);
            view.triangle(&mut targets, &c[0], &c[2], &c[3], &fragment, true);
        }
    }

    fn draw_terrain(&mut self, terrain: &Terrain, view: &View) {
        let hf = &terrain.heightfield;
        if hf.cols < 2 || hf.rows < 2 || hf.heights_m.len() < hf.cols * hf.rows {
            return;
        }
        let fingerprint = lod::fingerprint(hf, terrain.seed);
        if self.lod.as_ref().map(TerrainLod::fingerprint) != Some(fingerprint) {
            let lod = TerrainLod::build(hf, fingerprint);
            self.chunk_level = vec![CULLED; lod.chunk_count()];
            self.lod = Some(lod);
        }
        let Renderer { lod: Some(lod), chunk_level, inv_z, surface, slopes, mesh, stats, lod_config, camera, .. } =
            self
        else {
            return;
        };
        // Pass 1: which chunks are seen, and how finely.
        for j in 0..lod.chunks_y {
            for i in 0..lod.chunks_x {
                let k = j * lod.chunks_x + i;
                let (c0, c1, r0, r1) = lod.bounds(i, j);
                let lo = [cell_x(hf, c0), cell_y(hf, r0), f64::from(lod.z_min_m[k])];
                let hi = [cell_x(hf, c1), cell_y(hf, r1), f64::from(lod.z_max_m[k])];
                if !view.box_visible(&lo, &hi) {
                    chunk_level[k] = CULLED;
                    continue;
                }
                let distance_m = view.distance_to_box(&lo, &hi);
                let px_per_m = view.pinhole.f / distance_m.max(1e-6);
                let errors = lod.errors(hf, k);
                let level = if distance_m < lod_config.full_resolution_m {
                    0
                } else {
                    (1..LEVELS).rev().find(|&l| f64::from(errors[l]) * px_per_m <= lod_config.max_error_px).unwrap_or(0)
                };
                chunk_level[k] = level as u8;
                stats.chunks_per_level[level] += 1;
            }
        }
        // Pass 2: draw them.
        let mut targets = targets(camera, inv_z, surface, slopes);
        for j in 0..lod.chunks_y {
            for i in 0..lod.chunks_x {
                let level = chunk_level[j * lod.chunks_x + i];
                if level != CULLED {
                    let chunk = Chunk { i, j, level: usize::from(level) };
                    stats.terrain_triangles += draw_chunk(hf, lod, chunk_level, chunk, view, mesh, &mut targets);
                }
            }
        }
    }
}

fn targets<'a>(
    camera: &StereoCamera,
    inv_z: &'a mut [Vec<f32>; 2],
    surface: &'a mut [Vec<u32>; 2],
    slopes: &'a mut [Vec<[f32; 2]>; 2],
) -> [Target<'a>; 2] {
    let [z0, z1] = inv_z;
    let [s0, s1] = surface;
    let [g0, g1] = slopes;
    let (width, height) = (camera.width_px as usize, camera.height_px as usize);
    [
        Target { width, height, inv_z: z0, surface: s0, slopes: g0 },
        Target { width, height, inv_z: z1, surface: s1, slopes: g1 },
    ]
}

/// Surface id of terrain pixels whose slopes are in the slopes buffer, and of skirt pixels, which
/// take them from the full-resolution mesh. Quad `i` is `i + 1`.
pub(crate) const TERRAIN: u32 = 0;
pub(crate) const SKIRT: u32 = u32::MAX;

#[inline]
fn cell_x(hf: &Heightfield, c: usize) -> f64 {
    hf.origin_m[0] + c as f64 * hf.resolution_m
}

#[inline]
fn cell_y(hf: &Heightfield, r: usize) -> f64 {
    hf.origin_m[1] + r as f64 * hf.resolution_m
}

#[derive(Debug, Clone, Copy)]
struct Chunk {
    i: usize,
    j: usize,
    level: usize,
}

/// Draws one chunk (and its skirts towards chunks of other levels); returns the triangle count.
fn draw_chunk(
    hf: &Heightfield,
    lod: &TerrainLod,
    chunk_level: &[u8],
    chunk: Chunk,
    view: &View,
    mesh: &mut [MeshVertex],
    targets: &mut [Target<'_>; 2],
) -> u64 {
    let (c0, c1, r0, r1) = lod.bounds(chunk.i, chunk.j);
    let step = 1 << chunk.level;
    let mut xs = [0; MAX_AXIS];
    let mut ys = [0; MAX_AXIS];
    let nx = lod::axis(c0, c1, step, &mut xs);
    let ny = lod::axis(r0, r1, step, &mut ys);
    let world =
        |c: usize, r: usize| Vector3::new(cell_x(hf, c), cell_y(hf, r), f64::from(hf.heights_m[r * hf.cols + c]));
    for y in 0..ny {
        for x in 0..nx {
            mesh[y * nx + x] = view.vertex(&world(xs[x], ys[y]));
        }
    }
    let mut triangles = 0;
    let h = |c: usize, r: usize| hf.heights_m[r * hf.cols + c];
    let mut inv_dxs = [0.0f32; MAX_AXIS];
    for x in 0..nx - 1 {
        inv_dxs[x] = (1.0 / ((xs[x + 1] - xs[x]) as f64 * hf.resolution_m)) as f32;
    }
    for y in 0..ny - 1 {
        let inv_dy = (1.0 / ((ys[y + 1] - ys[y]) as f64 * hf.resolution_m)) as f32;
        for x in 0..nx - 1 {
            let (a00, a10) = (&mesh[y * nx + x], &mesh[y * nx + x + 1]);
            let (a01, a11) = (&mesh[(y + 1) * nx + x], &mesh[(y + 1) * nx + x + 1]);
            let inv_dx = inv_dxs[x];
            let (h00, h10) = (h(xs[x], ys[y]), h(xs[x + 1], ys[y]));
            let (h01, h11) = (h(xs[x], ys[y + 1]), h(xs[x + 1], ys[y + 1]));
            // Counter-clockwise from above is clockwise on screen (v points down): the order that
            // makes upward faces front faces for the rasteriser.
            let lower = Fragment { surface: TERRAIN, slopes: [(h10 - h00) * inv_dx, (h11 - h10) * inv_dy] };
            let upper = Fragment { surface: TERRAIN, slopes: [(h11 - h01) * inv_dx, (h01 - h00) * inv_dy] };
            view.square(targets, [a00, a10, a11, a01], &lower, &upper);
            triangles += 2;
        }
    }
    // Skirts towards neighbours drawn at another level: their edges differ by at most the two
    // border errors, plus what snapping T-junctions to sub-pixels leaves.
    let k = chunk.j * lod.chunks_x + chunk.i;
    let neighbours = [
        (WEST, chunk.i.checked_sub(1).map(|i| (i, chunk.j)), EAST),
        (EAST, (chunk.i + 1 < lod.chunks_x).then_some((chunk.i + 1, chunk.j)), WEST),
        (SOUTH, chunk.j.checked_sub(1).map(|j| (chunk.i, j)), NORTH),
        (NORTH, (chunk.j + 1 < lod.chunks_y).then_some((chunk.i, chunk.j + 1)), SOUTH),
    ];
    for (side, neighbour, opposite) in neighbours {
        let Some((ni, nj)) = neighbour else { continue };
        let nk = nj * lod.chunks_x + ni;
        let other = chunk_level[nk];
        if other == CULLED || usize::from(other) == chunk.level {
            continue;
        }
        let gap = lod.border_error(k, chunk.level, side) + lod.border_error(nk, usize::from(other), opposite);
        let depth = 1.05 * f64::from(gap) + 0.005;
        let (count, index): (usize, &dyn Fn(usize) -> (usize, usize)) = match side {
            WEST => (ny, &|t| (0, t)),
            EAST => (ny, &|t| (nx - 1, t)),
            SOUTH => (nx, &|t| (t, 0)),
            _ => (nx, &|t| (t, ny - 1)),
        };
        let mut prev: Option<(MeshVertex, MeshVertex)> = None;
        for t in 0..count {
            let (x, y) = index(t);
            let top = mesh[y * nx + x];
            let bottom = view.vertex_below(&top, depth);
            if let Some((pt, pb)) = prev {
                let skirt = Fragment { surface: SKIRT, slopes: [0.0; 2] };
                view.triangle(targets, &pt, &top, &bottom, &skirt, true);
                view.triangle(targets, &pt, &bottom, &pb, &skirt, true);
                triangles += 2;
            }
            prev = Some((top, bottom));
        }
    }
    triangles
}

/// A vertex transformed into the left camera's frame and projected into each camera.
#[derive(Debug, Clone, Copy, Default)]
struct MeshVertex {
    cam: [f64; 3],
    /// `None` when the vertex needs clipping in that camera.
    screen: [Option<ScreenVertex>; 2],
}

/// The pair's pose and projection for the geometry pass.
#[derive(Debug, Clone, Copy)]
struct View {
    r_cam_world: Matrix3<f64>,
    origin_world: Vector3<f64>,
    pinhole: Pinhole,
    baseline_m: f64,
    cameras: usize,
    /// Half-spaces `n · p + d ≥ 0` (world frame) bounding what either camera sees.
    frustum: [[f64; 4]; 5],
}

impl View {
    fn new(camera: &StereoCamera, t_world_cam: &Isometry3<f64>, cameras: usize) -> View {
        let r_world_cam = *t_world_cam.rotation.to_rotation_matrix().matrix();
        let origin_world = t_world_cam.translation.vector;
        let pinhole = Pinhole {
            f: camera.f_px,
            cx: camera.cx_px,
            cy: camera.cy_px,
            width: camera.width_px as usize,
            height: camera.height_px as usize,
        };
        // Planes in the left camera's frame, a couple of pixels generous; the right edge is the
        // right camera's (`x − b`).
        let margin = 2.0;
        let (f, cx, cy) = (pinhole.f, pinhole.cx, pinhole.cy);
        let (w, h) = (pinhole.width as f64 - 1.0, pinhole.height as f64 - 1.0);
        let shift = (cameras as f64 - 1.0) * camera.baseline_m;
        let planes_cam = [
            [0.0, 0.0, 1.0, -raster::NEAR_M],
            [f, 0.0, cx + margin, 0.0],
            [-f, 0.0, w + margin - cx, f * shift],
            [0.0, f, cy + margin, 0.0],
            [0.0, -f, h + margin - cy, 0.0],
        ];
        let frustum = planes_cam.map(|p| {
            let n = r_world_cam * Vector3::new(p[0], p[1], p[2]);
            [n.x, n.y, n.z, p[3] - n.dot(&origin_world)]
        });
        View {
            r_cam_world: r_world_cam.transpose(),
            origin_world,
            pinhole,
            baseline_m: camera.baseline_m,
            cameras,
            frustum,
        }
    }

    #[inline]
    fn vertex(&self, p_world: &Vector3<f64>) -> MeshVertex {
        let p = self.r_cam_world * (p_world - self.origin_world);
        let cam = [p.x, p.y, p.z];
        MeshVertex { cam, screen: self.project(&cam) }
    }

    /// The vertex `depth_m` straight below `top` (world z), without a full transform.
    #[inline]
    fn vertex_below(&self, top: &MeshVertex, depth_m: f64) -> MeshVertex {
        let down = self.r_cam_world.column(2) * depth_m;
        let cam = [top.cam[0] - down.x, top.cam[1] - down.y, top.cam[2] - down.z];
        MeshVertex { cam, screen: self.project(&cam) }
    }

    #[inline]
    fn project(&self, cam: &[f64; 3]) -> [Option<ScreenVertex>; 2] {
        if self.cameras == 2 {
            self.pinhole.project_pair(cam, self.baseline_m)
        } else {
            [self.pinhole.project(cam), None]
        }
    }

    /// A left-camera point in camera `k`'s frame.
    #[inline]
    fn in_camera(&self, p: &[f64; 3], k: usize) -> [f64; 3] {
        [p[0] - k as f64 * self.baseline_m, p[1], p[2]]
    }

    #[inline]
    fn triangle(
        &self,
        targets: &mut [Target<'_>; 2],
        a: &MeshVertex,
        b: &MeshVertex,
        c: &MeshVertex,
        fragment: &Fragment,
        two_sided: bool,
    ) {
        // Both cameras share the rows (same v): most distant triangles fall between two rows of
        // pixel centres, and are rejected here once for the pair.
        if let (Some(sa), Some(sb), Some(sc)) = (a.screen[0], b.screen[0], c.screen[0])
            && !raster::spans_a_row(sa.y, sb.y, sc.y)
        {
            return;
        }
        for (k, target) in targets.iter_mut().enumerate().take(self.cameras) {
            if let (Some(sa), Some(sb), Some(sc)) = (a.screen[k], b.screen[k], c.screen[k]) {
                raster::triangle(target, &sa, &sb, &sc, fragment, two_sided);
            } else {
                let points = [self.in_camera(&a.cam, k), self.in_camera(&b.cam, k), self.in_camera(&c.cam, k)];
                raster::clip_and_draw(target, &self.pinhole, points, fragment, two_sided);
            }
        }
    }

    /// The mesh square `a00, a10, a11, a01` as its triangles `(a00, a11, a10)` with `lower` and
    /// `(a00, a01, a11)` with `upper` (one-sided).
    #[inline]
    fn square(&self, targets: &mut [Target<'_>; 2], corners: [&MeshVertex; 4], lower: &Fragment, upper: &Fragment) {
        let [a00, a10, a11, a01] = corners;
        if let (Some(s00), Some(s10), Some(s11), Some(s01)) =
            (a00.screen[0], a10.screen[0], a11.screen[0], a01.screen[0])
            && !raster::square_spans_a_row(s00.y, s10.y, s11.y, s01.y)
        {
            return;
        }
        for (k, target) in targets.iter_mut().enumerate().take(self.cameras) {
            if let (Some(s00), Some(s10), Some(s11), Some(s01)) =
                (a00.screen[k], a10.screen[k], a11.screen[k], a01.screen[k])
            {
                raster::square(target, [&s00, &s10, &s11, &s01], lower, upper);
            } else {
                self.triangle_in(target, k, [a00, a11, a10], lower);
                self.triangle_in(target, k, [a00, a01, a11], upper);
            }
        }
    }

    /// A one-sided triangle in camera `k` alone (clipped where needed).
    fn triangle_in(&self, target: &mut Target<'_>, k: usize, corners: [&MeshVertex; 3], fragment: &Fragment) {
        let [a, b, c] = corners;
        if let (Some(sa), Some(sb), Some(sc)) = (a.screen[k], b.screen[k], c.screen[k]) {
            raster::triangle(target, &sa, &sb, &sc, fragment, false);
        } else {
            let points = [self.in_camera(&a.cam, k), self.in_camera(&b.cam, k), self.in_camera(&c.cam, k)];
            raster::clip_and_draw(target, &self.pinhole, points, fragment, false);
        }
    }

    fn box_visible(&self, lo: &[f64; 3], hi: &[f64; 3]) -> bool {
        self.frustum.iter().all(|p| {
            let corner = |k: usize| if p[k] >= 0.0 { hi[k] } else { lo[k] };
            p[0] * corner(0) + p[1] * corner(1) + p[2] * corner(2) + p[3] >= 0.0
        })
    }

    fn distance_to_box(&self, lo: &[f64; 3], hi: &[f64; 3]) -> f64 {
        let o = &self.origin_world;
        let gap = |k: usize| (lo[k] - o[k]).max(o[k] - hi[k]).max(0.0);
        (gap(0).powi(2) + gap(1).powi(2) + gap(2).powi(2)).sqrt()
    }
}
