//! Reliable, in-order channels: a sender with a bounded window of stored packets and a receiver
//! with a bounded reorder buffer. Both are sans-IO and know nothing of peers or priorities; the
//! [`super::Endpoint`] keeps one sender per (peer, channel) it sends to and one receiver per
//! (peer, channel) it receives from.
//!
//! Sequence numbers are `u32` per (source, destination, channel) stream, start at 0 and are
//! compared in serial-number arithmetic (RFC 1982), so the streams survive wrapping.

use crate::codec::MAX_PACKET_BYTES;
use crate::delivery::rtt::RttEstimator;
use crate::message::Ack;

/// Bits of selective acknowledgement in an [`Ack`].
pub const SACK_BITS: u32 = 32;

/// A packet counts as lost (fast retransmit) once this many packets transmitted after it have
/// been acknowledged (TCP's duplicate-ack threshold, counted on selective acknowledgements).
pub const FAST_RETRANSMIT_THRESHOLD: usize = 3;

/// Whether serial number `a` is before `b` (RFC 1982, 32-bit).
fn serial_lt(a: u32, b: u32) -> bool {
    a != b && b.wrapping_sub(a) < (1 << 31)
}

#[derive(Debug, Clone)]
struct TxSlot {
    bytes: [u8; MAX_PACKET_BYTES],
    len: u16,
    /// Times transmitted (0: not yet).
    transmissions: u32,
    last_sent_ms: u64,
    /// Order of the last transmission within the channel (for fast retransmit).
    tx_order: u64,
    /// Selectively acknowledged: the receiver holds it, never resend.
    sacked: bool,
    /// Deemed lost by fast retransmit: resend now, without waiting for the timeout.
    lost: bool,
}

impl TxSlot {
    const EMPTY: TxSlot = TxSlot {
        bytes: [0; MAX_PACKET_BYTES],
        len: 0,
        transmissions: 0,
        last_sent_ms: 0,
        tx_order: 0,
        sacked: false,
        lost: false,
    };

    fn packet(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&[])
    }
}

/// Why [`ReliableSender::push_with`] stored nothing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PushError<E> {
    /// `W` packets are stored (unsent or unacknowledged): back-pressure.
    Full,
    /// The encoder failed.
    Encode(E),
}

/// An acknowledgement that does not fit the sender's state: it acknowledges packets never sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BogusAck;

/// What an acknowledgement changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct AckOutcome {
    /// Packets released from the window (cumulatively acknowledged).
    pub released: usize,
    /// Packets newly acknowledged selectively.
    pub newly_sacked: usize,
    /// RTT of the most recently sent newly acknowledged packet that was transmitted once.
    pub rtt_sample_ms: Option<u64>,
    /// Packets newly deemed lost (to be fast-retransmitted).
    pub newly_lost: usize,
}

/// Which packet to transmit next, and whether it is a retransmission.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TxChoice {
    pub seq: u32,
    pub retransmission: bool,
    /// A fast retransmission (deemed lost from selective acknowledgements, not a timeout).
    pub fast: bool,
}

/// Sender side of one reliable channel: up to `W` stored packets, the encoded bytes as first
/// sent (so authenticated packets are resent unchanged). Stored packets are the window: the
/// first [`ReliableSender::in_flight`] have been transmitted and wait for acknowledgement, the
/// rest are queued. Memory: `W · (MAX_PACKET_BYTES + 40)` bytes.
#[derive(Debug, Clone)]
pub struct ReliableSender<const W: usize> {
    slots: [TxSlot; W],
    /// Ring index of `base`.
    head: usize,
    /// Sequence number of the oldest stored packet.
    base: u32,
    /// Stored packets: `base .. base + count`.
    count: usize,
    /// Of the stored packets, the first `sent` have been transmitted at least once.
    sent: usize,
    tx_counter: u64,
}

impl<const W: usize> Default for ReliableSender<W> {
    fn default() -> Self {
        Self::new()
    }
}

impl<const W: usize> ReliableSender<W> {
    const WINDOW_OK: () = assert!(W >= 1 && W <= 1 << 16, "window must be 1..=65536 packets");

    pub fn new() -> Self {
        let () = Self::WINDOW_OK;
        ReliableSender { slots: [const { TxSlot::EMPTY }; W], head: 0, base: 0, count: 0, sent: 0, tx_counter: 0 }
    }

    fn index(&self, offset: usize) -> usize {
        (self.head + offset) % W
    }

    fn offset_of(&self, seq: u32) -> Option<usize> {
        let offset = seq.wrapping_sub(self.base) as usize;
        (offset < self.count).then_some(offset)
    }

    /// Sequence number the next pushed packet gets.
    pub fn next_seq(&self) -> u32 {
        self.base.wrapping_add(self.count as u32)
    }

    /// Oldest unacknowledged sequence number.
    pub fn base(&self) -> u32 {
        self.base
    }

    /// Packets stored (queued + in flight).
    pub fn stored(&self) -> usize {
        self.count
    }

    /// Packets transmitted at least once and not yet cumulatively acknowledged.
    pub fn in_flight(&self) -> usize {
        self.sent
    }

    /// Packets not yet transmitted.
    pub fn queued(&self) -> usize {
        self.count - self.sent
    }

    pub fn is_full(&self) -> bool {
        self.count >= W
    }

    /// Stores a new packet: `encode(seq, buffer)` writes it into the window's buffer and returns
    /// its length. Returns the packet's sequence number.
    pub fn push_with<E>(
        &mut self,
        encode: impl FnOnce(u32, &mut [u8]) -> Result<usize, E>,
    ) -> Result<u32, PushError<E>> {
        if self.is_full() {
            return Err(PushError::Full);
        }
        let seq = self.next_seq();
        let index = self.index(self.count);
        let slot = &mut self.slots[index];
        let len = encode(seq, &mut slot.bytes).map_err(PushError::Encode)?;
        slot.len = len.min(MAX_PACKET_BYTES) as u16;
        slot.transmissions = 0;
        slot.last_sent_ms = 0;
        slot.tx_order = 0;
        slot.sacked = false;
        slot.lost = false;
        self.count += 1;
        Ok(seq)
    }

    /// The stored bytes of packet `seq`.
    pub fn packet(&self, seq: u32) -> Option<&[u8]> {
        let offset = self.offset_of(seq)?;
        Some(self.slots[self.index(offset)].packet())
    }

    fn due(&self, now_ms: u64, rtt: &RttEstimator, offset: usize) -> Option<bool> {
        let slot = &self.slots[self.index(offset)];
        if slot.sacked {
            return None;
        }
        if slot.lost {
            return Some(true);
        }
        let deadline = slot.last_sent_ms.saturating_add(rtt.timeout_ms());
        (now_ms >= deadline).then_some(false)
    }

    /// The oldest packet due for retransmission (deemed lost, or its timeout expired).
    pub fn due_retransmission(&self, now_ms: u64, rtt: &RttEstimator) -> Option<TxChoice> {
        (0..self.sent).find_map(|offset| {
            self.due(now_ms, rtt, offset).map(|fast| TxChoice {
                seq: self.base.wrapping_add(offset as u32),
                retransmission: true,
                fast,
            })
        })
    }

    /// The oldest packet not transmitted yet.
    pub fn next_new(&self) -> Option<TxChoice> {
        (self.sent < self.count).then(|| TxChoice {
            seq: self.base.wrapping_add(self.sent as u32),
            retransmission: false,
            fast: false,
        })
    }

    /// Retransmissions first, then new data.
    pub fn next_to_send(&self, now_ms: u64, rtt: &RttEstimator) -> Option<TxChoice> {
        self.due_retransmission(now_ms, rtt).or_else(|| self.next_new())
    }

    /// When the earliest retransmission timer of a packet in flight expires (`now_ms` or
    /// earlier if one is due already).
    pub fn next_timer_ms(&self, rtt: &RttEstimator) -> Option<u64> {
        (0..self.sent)
            .filter_map(|offset| {
                let slot = &self.slots[self.index(offset)];
                if slot.sacked {
                    None
                } else if slot.lost {
                    Some(0)
                } else {
                    Some(slot.last_sent_ms.saturating_add(rtt.timeout_ms()))
                }
            })
            .min()
    }

    /// Records that packet `seq` was put on the link at `now_ms`; returns when it was sent
    /// before, if it was (for [`RttEstimator::on_timeout`]).
    pub fn mark_sent(&mut self, now_ms: u64, seq: u32) -> Option<u64> {
        let offset = self.offset_of(seq)?;
        if offset >= self.sent {
            // New data goes out in order; the endpoint only offers the first unsent packet.
            self.sent = offset + 1;
        }
        self.tx_counter += 1;
        let index = self.index(offset);
        let slot = &mut self.slots[index];
        let previous = (slot.transmissions > 0).then_some(slot.last_sent_ms);
        slot.transmissions = slot.transmissions.saturating_add(1);
        slot.last_sent_ms = now_ms;
        slot.tx_order = self.tx_counter;
        slot.lost = false;
        previous
    }

    /// Processes an acknowledgement: `next_expected` cumulative, bit `i` of `received_mask`
    /// for `next_expected + 1 + i`. Stale acknowledgements (reordered behind newer ones) are
    /// harmless; one acknowledging packets never sent is rejected whole.
    pub fn on_ack(&mut self, now_ms: u64, next_expected: u32, received_mask: u32) -> Result<AckOutcome, BogusAck> {
        let cumulative = next_expected.wrapping_sub(self.base);
        let stale = cumulative >= 1 << 31;
        if !stale && cumulative as usize > self.sent {
            return Err(BogusAck);
        }
        let mut outcome = AckOutcome::default();
        let mut sample: Option<(u64, u64)> = None; // (last_sent_ms, tx_order) of the sample
        let consider = |slot: &TxSlot, sample: &mut Option<(u64, u64)>| {
            if slot.transmissions == 1 && sample.is_none_or(|(_, order)| slot.tx_order > order) {
                *sample = Some((slot.last_sent_ms, slot.tx_order));
            }
        };

        // Selective part first, relative to the acknowledgement's own `next_expected`.
        for bit in 0..SACK_BITS {
            if received_mask & (1 << bit) == 0 {
                continue;
            }
            let seq = next_expected.wrapping_add(1 + bit);
            let offset = seq.wrapping_sub(self.base) as usize;
            if offset >= self.sent {
                continue; // before the window (stale) or never sent: ignore the bit
            }
            let index = self.index(offset);
            let slot = &mut self.slots[index];
            if !slot.sacked {
                slot.sacked = true;
                outcome.newly_sacked += 1;
                consider(slot, &mut sample);
            }
        }

        // Cumulative part: release acknowledged packets from the window.
        if !stale {
            let released = cumulative as usize;
            for offset in 0..released {
                let slot = &self.slots[self.index(offset)];
                if !slot.sacked {
                    consider(slot, &mut sample);
                }
            }
            self.head = (self.head + released) % W;
            self.base = next_expected;
            self.count -= released;
            self.sent -= released;
            outcome.released = released;
        }

        outcome.rtt_sample_ms = sample.map(|(sent_ms, _)| now_ms.saturating_sub(sent_ms));
        if outcome.newly_sacked > 0 {
            outcome.newly_lost = self.mark_lost();
        }
        Ok(outcome)
    }

    /// Fast retransmit: a packet in flight is lost once `FAST_RETRANSMIT_THRESHOLD` packets
    /// transmitted after it have been selectively acknowledged.
    fn mark_lost(&mut self) -> usize {
        let mut newly_lost = 0;
        for offset in 0..self.sent {
            let index = self.index(offset);
            let (sacked, lost, order) = {
                let slot = &self.slots[index];
                (slot.sacked, slot.lost, slot.tx_order)
            };
            if sacked || lost {
                continue;
            }
            let later_acked = (0..self.sent)
                .filter(|&other| {
                    let slot = &self.slots[self.index(other)];
                    slot.sacked && slot.tx_order > order
                })
                .take(FAST_RETRANSMIT_THRESHOLD)
                .count();
            if later_acked >= FAST_RETRANSMIT_THRESHOLD {
                self.slots[index].lost = true;
                newly_lost += 1;
            }
        }
        newly_lost
    }
}

/// How a received sequence number relates to the receiver's window.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Arrival {
    /// The next one to deliver.
    Next,
    /// Inside the window, after a gap.
    Ahead,
    /// Delivered or buffered already.
    Duplicate,
    /// Beyond the window: the sender cannot have sent it (or state was lost on one side).
    OutOfWindow,
}

/// Receiver side of one reliable channel: a reorder buffer of `N` items (handles to packets, or
/// the packets themselves) for sequence numbers `next .. next + N`.
///
/// Every item is handed out by [`ReliableReceiver::pop_ready`] exactly once and in sequence
/// order; duplicates and out-of-window numbers are refused. Buffered items count as received in
/// the acknowledgement (they are never dropped afterwards), whether or not the application has
/// taken them yet.
#[derive(Debug, Clone)]
pub struct ReliableReceiver<T, const N: usize> {
    slots: [Option<T>; N],
    /// Ring index of `next`.
    head: usize,
    /// Next sequence number to hand out.
    next: u32,
}

impl<T, const N: usize> Default for ReliableReceiver<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T, const N: usize> ReliableReceiver<T, N> {
    const WINDOW_OK: () = assert!(N >= 1 && N < 1 << 31, "reorder window must be at least 1");

    pub fn new() -> Self {
        let () = Self::WINDOW_OK;
        ReliableReceiver { slots: core::array::from_fn(|_| None), head: 0, next: 0 }
    }

    fn index(&self, offset: usize) -> usize {
        (self.head + offset) % N
    }

    /// Next sequence number to hand out.
    pub fn next_seq(&self) -> u32 {
        self.next
    }

    /// Items buffered (in order or not) and not handed out yet.
    pub fn buffered(&self) -> usize {
        self.slots.iter().filter(|slot| slot.is_some()).count()
    }

    pub fn classify(&self, seq: u32) -> Arrival {
        let offset = seq.wrapping_sub(self.next);
        if offset >= 1 << 31 {
            Arrival::Duplicate
        } else if offset as usize >= N {
            Arrival::OutOfWindow
        } else if self.slots[self.index(offset as usize)].is_some() {
            Arrival::Duplicate
        } else if offset == 0 {
            Arrival::Next
        } else {
            Arrival::Ahead
        }
    }

    /// Buffers `item` under `seq`; gives it back unless `seq` is [`Arrival::Next`] or
    /// [`Arrival::Ahead`].
    pub fn insert(&mut self, seq: u32, item: T) -> Result<Arrival, (Arrival, T)> {
        match self.classify(seq) {
            arrival @ (Arrival::Next | Arrival::Ahead) => {
                let index = self.index(seq.wrapping_sub(self.next) as usize);
                self.slots[index] = Some(item);
                Ok(arrival)
            }
            other => Err((other, item)),
        }
    }

    /// Marks the [`Arrival::Next`] sequence number as handed out directly by the caller
    /// (without buffering it). Does nothing if `seq` is not the next one.
    pub fn skip_next(&mut self, seq: u32) {
        if self.classify(seq) == Arrival::Next {
            self.advance();
        }
    }

    fn advance(&mut self) {
        self.slots[self.head] = None;
        self.head = (self.head + 1) % N;
        self.next = self.next.wrapping_add(1);
    }

    /// Whether the next item in order is buffered.
    pub fn has_ready(&self) -> bool {
        self.slots[self.head].is_some()
    }

    /// The next item in order, if buffered.
    pub fn pop_ready(&mut self) -> Option<(u32, T)> {
        let item = self.slots[self.head].take()?;
        let seq = self.next;
        self.advance();
        Some((seq, item))
    }

    /// The acknowledgement of this channel: everything below the first gap, plus a mask of the
    /// 32 sequence numbers after it.
    pub fn ack(&self, channel: u8) -> Ack {
        let run = (0..N).take_while(|&offset| self.slots[self.index(offset)].is_some()).count();
        let next_expected = self.next.wrapping_add(run as u32);
        let mut received_mask = 0u32;
        for bit in 0..SACK_BITS {
            let offset = run + 1 + bit as usize;
            if offset < N && self.slots[self.index(offset)].is_some() {
                received_mask |= 1 << bit;
            }
        }
        Ack { channel, next_expected, received_mask }
    }

    /// Clears the reorder buffer and restarts at sequence number 0 (peer restarted), giving
    /// back the items that were buffered.
    pub fn reset(&mut self, mut release: impl FnMut(T)) {
        for slot in &mut self.slots {
            if let Some(item) = slot.take() {
                release(item);
            }
        }
        self.head = 0;
        self.next = 0;
    }
}

/// Whether `a` comes before `b` in a reliable stream (serial-number arithmetic).
pub fn seq_before(a: u32, b: u32) -> bool {
    serial_lt(a, b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::delivery::rtt::{RtoConfig, RttEstimator};

    fn push(sender: &mut ReliableSender<8>, byte: u8) -> u32 {
        match sender.push_with(|_, buf: &mut [u8]| -> Result<usize, ()> {
            buf[0] = byte;
            Ok(1)
        }) {
            Ok(seq) => seq,
            Err(e) => panic!("{e:?}"),
        }
    }

    #[test]
    fn sender_releases_on_cumulative_ack_and_samples_rtt() {
        let mut rtt = RttEstimator::new(RtoConfig::default());
        let mut sender = ReliableSender::<8>::new();
        for i in 0..3 {
            push(&mut sender, i);
        }
        for _ in 0..3 {
            let choice = sender.next_to_send(0, &rtt).unwrap();
            assert!(!choice.retransmission);
            sender.mark_sent(10, choice.seq);
        }
        assert_eq!(sender.next_to_send(10, &rtt), None);
        let outcome = sender.on_ack(60, 2, 0).unwrap();
        assert_eq!(outcome.released, 2);
        assert_eq!(outcome.rtt_sample_ms, Some(50));
        // (The sample is not fed to `rtt`, to keep the initial 1 s RTO.)
        assert_eq!(sender.base(), 2);
        assert_eq!(sender.packet(2), Some(&[2u8][..]));
        assert_eq!(sender.on_ack(60, 5, 0), Err(BogusAck));
        // Times out after the initial RTO, then backs off.
        assert_eq!(sender.next_timer_ms(&rtt), Some(1_010));
        let choice = sender.next_to_send(1_010, &rtt).unwrap();
        assert!(choice.retransmission && !choice.fast);
        let previous = sender.mark_sent(1_010, choice.seq);
        assert_eq!(previous, Some(10));
        rtt.on_timeout(1_010, 10);
        assert_eq!(sender.next_timer_ms(&rtt), Some(3_010));
    }

    #[test]
    fn sack_gaps_trigger_fast_retransmit() {
        let rtt = RttEstimator::new(RtoConfig::default());
        let mut sender = ReliableSender::<8>::new();
        for i in 0..5 {
            push(&mut sender, i);
            sender.mark_sent(0, u32::from(i));
        }
        // 0 lost; 1, 2, 3 received.
        let outcome = sender.on_ack(5, 0, 0b111).unwrap();
        assert_eq!(outcome.newly_sacked, 3);
        assert_eq!(outcome.newly_lost, 1);
        let choice = sender.next_to_send(5, &rtt).unwrap();
        assert_eq!((choice.seq, choice.retransmission, choice.fast), (0, true, true));
    }

    #[test]
    fn receiver_acks_buffered_runs_and_gaps() {
        let mut rx = ReliableReceiver::<u8, 8>::new();
        assert_eq!(rx.insert(1, 1), Ok(Arrival::Ahead));
        assert_eq!(rx.insert(3, 3), Ok(Arrival::Ahead));
        assert_eq!(rx.ack(2), Ack { channel: 2, next_expected: 0, received_mask: 0b101 });
        assert_eq!(rx.insert(0, 0), Ok(Arrival::Next));
        assert_eq!(rx.ack(2), Ack { channel: 2, next_expected: 2, received_mask: 0b1 });
        assert_eq!(rx.insert(1, 9), Err((Arrival::Duplicate, 9)));
        assert_eq!(rx.insert(8, 8), Err((Arrival::OutOfWindow, 8)));
        assert_eq!(rx.pop_ready(), Some((0, 0)));
        assert_eq!(rx.pop_ready(), Some((1, 1)));
        assert_eq!(rx.pop_ready(), None);
        assert_eq!(rx.classify(0), Arrival::Duplicate);
    }
}
