//! Obstacle classification on depth images (thesis §5.1.1). (In progress.)

/// Per-pixel classification result of one depth image, row-major like the depth image.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct PixelLabels {
    pub width: usize,
    pub height: usize,
    /// Bit flags per pixel, see [`PixelLabels::OBSTACLE`] and friends.
    pub flags: Vec<u8>,
}

impl PixelLabels {
    /// The pixel's 3D point is part of an untraversable obstacle (step or cliff).
    pub const OBSTACLE: u8 = 1;
    /// The pixel is the top of a negative edge (cliff) that exceeds the slope limit.
    pub const NEGATIVE_EDGE: u8 = 2;
    /// The pixel's point lies beyond the stereo-error range cutoff (not mapped).
    pub const TOO_FAR: u8 = 4;

    pub fn is_obstacle(&self, x: usize, y: usize) -> bool {
        self.flags.get(y * self.width + x).is_some_and(|f| f & Self::OBSTACLE != 0)
    }
}
