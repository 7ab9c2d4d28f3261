//! The wire protocol between rovers and the ground station.
//!
//! `no_std` and allocation-free: every buffer is bounded at compile time. Layers, bottom up:
//! - [`message`]: message types with stable keys, versions, delivery classes and priorities;
//! - [`codec`]: packet header, postcard encoding and a total decoder;
//! - [`auth`]: HMAC-SHA256 command authentication with replay protection;
//! - [`frame`]: framing for byte streams (COBS + CRC-32), CAN (ISO-TP-like) and UDP datagrams;
//! - [`delivery`]: reliable and latest-wins delivery, priorities and a token-bucket rate cap.
#![no_std]

pub mod auth;
pub mod codec;
pub mod delivery;
pub mod frame;
pub mod geometry;
pub mod ids;
pub mod message;

pub use auth::{AuthError, AuthKey, ReplayGuard};
pub use codec::{DecodeError, EncodeError, Header, MAX_PACKET_BYTES, Packet, decode, encode, encode_authenticated};
pub use geometry::{Cov6, Pose3};
pub use ids::{NodeId, NodeRef, RobotId, SubmapId};
pub use message::{AnyMessage, Delivery, Message, MessageKey, Priority};
