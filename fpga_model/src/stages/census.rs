//! Stage 1 of `SPEC.md`: the census transform.

use crate::image::GrayImage;

/// Census words of every pixel, row-major, `u64` each.
///
/// Bits are appended MSB first in raster order over the `window_width × window_height` window
/// (rows top to bottom, columns left to right), skipping the centre: a bit is 1 where the
/// neighbour is darker than the centre. Coordinates outside the image are clamped (edge pixels
/// replicated), which is what a line buffer that repeats its first and last row/column gives.
/// The word has `window_width · window_height − 1` significant bits.
pub fn transform(image: &GrayImage, window_width: usize, window_height: usize) -> Vec<u64> {
    let half_w = (window_width / 2) as isize;
    let half_h = (window_height / 2) as isize;
    let mut words = Vec::with_capacity(image.width * image.height);
    for y in 0..image.height as isize {
        for x in 0..image.width as isize {
            let centre = image.clamped(x, y);
            let mut word: u64 = 0;
            for dy in -half_h..=half_h {
                for dx in -half_w..=half_w {
                    if (dx, dy) == (0, 0) {
                        continue;
                    }
                    let neighbour_is_darker = image.clamped(x + dx, y + dy) < centre;
                    word = (word << 1) | u64::from(neighbour_is_darker);
                }
            }
            words.push(word);
        }
    }
    words
}
