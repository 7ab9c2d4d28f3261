//! Local reference filter (thesis §4.1): a keyframe error-state EKF that fuses IMU, stereo
//! visual odometry and wheel odometry, with state cloning for keyframes and delay compensation,
//! and frame-of-reference switching of x, y, z and yaw.
//!
//! # Frames and conventions
//!
//! - Local navigation frame `local`: gravity-aligned (z up), the origin of the current submap.
//!   Every frame switch starts a new one at the body's current x, y, z and yaw.
//! - Body frame = IMU frame (x forward, y left, z up), as in `hal::sensor`.
//! - Nominal state `x = (p, v, q, b_a, b_g)` (eq. 4.1): position and velocity of the body in
//!   `local`, orientation `q = q_local_body`, accelerometer and gyro biases.
//! - Error state `δ = (δp, δv, δθ, δb_a, δb_g)` ∈ R^15 (eq. 4.2), in that order; `δθ` is the
//!   global (left) attitude error, `q_true = Exp(δθ)·q̂`, in the local frame (see [`eskf`]).
//! - Relative-pose measurements use the covariance convention of `vision`: `[δt; δθ]`,
//!   translation in the earlier body frame, rotation right-multiplied.
//!
//! # Usage
//!
//! Feed every IMU sample to [`Filter::propagate`]; call [`Filter::clone_at`] at each image trigger,
//! [`Filter::mark_keyframe`] when the odometry makes that frame a keyframe, and
//! [`Filter::update_relative_pose`] when its delta arrives (it may be ~250 ms late: the clones
//! carry the correction to the current state). Wheel samples go to
//! [`Filter::update_wheel_odometry`]; while [`StandstillDetector::is_standing`], call
//! [`Filter::update_zero_velocity`]. [`Filter::switch_frame`] starts a new local frame.
//!
//! This crate does no I/O.

pub mod chi2;
mod clones;
pub mod config;
pub mod eskf;
pub mod health;
#[cfg(test)]
mod jacobian_checks;
pub mod math;
#[cfg(test)]
#[path = "../../graph/src/numdiff.rs"]
mod numdiff;
mod propagate;
mod snapshot;
pub mod switch;
mod updates;
pub mod zupt;

pub use config::{FilterConfig, ImuNoise, InitialSigmas};
pub use eskf::{Filter, FilterError, FilterState, RelativePoseMeasurement, UpdateOutcome};
pub use health::{FilterHealth, GateCounters};
pub use snapshot::{CloneSnapshot, FilterSnapshot};
pub use switch::FrameSwitch;
pub use zupt::{StandstillConfig, StandstillDetector};
