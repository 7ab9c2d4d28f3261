//! Shared by the real-data mapping examples: SGM depth, a software point renderer with a depth
//! buffer (the pictures in the README), PNG/PLY output and the height-consistency statistic.
#![allow(dead_code)]

use std::collections::HashMap;
use std::path::Path;

use fpga_model::fast::Matcher;
use fpga_model::{DisparityImage, GrayImage, SgmConfig};
use hal::sensor::{StereoCalibration, StereoFrame};
use mapper::cloud::MapPoint;
use nalgebra::{Isometry3, Point3, Vector3};
use vision::depth::{DepthImage, StereoGeometry};

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

/// SGM (the FPGA model's fast path) from rectified pairs to depth, buffers reused.
pub struct StereoDepth {
    matcher: Matcher,
    left: GrayImage,
    right: GrayImage,
    disparity: DisparityImage,
    pub depth: DepthImage,
    geometry: StereoGeometry,
}

impl StereoDepth {
    pub fn new(disparities: u16, width: usize, height: usize, geometry: StereoGeometry) -> Result<Self, BoxError> {
        let config = SgmConfig { disparities, ..SgmConfig::default() };
        let threads = std::thread::available_parallelism().map_or(1, |n| n.get());
        Ok(StereoDepth {
            matcher: Matcher::new(config, width, height, threads)?,
            left: GrayImage { width, height, pixels: vec![0; width * height] },
            right: GrayImage { width, height, pixels: vec![0; width * height] },
            disparity: DisparityImage { width, height, data: vec![0; width * height] },
            depth: DepthImage::new(width, height),
            geometry,
        })
    }

    pub fn compute(&mut self, frame: &StereoFrame) -> Result<&DepthImage, BoxError> {
        self.left.pixels.copy_from_slice(&frame.left);
        self.right.pixels.copy_from_slice(&frame.right);
        self.matcher.compute_into(&self.left, &self.right, &mut self.disparity)?;
        self.depth.fill_from_disparity(&self.disparity, &self.geometry);
        Ok(&self.depth)
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

    /// (cells seen by ≥ 2 frames, median spread, 95th-percentile spread) in metres.
    pub fn spread(&self) -> (usize, f64, f64) {
        let mut s: Vec<f64> = self.cells.values().filter(|c| c.2 >= 2).map(|c| c.1 - c.0).collect();
        s.sort_by(f64::total_cmp);
        let q = |f: f64| if s.is_empty() { f64::NAN } else { s[((s.len() - 1) as f64 * f).round() as usize] };
        (s.len(), q(0.5), q(0.95))
    }
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

/// Pinhole view from `eye` towards `target` (z up), `fov_deg` horizontal.
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
        canvas.splat(u, v, z as f32, size, colour);
    }
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
