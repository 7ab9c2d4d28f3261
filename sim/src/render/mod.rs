//! Stereo rendering of the terrain and the robots (owned by the renderer helper).
//!
//! CONTRACT: [`Renderer::render_stereo`] fills a rectified 8-bit pair for the left camera pose
//! `t_world_cam` (right camera at `+baseline` along the left camera's x); the left camera's
//! z-depth of the same render is then available from [`Renderer::depth_m`] (`f32::INFINITY` where
//! the sky is seen). [`raycast_depth_m`] is the exact, slow ground truth for one pixel.

use nalgebra::{Isometry3, Point3};

use crate::camera::StereoCamera;
use crate::lighting::{Reflectance, ShadowMap, Sun};
use crate::terrain::Terrain;

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

/// A reusable renderer for one camera: all buffers allocated at construction.
#[derive(Debug)]
pub struct Renderer {
    camera: StereoCamera,
    sensor: SensorModel,
    depth_m: Vec<f32>,
}

impl Renderer {
    pub fn new(camera: StereoCamera, sensor: SensorModel) -> Self {
        Renderer { camera, sensor, depth_m: vec![f32::INFINITY; camera.pixels()] }
    }

    pub fn camera(&self) -> &StereoCamera {
        &self.camera
    }

    pub fn sensor(&self) -> &SensorModel {
        &self.sensor
    }

    /// Renders the pair into `left` and `right` (each `width × height`). `noise_seed` keys the
    /// image noise (deterministic).
    pub fn render_stereo(
        &mut self,
        scene: &Scene<'_>,
        t_world_cam: &Isometry3<f64>,
        noise_seed: u64,
        left: &mut [u8],
        right: &mut [u8],
    ) {
        let _ = (scene, t_world_cam, noise_seed);
        left.fill(0);
        right.fill(0);
    }

    /// Left-camera z-depth of the last [`Renderer::render_stereo`] (or [`Renderer::render_depth`]).
    pub fn depth_m(&self) -> &[f32] {
        &self.depth_m
    }

    /// Renders only the left camera's depth.
    pub fn render_depth(&mut self, scene: &Scene<'_>, t_world_cam: &Isometry3<f64>) -> &[f32] {
        let _ = (scene, t_world_cam);
        &self.depth_m
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
    let _ = (terrain, camera, t_world_cam, u, v);
    None
}
