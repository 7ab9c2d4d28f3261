//! One depth image (with its obstacle labels) into a submap's cloud and octree (thesis §5.1.2).
//!
//! Per image:
//! 1. Every valid pixel closer than the range cutoff becomes a point in the submap frame; the
//!    points are voxel-filtered at 5 cm (centroid, mean intensity, obstacle OR) and merged into
//!    the submap cloud weighted by their counts (the second filter, trap 14).
//! 2. The octree gets one scan: a hit in the voxel of every valid point's endpoint and free space
//!    along the rays to them (3D DDA), each voxel updated once per image with occupied winning.
//!    Pixels at infinite depth (zero disparity) or beyond the cutoff cast free space up to the
//!    cutoff distance without a hit (trap 11: they are never hits). The thesis leaves this open;
//!    we do it because sky-facing and far pixels do tell that the near space along them is empty,
//!    and the hit rays alone leave the space above the ground unknown.
//!
//! Rays are cast to the centres of the distinct endpoint voxels (OctoMap's "discretize" mode),
//! not once per pixel: a 10 cm voxel at 3 m spans ~20×20 pixels, so this cuts the ray count by
//! two orders of magnitude. The free space differs from per-pixel rays only within a voxel at the
//! endpoint, which the occupied-wins rule makes moot. `ray_pixel_step` subsamples the pixels
//! that take part in the octree update on top of that (see [`IntegratorConfig`]).
//!
//! # Range cutoff (thesis §5.1.1, trap 13)
//!
//! Stereo depth error `Δz = Δp·z²/(f·b)·√2` (Δp the disparity error in px, √2 for the two
//! images); points with `Δz > max_depth_error_m` are dropped from both cloud and octree:
//! `z_max = sqrt(max_depth_error_m·f·b / (Δp·√2))`, or an explicit `max_range_m`.

use nalgebra::{Isometry3, Point3, Vector3};
use vision::depth::{DepthImage, StereoGeometry};
use vision::obstacles::PixelLabels;

use crate::cloud::{MapPoint, VoxelAccumulator};
use crate::occupancy::ScanBuffer;
use crate::submap::Submap;

/// Integration parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IntegratorConfig {
    /// Largest accepted stereo depth error (thesis: Δp_z < 0.15 m).
    pub max_depth_error_m: f64,
    /// Disparity error Δp (px) in the depth-error model (0.5 px: SGM's sub-pixel accuracy).
    pub disparity_error_px: f64,
    /// Explicit depth cutoff (m) replacing the one derived from the depth error.
    pub max_range_m: Option<f64>,
    /// Points closer than this are dropped (the rover's own body, matching artefacts).
    pub min_depth_m: f64,
    /// Every `ray_pixel_step`-th pixel in x and y takes part in the octree update (1 = all).
    /// Default 1: with rays discretized to endpoint voxels, all pixels cost ~1/4 more than every
    /// 2nd one (the per-pixel part is one hash insert) and keep thin obstacles and
    /// far, sparsely sampled ground in the octree. Larger steps lose 10 cm voxels that only a few
    /// pixels see (far ground at grazing angles) first; see the README's benchmark.
    pub ray_pixel_step: usize,
    /// Cast free space to the cutoff for infinite-depth and too-far pixels.
    pub free_space_beyond_cutoff: bool,
}

impl Default for IntegratorConfig {
    fn default() -> Self {
        IntegratorConfig {
            max_depth_error_m: 0.15,
            disparity_error_px: 0.5,
            max_range_m: None,
            min_depth_m: 0.3,
            ray_pixel_step: 1,
            free_space_beyond_cutoff: true,
        }
    }
}

/// What one integration did.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct IntegrationStats {
    /// The depth cutoff used (m).
    pub cutoff_m: f64,
    /// Pixels with a finite depth inside `[min_depth_m, cutoff_m]` (the cloud's input points).
    pub points: usize,
    /// Of those, labelled obstacle.
    pub obstacle_points: usize,
    /// Pixels at infinite depth or beyond the cutoff.
    pub far_pixels: usize,
    /// Voxels of the per-image filtered cloud, and the submap cloud's size after merging.
    pub frame_voxels: usize,
    pub cloud_points: usize,
    /// Rays cast (to distinct endpoint voxels), with and without a hit at the end.
    pub hit_rays: usize,
    pub free_rays: usize,
    /// Octree leaves updated as free and as occupied.
    pub free_updates: usize,
    pub occupied_updates: usize,
}

/// Which submap the count-carrying cloud accumulator mirrors (see [`DepthIntegrator`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct BoundSubmap {
    robot_id: u16,
    index: u32,
    start_stamp_ns: u64,
    cloud_len: usize,
}

/// Integrates depth images into submaps, reusing all its buffers.
///
/// A [`crate::cloud::VoxelCloud`] carries no point counts, so the integrator keeps them for the
/// submap it last integrated into (identified by robot, index, start stamp and cloud size). A
/// submap it does not know (another one, or one whose cloud was changed outside) is re-read with
/// each existing point weighing one input point.
#[derive(Debug, Clone)]
pub struct DepthIntegrator {
    config: IntegratorConfig,
    geometry: StereoGeometry,
    frame: VoxelAccumulator,
    submap_cloud: VoxelAccumulator,
    bound: Option<BoundSubmap>,
    scan: ScanBuffer,
    /// Endpoints of the free-only rays (distinct voxels), in the submap frame.
    far_ends: ScanBuffer,
    /// Per image column `(u − cx)/fx` and per row `(v − cy)/fy`.
    column_dirs: Vec<f64>,
    row_dirs: Vec<f64>,
}

impl DepthIntegrator {
    pub fn new(config: IntegratorConfig, geometry: StereoGeometry) -> DepthIntegrator {
        DepthIntegrator {
            config,
            geometry,
            frame: VoxelAccumulator::new(crate::cloud::CLOUD_LEAF_M),
            submap_cloud: VoxelAccumulator::new(crate::cloud::CLOUD_LEAF_M),
            bound: None,
            scan: ScanBuffer::new(crate::occupancy::OCTREE_RESOLUTION_M),
            far_ends: ScanBuffer::new(crate::occupancy::OCTREE_RESOLUTION_M),
            column_dirs: Vec::new(),
            row_dirs: Vec::new(),
        }
    }

    pub fn config(&self) -> &IntegratorConfig {
        &self.config
    }

    pub fn geometry(&self) -> &StereoGeometry {
        &self.geometry
    }

    /// The depth cutoff: the explicit range, else where the stereo depth error reaches
    /// `max_depth_error_m`.
    pub fn cutoff_m(&self) -> f64 {
        match self.config.max_range_m {
            Some(r) => r,
            None => stereo_range_limit_m(
                self.config.max_depth_error_m,
                self.config.disparity_error_px,
                self.geometry.fx_px,
                self.geometry.baseline_m,
            ),
        }
    }

    /// Integrates one depth image taken at `t_submap_cam` (left camera in the submap frame).
    ///
    /// `labels` (same size as `depth`) set the obstacle bit of a pixel's point when flagged
    /// `OBSTACLE` or `NEGATIVE_EDGE`; `intensity` (the left grey image, same size) gives the
    /// points' grey value (0 without it). A labels or intensity buffer of the wrong size is
    /// ignored. Increments `submap.images`; the caller keeps the stamps.
    pub fn integrate(
        &mut self,
        submap: &mut Submap,
        depth: &DepthImage,
        labels: Option<&PixelLabels>,
        intensity: Option<&[u8]>,
        t_submap_cam: &Isometry3<f64>,
    ) -> IntegrationStats {
        let (w, h) = (depth.width, depth.height);
        let n = w * h;
        let labels = labels.filter(|l| l.flags.len() == n && l.width == w);
        let intensity = intensity.filter(|i| i.len() == n);
        let cutoff_m = self.cutoff_m();
        let mut stats = IntegrationStats { cutoff_m, ..IntegrationStats::default() };
        if depth.depth_m.len() != n || n == 0 {
            return stats;
        }
        self.prepare_directions(w, h);
        self.frame.clear();
        self.scan.clear(submap.occupancy.resolution_m);
        self.far_ends.clear(submap.occupancy.resolution_m);

        let rotation = t_submap_cam.rotation.to_rotation_matrix();
        let r = rotation.matrix();
        let origin = t_submap_cam.translation.vector;
        let (c0, c1, c2) = (r.column(0).into_owned(), r.column(1).into_owned(), r.column(2).into_owned());
        let step = self.config.ray_pixel_step.max(1);
        let obstacle_mask = PixelLabels::OBSTACLE | PixelLabels::NEGATIVE_EDGE;
        let min_depth = self.config.min_depth_m;
        for v in 0..h {
            let row_dir: Vector3<f64> = c1 * self.row_dirs[v] + c2;
            let ray_row = v % step == 0;
            for u in 0..w {
                let i = v * w + u;
                let z = f64::from(depth.depth_m[i]);
                if z.is_nan() || z < min_depth {
                    continue;
                }
                let dir = c0 * self.column_dirs[u] + row_dir;
                let in_octree = ray_row && u % step == 0;
                if z > cutoff_m {
                    stats.far_pixels += 1;
                    if in_octree && self.config.free_space_beyond_cutoff {
                        let end = origin + dir * cutoff_m;
                        self.far_ends.mark_hit(&[end.x, end.y, end.z]);
                    }
                    continue;
                }
                let p = origin + dir * z;
                let obstacle = labels.is_some_and(|l| l.flags[i] & obstacle_mask != 0);
                let grey = intensity.map_or(0, |g| g[i]);
                self.frame.add(&Point3::new(p.x as f32, p.y as f32, p.z as f32), grey, obstacle);
                stats.points += 1;
                stats.obstacle_points += usize::from(obstacle);
                if in_octree {
                    self.scan.mark_hit(&[p.x, p.y, p.z]);
                }
            }
        }

        self.merge_cloud(submap);
        stats.frame_voxels = self.frame.len();
        stats.cloud_points = submap.cloud.len();

        // Rays to the distinct voxels: hits first (their free space stops before the endpoint),
        // then the free-only rays (free up to and including the voxel at the cutoff).
        let o = [origin.x, origin.y, origin.z];
        let res = submap.occupancy.resolution_m;
        let centre = |k: &[i32; 3]| {
            [(f64::from(k[0]) + 0.5) * res, (f64::from(k[1]) + 0.5) * res, (f64::from(k[2]) + 0.5) * res]
        };
        stats.hit_rays = self.scan.hit_count();
        stats.free_rays = self.far_ends.hit_count();
        cast_rays(&mut self.scan, &self.far_ends, &o, centre);
        let (free, occupied) = submap.occupancy.insert_scan(&self.scan);
        stats.free_updates = free;
        stats.occupied_updates = occupied;
        submap.images += 1;
        stats
    }

    fn prepare_directions(&mut self, w: usize, h: usize) {
        let g = self.geometry;
        if self.column_dirs.len() != w {
            self.column_dirs.clear();
            self.column_dirs.extend((0..w).map(|u| (u as f64 - g.cx_px) / g.fx_px));
        }
        if self.row_dirs.len() != h {
            self.row_dirs.clear();
            self.row_dirs.extend((0..h).map(|v| (v as f64 - g.cy_px) / g.fy_px));
        }
    }

    /// Second filter: the frame's voxels merged into the submap cloud by count.
    fn merge_cloud(&mut self, submap: &mut Submap) {
        let id = |s: &Submap| BoundSubmap {
            robot_id: s.robot_id,
            index: s.index,
            start_stamp_ns: s.start_stamp_ns,
            cloud_len: s.cloud.len(),
        };
        let leaf_ok = submap.cloud.leaf_m == self.submap_cloud.leaf_m();
        if self.bound != Some(id(submap)) || !leaf_ok {
            if submap.cloud.leaf_m <= 0.0 || !submap.cloud.leaf_m.is_finite() {
                submap.cloud.leaf_m = crate::cloud::CLOUD_LEAF_M;
            }
            self.submap_cloud.reset_from(&submap.cloud);
            if self.frame.leaf_m() != submap.cloud.leaf_m {
                // Refilter this frame's points at the submap's leaf.
                let points: Vec<MapPoint> = self.frame.points().collect();
                self.frame = VoxelAccumulator::new(submap.cloud.leaf_m);
                for p in &points {
                    self.frame.add(&p.position_m, p.intensity, p.obstacle);
                }
            }
            self.submap_cloud.write_into(&mut submap.cloud);
        }
        self.submap_cloud.merge_into_cloud(&self.frame, &mut submap.cloud);
        self.bound = Some(id(submap));
    }
}

/// Casts the scan's rays: free space to every hit voxel (endpoint excluded) and to every far
/// endpoint (included).
fn cast_rays(scan: &mut ScanBuffer, far_ends: &ScanBuffer, origin: &[f64; 3], centre: impl Fn(&[i32; 3]) -> [f64; 3]) {
    scan.cast_free_to_hits(origin, &centre);
    for end in far_ends.hits() {
        scan.cast_free(origin, &centre(end), true);
    }
}

/// Depth at which the stereo depth error `Δp·z²/(f·b)·√2` reaches `max_error_m`.
pub fn stereo_range_limit_m(max_error_m: f64, disparity_error_px: f64, focal_px: f64, baseline_m: f64) -> f64 {
    (max_error_m * focal_px * baseline_m / (disparity_error_px * std::f64::consts::SQRT_2)).sqrt()
}
