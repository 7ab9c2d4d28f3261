//! Framing for UDP: segmentation of packets into datagrams of at most `mtu` bytes, and
//! reassembly.
//!
//! Every datagram is one fragment:
//!
//! ```text
//! datagram = message id u16 LE | fragment index u16 LE | fragment count u16 LE | payload
//! ```
//!
//! The packet is cut into `count` fragments of `mtu - 6` bytes each, the last one shorter (and
//! empty only for an empty packet, which is one fragment). The receiver therefore learns the
//! fragment size from any fragment but the last, and places fragment `i` at `i * size`.
//! Message ids increase by one per packet and wrap; they only need to be unique among a
//! sender's messages that can be in flight together.
//!
//! Why so little header: UDP already checksums each datagram, and the packet inside is checked
//! by its decoder and, for commands, its MAC. The fragment count is 16 bits although at most
//! [`MAX_FRAGMENTS`] are sent, so that limit can grow without changing the wire format.
//!
//! Why a 1200-byte ceiling: it fits the IPv6 minimum MTU (1280) with room for tunnels, so no
//! datagram of ours is ever IP-fragmented, where losing one IP fragment loses the datagram.

use super::{FrameError, copy_into};

/// Largest datagram (UDP payload) the segmenter emits.
pub const MAX_DATAGRAM_BYTES: usize = 1200;
/// Bytes of the fragment header at the start of each datagram.
pub const FRAGMENT_HEADER_BYTES: usize = 6;
/// Smallest usable MTU: the header and one payload byte.
pub const MIN_MTU: usize = FRAGMENT_HEADER_BYTES + 1;
/// Most fragments per packet. The receiver keeps one bit per fragment to ignore duplicates, so
/// this bounds that bitmap (256 bytes per slot). It still carries 16 KiB packets down to an MTU
/// of 14 bytes, and 116 KiB at an MTU of 64.
pub const MAX_FRAGMENTS: usize = 2048;
/// IPv4 (20 bytes without options) plus UDP (8 bytes) header of every datagram. Link-layer
/// framing (Ethernet, Wi-Fi, radio) differs per link and is left to the link's byte rate.
pub const IP_UDP_HEADER_BYTES: usize = 28;

/// Fragments of a `packet_len`-byte packet at `mtu` (an empty packet is still one fragment).
/// `mtu` is clamped to the supported range, as in [`wire_bytes`].
pub fn fragment_count(mtu: usize, packet_len: usize) -> usize {
    let payload = mtu.clamp(MIN_MTU, MAX_DATAGRAM_BYTES) - FRAGMENT_HEADER_BYTES;
    packet_len.div_ceil(payload).max(1)
}

/// Bytes a `packet_len`-byte packet costs on an IPv4 network at `mtu`: the packet, a fragment
/// header and an IPv4+UDP header of [`IP_UDP_HEADER_BYTES`] per datagram. An `mtu` outside
/// `MIN_MTU..=MAX_DATAGRAM_BYTES` (which [`Segmenter::new`] refuses) is clamped into it.
pub fn wire_bytes(mtu: usize, packet_len: usize) -> usize {
    let per_datagram = FRAGMENT_HEADER_BYTES + IP_UDP_HEADER_BYTES;
    packet_len.saturating_add(fragment_count(mtu, packet_len).saturating_mul(per_datagram))
}

/// Cuts packets into datagrams for one sender socket.
#[derive(Debug, Clone)]
pub struct Segmenter {
    mtu: usize,
    next_id: u16,
}

impl Segmenter {
    /// `mtu` is the largest UDP payload to emit, `MIN_MTU..=MAX_DATAGRAM_BYTES`.
    pub fn new(mtu: usize) -> Result<Self, FrameError> {
        Self::with_first_id(mtu, 0)
    }

    /// Like [`Segmenter::new`], numbering messages from `first_id`. A sender that restarts
    /// often can start at a random id, so receivers do not take its new messages for
    /// duplicates or continuations of ones from before the restart.
    pub fn with_first_id(mtu: usize, first_id: u16) -> Result<Self, FrameError> {
        if !(MIN_MTU..=MAX_DATAGRAM_BYTES).contains(&mtu) {
            return Err(FrameError::InvalidMtu(mtu));
        }
        Ok(Segmenter { mtu, next_id: first_id })
    }

    pub fn mtu(&self) -> usize {
        self.mtu
    }

    /// The id the next packet will carry.
    pub fn next_id(&self) -> u16 {
        self.next_id
    }

    /// Emits `packet` as datagrams and returns how many. The datagram slice is only valid
    /// during the call to `emit`.
    pub fn segment(&mut self, packet: &[u8], mut emit: impl FnMut(&[u8])) -> Result<usize, FrameError> {
        let payload_max = self.mtu - FRAGMENT_HEADER_BYTES;
        let count = fragment_count(self.mtu, packet.len());
        if count > MAX_FRAGMENTS {
            return Err(FrameError::PacketTooLong { len: packet.len(), max: MAX_FRAGMENTS * payload_max });
        }
        let id = self.next_id;
        self.next_id = id.wrapping_add(1);

        let mut datagram = [0u8; MAX_DATAGRAM_BYTES];
        let mut chunks = packet.chunks(payload_max);
        for index in 0..count {
            let payload = chunks.next().unwrap_or_default();
            let header = FragmentHeader { id, index: index as u16, count: count as u16 };
            let len = FRAGMENT_HEADER_BYTES + payload.len();
            let Some((head, body)) =
                datagram.get_mut(..len).and_then(|d| d.split_at_mut_checked(FRAGMENT_HEADER_BYTES))
            else {
                return Err(FrameError::BufferTooSmall);
            };
            head.copy_from_slice(&header.to_bytes());
            body.copy_from_slice(payload);
            emit(datagram.get(..len).unwrap_or_default());
        }
        Ok(count)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct FragmentHeader {
    id: u16,
    index: u16,
    count: u16,
}

impl FragmentHeader {
    fn to_bytes(self) -> [u8; FRAGMENT_HEADER_BYTES] {
        let [i0, i1] = self.id.to_le_bytes();
        let [x0, x1] = self.index.to_le_bytes();
        let [c0, c1] = self.count.to_le_bytes();
        [i0, i1, x0, x1, c0, c1]
    }

    /// Splits a datagram into a checked header and its payload.
    fn parse(datagram: &[u8]) -> Result<(Self, &[u8]), FrameError> {
        let Some((&[i0, i1, x0, x1, c0, c1], payload)) = datagram.split_first_chunk::<FRAGMENT_HEADER_BYTES>() else {
            return Err(FrameError::Malformed);
        };
        let header = FragmentHeader {
            id: u16::from_le_bytes([i0, i1]),
            index: u16::from_le_bytes([x0, x1]),
            count: u16::from_le_bytes([c0, c1]),
        };
        let count = usize::from(header.count);
        if count == 0 || header.index >= header.count || count > MAX_FRAGMENTS || payload.len() > MAX_DATAGRAM_BYTES {
            return Err(FrameError::Malformed);
        }
        let last = header.index + 1 == header.count;
        // Only an empty packet has an empty fragment, and it is a single fragment.
        if payload.is_empty() && (header.count > 1 || !last) {
            return Err(FrameError::Malformed);
        }
        Ok((header, payload))
    }
}

/// Counters of a [`Reassembler`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ReassemblyStats {
    /// Packets delivered.
    pub messages: u64,
    /// Fragments accepted (duplicates not included).
    pub fragments: u64,
    /// Fragments ignored because they had already arrived.
    pub duplicates: u64,
    /// Incomplete messages dropped after `timeout_ms` without a new fragment.
    pub expired: u64,
    /// Incomplete messages dropped to make room for a newer one.
    pub evicted: u64,
    /// Datagrams refused with an error (each `Err` returned by `push`).
    pub errors: u64,
}

const BITMAP_WORDS: usize = MAX_FRAGMENTS / 32;
/// Recently completed messages remembered to recognise their late duplicates.
const HISTORY: usize = 16;

/// A message being reassembled.
struct Slot<const MAX: usize> {
    used: bool,
    source: u64,
    id: u16,
    count: u16,
    received: u16,
    /// Payload bytes of every fragment but the last; 0 until such a fragment arrives.
    fragment_len: usize,
    /// Length of the last fragment; 0 until it arrives (it is never empty in a multi-fragment
    /// message).
    last_len: usize,
    /// The last fragment arrived before the fragment size was known, so its offset was not: it
    /// waits at the end of the buffer, which no other fragment reaches before it is moved.
    last_parked: bool,
    touched_ms: u64,
    seen: [u32; BITMAP_WORDS],
    buf: [u8; MAX],
}

impl<const MAX: usize> Slot<MAX> {
    const EMPTY: Self = Slot {
        used: false,
        source: 0,
        id: 0,
        count: 0,
        received: 0,
        fragment_len: 0,
        last_len: 0,
        last_parked: false,
        touched_ms: 0,
        seen: [0; BITMAP_WORDS],
        buf: [0; MAX],
    };

    fn start(&mut self, now_ms: u64, source: u64, header: FragmentHeader) {
        self.used = true;
        self.source = source;
        self.id = header.id;
        self.count = header.count;
        self.received = 0;
        self.fragment_len = 0;
        self.last_len = 0;
        self.last_parked = false;
        self.touched_ms = now_ms;
        self.seen = [0; BITMAP_WORDS];
    }

    fn seen(&self, index: u16) -> bool {
        let index = usize::from(index);
        self.seen.get(index / 32).is_some_and(|word| word & (1 << (index % 32)) != 0)
    }

    fn mark(&mut self, index: u16) {
        let index = usize::from(index);
        if let Some(word) = self.seen.get_mut(index / 32) {
            *word |= 1 << (index % 32);
        }
    }

    /// Offset of the last fragment once the fragment size is known.
    fn last_offset(&self) -> usize {
        usize::from(self.count - 1) * self.fragment_len
    }

    /// Stores a fragment's payload; on error the caller drops the message.
    fn store(&mut self, index: u16, payload: &[u8]) -> Result<(), FrameError> {
        let last = index + 1 == self.count;
        if last {
            self.last_len = payload.len();
            if self.fragment_len == 0 {
                // Offset unknown: park it at the end. Only the bound every fragment size
                // implies can be checked yet.
                let at_least = usize::from(self.count - 1) + payload.len();
                let start = MAX.checked_sub(payload.len()).filter(|_| at_least <= MAX);
                let start = start.ok_or(FrameError::MessageTooLong { len: at_least, max: MAX })?;
                self.last_parked = true;
                return copy_into(&mut self.buf, start, payload);
            }
            if payload.len() > self.fragment_len {
                return Err(FrameError::InconsistentFragments);
            }
            let offset = self.last_offset();
            return copy_into(&mut self.buf, offset, payload);
        }

        if self.fragment_len == 0 {
            self.fragment_len = payload.len();
            let len = self.last_offset() + self.last_len.max(1);
            if len > MAX {
                return Err(FrameError::MessageTooLong { len, max: MAX });
            }
            if self.last_parked {
                if self.last_len > self.fragment_len {
                    return Err(FrameError::InconsistentFragments);
                }
                // The message fits, so the target lies before the parked bytes or on them.
                let parked = MAX - self.last_len..MAX;
                let offset = self.last_offset();
                if self.buf.get(parked.clone()).is_none() || self.buf.get(offset..offset + self.last_len).is_none() {
                    return Err(FrameError::MessageTooLong { len, max: MAX });
                }
                self.buf.copy_within(parked, offset);
                self.last_parked = false;
            }
        } else if payload.len() != self.fragment_len {
            return Err(FrameError::InconsistentFragments);
        }
        copy_into(&mut self.buf, usize::from(index) * self.fragment_len, payload)
    }

    fn total_len(&self) -> usize {
        self.last_offset() + self.last_len
    }
}

/// A message delivered recently, to ignore its late duplicates instead of starting a message
/// that could never complete.
#[derive(Clone, Copy)]
struct Done {
    used: bool,
    source: u64,
    id: u16,
    count: u16,
    at_ms: u64,
}

impl Done {
    const EMPTY: Self = Done { used: false, source: 0, id: 0, count: 0, at_ms: 0 };
}

/// Where a completed packet lies.
enum Ready {
    Single(usize),
    Slot(usize, usize),
}

/// Reassembles datagrams from any number of senders into packets of at most `MAX` bytes, with
/// `SLOTS` multi-fragment messages in progress at once.
///
/// UDP may duplicate, reorder and lose datagrams, so: a message is keyed by (source, message
/// id) and fragments are placed by index in any order; a fragment already received is ignored,
/// and so is one of a message delivered within the last `timeout_ms` (the last 16 messages are
/// remembered), so a late duplicate cannot start a message that never completes. A message
/// missing a fragment expires; when all slots are busy, the message that waited longest for a
/// fragment is evicted. Single-fragment packets (the common case) bypass the slots, so they
/// never evict a large message in progress.
pub struct Reassembler<const SLOTS: usize, const MAX: usize> {
    timeout_ms: u64,
    slots: [Slot<MAX>; SLOTS],
    history: [Done; HISTORY],
    history_next: usize,
    single: [u8; MAX_DATAGRAM_BYTES],
    stats: ReassemblyStats,
}

impl<const SLOTS: usize, const MAX: usize> Reassembler<SLOTS, MAX> {
    /// An incomplete message is dropped once `timeout_ms` pass without a new fragment of it:
    /// a message still arriving at a low rate is kept, a message missing a fragment is not.
    pub const fn new(timeout_ms: u64) -> Self {
        Reassembler {
            timeout_ms,
            slots: [Slot::EMPTY; SLOTS],
            history: [Done::EMPTY; HISTORY],
            history_next: 0,
            single: [0; MAX_DATAGRAM_BYTES],
            stats: ReassemblyStats { messages: 0, fragments: 0, duplicates: 0, expired: 0, evicted: 0, errors: 0 },
        }
    }

    pub fn stats(&self) -> ReassemblyStats {
        self.stats
    }

    /// Messages in progress.
    pub fn in_progress(&self) -> usize {
        self.slots.iter().filter(|slot| slot.used).count()
    }

    /// Drops the messages that timed out by `now_ms`. [`Reassembler::push`] does this too; call
    /// it when no datagrams arrive to free their memory for statistics' sake.
    pub fn expire(&mut self, now_ms: u64) {
        let timeout_ms = self.timeout_ms;
        for slot in self.slots.iter_mut().filter(|slot| slot.used) {
            if now_ms.saturating_sub(slot.touched_ms) >= timeout_ms {
                slot.used = false;
                self.stats.expired = self.stats.expired.saturating_add(1);
            }
        }
        for done in self.history.iter_mut().filter(|done| done.used) {
            if now_ms.saturating_sub(done.at_ms) >= timeout_ms {
                done.used = false;
            }
        }
    }

    /// Takes one datagram from `source` (the caller's key for the sender, e.g. a hash of its
    /// socket address) received at `now_ms`. Returns the packet when this datagram completes
    /// one; the slice is valid until the next call.
    pub fn push(&mut self, now_ms: u64, source: u64, datagram: &[u8]) -> Result<Option<&[u8]>, FrameError> {
        match self.accept(now_ms, source, datagram) {
            Err(error) => {
                self.stats.errors = self.stats.errors.saturating_add(1);
                Err(error)
            }
            Ok(None) => Ok(None),
            Ok(Some(Ready::Single(len))) => Ok(self.single.get(..len)),
            Ok(Some(Ready::Slot(index, len))) => Ok(self.slots.get(index).and_then(|slot| slot.buf.get(..len))),
        }
    }

    fn accept(&mut self, now_ms: u64, source: u64, datagram: &[u8]) -> Result<Option<Ready>, FrameError> {
        self.expire(now_ms);
        let (header, payload) = FragmentHeader::parse(datagram)?;

        let existing = self.slots.iter().position(|s| s.used && s.source == source && s.id == header.id);
        let index = match existing {
            Some(index) => {
                let slot = self.slots.get_mut(index).ok_or(FrameError::Malformed)?;
                if slot.count != header.count {
                    slot.used = false;
                    return Err(FrameError::InconsistentFragments);
                }
                index
            }
            None => {
                if self.recently_done(source, header) {
                    self.stats.duplicates = self.stats.duplicates.saturating_add(1);
                    return Ok(None);
                }
                if header.count == 1 {
                    return self.complete_single(now_ms, source, header, payload);
                }
                self.allocate(now_ms, source, header)
            }
        };

        let slot = self.slots.get_mut(index).ok_or(FrameError::Malformed)?;
        if slot.seen(header.index) {
            self.stats.duplicates = self.stats.duplicates.saturating_add(1);
            return Ok(None);
        }
        if let Err(error) = slot.store(header.index, payload) {
            slot.used = false;
            return Err(error);
        }
        slot.mark(header.index);
        slot.received += 1;
        slot.touched_ms = now_ms;
        self.stats.fragments = self.stats.fragments.saturating_add(1);
        if slot.received < slot.count {
            return Ok(None);
        }
        slot.used = false;
        let len = slot.total_len();
        self.remember(now_ms, source, header);
        self.stats.messages = self.stats.messages.saturating_add(1);
        Ok(Some(Ready::Slot(index, len)))
    }

    fn complete_single(
        &mut self,
        now_ms: u64,
        source: u64,
        header: FragmentHeader,
        payload: &[u8],
    ) -> Result<Option<Ready>, FrameError> {
        let len = payload.len();
        if len > MAX {
            return Err(FrameError::MessageTooLong { len, max: MAX });
        }
        copy_into(&mut self.single, 0, payload)?;
        self.remember(now_ms, source, header);
        self.stats.fragments = self.stats.fragments.saturating_add(1);
        self.stats.messages = self.stats.messages.saturating_add(1);
        Ok(Some(Ready::Single(len)))
    }

    /// A free slot, or else the one that waited longest for a fragment.
    fn allocate(&mut self, now_ms: u64, source: u64, header: FragmentHeader) -> usize {
        let index = match self.slots.iter().position(|slot| !slot.used) {
            Some(index) => index,
            None => {
                self.stats.evicted = self.stats.evicted.saturating_add(1);
                self.slots.iter().enumerate().min_by_key(|(_, slot)| slot.touched_ms).map_or(0, |(index, _)| index)
            }
        };
        if let Some(slot) = self.slots.get_mut(index) {
            slot.start(now_ms, source, header);
        }
        index
    }

    fn recently_done(&self, source: u64, header: FragmentHeader) -> bool {
        self.history
            .iter()
            .any(|done| done.used && done.source == source && done.id == header.id && done.count == header.count)
    }

    fn remember(&mut self, now_ms: u64, source: u64, header: FragmentHeader) {
        if let Some(done) = self.history.get_mut(self.history_next) {
            *done = Done { used: true, source, id: header.id, count: header.count, at_ms: now_ms };
        }
        self.history_next = (self.history_next + 1) % HISTORY;
    }
}

impl<const SLOTS: usize, const MAX: usize> core::fmt::Debug for Reassembler<SLOTS, MAX> {
    // Buffers of partial messages are of no use in a log.
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Reassembler")
            .field("slots", &SLOTS)
            .field("max_bytes", &MAX)
            .field("timeout_ms", &self.timeout_ms)
            .field("in_progress", &self.in_progress())
            .field("stats", &self.stats)
            .finish()
    }
}
