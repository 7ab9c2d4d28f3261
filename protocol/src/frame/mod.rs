//! Framing: how packets travel over each kind of link.
//!
//! - [`stream`]: byte streams (serial radios): COBS + CRC-32, `0x00`-delimited frames.
//! - [`datagram`]: UDP: segmentation into datagrams of at most 1200 bytes and reassembly.
//! - [`can`]: CAN (classic 8-byte and FD 64-byte frames): ISO-TP-like segmentation.

pub mod can;
pub mod datagram;
pub mod stream;

/// How a link carries packets, and therefore what a packet costs on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Framing {
    Stream,
    Datagram { mtu: u16 },
    Can(can::CanKind),
}

impl Framing {
    /// Upper bound of the bytes a packet of `packet_len` bytes occupies on the link, framing and
    /// per-frame link overhead included. The token bucket charges this, so a sender that keeps
    /// within its byte rate keeps within the link's capacity.
    pub fn wire_bytes(&self, packet_len: usize) -> usize {
        match *self {
            Framing::Stream => stream::max_frame_len(packet_len),
            Framing::Datagram { mtu } => datagram::wire_bytes(usize::from(mtu), packet_len),
            Framing::Can(kind) => can::wire_bytes(kind, packet_len),
        }
    }
}

/// Why a frame or fragment was refused. One enum for every link, so a link driver can count and
/// log failures the same way whatever the framing; each variant names something the caller can
/// act on (grow a buffer, fix a configuration, or just count a corrupted or lost frame).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// The caller's output buffer cannot hold the frame; size it with the framing's `max_*` bound.
    #[error("output buffer too small")]
    BufferTooSmall,
    /// The packet is longer than this framing can carry with the given configuration.
    #[error("packet of {len} bytes exceeds the framing limit of {max} bytes")]
    PacketTooLong { len: usize, max: usize },
    /// Stream frame whose CRC-32 does not match (also frames too short to hold one): corrupted.
    #[error("frame CRC mismatch")]
    Crc,
    /// Stream frame that ended in the middle of a COBS block: corrupted or truncated.
    #[error("malformed COBS encoding")]
    Cobs,
    /// Stream frame longer than the decoder's buffer; discarded up to the next delimiter.
    #[error("frame longer than the decoder buffer")]
    Overflow,
    /// Datagram MTU outside what the segmenter supports.
    #[error("MTU of {0} bytes unsupported")]
    InvalidMtu(usize),
    /// A datagram fragment header or CAN protocol control byte that no sender of ours produces.
    #[error("malformed fragment")]
    Malformed,
    /// A fragment disagrees with earlier fragments of the same message (count or size): the
    /// partial message is dropped, typically because the sender restarted and reused its ids.
    #[error("fragment inconsistent with the message being reassembled")]
    InconsistentFragments,
    /// The announced message does not fit the reassembly buffer.
    #[error("message of at least {len} bytes exceeds the reassembly buffer of {max} bytes")]
    MessageTooLong { len: usize, max: usize },
    /// A CAN identifier wider than 29 bits.
    #[error("CAN id {0:#x} is not a 29-bit identifier")]
    InvalidCanId(u32),
    /// A CAN data length that the bus kind cannot carry.
    #[error("CAN data length {0} is invalid for this bus")]
    InvalidCanLength(usize),
    /// A consecutive CAN frame was lost or reordered; the message in flight is dropped.
    #[error("CAN sequence number {got} where {expected} was due")]
    SequenceMismatch { expected: u8, got: u8 },
    /// A consecutive CAN frame with no message in flight on its id (its first frame was lost).
    #[error("CAN consecutive frame without a first frame")]
    UnexpectedConsecutive,
}

/// Copies `bytes` into `buf` at `offset`, refusing what would not fit: reassembly offsets come
/// from the wire, so they are checked rather than trusted.
fn copy_into(buf: &mut [u8], offset: usize, bytes: &[u8]) -> Result<(), FrameError> {
    let max = buf.len();
    let target = offset
        .checked_add(bytes.len())
        .and_then(|end| buf.get_mut(offset..end))
        .ok_or(FrameError::MessageTooLong { len: offset.saturating_add(bytes.len()), max })?;
    target.copy_from_slice(bytes);
    Ok(())
}
