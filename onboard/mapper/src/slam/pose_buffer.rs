//! Poses by timestamp, the project's one stamped-pose buffer: the team graph's filter poses
//! (thesis §4.2.2: "each robot therefore buffers its filter estimates", so that a detection made
//! during an outage can be attached later, trap 8), the mapper node's filter states at the image
//! stamps, the vision node's capture poses.
//!
//! Lookups are exact by stamp, or between two buffered poses of the same frame no more than
//! `max_gap_ns` apart, interpolated (translation linearly, rotation by slerp) with the later
//! pose's covariance, which is the larger one within a frame. A pose is never taken across a
//! frame switch, because a pose is relative to the frame active at its stamp.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix6, Translation3};

use super::measurements::FilterPose;

/// A pose sample the buffer can hold.
pub trait StampedPose: Copy {
    fn stamp_ns(&self) -> u64;
    /// The frame (submap) the pose is relative to: never interpolated across.
    fn frame(&self) -> u32;
    /// The sample between `before` and `after` at `stamp_ns` (`fraction` of the way), with the
    /// pose from [`interpolate_pose`] and the later sample's covariance.
    fn between(before: &Self, after: &Self, stamp_ns: u64, fraction: f64) -> Self;
}

impl StampedPose for FilterPose {
    fn stamp_ns(&self) -> u64 {
        self.stamp_ns
    }

    fn frame(&self) -> u32 {
        self.submap_index
    }

    fn between(before: &Self, after: &Self, stamp_ns: u64, fraction: f64) -> Self {
        FilterPose {
            robot: before.robot,
            stamp_ns,
            submap_index: before.submap_index,
            t_submap_body: interpolate_pose(&before.t_submap_body, &after.t_submap_body, fraction),
            covariance: after.covariance,
        }
    }
}

/// A pose in some frame with its covariance (any convention: it is carried, not transformed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FramePose {
    pub stamp_ns: u64,
    pub frame_id: u32,
    pub pose: Isometry3<f64>,
    pub covariance: Matrix6<f64>,
}

impl StampedPose for FramePose {
    fn stamp_ns(&self) -> u64 {
        self.stamp_ns
    }

    fn frame(&self) -> u32 {
        self.frame_id
    }

    fn between(before: &Self, after: &Self, stamp_ns: u64, fraction: f64) -> Self {
        FramePose {
            stamp_ns,
            frame_id: before.frame_id,
            pose: interpolate_pose(&before.pose, &after.pose, fraction),
            covariance: after.covariance,
        }
    }
}

/// The pose `fraction` of the way from `a` to `b`: translation linearly, rotation by slerp.
pub fn interpolate_pose(a: &Isometry3<f64>, b: &Isometry3<f64>, fraction: f64) -> Isometry3<f64> {
    let translation = a.translation.vector.lerp(&b.translation.vector, fraction);
    let rotation = a.rotation.slerp(&b.rotation, fraction);
    Isometry3::from_parts(Translation3::from(translation), rotation)
}

/// What a second pose of an occupied stamp does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SameStamp {
    /// Ignored: the first pose was the robot's own estimate at that time (the team graph).
    #[default]
    KeepFirst,
    /// Replaces it: a later state of the same stamp (an update after the sample) is the newer
    /// estimate (the nodes' rings of filter states).
    KeepLatest,
}

/// Stamped poses, optionally bounded (the oldest goes first).
#[derive(Debug, Clone)]
pub struct PoseBuffer<P = FilterPose> {
    poses: BTreeMap<u64, P>,
    capacity: Option<usize>,
    same_stamp: SameStamp,
}

impl<P> Default for PoseBuffer<P> {
    fn default() -> Self {
        PoseBuffer { poses: BTreeMap::new(), capacity: None, same_stamp: SameStamp::KeepFirst }
    }
}

impl<P: StampedPose> PoseBuffer<P> {
    /// An unbounded buffer that keeps the first pose of a stamp.
    pub fn new() -> Self {
        Self::default()
    }

    /// An unbounded buffer with the `same_stamp` policy.
    pub fn unbounded(same_stamp: SameStamp) -> Self {
        PoseBuffer { poses: BTreeMap::new(), capacity: None, same_stamp }
    }

    /// A buffer of at most `capacity` poses (at least one).
    pub fn bounded(capacity: usize, same_stamp: SameStamp) -> Self {
        PoseBuffer { poses: BTreeMap::new(), capacity: Some(capacity.max(1)), same_stamp }
    }

    /// Stores a pose; returns whether it was stored (see [`SameStamp`]). When bounded, the
    /// oldest pose makes room.
    pub fn insert(&mut self, pose: P) -> bool {
        match self.poses.entry(pose.stamp_ns()) {
            std::collections::btree_map::Entry::Occupied(mut slot) => {
                if self.same_stamp == SameStamp::KeepFirst {
                    return false;
                }
                slot.insert(pose);
            }
            std::collections::btree_map::Entry::Vacant(slot) => {
                slot.insert(pose);
            }
        }
        if self.capacity.is_some_and(|c| self.poses.len() > c) {
            self.poses.pop_first();
        }
        true
    }

    pub fn len(&self) -> usize {
        self.poses.len()
    }

    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }

    pub fn clear(&mut self) {
        self.poses.clear();
    }

    /// The latest pose.
    pub fn latest(&self) -> Option<&P> {
        self.poses.values().next_back()
    }

    /// The pose of exactly `stamp_ns`.
    pub fn exact(&self, stamp_ns: u64) -> Option<&P> {
        self.poses.get(&stamp_ns)
    }

    /// The pose at `stamp_ns`: exact, or interpolated within one frame over at most `max_gap_ns`.
    pub fn lookup(&self, stamp_ns: u64, max_gap_ns: u64) -> Option<P> {
        if let Some(pose) = self.poses.get(&stamp_ns) {
            return Some(*pose);
        }
        let (_, before) = self.poses.range(..stamp_ns).next_back()?;
        let (_, after) = self.poses.range(stamp_ns..).next()?;
        let (t0, t1) = (before.stamp_ns(), after.stamp_ns());
        if before.frame() != after.frame() || t1 - t0 > max_gap_ns {
            return None;
        }
        Some(P::between(before, after, stamp_ns, (stamp_ns - t0) as f64 / (t1 - t0) as f64))
    }

    /// Poses in `[from_ns, to_ns]`.
    pub fn range(&self, from_ns: u64, to_ns: u64) -> impl Iterator<Item = &P> {
        self.poses.range(from_ns..=to_ns).map(|(_, p)| p)
    }
}

impl PoseBuffer<FilterPose> {
    /// Covariance of the buffered pose at exactly `stamp_ns`.
    pub fn covariance_at(&self, stamp_ns: u64) -> Option<Matrix6<f64>> {
        self.poses.get(&stamp_ns).map(|p| p.covariance)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use nalgebra::UnitQuaternion;

    fn sample(stamp_ns: u64, frame_id: u32, x: f64, yaw: f64) -> FramePose {
        FramePose {
            stamp_ns,
            frame_id,
            pose: Isometry3::from_parts(
                Translation3::new(x, 0.0, 0.0),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            ),
            covariance: Matrix6::identity() * x,
        }
    }

    #[test]
    fn lookups_interpolate_within_a_frame_and_a_gap_only() {
        let mut buffer = PoseBuffer::new();
        for s in [sample(0, 0, 0.0, 0.0), sample(10, 0, 1.0, 0.2), sample(20, 1, 5.0, 0.0)] {
            assert!(buffer.insert(s));
        }
        let mid = buffer.lookup(5, 10).unwrap();
        assert!((mid.pose.translation.x - 0.5).abs() < 1e-12);
        assert!((mid.pose.rotation.euler_angles().2 - 0.1).abs() < 1e-12);
        assert_eq!(mid.covariance, Matrix6::identity(), "the later sample's covariance");
        assert!(buffer.lookup(5, 9).is_none(), "gap too long");
        assert!(buffer.lookup(15, 100).is_none(), "across a frame switch");
        assert!(buffer.lookup(25, 100).is_none(), "after the newest");
        assert_eq!(buffer.exact(20).unwrap().frame_id, 1);
    }

    #[test]
    fn same_stamps_and_bounds_follow_the_policy() {
        let mut first = PoseBuffer::new();
        assert!(first.insert(sample(0, 0, 1.0, 0.0)));
        assert!(!first.insert(sample(0, 0, 2.0, 0.0)));
        assert_eq!(first.exact(0).unwrap().pose.translation.x, 1.0);
        let mut latest = PoseBuffer::bounded(2, SameStamp::KeepLatest);
        assert!(latest.insert(sample(0, 0, 1.0, 0.0)));
        assert!(latest.insert(sample(0, 0, 2.0, 0.0)));
        assert_eq!(latest.exact(0).unwrap().pose.translation.x, 2.0);
        latest.insert(sample(1, 0, 3.0, 0.0));
        latest.insert(sample(2, 0, 4.0, 0.0));
        assert_eq!(latest.len(), 2);
        assert!(latest.exact(0).is_none(), "the oldest made room");
        assert_eq!(latest.latest().unwrap().stamp_ns, 2);
    }
}
