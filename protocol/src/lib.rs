//! The wire protocol between rovers and the ground station.
//!
//! `no_std` and allocation-free: every buffer is bounded at compile time. Layers, bottom up:
//! - [`message`]: message types with stable keys, versions, delivery classes and priorities;
//! - [`codec`]: packet header, postcard encoding and a total decoder;
//! - [`auth`]: HMAC-SHA256 command authentication with replay protection;
//! - [`frame`]: framing for byte streams (COBS + CRC-32), CAN (ISO-TP-like) and UDP datagrams;
//! - [`delivery`]: reliable and latest-wins delivery, priorities and a token-bucket rate cap.
//!
//! ```
//! use protocol::message::{AnyMessage, CommandAck, CommandOutcome};
//! use protocol::{MAX_PACKET_BYTES, NodeId, RobotId, decode, encode};
//!
//! let ack = AnyMessage::from(CommandAck { robot: RobotId(2), command_id: 7, outcome: CommandOutcome::Executed });
//! let mut buf = [0u8; MAX_PACKET_BYTES];
//! let len = encode(&ack, NodeId(2), NodeId::GROUND, 0, &mut buf)?;
//! let packet = decode(&buf[..len])?;
//! assert_eq!(packet.message, ack);
//! assert_eq!(packet.header.destination, NodeId::GROUND);
//! // Any other bytes give a typed error, never a panic.
//! assert!(decode(&buf[..len - 1]).is_err());
//! # Ok::<(), Box<dyn core::error::Error>>(())
//! ```
#![no_std]

pub mod auth;
pub mod codec;
pub mod crc;
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
