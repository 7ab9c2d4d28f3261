//! Hough3D correspondence grouping (Tombari & Di Stefano 2010, "Object recognition in 3D
//! scenes with occlusions and clutter by Hough voting").
//!
//! The model cloud's reference point is the centroid of its described keypoints. Each model
//! keypoint stores the vector to it in its own LRF; a correspondence carries that vector into
//! the scene through the scene keypoint's LRF and votes for where the reference point lies. Votes
//! of a correct alignment pile up in one bin whatever the rotation, which is why the grouping
//! needs no rotation search.
//!
//! Votes are spread trilinearly over the 8 nearest bin centres (as PCL's interpolated
//! accumulator). A bin that is a local maximum over its 26 neighbours, holds at least
//! `hough_min_votes` and at least `hough_relative_threshold` of the strongest bin becomes a
//! cluster: the correspondences whose vote lies within one bin edge (Chebyshev) of its centre.

use std::collections::HashMap;

use nalgebra::{Matrix3, Point3, Vector3};

use super::correspondences::Correspondence;
use super::params::MatcherParams;
use crate::cloud::VoxelBuildHasher;

/// One side's described keypoints: positions and LRFs (rows = axes).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Side<'a> {
    pub position: &'a [Point3<f32>],
    pub lrf: &'a [Matrix3<f32>],
}

/// Which way the votes go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Direction {
    /// Model = source, scene = target.
    SourceInTarget,
    /// Model = target, scene = source.
    TargetInSource,
}

/// Clusters of correspondence indices (into `corrs`), strongest first.
pub(crate) fn cluster(
    source: Side<'_>,
    target: Side<'_>,
    corrs: &[Correspondence],
    direction: Direction,
    params: &MatcherParams,
) -> Vec<Vec<usize>> {
    let (model, scene) = match direction {
        Direction::SourceInTarget => (source, target),
        Direction::TargetInSource => (target, source),
    };
    if model.position.is_empty() || corrs.is_empty() || !(params.hough_bin_m > 0.0) {
        return Vec::new();
    }
    let reference = model.position.iter().fold(Vector3::<f64>::zeros(), |acc, p| acc + p.coords.cast::<f64>())
        / model.position.len() as f64;
    let bin = params.hough_bin_m;

    let votes: Vec<Vector3<f64>> = corrs
        .iter()
        .map(|c| {
            let (m, s) = match direction {
                Direction::SourceInTarget => (c.source, c.target),
                Direction::TargetInSource => (c.target, c.source),
            };
            let to_reference_local = model.lrf[m].cast::<f64>() * (reference - model.position[m].coords.cast::<f64>());
            scene.position[s].coords.cast::<f64>() + scene.lrf[s].cast::<f64>().transpose() * to_reference_local
        })
        .collect();

    let mut accumulator: HashMap<[i32; 3], f64, VoxelBuildHasher> = HashMap::default();
    for v in &votes {
        // Bin centres at (i + 0.5)·bin: continuous coordinate relative to the centre grid.
        let g = v / bin - Vector3::repeat(0.5);
        let base = [g.x.floor(), g.y.floor(), g.z.floor()];
        if !base.iter().all(|b| b.is_finite() && b.abs() < 1e8) {
            continue;
        }
        let frac = [g.x - base[0], g.y - base[1], g.z - base[2]];
        for corner in 0..8 {
            let mut key = [0i32; 3];
            let mut w = 1.0;
            for a in 0..3 {
                let hi = (corner >> a) & 1 == 1;
                key[a] = base[a] as i32 + i32::from(hi);
                w *= if hi { frac[a] } else { 1.0 - frac[a] };
            }
            *accumulator.entry(key).or_insert(0.0) += w;
        }
    }
    let strongest = accumulator.values().copied().fold(0.0, f64::max);
    let threshold = params.hough_min_votes.max(params.hough_relative_threshold * strongest);
    let mut maxima: Vec<([i32; 3], f64)> = accumulator
        .iter()
        .filter(|&(key, &w)| {
            w >= threshold
                && (0..27).all(|n| {
                    let d = [n % 3 - 1, (n / 3) % 3 - 1, n / 9 - 1];
                    if d == [0, 0, 0] {
                        return true;
                    }
                    let other = [key[0] + d[0], key[1] + d[1], key[2] + d[2]];
                    let ow = accumulator.get(&other).copied().unwrap_or(0.0);
                    // Ties go to the lexicographically smaller key, so a plateau yields one maximum.
                    ow < w || (ow == w && *key < other)
                })
        })
        .map(|(k, &w)| (*k, w))
        .collect();
    maxima.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
    maxima.truncate(params.hough_max_clusters);

    maxima
        .iter()
        .map(|(key, _)| {
            let centre = Vector3::new(f64::from(key[0]) + 0.5, f64::from(key[1]) + 0.5, f64::from(key[2]) + 0.5) * bin;
            votes.iter().enumerate().filter(|(_, v)| (*v - centre).amax() <= bin).map(|(i, _)| i).collect()
        })
        .collect()
}
