//! A synthetic rocky terrain patch for the matcher's tests and benchmark: undulating ground with
//! fine noise and grey-value texture (not obstacles), and irregular half-buried rocks (obstacle
//! points) of a few hundred 5 cm points each. Crops of it are seen from two submap frames, each
//! with its own sensor noise and its own 5 cm voxelisation, as two robots' submaps would be.
#![allow(dead_code)]

// The includer provides the cloud types (the crate itself or `mapper`).
use super::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

/// SplitMix64, so the terrain is the same on every platform.
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Rng {
        Rng(seed)
    }
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in [0, 1).
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.uniform()
    }
    /// Standard normal (Box–Muller).
    pub fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
    }
}

struct Rock {
    center: Vector3<f64>,
    radii: Vector3<f64>,
    yaw: f64,
    bumps: [(f64, f64, f64); 3],
    grey: f64,
}

impl Rock {
    /// Surface point in direction (azimuth, elevation) in the rock's frame, world coordinates.
    fn surface(&self, az: f64, el: f64) -> Vector3<f64> {
        let bump: f64 = self.bumps.iter().map(|&(a, k, ph)| a * (k * az + ph).sin() * (k * el + ph).cos()).sum();
        let d = Vector3::new(
            el.cos() * az.cos() * self.radii.x,
            el.cos() * az.sin() * self.radii.y,
            el.sin() * self.radii.z,
        ) * (1.0 + bump);
        let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), self.yaw);
        self.center + r * d
    }

    fn covers(&self, x: f64, y: f64) -> bool {
        let r = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), -self.yaw);
        let l = r * Vector3::new(x - self.center.x, y - self.center.y, 0.0);
        (l.x / self.radii.x).powi(2) + (l.y / self.radii.y).powi(2) < 0.8
    }
}

fn ground_height(x: f64, y: f64) -> f64 {
    0.25 * (0.35 * x).sin() * (0.27 * y).cos() + 0.08 * (1.3 * x + 0.4).sin() * (1.1 * y - 0.7).sin()
}

fn ground_grey(x: f64, y: f64) -> f64 {
    110.0 + 25.0 * (2.1 * x).sin() * (1.7 * y + 0.3).cos() + 15.0 * (5.3 * x - 3.1 * y).sin()
}

/// Raw terrain samples (about 2.5 cm apart) of a `size_m` square patch starting at the origin,
/// with `rocks` rocks.
pub fn terrain(size_m: f64, rocks: usize, seed: u64) -> Vec<MapPoint> {
    let mut rng = Rng::new(seed);
    let rocks: Vec<Rock> = (0..rocks)
        .map(|_| {
            let radii = Vector3::new(rng.range(0.15, 0.5), rng.range(0.15, 0.45), rng.range(0.12, 0.4));
            let (x, y) = (rng.range(0.3, size_m - 0.3), rng.range(0.3, size_m - 0.3));
            let center = Vector3::new(x, y, ground_height(x, y) - 0.3 * radii.z);
            let mut bump = || (rng.range(0.03, 0.12), rng.range(2.0, 5.0).round(), rng.range(0.0, 6.3));
            let bumps = [bump(), bump(), bump()];
            Rock { center, radii, yaw: rng.range(0.0, std::f64::consts::TAU), bumps, grey: rng.range(140.0, 200.0) }
        })
        .collect();
    let mut out = Vec::new();
    let step = 0.025;
    let n = (size_m / step) as usize;
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f64 * step + rng.range(0.0, step), j as f64 * step + rng.range(0.0, step));
            if rocks.iter().any(|r| r.covers(x, y)) {
                continue;
            }
            let z = ground_height(x, y) + 0.005 * rng.normal();
            let grey = (ground_grey(x, y) + 8.0 * rng.normal()).clamp(0.0, 255.0) as u8;
            out.push(MapPoint {
                position_m: Point3::new(x as f32, y as f32, z as f32),
                intensity: grey,
                obstacle: false,
            });
        }
    }
    for rock in &rocks {
        let mean_r = (rock.radii.x + rock.radii.y + rock.radii.z) / 3.0;
        let count = (4.0 * std::f64::consts::PI * mean_r * mean_r / (step * step)) as usize;
        for _ in 0..count {
            // Uniform on the sphere, then stretched: good enough coverage at this density.
            let az = rng.range(-std::f64::consts::PI, std::f64::consts::PI);
            let el = rng.range(-1.0f64, 1.0).asin();
            let p = rock.surface(az, el);
            if p.z < ground_height(p.x, p.y) {
                continue;
            }
            let grey =
                (rock.grey + 20.0 * (7.0 * az).sin() * (5.0 * el).cos() + 6.0 * rng.normal()).clamp(0.0, 255.0) as u8;
            out.push(MapPoint {
                position_m: Point3::new(p.x as f32, p.y as f32, p.z as f32),
                intensity: grey,
                obstacle: true,
            });
        }
    }
    out
}

/// A submap frame in the terrain's frame: origin (x, y, z) and yaw (gravity-aligned).
pub fn frame(x: f64, y: f64, z: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, z), UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw))
}

/// The raw samples inside the world-frame box [min, max] (xy), expressed in `t_world_frame`'s
/// frame with isotropic noise `noise_m`, voxel-filtered at 5 cm.
pub fn crop(
    raw: &[MapPoint],
    min_xy: (f64, f64),
    max_xy: (f64, f64),
    t_world_frame: &Isometry3<f64>,
    noise_m: f64,
    seed: u64,
) -> VoxelCloud {
    let mut rng = Rng::new(seed);
    let t_frame_world = t_world_frame.inverse();
    let pts: Vec<MapPoint> = raw
        .iter()
        .filter(|p| {
            let (x, y) = (f64::from(p.position_m.x), f64::from(p.position_m.y));
            x >= min_xy.0 && x <= max_xy.0 && y >= min_xy.1 && y <= max_xy.1
        })
        .map(|p| {
            let w = p.position_m.cast::<f64>();
            let l = t_frame_world * w + Vector3::new(rng.normal(), rng.normal(), rng.normal()) * noise_m;
            MapPoint { position_m: l.cast::<f32>(), ..*p }
        })
        .collect();
    VoxelCloud::filtered(CLOUD_LEAF_M, &pts)
}

/// Two overlapping crops of one terrain and the true `t_target_source`.
pub struct Pair {
    pub source: VoxelCloud,
    pub target: VoxelCloud,
    pub t_target_source: Isometry3<f64>,
}

/// The standard test pair: an 8 m × 8 m source crop and a target crop shifted by (2.5, 1.5) m
/// (5.5 m × 6.5 m overlap), seen from frames differing by (x, y, z, yaw).
pub fn standard_pair(noise_m: f64) -> Pair {
    let raw = terrain(11.0, 45, 42);
    let t_world_source = frame(1.0, 1.0, 0.05, 0.3);
    let t_world_target = frame(3.4, 2.3, -0.12, -0.45);
    let source = crop(&raw, (0.0, 0.0), (8.0, 8.0), &t_world_source, noise_m, 1);
    let target = crop(&raw, (2.5, 1.5), (10.5, 9.5), &t_world_target, noise_m, 2);
    Pair { source, target, t_target_source: t_world_target.inverse() * t_world_source }
}
