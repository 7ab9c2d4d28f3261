//! Borrowed greyscale images and stereo pairs.

use hal::sensor::StereoFrame;

/// A borrowed 8-bit greyscale image, row-major, `width × height`, no padding.
#[derive(Debug, Clone, Copy)]
pub struct ImageView<'a> {
    pub width: usize,
    pub height: usize,
    pub data: &'a [u8],
}

impl<'a> ImageView<'a> {
    /// `None` when `data` is not exactly `width × height` bytes.
    pub fn new(width: usize, height: usize, data: &'a [u8]) -> Option<Self> {
        (width > 0 && height > 0 && data.len() == width * height).then_some(ImageView { width, height, data })
    }

    #[inline]
    pub fn get(&self, x: usize, y: usize) -> u8 {
        self.data[y * self.width + x]
    }
}

/// A borrowed stereo pair with its capture metadata: the fields of a `hal::sensor::StereoFrame`,
/// with the images left where they are (a shared-memory sample, a frame owned by someone else),
/// so that rectification and odometry read them without a copy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoView<'a> {
    pub stamp_ns: u64,
    /// Frame counter of the camera (gaps mean dropped frames).
    pub sequence: u64,
    pub width_px: u32,
    pub height_px: u32,
    /// Row-major, `width_px × height_px` bytes each (checked by whoever reads them).
    pub left: &'a [u8],
    pub right: &'a [u8],
    /// Pan and tilt of the camera head at capture time (0 without a head).
    pub pan_rad: f64,
    pub tilt_rad: f64,
}

impl<'a> StereoView<'a> {
    /// A view of an owned frame.
    pub fn of(frame: &'a StereoFrame) -> Self {
        StereoView {
            stamp_ns: frame.stamp_ns,
            sequence: frame.sequence,
            width_px: frame.width_px,
            height_px: frame.height_px,
            left: &frame.left,
            right: &frame.right,
            pan_rad: frame.pan_rad,
            tilt_rad: frame.tilt_rad,
        }
    }
}

impl<'a> From<&'a StereoFrame> for StereoView<'a> {
    fn from(frame: &'a StereoFrame) -> Self {
        StereoView::of(frame)
    }
}
