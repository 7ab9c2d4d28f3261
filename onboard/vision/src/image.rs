//! Borrowed greyscale images.

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
