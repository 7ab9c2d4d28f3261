//! The keyframe history (thesis §4.1.1: the last five keyframes) and the pool of feature tracks
//! the keyframes share.
//!
//! A [`Track`] is one image point followed frame to frame by KLT. It links to at most one
//! landmark in each keyframe slot: a point seen when two keyframes were taken carries a landmark
//! in both, triangulated separately from each keyframe's stereo pair. One KLT track per image
//! point therefore serves every keyframe in the history, so tracking cost does not grow with the
//! history length.

use nalgebra::{Isometry3, Matrix3, Vector3};

/// Keyframes kept in the history (thesis §4.1.1: n = 5).
pub const MAX_KEYFRAMES: usize = 5;
/// A track's entry for a keyframe slot where it has no landmark.
pub const NO_LANDMARK: u32 = u32::MAX;
/// Coverage grid: the image is split into `COVERAGE_GRID × COVERAGE_GRID` cells.
pub const COVERAGE_GRID: usize = 4;

/// A stereo-triangulated point of a keyframe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Landmark {
    /// In the keyframe's left camera frame, metres.
    pub point_m: Vector3<f64>,
    pub covariance_m2: Matrix3<f64>,
    /// Where the keyframe's left image saw it.
    pub pixel_keyframe: [f32; 2],
}

/// One keyframe of the history.
#[derive(Debug, Clone)]
pub struct Keyframe {
    /// Increases with every keyframe the odometry creates (never reused).
    pub id: u64,
    pub stamp_ns: u64,
    /// Body pose at the keyframe in the odometry frame.
    pub t_odom_body: Isometry3<f64>,
    /// Left camera in the body frame at the keyframe's head angles.
    pub t_body_cam: Isometry3<f64>,
    pub landmarks: Vec<Landmark>,
    /// Frame counter when this keyframe was last measured against (eviction picks the least
    /// recently used keyframe, so an old keyframe the rover came back to survives).
    pub last_used_frame: u64,
}

impl Keyframe {
    fn empty() -> Self {
        Keyframe {
            id: 0,
            stamp_ns: 0,
            t_odom_body: Isometry3::identity(),
            t_body_cam: Isometry3::identity(),
            landmarks: Vec::new(),
            last_used_frame: 0,
        }
    }

    /// Left camera pose at the keyframe in the odometry frame.
    pub fn t_odom_cam(&self) -> Isometry3<f64> {
        self.t_odom_body * self.t_body_cam
    }
}

/// An image point tracked frame to frame, with its landmark in each keyframe slot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Track {
    /// Position in the last processed left image, pixels.
    pub pixel: [f32; 2],
    /// Index into `Keyframe::landmarks` of each slot, [`NO_LANDMARK`] where none.
    pub landmark: [u32; MAX_KEYFRAMES],
}

impl Track {
    pub fn new(pixel: [f32; 2]) -> Self {
        Track { pixel, landmark: [NO_LANDMARK; MAX_KEYFRAMES] }
    }

    pub fn has_any_landmark(&self) -> bool {
        self.landmark.iter().any(|&l| l != NO_LANDMARK)
    }
}

/// The keyframe slots and the shared track pool. Buffers keep their capacity across keyframes.
#[derive(Debug)]
pub struct KeyframeHistory {
    slots: [Keyframe; MAX_KEYFRAMES],
    live: [bool; MAX_KEYFRAMES],
    next_id: u64,
    pub tracks: Vec<Track>,
}

impl Default for KeyframeHistory {
    fn default() -> Self {
        Self::new()
    }
}

impl KeyframeHistory {
    pub fn new() -> Self {
        KeyframeHistory {
            slots: std::array::from_fn(|_| Keyframe::empty()),
            live: [false; MAX_KEYFRAMES],
            next_id: 0,
            tracks: Vec::new(),
        }
    }

    /// Forgets every keyframe and track (after a tracking loss).
    pub fn clear(&mut self) {
        self.live = [false; MAX_KEYFRAMES];
        self.tracks.clear();
        for slot in &mut self.slots {
            slot.landmarks.clear();
        }
    }

    pub fn is_live(&self, slot: usize) -> bool {
        self.live.get(slot).copied().unwrap_or(false)
    }

    pub fn live_count(&self) -> usize {
        self.live.iter().filter(|&&l| l).count()
    }

    pub fn keyframe(&self, slot: usize) -> &Keyframe {
        &self.slots[slot]
    }

    pub fn keyframe_mut(&mut self, slot: usize) -> &mut Keyframe {
        &mut self.slots[slot]
    }

    /// Starts a keyframe in a free slot, or in the least recently used one (whose landmark links
    /// are dropped first; tracks left without any landmark are removed). `protect` is never
    /// evicted (the keyframe the current frame's delta refers to). Returns the slot.
    pub fn begin_keyframe(
        &mut self,
        stamp_ns: u64,
        t_odom_body: Isometry3<f64>,
        t_body_cam: Isometry3<f64>,
        frame_counter: u64,
        protect: Option<usize>,
    ) -> usize {
        let slot = match self.live.iter().position(|&l| !l) {
            Some(free) => free,
            None => (0..MAX_KEYFRAMES)
                .filter(|&s| Some(s) != protect)
                .min_by_key(|&s| (self.slots[s].last_used_frame, self.slots[s].id))
                .unwrap_or(0),
        };
        self.retire(slot);
        let keyframe = &mut self.slots[slot];
        keyframe.id = self.next_id;
        keyframe.stamp_ns = stamp_ns;
        keyframe.t_odom_body = t_odom_body;
        keyframe.t_body_cam = t_body_cam;
        keyframe.landmarks.clear();
        keyframe.last_used_frame = frame_counter;
        self.live[slot] = true;
        self.next_id += 1;
        slot
    }

    /// Drops a slot's keyframe and its landmark links.
    fn retire(&mut self, slot: usize) {
        self.live[slot] = false;
        self.slots[slot].landmarks.clear();
        for track in &mut self.tracks {
            track.landmark[slot] = NO_LANDMARK;
        }
        self.tracks.retain(Track::has_any_landmark);
    }

    /// Tracks with a landmark in `slot`.
    pub fn support(&self, slot: usize) -> usize {
        self.tracks.iter().filter(|t| t.landmark[slot] != NO_LANDMARK).count()
    }

    /// Coverage (occupied cells of the coverage grid) of the tracks with a landmark in `slot`.
    pub fn support_coverage(&self, slot: usize, width: usize, height: usize) -> u32 {
        coverage_cells(self.tracks.iter().filter(|t| t.landmark[slot] != NO_LANDMARK).map(|t| t.pixel), width, height)
    }
}

/// Number of occupied cells of a [`COVERAGE_GRID`]² grid over the image: how well a point set is
/// spread (pose estimates from points bunched in one corner are poorly conditioned).
pub fn coverage_cells(pixels: impl Iterator<Item = [f32; 2]>, width: usize, height: usize) -> u32 {
    let mut occupied = 0u32;
    let (w, h) = (width.max(1) as f32, height.max(1) as f32);
    for [x, y] in pixels {
        if !(x.is_finite() && y.is_finite()) {
            continue;
        }
        let cx = ((x / w * COVERAGE_GRID as f32).max(0.0) as usize).min(COVERAGE_GRID - 1);
        let cy = ((y / h * COVERAGE_GRID as f32).max(0.0) as usize).min(COVERAGE_GRID - 1);
        occupied |= 1 << (cy * COVERAGE_GRID + cx);
    }
    occupied.count_ones()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coverage_counts_distinct_cells() {
        assert_eq!(coverage_cells([[1.0, 1.0], [2.0, 2.0]].into_iter(), 100, 100), 1);
        assert_eq!(coverage_cells([[1.0, 1.0], [99.0, 99.0], [99.0, 1.0]].into_iter(), 100, 100), 3);
        // Outside the image clamps to the border cells; NaN is ignored.
        assert_eq!(coverage_cells([[-5.0, 500.0], [f32::NAN, 1.0]].into_iter(), 100, 100), 1);
    }

    #[test]
    fn eviction_takes_least_recently_used_and_prunes_orphans() {
        let mut history = KeyframeHistory::new();
        let mut slots = Vec::new();
        for i in 0..MAX_KEYFRAMES as u64 {
            slots.push(history.begin_keyframe(i, Isometry3::identity(), Isometry3::identity(), i, None));
        }
        assert_eq!(history.live_count(), MAX_KEYFRAMES);
        // A track only in slot of keyframe 1, one in keyframes 1 and 2.
        let mut only_one = Track::new([1.0, 1.0]);
        only_one.landmark[slots[1]] = 0;
        let mut both = Track::new([2.0, 2.0]);
        both.landmark[slots[1]] = 1;
        both.landmark[slots[2]] = 0;
        history.tracks.extend([only_one, both]);
        // Keyframe 0 was used recently, so keyframe 1 is the least recently used.
        history.keyframe_mut(slots[0]).last_used_frame = 10;
        let new = history.begin_keyframe(9, Isometry3::identity(), Isometry3::identity(), 11, None);
        assert_eq!(new, slots[1]);
        assert_eq!(history.tracks.len(), 1);
        assert_eq!(history.support(slots[2]), 1);
        assert_eq!(history.keyframe(new).id, MAX_KEYFRAMES as u64);
        // A protected slot is not evicted even when it is the least recently used.
        let lru = (0..MAX_KEYFRAMES).min_by_key(|&s| history.keyframe(s).last_used_frame).unwrap();
        let next = history.begin_keyframe(10, Isometry3::identity(), Isometry3::identity(), 12, Some(lru));
        assert_ne!(next, lru);
    }
}
