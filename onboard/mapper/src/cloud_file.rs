//! Point-cloud files for the command-line tools, tests and benchmarks (feature `cli`; the on-board
//! code gets its clouds from the integrator and the radio, never from files).
//!
//! Formats, recognised by their first bytes (not the file name):
//! - PLY (`ply\n`): ASCII, binary little- and big-endian; the `vertex` element's `x y z` of any
//!   scalar type, an optional `intensity` / `scalar_intensity`. The project's own export
//!   (`export::write_ply`, header comment `voxel cloud`) keeps its obstacle flag: red points are
//!   obstacles, grey ones are not and carry their intensity. Any other PLY: every point is an
//!   obstacle, since nothing says otherwise and the matcher's keypoints come from obstacles.
//! - PCD (`#` comment or `VERSION`): `DATA ascii` or `binary`, fields `x y z`, optional `intensity`.
//! - XYZ text: anything else; one point per line, at least three numbers separated by blanks or
//!   commas; `#` and `//` lines are comments. Every point is an obstacle.
//!
//! Points with a non-finite coordinate (PCD's NaN for "no return") are dropped and counted.
//! Every parser is total: any bytes give points or an error, never a panic or an allocation
//! larger than the input warrants.

mod pcd;
mod ply;
mod scalar;
mod xyz;

use std::path::Path;

use nalgebra::Point3;

use crate::cloud::MapPoint;

/// Which parser read a file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CloudFormat {
    /// The project's own PLY export, obstacle flag from the colour.
    ProjectPly,
    Ply,
    Pcd,
    Xyz,
}

impl CloudFormat {
    pub fn name(self) -> &'static str {
        match self {
            CloudFormat::ProjectPly => "ply (project export)",
            CloudFormat::Ply => "ply",
            CloudFormat::Pcd => "pcd",
            CloudFormat::Xyz => "xyz",
        }
    }
}

/// The points of a file, in the file's frame and unit (metres expected).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CloudFile {
    pub points: Vec<MapPoint>,
    /// Points dropped for a NaN or infinite coordinate.
    pub dropped_non_finite: usize,
    pub format: Option<CloudFormat>,
}

/// Why bytes are not a point cloud; the message says where.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CloudParseError {
    #[error("{format}: header: {message}")]
    Header { format: &'static str, message: String },
    #[error("{format}: {what}: {message}")]
    Data { format: &'static str, what: String, message: String },
    #[error("{format}: no points")]
    Empty { format: &'static str },
}

/// Why a file could not be read as a point cloud.
#[derive(Debug, thiserror::Error)]
pub enum CloudFileError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: {source}")]
    Parse { path: String, source: CloudParseError },
}

/// Reads a PLY, PCD or XYZ file (by its first bytes).
pub fn read_cloud(path: impl AsRef<Path>) -> Result<CloudFile, CloudFileError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| CloudFileError::Io { path: name.clone(), source })?;
    parse_cloud(&bytes).map_err(|source| CloudFileError::Parse { path: name, source })
}

/// Parses the bytes of a PLY, PCD or XYZ file (by its first bytes).
pub fn parse_cloud(bytes: &[u8]) -> Result<CloudFile, CloudParseError> {
    if bytes.starts_with(b"ply\n") || bytes.starts_with(b"ply\r\n") {
        ply::parse(bytes)
    } else if looks_like_pcd(bytes) {
        pcd::parse(bytes)
    } else {
        xyz::parse(bytes)
    }
}

/// A PCD header starts with comments and then `VERSION` (PCL writes `# .PCD v0.7 ...` first).
fn looks_like_pcd(bytes: &[u8]) -> bool {
    bytes
        .split(|&b| b == b'\n')
        .map(|line| line.trim_ascii())
        .find(|line| !line.is_empty() && !line.starts_with(b"#"))
        .is_some_and(|line| line.starts_with(b"VERSION"))
}

/// Collects points, dropping non-finite ones; shared by the parsers.
#[derive(Debug, Default)]
struct PointSink {
    points: Vec<MapPoint>,
    dropped_non_finite: usize,
}

impl PointSink {
    /// `capacity_hint` comes from a header: trusted only as far as the input's size allows.
    fn with_capacity(capacity_hint: usize, input_len: usize, min_record_len: usize) -> PointSink {
        let bound = input_len / min_record_len.max(1);
        PointSink { points: Vec::with_capacity(capacity_hint.min(bound)), dropped_non_finite: 0 }
    }

    fn push(&mut self, xyz: [f64; 3], intensity: u8, obstacle: bool) {
        let position = xyz.map(|v| v as f32);
        if position.iter().all(|v| v.is_finite()) {
            self.points.push(MapPoint { position_m: Point3::from(position), intensity, obstacle });
        } else {
            self.dropped_non_finite += 1;
        }
    }

    fn finish(self, format: CloudFormat) -> Result<CloudFile, CloudParseError> {
        if self.points.is_empty() && self.dropped_non_finite == 0 {
            return Err(CloudParseError::Empty { format: format.name() });
        }
        Ok(CloudFile { points: self.points, dropped_non_finite: self.dropped_non_finite, format: Some(format) })
    }
}

/// Intensity of a file's value as the cloud's grey level: rounded and clamped to 0..=255 (lidar
/// intensities beyond that saturate; the matcher does not use intensity).
fn grey_level(value: f64) -> u8 {
    if value.is_nan() { 0 } else { value.round().clamp(0.0, 255.0) as u8 }
}
