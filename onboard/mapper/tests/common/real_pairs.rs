//! The real point-cloud pairs of `data/pointcloud/` with their reference transforms, shared by the
//! `submap-match` tests and the Open3D comparison benchmark (`#[path]`-included by both).

#![allow(dead_code, reason = "each includer uses its own part")]

use std::path::{Path, PathBuf};
use std::process::Command;

use nalgebra::{Isometry3, Matrix3, Matrix4, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};

pub const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/pointcloud/");

/// The extra yaw applied to the lidar source for the non-trivial pair.
pub const EXTRA_YAW_DEG: f64 = 30.0;

/// One pair: files, the reference `t_target_source`, and how each tool is told the scale.
#[derive(Debug, Clone)]
pub struct RealPair {
    pub name: &'static str,
    pub source: PathBuf,
    pub target: PathBuf,
    pub t_target_source: Isometry3<f64>,
    /// `submap-match` options besides the files and `--json`.
    pub ours_args: Vec<String>,
    /// Open3D's down-sampling voxel (its other lengths are multiples of it), m: the resolution
    /// our matcher works at too.
    pub voxel_m: f64,
}

/// Reads a 4×4 row-major matrix text file (whitespace separated) as an isometry.
pub fn read_transform(path: &Path) -> Isometry3<f64> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let values: Vec<f64> = text.split_ascii_whitespace().map(|t| t.parse().unwrap()).collect();
    assert_eq!(values.len(), 16, "{}", path.display());
    isometry_from_rows(&values)
}

/// A 4×4 row-major matrix as an isometry (the rotation re-orthonormalised: text files carry
/// six digits).
pub fn isometry_from_rows(values: &[f64]) -> Isometry3<f64> {
    let m = Matrix4::from_row_slice(values);
    let r: Matrix3<f64> = m.fixed_view::<3, 3>(0, 0).into();
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix(&r));
    Isometry3::from_parts(Translation3::new(m[(0, 3)], m[(1, 3)], m[(2, 3)]), rotation)
}

/// Rotation error (deg) and translation error (m) of `estimate` against `reference`.
pub fn errors(estimate: &Isometry3<f64>, reference: &Isometry3<f64>) -> (f64, f64) {
    let rotation_deg = (reference.rotation.inverse() * estimate.rotation).angle().to_degrees();
    let translation_m = (estimate.translation.vector - reference.translation.vector).norm();
    (rotation_deg, translation_m)
}

/// The bunny: PCL's bun4 (source) into bun0 (target); Stanford's registration as reference.
pub fn bunny() -> RealPair {
    RealPair {
        name: "bunny",
        source: PathBuf::from(format!("{DATA}bunny/pcl_test_bun4.pcd")),
        target: PathBuf::from(format!("{DATA}bunny/pcl_test_bun0.pcd")),
        t_target_source: read_transform(Path::new(&format!("{DATA}bunny/T_target_source.txt"))),
        // y is up (the turntable axis): the 34° turn becomes mostly a yaw, and 6D takes the
        // rest. Points ~6 mm apart: the resolution lengths a tenth of a submap's (5 mm voxels,
        // 2 cm radii). The spread distance scales with the scene instead: 0.5 m is ~1/20 of a
        // ~10 m submap, and 1/20 of the ~15 cm bunny is 7.5 mm. ~350 points per cloud after the
        // voxel filter, so the size gates (1000 points, 300 ICP pairs) come down too.
        ours_args: [
            "--up",
            "0,1,0",
            "--mode",
            "6d",
            "--scale",
            "0.1",
            "--spread-m",
            "0.0075",
            "--min-points",
            "200",
            "--icp-min-pairs",
            "100",
        ]
        .map(String::from)
        .to_vec(),
        voxel_m: 0.005,
    }
}

/// The lidar pair as published.
pub fn lidar() -> RealPair {
    RealPair {
        name: "lidar",
        source: PathBuf::from(format!("{DATA}lidar_pair/source.ply")),
        target: PathBuf::from(format!("{DATA}lidar_pair/target.ply")),
        t_target_source: read_transform(Path::new(&format!("{DATA}lidar_pair/T_target_source.txt"))),
        ours_args: Vec::new(),
        voxel_m: 0.05,
    }
}

/// The lidar pair with the source turned by [`EXTRA_YAW_DEG`] about z, written as a plain
/// binary PLY into `dir`: `source' = Rz · source`, so `t_target_source' = t_target_source · Rz⁻¹`.
pub fn lidar_yawed(dir: &Path) -> RealPair {
    let base = lidar();
    let cloud = mapper::cloud_file::read_cloud(&base.source).unwrap();
    let rz = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), EXTRA_YAW_DEG.to_radians());
    let rotated: Vec<Point3<f32>> =
        cloud.points.iter().map(|p| (rz * p.position_m.cast::<f64>()).cast::<f32>()).collect();
    std::fs::create_dir_all(dir).unwrap();
    let source = dir.join(format!("lidar_source_yaw{EXTRA_YAW_DEG}.ply"));
    write_plain_ply(&source, &rotated);
    RealPair {
        name: "lidar + 30° yaw",
        source,
        t_target_source: base.t_target_source * Isometry3::from_parts(Translation3::identity(), rz.inverse()),
        ..base
    }
}

/// A generic binary little-endian PLY with `float x y z` only (not the project's export, whose
/// colours would mark these points as non-obstacles).
pub fn write_plain_ply(path: &Path, points: &[Point3<f32>]) {
    let mut bytes = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty float x\nproperty float y\nproperty float z\nend_header\n",
        points.len()
    )
    .into_bytes();
    for p in points {
        p.coords.iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
    }
    std::fs::write(path, bytes).unwrap();
}

/// One `submap-match --json` run: its exit code and JSON object.
pub fn run_ours(exe: &str, pair: &RealPair) -> (Option<i32>, serde_json::Value) {
    let output = Command::new(exe)
        .arg("--source")
        .arg(&pair.source)
        .arg("--target")
        .arg(&pair.target)
        .args(&pair.ours_args)
        .arg("--json")
        .output()
        .unwrap();
    let json = serde_json::from_slice(&output.stdout).unwrap_or_else(|e| {
        panic!(
            "{}: {e}; stdout {:?}, stderr {:?}",
            pair.name,
            String::from_utf8_lossy(&output.stdout),
            String::from_utf8_lossy(&output.stderr)
        )
    });
    (output.status.code(), json)
}

/// The `transform` field of a JSON result (4×4 row-major) as an isometry.
pub fn json_transform(json: &serde_json::Value) -> Option<Isometry3<f64>> {
    let rows = json["transform"].as_array()?;
    let values: Vec<f64> =
        rows.iter().flat_map(|r| r.as_array().into_iter().flatten()).filter_map(|v| v.as_f64()).collect();
    (values.len() == 16).then(|| isometry_from_rows(&values))
}
