//! Map exports users open elsewhere (issue 8): a PLY point cloud (MeshLab, CloudCompare,
//! Open3D), an OctoMap binary `.bt` (octovis, the `octomap` Python binding, ROS) and a top-down
//! height picture (any image viewer). Writers take `impl Write`; this crate does no file I/O.

pub mod bt;
pub mod ply;
pub mod png;

pub use bt::{BtError, BtLeaf, BtTree, read_bt, write_bt};
pub use ply::{PlyFormat, point_colour, write_ply};
pub use png::{PngExportError, write_height_png};
