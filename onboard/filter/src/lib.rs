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
//! - Error state `δ = (δp, δv, δθ, δb_a, δb_g)` ∈ R^15 (eq. 4.2), in that order.
//! - Relative-pose measurements use the covariance convention of `vision`: `[δt; δθ]`,
//!   translation in the earlier body frame, rotation right-multiplied.
//!
//! This crate does no I/O.

pub mod config;
pub mod eskf;
pub mod health;
pub mod switch;
pub mod zupt;

pub use config::FilterConfig;
pub use eskf::{Filter, FilterError, FilterState, RelativePoseMeasurement, UpdateOutcome};
pub use health::FilterHealth;
pub use switch::FrameSwitch;
