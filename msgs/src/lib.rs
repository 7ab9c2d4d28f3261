//! Bus payloads of the rover firmware (DESIGN §4): every message that crosses a process boundary
//! on the rover, as `#[repr(C)]` plain data that lives in iceoryx2 shared memory.
//!
//! - Every type is `Copy`, has no pointers and no padding (`bytemuck::Pod`), so a payload can be
//!   recorded as its exact bytes and read back with a total, checked cast ([`bytemuck::try_from_bytes`]).
//! - Every type carries a versioned iceoryx2 type name (`rover.Imu.v1`): a publisher and a
//!   subscriber built from different layouts refuse to connect instead of misreading memory.
//! - Images and disparity maps are slice payloads (`[u8]`, [`DisparityPixel`]) with a fixed-size
//!   user header ([`StereoHeader`], [`DisparityHeader`]): written once into shared memory by their
//!   producer and read in place by every consumer.
//! - Poses are `t_a_b` ([`Pose`]: translation in m, unit quaternion `[w, x, y, z]`), covariances
//!   are row-major 6×6 ordered `[translation, rotation]` as in the algorithm crates.

mod convert;
mod types;

pub use convert::*;
pub use types::*;
