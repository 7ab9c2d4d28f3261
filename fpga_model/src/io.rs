//! Image files in and out of the model: PNG input (any PNG colour type, converted to the 8-bit
//! gray the core matches on), PFM disparity output in the Middlebury convention, and the raw
//! values of ground-truth and mask PNGs.
//!
//! Colour to gray uses the integer BT.601 luma `(77·R + 150·G + 29·B + 128) >> 8` (weights sum
//! to 256, so white stays 255 and gray stays gray); it is what a hardware pipeline in front of
//! the core would compute, and the OpenCV comparison script uses the same formula so both
//! matchers see identical pixels. 16-bit samples keep their high byte; alpha is ignored.

use std::fs;
use std::io::{BufReader, BufWriter, Write};
use std::path::{Path, PathBuf};

use crate::image::{DISPARITY_FRAC_BITS, DisparityImage, GrayImage, INVALID};

/// Errors of reading or writing an image file. Each names the file it concerns.
#[derive(Debug, thiserror::Error)]
pub enum IoError {
    #[error("{path}: {source}")]
    File { path: PathBuf, source: std::io::Error },
    #[error("{path}: PNG decoding failed: {source}")]
    PngDecode { path: PathBuf, source: png::DecodingError },
    #[error("{path}: PNG encoding failed: {source}")]
    PngEncode { path: PathBuf, source: png::EncodingError },
    #[error("{path}: {reason}")]
    Png { path: PathBuf, reason: String },
    #[error("PFM: {0}")]
    Pfm(String),
    #[error("{path}: {source}")]
    PfmFile { path: PathBuf, source: Box<IoError> },
    #[error("{width}x{height} image cannot hold {len} values")]
    Size { width: usize, height: usize, len: usize },
}

/// One channel of a PNG's samples, after palette expansion; row-major.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PngValues {
    pub width: usize,
    pub height: usize,
    /// Bits per sample of `values`: 8, or 16 for a 16-bit PNG (values then use the full `u16`).
    pub bit_depth: u8,
    pub values: Vec<u16>,
}

/// Decoded samples with the channel layout of the file, after palette and low-bit expansion.
struct Decoded {
    width: usize,
    height: usize,
    /// Samples per pixel: 1 gray, 2 gray+alpha, 3 RGB, 4 RGBA.
    channels: usize,
    /// Every sample widened to u16; `sixteen_bit` tells the range.
    samples: Vec<u16>,
    sixteen_bit: bool,
}

fn decode_png(path: &Path) -> Result<Decoded, IoError> {
    let file = fs::File::open(path).map_err(|source| IoError::File { path: path.to_owned(), source })?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    // EXPAND: palette -> RGB(A) through the palette (the 4-bit tsukuba GT and the 1-bit masks are
    // palette PNGs), gray below 8 bits -> 8 bits scaled to 0..=255 (as libpng and OpenCV do).
    // 16-bit samples stay 16-bit so that `read_png_values` can return them whole.
    decoder.set_transformations(png::Transformations::EXPAND);
    let decode_err = |source| IoError::PngDecode { path: path.to_owned(), source };
    let mut reader = decoder.read_info().map_err(decode_err)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| IoError::Png { path: path.to_owned(), reason: "image too large for this machine".to_owned() })?;
    let mut buffer = vec![0u8; size];
    let frame = reader.next_frame(&mut buffer).map_err(decode_err)?;
    buffer.truncate(frame.buffer_size());
    let channels = match frame.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => {
            return Err(IoError::Png { path: path.to_owned(), reason: "palette was not expanded".to_owned() });
        }
    };
    let (width, height) = (frame.width as usize, frame.height as usize);
    let sixteen_bit = match frame.bit_depth {
        png::BitDepth::Eight => false,
        png::BitDepth::Sixteen => true,
        other => {
            return Err(IoError::Png { path: path.to_owned(), reason: format!("unexpected bit depth {other:?}") });
        }
    };
    let samples: Vec<u16> = if sixteen_bit {
        buffer.chunks_exact(2).map(|b| u16::from_be_bytes([b[0], b[1]])).collect()
    } else {
        buffer.iter().map(|&b| u16::from(b)).collect()
    };
    if width == 0 || height == 0 || samples.len() != width * height * channels {
        return Err(IoError::Png {
            path: path.to_owned(),
            reason: format!("{width}x{height}x{channels} image decoded to {} samples", samples.len()),
        });
    }
    Ok(Decoded { width, height, channels, samples, sixteen_bit })
}

/// Integer BT.601 luma of an 8-bit RGB triple: `(77·R + 150·G + 29·B + 128) >> 8`.
#[inline]
pub fn luma_u8(r: u8, g: u8, b: u8) -> u8 {
    // Max (256·255 + 128) >> 8 = 255: never overflows u8.
    ((77 * u32::from(r) + 150 * u32::from(g) + 29 * u32::from(b) + 128) >> 8) as u8
}

/// Reads any PNG as the 8-bit gray image the core matches on (see the module doc for the
/// conversion: 16-bit → high byte, colour → integer luma, alpha ignored, palette expanded).
pub fn read_gray_png(path: impl AsRef<Path>) -> Result<GrayImage, IoError> {
    let path = path.as_ref();
    let decoded = decode_png(path)?;
    let to_u8 = |s: u16| if decoded.sixteen_bit { (s >> 8) as u8 } else { s as u8 };
    let pixels: Vec<u8> = decoded
        .samples
        .chunks_exact(decoded.channels)
        .map(|px| match decoded.channels {
            1 | 2 => to_u8(px[0]),
            _ => luma_u8(to_u8(px[0]), to_u8(px[1]), to_u8(px[2])),
        })
        .collect();
    GrayImage::new(decoded.width, decoded.height, pixels)
        .map_err(|e| IoError::Png { path: path.to_owned(), reason: e.to_string() })
}

/// Reads the sample values of a single-valued PNG (ground truth, evaluation mask): gray samples
/// as stored (8- or 16-bit; below 8 bits scaled to 0..=255), palette entries expanded to their
/// colour. A colour pixel must be gray (R = G = B), otherwise the file is not a value map and
/// this is an error rather than a silent luma. Alpha is ignored.
pub fn read_png_values(path: impl AsRef<Path>) -> Result<PngValues, IoError> {
    let path = path.as_ref();
    let decoded = decode_png(path)?;
    let mut values = Vec::with_capacity(decoded.width * decoded.height);
    for (i, px) in decoded.samples.chunks_exact(decoded.channels).enumerate() {
        if decoded.channels >= 3 && (px[0] != px[1] || px[1] != px[2]) {
            return Err(IoError::Png {
                path: path.to_owned(),
                reason: format!(
                    "pixel ({}, {}) is coloured {:?}: not a gray value map",
                    i % decoded.width,
                    i / decoded.width,
                    &px[..3]
                ),
            });
        }
        values.push(px[0]);
    }
    Ok(PngValues {
        width: decoded.width,
        height: decoded.height,
        bit_depth: if decoded.sixteen_bit { 16 } else { 8 },
        values,
    })
}

/// Writes an 8-bit grayscale PNG.
pub fn write_gray_png(path: impl AsRef<Path>, image: &GrayImage) -> Result<(), IoError> {
    let path = path.as_ref();
    if image.pixels.len() != image.width * image.height {
        return Err(IoError::Size { width: image.width, height: image.height, len: image.pixels.len() });
    }
    let (width, height) = match (u32::try_from(image.width), u32::try_from(image.height)) {
        (Ok(w), Ok(h)) => (w, h),
        _ => return Err(IoError::Size { width: image.width, height: image.height, len: image.pixels.len() }),
    };
    let file = fs::File::create(path).map_err(|source| IoError::File { path: path.to_owned(), source })?;
    let mut encoder = png::Encoder::new(BufWriter::new(file), width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    let encode_err = |source| IoError::PngEncode { path: path.to_owned(), source };
    let mut writer = encoder.write_header().map_err(encode_err)?;
    writer.write_image_data(&image.pixels).map_err(encode_err)?;
    writer.finish().map_err(encode_err)
}

/// A single-channel float image as stored in a PFM, rows top to bottom (already flipped).
#[derive(Debug, Clone, PartialEq)]
pub struct PfmImage {
    pub width: usize,
    pub height: usize,
    pub values: Vec<f32>,
}

/// Left-view disparities in pixels for a PFM: `value / 16`, [`INVALID`] → `+inf` (Middlebury's
/// marker for "no disparity").
pub fn disparity_to_pfm_values(disparity: &DisparityImage) -> Vec<f32> {
    let scale = (1u32 << DISPARITY_FRAC_BITS) as f32;
    disparity.data.iter().map(|&v| if v == INVALID { f32::INFINITY } else { f32::from(v) / scale }).collect()
}

/// Encodes a grayscale PFM as Middlebury writes it: `Pf`, `W H`, scale `-1` (negative = little
/// endian), then the rows bottom to top as `f32`. `values` are row-major, top row first.
pub fn encode_pfm(width: usize, height: usize, values: &[f32]) -> Result<Vec<u8>, IoError> {
    if width == 0 || height == 0 || width.checked_mul(height) != Some(values.len()) {
        return Err(IoError::Size { width, height, len: values.len() });
    }
    let header = format!("Pf\n{width} {height}\n-1\n");
    let mut bytes = Vec::with_capacity(header.len() + values.len() * 4);
    bytes.extend_from_slice(header.as_bytes());
    for row in values.chunks_exact(width).rev() {
        for v in row {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    Ok(bytes)
}

/// Writes a grayscale PFM (see [`encode_pfm`]).
pub fn write_pfm(path: impl AsRef<Path>, width: usize, height: usize, values: &[f32]) -> Result<(), IoError> {
    let path = path.as_ref();
    let bytes = encode_pfm(width, height, values)?;
    let file_err = |source| IoError::File { path: path.to_owned(), source };
    let mut file = BufWriter::new(fs::File::create(path).map_err(file_err)?);
    file.write_all(&bytes).map_err(file_err)?;
    file.flush().map_err(file_err)
}

/// Reads a grayscale PFM (either endianness). See [`parse_pfm`].
pub fn read_pfm(path: impl AsRef<Path>) -> Result<PfmImage, IoError> {
    let path = path.as_ref();
    let bytes = fs::read(path).map_err(|source| IoError::File { path: path.to_owned(), source })?;
    parse_pfm(&bytes).map_err(|e| IoError::PfmFile { path: path.to_owned(), source: Box::new(e) })
}

/// Parses a grayscale PFM. Total: any byte string gives an image or an error, never a panic,
/// and the body length is checked against the header before anything is allocated, so a
/// header claiming a huge image cannot exhaust memory.
///
/// Accepted: `Pf`, whitespace, width, whitespace, height, whitespace, a finite non-zero scale,
/// exactly one whitespace byte, then exactly `width · height` `f32` (little endian if the scale
/// is negative), rows bottom to top. Colour `PF` files are rejected.
pub fn parse_pfm(bytes: &[u8]) -> Result<PfmImage, IoError> {
    let err = |reason: &str| IoError::Pfm(reason.to_owned());
    let mut pos = 0usize;
    let magic = next_token(bytes, &mut pos).ok_or_else(|| err("empty file"))?;
    match magic {
        b"Pf" => {}
        b"PF" => return Err(err("colour PF files are not supported (disparity maps are Pf)")),
        _ => return Err(err("not a PFM file (magic is not Pf)")),
    }
    let width = parse_dim(next_token(bytes, &mut pos)).ok_or_else(|| err("bad width"))?;
    let height = parse_dim(next_token(bytes, &mut pos)).ok_or_else(|| err("bad height"))?;
    let scale: f32 = next_token(bytes, &mut pos)
        .and_then(|t| std::str::from_utf8(t).ok())
        .and_then(|t| t.parse().ok())
        .filter(|s: &f32| s.is_finite() && *s != 0.0)
        .ok_or_else(|| err("bad scale (must be a finite non-zero number)"))?;
    // Exactly one whitespace byte separates the header from the binary body.
    match bytes.get(pos) {
        Some(b) if b.is_ascii_whitespace() => pos += 1,
        _ => return Err(err("missing whitespace after the scale")),
    }
    let body = &bytes[pos..];
    let count = width.checked_mul(height).ok_or_else(|| err("width x height overflows"))?;
    if count.checked_mul(4) != Some(body.len()) {
        return Err(IoError::Pfm(format!("{width}x{height} needs {count} floats, body has {} bytes", body.len())));
    }
    let little_endian = scale < 0.0;
    let mut values = vec![0f32; count];
    for (row_from_bottom, chunk) in body.chunks_exact(width * 4).enumerate() {
        let y = height - 1 - row_from_bottom;
        for (x, b) in chunk.chunks_exact(4).enumerate() {
            let raw = [b[0], b[1], b[2], b[3]];
            values[y * width + x] = if little_endian { f32::from_le_bytes(raw) } else { f32::from_be_bytes(raw) };
        }
    }
    Ok(PfmImage { width, height, values })
}

/// The next whitespace-separated ASCII token from `pos`, advancing `pos` to just after it.
fn next_token<'a>(bytes: &'a [u8], pos: &mut usize) -> Option<&'a [u8]> {
    while bytes.get(*pos).is_some_and(|b| b.is_ascii_whitespace()) {
        *pos += 1;
    }
    let start = *pos;
    while bytes.get(*pos).is_some_and(|b| !b.is_ascii_whitespace()) {
        *pos += 1;
    }
    (*pos > start).then(|| &bytes[start..*pos])
}

fn parse_dim(token: Option<&[u8]>) -> Option<usize> {
    let token = std::str::from_utf8(token?).ok()?;
    // Only plain decimal digits: `usize::from_str` would also accept a leading '+'.
    if !token.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    token.parse().ok().filter(|&n: &usize| n > 0)
}
