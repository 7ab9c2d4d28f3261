//! 3-D nearest-neighbour and radius queries over a cloud's points (kiddo's immutable k-d tree).
//!
//! A voxel hash grid was not measured against it: a 5 cm surface cloud puts ~16 points in each
//! 0.2 m cell, so a 27-cell scan would test ~400 candidates for the ~50 hits of a 0.2 m radius
//! query, and nearest-neighbour queries with ICP's shrinking gate would need a grid per gate.

use kiddo::SquaredEuclidean;
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use nalgebra::Point3;

/// Bucket size 32: kiddo's default, and fine for clouds with many duplicate coordinates.
type Tree = ImmutableKdTree<f32, u32, 3, 32>;

#[derive(Debug, Clone)]
pub(crate) struct PointIndex {
    /// None for an empty cloud (kiddo's queries assume at least one point).
    tree: Option<Tree>,
}

impl PointIndex {
    pub(crate) fn new(points: &[Point3<f32>]) -> PointIndex {
        if points.is_empty() {
            return PointIndex { tree: None };
        }
        let coords: Vec<[f32; 3]> = points.iter().map(|p| [p.x, p.y, p.z]).collect();
        PointIndex { tree: Some(Tree::new_from_slice(&coords)) }
    }

    /// The nearest point's index and squared distance.
    pub(crate) fn nearest(&self, q: &Point3<f32>) -> Option<(usize, f32)> {
        let tree = self.tree.as_ref()?;
        let n = tree.nearest_one::<SquaredEuclidean>(&[q.x, q.y, q.z]);
        Some((n.item as usize, n.distance))
    }

    /// Indices of the points within `radius_m` of `q` (unsorted), replacing `out`'s contents.
    pub(crate) fn within(&self, q: &Point3<f32>, radius_m: f32, out: &mut Vec<usize>) {
        out.clear();
        if let Some(tree) = &self.tree {
            out.extend(
                tree.within_unsorted::<SquaredEuclidean>(&[q.x, q.y, q.z], radius_m * radius_m)
                    .into_iter()
                    .map(|n| n.item as usize),
            );
        }
    }
}
