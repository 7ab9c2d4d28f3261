//! Sensor interfaces: what a rover's drivers deliver to the on-board software, whatever is behind
//! them (the real cameras and IMU, the simulator, or a recorded dataset).
//!
//! # Frames and units
//!
//! - Body frame `body`: x forward, y left, z up; it is also the IMU frame (as in EuRoC, where the
//!   body frame is the IMU frame).
//! - Camera frame `cam`: the optical frame of the *left* rectified camera, x right, y down, z
//!   along the optical axis. The right camera sits at `+baseline_m` along the left camera's x.
//! - Timestamps are nanoseconds on the robot's clock (`stamp_ns`); a stereo frame's stamp is its
//!   capture (mid-exposure) time.
//!
//! A [`SensorSource`] yields events in non-decreasing timestamp order. A stereo pair is announced
//! by its [`StereoInfo`] and its pixels are then written by [`SensorSource::read_stereo`] straight
//! into memory the caller chooses (the driver: a loaned shared-memory sample), so the image is
//! rendered or decoded once, where its readers read it, and nothing is allocated per frame.

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Pinhole intrinsics of one camera, in pixels.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pinhole {
    pub fx_px: f64,
    pub fy_px: f64,
    pub cx_px: f64,
    pub cy_px: f64,
}

/// Lens distortion of a raw (unrectified) camera.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Distortion {
    /// Already rectified (or an ideal pinhole).
    None,
    /// Radial-tangential (plumb bob) `[k1, k2, p1, p2]`, as in EuRoC's `sensor.yaml`.
    RadTan([f64; 4]),
}

/// Calibration of one camera of a stereo pair.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CameraCalibration {
    pub width_px: u32,
    pub height_px: u32,
    pub intrinsics: Pinhole,
    pub distortion: Distortion,
    /// Camera pose in the body frame when the pan-tilt head is at pan = tilt = 0 (or the fixed
    /// mounting when there is no head). With a head, use [`StereoCalibration::t_body_left`] with
    /// the frame's pan and tilt.
    pub t_body_cam: Isometry3<f64>,
}

/// Rotation from the optical frame (x right, y down, z forward) to a forward-left-up frame.
pub fn r_flu_optical() -> Rotation3<f64> {
    // Columns: the optical axes expressed in forward-left-up coordinates.
    Rotation3::from_matrix_unchecked(Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0))
}

/// Kinematics of a pan-tilt camera head on a mast.
///
/// The pan axis is the body's z axis through `pan_axis_body_m`; the tilt axis is the panned y
/// axis; **positive tilt looks down**. At pan = tilt = 0 the cameras look along the body's x
/// axis. The stereo pair's centre sits at `stereo_centre_head_m` in the head frame
/// (forward-left-up after pan and tilt), the left camera `baseline_m / 2` to its left.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PanTiltHead {
    /// Where the pan and tilt axes cross, in the body frame.
    pub pan_axis_body_m: Vector3<f64>,
    pub stereo_centre_head_m: Vector3<f64>,
    pub baseline_m: f64,
    /// Mechanical limits; angles beyond them are clamped.
    pub pan_limit_rad: f64,
    pub tilt_limit_rad: f64,
}

impl PanTiltHead {
    /// The LRU-like head (thesis §7.1: pan ±180°, tilt ±90°, 9 cm baseline): axes 1.05 m above
    /// and 0.30 m ahead of the chassis centre (about 1.4 m above the ground), cameras 6 cm in
    /// front of the tilt axis.
    pub fn lru() -> Self {
        PanTiltHead {
            pan_axis_body_m: Vector3::new(0.30, 0.0, 1.05),
            stereo_centre_head_m: Vector3::new(0.06, 0.0, 0.0),
            baseline_m: 0.09,
            pan_limit_rad: std::f64::consts::PI,
            tilt_limit_rad: std::f64::consts::FRAC_PI_2,
        }
    }

    /// Pose of the left camera's optical frame in the body frame, angles clamped to the limits.
    pub fn t_body_cam(&self, pan_rad: f64, tilt_rad: f64) -> Isometry3<f64> {
        let pan = pan_rad.clamp(-self.pan_limit_rad, self.pan_limit_rad);
        let tilt = tilt_rad.clamp(-self.tilt_limit_rad, self.tilt_limit_rad);
        let r_body_head =
            Rotation3::from_axis_angle(&Vector3::z_axis(), pan) * Rotation3::from_axis_angle(&Vector3::y_axis(), tilt);
        let left_lens_head = self.stereo_centre_head_m + Vector3::new(0.0, 0.5 * self.baseline_m, 0.0);
        let t = self.pan_axis_body_m + r_body_head * left_lens_head;
        let r = r_body_head * r_flu_optical();
        Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_rotation_matrix(&r))
    }
}

/// What a consumer needs to know about a stereo head.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoCalibration {
    pub left: CameraCalibration,
    pub right: CameraCalibration,
    /// True when the images are rectified: same intrinsics, no distortion, right camera at
    /// `+baseline_m` along the left camera's x axis.
    pub rectified: bool,
    /// Distance between the two optical centres.
    pub baseline_m: f64,
    /// The pan-tilt head the pair sits on, if any; frames then carry the head's angles.
    pub head: Option<PanTiltHead>,
}

impl StereoCalibration {
    /// Pose of the left camera in the body frame at the given head angles (the fixed mounting
    /// without a head).
    pub fn t_body_left(&self, pan_rad: f64, tilt_rad: f64) -> Isometry3<f64> {
        match &self.head {
            Some(head) => head.t_body_cam(pan_rad, tilt_rad),
            None => self.left.t_body_cam,
        }
    }
}

/// A synchronised stereo pair, 8-bit greyscale, row-major, `width × height` each.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct StereoFrame {
    pub stamp_ns: u64,
    /// Frame counter of the camera (gaps mean dropped frames).
    pub sequence: u64,
    pub width_px: u32,
    pub height_px: u32,
    pub left: Vec<u8>,
    pub right: Vec<u8>,
    /// Pan and tilt of the camera head at capture time (0 without a head).
    pub pan_rad: f64,
    pub tilt_rad: f64,
}

impl StereoFrame {
    /// The frame's metadata.
    pub fn info(&self) -> StereoInfo {
        StereoInfo {
            stamp_ns: self.stamp_ns,
            sequence: self.sequence,
            width_px: self.width_px,
            height_px: self.height_px,
            pan_rad: self.pan_rad,
            tilt_rad: self.tilt_rad,
        }
    }

    /// Resizes both images to `width × height` (keeping their allocation when it is big enough).
    pub fn resize(&mut self, width_px: u32, height_px: u32) {
        let len = width_px as usize * height_px as usize;
        self.width_px = width_px;
        self.height_px = height_px;
        self.left.resize(len, 0);
        self.right.resize(len, 0);
    }
}

/// One IMU sample in the IMU (= body) frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    pub stamp_ns: u64,
    /// Angular velocity of the body relative to the inertial frame, in the body frame.
    pub gyro_radps: Vector3<f64>,
    /// Specific force (acceleration minus gravity) in the body frame: `+g` up when at rest.
    pub accel_mps2: Vector3<f64>,
}

/// One wheel odometry sample: the body twist the wheel encoders and steering angles imply.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelOdomSample {
    pub stamp_ns: u64,
    /// Linear velocity of the body, in the body frame.
    pub linear_mps: Vector3<f64>,
    /// Angular velocity of the body, in the body frame.
    pub angular_radps: Vector3<f64>,
    /// Standard deviations of `[linear x, y, z, angular x, y, z]` the odometry itself claims.
    pub sigma: [f64; 6],
}

/// A stereo pair announced by [`SensorSource::next_event`], before its pixels are read.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoInfo {
    /// Capture (mid-exposure) time.
    pub stamp_ns: u64,
    /// Frame counter of the camera (gaps mean dropped frames).
    pub sequence: u64,
    pub width_px: u32,
    pub height_px: u32,
    /// Pan and tilt of the camera head at capture time (0 without a head).
    pub pan_rad: f64,
    pub tilt_rad: f64,
}

impl StereoInfo {
    /// Pixels per image, `None` if the size overflows.
    pub fn pixels(&self) -> Option<usize> {
        usize::try_from(self.width_px).ok()?.checked_mul(usize::try_from(self.height_px).ok()?)
    }
}

/// What [`SensorSource::next_event`] produced.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum SensorEvent {
    /// A new pair; [`SensorSource::read_stereo`] writes its pixels.
    Stereo(StereoInfo),
    Imu(ImuSample),
    WheelOdom(WheelOdomSample),
}

impl SensorEvent {
    /// The event's time stamp.
    pub fn stamp_ns(&self) -> u64 {
        match self {
            SensorEvent::Stereo(info) => info.stamp_ns,
            SensorEvent::Imu(sample) => sample.stamp_ns,
            SensorEvent::WheelOdom(sample) => sample.stamp_ns,
        }
    }
}

/// Why a sensor source failed. The end of a recording is `Ok(None)`, not an error.
#[derive(Debug, thiserror::Error)]
pub enum SensorError {
    #[error("{context}: {source}")]
    Io {
        context: String,
        #[source]
        source: std::io::Error,
    },
    /// A file of a dataset could not be understood; `context` names file and line.
    #[error("{context}: {reason}")]
    Format { context: String, reason: String },
    /// The simulator or device could not produce the data.
    #[error("sensor source: {0}")]
    Source(String),
}

/// A source of time-ordered sensor events: a driver, the simulator or a dataset replay.
pub trait SensorSource {
    /// Calibration of the stereo head (`None` for a source without cameras).
    fn stereo_calibration(&self) -> Option<StereoCalibration>;

    /// The next event in timestamp order, or `Ok(None)` when the source is exhausted. A stereo
    /// pair is announced as [`SensorEvent::Stereo`]; its pixels come from [`Self::read_stereo`]
    /// (a pair not read before the next call is skipped: nothing is rendered or decoded).
    fn next_event(&mut self) -> Result<Option<SensorEvent>, SensorError>;

    /// Writes the pixels of the pair announced last into `left` and `right` (row-major, each
    /// exactly `width × height` of its [`StereoInfo`]). An error if no pair is pending or a
    /// buffer has another size.
    fn read_stereo(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), SensorError>;

    /// A live source (the rover's devices) is never exhausted: `next_event` returns `Ok(None)`
    /// when nothing is due *yet*, and its stamps are the host's `CLOCK_MONOTONIC` nanoseconds.
    fn is_live(&self) -> bool {
        false
    }

    /// What a live source knows about its devices; `None` for recorded sources.
    fn device_health(&self) -> Option<DeviceHealth> {
        None
    }

    /// A live source's device changes: (stamp on its clock, what happened), oldest first.
    fn device_log(&self) -> Vec<(u64, String)> {
        Vec::new()
    }

    /// Sends the pan-tilt head towards `target`. `Ok(false)` when the source has no head it
    /// can move (a recorded dataset, a fixed camera): the pairs keep the angles they were
    /// recorded with. Pairs announced after the command carry the angles the head really had.
    fn command_head(&mut self, target: &HeadTarget) -> Result<bool, SensorError> {
        let _ = target;
        Ok(false)
    }
}

/// Where a gaze policy wants the pan-tilt head ([`SensorSource::command_head`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadTarget {
    /// When the command was given, on the source's clock.
    pub stamp_ns: u64,
    /// Pan about the body's z axis (left positive) and tilt about the head's y axis (down
    /// positive), as [`PanTiltHead::t_body_cam`].
    pub pan_rad: f64,
    pub tilt_rad: f64,
    /// The fastest either joint may move.
    pub max_rate_radps: f64,
}

/// One device of a live source, as its driver sees it.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeviceStatus {
    /// Delivering now.
    pub available: bool,
    /// Samples delivered since start.
    pub samples: u64,
    /// Times the device went from available to unavailable.
    pub dropouts: u64,
    /// Frames rejected (checksum, malformed) and transport errors.
    pub errors: u64,
}

/// The devices behind a live source.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeviceHealth {
    pub imu: DeviceStatus,
    pub wheels: DeviceStatus,
    pub head: DeviceStatus,
}

impl<S: SensorSource + ?Sized> SensorSource for Box<S> {
    fn stereo_calibration(&self) -> Option<StereoCalibration> {
        (**self).stereo_calibration()
    }

    fn next_event(&mut self) -> Result<Option<SensorEvent>, SensorError> {
        (**self).next_event()
    }

    fn read_stereo(&mut self, left: &mut [u8], right: &mut [u8]) -> Result<(), SensorError> {
        (**self).read_stereo(left, right)
    }

    fn is_live(&self) -> bool {
        (**self).is_live()
    }

    fn device_health(&self) -> Option<DeviceHealth> {
        (**self).device_health()
    }

    fn device_log(&self) -> Vec<(u64, String)> {
        (**self).device_log()
    }

    fn command_head(&mut self, target: &HeadTarget) -> Result<bool, SensorError> {
        (**self).command_head(target)
    }
}

/// Reads the announced pair `info` into `frame` (resized as needed, metadata set): for consumers
/// that keep frames of their own.
pub fn read_stereo_frame<S: SensorSource + ?Sized>(
    source: &mut S,
    info: &StereoInfo,
    frame: &mut StereoFrame,
) -> Result<(), SensorError> {
    frame.resize(info.width_px, info.height_px);
    source.read_stereo(&mut frame.left, &mut frame.right)?;
    frame.stamp_ns = info.stamp_ns;
    frame.sequence = info.sequence;
    frame.pan_rad = info.pan_rad;
    frame.tilt_rad = info.tilt_rad;
    Ok(())
}

/// The next event of `source`, with a stereo pair read into `frame` straight away: for consumers
/// that keep every frame of their own (tests, offline tools).
pub fn next_event_with_frame<S: SensorSource + ?Sized>(
    source: &mut S,
    frame: &mut StereoFrame,
) -> Result<Option<SensorEvent>, SensorError> {
    let event = source.next_event()?;
    if let Some(SensorEvent::Stereo(info)) = &event {
        read_stereo_frame(source, info, frame)?;
    }
    Ok(event)
}

/// The check every source makes before writing a pair: both buffers of the announced size.
pub fn check_stereo_buffers(info: &StereoInfo, left: &[u8], right: &[u8]) -> Result<(), SensorError> {
    let n = info.pixels();
    if n != Some(left.len()) || n != Some(right.len()) {
        return Err(SensorError::Source(format!(
            "stereo buffers of {} and {} bytes for a {}x{} pair",
            left.len(),
            right.len(),
            info.width_px,
            info.height_px
        )));
    }
    Ok(())
}

/// The error of a [`SensorSource::read_stereo`] call with no pair announced.
pub fn no_pending_pair() -> SensorError {
    SensorError::Source("read_stereo: no stereo pair was announced".into())
}
