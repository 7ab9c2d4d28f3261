//! PNG and JPEG files as greyscale images, for the command-line tools, tests and benchmarks
//! (feature `cli`; the on-board code gets its images from the bus, never from files).
//!
//! Colour becomes grey with the ITU-R BT.601 luma weights in 16-bit fixed point,
//! `(19595·R + 38470·G + 7471·B + 32768) >> 16` (0.299, 0.587, 0.114, rounded): Pillow's "L"
//! conversion, so that the Python reference scripts see the same pixels. Alpha is ignored, a
//! palette is expanded, 16-bit samples keep their high byte. JPEGs are decoded by `zune-jpeg`,
//! whose IDCT and chroma upsampling can differ from libjpeg's by a grey level on some pixels.

use std::path::Path;

/// An owned 8-bit greyscale image, row-major, no padding.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct GreyImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<u8>,
}

impl GreyImage {
    pub fn view(&self) -> crate::image::ImageView<'_> {
        crate::image::ImageView { width: self.width, height: self.height, data: &self.data }
    }
}

/// Why a file could not be read as an image.
#[derive(Debug, thiserror::Error)]
pub enum ImageFileError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not a PNG or JPEG file")]
    UnknownFormat { path: String },
    #[error("{path}: {message}")]
    Decode { path: String, message: String },
}

/// BT.601 luma of an 8-bit RGB pixel, rounded (Pillow's "L").
#[inline]
pub fn luma(r: u8, g: u8, b: u8) -> u8 {
    ((19595 * u32::from(r) + 38470 * u32::from(g) + 7471 * u32::from(b) + 32768) >> 16) as u8
}

/// Reads a PNG or JPEG file (by its signature) as greyscale.
pub fn read_grey(path: impl AsRef<Path>) -> Result<GreyImage, ImageFileError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|source| ImageFileError::Io { path: name.clone(), source })?;
    let decode = |message: String| ImageFileError::Decode { path: name.clone(), message };
    if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        decode_png(&bytes).map_err(decode)
    } else if bytes.starts_with(&[0xFF, 0xD8]) {
        decode_jpeg(&bytes).map_err(decode)
    } else {
        Err(ImageFileError::UnknownFormat { path: name })
    }
}

/// Writes `image` as an 8-bit greyscale PNG.
pub fn write_grey_png(path: impl AsRef<Path>, image: &GreyImage) -> Result<(), ImageFileError> {
    let path = path.as_ref();
    let name = path.display().to_string();
    let file = std::fs::File::create(path).map_err(|source| ImageFileError::Io { path: name.clone(), source })?;
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), image.width as u32, image.height as u32);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    let failed = |e: png::EncodingError| ImageFileError::Decode { path: name.clone(), message: e.to_string() };
    let mut writer = encoder.write_header().map_err(failed)?;
    writer.write_image_data(&image.data).map_err(failed)?;
    writer.finish().map_err(failed)
}

fn decode_png(bytes: &[u8]) -> Result<GreyImage, String> {
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| e.to_string())?;
    let size = reader.output_buffer_size().ok_or("image too large")?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(|e| e.to_string())?;
    let (width, height) = (info.width as usize, info.height as usize);
    let channels = info.color_type.samples();
    if info.bit_depth != png::BitDepth::Eight {
        return Err(format!("unexpected bit depth {:?} after expansion", info.bit_depth));
    }
    let pixels = &buf[..info.buffer_size()];
    let data: Vec<u8> = match info.color_type {
        png::ColorType::Grayscale | png::ColorType::GrayscaleAlpha => {
            pixels.chunks_exact(info.line_size).flat_map(|row| row.chunks_exact(channels).map(|p| p[0])).collect()
        }
        png::ColorType::Rgb | png::ColorType::Rgba => pixels
            .chunks_exact(info.line_size)
            .flat_map(|row| row.chunks_exact(channels).map(|p| luma(p[0], p[1], p[2])))
            .collect(),
        png::ColorType::Indexed => return Err("palette was not expanded".to_owned()),
    };
    if data.len() != width * height {
        return Err(format!("{} pixels for {width}x{height}", data.len()));
    }
    Ok(GreyImage { width, height, data })
}

fn decode_jpeg(bytes: &[u8]) -> Result<GreyImage, String> {
    use zune_jpeg::zune_core::colorspace::ColorSpace;
    use zune_jpeg::zune_core::options::DecoderOptions;
    let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(std::io::Cursor::new(bytes), options);
    let rgb = decoder.decode().map_err(|e| e.to_string())?;
    let info = decoder.info().ok_or("no image header")?;
    let (width, height) = (usize::from(info.width), usize::from(info.height));
    let channels = decoder.output_colorspace().map_or(3, |c| c.num_components());
    if rgb.len() != width * height * channels || channels < 3 {
        return Err(format!("{} samples for {width}x{height}x{channels}", rgb.len()));
    }
    let data = rgb.chunks_exact(channels).map(|p| luma(p[0], p[1], p[2])).collect();
    Ok(GreyImage { width, height, data })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn luma_matches_pillow_l() {
        // Values from Pillow 13 `Image.new("RGB", (1, 1), c).convert("L")`.
        assert_eq!(luma(255, 255, 255), 255);
        assert_eq!(luma(0, 0, 0), 0);
        assert_eq!(luma(255, 0, 0), 76);
        assert_eq!(luma(0, 255, 0), 150);
        assert_eq!(luma(0, 0, 255), 29);
        assert_eq!(luma(10, 200, 30), 124);
    }
}
