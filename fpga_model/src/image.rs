//! Images in and out of the core.

use crate::SgmError;

/// An 8-bit grayscale image, row-major.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct GrayImage {
    pub width: usize,
    pub height: usize,
    pub pixels: Vec<u8>,
}

impl GrayImage {
    pub fn new(width: usize, height: usize, pixels: Vec<u8>) -> Result<Self, SgmError> {
        if width == 0 || height == 0 || pixels.len() != width * height {
            return Err(SgmError::BadImage { width, height, len: pixels.len() });
        }
        Ok(GrayImage { width, height, pixels })
    }

    /// The pixel at `(x, y)` with coordinates clamped into the image (edge replication).
    #[inline]
    pub fn clamped(&self, x: isize, y: isize) -> u8 {
        let x = x.clamp(0, self.width as isize - 1) as usize;
        let y = y.clamp(0, self.height as isize - 1) as usize;
        self.pixels[y * self.width + x]
    }

    /// The image as a borrowed view (what the matcher reads).
    pub fn view(&self) -> GrayView<'_> {
        GrayView { width: self.width, height: self.height, pixels: &self.pixels }
    }
}

/// A borrowed 8-bit grayscale image, row-major, no row padding: lets the matcher read pixels
/// where they already are (a shared-memory sample, one half of a stereo buffer) instead of
/// copying them into a [`GrayImage`] first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GrayView<'a> {
    pub width: usize,
    pub height: usize,
    pub pixels: &'a [u8],
}

impl<'a> GrayView<'a> {
    /// A view of `pixels` as a `width × height` image; refuses an empty image or a slice of
    /// another length.
    pub fn new(width: usize, height: usize, pixels: &'a [u8]) -> Result<Self, SgmError> {
        let view = GrayView { width, height, pixels };
        view.check()?;
        Ok(view)
    }

    /// The fields are public, so every consumer re-checks what `new` checks.
    pub(crate) fn check(&self) -> Result<(), SgmError> {
        if self.width == 0 || self.height == 0 || self.width.checked_mul(self.height) != Some(self.pixels.len()) {
            return Err(SgmError::BadImage { width: self.width, height: self.height, len: self.pixels.len() });
        }
        Ok(())
    }
}

impl<'a> From<&'a GrayImage> for GrayView<'a> {
    fn from(image: &'a GrayImage) -> Self {
        image.view()
    }
}

/// Fractional bits of an output disparity.
pub const DISPARITY_FRAC_BITS: u32 = 4;
/// Output value of a pixel without a valid disparity.
pub const INVALID: u16 = 0xFFFF;

/// The core's output: left-view disparity in 1/16 px, or [`INVALID`].
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DisparityImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u16>,
}

impl DisparityImage {
    /// Disparity of a pixel in pixels, `None` where invalid.
    pub fn get_px(&self, x: usize, y: usize) -> Option<f32> {
        match self.data[y * self.width + x] {
            INVALID => None,
            v => Some(f32::from(v) / (1 << DISPARITY_FRAC_BITS) as f32),
        }
    }

    /// Share of pixels without a valid disparity.
    pub fn invalid_fraction(&self) -> f64 {
        self.data.iter().filter(|&&v| v == INVALID).count() as f64 / self.data.len().max(1) as f64
    }
}

/// Checks that a stereo pair can be matched: same size, not empty.
pub fn check_pair(left: &GrayImage, right: &GrayImage) -> Result<(), SgmError> {
    if left.width != right.width || left.height != right.height {
        return Err(SgmError::SizeMismatch { left: (left.width, left.height), right: (right.width, right.height) });
    }
    Ok(())
}
