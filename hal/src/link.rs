//! The [`Link`] trait: a transport that carries whole packets, whatever it has to do to them
//! (frame, segment, reassemble) on the way.
//!
//! Links are lossy: a frame that fails its checks is counted in [`LinkCounters`] and skipped, so
//! one burst of noise costs the packets it hit and nothing else. The delivery layer above
//! retransmits what must arrive. Errors are kept for what the caller must act on: a broken
//! device, a closed peer, a buffer or packet of the wrong size, a bad configuration.

use std::time::Duration;

use protocol::frame::{FrameError, Framing};

/// Largest packet any link carries. Receivers size their reassembly buffers for it, so a larger
/// packet would be dropped at the far end: links refuse it at the sender instead.
pub const MAX_LINK_PACKET_BYTES: usize = protocol::MAX_PACKET_BYTES;

/// A transport carrying whole packets between nodes.
pub trait Link: Send {
    /// Sends one packet, at most [`MAX_LINK_PACKET_BYTES`] long. Returning `Ok` means the link
    /// took it, not that anyone received it.
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkError>;

    /// Next complete packet into `buf`, waiting at most `timeout`; `Ok(None)` on timeout.
    ///
    /// Corrupt or foreign frames are counted and skipped, never returned as errors. `buf` should
    /// hold [`MAX_LINK_PACKET_BYTES`]: a packet that does not fit is dropped with
    /// [`LinkError::BufferTooSmall`].
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<Option<usize>, LinkError>;

    /// How this link frames packets, so a rate limiter can charge what a packet costs on the wire.
    fn framing(&self) -> Framing;

    /// Counters since the link was opened.
    fn counters(&self) -> LinkCounters;
}

impl<L: Link + ?Sized> Link for Box<L> {
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkError> {
        (**self).send(packet)
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<Option<usize>, LinkError> {
        (**self).recv(buf, timeout)
    }

    fn framing(&self) -> Framing {
        (**self).framing()
    }

    fn counters(&self) -> LinkCounters {
        (**self).counters()
    }
}

/// Why a link operation failed. Corrupt input is not an error (see [`LinkCounters::rejected`]).
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The OS refused an operation on the device or socket; `context` says which and where.
    #[error("{context}: {source}")]
    Io {
        context: String,
        #[source]
        source: std::io::Error,
    },
    /// The packet is longer than the link carries; split it above this layer.
    #[error("packet of {len} bytes exceeds the link limit of {max} bytes")]
    PacketTooLarge { len: usize, max: usize },
    /// The caller's receive buffer cannot hold the packet that arrived, which is dropped.
    #[error(
        "receive buffer of {available} bytes cannot hold a {needed}-byte packet \
         (size it to MAX_LINK_PACKET_BYTES); packet dropped"
    )]
    BufferTooSmall { needed: usize, available: usize },
    /// The other end or the device is gone for good (end of file, hung-up port, bus dropped).
    #[error("link closed: {0}")]
    Closed(String),
    /// The link was configured with values it cannot work with.
    #[error("invalid link configuration: {0}")]
    Config(String),
    /// A UDP link with no peer to send to: nothing would leave this node.
    #[error("no peers configured: set the link's peer addresses before sending")]
    NoPeers,
    /// A CAN frame longer than the bus carries (an FD frame on a classic bus).
    #[error("CAN frame of {len} data bytes does not fit a bus carrying at most {max}")]
    CanFrameTooLong { len: usize, max: usize },
    /// The framing refused the packet or configuration (see the variant for what to fix).
    #[error("framing: {0}")]
    Framing(#[from] FrameError),
}

impl LinkError {
    /// For `map_err`: an [`LinkError::Io`] whose context is built only if there is an error,
    /// so hot paths do not format strings that are never shown.
    pub fn io<C: Into<String>>(context: impl FnOnce() -> C) -> impl FnOnce(std::io::Error) -> LinkError {
        move |source| LinkError::Io { context: context().into(), source }
    }
}

/// Counters of a link since it was opened. Saturating, never wrapping.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LinkCounters {
    pub packets_sent: u64,
    /// Bytes of the packets sent, before framing.
    pub packet_bytes_sent: u64,
    pub packets_received: u64,
    /// Bytes of the packets received, after reassembly.
    pub packet_bytes_received: u64,
    /// Frames (stream frames, datagrams, CAN frames) put on the wire; fan-out to several UDP
    /// peers counts one per peer.
    pub frames_sent: u64,
    /// Frames that reached the framing layer, good or not.
    pub frames_received: u64,
    /// Frames and incomplete messages the framing refused or dropped, by cause.
    pub rejected: Rejections,
    /// UDP datagrams from addresses outside the peer list (accepted all the same: a node may
    /// hear a radio it was not told about).
    pub unknown_sources: u64,
    /// Frames lost or discarded below the framing: a receive queue overflow, a CAN frame that is
    /// not ours (standard id, remote or error frame).
    pub dropped_frames: u64,
    /// Packets that arrived whole but did not fit the caller's buffer.
    pub packets_too_large_for_buffer: u64,
}

/// Frames or messages refused by the framing, by cause. Each corresponds to a
/// [`FrameError`] (or, for the last three, to a reassembler's give-up).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Rejections {
    /// Stream frames with a wrong CRC: bit errors or garbage on the line.
    pub crc: u64,
    /// Stream frames with broken COBS: truncated or garbage.
    pub cobs: u64,
    /// Stream frames longer than any packet: garbage or a lost delimiter.
    pub overflow: u64,
    /// Fragments or CAN frames no sender of ours produces.
    pub malformed: u64,
    /// Fragments disagreeing with their message (typically a sender restart).
    pub inconsistent: u64,
    /// Messages announced longer than the reassembly buffer.
    pub too_long: u64,
    /// CAN frames with an invalid id or length for the bus.
    pub invalid_can: u64,
    /// CAN messages dropped for a lost or reordered frame.
    pub sequence: u64,
    /// CAN consecutive frames whose first frame was lost.
    pub orphan: u64,
    /// Any other framing error.
    pub other: u64,
    /// Incomplete messages dropped after the reassembly timeout.
    pub expired: u64,
    /// Incomplete messages dropped to make room for others.
    pub evicted: u64,
    /// CAN messages abandoned by their sender (a new one started on the same id).
    pub aborted: u64,
}

impl Rejections {
    /// Counts one frame refused with `error`.
    pub fn count(&mut self, error: FrameError) {
        let counter = match error {
            FrameError::Crc => &mut self.crc,
            FrameError::Cobs => &mut self.cobs,
            FrameError::Overflow => &mut self.overflow,
            FrameError::Malformed => &mut self.malformed,
            FrameError::InconsistentFragments => &mut self.inconsistent,
            FrameError::MessageTooLong { .. } | FrameError::PacketTooLong { .. } => &mut self.too_long,
            FrameError::InvalidCanId(_) | FrameError::InvalidCanLength(_) => &mut self.invalid_can,
            FrameError::SequenceMismatch { .. } => &mut self.sequence,
            FrameError::UnexpectedConsecutive => &mut self.orphan,
            _ => &mut self.other,
        };
        *counter = counter.saturating_add(1);
    }

    /// All frames refused plus all messages given up.
    pub fn total(&self) -> u64 {
        [
            self.crc,
            self.cobs,
            self.overflow,
            self.malformed,
            self.inconsistent,
            self.too_long,
            self.invalid_can,
            self.sequence,
            self.orphan,
            self.other,
            self.expired,
            self.evicted,
            self.aborted,
        ]
        .iter()
        .fold(0u64, |sum, &n| sum.saturating_add(n))
    }
}

/// Saturating increment for counters.
pub(crate) fn bump(counter: &mut u64, by: usize) {
    *counter = counter.saturating_add(by as u64);
}

/// Refuses packets the far end could not reassemble.
pub(crate) fn check_packet_len(packet: &[u8]) -> Result<(), LinkError> {
    if packet.len() > MAX_LINK_PACKET_BYTES {
        return Err(LinkError::PacketTooLarge { len: packet.len(), max: MAX_LINK_PACKET_BYTES });
    }
    Ok(())
}

/// Copies a received packet into the caller's buffer, counting it.
pub(crate) fn deliver(packet: &[u8], buf: &mut [u8], counters: &mut LinkCounters) -> Result<usize, LinkError> {
    let Some(target) = buf.get_mut(..packet.len()) else {
        bump(&mut counters.packets_too_large_for_buffer, 1);
        return Err(LinkError::BufferTooSmall { needed: packet.len(), available: buf.len() });
    };
    target.copy_from_slice(packet);
    bump(&mut counters.packets_received, 1);
    bump(&mut counters.packet_bytes_received, packet.len());
    Ok(packet.len())
}

/// The instant `timeout` from now; a timeout too long to represent waits "forever" (136 years).
pub(crate) fn deadline_after(timeout: Duration) -> std::time::Instant {
    let now = std::time::Instant::now();
    now.checked_add(timeout).or_else(|| now.checked_add(Duration::from_secs(u64::from(u32::MAX)))).unwrap_or(now)
}
