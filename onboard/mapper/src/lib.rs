//! Dense mapping (thesis ch. 5): submaps, their exchange encoding, the composed global map and
//! the exports users open elsewhere.
//!
//! - [`cloud`]: the 5 cm voxel point cloud (centroid, intensity, obstacle bit per voxel).
//! - [`occupancy`]: the 10 cm probabilistic occupancy octree (OctoMap log-odds semantics).
//! - [`integrate`]: one depth image (with its obstacle labels) into a submap's cloud and octree.
//! - [`matching`]: the submap matcher (thesis §6.1): map-matching loop closures.
//! - [`submap`]: a submap and the policy that starts the next one (filter frame switch).
//! - [`exchange`]: compact, lossless encoding of a finished submap for the radio.
//! - [`global`]: composition of all submaps at their graph poses, cached.
//! - [`matching`]: the submap matcher: keypoints, descriptors, Hough/RANSAC, 4-DoF ICP (§6.1.2).
//! - [`pairing`]: which submap pairs the matcher tries, in which order (overlap, Δσ, score).
//! - [`scheduler`]: the matcher as background work: submaps in, attempts and matches out.
//! - [`export`]: PLY point cloud, OctoMap `.bt`, top-down height/traversability PNG.
//! - [`slam`]: the multi-robot SLAM front-end: what enters each robot's pose graph of the team.
//! - [`wire`]: team-protocol messages to and from `slam` measurements, submap fragmentation.
//! - `cloud_file` (feature `cli`, off in the firmware): PLY/PCD/XYZ point-cloud files for the
//!   `submap-match` tool, tests and benchmarks.
//!
//! # Frames
//!
//! A submap's data is in the submap frame: the filter's local frame at the submap's start,
//! gravity-aligned (z up), origin at the body position then. `t_submap_cam` maps left-camera
//! coordinates into it. The global map is in the robot's own global (graph) frame; a submap
//! enters it through `t_global_submap`.
//!
//! Apart from `cloud_file`, this crate does no file or network I/O: encoders write into `Vec<u8>`/`impl Write`.

pub mod cloud;
#[cfg(feature = "cli")]
pub mod cloud_file;
pub mod exchange;
pub mod export;
pub mod global;
pub mod integrate;
pub mod matching;
pub mod occupancy;
pub mod pairing;
pub mod scheduler;
pub mod slam;
pub mod submap;
pub mod wire;

pub use cloud::{MapPoint, VoxelCloud};
pub use occupancy::{OccupancyMap, OccupancyParams, VoxelKey};
pub use submap::Submap;
