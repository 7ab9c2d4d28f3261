//! Writes a simulated run as EuRoC/ASL datasets, one per robot, plus the world's ground truth
//! (owned by the dataset helper).
//!
//! Per robot (`<dir>/`):
//!
//! - `mav0/cam0|cam1/`: `data.csv`, `data/<stamp>.png` (8-bit grey), `sensor.yaml` (EuRoC style;
//!   `T_BS` is the camera in the body at pan 0 and the scenario's fixed tilt).
//! - `mav0/imu0/`: `data.csv` (EuRoC columns), `sensor.yaml` with the noise densities.
//! - `mav0/wheel0/` (rovers): `data.csv` (body twist and its claimed sigmas), `sensor.yaml`.
//! - `mav0/pantilt0/` (robots with a head): `data.csv` with pan and tilt per stereo frame;
//!   `sensor.yaml` names the head angles of the cameras' `T_BS` and gives `T_BS_cam0_pan0_tilt0`.
//! - `mav0/state_groundtruth_estimate0/data.csv`: EuRoC's ground-truth layout at every IMU stamp.
//! - `groundtruth.tum`: the body pose at every camera stamp (`t_s tx ty tz qx qy qz qw`).
//!
//! Floats are printed with Rust's shortest round-trip representation (`{:?}`): read back they
//! are the same `f64`, and the same run always gives the same bytes.

use std::fmt::Write as _;
use std::fs;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

use hal::asl::transform_rows;
use hal::sensor::{ImuSample, SensorError, SensorEvent, StereoFrame, WheelOdomSample};
use nalgebra::Isometry3;

use crate::camera::{PanTiltHead, StereoCamera};
use crate::driver::{GroundTruthSample, SimSensorSource};
use crate::imu::ImuNoise;
use crate::robot::RobotKind;
use crate::wheel::WheelOdomConfig;
use crate::world::World;

pub use world_export::{WorldExport, WorldFiles, path_bounds, write_world, write_world_with};

mod world_export;

/// Why a dataset could not be written.
#[derive(Debug, thiserror::Error)]
pub enum AslError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("{}: PNG: {source}", path.display())]
    Png {
        path: PathBuf,
        #[source]
        source: png::EncodingError,
    },
    #[error(transparent)]
    Sensor(#[from] SensorError),
    #[error("{0}")]
    Invalid(String),
}

pub(crate) fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> AslError + '_ {
    move |source| AslError::Io { path: path.to_owned(), source }
}

/// What one robot's recording produced.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct RecordStats {
    pub stereo_pairs: u64,
    pub imu_samples: u64,
    pub wheel_samples: u64,
    pub ground_truth_rows: u64,
    /// Bytes of every file written.
    pub bytes: u64,
    /// Wall time of the recording (rendering included).
    pub elapsed_s: f64,
}

/// The sensors of one robot as the dataset's `sensor.yaml` files describe them.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorSetup {
    pub label: String,
    pub camera: StereoCamera,
    /// Left camera in the body at the head angles the cameras' `T_BS` is given for (pan 0 and the
    /// scenario's fixed tilt; the fixed mounting without a head).
    pub t_body_cam: Isometry3<f64>,
    /// The head and the tilt of `t_body_cam`, when the robot has one.
    pub head: Option<(PanTiltHead, f64)>,
    pub camera_rate_hz: f64,
    pub imu_rate_hz: f64,
    pub imu_noise: ImuNoise,
    /// Wheel odometry (rovers only).
    pub wheel: Option<WheelOdomConfig>,
}

impl SensorSetup {
    /// The setup of robot `robot` of `world`.
    pub fn of(world: &World, robot: usize) -> Result<SensorSetup, AslError> {
        let sim_robot =
            world.robots.get(robot).ok_or_else(|| AslError::Invalid(format!("the world has no robot {robot}")))?;
        let setup = &sim_robot.setup;
        let model = &setup.model;
        let scenario = &world.scenario;
        Ok(SensorSetup {
            label: format!(
                "sim scenario {} seed {}, robot {} ({})",
                scenario.name, scenario.seed, setup.id, setup.name
            ),
            camera: model.camera,
            t_body_cam: model.t_body_cam(0.0, setup.tilt_rad),
            head: model.head.map(|head| (head, setup.tilt_rad)),
            camera_rate_hz: scenario.camera_rate_hz,
            imu_rate_hz: scenario.imu_rate_hz,
            imu_noise: scenario.imu_noise,
            wheel: (model.kind == RobotKind::Rover).then_some(scenario.wheel),
        })
    }
}

/// A CSV file being written, with a byte count.
#[derive(Debug)]
struct CsvFile {
    path: PathBuf,
    out: std::io::BufWriter<fs::File>,
    bytes: u64,
    rows: u64,
}

impl CsvFile {
    fn create(path: PathBuf, header: &str) -> Result<CsvFile, AslError> {
        let file = fs::File::create(&path).map_err(io_error(&path))?;
        let mut csv = CsvFile { path, out: std::io::BufWriter::new(file), bytes: 0, rows: 0 };
        csv.write_line(header)?;
        csv.rows = 0;
        Ok(csv)
    }

    /// Writes `line` and a newline.
    fn write_line(&mut self, line: &str) -> Result<(), AslError> {
        self.out.write_all(line.as_bytes()).and_then(|()| self.out.write_all(b"\n")).map_err(io_error(&self.path))?;
        self.bytes += line.len() as u64 + 1;
        self.rows += 1;
        Ok(())
    }

    fn finish(mut self) -> Result<u64, AslError> {
        self.out.flush().map_err(io_error(&self.path))?;
        Ok(self.bytes)
    }
}

fn create_dir(path: &Path) -> Result<(), AslError> {
    fs::create_dir_all(path).map_err(io_error(path))
}

/// Writes `text` to `path`, returning its length.
pub(crate) fn write_text(path: &Path, text: &str) -> Result<u64, AslError> {
    fs::write(path, text).map_err(io_error(path))?;
    Ok(text.len() as u64)
}

/// Writes `bytes` to `path`.
pub(crate) fn write_bytes(path: &Path, bytes: &[u8]) -> Result<(), AslError> {
    fs::write(path, bytes).map_err(io_error(path))
}

/// Appends `[a, b, c]` with round-trip floats.
fn push_list(out: &mut String, values: &[f64]) {
    out.push('[');
    for (i, v) in values.iter().enumerate() {
        let _ = write!(out, "{}{v:?}", if i == 0 { "" } else { ", " });
    }
    out.push(']');
}

/// A `T_BS`-style 4×4 block under `key`, laid out as EuRoC's files are.
fn push_transform(out: &mut String, key: &str, t: &Isometry3<f64>) {
    let rows = transform_rows(t);
    let _ = write!(out, "{key}:\n  cols: 4\n  rows: 4\n  data: [");
    for (i, v) in rows.iter().enumerate() {
        let separator = match i {
            0 => "",
            4 | 8 | 12 => ",\n         ",
            _ => ", ",
        };
        let _ = write!(out, "{separator}{v:?}");
    }
    out.push_str("]\n");
}

fn camera_yaml(setup: &SensorSetup, side: &str, t_body_cam: &Isometry3<f64>) -> String {
    let cam = &setup.camera;
    let mut out = String::from("%YAML:1.0\n# General sensor definitions.\nsensor_type: camera\n");
    let _ = writeln!(out, "comment: {}, {side} camera (rectified pair, ideal pinhole)", setup.label);
    out.push_str("\n# Sensor extrinsics wrt. the body-frame.\n");
    push_transform(&mut out, "T_BS", t_body_cam);
    out.push_str("\n# Camera specific definitions.\n");
    let _ = writeln!(out, "rate_hz: {:?}", setup.camera_rate_hz);
    let _ = writeln!(out, "resolution: [{}, {}]", cam.width_px, cam.height_px);
    out.push_str("camera_model: pinhole\nintrinsics: ");
    push_list(&mut out, &[cam.f_px, cam.f_px, cam.cx_px, cam.cy_px]);
    out.push_str(" #fu, fv, cu, cv\ndistortion_model: radial-tangential\n");
    out.push_str("distortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n");
    out
}

fn imu_yaml(setup: &SensorSetup) -> String {
    let noise = &setup.imu_noise;
    let mut out = String::from("%YAML:1.0\nsensor_type: imu\n");
    let _ = writeln!(out, "comment: {}, IMU (body frame = IMU frame)", setup.label);
    out.push_str("\n# Sensor extrinsics wrt. the body-frame.\n");
    push_transform(&mut out, "T_BS", &Isometry3::identity());
    let _ = writeln!(out, "rate_hz: {:?}", setup.imu_rate_hz);
    out.push_str("\n# inertial sensor noise model parameters (static)\n");
    let _ =
        writeln!(out, "gyroscope_noise_density: {:?} # [ rad / s / sqrt(Hz) ]", noise.gyro_noise_density_radps_rthz);
    let _ = writeln!(out, "gyroscope_random_walk: {:?} # [ rad / s^2 / sqrt(Hz) ]", noise.gyro_bias_rw_radps2_rthz);
    let _ = writeln!(
        out,
        "accelerometer_noise_density: {:?} # [ m / s^2 / sqrt(Hz) ]",
        noise.accel_noise_density_mps2_rthz
    );
    let _ = writeln!(out, "accelerometer_random_walk: {:?} # [ m / s^3 / sqrt(Hz) ]", noise.accel_bias_rw_mps3_rthz);
    out.push_str("\n# turn-on bias standard deviations (simulator)\n");
    let _ = writeln!(out, "gyroscope_bias_init_sigma: {:?} # [ rad / s ]", noise.gyro_bias_init_radps);
    let _ = writeln!(out, "accelerometer_bias_init_sigma: {:?} # [ m / s^2 ]", noise.accel_bias_init_mps2);
    out
}

fn wheel_yaml(setup: &SensorSetup, config: &WheelOdomConfig) -> String {
    let mut out = String::from("%YAML:1.0\nsensor_type: wheel_odometry\n");
    let _ = writeln!(out, "comment: {}, body twist from wheel encoders and steering", setup.label);
    out.push_str("# data.csv: body-frame linear and angular velocity, then the standard deviations\n");
    out.push_str("# the odometry claims for each of the six components.\n");
    push_transform(&mut out, "T_BS", &Isometry3::identity());
    let _ = writeln!(out, "rate_hz: {:?}", config.rate_hz);
    let _ = writeln!(out, "base_slip: {:?}", config.base_slip);
    let _ = writeln!(out, "slip_per_uphill_rad: {:?}", config.slip_per_uphill_rad);
    let _ = writeln!(out, "speed_noise: {:?} # [ m / s ]", config.speed_noise_mps);
    let _ = writeln!(out, "yaw_rate_noise: {:?} # [ rad / s ]", config.yaw_rate_noise_radps);
    out
}

fn pantilt_yaml(setup: &SensorSetup, head: &PanTiltHead, tilt_rad: f64) -> String {
    let mut out = String::from("%YAML:1.0\nsensor_type: pan_tilt\n");
    let _ = writeln!(out, "comment: {}, camera head (positive tilt looks down)", setup.label);
    out.push_str("# The cameras' T_BS holds at these head angles:\n");
    let _ = writeln!(out, "reference_pan_rad: 0.0\nreference_tilt_rad: {tilt_rad:?}");
    out.push_str("# The left camera at pan = tilt = 0:\n");
    push_transform(&mut out, "T_BS_cam0_pan0_tilt0", &head.t_body_cam(0.0, 0.0));
    out.push_str("# Kinematics: pan about body z through pan_axis, then tilt about the panned y axis.\n");
    out.push_str("pan_axis_body_m: ");
    push_list(&mut out, head.pan_axis_body_m.as_slice());
    out.push_str("\nstereo_centre_head_m: ");
    push_list(&mut out, head.stereo_centre_head_m.as_slice());
    let _ = writeln!(out, "\npan_limit_rad: {:?}\ntilt_limit_rad: {:?}", head.pan_limit_rad, head.tilt_limit_rad);
    out
}

const CAMERA_HEADER: &str = "#timestamp [ns],filename";
const IMU_HEADER: &str = "#timestamp [ns],w_RS_S_x [rad s^-1],w_RS_S_y [rad s^-1],w_RS_S_z [rad s^-1],\
a_RS_S_x [m s^-2],a_RS_S_y [m s^-2],a_RS_S_z [m s^-2]";
const PANTILT_HEADER: &str = "#timestamp [ns],pan [rad],tilt [rad]";
/// EuRoC's `state_groundtruth_estimate0/data.csv` header, verbatim.
pub const GROUND_TRUTH_HEADER: &str = "#timestamp, p_RS_R_x [m], p_RS_R_y [m], p_RS_R_z [m], \
q_RS_w [], q_RS_x [], q_RS_y [], q_RS_z [], v_RS_R_x [m s^-1], v_RS_R_y [m s^-1], v_RS_R_z [m s^-1], \
b_w_RS_S_x [rad s^-1], b_w_RS_S_y [rad s^-1], b_w_RS_S_z [rad s^-1], \
b_a_RS_S_x [m s^-2], b_a_RS_S_y [m s^-2], b_a_RS_S_z [m s^-2]";
const TUM_HEADER: &str = "# timestamp[s] tx ty tz qx qy qz qw (body in world)";

fn wheel_header() -> String {
    let mut header = String::from("#timestamp [ns]");
    for column in hal::asl::csv::WHEEL_COLUMNS {
        header.push(',');
        header.push_str(column);
    }
    header
}

/// Appends `,v` for each value.
fn push_values(line: &mut String, values: &[f64]) {
    for v in values {
        let _ = write!(line, ",{v:?}");
    }
}

/// `stamp_ns` as seconds with all nine decimals: exact, unlike a float.
fn push_seconds(line: &mut String, stamp_ns: u64) {
    let _ = write!(line, "{}.{:09}", stamp_ns / 1_000_000_000, stamp_ns % 1_000_000_000);
}

/// Writes one robot's dataset, event by event.
#[derive(Debug)]
pub struct AslWriter {
    mav0: PathBuf,
    cam_data: [PathBuf; 2],
    cameras: [CsvFile; 2],
    imu: CsvFile,
    wheel: Option<CsvFile>,
    pantilt: Option<CsvFile>,
    ground_truth: CsvFile,
    tum: CsvFile,
    /// Reused buffers: one CSV line, one encoded PNG.
    line: String,
    png_bytes: Vec<u8>,
    image_bytes: u64,
    other_bytes: u64,
}

impl AslWriter {
    /// Creates `dir/mav0/…` and `dir/groundtruth.tum` and writes every `sensor.yaml`.
    pub fn create(dir: &Path, setup: &SensorSetup) -> Result<AslWriter, AslError> {
        let mav0 = dir.join("mav0");
        let mut other_bytes = 0;
        let t_body_right = setup.t_body_cam * setup.camera.t_left_right();
        let mut camera = |name: &str, side: &str, t_body_cam: &Isometry3<f64>| -> Result<_, AslError> {
            let cam_dir = mav0.join(name);
            let data = cam_dir.join("data");
            create_dir(&data)?;
            other_bytes += write_text(&cam_dir.join("sensor.yaml"), &camera_yaml(setup, side, t_body_cam))?;
            Ok((data, CsvFile::create(cam_dir.join("data.csv"), CAMERA_HEADER)?))
        };
        let (data0, cam0) = camera("cam0", "left", &setup.t_body_cam)?;
        let (data1, cam1) = camera("cam1", "right", &t_body_right)?;
        let cam_data = [data0, data1];

        let imu_dir = mav0.join("imu0");
        create_dir(&imu_dir)?;
        other_bytes += write_text(&imu_dir.join("sensor.yaml"), &imu_yaml(setup))?;
        let imu = CsvFile::create(imu_dir.join("data.csv"), IMU_HEADER)?;

        let wheel = match &setup.wheel {
            Some(config) => {
                let wheel_dir = mav0.join("wheel0");
                create_dir(&wheel_dir)?;
                other_bytes += write_text(&wheel_dir.join("sensor.yaml"), &wheel_yaml(setup, config))?;
                Some(CsvFile::create(wheel_dir.join("data.csv"), &wheel_header())?)
            }
            None => None,
        };
        let pantilt = match &setup.head {
            Some((head, tilt_rad)) => {
                let head_dir = mav0.join("pantilt0");
                create_dir(&head_dir)?;
                other_bytes += write_text(&head_dir.join("sensor.yaml"), &pantilt_yaml(setup, head, *tilt_rad))?;
                Some(CsvFile::create(head_dir.join("data.csv"), PANTILT_HEADER)?)
            }
            None => None,
        };

        let gt_dir = mav0.join("state_groundtruth_estimate0");
        create_dir(&gt_dir)?;
        let gt_yaml = format!(
            "%YAML:1.0\nsensor_type: visual-inertial\ncomment: {}, exact simulated state of the body (IMU) \
             frame in the world frame; biases are the IMU's true biases\n",
            setup.label
        );
        other_bytes += write_text(&gt_dir.join("sensor.yaml"), &gt_yaml)?;
        let ground_truth = CsvFile::create(gt_dir.join("data.csv"), GROUND_TRUTH_HEADER)?;
        let tum = CsvFile::create(dir.join("groundtruth.tum"), TUM_HEADER)?;

        Ok(AslWriter {
            mav0,
            cam_data,
            cameras: [cam0, cam1],
            imu,
            wheel,
            pantilt,
            ground_truth,
            tum,
            line: String::with_capacity(512),
            png_bytes: Vec::new(),
            image_bytes: 0,
            other_bytes,
        })
    }

    /// The `mav0` folder.
    pub fn mav0(&self) -> &Path {
        &self.mav0
    }

    /// Writes both images of `frame` as `<stamp>.png` and their rows (and the head's angles).
    pub fn write_stereo(&mut self, frame: &StereoFrame) -> Result<(), AslError> {
        let name = format!("{}.png", frame.stamp_ns);
        for (i, image) in [&frame.left, &frame.right].into_iter().enumerate() {
            let path = self.cam_data[i].join(&name);
            encode_grey_png(&mut self.png_bytes, frame.width_px, frame.height_px, image, png::Compression::Fast)
                .map_err(|source| AslError::Png { path: path.clone(), source })?;
            fs::write(&path, &self.png_bytes).map_err(io_error(&path))?;
            self.image_bytes += self.png_bytes.len() as u64;
            self.line.clear();
            let _ = write!(self.line, "{},{name}", frame.stamp_ns);
            self.cameras[i].write_line(&self.line)?;
        }
        if let Some(pantilt) = self.pantilt.as_mut() {
            self.line.clear();
            let _ = write!(self.line, "{}", frame.stamp_ns);
            push_values(&mut self.line, &[frame.pan_rad, frame.tilt_rad]);
            pantilt.write_line(&self.line)?;
        }
        Ok(())
    }

    pub fn write_imu(&mut self, sample: &ImuSample) -> Result<(), AslError> {
        self.line.clear();
        let _ = write!(self.line, "{}", sample.stamp_ns);
        push_values(&mut self.line, sample.gyro_radps.as_slice());
        push_values(&mut self.line, sample.accel_mps2.as_slice());
        self.imu.write_line(&self.line)
    }

    pub fn write_wheel(&mut self, sample: &WheelOdomSample) -> Result<(), AslError> {
        let Some(wheel) = self.wheel.as_mut() else {
            return Err(AslError::Invalid("wheel odometry from a robot set up without it".to_owned()));
        };
        self.line.clear();
        let _ = write!(self.line, "{}", sample.stamp_ns);
        push_values(&mut self.line, sample.linear_mps.as_slice());
        push_values(&mut self.line, sample.angular_radps.as_slice());
        push_values(&mut self.line, &sample.sigma);
        wheel.write_line(&self.line)
    }

    /// One row of `state_groundtruth_estimate0/data.csv`.
    pub fn write_ground_truth(&mut self, sample: &GroundTruthSample) -> Result<(), AslError> {
        let pose = &sample.state.t_world_body;
        let q = pose.rotation.quaternion();
        self.line.clear();
        let _ = write!(self.line, "{}", sample.stamp_ns);
        push_values(&mut self.line, pose.translation.vector.as_slice());
        push_values(&mut self.line, &[q.w, q.i, q.j, q.k]);
        push_values(&mut self.line, sample.state.v_world_mps.as_slice());
        push_values(&mut self.line, sample.gyro_bias_radps.as_slice());
        push_values(&mut self.line, sample.accel_bias_mps2.as_slice());
        self.ground_truth.write_line(&self.line)
    }

    /// One row of `groundtruth.tum`.
    pub fn write_tum(&mut self, stamp_ns: u64, t_world_body: &Isometry3<f64>) -> Result<(), AslError> {
        let q = t_world_body.rotation.quaternion();
        let p = t_world_body.translation.vector;
        self.line.clear();
        push_seconds(&mut self.line, stamp_ns);
        for v in [p.x, p.y, p.z, q.i, q.j, q.k, q.w] {
            let _ = write!(self.line, " {v:?}");
        }
        self.tum.write_line(&self.line)
    }

    /// Flushes every file; the counts and bytes written (`elapsed_s` is left 0).
    pub fn finish(self) -> Result<RecordStats, AslError> {
        let stereo_pairs = self.cameras[0].rows;
        let imu_samples = self.imu.rows;
        let wheel_samples = self.wheel.as_ref().map_or(0, |w| w.rows);
        let ground_truth_rows = self.ground_truth.rows;
        let mut bytes = self.image_bytes + self.other_bytes;
        let [cam0, cam1] = self.cameras;
        for csv in
            [Some(cam0), Some(cam1), Some(self.imu), self.wheel, self.pantilt, Some(self.ground_truth), Some(self.tum)]
                .into_iter()
                .flatten()
        {
            bytes += csv.finish()?;
        }
        Ok(RecordStats { stereo_pairs, imu_samples, wheel_samples, ground_truth_rows, bytes, elapsed_s: 0.0 })
    }
}

/// Encodes an 8-bit grey image into `out` (cleared first).
pub fn encode_grey_png(
    out: &mut Vec<u8>,
    width_px: u32,
    height_px: u32,
    pixels: &[u8],
    compression: png::Compression,
) -> Result<(), png::EncodingError> {
    encode_png(out, width_px, height_px, png::ColorType::Grayscale, pixels, compression)
}

/// Encodes an 8-bit image of `color` into `out` (cleared first).
pub fn encode_png(
    out: &mut Vec<u8>,
    width_px: u32,
    height_px: u32,
    color: png::ColorType,
    pixels: &[u8],
    compression: png::Compression,
) -> Result<(), png::EncodingError> {
    out.clear();
    let mut encoder = png::Encoder::new(&mut *out, width_px, height_px);
    encoder.set_color(color);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.set_compression(compression);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(pixels)?;
    writer.finish()
}

/// Records robot `robot` of `world` into `dir` (see the module docs) by running its
/// [`SimSensorSource`] to the end; `progress` gets the stamp of every stereo pair written.
pub fn record_robot(
    world: &Arc<World>,
    robot: usize,
    dir: &Path,
    mut progress: impl FnMut(u64),
) -> Result<RecordStats, AslError> {
    let start = Instant::now();
    let setup = SensorSetup::of(world, robot)?;
    let mut source = SimSensorSource::new(Arc::clone(world), robot)?;
    let mut writer = AslWriter::create(dir, &setup)?;
    let mut frame = StereoFrame::default();
    while let Some(event) = hal::sensor::next_event_with_frame(&mut source, &mut frame)? {
        match event {
            SensorEvent::Imu(sample) => {
                writer.write_imu(&sample)?;
                let truth = source.ground_truth(sample.stamp_ns).ok_or_else(|| {
                    AslError::Invalid(format!("robot {robot}: no ground truth at IMU stamp {} ns", sample.stamp_ns))
                })?;
                writer.write_ground_truth(&truth)?;
            }
            SensorEvent::WheelOdom(sample) => writer.write_wheel(&sample)?,
            SensorEvent::Stereo(_) => {
                writer.write_stereo(&frame)?;
                let state = world.robot_state(robot, frame.stamp_ns).ok_or_else(|| {
                    AslError::Invalid(format!("robot {robot}: no state at camera stamp {} ns", frame.stamp_ns))
                })?;
                writer.write_tum(frame.stamp_ns, &state.t_world_body)?;
                progress(frame.stamp_ns);
            }
        }
    }
    let mut stats = writer.finish()?;
    stats.elapsed_s = start.elapsed().as_secs_f64();
    Ok(stats)
}

/// The folder of robot `robot`'s dataset under a run's output folder: `robot<id>`.
pub fn robot_dir(world: &World, out: &Path, robot: usize) -> PathBuf {
    let id = world.robots.get(robot).map_or(robot, |r| usize::from(r.setup.id));
    out.join(format!("robot{id}"))
}

/// Records every robot into [`robot_dir`] and the world into `out/world`, robots on up to
/// `threads` threads (the files do not depend on the thread count). `progress(robot, stamp_ns)`
/// is called from the recording threads.
pub fn record_run(
    world: &Arc<World>,
    out: &Path,
    threads: usize,
    progress: &(dyn Fn(usize, u64) + Sync),
) -> Result<(Vec<RecordStats>, WorldFiles), AslError> {
    let world_files = write_world(world, &out.join("world"))?;
    let robots = world.robots.len();
    let next = std::sync::atomic::AtomicUsize::new(0);
    // Each thread takes the next robot until none is left; which thread records which robot
    // does not matter, every robot's files depend on the world alone.
    let worker = || {
        let mut done = Vec::new();
        loop {
            let robot = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            if robot >= robots {
                return done;
            }
            let result = record_robot(world, robot, &robot_dir(world, out, robot), |stamp| progress(robot, stamp));
            done.push((robot, result));
        }
    };
    let mut results: Vec<Option<Result<RecordStats, AslError>>> = (0..robots).map(|_| None).collect();
    std::thread::scope(|scope| {
        let handles: Vec<_> = (0..threads.clamp(1, robots.max(1))).map(|_| scope.spawn(worker)).collect();
        for handle in handles {
            // A panicking thread leaves its robots unrecorded; reported below.
            for (robot, result) in handle.join().unwrap_or_default() {
                results[robot] = Some(result);
            }
        }
    });
    let mut stats = Vec::with_capacity(robots);
    for (robot, result) in results.into_iter().enumerate() {
        match result {
            Some(result) => stats.push(result?),
            None => return Err(AslError::Invalid(format!("robot {robot} was not recorded (its thread panicked)"))),
        }
    }
    Ok((stats, world_files))
}
