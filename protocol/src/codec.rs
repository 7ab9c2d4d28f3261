//! Packet layout and the total decoder.
//!
//! ```text
//! packet = header | body | [counter: u64 LE | tag: 16 bytes]   (trailer only if AUTHENTICATED)
//! header = protocol version u8 | key u8 | version u8 | flags u8 | source u8 | destination u8 | seq varint u32
//! body   = postcard encoding of the message type named by `key`
//! ```
//! The MAC covers everything before the tag (header, body and counter), see [`crate::auth`].

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::auth::{AUTH_TRAILER_BYTES, AuthKey, COUNTER_BYTES, TAG_BYTES};
use crate::ids::NodeId;
use crate::message::{AnyMessage, Delivery, MessageKey};

/// First byte of every packet. A receiver drops packets of other protocol versions.
pub const PROTOCOL_VERSION: u8 = 1;

/// Packet flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct Flags(pub u8);

impl Flags {
    pub const RELIABLE: u8 = 0x01;
    pub const AUTHENTICATED: u8 = 0x02;
    const KNOWN: u8 = Self::RELIABLE | Self::AUTHENTICATED;

    pub fn reliable(self) -> bool {
        self.0 & Self::RELIABLE != 0
    }

    pub fn authenticated(self) -> bool {
        self.0 & Self::AUTHENTICATED != 0
    }
}

/// The header of every packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct Header {
    pub protocol: u8,
    pub key: u8,
    pub version: u8,
    pub flags: Flags,
    pub source: NodeId,
    pub destination: NodeId,
    /// Reliable packets: sequence number in the (source, destination, channel) stream.
    /// Others: a per-source running counter, used for loss statistics.
    pub seq: u32,
}

impl Header {
    pub fn message_key(&self) -> MessageKey {
        MessageKey(self.key)
    }
}

/// Largest header encoding.
pub const HEADER_MAX_BYTES: usize = Header::POSTCARD_MAX_SIZE;
/// Largest packet of any message type, authenticated or not.
pub const MAX_PACKET_BYTES: usize = HEADER_MAX_BYTES + AnyMessage::MAX_BODY_SIZE + AUTH_TRAILER_BYTES;

/// The authentication trailer of a packet.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AuthTrailer {
    pub counter: u64,
    pub tag: [u8; TAG_BYTES],
}

/// A decoded packet. Decoding checks structure only; [`crate::auth`] checks the MAC.
#[derive(Debug, Clone, PartialEq)]
pub struct Packet {
    pub header: Header,
    pub message: AnyMessage,
    pub auth: Option<AuthTrailer>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum EncodeError {
    #[error("output buffer too small")]
    BufferTooSmall,
    #[error("{0} must be sent authenticated")]
    NeedsAuthentication(&'static str),
    #[error("{0} is not an authenticated message type")]
    NotAuthenticated(&'static str),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum DecodeError {
    #[error("packet shorter than its header")]
    TruncatedHeader,
    #[error("protocol version {0} (expected {PROTOCOL_VERSION})")]
    WrongProtocol(u8),
    #[error("unknown flag bits {0:#04x}")]
    UnknownFlags(u8),
    #[error("unknown message key {0:#04x}")]
    UnknownKey(u8),
    #[error("message key {key:#04x} has no version {version}")]
    UnsupportedVersion { key: u8, version: u8 },
    #[error("flags do not match the delivery class of message key {key:#04x}")]
    DeliveryMismatch { key: u8 },
    #[error("authentication flag does not match message key {key:#04x}")]
    AuthenticationMismatch { key: u8 },
    #[error("packet too short for its authentication trailer")]
    TruncatedTrailer,
    #[error("malformed body of message key {key:#04x}")]
    MalformedBody { key: u8 },
    #[error("{count} bytes after the message body")]
    TrailingBytes { count: usize },
}

fn header_for(message: &AnyMessage, source: NodeId, destination: NodeId, seq: u32, authenticated: bool) -> Header {
    let mut flags = 0;
    if message.delivery() == Delivery::Reliable {
        flags |= Flags::RELIABLE;
    }
    if authenticated {
        flags |= Flags::AUTHENTICATED;
    }
    Header {
        protocol: PROTOCOL_VERSION,
        key: message.key().0,
        version: message.version(),
        flags: Flags(flags),
        source,
        destination,
        seq,
    }
}

fn encode_unsigned(header: &Header, message: &AnyMessage, out: &mut [u8]) -> Result<usize, EncodeError> {
    let header_len = postcard::to_slice(header, out).map_err(|_| EncodeError::BufferTooSmall)?.len();
    let body_out = out.get_mut(header_len..).ok_or(EncodeError::BufferTooSmall)?;
    let body_len = message.encode_body(body_out).map_err(|_| EncodeError::BufferTooSmall)?.len();
    Ok(header_len + body_len)
}

/// Encodes an unauthenticated packet into `out` and returns its length.
pub fn encode(
    message: &AnyMessage,
    source: NodeId,
    destination: NodeId,
    seq: u32,
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    if message.requires_authentication() {
        return Err(EncodeError::NeedsAuthentication(message.type_name()));
    }
    encode_unsigned(&header_for(message, source, destination, seq, false), message, out)
}

/// Encodes an authenticated packet: MAC over header, body and `counter`, which the sender must
/// never reuse with the same key (persist it across restarts).
pub fn encode_authenticated(
    message: &AnyMessage,
    source: NodeId,
    destination: NodeId,
    seq: u32,
    counter: u64,
    key: &AuthKey,
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    if !message.requires_authentication() {
        return Err(EncodeError::NotAuthenticated(message.type_name()));
    }
    let header = header_for(message, source, destination, seq, true);
    let signed_len = encode_unsigned(&header, message, out)?;
    let total = signed_len + AUTH_TRAILER_BYTES;
    if out.len() < total {
        return Err(EncodeError::BufferTooSmall);
    }
    out[signed_len..signed_len + COUNTER_BYTES].copy_from_slice(&counter.to_le_bytes());
    let tag = key.tag(&out[..signed_len + COUNTER_BYTES]);
    out[signed_len + COUNTER_BYTES..total].copy_from_slice(&tag);
    Ok(total)
}

/// Decodes and checks the header alone, returning it and the bytes after it.
pub fn decode_header(bytes: &[u8]) -> Result<(Header, &[u8]), DecodeError> {
    let (header, rest) = postcard::take_from_bytes::<Header>(bytes).map_err(|_| DecodeError::TruncatedHeader)?;
    if header.protocol != PROTOCOL_VERSION {
        return Err(DecodeError::WrongProtocol(header.protocol));
    }
    if header.flags.0 & !Flags::KNOWN != 0 {
        return Err(DecodeError::UnknownFlags(header.flags.0));
    }
    Ok((header, rest))
}

/// Decodes a packet. Total: any bytes give a packet or an error, never a panic.
pub fn decode(bytes: &[u8]) -> Result<Packet, DecodeError> {
    let (header, rest) = decode_header(bytes)?;
    let (body, auth) = if header.flags.authenticated() {
        if rest.len() < AUTH_TRAILER_BYTES {
            return Err(DecodeError::TruncatedTrailer);
        }
        let (body, trailer) = rest.split_at(rest.len() - AUTH_TRAILER_BYTES);
        let mut counter = [0u8; COUNTER_BYTES];
        counter.copy_from_slice(&trailer[..COUNTER_BYTES]);
        let mut tag = [0u8; TAG_BYTES];
        tag.copy_from_slice(&trailer[COUNTER_BYTES..]);
        (body, Some(AuthTrailer { counter: u64::from_le_bytes(counter), tag }))
    } else {
        (rest, None)
    };
    let message = AnyMessage::decode_body(header.message_key(), header.version, body)?;
    if header.flags.reliable() != (message.delivery() == Delivery::Reliable) {
        return Err(DecodeError::DeliveryMismatch { key: header.key });
    }
    if header.flags.authenticated() != message.requires_authentication() {
        return Err(DecodeError::AuthenticationMismatch { key: header.key });
    }
    Ok(Packet { header, message, auth })
}
