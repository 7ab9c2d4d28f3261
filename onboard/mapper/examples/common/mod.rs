//! Shared by the real-data mapping examples: SGM depth, a software point renderer with a depth
//! buffer (the pictures in the README), PNG/PLY output and the height-consistency statistic.
#![allow(dead_code)]

use std::collections::HashMap;
use std::path::Path;

use fpga_model::SgmConfig;
use hal::sensor::{StereoCalibration, StereoFrame};
use mapper::cloud::MapPoint;
use nalgebra::{Isometry3, Matrix3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use vision::depth::{DepthImage, StereoGeometry};
use vision::{DepthOptions, DepthPipeline};

pub type BoxError = Box<dyn std::error::Error>;

/// `--out DIR` from the command line, else `default`.
pub fn out_dir(default: &str) -> std::path::PathBuf {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == "--out")
        .and_then(|i| args.get(i + 1))
        .map_or_else(|| std::path::PathBuf::from(default), std::path::PathBuf::from)
}

pub fn geometry_of(calibration: &StereoCalibration) -> StereoGeometry {
    StereoGeometry::from_calibration(calibration)
}

/// SGM (the FPGA model's default configuration, no speckle filter) from rectified pairs to
/// depth through the on-board [`DepthPipeline`], buffers reused.
pub struct StereoDepth {
    pipeline: DepthPipeline,
}

impl StereoDepth {
    pub fn new(disparities: u16, width: usize, height: usize, geometry: StereoGeometry) -> Result<Self, BoxError> {
        let sgm = SgmConfig { disparities, ..SgmConfig::default() };
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        let options = DepthOptions { sgm, despeckle: false, threads };
        Ok(StereoDepth { pipeline: DepthPipeline::with_geometry(geometry, width, height, options)? })
    }

    pub fn compute(&mut self, frame: &StereoFrame) -> Result<&DepthImage, BoxError> {
        self.pipeline.compute(&frame.left, &frame.right)?;
        Ok(self.pipeline.depth())
    }
}

/// Per 10 cm x–y cell, the lowest and highest of the per-frame mean surface heights: how well
/// overlapping observations from different frames agree.
#[derive(Default)]
pub struct HeightConsistency {
    cell_m: f64,
    frame: HashMap<(i32, i32), (f64, u32)>,
    cells: HashMap<(i32, i32), (f64, f64, u32)>,
}

impl HeightConsistency {
    pub fn new(cell_m: f64) -> Self {
        HeightConsistency { cell_m, ..Default::default() }
    }

    pub fn add_point(&mut self, p_world: &Point3<f64>) {
        let k = ((p_world.x / self.cell_m).floor() as i32, (p_world.y / self.cell_m).floor() as i32);
        let e = self.frame.entry(k).or_insert((0.0, 0));
        e.0 += p_world.z;
        e.1 += 1;
    }

    /// Closes one frame: cells with at least `min_points` points record the frame's mean height.
    pub fn end_frame(&mut self, min_points: u32) {
        for (k, (sum, n)) in self.frame.drain() {
            if n < min_points {
                continue;
            }
            let h = sum / f64::from(n);
            let c = self.cells.entry(k).or_insert((h, h, 0));
            c.0 = c.0.min(h);
            c.1 = c.1.max(h);
            c.2 += 1;
        }
    }

    /// Centres (x, y) of the cells seen by ≥ 2 frames, in key order.
    pub fn cell_centres(&self) -> Vec<(f64, f64)> {
        let mut keys: Vec<_> = self.cells.iter().filter(|(_, c)| c.2 >= 2).map(|(k, _)| *k).collect();
        keys.sort_unstable();
        keys.iter().map(|k| ((f64::from(k.0) + 0.5) * self.cell_m, (f64::from(k.1) + 0.5) * self.cell_m)).collect()
    }

    /// (cells seen by ≥ 2 frames, median spread, 95th-percentile spread) in metres.
    pub fn spread(&self) -> (usize, f64, f64) {
        let mut s: Vec<f64> = self.cells.values().filter(|c| c.2 >= 2).map(|c| c.1 - c.0).collect();
        s.sort_by(f64::total_cmp);
        let q = |f: f64| if s.is_empty() { f64::NAN } else { s[((s.len() - 1) as f64 * f).round() as usize] };
        (s.len(), q(0.5), q(0.95))
    }
}

/// A plane `n·p = d` with unit normal `n` pointing up.
#[derive(Debug, Clone, Copy)]
pub struct Plane {
    pub normal: Vector3<f64>,
    pub d: f64,
}

impl Plane {
    pub fn distance(&self, p: &Point3<f64>) -> f64 {
        self.normal.dot(&p.coords) - self.d
    }

    pub fn tilt_deg(&self) -> f64 {
        self.normal.z.clamp(-1.0, 1.0).acos().to_degrees()
    }

    /// Height of the plane above the origin's x–y position.
    pub fn z_at(&self, x: f64, y: f64) -> f64 {
        (self.d - self.normal.x * x - self.normal.y * y) / self.normal.z
    }
}

/// RANSAC for the plane with the most points within `inlier_m`, among planes whose normal is
/// within `max_tilt_deg` of +z (seeded, deterministic). Returns the plane and its inlier count.
pub fn fit_horizontal_plane(
    points: &[Point3<f64>],
    max_tilt_deg: f64,
    inlier_m: f64,
    iterations: usize,
    seed: u64,
) -> Option<(Plane, usize)> {
    if points.len() < 3 {
        return None;
    }
    let mut state = seed | 1;
    let mut next = |n: usize| {
        // xorshift64*: enough for picking samples.
        state ^= state >> 12;
        state ^= state << 25;
        state ^= state >> 27;
        (state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 33) as usize % n
    };
    let min_nz = max_tilt_deg.to_radians().cos();
    let count = |plane: &Plane| points.iter().filter(|p| plane.distance(p).abs() < inlier_m).count();
    let mut best: Option<(Plane, usize)> = None;
    for _ in 0..iterations {
        let (a, b, c) = (points[next(points.len())], points[next(points.len())], points[next(points.len())]);
        let mut normal = (b - a).cross(&(c - a));
        if normal.norm() < 1e-6 {
            continue;
        }
        normal.normalize_mut();
        if normal.z < 0.0 {
            normal = -normal;
        }
        if normal.z < min_nz {
            continue;
        }
        let plane = Plane { normal, d: normal.dot(&a.coords) };
        let n = count(&plane);
        if best.is_none_or(|(_, m)| n > m) {
            best = Some((plane, n));
        }
    }
    // Least-squares refit z = αx + βy + γ on the inliers.
    let (plane, _) = best?;
    let inliers: Vec<&Point3<f64>> = points.iter().filter(|p| plane.distance(p).abs() < inlier_m).collect();
    let mut ata = nalgebra::Matrix3::<f64>::zeros();
    let mut atb = Vector3::<f64>::zeros();
    for p in &inliers {
        let row = Vector3::new(p.x, p.y, 1.0);
        ata += row * row.transpose();
        atb += row * p.z;
    }
    let refined = ata.lu().solve(&atb).map_or(plane, |x| {
        let n = Vector3::new(-x[0], -x[1], 1.0);
        let norm = n.norm();
        Plane { normal: n / norm, d: x[2] / norm }
    });
    Some((refined, count(&refined)))
}

/// Back-projects the valid pixels of `depth` within `[min_m, max_m]` (every `step`-th pixel).
pub fn for_each_point(
    depth: &DepthImage,
    geometry: &StereoGeometry,
    t_world_cam: &Isometry3<f64>,
    (min_m, max_m): (f64, f64),
    step: usize,
    mut f: impl FnMut(Point3<f64>),
) {
    for v in (0..depth.height).step_by(step) {
        for u in (0..depth.width).step_by(step) {
            let z = f64::from(depth.get(u, v));
            if z.is_finite() && z >= min_m && z <= max_m {
                let p = geometry.point_at(u as f64, v as f64, z);
                f(t_world_cam * Point3::new(p[0], p[1], p[2]));
            }
        }
    }
}

/// An RGB image with a depth buffer.
pub struct Canvas {
    pub width: usize,
    pub height: usize,
    rgb: Vec<u8>,
    depth: Vec<f32>,
}

impl Canvas {
    pub fn new(width: usize, height: usize) -> Canvas {
        Canvas { width, height, rgb: vec![16; width * height * 3], depth: vec![f32::INFINITY; width * height] }
    }

    /// A `size`×`size` splat at `(x, y)` at `depth`, kept where nearer than what is there.
    pub fn splat(&mut self, x: f64, y: f64, depth: f32, size: usize, rgb: [u8; 3]) {
        let (x0, y0) = ((x - size as f64 / 2.0).round() as i64, (y - size as f64 / 2.0).round() as i64);
        for dy in 0..size as i64 {
            for dx in 0..size as i64 {
                let (px, py) = (x0 + dx, y0 + dy);
                if px < 0 || py < 0 || px >= self.width as i64 || py >= self.height as i64 {
                    continue;
                }
                let i = py as usize * self.width + px as usize;
                if depth < self.depth[i] {
                    self.depth[i] = depth;
                    self.rgb[3 * i..3 * i + 3].copy_from_slice(&rgb);
                }
            }
        }
    }

    /// Eye-dome lighting: darkens a pixel by how far behind its neighbours (3 px away) it lies,
    /// in log depth, quantized to 4 levels to keep the PNG small.
    pub fn eye_dome(&mut self) {
        let (w, h) = (self.width as i64, self.height as i64);
        let log_depth: Vec<f32> = self.depth.iter().map(|d| if d.is_finite() { d.ln() } else { f32::NAN }).collect();
        for y in 0..h {
            for x in 0..w {
                let i = (y * w + x) as usize;
                let here = log_depth[i];
                if here.is_nan() {
                    continue;
                }
                let mut behind = 0.0f32;
                for (dx, dy) in [(3, 0), (-3, 0), (0, 3), (0, -3)] {
                    let (nx, ny) = (x + dx, y + dy);
                    if nx < 0 || ny < 0 || nx >= w || ny >= h {
                        continue;
                    }
                    let there = log_depth[(ny * w + nx) as usize];
                    // Background counts as far behind: the outline of the cloud.
                    behind += if there.is_nan() { 0.0 } else { (here - there).max(0.0) };
                }
                let shade = (-40.0 * behind).exp();
                let shade = (shade * 3.0).round() / 3.0 * 0.75 + 0.25;
                for c in &mut self.rgb[3 * i..3 * i + 3] {
                    *c = (f32::from(*c) * shade) as u8;
                }
            }
        }
    }

    pub fn write_png(&self, path: &Path) -> Result<u64, BoxError> {
        let file = std::fs::File::create(path)?;
        let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), self.width as u32, self.height as u32);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::High);
        encoder.write_header()?.write_image_data(&self.rgb)?;
        Ok(std::fs::metadata(path)?.len())
    }
}

/// A perceptual-ish height colour ramp (blue → cyan → green → yellow → red), shaded by intensity.
pub fn height_colour(t: f64, intensity: u8, obstacle: bool) -> [u8; 3] {
    if obstacle {
        return [255, 40, 200];
    }
    // Quantized (32 hues × 4 shades) so the pictures compress to a few hundred KB.
    let t = (t.clamp(0.0, 1.0) * 31.0).round() / 31.0;
    let stops =
        [[40.0, 60.0, 200.0], [0.0, 190.0, 220.0], [40.0, 200.0, 60.0], [240.0, 220.0, 40.0], [220.0, 50.0, 30.0]];
    let s = t * (stops.len() - 1) as f64;
    let i = (s.floor() as usize).min(stops.len() - 2);
    let f = s - i as f64;
    let shade = 0.5 + 0.5 * (f64::from(intensity) / 255.0 * 3.0).round() / 3.0;
    let mut out = [0u8; 3];
    for c in 0..3 {
        out[c] = ((stops[i][c] * (1.0 - f) + stops[i + 1][c] * f) * shade).clamp(0.0, 255.0) as u8;
    }
    out
}

/// Height range for colouring: 2nd to 98th percentile of the points' z.
pub fn height_range(points: &[MapPoint]) -> (f64, f64) {
    let mut z: Vec<f64> = points.iter().map(|p| f64::from(p.position_m.z)).collect();
    if z.is_empty() {
        return (0.0, 1.0);
    }
    z.sort_by(f64::total_cmp);
    let q = |f: f64| z[((z.len() - 1) as f64 * f) as usize];
    (q(0.02), q(0.98).max(q(0.02) + 1e-3))
}

/// Orthographic view from above, the cloud's x–y bounding box fitted into `width` pixels.
pub fn render_top_down(points: &[MapPoint], width: usize) -> Canvas {
    let (lo, hi) = height_range(points);
    let xs = points.iter().map(|p| f64::from(p.position_m.x));
    let ys = points.iter().map(|p| f64::from(p.position_m.y));
    let (x0, x1) = (xs.clone().fold(f64::INFINITY, f64::min), xs.fold(f64::NEG_INFINITY, f64::max));
    let (y0, y1) = (ys.clone().fold(f64::INFINITY, f64::min), ys.fold(f64::NEG_INFINITY, f64::max));
    let scale = (width as f64 - 20.0) / (x1 - x0).max(y1 - y0).max(1e-3);
    let height = (((y1 - y0) * scale) as usize + 20).max(20);
    let mut canvas = Canvas::new(width, height);
    let splat = (scale * 0.05).ceil().max(1.0) as usize;
    for p in points {
        let (x, y, z) = (f64::from(p.position_m.x), f64::from(p.position_m.y), f64::from(p.position_m.z));
        let colour = height_colour((z - lo) / (hi - lo), p.intensity, p.obstacle);
        // Higher points win: depth is −z.
        canvas.splat(10.0 + (x - x0) * scale, height as f64 - 10.0 - (y - y0) * scale, (-z) as f32, splat, colour);
    }
    canvas
}

/// A view looking at the robust centre of the cloud from `azimuth_deg` (0 = from −x, counter-
/// clockwise) and `elevation_deg` above the horizon, at the distance that fits the cloud's robust
/// bounding box (1st–99th percentile per axis) into the picture with a margin.
pub fn frame_view(
    points: &[MapPoint],
    azimuth_deg: f64,
    elevation_deg: f64,
    fov_deg: f64,
    (width, height): (usize, usize),
) -> (Point3<f64>, Point3<f64>) {
    let quantiles = |a: usize| {
        let mut v: Vec<f64> = points.iter().map(|p| f64::from(p.position_m[a])).collect();
        v.sort_by(f64::total_cmp);
        if v.is_empty() {
            return (0.0, 0.0);
        }
        let q = |f: f64| v[((v.len() - 1) as f64 * f).round() as usize];
        (q(0.01), q(0.99))
    };
    let (x, y, z) = (quantiles(0), quantiles(1), quantiles(2));
    let target = Point3::new((x.0 + x.1) / 2.0, (y.0 + y.1) / 2.0, (z.0 + z.1) / 2.0);
    let (az, el) = (azimuth_deg.to_radians(), elevation_deg.to_radians());
    // Unit vector from the target to the eye.
    let back = Vector3::new(-az.cos() * el.cos(), -az.sin() * el.cos(), el.sin());
    let view = Isometry3::look_at_rh(&(target + back), &target, &Vector3::z());
    let f = (width as f64 / 2.0) / (fov_deg.to_radians() / 2.0).tan();
    // Each corner at camera offset (cx, cy, −cz) from the target sits at depth distance + cz: it
    // fits when f·|cx| / (distance + cz) ≤ 0.45·width (and likewise vertically).
    let mut distance: f64 = 1.0;
    for cx in [x.0, x.1] {
        for cy in [y.0, y.1] {
            for cz in [z.0, z.1] {
                let c = view.rotation * (Point3::new(cx, cy, cz) - target);
                let along = -c.z;
                distance = distance
                    .max(f * c.x.abs() / (0.45 * width as f64) - along)
                    .max(f * c.y.abs() / (0.45 * height as f64) - along);
            }
        }
    }
    (target + back * distance, target)
}

/// Pinhole view from `eye` towards `target` (z up), `fov_deg` horizontal. Points are shaded by
/// eye-dome lighting (darker where neighbouring pixels are nearer), so the silhouettes of
/// obstacles stand out against the ground behind them.
pub fn render_perspective(
    points: &[MapPoint],
    eye: Point3<f64>,
    target: Point3<f64>,
    fov_deg: f64,
    (width, height): (usize, usize),
) -> Canvas {
    let (lo, hi) = height_range(points);
    let view = Isometry3::look_at_rh(&eye, &target, &Vector3::z());
    let f = (width as f64 / 2.0) / (fov_deg.to_radians() / 2.0).tan();
    let mut canvas = Canvas::new(width, height);
    for p in points {
        let pw = p.position_m.cast::<f64>();
        let c = view * pw;
        let z = -c.z;
        if z < 0.3 {
            continue;
        }
        let (u, v) = (width as f64 / 2.0 + f * c.x / z, height as f64 / 2.0 - f * c.y / z);
        let size = ((f * 0.05 / z).ceil() as usize).clamp(1, 8);
        let colour = height_colour((pw.z - lo) / (hi - lo), p.intensity, p.obstacle);
        let size = if p.obstacle { size + 1 } else { size };
        canvas.splat(u, v, z as f32, size, colour);
    }
    canvas.eye_dome();
    canvas
}

/// Writes the cloud as binary PLY (positions) with `eval::map::ply_bytes`.
pub fn write_ply(points: &[MapPoint], path: &Path) -> Result<u64, BoxError> {
    let p: Vec<Point3<f64>> = points.iter().map(|p| p.position_m.cast::<f64>()).collect();
    std::fs::write(path, eval::map::ply_bytes(&p, eval::map::PlyFormat::BinaryLittleEndian))?;
    Ok(std::fs::metadata(path)?.len())
}

/// An empty submap with its origin at `t_world_submap`.
pub fn empty_submap(index: u32, stamp_ns: u64) -> mapper::Submap {
    mapper::Submap {
        robot_id: 0,
        index,
        start_stamp_ns: stamp_ns,
        end_stamp_ns: stamp_ns,
        t_prev_this: Isometry3::identity(),
        switch_covariance: nalgebra::Matrix6::zeros(),
        cloud: mapper::VoxelCloud::new(mapper::cloud::CLOUD_LEAF_M),
        occupancy: mapper::OccupancyMap::new(
            mapper::occupancy::OCTREE_RESOLUTION_M,
            mapper::OccupancyParams::default(),
        ),
        images: 0,
        distance_m: 0.0,
    }
}

/// A gravity-aligned submap origin at the camera: its position, yaw only.
pub fn gravity_aligned(t_world_cam: &Isometry3<f64>) -> Isometry3<f64> {
    let forward = t_world_cam.rotation * Vector3::z();
    let yaw = forward.y.atan2(forward.x);
    Isometry3::new(t_world_cam.translation.vector, Vector3::z() * yaw)
}

/// Integrates frames into fixed-length submaps (a new one every `submap_length_m` of camera
/// travel) and keeps the finished ones in a [`mapper::global::GlobalMap`].
pub struct SubmapRun {
    pub integrator: mapper::integrate::DepthIntegrator,
    pub global: mapper::global::GlobalMap,
    pub current: mapper::Submap,
    pub t_world_current: Isometry3<f64>,
    last_position: Option<Vector3<f64>>,
    pub submap_length_m: f64,
    pub integrate_s: f64,
    pub frames: usize,
}

impl SubmapRun {
    pub fn new(geometry: StereoGeometry, config: mapper::integrate::IntegratorConfig, submap_length_m: f64) -> Self {
        SubmapRun {
            integrator: mapper::integrate::DepthIntegrator::new(config, geometry),
            global: mapper::global::GlobalMap::new(mapper::global::GlobalMapConfig::default()),
            current: empty_submap(0, 0),
            t_world_current: Isometry3::identity(),
            last_position: None,
            submap_length_m,
            integrate_s: 0.0,
            frames: 0,
        }
    }

    pub fn add(&mut self, stamp_ns: u64, depth: &DepthImage, intensity: &[u8], t_world_cam: &Isometry3<f64>) {
        let position = t_world_cam.translation.vector;
        match self.last_position {
            None => {
                self.current = empty_submap(0, stamp_ns);
                self.t_world_current = gravity_aligned(t_world_cam);
            }
            Some(last) => {
                self.current.distance_m += (position - last).norm();
                if self.current.distance_m > self.submap_length_m {
                    let index = self.current.index + 1;
                    let finished = std::mem::replace(&mut self.current, empty_submap(index, stamp_ns));
                    let t_world_next = gravity_aligned(t_world_cam);
                    self.current.t_prev_this = self.t_world_current.inverse() * t_world_next;
                    self.global.insert(std::sync::Arc::new(finished), self.t_world_current);
                    self.t_world_current = t_world_next;
                }
            }
        }
        self.last_position = Some(position);
        let t_submap_cam = self.t_world_current.inverse() * t_world_cam;
        let started = std::time::Instant::now();
        self.integrator.integrate(&mut self.current, depth, None, Some(intensity), &t_submap_cam);
        self.integrate_s += started.elapsed().as_secs_f64();
        self.current.end_stamp_ns = stamp_ns;
        self.frames += 1;
    }

    /// Composes the finished submaps and the current one.
    pub fn compose(&mut self) -> mapper::global::Composition {
        let t = self.t_world_current;
        self.global.compose(Some((&self.current, &t)))
    }
}

/// KITTI `poses.txt`: per frame the 3×4 row-major pose of the left camera in the first camera's frame.
pub fn read_kitti_poses(text: &str) -> Result<Vec<Isometry3<f64>>, BoxError> {
    let mut poses = Vec::new();
    for line in text.lines().filter(|l| !l.trim().is_empty()) {
        let v: Vec<f64> = line.split_whitespace().map(str::parse).collect::<Result<_, _>>()?;
        if v.len() != 12 {
            return Err(format!("pose line with {} values", v.len()).into());
        }
        let r = Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]);
        let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
        poses.push(Isometry3::from_parts(Translation3::new(v[3], v[7], v[11]), rotation));
    }
    Ok(poses)
}
