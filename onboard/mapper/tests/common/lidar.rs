//! The real lidar pair of `data/pointcloud/lidar_pair/` as two matcher clouds.
#![allow(dead_code)]

use nalgebra::{Isometry3, Matrix3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion};

// The includer provides the cloud types (the crate itself or `mapper`).
use super::{CLOUD_LEAF_M, MapPoint, VoxelCloud};

pub const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/pointcloud/lidar_pair");

/// x, y, z, intensity of a binary little-endian PLY with exactly those four float properties.
pub fn read_ply(path: &str) -> Result<Vec<[f32; 4]>, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    let marker = b"end_header\n";
    let end = bytes.windows(marker.len()).position(|w| w == marker).ok_or("no end_header")? + marker.len();
    let header = std::str::from_utf8(&bytes[..end]).map_err(|e| e.to_string())?;
    if !header.contains("format binary_little_endian 1.0") {
        return Err("not binary little-endian".into());
    }
    let count: usize = header
        .lines()
        .find_map(|l| l.strip_prefix("element vertex "))
        .ok_or("no vertex element")?
        .trim()
        .parse()
        .map_err(|e| format!("vertex count: {e}"))?;
    let props: Vec<&str> = header.lines().filter(|l| l.starts_with("property ")).collect();
    if props.len() != 4 || !props.iter().all(|p| p.starts_with("property float ")) {
        return Err(format!("unexpected properties {props:?}"));
    }
    let body = &bytes[end..];
    if body.len() < count * 16 {
        return Err("truncated".into());
    }
    Ok(body[..count * 16]
        .chunks_exact(16)
        .map(|c| {
            let f = |i: usize| f32::from_le_bytes([c[4 * i], c[4 * i + 1], c[4 * i + 2], c[4 * i + 3]]);
            [f(0), f(1), f(2), f(3)]
        })
        .collect())
}

/// The reference `T_target_source` (rotation re-orthonormalised).
pub fn reference() -> Result<Isometry3<f64>, String> {
    let path = format!("{DIR}/T_target_source.txt");
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{path}: {e}"))?;
    let v: Vec<f64> =
        text.split_whitespace().map(str::parse).collect::<Result<_, _>>().map_err(|e| format!("{path}: {e}"))?;
    if v.len() < 16 {
        return Err(format!("{path}: {} numbers, not 16", v.len()));
    }
    let m = Matrix4::from_row_slice(&v[..16]);
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into_owned();
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    Ok(Isometry3::from_parts(Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]), rotation))
}

/// A scan as a submap cloud: points within `range_m` (horizontal) of the sensor, voxel-filtered
/// at 5 cm, intensity scaled to a grey value. A point is an obstacle when it lies more than
/// `obstacle_height_m` above the lowest point of its 1 m × 1 m column (a local ground
/// estimate): the lidar has no stereo obstacle classifier, and flagging everything would make
/// the flat road keypoints too.
pub fn cloud(name: &str, range_m: f32, obstacle_height_m: f32) -> Result<VoxelCloud, String> {
    let raw = read_ply(&format!("{DIR}/{name}.ply"))?;
    let near: Vec<[f32; 4]> =
        raw.into_iter().filter(|p| p[0].hypot(p[1]) <= range_m && p.iter().all(|v| v.is_finite())).collect();
    let mut ground: std::collections::HashMap<(i32, i32), f32> = std::collections::HashMap::new();
    for p in &near {
        let key = (p[0].floor() as i32, p[1].floor() as i32);
        let z = ground.entry(key).or_insert(f32::INFINITY);
        *z = z.min(p[2]);
    }
    let max_intensity = near.iter().map(|p| p[3]).fold(0f32, f32::max).max(1e-6);
    let points: Vec<MapPoint> = near
        .iter()
        .map(|p| {
            let floor = ground.get(&(p[0].floor() as i32, p[1].floor() as i32)).copied().unwrap_or(p[2]);
            MapPoint {
                position_m: Point3::new(p[0], p[1], p[2]),
                intensity: (p[3] / max_intensity * 255.0).round().clamp(0.0, 255.0) as u8,
                obstacle: p[2] - floor > obstacle_height_m,
            }
        })
        .collect();
    Ok(VoxelCloud::filtered(CLOUD_LEAF_M, &points))
}
