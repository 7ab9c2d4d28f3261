//! Replay of a EuRoC/ASL dataset (`mav0/…`) as a [`SensorSource`].
//!
//! Layout read (every part but the cameras' images is loaded at [`AslDataset::open`]):
//!
//! - `cam0/`, `cam1/`: `data.csv` (`#timestamp [ns],filename`), `data/<file>` 8-bit grey PNGs,
//!   `sensor.yaml` (`T_BS`, `resolution`, `intrinsics`, `distortion_model`,
//!   `distortion_coefficients`). A stereo pair is a cam0 and a cam1 image with equal stamps;
//!   images of one camera without a partner are skipped and counted
//!   ([`AslDataset::unmatched_frames`]). Images are decoded lazily, one pair per event, straight
//!   into the caller's [`StereoFrame`].
//! - `imu0/` (optional): `data.csv` (`#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z`), `sensor.yaml`
//!   with the noise densities.
//! - `wheel0/` (optional, our extension): `data.csv`, see [`csv::parse_wheel_csv`].
//! - `pantilt0/` (optional, our extension): `data.csv` (`#timestamp [ns],pan [rad],tilt [rad]`)
//!   per stereo frame, and `sensor.yaml`, whose optional `T_BS_cam0_pan0_tilt0` (same layout as
//!   `T_BS`) is the left camera at pan = tilt = 0 when the cameras' own `T_BS` is given at
//!   other (`reference_pan_rad`, `reference_tilt_rad`) head angles.
//!
//! Events come in timestamp order; at equal stamps IMU, then wheel odometry, then stereo. Every
//! parser is total: malformed bytes give a [`SensorError::Format`] naming file and line.

pub mod csv;
pub mod yaml;

use std::fs;
use std::io::Read;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use crate::sensor::{
    CameraCalibration, Distortion, ImuSample, PanTiltHead, Pinhole, SensorError, SensorEvent, SensorSource,
    StereoCalibration, StereoFrame, StereoInfo, WheelOdomSample, check_stereo_buffers, no_pending_pair,
};
use csv::{CameraRow, PanTiltRow};
use yaml::Yaml;

/// How far a `T_BS` rotation may be from orthonormal (EuRoC's are within about 1e-9).
const ROTATION_TOLERANCE: f64 = 1e-6;
/// A pair counts as rectified when the right camera's rotation and off-axis offset relative to the
/// left are below these (text round trips of exact poses leave about 1e-16).
const RECTIFIED_ANGLE_TOLERANCE_RAD: f64 = 1e-9;
const RECTIFIED_OFFSET_TOLERANCE_M: f64 = 1e-9;

/// The noise parameters of `imu0/sensor.yaml` (Kalibr/EuRoC names and units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuNoiseDensities {
    pub gyroscope_noise_density: f64,
    pub gyroscope_random_walk: f64,
    pub accelerometer_noise_density: f64,
    pub accelerometer_random_walk: f64,
    pub rate_hz: Option<f64>,
}

/// One stereo pair of the dataset (images not loaded).
#[derive(Debug, Clone, PartialEq)]
pub struct StereoPair {
    pub stamp_ns: u64,
    /// Index of the left image in `cam0/data.csv` (gaps mean frames without a partner).
    pub sequence: u64,
    pub left: PathBuf,
    pub right: PathBuf,
    pub pan_rad: f64,
    pub tilt_rad: f64,
}

/// A EuRoC/ASL dataset opened for replay.
#[derive(Debug)]
pub struct AslDataset {
    root: PathBuf,
    calibration: Option<StereoCalibration>,
    camera_rate_hz: Option<f64>,
    pairs: Vec<StereoPair>,
    imu: Vec<ImuSample>,
    imu_noise: Option<ImuNoiseDensities>,
    wheel: Vec<WheelOdomSample>,
    unmatched_frames: usize,
    next_pair: usize,
    next_imu: usize,
    next_wheel: usize,
    /// The pair announced by `next_event`, not read yet.
    pending_pair: Option<usize>,
    /// The PNG file being decoded, reused so replay does not allocate per frame.
    file_bytes: Vec<u8>,
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> SensorError + '_ {
    move |source| SensorError::Io { context: path.display().to_string(), source }
}

fn read(path: &Path) -> Result<Vec<u8>, SensorError> {
    fs::read(path).map_err(io_error(path))
}

fn read_yaml(path: &Path) -> Result<Yaml, SensorError> {
    Yaml::parse(&read(path)?, path)
}

/// A `T_BS`-like 4×4 homogeneous transform at `key` (sensor pose in the body frame).
pub fn read_transform(yaml: &Yaml, key: &str) -> Result<Option<Isometry3<f64>>, SensorError> {
    let data_key = format!("{key}.data");
    let Some(data) = yaml.array::<16>(&data_key)? else {
        return Ok(None);
    };
    let line = yaml.line(&data_key);
    for dimension in ["rows", "cols"] {
        let path = format!("{key}.{dimension}");
        if let Some(n) = yaml.number(&path)?
            && n != 4.0
        {
            return Err(yaml.error(yaml.line(&path), format!("`{path}` is {n}, expected 4")));
        }
    }
    let last_row = [data[12], data[13], data[14], data[15]];
    if last_row != [0.0, 0.0, 0.0, 1.0] {
        return Err(yaml.error(line, format!("`{data_key}`: last row {last_row:?} is not [0, 0, 0, 1]")));
    }
    let m = Matrix3::new(data[0], data[1], data[2], data[4], data[5], data[6], data[8], data[9], data[10]);
    let error = (m.transpose() * m - Matrix3::identity()).abs().max();
    let determinant = m.determinant();
    // Written so that NaN (from overflowing products of huge entries) is rejected too.
    if error.is_nan() || error > ROTATION_TOLERANCE || determinant.is_nan() || determinant <= 0.0 {
        return Err(yaml.error(line, format!("`{data_key}`: not a rotation (|RᵀR − I| = {error:.1e})")));
    }
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(m));
    Ok(Some(Isometry3::from_parts(Translation3::new(data[3], data[7], data[11]), rotation)))
}

/// One camera's `sensor.yaml`: its calibration and frame rate.
pub fn camera_calibration(yaml: &Yaml) -> Result<(CameraCalibration, Option<f64>), SensorError> {
    if let Some(model) = yaml.string("camera_model")
        && model != "pinhole"
    {
        let reason = format!("camera_model `{}` is not supported (only pinhole)", yaml::excerpt(model));
        return Err(yaml.error(yaml.line("camera_model"), reason));
    }
    let [width, height] = yaml.required_array::<2>("resolution")?;
    let size = |v: f64| (v >= 1.0 && v <= f64::from(u32::MAX) && v.fract() == 0.0).then_some(v as u32);
    let (Some(width_px), Some(height_px)) = (size(width), size(height)) else {
        return Err(yaml.error(yaml.line("resolution"), "resolution must be two positive whole numbers"));
    };
    let [fx_px, fy_px, cx_px, cy_px] = yaml.required_array::<4>("intrinsics")?;
    if fx_px <= 0.0 || fy_px <= 0.0 {
        return Err(yaml.error(yaml.line("intrinsics"), "focal lengths must be positive"));
    }
    let distortion = distortion(yaml)?;
    let t_body_cam = read_transform(yaml, "T_BS")?.ok_or_else(|| yaml.error(0, "missing `T_BS.data`"))?;
    let rate_hz = yaml.number("rate_hz")?;
    let calibration = CameraCalibration {
        width_px,
        height_px,
        intrinsics: Pinhole { fx_px, fy_px, cx_px, cy_px },
        distortion,
        t_body_cam,
    };
    Ok((calibration, rate_hz))
}

/// Radial-tangential coefficients that are all zero describe an ideal pinhole: [`Distortion::None`].
fn distortion(yaml: &Yaml) -> Result<Distortion, SensorError> {
    let coefficients = yaml.numbers("distortion_coefficients")?.unwrap_or_default();
    let line = yaml.line("distortion_coefficients");
    let model = yaml.string("distortion_model");
    let all_zero = coefficients.iter().all(|&c| c == 0.0);
    match model {
        None | Some("none") if all_zero => Ok(Distortion::None),
        None | Some("none") => Err(yaml.error(line, "distortion coefficients without a distortion_model")),
        Some("radial-tangential" | "radtan" | "plumb_bob") => {
            let (k, extra) = coefficients.split_at(coefficients.len().min(4));
            // plumb_bob's fifth coefficient (k3) is representable only when zero.
            if k.len() != 4 || extra.len() > 1 || extra.iter().any(|&c| c != 0.0) {
                return Err(yaml.error(
                    line,
                    format!("radial-tangential needs 4 coefficients [k1, k2, p1, p2], got {}", coefficients.len()),
                ));
            }
            if all_zero { Ok(Distortion::None) } else { Ok(Distortion::RadTan([k[0], k[1], k[2], k[3]])) }
        }
        Some(other) => Err(yaml.error(
            yaml.line("distortion_model"),
            format!("distortion_model `{}` is not supported", yaml::excerpt(other)),
        )),
    }
}

/// The head kinematics of `pantilt0/sensor.yaml`; the baseline is the cameras' distance.
fn pan_tilt_head(yaml: &Yaml, left: &CameraCalibration, right: &CameraCalibration) -> Result<PanTiltHead, SensorError> {
    let [px, py, pz] = yaml.required_array::<3>("pan_axis_body_m")?;
    let [sx, sy, sz] = yaml.required_array::<3>("stereo_centre_head_m")?;
    let limit = |key: &str, default: f64| -> Result<f64, SensorError> {
        match yaml.number(key)? {
            Some(v) if v.is_finite() && v >= 0.0 => Ok(v),
            Some(_) => Err(yaml.error(yaml.line(key), format!("{key} must be a finite angle ≥ 0"))),
            None => Ok(default),
        }
    };
    Ok(PanTiltHead {
        pan_axis_body_m: Vector3::new(px, py, pz),
        stereo_centre_head_m: Vector3::new(sx, sy, sz),
        baseline_m: (left.t_body_cam.inverse() * right.t_body_cam).translation.vector.norm(),
        pan_limit_rad: limit("pan_limit_rad", std::f64::consts::PI)?,
        tilt_limit_rad: limit("tilt_limit_rad", std::f64::consts::FRAC_PI_2)?,
    })
}

/// The stereo calibration of two cameras: rectified when both are ideal pinholes with equal
/// intrinsics and size and the right camera sits on the left one's +x axis, unrotated.
pub fn pair_calibration(left: CameraCalibration, right: CameraCalibration) -> StereoCalibration {
    let t_left_right = left.t_body_cam.inverse() * right.t_body_cam;
    let offset = t_left_right.translation.vector;
    let rectified = left.distortion == Distortion::None
        && right.distortion == Distortion::None
        && left.intrinsics == right.intrinsics
        && (left.width_px, left.height_px) == (right.width_px, right.height_px)
        && t_left_right.rotation.angle() < RECTIFIED_ANGLE_TOLERANCE_RAD
        && offset.x > 0.0
        && offset.y.abs() < RECTIFIED_OFFSET_TOLERANCE_M
        && offset.z.abs() < RECTIFIED_OFFSET_TOLERANCE_M;
    StereoCalibration { left, right, rectified, baseline_m: offset.norm(), head: None }
}

fn imu_noise(yaml: &Yaml) -> Result<Option<ImuNoiseDensities>, SensorError> {
    let keys = [
        "gyroscope_noise_density",
        "gyroscope_random_walk",
        "accelerometer_noise_density",
        "accelerometer_random_walk",
    ];
    let mut values = [0.0; 4];
    for (value, key) in values.iter_mut().zip(keys) {
        match yaml.number(key)? {
            Some(v) => *value = v,
            None => return Ok(None),
        }
    }
    Ok(Some(ImuNoiseDensities {
        gyroscope_noise_density: values[0],
        gyroscope_random_walk: values[1],
        accelerometer_noise_density: values[2],
        accelerometer_random_walk: values[3],
        rate_hz: yaml.number("rate_hz")?,
    }))
}

/// Pairs cam0 and cam1 rows with equal stamps (both sorted); returns the pairs and how many rows
/// of either camera had no partner.
fn match_pairs(
    cam0: &[CameraRow],
    cam1: &[CameraRow],
    dir0: &Path,
    dir1: &Path,
    pantilt: &[PanTiltRow],
) -> (Vec<StereoPair>, usize) {
    let (mut i, mut j, mut k) = (0, 0, 0);
    let mut pairs = Vec::with_capacity(cam0.len().min(cam1.len()));
    let mut unmatched = 0;
    while i < cam0.len() && j < cam1.len() {
        let (a, b) = (&cam0[i], &cam1[j]);
        if a.stamp_ns < b.stamp_ns {
            unmatched += 1;
            i += 1;
        } else if b.stamp_ns < a.stamp_ns {
            unmatched += 1;
            j += 1;
        } else {
            while k < pantilt.len() && pantilt[k].stamp_ns < a.stamp_ns {
                k += 1;
            }
            let (pan_rad, tilt_rad) = match pantilt.get(k) {
                Some(row) if row.stamp_ns == a.stamp_ns => (row.pan_rad, row.tilt_rad),
                _ => (0.0, 0.0),
            };
            pairs.push(StereoPair {
                stamp_ns: a.stamp_ns,
                sequence: i as u64,
                left: dir0.join(&a.file_name),
                right: dir1.join(&b.file_name),
                pan_rad,
                tilt_rad,
            });
            i += 1;
            j += 1;
        }
    }
    unmatched += (cam0.len() - i) + (cam1.len() - j);
    (pairs, unmatched)
}

/// The stereo part of a dataset.
struct Cameras {
    calibration: Option<StereoCalibration>,
    rate_hz: Option<f64>,
    pairs: Vec<StereoPair>,
    unmatched: usize,
}

/// Reads `cam0/` and `cam1/` (both or neither) and pairs their images.
fn open_cameras(root: &Path, pantilt: &[PanTiltRow]) -> Result<Cameras, SensorError> {
    let (cam0, cam1) = (root.join("cam0"), root.join("cam1"));
    match (cam0.is_dir(), cam1.is_dir()) {
        (false, false) => return Ok(Cameras { calibration: None, rate_hz: None, pairs: Vec::new(), unmatched: 0 }),
        (true, true) => {}
        _ => {
            return Err(SensorError::Format {
                context: root.display().to_string(),
                reason: "only one of cam0/ and cam1/: a stereo pair needs both".to_owned(),
            });
        }
    }
    let (mut left, rate_hz) = camera_calibration(&read_yaml(&cam0.join("sensor.yaml"))?)?;
    let (mut right, _) = camera_calibration(&read_yaml(&cam1.join("sensor.yaml"))?)?;
    let pantilt_yaml = root.join("pantilt0").join("sensor.yaml");
    let mut head = None;
    if pantilt_yaml.is_file() {
        let yaml = read_yaml(&pantilt_yaml)?;
        if let Some(t_body_left_zero) = read_transform(&yaml, "T_BS_cam0_pan0_tilt0")? {
            // The pair is rigid: the right camera keeps its pose relative to the left one.
            let t_left_right = left.t_body_cam.inverse() * right.t_body_cam;
            left.t_body_cam = t_body_left_zero;
            right.t_body_cam = t_body_left_zero * t_left_right;
        }
        // Without the kinematics the angles in data.csv cannot be turned into poses: no head.
        if yaml.contains("pan_axis_body_m") {
            head = Some(pan_tilt_head(&yaml, &left, &right)?);
        }
    }
    let mut calibration = pair_calibration(left, right);
    calibration.head = head;
    let csv0 = cam0.join("data.csv");
    let csv1 = cam1.join("data.csv");
    let rows0 = csv::parse_camera_csv(&read(&csv0)?, &csv0)?;
    let rows1 = csv::parse_camera_csv(&read(&csv1)?, &csv1)?;
    let (pairs, unmatched) = match_pairs(&rows0, &rows1, &cam0.join("data"), &cam1.join("data"), pantilt);
    Ok(Cameras { calibration: Some(calibration), rate_hz, pairs, unmatched })
}

impl AslDataset {
    /// Opens the dataset in `dir`: either the folder holding `mav0/` or `mav0/` itself.
    pub fn open(dir: impl AsRef<Path>) -> Result<AslDataset, SensorError> {
        let dir = dir.as_ref();
        let root = if dir.join("mav0").is_dir() {
            dir.join("mav0")
        } else if dir.join("cam0").is_dir() || dir.join("imu0").is_dir() {
            dir.to_path_buf()
        } else {
            return Err(SensorError::Format {
                context: dir.display().to_string(),
                reason: "not an ASL dataset: no mav0/, cam0/ or imu0/ inside".to_owned(),
            });
        };

        let pantilt_dir = root.join("pantilt0");
        let pantilt = if pantilt_dir.join("data.csv").is_file() {
            let path = pantilt_dir.join("data.csv");
            csv::parse_pantilt_csv(&read(&path)?, &path)?
        } else {
            Vec::new()
        };
        let cameras = open_cameras(&root, &pantilt)?;

        let imu_dir = root.join("imu0");
        let imu = if imu_dir.join("data.csv").is_file() {
            let path = imu_dir.join("data.csv");
            csv::parse_imu_csv(&read(&path)?, &path)?
        } else {
            Vec::new()
        };
        let imu_noise = if imu_dir.join("sensor.yaml").is_file() {
            imu_noise(&read_yaml(&imu_dir.join("sensor.yaml"))?)?
        } else {
            None
        };
        let wheel_path = root.join("wheel0").join("data.csv");
        let wheel =
            if wheel_path.is_file() { csv::parse_wheel_csv(&read(&wheel_path)?, &wheel_path)? } else { Vec::new() };

        Ok(AslDataset {
            root,
            calibration: cameras.calibration,
            camera_rate_hz: cameras.rate_hz,
            pairs: cameras.pairs,
            imu,
            imu_noise,
            wheel,
            unmatched_frames: cameras.unmatched,
            next_pair: 0,
            next_imu: 0,
            next_wheel: 0,
            pending_pair: None,
            file_bytes: Vec::new(),
        })
    }

    /// The `mav0` folder.
    pub fn root(&self) -> &Path {
        &self.root
    }

    /// The stereo pairs in replay order.
    pub fn pairs(&self) -> &[StereoPair] {
        &self.pairs
    }

    pub fn imu_samples(&self) -> &[ImuSample] {
        &self.imu
    }

    pub fn wheel_samples(&self) -> &[WheelOdomSample] {
        &self.wheel
    }

    /// Noise densities from `imu0/sensor.yaml`, when it has all four.
    pub fn imu_noise(&self) -> Option<ImuNoiseDensities> {
        self.imu_noise
    }

    /// `rate_hz` of `cam0/sensor.yaml`.
    pub fn camera_rate_hz(&self) -> Option<f64> {
        self.camera_rate_hz
    }

    /// Camera images of either side skipped for want of a partner with the same stamp.
    pub fn unmatched_frames(&self) -> usize {
        self.unmatched_frames
    }

    /// Starts the replay again from the first event.
    pub fn rewind(&mut self) {
        (self.next_pair, self.next_imu, self.next_wheel) = (0, 0, 0);
        self.pending_pair = None;
    }

    /// Decodes pair `index` into `frame`.
    pub fn load_pair(&mut self, index: usize, frame: &mut StereoFrame) -> Result<(), SensorError> {
        let Some(pair) = self.pairs.get(index) else {
            return Err(SensorError::Source(format!("no stereo pair {index} (dataset has {})", self.pairs.len())));
        };
        let (width, height) = self.calibration.map_or((0, 0), |c| (c.left.width_px, c.left.height_px));
        frame.resize(width, height);
        decode_grey_png(&pair.left, &mut self.file_bytes, width, height, &mut frame.left)?;
        decode_grey_png(&pair.right, &mut self.file_bytes, width, height, &mut frame.right)?;
        frame.stamp_ns = pair.stamp_ns;
        frame.sequence = pair.sequence;
        frame.pan_rad = pair.pan_rad;
        frame.tilt_rad = pair.tilt_rad;
        Ok(())
    }
}

/// Decodes the 8-bit grey PNG at `path` (16-bit grey keeps its high byte) into `out`, which must
/// match the calibrated `width × height`.
fn decode_grey_png(
    path: &Path,
    file_bytes: &mut Vec<u8>,
    width: u32,
    height: u32,
    out: &mut [u8],
) -> Result<(), SensorError> {
    file_bytes.clear();
    fs::File::open(path).and_then(|mut f| f.read_to_end(file_bytes)).map_err(io_error(path))?;
    let bad = |reason: String| SensorError::Format { context: path.display().to_string(), reason };
    let mut decoder = png::Decoder::new(std::io::Cursor::new(file_bytes.as_slice()));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().map_err(|e| bad(format!("PNG: {e}")))?;
    let (color, depth) = reader.output_color_type();
    if color != png::ColorType::Grayscale || depth != png::BitDepth::Eight {
        return Err(bad(format!("expected an 8-bit grey PNG, found {color:?} {depth:?}")));
    }
    let info = reader.info();
    if (info.width, info.height) != (width, height) {
        return Err(bad(format!("image is {}×{}, sensor.yaml says {width}×{height}", info.width, info.height)));
    }
    if reader.output_buffer_size() != Some(out.len()) {
        return Err(bad("unexpected PNG row layout".to_owned()));
    }
    reader.next_frame(out).map_err(|e| bad(format!("PNG: {e}")))?;
    Ok(())
}

impl SensorSource for AslDataset {
    fn stereo_calibration(&self) -> Option<StereoCalibration> {
        self.calibration
    }

    fn next_event(&mut self) -> Result<Option<SensorEvent>, SensorError> {
        self.pending_pair = None;
        let imu = self.imu.get(self.next_imu).map(|s| s.stamp_ns);
        let wheel = self.wheel.get(self.next_wheel).map(|s| s.stamp_ns);
        let stereo = self.pairs.get(self.next_pair).map(|p| p.stamp_ns);
        // Ties go to the earlier stream in this order: IMU, wheel odometry, stereo.
        let earliest =
            [imu, wheel, stereo].into_iter().enumerate().filter_map(|(kind, stamp)| stamp.map(|s| (s, kind))).min();
        match earliest {
            None => Ok(None),
            Some((_, 0)) => {
                let sample = self.imu[self.next_imu];
                self.next_imu += 1;
                Ok(Some(SensorEvent::Imu(sample)))
            }
            Some((_, 1)) => {
                let sample = self.wheel[self.next_wheel];
                self.next_wheel += 1;
                Ok(Some(SensorEvent::WheelOdom(sample)))
            }
            Some(_) => {
                let index = self.next_pair;
                self.next_pair += 1;
                let pair = &self.pairs[index];
                let (width_px, height_px) = self.calibration.map_or((0, 0), |c| (c.left.width_px, c.left.height_px));
                self.pending_pair = Some(index);
                Ok(Some(SensorEvent::Stereo(StereoInfo {
                    stamp_ns: pair.stamp_ns,
                    sequence: pair.sequence,
                    width_px,
                    height_px,
                    pan_rad: pair.pan_rad,
                    tilt_rad: pair.tilt_rad,
                })))
            }
        }
    }

    fn read_stereo(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), SensorError> {
        let index = self.pending_pair.take().ok_or_else(no_pending_pair)?;
        let (width, height) = self.calibration.map_or((0, 0), |c| (c.left.width_px, c.left.height_px));
        let info =
            StereoInfo { stamp_ns: 0, sequence: 0, width_px: width, height_px: height, pan_rad: 0.0, tilt_rad: 0.0 };
        check_stereo_buffers(&info, left, right)?;
        let pair = &self.pairs[index];
        decode_grey_png(&pair.left, &mut self.file_bytes, width, height, left)?;
        decode_grey_png(&pair.right, &mut self.file_bytes, width, height, right)
    }
}

/// Helper for writers: the 4×4 row-major homogeneous matrix of a pose, as `T_BS.data` holds it.
pub fn transform_rows(t: &Isometry3<f64>) -> [f64; 16] {
    let r = t.rotation.to_rotation_matrix();
    let m = r.matrix();
    let p: Vector3<f64> = t.translation.vector;
    [
        m[(0, 0)],
        m[(0, 1)],
        m[(0, 2)],
        p.x,
        m[(1, 0)],
        m[(1, 1)],
        m[(1, 2)],
        p.y,
        m[(2, 0)],
        m[(2, 1)],
        m[(2, 2)],
        p.z,
        0.0,
        0.0,
        0.0,
        1.0,
    ]
}
