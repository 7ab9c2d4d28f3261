//! Keypoints (§6.1.1 b) and the keypoint-distribution test (§6.1.1 d, reused for hypotheses in
//! §6.1.2 d).

use nalgebra::{Point3, Vector2, Vector3};

use super::params::MatcherParams;
use super::rng::SplitMix64;
use crate::cloud::{MapPoint, VoxelCloud};

/// Centroids of the cloud's obstacle points per `voxel_m` voxel (the same voxel filter as the
/// submap clouds, on obstacle points only: trap T11).
pub(crate) fn obstacle_keypoints(cloud: &VoxelCloud, voxel_m: f64) -> Vec<Point3<f32>> {
    let obstacles: Vec<MapPoint> = cloud.points.iter().filter(|p| p.obstacle).copied().collect();
    VoxelCloud::filtered(voxel_m, &obstacles).points.into_iter().map(|p| p.position_m).collect()
}

/// A 3-D line through `origin` along the unit vector `direction`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Line3 {
    pub origin: Point3<f32>,
    pub direction: Vector3<f32>,
}

impl Line3 {
    fn distance(&self, p: &Point3<f32>) -> f32 {
        let d = p - self.origin;
        (d - self.direction * d.dot(&self.direction)).norm()
    }

    /// Distance of `p` from the line, both projected onto the xy-plane. A vertical line
    /// projects to a point, and the distance is the one to that point.
    fn distance_xy(&self, p: &Point3<f32>) -> f32 {
        let d = Vector2::new(p.x - self.origin.x, p.y - self.origin.y);
        let u = Vector2::new(self.direction.x, self.direction.y);
        let n = u.norm();
        if n < 1e-6 {
            return d.norm();
        }
        let u = u / n;
        (d - u * d.dot(&u)).norm()
    }
}

/// RANSAC fit of a 3-D line: the two-point line with most points within `inlier_m`. None for
/// fewer than two distinct points.
pub(crate) fn ransac_line(points: &[Point3<f32>], inlier_m: f32, iterations: usize, seed: u64) -> Option<Line3> {
    if points.len() < 2 {
        return None;
    }
    let mut rng = SplitMix64::new(seed);
    let mut best: Option<(usize, Line3)> = None;
    for _ in 0..iterations {
        let a = points[rng.below(points.len())];
        let b = points[rng.below(points.len())];
        let d = b - a;
        let len = d.norm();
        if !(len > 1e-4) {
            continue;
        }
        let line = Line3 { origin: a, direction: d / len };
        let inliers = points.iter().filter(|p| line.distance(p) < inlier_m).count();
        if best.is_none_or(|(n, _)| inliers > n) {
            best = Some((inliers, line));
        }
    }
    if best.is_none() {
        // Random draws can miss the only distinct pair of a nearly all-duplicate set.
        let a = points[0];
        if let Some(b) = points.iter().find(|p| (*p - a).norm() > 1e-4) {
            let d = b - a;
            best = Some((0, Line3 { origin: a, direction: d / d.norm() }));
        }
    }
    best.map(|(_, l)| l)
}

/// Number of `points` farther than `spread_m` from their RANSAC line in the xy-plane: the
/// thesis's descriptiveness measure (a straight wall or a single stone scores low).
pub(crate) fn line_spread(points: &[Point3<f32>], params: &MatcherParams) -> usize {
    let Some(line) = ransac_line(points, params.line_inlier_m as f32, params.line_iterations, params.seed) else {
        return 0;
    };
    let spread_m = params.line_spread_distance_m as f32;
    points.iter().filter(|p| line.distance_xy(p) > spread_m).count()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    /// A noisy wall along a 30° line plus `extra` points scattered 2 m off it.
    fn wall(extra: usize) -> Vec<Point3<f32>> {
        let mut rng = SplitMix64::new(3);
        let mut noise = || (rng.below(1000) as f32 / 1000.0 - 0.5) * 0.1;
        let (c, s) = (30f32.to_radians().cos(), 30f32.to_radians().sin());
        let mut pts: Vec<Point3<f32>> = (0..200)
            .map(|i| {
                let t = i as f32 * 0.05;
                Point3::new(1.0 + c * t + noise(), 2.0 + s * t + noise(), 0.3 * (i % 7) as f32 + noise())
            })
            .collect();
        for i in 0..extra {
            let t = i as f32 * 0.3;
            pts.push(Point3::new(1.0 + c * t - s * 2.0, 2.0 + s * t + c * 2.0, 0.2));
        }
        pts
    }

    #[test]
    fn ransac_line_finds_the_wall_among_outliers() {
        let pts = wall(25);
        let line = ransac_line(&pts, 0.2, 200, 1).unwrap();
        let angle = line.direction.y.atan2(line.direction.x).to_degrees().rem_euclid(180.0);
        assert!((angle - 30.0).abs() < 3.0, "line direction {angle}°");
        assert!(line.distance_xy(&Point3::new(1.0, 2.0, 0.0)) < 0.1);
    }

    #[test]
    fn spread_counts_points_off_the_wall_only() {
        let params = MatcherParams::default();
        assert!(line_spread(&wall(0), &params) < 10, "a straight wall is not descriptive");
        assert_eq!(line_spread(&wall(25), &params), 25);
    }

    #[test]
    fn degenerate_sets_do_not_panic() {
        let params = MatcherParams::default();
        assert_eq!(line_spread(&[], &params), 0);
        assert_eq!(line_spread(&[Point3::origin(); 5], &params), 0);
        let vertical: Vec<_> = (0..20).map(|i| Point3::new(0.0, 0.0, i as f32 * 0.1)).collect();
        assert_eq!(line_spread(&vertical, &params), 0);
    }
}
