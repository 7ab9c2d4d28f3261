//! Framing for CAN (classic and FD): ISO 15765-2-like (ISO-TP) segmentation over 29-bit ids.
//!
//! # Identifier
//!
//! ```text
//! bit  28..26  priority (Priority::channel; 0 = Control)
//! bit  25..16  reserved, sent as 0 (receivers do not check them, so they can be used later)
//! bit  15..8   destination NodeId
//! bit   7..0   source NodeId
//! ```
//!
//! Arbitration lets the numerically lowest id through, so priority takes the top bits and a
//! control frame wins over any bulk frame. Source and destination make the id unique per
//! sender: two nodes never transmit the same id, which CAN requires (two senders writing the
//! same id at once would collide undetected), and the receiver can key reassembly by id.
//!
//! # Frames
//!
//! The first data byte is the protocol control information (PCI), as in ISO 15765-2:
//!
//! ```text
//! single, short    0x0L | L data bytes              L = 0..=7, frame of at most 8 bytes
//! single, escape   0x00 | L u8 | L data bytes       FD only, L = 8..=62, frame of more than 8 bytes
//! first            0x1H | LL | data                 length 0xHLL = 8..=4095
//! first, escape    0x10 | 0x00 | length u32 BE | data   length > 4095
//! consecutive      0x2N | data                      N = 1, 2, .., 15, 0, 1, .. (wraps)
//! ```
//!
//! A first frame fills the whole frame (8 bytes classic, 64 FD), as do all consecutive frames
//! but the last. On FD the last frame is padded with `0xCC` to the next valid FD length (0..=8,
//! 12, 16, 20, 24, 32, 48, 64); on classic CAN every length up to 8 is valid, so nothing is
//! padded. Unlike ISO-TP, a single frame may carry 0 bytes (`0x00` in a frame of 1 byte), so an
//! empty packet round-trips.
//!
//! # No flow control
//!
//! ISO-TP has the receiver pace the sender with flow-control frames. Here the token bucket above
//! this layer already caps each sender's share of the bus, and the buses are broadcast: a
//! message to every node would need flow control from each of them, and a silent or dead
//! receiver would stall the sender. So the sender sends all frames back to back and the
//! receiver checks the sequence number of each consecutive frame: a frame lost (for example in
//! a receive FIFO overrun) or reordered shows as a sequence mismatch and the message is
//! dropped; the delivery layer retransmits what must arrive. Losing 16 frames in a row does not
//! fool the check either: the message then cannot complete before the next first frame on its
//! id replaces it, or the timeout drops it.
//!
//! Because reassembly is keyed by id, a sender must finish one message before it starts the
//! next with the same id (same priority and destination), and its driver must transmit frames
//! of one id in order.

use crate::{NodeId, Priority};

use super::{FrameError, copy_into};

/// Largest 29-bit (extended) identifier.
pub const CAN_ID_MASK: u32 = 0x1FFF_FFFF;
/// Fill of the unused tail of a padded FD frame (the ISO-TP default, few stuff bits).
pub const PADDING: u8 = 0xCC;
/// Worst-case wire cost of a classic extended-id frame with 8 data bytes, see [`frame_wire_bytes`].
pub const CLASSIC_FRAME_WIRE_BYTES: usize = frame_wire_bytes(CanKind::Classic, 8);
/// Worst-case wire cost of an FD extended-id frame with 64 data bytes, see [`frame_wire_bytes`].
pub const FD_FRAME_WIRE_BYTES: usize = frame_wire_bytes(CanKind::Fd, 64);

const PRIORITY_SHIFT: u32 = 26;
const DESTINATION_SHIFT: u32 = 8;

/// Data lengths a CAN FD frame can have (indexed by DLC).
const FD_LENGTHS: [u8; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];

const PCI_SINGLE: u8 = 0x0;
const PCI_FIRST: u8 = 0x1;
const PCI_CONSECUTIVE: u8 = 0x2;
/// Largest packet whose length fits the 12-bit first-frame length.
const FIRST_FRAME_SHORT_MAX: usize = 0xFFF;
/// Largest single-frame packet with the one-byte PCI (a frame of at most 8 bytes).
const SINGLE_SHORT_MAX: usize = 7;

/// The kind of CAN bus a link uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum CanKind {
    /// Classic CAN 2.0B: up to 8 data bytes per frame.
    Classic,
    /// CAN FD: up to 64 data bytes per frame.
    Fd,
}

impl CanKind {
    /// Most data bytes of one frame.
    pub const fn max_data(self) -> usize {
        match self {
            CanKind::Classic => 8,
            CanKind::Fd => 64,
        }
    }

    /// The shortest valid frame data length of at least `len` bytes, if any.
    pub const fn padded_len(self, len: usize) -> Option<usize> {
        if len > self.max_data() {
            return None;
        }
        let mut dlc = 0;
        while dlc < FD_LENGTHS.len() {
            if FD_LENGTHS[dlc] as usize >= len {
                return Some(FD_LENGTHS[dlc] as usize);
            }
            dlc += 1;
        }
        None
    }

    /// Largest packet carried in a single frame.
    const fn single_max(self) -> usize {
        match self {
            CanKind::Classic => SINGLE_SHORT_MAX,
            CanKind::Fd => 64 - 2,
        }
    }
}

/// The extended CAN id of a frame from `source` to `destination` at `priority` (see the module
/// doc for the layout).
pub fn can_id(priority: Priority, source: NodeId, destination: NodeId) -> u32 {
    (u32::from(priority.channel()) << PRIORITY_SHIFT)
        | (u32::from(destination.0) << DESTINATION_SHIFT)
        | u32::from(source.0)
}

/// The priority encoded in `id`, if it is one of ours.
pub fn can_id_priority(id: u32) -> Option<Priority> {
    Priority::from_channel(((id & CAN_ID_MASK) >> PRIORITY_SHIFT) as u8)
}

pub fn can_id_source(id: u32) -> NodeId {
    NodeId(id as u8)
}

pub fn can_id_destination(id: u32) -> NodeId {
    NodeId((id >> DESTINATION_SHIFT) as u8)
}

/// One CAN data frame. Bytes past `len` are not part of the frame.
///
/// The team link uses extended (29-bit) ids only; device protocols such as CANopen use standard
/// (11-bit) ids on the same bus, so a frame says which it is.
#[derive(Debug, Clone, Copy)]
pub struct CanFrame {
    pub id: u32,
    pub len: u8,
    pub data: [u8; 64],
    /// A 29-bit id (CAN 2.0B); `false`: an 11-bit id (CAN 2.0A).
    pub extended: bool,
}

/// Largest standard (11-bit) CAN id.
pub const CAN_STANDARD_ID_MASK: u32 = 0x7FF;

impl CanFrame {
    /// A frame with `data`, whose length must be a valid CAN FD length (which includes every
    /// classic length).
    pub fn new(id: u32, data: &[u8]) -> Result<Self, FrameError> {
        if id > CAN_ID_MASK {
            return Err(FrameError::InvalidCanId(id));
        }
        if CanKind::Fd.padded_len(data.len()) != Some(data.len()) {
            return Err(FrameError::InvalidCanLength(data.len()));
        }
        let mut frame = CanFrame { id, len: data.len() as u8, data: [0; 64], extended: true };
        frame.data.get_mut(..data.len()).ok_or(FrameError::InvalidCanLength(data.len()))?.copy_from_slice(data);
        Ok(frame)
    }

    /// A frame with a standard (11-bit) id and `data`, whose length must be a valid CAN FD
    /// length.
    pub fn standard(id: u32, data: &[u8]) -> Result<Self, FrameError> {
        if id > CAN_STANDARD_ID_MASK {
            return Err(FrameError::InvalidCanId(id));
        }
        let mut frame = CanFrame::new(id, data)?;
        frame.extended = false;
        Ok(frame)
    }

    /// The frame's data; all 64 bytes if `len` was set beyond them.
    pub fn data(&self) -> &[u8] {
        self.data.get(..usize::from(self.len)).unwrap_or(&self.data)
    }
}

impl PartialEq for CanFrame {
    fn eq(&self, other: &Self) -> bool {
        self.id == other.id && self.extended == other.extended && self.data() == other.data()
    }
}

impl Eq for CanFrame {}

/// Frames `segment` emits for a `packet_len`-byte packet.
pub const fn frame_count(kind: CanKind, packet_len: usize) -> usize {
    if packet_len <= kind.single_max() {
        return 1;
    }
    let first_data = kind.max_data() - first_pci_len(packet_len);
    1 + (packet_len - first_data).div_ceil(kind.max_data() - 1)
}

const fn first_pci_len(packet_len: usize) -> usize {
    if packet_len <= FIRST_FRAME_SHORT_MAX { 2 } else { 6 }
}

/// Worst-case bytes one frame of `data_len` data bytes occupies on the bus: every bit from
/// start of frame to the end of interframe space, extended id, worst-case bit stuffing,
/// rounded up to whole bytes.
///
/// Classic (CAN 2.0B): 54 + 8·d bits are subject to stuffing (SOF, 29-bit id with SRR, IDE and
/// RTR, r1, r0, DLC, data, 15-bit CRC), plus at worst one stuff bit per 4 bits after the first
/// 5, plus 13 bits unstuffed (CRC delimiter, ACK slot and delimiter, 7 EOF, 3 intermission).
/// For d = 8: 118 + 29 + 13 = 160 bits = 20 bytes ([`CLASSIC_FRAME_WIRE_BYTES`]).
///
/// FD: 41 + 8·d bits are subject to dynamic stuffing (SOF, id with SRR and IDE, RRS, FDF, res,
/// BRS, ESI, DLC, data), then the CRC field with a 4-bit stuff count and a 17-bit CRC (d ≤ 16)
/// or 21-bit CRC, with a fixed stuff bit before every 4 of those bits, then the same 13 bits.
/// For d = 64: 553 + 138 + 25 + 7 + 13 = 736 bits = 92 bytes ([`FD_FRAME_WIRE_BYTES`]). This
/// counts every bit as if sent at the nominal (arbitration) rate, so the link's byte rate must be
/// the nominal bit rate / 8: with bit-rate switching most of those bits go faster, and the
/// cost is then an over-estimate, which is the safe side for a rate cap.
pub const fn frame_wire_bytes(kind: CanKind, data_len: usize) -> usize {
    let data_bits = 8 * if data_len < kind.max_data() { data_len } else { kind.max_data() };
    let trailer_bits = 13;
    let bits = match kind {
        CanKind::Classic => {
            let stuffed = 54 + data_bits;
            stuffed + (stuffed - 1) / 4 + trailer_bits
        }
        CanKind::Fd => {
            let stuffed = 41 + data_bits;
            let crc_field = 4 + if data_bits <= 16 * 8 { 17 } else { 21 };
            stuffed + (stuffed - 1) / 4 + crc_field + crc_field.div_ceil(4) + trailer_bits
        }
    };
    bits.div_ceil(8)
}

/// Worst-case bytes on the bus for a `packet_len`-byte packet: the sum of [`frame_wire_bytes`]
/// over the frames [`segment`] emits (full frames, and the last one at its padded length).
pub fn wire_bytes(kind: CanKind, packet_len: usize) -> usize {
    let frames = frame_count(kind, packet_len);
    let last_data = if frames == 1 {
        single_frame_len(kind, packet_len)
    } else {
        let first_data = kind.max_data() - first_pci_len(packet_len);
        let rest = packet_len - first_data;
        let last_payload = rest - (frames - 2) * (kind.max_data() - 1);
        padded_or_max(kind, 1 + last_payload)
    };
    (frames - 1)
        .saturating_mul(frame_wire_bytes(kind, kind.max_data()))
        .saturating_add(frame_wire_bytes(kind, last_data))
}

fn padded_or_max(kind: CanKind, len: usize) -> usize {
    kind.padded_len(len).unwrap_or(kind.max_data())
}

/// Data length of the single frame carrying `packet_len` bytes.
fn single_frame_len(kind: CanKind, packet_len: usize) -> usize {
    if packet_len <= SINGLE_SHORT_MAX { 1 + packet_len } else { padded_or_max(kind, 2 + packet_len) }
}

/// Emits `packet` as frames with `id` (see [`can_id`]) and returns how many.
pub fn segment(kind: CanKind, id: u32, packet: &[u8], mut emit: impl FnMut(&CanFrame)) -> Result<usize, FrameError> {
    if id > CAN_ID_MASK {
        return Err(FrameError::InvalidCanId(id));
    }
    let len = packet.len();
    let max = kind.max_data();
    let mut frame = CanFrame { id, len: 0, data: [PADDING; 64], extended: true };

    if len <= kind.single_max() {
        let pci: &[u8] = if len <= SINGLE_SHORT_MAX { &[PCI_SINGLE << 4 | len as u8] } else { &[0, len as u8] };
        fill(&mut frame, pci, packet, single_frame_len(kind, len))?;
        emit(&frame);
        return Ok(1);
    }

    let total = u32::try_from(len).map_err(|_| FrameError::PacketTooLong { len, max: u32::MAX as usize })?;
    let [l0, l1, l2, l3] = total.to_be_bytes();
    let long_pci = [PCI_FIRST << 4, 0, l0, l1, l2, l3];
    let short_pci = [PCI_FIRST << 4 | (len >> 8) as u8, len as u8];
    let pci: &[u8] = if len <= FIRST_FRAME_SHORT_MAX { &short_pci } else { &long_pci };
    let (first, rest) = packet.split_at_checked(max - pci.len()).ok_or(FrameError::Malformed)?;
    fill(&mut frame, pci, first, max)?;
    emit(&frame);

    let mut frames = 1;
    let mut sequence = 1u8;
    for chunk in rest.chunks(max - 1) {
        frame.data = [PADDING; 64];
        fill(&mut frame, &[PCI_CONSECUTIVE << 4 | sequence], chunk, padded_or_max(kind, 1 + chunk.len()))?;
        emit(&frame);
        sequence = (sequence + 1) & 0x0F;
        frames += 1;
    }
    Ok(frames)
}

/// Writes `pci` then `payload` into `frame`, whose length becomes `frame_len` (the bytes in
/// between keep their padding).
fn fill(frame: &mut CanFrame, pci: &[u8], payload: &[u8], frame_len: usize) -> Result<(), FrameError> {
    let end = pci.len() + payload.len();
    let (head, tail) = frame.data.split_at_mut_checked(pci.len()).ok_or(FrameError::InvalidCanLength(end))?;
    head.copy_from_slice(pci);
    tail.get_mut(..payload.len()).ok_or(FrameError::InvalidCanLength(end))?.copy_from_slice(payload);
    frame.len = u8::try_from(frame_len).map_err(|_| FrameError::InvalidCanLength(frame_len))?;
    Ok(())
}

/// Counters of a [`CanReassembler`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CanStats {
    /// Packets delivered.
    pub messages: u64,
    /// Frames pushed.
    pub frames: u64,
    /// Frames refused with an error (each `Err` returned by `push`), sequence errors included.
    pub errors: u64,
    /// Messages dropped for a lost or reordered consecutive frame.
    pub sequence_errors: u64,
    /// Messages replaced by a new first or single frame on the same id before completing (their
    /// last frames were lost).
    pub aborted: u64,
    /// Incomplete messages dropped after `timeout_ms` without a frame.
    pub expired: u64,
    /// Incomplete messages dropped to make room for a message on another id.
    pub evicted: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum SlotState {
    Free,
    Receiving,
    /// The message failed; its remaining consecutive frames are swallowed, so one loss gives
    /// one error rather than one per frame.
    Discarding,
}

struct CanSlot<const MAX: usize> {
    state: SlotState,
    id: u32,
    total: usize,
    received: usize,
    next_sequence: u8,
    touched_ms: u64,
    buf: [u8; MAX],
}

impl<const MAX: usize> CanSlot<MAX> {
    const EMPTY: Self = CanSlot {
        state: SlotState::Free,
        id: 0,
        total: 0,
        received: 0,
        next_sequence: 0,
        touched_ms: 0,
        buf: [0; MAX],
    };
}

enum Ready {
    Single(usize),
    Slot(usize, usize),
}

/// Reassembles frames from a bus into packets of at most `MAX` bytes, with `SLOTS` multi-frame
/// messages in progress at once (one per CAN id).
///
/// Single frames bypass the slots, so heartbeats and acknowledgements never evict a long
/// message in progress.
pub struct CanReassembler<const SLOTS: usize, const MAX: usize> {
    kind: CanKind,
    timeout_ms: u64,
    slots: [CanSlot<MAX>; SLOTS],
    single: [u8; 64],
    stats: CanStats,
}

impl<const SLOTS: usize, const MAX: usize> CanReassembler<SLOTS, MAX> {
    /// An incomplete message is dropped once `timeout_ms` pass without a frame of it. Frames
    /// longer than `kind` allows are refused.
    pub const fn new(kind: CanKind, timeout_ms: u64) -> Self {
        CanReassembler {
            kind,
            timeout_ms,
            slots: [CanSlot::EMPTY; SLOTS],
            single: [0; 64],
            stats: CanStats {
                messages: 0,
                frames: 0,
                errors: 0,
                sequence_errors: 0,
                aborted: 0,
                expired: 0,
                evicted: 0,
            },
        }
    }

    pub fn stats(&self) -> CanStats {
        self.stats
    }

    /// Messages in progress.
    pub fn in_progress(&self) -> usize {
        self.slots.iter().filter(|slot| slot.state == SlotState::Receiving).count()
    }

    /// Drops the messages that timed out by `now_ms`; [`CanReassembler::push`] does this too.
    pub fn expire(&mut self, now_ms: u64) {
        let timeout_ms = self.timeout_ms;
        for slot in self.slots.iter_mut().filter(|slot| slot.state != SlotState::Free) {
            if now_ms.saturating_sub(slot.touched_ms) >= timeout_ms {
                if slot.state == SlotState::Receiving {
                    self.stats.expired = self.stats.expired.saturating_add(1);
                }
                slot.state = SlotState::Free;
            }
        }
    }

    /// Takes one frame received at `now_ms`. Returns the packet when this frame completes one;
    /// the slice is valid until the next call.
    pub fn push(&mut self, now_ms: u64, frame: &CanFrame) -> Result<Option<&[u8]>, FrameError> {
        self.stats.frames = self.stats.frames.saturating_add(1);
        match self.accept(now_ms, frame) {
            Err(error) => {
                self.stats.errors = self.stats.errors.saturating_add(1);
                Err(error)
            }
            Ok(None) => Ok(None),
            Ok(Some(Ready::Single(len))) => Ok(self.single.get(..len)),
            Ok(Some(Ready::Slot(index, len))) => Ok(self.slots.get(index).and_then(|slot| slot.buf.get(..len))),
        }
    }

    fn accept(&mut self, now_ms: u64, frame: &CanFrame) -> Result<Option<Ready>, FrameError> {
        self.expire(now_ms);
        let len = usize::from(frame.len);
        if self.kind.padded_len(len) != Some(len) {
            return Err(FrameError::InvalidCanLength(len));
        }
        if frame.id > CAN_ID_MASK || !frame.extended {
            return Err(FrameError::InvalidCanId(frame.id));
        }
        let data = frame.data();
        let Some((&pci, rest)) = data.split_first() else {
            return Err(FrameError::Malformed);
        };
        match pci >> 4 {
            PCI_SINGLE => self.single_frame(frame.id, pci, rest, data.len()),
            PCI_FIRST => self.first_frame(now_ms, frame.id, pci, rest, data.len()),
            PCI_CONSECUTIVE => self.consecutive_frame(now_ms, frame.id, pci, rest),
            // Flow control (3) is never sent on these buses, and 4..=15 are undefined.
            _ => Err(FrameError::Malformed),
        }
    }

    fn single_frame(&mut self, id: u32, pci: u8, rest: &[u8], frame_len: usize) -> Result<Option<Ready>, FrameError> {
        let payload = if frame_len <= 8 {
            rest.get(..usize::from(pci & 0x0F))
        } else if pci & 0x0F == 0 {
            rest.split_first().and_then(|(&len, payload)| payload.get(..usize::from(len)))
        } else {
            None
        };
        let payload = payload.ok_or(FrameError::Malformed)?;
        // The sender has given up the message it was sending on this id, if any.
        self.release(id);
        if payload.len() > MAX {
            return Err(FrameError::MessageTooLong { len: payload.len(), max: MAX });
        }
        copy_into(&mut self.single, 0, payload)?;
        self.stats.messages = self.stats.messages.saturating_add(1);
        Ok(Some(Ready::Single(payload.len())))
    }

    fn first_frame(
        &mut self,
        now_ms: u64,
        id: u32,
        pci: u8,
        rest: &[u8],
        frame_len: usize,
    ) -> Result<Option<Ready>, FrameError> {
        if frame_len < 8 {
            return Err(FrameError::Malformed);
        }
        let Some((&low, rest)) = rest.split_first() else {
            return Err(FrameError::Malformed);
        };
        let short_len = usize::from(pci & 0x0F) << 8 | usize::from(low);
        let (total, payload) = if short_len != 0 {
            (short_len, rest)
        } else {
            let Some((length, payload)) = rest.split_first_chunk::<4>() else {
                return Err(FrameError::Malformed);
            };
            (u32::from_be_bytes(*length) as usize, payload)
        };
        let slot_index = self.release(id);
        // A first frame that holds the whole message is not what a sender of ours emits.
        if total <= payload.len() {
            return Err(FrameError::Malformed);
        }
        if total > MAX {
            // Swallow the consecutive frames that follow, if a slot is free for that.
            if let Some(slot) = slot_index.or_else(|| self.free_slot()).and_then(|i| self.slots.get_mut(i)) {
                slot.state = SlotState::Discarding;
                slot.id = id;
                slot.touched_ms = now_ms;
            }
            return Err(FrameError::MessageTooLong { len: total, max: MAX });
        }
        let index = match slot_index.or_else(|| self.free_slot()) {
            Some(index) => index,
            None => self.evict(),
        };
        let slot = self.slots.get_mut(index).ok_or(FrameError::MessageTooLong { len: total, max: 0 })?;
        slot.state = SlotState::Receiving;
        slot.id = id;
        slot.total = total;
        slot.received = payload.len();
        slot.next_sequence = 1;
        slot.touched_ms = now_ms;
        copy_into(&mut slot.buf, 0, payload)?;
        Ok(None)
    }

    fn consecutive_frame(&mut self, now_ms: u64, id: u32, pci: u8, rest: &[u8]) -> Result<Option<Ready>, FrameError> {
        let Some(index) = self.slot_of(id) else {
            return Err(FrameError::UnexpectedConsecutive);
        };
        let slot = self.slots.get_mut(index).ok_or(FrameError::UnexpectedConsecutive)?;
        slot.touched_ms = now_ms;
        if slot.state != SlotState::Receiving {
            return Ok(None);
        }
        let sequence = pci & 0x0F;
        if sequence != slot.next_sequence {
            slot.state = SlotState::Discarding;
            self.stats.sequence_errors = self.stats.sequence_errors.saturating_add(1);
            return Err(FrameError::SequenceMismatch { expected: slot.next_sequence, got: sequence });
        }
        slot.next_sequence = (sequence + 1) & 0x0F;
        // Bytes past the message are padding.
        let take = rest.len().min(slot.total - slot.received);
        copy_into(&mut slot.buf, slot.received, rest.get(..take).unwrap_or_default())?;
        slot.received += take;
        if slot.received < slot.total {
            return Ok(None);
        }
        slot.state = SlotState::Free;
        self.stats.messages = self.stats.messages.saturating_add(1);
        Ok(Some(Ready::Slot(index, slot.total)))
    }

    fn slot_of(&self, id: u32) -> Option<usize> {
        self.slots.iter().position(|slot| slot.state != SlotState::Free && slot.id == id)
    }

    fn free_slot(&self) -> Option<usize> {
        self.slots.iter().position(|slot| slot.state == SlotState::Free)
    }

    /// Ends whatever is in progress on `id` and returns its (now free) slot.
    fn release(&mut self, id: u32) -> Option<usize> {
        let index = self.slot_of(id)?;
        let slot = self.slots.get_mut(index)?;
        if slot.state == SlotState::Receiving {
            self.stats.aborted = self.stats.aborted.saturating_add(1);
        }
        slot.state = SlotState::Free;
        Some(index)
    }

    /// Frees a slot when all are busy: one that only swallows frames of a failed message if
    /// there is one, else the message that waited longest for a frame.
    fn evict(&mut self) -> usize {
        if let Some(index) = self.slots.iter().position(|slot| slot.state == SlotState::Discarding) {
            return index;
        }
        self.stats.evicted = self.stats.evicted.saturating_add(1);
        self.slots.iter().enumerate().min_by_key(|(_, slot)| slot.touched_ms).map_or(0, |(index, _)| index)
    }
}

impl<const SLOTS: usize, const MAX: usize> core::fmt::Debug for CanReassembler<SLOTS, MAX> {
    // Buffers of partial messages are of no use in a log.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("CanReassembler")
            .field("kind", &self.kind)
            .field("slots", &SLOTS)
            .field("max_bytes", &MAX)
            .field("timeout_ms", &self.timeout_ms)
            .field("in_progress", &self.in_progress())
            .field("stats", &self.stats)
            .finish()
    }
}
