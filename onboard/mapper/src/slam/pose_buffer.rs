//! Filter poses by timestamp (thesis §4.2.2: "each robot therefore buffers its filter estimates"),
//! so that a detection made during an outage can be attached later (trap 8).
//!
//! Lookups are exact by stamp (detections carry image stamps, and the filter's poses are logged
//! at image stamps). Between two buffered poses of the same submap no more than `max_gap_ns`
//! apart, the pose is interpolated (translation linearly, rotation by slerp) with the later
//! pose's covariance, which is the larger one within a submap. A pose is never taken across a
//! frame switch, because `v` is relative to the submap active at the stamp.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix6, Translation3};

use super::measurements::FilterPose;

/// One robot's buffered filter poses.
#[derive(Debug, Clone, Default)]
pub struct PoseBuffer {
    poses: BTreeMap<u64, FilterPose>,
}

impl PoseBuffer {
    pub fn new() -> Self {
        Self::default()
    }

    /// Stores a pose; a second pose with the same stamp is ignored (the first one was the
    /// robot's own estimate at that time).
    pub fn insert(&mut self, pose: FilterPose) -> bool {
        match self.poses.entry(pose.stamp_ns) {
            std::collections::btree_map::Entry::Occupied(_) => false,
            std::collections::btree_map::Entry::Vacant(slot) => {
                slot.insert(pose);
                true
            }
        }
    }

    pub fn len(&self) -> usize {
        self.poses.len()
    }

    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    /// The latest pose.
    pub fn latest(&self) -> Option<&FilterPose> {
        self.poses.values().next_back()
    }

    /// The pose at `stamp_ns`: exact, or interpolated within one submap over at most `max_gap_ns`.
    pub fn lookup(&self, stamp_ns: u64, max_gap_ns: u64) -> Option<FilterPose> {
        if let Some(pose) = self.poses.get(&stamp_ns) {
            return Some(*pose);
        }
        let (_, before) = self.poses.range(..stamp_ns).next_back()?;
        let (_, after) = self.poses.range(stamp_ns..).next()?;
        if before.submap_index != after.submap_index || after.stamp_ns - before.stamp_ns > max_gap_ns {
            return None;
        }
        let a = (stamp_ns - before.stamp_ns) as f64 / (after.stamp_ns - before.stamp_ns) as f64;
        Some(FilterPose {
            robot: before.robot,
            stamp_ns,
            submap_index: before.submap_index,
            t_submap_body: interpolate(&before.t_submap_body, &after.t_submap_body, a),
            covariance: after.covariance,
        })
    }

    /// Poses in `[from_ns, to_ns]`.
    pub fn range(&self, from_ns: u64, to_ns: u64) -> impl Iterator<Item = &FilterPose> {
        self.poses.range(from_ns..=to_ns).map(|(_, p)| p)
    }

    /// Covariance of the buffered pose at exactly `stamp_ns`.
    pub fn covariance_at(&self, stamp_ns: u64) -> Option<Matrix6<f64>> {
        self.poses.get(&stamp_ns).map(|p| p.covariance)
    }
}

fn interpolate(a: &Isometry3<f64>, b: &Isometry3<f64>, t: f64) -> Isometry3<f64> {
    let translation = a.translation.vector.lerp(&b.translation.vector, t);
    let rotation = a.rotation.slerp(&b.rotation, t);
    Isometry3::from_parts(Translation3::from(translation), rotation)
}
