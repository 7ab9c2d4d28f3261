//! Replay of a KITTI odometry sequence as a [`SensorSource`] (stereo events only).
//!
//! Layout read:
//!
//! - `image_l/` + `image_r/` or `image_0/` + `image_1/`: rectified PNGs (8-bit grey; RGB or
//!   grey-alpha are converted to grey, 16-bit keeps its high byte), paired by file name, replayed
//!   in file-name order. Every image must have the size of the first left image.
//! - `calib.txt`: the 3×4 projection matrices of the two cameras, either as labelled lines
//!   `P0: …` / `P1: …` (other labels such as `P2:` or `Tr:` are ignored) or as the first two
//!   unlabelled lines of 12 numbers. The baseline is `(P0[0,3] − P1[0,3]) / P1[0,0]`, which is
//!   `−P1[0,3] / P1[0,0]` for KITTI's grey pair (P0 has no offset).
//! - `times.txt` (optional): one stamp in seconds per frame; without it frame `i` is at
//!   `i × 0.1 s` (KITTI's nominal 10 Hz).
//!
//! Frames: the images are rectified, so the calibration is the canonical pair. The body frame is
//! the left camera's centre with forward-left-up axes: `t_body_cam` is the pure rotation
//! [`r_flu_optical`], so body x is the driving direction.
//!
//! Every parser is total: malformed text gives a [`SensorError::Format`] naming file and line.

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Translation3, UnitQuaternion};

use crate::sensor::{
    CameraCalibration, Distortion, Pinhole, SensorError, SensorEvent, SensorSource, StereoCalibration, StereoFrame,
    StereoInfo, check_stereo_buffers, no_pending_pair, r_flu_optical,
};

/// Frame spacing without `times.txt`.
pub const DEFAULT_FRAME_PERIOD_NS: u64 = 100_000_000;
/// How far the fixed entries of a projection matrix may be from their ideal values.
const PROJECTION_TOLERANCE: f64 = 1e-6;
/// Longest excerpt of bad text quoted in an error.
const MAX_QUOTED_CHARS: usize = 40;

/// The two projection matrices of `calib.txt` (row-major 3×4).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct KittiProjections {
    pub p0: [f64; 12],
    pub p1: [f64; 12],
}

impl KittiProjections {
    /// The rectified pinhole shared by both cameras and the baseline (m).
    pub fn pinhole_and_baseline(&self) -> Result<(Pinhole, f64), String> {
        let (p0, p1) = (&self.p0, &self.p1);
        let pinhole = |p: &[f64; 12]| Pinhole { fx_px: p[0], fy_px: p[5], cx_px: p[2], cy_px: p[6] };
        let (left, right) = (pinhole(p0), pinhole(p1));
        for (name, p) in [("P0", p0), ("P1", p1)] {
            if p.iter().any(|v| !v.is_finite()) {
                return Err(format!("{name} has a non-finite entry"));
            }
            if !(p[0] > 0.0 && p[5] > 0.0) {
                return Err(format!("{name}: focal lengths must be positive"));
            }
            // A rectified projection: no skew, no y or z offset, last row [0 0 1 0].
            let fixed = [p[1], p[4], p[7], p[8], p[9], p[10] - 1.0, p[11]];
            if fixed.iter().any(|v| v.abs() > PROJECTION_TOLERANCE * p[0].max(1.0)) {
                return Err(format!("{name} is not the projection matrix of a rectified camera"));
            }
        }
        let same = |a: f64, b: f64| (a - b).abs() <= PROJECTION_TOLERANCE * a.abs().max(1.0);
        if !(same(left.fx_px, right.fx_px)
            && same(left.fy_px, right.fy_px)
            && same(left.cx_px, right.cx_px)
            && same(left.cy_px, right.cy_px))
        {
            return Err("P0 and P1 have different intrinsics: not a rectified pair".to_owned());
        }
        let baseline_m = (p0[3] - p1[3]) / p1[0];
        if !(baseline_m.is_finite() && baseline_m > 0.0) {
            return Err(format!("baseline (P0[0,3] − P1[0,3]) / P1[0,0] = {baseline_m} m is not positive"));
        }
        Ok((left, baseline_m))
    }
}

fn excerpt(text: &str) -> String {
    text.chars().take(MAX_QUOTED_CHARS).collect()
}

fn format_error(path: &Path, line: usize, reason: impl Into<String>) -> SensorError {
    let context = if line == 0 { path.display().to_string() } else { format!("{}:{line}", path.display()) };
    SensorError::Format { context, reason: reason.into() }
}

/// Twelve numbers, or why not.
fn twelve_numbers(text: &str) -> Result<[f64; 12], String> {
    let mut out = [0.0; 12];
    let mut count = 0;
    for token in text.split_whitespace() {
        let value: f64 = token.parse().map_err(|_| format!("`{}` is not a number", excerpt(token)))?;
        if count < 12 {
            out[count] = value;
        }
        count += 1;
    }
    if count != 12 { Err(format!("expected 12 numbers, found {count}")) } else { Ok(out) }
}

/// Reads `calib.txt` (`path` only names it in errors).
pub fn parse_calib(text: &str, path: &Path) -> Result<KittiProjections, SensorError> {
    let (mut p0, mut p1) = (None, None);
    let mut unlabelled: Vec<[f64; 12]> = Vec::with_capacity(2);
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        match content.split_once(':') {
            Some((label, rest)) => {
                let slot = match label.trim() {
                    "P0" => &mut p0,
                    "P1" => &mut p1,
                    _ => continue,
                };
                if slot.is_some() {
                    return Err(format_error(path, line, format!("{} given twice", label.trim())));
                }
                *slot = Some(twelve_numbers(rest).map_err(|reason| format_error(path, line, reason))?);
            }
            None => {
                let numbers = twelve_numbers(content).map_err(|reason| format_error(path, line, reason))?;
                if unlabelled.len() < 2 {
                    unlabelled.push(numbers);
                }
            }
        }
    }
    match (p0, p1, unlabelled.as_slice()) {
        (Some(p0), Some(p1), _) => Ok(KittiProjections { p0, p1 }),
        (None, None, [p0, p1]) => Ok(KittiProjections { p0: *p0, p1: *p1 }),
        _ => Err(format_error(path, 0, "expected `P0:` and `P1:` lines or two lines of 12 numbers")),
    }
}

/// Reads `times.txt`: one stamp in seconds per line, finite, ≥ 0 and strictly increasing;
/// returns nanoseconds.
pub fn parse_times(text: &str, path: &Path) -> Result<Vec<u64>, SensorError> {
    let mut stamps_ns: Vec<u64> = Vec::new();
    for (index, raw) in text.lines().enumerate() {
        let line = index + 1;
        let content = raw.trim();
        if content.is_empty() || content.starts_with('#') {
            continue;
        }
        let seconds: f64 =
            content.parse().map_err(|_| format_error(path, line, format!("`{}` is not a stamp", excerpt(content))))?;
        // 1.8e10 s keeps the nanoseconds inside u64.
        if !(seconds.is_finite() && (0.0..1.8e10).contains(&seconds)) {
            return Err(format_error(path, line, format!("stamp {seconds} s is out of range")));
        }
        let stamp_ns = (seconds * 1e9).round() as u64;
        if stamps_ns.last().is_some_and(|&previous| stamp_ns <= previous) {
            return Err(format_error(path, line, "stamps must increase"));
        }
        stamps_ns.push(stamp_ns);
    }
    Ok(stamps_ns)
}

/// One stereo pair of the sequence (images not loaded).
#[derive(Debug, Clone, PartialEq)]
pub struct KittiFrame {
    pub stamp_ns: u64,
    pub left: PathBuf,
    pub right: PathBuf,
}

/// A KITTI odometry sequence opened for replay.
#[derive(Debug)]
pub struct KittiDataset {
    root: PathBuf,
    calibration: StereoCalibration,
    frames: Vec<KittiFrame>,
    next: usize,
    /// The frame announced by `next_event`, not read yet.
    pending: Option<usize>,
    /// The PNG file and its decoded pixels, reused so replay does not allocate per frame.
    file_bytes: Vec<u8>,
    pixels: Vec<u8>,
}

/// True when `dir` looks like a KITTI sequence (has one of the image folder pairs).
pub fn is_kitti_dir(dir: &Path) -> bool {
    image_dirs(dir).is_some()
}

fn image_dirs(dir: &Path) -> Option<(PathBuf, PathBuf)> {
    [("image_l", "image_r"), ("image_0", "image_1")]
        .into_iter()
        .map(|(l, r)| (dir.join(l), dir.join(r)))
        .find(|(l, r)| l.is_dir() && r.is_dir())
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> SensorError + '_ {
    move |source| SensorError::Io { context: path.display().to_string(), source }
}

/// PNG file names in `dir`, sorted.
fn png_names(dir: &Path) -> Result<Vec<std::ffi::OsString>, SensorError> {
    let mut names = Vec::new();
    for entry in fs::read_dir(dir).map_err(io_error(dir))? {
        let entry = entry.map_err(io_error(dir))?;
        let name = entry.file_name();
        if Path::new(&name).extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
            names.push(name);
        }
    }
    names.sort();
    Ok(names)
}

impl KittiDataset {
    /// Opens the sequence in `dir` (see the module documentation for the layout).
    pub fn open(dir: impl AsRef<Path>) -> Result<KittiDataset, SensorError> {
        let root = dir.as_ref().to_path_buf();
        if !root.is_dir() {
            return Err(SensorError::Io {
                context: root.display().to_string(),
                source: std::io::Error::new(std::io::ErrorKind::NotFound, "no such directory"),
            });
        }
        let Some((left_dir, right_dir)) = image_dirs(&root) else {
            return Err(format_error(&root, 0, "not a KITTI sequence: no image_l/ + image_r/ or image_0/ + image_1/"));
        };
        let calib_path = root.join("calib.txt");
        let calib_bytes = fs::read(&calib_path).map_err(io_error(&calib_path))?;
        let projections = parse_calib(&String::from_utf8_lossy(&calib_bytes), &calib_path)?;
        let (intrinsics, baseline_m) =
            projections.pinhole_and_baseline().map_err(|reason| format_error(&calib_path, 0, reason))?;

        let names = png_names(&left_dir)?;
        if names.is_empty() {
            return Err(format_error(&left_dir, 0, "no PNG images"));
        }
        let times_path = root.join("times.txt");
        let stamps_ns = if times_path.is_file() {
            let bytes = fs::read(&times_path).map_err(io_error(&times_path))?;
            let stamps = parse_times(&String::from_utf8_lossy(&bytes), &times_path)?;
            if stamps.len() != names.len() {
                let reason = format!("{} stamps for {} images", stamps.len(), names.len());
                return Err(format_error(&times_path, 0, reason));
            }
            stamps
        } else {
            (0..names.len() as u64).map(|i| i * DEFAULT_FRAME_PERIOD_NS).collect()
        };
        let mut frames = Vec::with_capacity(names.len());
        for (name, stamp_ns) in names.iter().zip(stamps_ns) {
            let right = right_dir.join(name);
            if !right.is_file() {
                return Err(format_error(&right, 0, "the right image of this pair is missing"));
            }
            frames.push(KittiFrame { stamp_ns, left: left_dir.join(name), right });
        }

        let mut file_bytes = Vec::new();
        let (width_px, height_px) = png_size(&frames[0].left, &mut file_bytes)?;
        let t_body_left =
            Isometry3::from_parts(Translation3::identity(), UnitQuaternion::from_rotation_matrix(&r_flu_optical()));
        let left = CameraCalibration {
            width_px,
            height_px,
            intrinsics,
            distortion: Distortion::None,
            t_body_cam: t_body_left,
        };
        let right = CameraCalibration { t_body_cam: t_body_left * Translation3::new(baseline_m, 0.0, 0.0), ..left };
        let calibration = StereoCalibration { left, right, rectified: true, baseline_m, head: None };
        Ok(KittiDataset { root, calibration, frames, next: 0, pending: None, file_bytes, pixels: Vec::new() })
    }

    pub fn root(&self) -> &Path {
        &self.root
    }

    pub fn calibration(&self) -> &StereoCalibration {
        &self.calibration
    }

    /// The stereo pairs in replay order.
    pub fn frames(&self) -> &[KittiFrame] {
        &self.frames
    }

    /// Starts the replay again from the first pair.
    pub fn rewind(&mut self) {
        self.next = 0;
        self.pending = None;
    }

    /// The announcement of pair `index`.
    fn info(&self, index: usize, stamp_ns: u64) -> StereoInfo {
        StereoInfo {
            stamp_ns,
            sequence: index as u64,
            width_px: self.calibration.left.width_px,
            height_px: self.calibration.left.height_px,
            pan_rad: 0.0,
            tilt_rad: 0.0,
        }
    }

    /// Decodes pair `index` into `frame`.
    pub fn load_frame(&mut self, index: usize, frame: &mut StereoFrame) -> Result<(), SensorError> {
        let Some(pair) = self.frames.get(index) else {
            return Err(SensorError::Source(format!("no stereo pair {index} (sequence has {})", self.frames.len())));
        };
        let (width, height) = (self.calibration.left.width_px, self.calibration.left.height_px);
        frame.resize(width, height);
        decode_to_grey(&pair.left, &mut self.file_bytes, &mut self.pixels, width, height, &mut frame.left)?;
        decode_to_grey(&pair.right, &mut self.file_bytes, &mut self.pixels, width, height, &mut frame.right)?;
        frame.stamp_ns = pair.stamp_ns;
        frame.sequence = index as u64;
        frame.pan_rad = 0.0;
        frame.tilt_rad = 0.0;
        Ok(())
    }
}

fn read_file(path: &Path, bytes: &mut Vec<u8>) -> Result<(), SensorError> {
    bytes.clear();
    fs::File::open(path).and_then(|mut f| f.read_to_end(bytes)).map_err(io_error(path))?;
    Ok(())
}

fn png_size(path: &Path, bytes: &mut Vec<u8>) -> Result<(u32, u32), SensorError> {
    read_file(path, bytes)?;
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes.as_slice()));
    let reader = decoder.read_info().map_err(|e| format_error(path, 0, format!("PNG: {e}")))?;
    let info = reader.info();
    Ok((info.width, info.height))
}

/// Decodes the PNG at `path` into the grey image `out` (`width × height`); colour is reduced to
/// luma with the Rec. 601 weights, alpha is dropped.
fn decode_to_grey(
    path: &Path,
    bytes: &mut Vec<u8>,
    pixels: &mut Vec<u8>,
    width: u32,
    height: u32,
    out: &mut [u8],
) -> Result<(), SensorError> {
    read_file(path, bytes)?;
    let bad = |reason: String| format_error(path, 0, reason);
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes.as_slice()));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| bad(format!("PNG: {e}")))?;
    let info = reader.info();
    if (info.width, info.height) != (width, height) {
        return Err(bad(format!("image is {}×{}, the sequence is {width}×{height}", info.width, info.height)));
    }
    let (color, depth) = reader.output_color_type();
    let channels = match color {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Err(bad("indexed PNG was not expanded".to_owned())),
    };
    let size = reader.output_buffer_size().ok_or_else(|| bad("PNG too large".to_owned()))?;
    if depth != png::BitDepth::Eight || size != out.len() * channels {
        return Err(bad(format!("unexpected PNG layout {color:?} {depth:?}")));
    }
    if channels == 1 {
        return reader.next_frame(out).map(|_| ()).map_err(|e| bad(format!("PNG: {e}")));
    }
    pixels.resize(size, 0);
    reader.next_frame(pixels).map_err(|e| bad(format!("PNG: {e}")))?;
    for (grey, px) in out.iter_mut().zip(pixels.chunks_exact(channels)) {
        *grey = if channels == 2 {
            px[0]
        } else {
            ((299 * u32::from(px[0]) + 587 * u32::from(px[1]) + 114 * u32::from(px[2]) + 500) / 1000) as u8
        };
    }
    Ok(())
}

impl SensorSource for KittiDataset {
    fn stereo_calibration(&self) -> Option<StereoCalibration> {
        Some(self.calibration)
    }

    fn next_event(&mut self) -> Result<Option<SensorEvent>, SensorError> {
        self.pending = None;
        let Some(frame) = self.frames.get(self.next) else {
            return Ok(None);
        };
        let index = self.next;
        self.next += 1;
        self.pending = Some(index);
        Ok(Some(SensorEvent::Stereo(self.info(index, frame.stamp_ns))))
    }

    fn read_stereo(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), SensorError> {
        let index = self.pending.take().ok_or_else(no_pending_pair)?;
        check_stereo_buffers(&self.info(index, 0), left, right)?;
        let (width, height) = (self.calibration.left.width_px, self.calibration.left.height_px);
        let pair = &self.frames[index];
        decode_to_grey(&pair.left, &mut self.file_bytes, &mut self.pixels, width, height, left)?;
        decode_to_grey(&pair.right, &mut self.file_bytes, &mut self.pixels, width, height, right)
    }
}
