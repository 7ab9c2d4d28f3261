//! PLY point cloud of a voxel cloud, obstacles in red and the rest grey by intensity.

use std::io::{self, Write};

use nalgebra::{Isometry3, Point3};

use crate::cloud::{MapPoint, VoxelCloud};

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PlyFormat {
    Ascii,
    BinaryLittleEndian,
}

/// Obstacles red so they stand out in any viewer; other points grey by their intensity.
pub fn point_colour(p: &MapPoint) -> [u8; 3] {
    if p.obstacle { [255, 0, 0] } else { [p.intensity; 3] }
}

/// Writes `cloud` as a PLY with `float x, y, z` and `uchar red, green, blue`, each point moved by
/// `t_out_cloud` when given (for example a submap's graph pose to see it in the global frame).
pub fn write_ply(
    cloud: &VoxelCloud,
    format: PlyFormat,
    t_out_cloud: Option<&Isometry3<f64>>,
    out: &mut impl Write,
) -> io::Result<()> {
    let name = match format {
        PlyFormat::Ascii => "ascii",
        PlyFormat::BinaryLittleEndian => "binary_little_endian",
    };
    write!(
        out,
        "ply\nformat {name} 1.0\ncomment voxel cloud, leaf {} m, obstacles red\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
        cloud.leaf_m,
        cloud.len()
    )?;
    // One record buffer reused for all points: a single write call per point either way.
    let mut record = Vec::with_capacity(64);
    for p in &cloud.points {
        let position = match t_out_cloud {
            Some(t) => (t * Point3::from(p.position_m.coords.cast::<f64>())).coords.cast::<f32>(),
            None => p.position_m.coords,
        };
        let [r, g, b] = point_colour(p);
        record.clear();
        match format {
            PlyFormat::Ascii => {
                writeln!(record, "{} {} {} {r} {g} {b}", position.x, position.y, position.z)?;
            }
            PlyFormat::BinaryLittleEndian => {
                position.iter().for_each(|v| record.extend_from_slice(&v.to_le_bytes()));
                record.extend_from_slice(&[r, g, b]);
            }
        }
        out.write_all(&record)?;
    }
    Ok(())
}
