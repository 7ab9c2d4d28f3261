//! Software-in-the-loop world for rover teams, with ground truth.
//!
//! A [`scenario::Scenario`] names a site (terrain preset, sun, gravity) and a team of robots with
//! their paths; [`world::World::build`] turns it, deterministically for its seed, into terrain,
//! trajectories and sensor models; [`driver::SimSensorSource`] streams one robot's stereo, IMU and
//! wheel odometry through `hal`'s [`hal::sensor::SensorSource`] interface, so the on-board
//! software cannot tell the simulator from hardware; [`asl`] writes a run as EuRoC/ASL datasets.
//!
//! # Frames and units (used throughout the crate)
//!
//! - `world`: x east, y north, z up, metres; gravity is `-z`. The terrain's heights are world z.
//! - `body`: x forward, y left, z up, at the chassis centre; it is also the IMU frame.
//! - `cam`: the left camera's optical frame, x right, y down, z forward (see [`camera`]).
//! - `marker`: an AprilTag's centre, x to the tag's right, y to the tag's top, z out of its face.
//! - Poses are `t_a_b: Isometry3<f64>`, the pose of frame `b` in frame `a` (maps b-coordinates to
//!   a-coordinates). Times are `stamp_ns: u64` since the start of the run.
//! - Orientation of trajectories: yaw-pitch-roll, `R = Rz(yaw) · Ry(pitch) · Rx(roll)`.

pub mod allan;
pub mod asl;
pub mod body;
pub mod camera;
pub mod driver;
pub mod head_servo;
pub mod imu;
pub mod lighting;
pub mod markers;
pub mod motion;
pub mod noise;
pub mod pictures;
pub mod radio;
pub mod render;
pub mod rng;
pub mod robot;
pub mod scenario;
pub mod se3;
pub mod terrain;
pub mod trajectory;
pub mod truth_constraints;
pub mod wheel;
pub mod world;
