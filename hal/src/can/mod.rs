//! CAN: the [`CanBus`] trait over which [`CanLink`] carries packets, with an in-memory bus
//! ([`LoopbackCanBus`]), SocketCAN ([`SocketCanBus`], Linux only), USB-CAN adapters speaking
//! SLCAN ([`SlcanBus`], and [`SlcanAdapter`] emulating one), and [`CanInterface`] naming any
//! of them in one string.
//!
//! # CAN ids
//!
//! [`CanLink`] sends each packet under the id `can_id(priority, source, destination)` (layout in
//! `protocol::frame::can`), where
//! - `source` is the link's own node id, given at construction, not the packet header's: the id
//!   must be unique to the node that transmits it (CAN arbitration and per-id reassembly both
//!   rely on that), and a node relaying another's packet is still the transmitter;
//! - `priority` is the priority of the packet's message type, and `destination` the header's
//!   destination, read from the packet's header alone (the key gives the priority), so a
//!   command wins arbitration over a submap chunk without the caller having to say so.
//!
//! A packet of an unknown message type (from a newer peer) goes as [`Priority::Bulk`] to the
//! header's destination; bytes without a valid header go as bulk to [`NodeId::BROADCAST`]: the
//! lowest priority, so opaque traffic never delays commands.

pub mod interface;
mod loopback;
pub mod slcan;
#[cfg(target_os = "linux")]
mod socketcan;

use std::fmt;
use std::time::{Duration, Instant};

use protocol::frame::Framing;
use protocol::frame::can::{CanKind, CanReassembler, can_id, segment};
use protocol::{AnyMessage, NodeId, Priority};

use crate::link::{
    Link, LinkCounters, LinkError, MAX_LINK_PACKET_BYTES, bump, check_packet_len, deadline_after, deliver,
};

pub use interface::{CanInterface, InterfaceError};
pub use loopback::{DEFAULT_QUEUE_FRAMES, LoopbackCanBus};
pub use protocol::frame::can::CanFrame;
pub use slcan::{SlcanAdapter, SlcanBus};
#[cfg(target_os = "linux")]
pub use socketcan::SocketCanBus;

/// A CAN bus as one node sees it: frames with 29-bit ids.
pub trait CanBus: Send {
    /// Queues one frame for transmission.
    fn send(&mut self, frame: &CanFrame) -> Result<(), LinkError>;

    /// Next frame sent by another node, waiting at most `timeout`; `Ok(None)` on timeout. A zero
    /// `timeout` takes a frame already received without waiting.
    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, LinkError>;

    fn kind(&self) -> CanKind;

    /// Frames lost or discarded before reaching the caller (queue overflow, frames that are not
    /// ours). Buses that cannot tell report 0.
    fn dropped_frames(&self) -> u64 {
        0
    }
}

impl<B: CanBus + ?Sized> CanBus for Box<B> {
    fn send(&mut self, frame: &CanFrame) -> Result<(), LinkError> {
        (**self).send(frame)
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, LinkError> {
        (**self).recv(timeout)
    }

    fn kind(&self) -> CanKind {
        (**self).kind()
    }

    fn dropped_frames(&self) -> u64 {
        (**self).dropped_frames()
    }
}

/// How long a partly received packet waits for its next frame. Frames of one packet are sent
/// back to back, so a gap this long means the rest was lost.
pub const DEFAULT_REASSEMBLY_TIMEOUT: Duration = Duration::from_secs(1);
/// Multi-frame packets being reassembled at once: one per transmitting (node, priority,
/// destination) id in flight.
const REASSEMBLY_SLOTS: usize = 16;

/// Frames `recv` still takes once its timeout has passed, as long as they are already there: a
/// packet whose frames have all arrived is returned even with a zero timeout, while a bus
/// flooded with frames cannot hold `recv` past its timeout by more than this many.
const LATE_FRAMES: usize = 512;

type LinkReassembler = CanReassembler<REASSEMBLY_SLOTS, MAX_LINK_PACKET_BYTES>;

/// A [`Link`] over a [`CanBus`], segmenting packets ISO-TP-like (see `protocol::frame::can`).
pub struct CanLink<B> {
    bus: B,
    node: NodeId,
    reassembler: Box<LinkReassembler>,
    /// Origin of the reassembler's millisecond clock.
    epoch: Instant,
    counters: LinkCounters,
}

impl<B: CanBus + fmt::Debug> fmt::Debug for CanLink<B> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("CanLink")
            .field("bus", &self.bus)
            .field("node", &self.node)
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

impl<B: CanBus> CanLink<B> {
    /// A link for node `node` (the source of every CAN id it sends, see the module doc).
    pub fn new(bus: B, node: NodeId) -> Self {
        Self::with_reassembly_timeout(bus, node, DEFAULT_REASSEMBLY_TIMEOUT)
    }

    pub fn with_reassembly_timeout(bus: B, node: NodeId, timeout: Duration) -> Self {
        let timeout_ms = u64::try_from(timeout.as_millis()).unwrap_or(u64::MAX);
        let kind = bus.kind();
        CanLink {
            bus,
            node,
            reassembler: Box::new(CanReassembler::new(kind, timeout_ms)),
            epoch: Instant::now(),
            counters: LinkCounters::default(),
        }
    }

    pub fn node(&self) -> NodeId {
        self.node
    }

    pub fn bus(&self) -> &B {
        &self.bus
    }

    pub fn into_bus(self) -> B {
        self.bus
    }

    /// The CAN id `packet` is sent under (see the module doc).
    pub fn can_id_for(&self, packet: &[u8]) -> u32 {
        let (priority, destination) = match protocol::codec::decode_header(packet) {
            Ok((header, _)) => {
                (AnyMessage::priority_of(header.message_key()).unwrap_or(Priority::Bulk), header.destination)
            }
            Err(_) => (Priority::Bulk, NodeId::BROADCAST),
        };
        can_id(priority, self.node, destination)
    }

    fn now_ms(&self) -> u64 {
        self.epoch.elapsed().as_millis() as u64
    }
}

impl<B: CanBus> Link for CanLink<B> {
    /// Sends the packet's frames back to back. If the bus refuses one, the rest are not sent
    /// (receivers drop the partial packet) and the error is returned.
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkError> {
        check_packet_len(packet)?;
        let id = self.can_id_for(packet);
        let mut failed = None;
        let mut frames_sent = 0usize;
        let bus = &mut self.bus;
        segment(bus.kind(), id, packet, |frame| {
            if failed.is_none() {
                match bus.send(frame) {
                    Ok(()) => frames_sent += 1,
                    Err(error) => failed = Some(error),
                }
            }
        })?;
        bump(&mut self.counters.frames_sent, frames_sent);
        if let Some(error) = failed {
            return Err(error);
        }
        bump(&mut self.counters.packets_sent, 1);
        bump(&mut self.counters.packet_bytes_sent, packet.len());
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<Option<usize>, LinkError> {
        let deadline = deadline_after(timeout);
        let mut late_frames = 0usize;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                late_frames += 1;
                if late_frames > LATE_FRAMES {
                    return Ok(None);
                }
            }
            let Some(frame) = self.bus.recv(left)? else {
                if Instant::now() >= deadline {
                    let now_ms = self.now_ms();
                    self.reassembler.expire(now_ms);
                    return Ok(None);
                }
                continue;
            };
            if !frame.extended {
                // A device protocol's frame (CANopen uses 11-bit ids) sharing the bus: not ours.
                continue;
            }
            bump(&mut self.counters.frames_received, 1);
            let now_ms = self.now_ms();
            match self.reassembler.push(now_ms, &frame) {
                Ok(Some(packet)) => return deliver(packet, buf, &mut self.counters).map(Some),
                Ok(None) => {}
                Err(error) => self.counters.rejected.count(error),
            }
        }
    }

    fn framing(&self) -> Framing {
        Framing::Can(self.bus.kind())
    }

    fn counters(&self) -> LinkCounters {
        let stats = self.reassembler.stats();
        let mut counters = self.counters;
        counters.rejected.expired = stats.expired;
        counters.rejected.evicted = stats.evicted;
        counters.rejected.aborted = stats.aborted;
        counters.dropped_frames = self.bus.dropped_frames();
        counters
    }
}
