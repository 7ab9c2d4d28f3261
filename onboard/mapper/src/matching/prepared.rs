//! A cloud ready for matching: its keypoints and suitability at once, its search tree and
//! descriptors on first use (trap T17: a submap never popped from the queue costs no
//! descriptors).

use std::fmt;
use std::sync::{Arc, OnceLock};

use nalgebra::{Point3, Vector3};

use super::descriptor::{Features, compute_features};
use super::keypoints::{line_spread, obstacle_keypoints};
use super::normals::{all_normals, normals_near};
use super::params::MatcherParams;
use super::report::Unsuitable;
use super::spatial::PointIndex;
use crate::cloud::VoxelCloud;

/// A cloud ready for matching: Send + Sync, shared as `Arc` between the pairing side and a
/// matcher thread.
pub struct PreparedCloud {
    cloud: Arc<VoxelCloud>,
    /// The parameters the features are computed with.
    params: MatcherParams,
    positions: Vec<Point3<f32>>,
    keypoints: Vec<Point3<f32>>,
    suitability: Result<(), Unsuitable>,
    index: OnceLock<PointIndex>,
    normals: OnceLock<Vec<Option<Vector3<f32>>>>,
    features: OnceLock<Features>,
}

impl fmt::Debug for PreparedCloud {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("PreparedCloud")
            .field("points", &self.cloud.len())
            .field("keypoints", &self.keypoints.len())
            .field("suitability", &self.suitability)
            .field("features_ready", &self.features_ready())
            .finish_non_exhaustive()
    }
}

impl PreparedCloud {
    /// Size check (< min_points or < min_obstacle_points → unsuitable), keypoints = centroids of
    /// the obstacle points in `keypoint_voxel_m` voxels, descriptiveness check (RANSAC 3-D line;
    /// ≥ `min_spread_keypoints` keypoints farther than `line_spread_distance_m` from it in xy).
    /// Descriptors are computed lazily on the first match that needs them, then cached.
    pub fn new(cloud: Arc<VoxelCloud>, params: &MatcherParams) -> PreparedCloud {
        // Non-finite points would poison every geometric stage; they cannot come from a voxel
        // filter, but a decoded or hand-made cloud might carry them.
        let positions: Vec<Point3<f32>> = cloud.points.iter().map(|p| p.position_m).collect();
        let points = cloud.len();
        let obstacles = cloud.obstacle_count();
        let keypoints = if points > 0 { obstacle_keypoints(&cloud, params.keypoint_voxel_m) } else { Vec::new() };
        let finite = positions.iter().all(|p| p.coords.iter().all(|v| v.is_finite()));
        let suitability = if points < params.min_points || !finite {
            Err(Unsuitable::TooFewPoints { points, min: params.min_points })
        } else if obstacles < params.min_obstacle_points {
            Err(Unsuitable::TooFewObstaclePoints { points: obstacles, min: params.min_obstacle_points })
        } else {
            let spread = line_spread(&keypoints, params);
            if spread < params.min_spread_keypoints {
                Err(Unsuitable::NotDescriptive { spread, min: params.min_spread_keypoints })
            } else {
                Ok(())
            }
        };
        PreparedCloud {
            cloud,
            params: params.clone(),
            positions,
            keypoints,
            suitability,
            index: OnceLock::new(),
            normals: OnceLock::new(),
            features: OnceLock::new(),
        }
    }

    pub fn cloud(&self) -> &VoxelCloud {
        &self.cloud
    }

    /// Keypoints in the cloud's frame.
    pub fn keypoints(&self) -> &[Point3<f32>] {
        &self.keypoints
    }

    pub fn suitability(&self) -> Result<(), Unsuitable> {
        self.suitability
    }

    /// Whether the descriptors are computed (the next match skips that stage).
    pub fn features_ready(&self) -> bool {
        self.features.get().is_some()
    }

    /// Number of keypoints that got a descriptor (computes the features if needed).
    pub fn described_keypoints(&self) -> usize {
        self.features().len()
    }

    /// The parameters this cloud's features are computed with.
    pub fn params(&self) -> &MatcherParams {
        &self.params
    }

    pub(crate) fn positions(&self) -> &[Point3<f32>] {
        &self.positions
    }

    pub(crate) fn index(&self) -> &PointIndex {
        self.index.get_or_init(|| PointIndex::new(&self.positions))
    }

    /// Normals of every point, for the descriptors and for point-to-plane ICP on this cloud as
    /// the target.
    pub(crate) fn normals(&self) -> &[Option<Vector3<f32>>] {
        self.normals.get_or_init(|| all_normals(&self.positions, self.index(), self.params.normal_radius_m as f32))
    }

    /// Descriptors of the keypoints. They read the normals of the points within the descriptor
    /// radius of a keypoint only: those are computed alone unless every normal already is (ICP
    /// as the target needs them all, and most pairs never reach ICP).
    pub(crate) fn features(&self) -> &Features {
        self.features.get_or_init(|| {
            let near;
            let normals = match self.normals.get() {
                Some(all) => all.as_slice(),
                None => {
                    near = normals_near(
                        &self.positions,
                        self.index(),
                        &self.keypoints,
                        self.params.descriptor_radius_m as f32,
                        self.params.normal_radius_m as f32,
                    );
                    near.as_slice()
                }
            };
            compute_features(&self.cloud, &self.positions, normals, self.index(), &self.keypoints, &self.params)
        })
    }
}
