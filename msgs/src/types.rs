//! The payload types, one per topic (see the crate documentation and DESIGN §4).

use bytemuck::{Pod, Zeroable};
use iceoryx2::prelude::ZeroCopySend;

/// A rigid transform `t_a_b`: translation in metres, unit quaternion `[w, x, y, z]`.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.Pose.v1")]
pub struct Pose {
    pub translation_m: [f64; 3],
    pub rotation_wxyz: [f64; 4],
}

/// Row-major 6×6 covariance ordered `[translation, rotation]`.
pub type Covariance6 = [f64; 36];

/// `sensors/imu`: one IMU sample in the body frame, numbered by the driver so the filter can
/// prove that none was lost between them.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.Imu.v1")]
pub struct ImuMsg {
    pub stamp_ns: u64,
    /// Consecutive from 0 for the driver's run; a gap is a lost sample.
    pub sequence: u64,
    pub gyro_radps: [f64; 3],
    /// Specific force (`+g` up at rest).
    pub accel_mps2: [f64; 3],
}

/// `sensors/wheel_odom`: the body twist the wheel encoders imply.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.WheelOdom.v1")]
pub struct WheelOdomMsg {
    pub stamp_ns: u64,
    pub sequence: u64,
    pub linear_mps: [f64; 3],
    pub angular_radps: [f64; 3],
    /// Standard deviations of `[linear x, y, z, angular x, y, z]`.
    pub sigma: [f64; 6],
}

/// `sensors/stereo` user header. The slice payload is `[u8]` of length `2 · width · height`: the
/// left image's rows, then the right image's rows (rectified, 8-bit grey).
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend, Default)]
#[repr(C)]
#[type_name("rover.StereoHeader.v1")]
pub struct StereoHeader {
    /// Capture (trigger) time.
    pub stamp_ns: u64,
    /// Camera frame counter; gaps are dropped frames.
    pub sequence: u64,
    pub pan_rad: f64,
    pub tilt_rad: f64,
    pub width_px: u32,
    pub height_px: u32,
}

/// `vision/disparity` user header. The slice payload is `[DisparityPixel]` of `width · height`.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend, Default)]
#[repr(C)]
#[type_name("rover.DisparityHeader.v1")]
pub struct DisparityHeader {
    /// Capture time of the stereo pair it was computed from.
    pub stamp_ns: u64,
    pub sequence: u64,
    pub pan_rad: f64,
    pub tilt_rad: f64,
    pub width_px: u32,
    pub height_px: u32,
}

/// One pixel of a disparity map: the SGM core's output and the obstacle classification's labels.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.DisparityPixel.v1")]
pub struct DisparityPixel {
    /// Disparity with 4 fractional bits (`fpga_model`'s format); [`DisparityPixel::INVALID`] when
    /// the core found no match.
    pub disparity_q4: u16,
    /// `vision::obstacles::PixelLabels` flags.
    pub labels: u8,
    pub reserved: u8,
}

impl DisparityPixel {
    /// The invalid disparity (same value as `fpga_model::INVALID`).
    pub const INVALID: u16 = u16::MAX;
}

/// `vision/vo_delta`: the keyframe stereo odometry's result for one frame.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.VoDelta.v2")]
pub struct VoDeltaMsg {
    /// Capture time of the frame.
    pub capture_stamp_ns: u64,
    /// Capture time of the keyframe the delta is relative to (valid with [`VoDeltaMsg::HAS_DELTA`]).
    pub keyframe_stamp_ns: u64,
    /// Body pose at capture in the body frame at the keyframe.
    pub t_keyframe_current_body: Pose,
    pub covariance_body: Covariance6,
    /// The odometry's own chained body pose (in its first keyframe's frame; after a tracking loss
    /// continued by prediction): the trajectory of a robot without IMU.
    pub t_odom_body: Pose,
    pub inliers: u32,
    /// [`VoDeltaMsg::HAS_DELTA`], [`VoDeltaMsg::NEW_KEYFRAME`], [`VoDeltaMsg::RESET`].
    pub flags: u32,
}

impl VoDeltaMsg {
    pub const HAS_DELTA: u32 = 1;
    pub const NEW_KEYFRAME: u32 = 2;
    pub const RESET: u32 = 4;
}

/// `vision/markers`: one detected AprilTag (thesis §6.2), with the pose of the better PnP solution
/// and the uncertainty model's covariance.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.Marker.v2")]
pub struct MarkerMsg {
    pub capture_stamp_ns: u64,
    /// The left camera in the body frame at the capture (the pan-tilt head's angles applied).
    pub t_body_cam: Pose,
    /// Marker pose in the left rectified camera frame (x right, y down, z forward; marker frame x
    /// to the tag's right, y to its top, z out of its face).
    pub t_cam_marker: Pose,
    /// Covariance of `t_cam_marker`, ordered `[δt; δθ]` in the camera's axes:
    /// `t_true = t̂ + δt`, `R_true = Exp(δθ) · R̂` (`vision::marker_pose`'s error convention).
    pub covariance_cam: Covariance6,
    /// The tag's corners in the image it was detected in (pixel centres at integers; the
    /// upstream AprilTag corner order).
    pub corners_px: [[f32; 2]; 4],
    pub tag_id: u32,
    /// Bits corrected by the decoder.
    pub hamming: u32,
    pub decision_margin: f32,
    /// Reprojection error of the worse PnP solution over the better one's (≥ 1; near 1 the
    /// planar pose is ambiguous).
    pub ambiguity_ratio: f32,
    /// Distance and signed tilt the uncertainty table was read at.
    pub distance_m: f32,
    pub tilt_rad: f32,
    /// [`MarkerMsg::LEFT`] or [`MarkerMsg::RIGHT`]: the image of the detection.
    pub camera: u32,
    /// The uncertainty model that gave `covariance_cam` (`vision::marker_pose` model code).
    pub model: u32,
}

impl MarkerMsg {
    pub const LEFT: u32 = 0;
    pub const RIGHT: u32 = 1;
}

/// `filter/state`: the local reference filter's estimate after one IMU sample.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.FilterState.v2")]
pub struct FilterStateMsg {
    pub stamp_ns: u64,
    /// Body pose in the current local frame.
    pub t_local_body: Pose,
    pub v_local_mps: [f64; 3],
    pub accel_bias_mps2: [f64; 3],
    pub gyro_bias_radps: [f64; 3],
    /// Pose covariance, filter convention `[δt local; δθ body]`.
    pub pose_covariance: Covariance6,
    /// IMU samples the filter has received, and the sequence gaps it saw (lost samples).
    pub imu_received: u64,
    pub imu_lost: u64,
    /// Id of the current local frame (incremented by every frame switch).
    pub frame_id: u32,
    /// [`FilterStateMsg::INITIALIZING`] or [`FilterStateMsg::RUNNING`].
    pub status: u32,
    /// Capture stamp of the last visual-odometry result the filter applied
    /// ([`FilterStateMsg::NEVER`]: none yet).
    pub last_vo_capture_ns: u64,
}

impl FilterStateMsg {
    pub const INITIALIZING: u32 = 0;
    pub const RUNNING: u32 = 1;
    /// A stamp that has not happened.
    pub const NEVER: u64 = u64::MAX;
}

/// `mapper/frame_switch_request`: the mapper asks the filter to start a new local frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.FrameSwitchRequest.v1")]
pub struct FrameSwitchRequestMsg {
    /// Stamp of the filter state that triggered the request.
    pub stamp_ns: u64,
    /// The frame that should end; the filter ignores a request for a frame that already ended
    /// (a repeated request after a restart must not switch twice).
    pub frame_id: u32,
    pub reserved: u32,
}

/// `filter/frame_switch`: a frame switch the filter performed.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.FrameSwitch.v1")]
pub struct FrameSwitchMsg {
    pub stamp_ns: u64,
    /// The new frame's origin in the old frame.
    pub t_old_new: Pose,
    /// Covariance of `t_old_new`, graph convention.
    pub covariance: Covariance6,
    pub old_frame_id: u32,
    pub new_frame_id: u32,
}

/// `mapper/to_comms` and `comms/to_mapper` user header. The slice payload is one
/// `protocol`-encoded message (postcard, no framing): the mapper speaks the team protocol, the
/// comms process only frames, schedules and carries it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Pod, Zeroable, ZeroCopySend, Default)]
#[repr(C)]
#[type_name("rover.TeamHeader.v1")]
pub struct TeamHeader {
    pub stamp_ns: u64,
    /// Sending robot (`to_mapper`) or destination robot (`to_comms`; [`TeamHeader::BROADCAST`]
    /// for every peer and the ground station).
    pub robot_id: u32,
    /// `protocol::MessageKey` of the payload.
    pub message_key: u32,
}

impl TeamHeader {
    pub const BROADCAST: u32 = u32::MAX;
}

/// `control/head`: where the gaze policy wants the pan-tilt head. The driver passes it to the
/// head (a CANopen RPDO on a rover, the simulator's head model in SIL); the angles the head
/// actually had at a capture come back in the [`StereoHeader`].
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend, Default)]
#[repr(C)]
#[type_name("rover.HeadCommand.v1")]
pub struct HeadCommandMsg {
    /// When the policy decided (sensor time).
    pub stamp_ns: u64,
    pub sequence: u64,
    /// Target joint angles: pan about the body's z axis (left positive), tilt about the head's
    /// y axis (down positive).
    pub pan_rad: f64,
    pub tilt_rad: f64,
    /// The fastest either joint may move to get there.
    pub max_rate_radps: f64,
    /// Why: [`HeadCommandMsg::LOOK_AHEAD`], [`HeadCommandMsg::LOOK_DOWN`] or
    /// [`HeadCommandMsg::SWEEP`].
    pub mode: u32,
    pub reserved: u32,
}

impl HeadCommandMsg {
    /// Driving: the far look that VO and mapping want.
    pub const LOOK_AHEAD: u32 = 0;
    /// Driving: the near look at the ground within stopping distance.
    pub const LOOK_DOWN: u32 = 1;
    /// Standing: the pan sweep around the rover.
    pub const SWEEP: u32 = 2;
}

/// Hazard cells a [`HazardCellsMsg`] carries at most (the nearest first).
pub const HAZARD_CELLS_MAX: usize = 960;

/// `vision/hazards`: the hazard cells of the rolling local obstacle map around the robot,
/// published about once a second for the ground station.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.HazardCells.v1")]
pub struct HazardCellsMsg {
    pub stamp_ns: u64,
    /// The body at `stamp_ns` in the filter's local frame `frame_id`, the frame of the cells.
    pub t_local_body: Pose,
    pub frame_id: u32,
    /// Edge of a cell.
    pub cell_size_m: f32,
    /// Lattice index of the cell holding the body: a listed cell `[di, dj]` has its centre at
    /// `((origin_cell[0] + di + ½)·cell_size_m, (origin_cell[1] + dj + ½)·cell_size_m)` in the
    /// local frame.
    pub origin_cell: [i32; 2],
    /// Valid entries of `cells`; `omitted` hazard cells farther away did not fit.
    pub count: u32,
    pub omitted: u32,
    pub cells: [[i16; 2]; HAZARD_CELLS_MAX],
}

/// Which process a [`TaskStatsMsg`] comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ProcessKind {
    Driver = 0,
    Vision = 1,
    Filter = 2,
    Mapper = 3,
    Comms = 4,
    Supervisor = 5,
}

/// `telemetry/tasks`: one fixed-rate task's counters, published about once a second.
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable, ZeroCopySend)]
#[repr(C)]
#[type_name("rover.TaskStats.v3")]
pub struct TaskStatsMsg {
    pub stamp_ns: u64,
    pub period_ns: u64,
    pub deadline_ns: u64,
    pub releases: u64,
    /// Runs that finished after their deadline.
    pub overruns: u64,
    /// Releases skipped because the previous run overran past them.
    pub skipped: u64,
    /// Release jitter (start − planned release) over the task's life.
    pub jitter_p50_ns: u64,
    pub jitter_p99_ns: u64,
    pub jitter_max_ns: u64,
    /// Longest run time.
    pub execution_max_ns: u64,
    /// CPU time of the whole process so far.
    pub process_cpu_ns: u64,
    pub process_rss_bytes: u64,
    /// [`ProcessKind`] as `u32`.
    pub process: u32,
    /// Index of the task within its process.
    pub task: u32,
    /// The fullest receive queue of the process since the last report: the topic's recording
    /// code (0: none), the most messages waiting in it at once, and its capacity (0: unbounded).
    pub queue_topic: u32,
    pub queue_depth_max: u32,
    pub queue_capacity: u32,
    /// The driver's devices ([`Self::DEVICES_REPORTED`] and one bit per available device); 0
    /// from every other process and from sources without devices.
    pub devices: u32,
}

impl TaskStatsMsg {
    /// `period_ns` of a report from a node without a fixed-rate task (the lockstep runner): its
    /// timing fields mean nothing, its CPU and memory are measured.
    pub const NO_TASK: u64 = 0;
    /// `devices`: the process reads devices (the bits below mean something).
    pub const DEVICES_REPORTED: u32 = 1 << 31;
    pub const DEVICE_IMU: u32 = 1;
    pub const DEVICE_WHEELS: u32 = 1 << 1;
    pub const DEVICE_HEAD: u32 = 1 << 2;
}
