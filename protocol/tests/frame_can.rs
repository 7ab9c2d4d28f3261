//! CAN framing: identifier layout and arbitration order, segmentation on classic and FD buses,
//! reassembly of interleaved senders, detection of lost and reordered frames, expiry, and
//! totality on garbage.

use proptest::collection::vec;
use proptest::prelude::*;
use protocol::frame::FrameError;
use protocol::frame::can::{
    CLASSIC_FRAME_WIRE_BYTES, CanFrame, CanKind, CanReassembler, CanStats, FD_FRAME_WIRE_BYTES, PADDING, can_id,
    can_id_destination, can_id_priority, can_id_source, frame_count, frame_wire_bytes, segment, wire_bytes,
};
use protocol::{MAX_PACKET_BYTES, NodeId, Priority};

const FD_LENGTHS: [usize; 16] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64];
type Receiver = CanReassembler<4, { 8 * 1024 }>;

fn frames(kind: CanKind, id: u32, packet: &[u8]) -> Result<Vec<CanFrame>, FrameError> {
    let mut out = Vec::new();
    let count = segment(kind, id, packet, |f| out.push(*f))?;
    assert_eq!(count, out.len());
    Ok(out)
}

fn push_all<const S: usize, const M: usize>(
    receiver: &mut CanReassembler<S, M>,
    now_ms: u64,
    frames: &[CanFrame],
) -> Result<Vec<Vec<u8>>, FrameError> {
    let mut delivered = Vec::new();
    for frame in frames {
        if let Some(packet) = receiver.push(now_ms, frame)? {
            delivered.push(packet.to_vec());
        }
    }
    Ok(delivered)
}

fn kind() -> impl Strategy<Value = CanKind> {
    prop_oneof![Just(CanKind::Classic), Just(CanKind::Fd)]
}

fn id() -> impl Strategy<Value = u32> {
    (0usize..Priority::COUNT, any::<u8>(), any::<u8>())
        .prop_map(|(p, s, d)| can_id(Priority::ALL[p], NodeId(s), NodeId(d)))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// Every packet up to the protocol maximum round-trips on both bus kinds; frames have valid
    /// lengths, FD padding is 0xCC, and `wire_bytes` bounds the cost of what was emitted.
    #[test]
    fn round_trip(kind in kind(), id in id(), packet in vec(any::<u8>(), 0..=MAX_PACKET_BYTES)) {
        let sent = frames(kind, id, &packet)?;
        prop_assert_eq!(sent.len(), frame_count(kind, packet.len()));
        let mut cost = 0;
        for frame in &sent {
            prop_assert_eq!(frame.id, id);
            let len = frame.data().len();
            match kind {
                CanKind::Classic => prop_assert!((1..=8).contains(&len)),
                CanKind::Fd => prop_assert!(FD_LENGTHS[1..].contains(&len)),
            }
            cost += frame_wire_bytes(kind, len);
        }
        prop_assert!(cost <= wire_bytes(kind, packet.len()), "{} > {}", cost, wire_bytes(kind, packet.len()));
        // Every frame but the last is full.
        for frame in &sent[..sent.len() - 1] {
            prop_assert_eq!(frame.data().len(), kind.max_data());
        }

        let mut receiver = Receiver::new(kind, 1_000);
        prop_assert_eq!(push_all(&mut receiver, 0, &sent)?, vec![packet.clone()]);
        prop_assert_eq!(receiver.in_progress(), 0);
        prop_assert_eq!(receiver.stats(), CanStats { messages: 1, frames: sent.len() as u64, ..CanStats::default() });

        // Padding: the bytes after the payload in the last frame.
        if kind == CanKind::Fd && sent.len() > 1 {
            let first_payload = kind.max_data() - 2;
            let in_last = (packet.len() - first_payload - 1) % (kind.max_data() - 1) + 1;
            let last = sent[sent.len() - 1].data();
            prop_assert!(last[1 + in_last..].iter().all(|&b| b == PADDING));
        }
    }

    /// Packets around the 12-bit first-frame length limit use the escape encoding above it.
    #[test]
    fn long_packets_use_the_escape_first_frame(kind in kind(), len in 4090usize..4200, fill in any::<u8>()) {
        let packet = vec![fill; len];
        let sent = frames(kind, 0x42, &packet)?;
        let first = sent[0].data();
        if len > 0xFFF {
            prop_assert_eq!(&first[..6], &[0x10, 0, 0, 0, (len >> 8) as u8, len as u8][..]);
        } else {
            prop_assert_eq!(&first[..2], &[0x10 | (len >> 8) as u8, len as u8][..]);
        }
        let mut receiver = Receiver::new(kind, 1_000);
        prop_assert_eq!(push_all(&mut receiver, 0, &sent)?, vec![packet]);
    }

    /// Two senders' messages interleaved frame by frame (and a third sender's single frames in
    /// between) all arrive intact.
    #[test]
    fn interleaved_senders(
        kind in kind(),
        a in vec(any::<u8>(), 0..600),
        b in vec(any::<u8>(), 0..600),
        c in vec(any::<u8>(), 0..=7),
        stride in 1usize..4,
    ) {
        let id_a = can_id(Priority::Bulk, NodeId(1), NodeId::GROUND);
        let id_b = can_id(Priority::Bulk, NodeId(2), NodeId::GROUND);
        let id_c = can_id(Priority::Control, NodeId(3), NodeId::GROUND);
        let (fa, fb) = (frames(kind, id_a, &a)?, frames(kind, id_b, &b)?);
        let fc = frames(kind, id_c, &c)?;
        let mut mixed = Vec::new();
        let (mut ia, mut ib) = (fa.iter(), fb.iter());
        loop {
            let chunk: Vec<CanFrame> = ia.by_ref().take(stride).chain(ib.by_ref().take(1)).copied().collect();
            if chunk.is_empty() {
                break;
            }
            mixed.extend(chunk);
            mixed.extend(&fc);
        }

        let mut receiver = Receiver::new(kind, 1_000);
        let mut got = Vec::new();
        for frame in &mixed {
            if let Some(packet) = receiver.push(0, frame)? {
                got.push((frame.id, packet.to_vec()));
            }
        }
        let from = |id: u32| got.iter().filter(|(i, _)| *i == id).map(|(_, p)| p.clone()).collect::<Vec<_>>();
        prop_assert_eq!(from(id_a), vec![a]);
        prop_assert_eq!(from(id_b), vec![b]);
        prop_assert_eq!(from(id_c).len(), mixed.len() - fa.len() - fb.len());
    }

    /// Dropping any one consecutive frame loses that message with one sequence error (or, for
    /// the last frame, an abort when the next message starts), never a wrong packet; the next
    /// message on the id arrives.
    #[test]
    fn dropped_consecutive_frame_is_detected(
        kind in kind(),
        packet in vec(any::<u8>(), 200..MAX_PACKET_BYTES),
        drop in any::<prop::sample::Index>(),
    ) {
        let sent = frames(kind, 7, &packet)?;
        prop_assume!(sent.len() > 2);
        let dropped = 1 + drop.index(sent.len() - 1);
        let mut receiver = Receiver::new(kind, 1_000);
        let mut results = Vec::new();
        for (i, frame) in sent.iter().enumerate() {
            if i != dropped {
                results.push(receiver.push(0, frame).map(|p| p.map(<[u8]>::to_vec)));
            }
        }
        let lost_or_pending = |r: &Result<Option<Vec<u8>>, FrameError>| {
            matches!(r, Ok(None) | Err(FrameError::SequenceMismatch { .. }))
        };
        prop_assert!(results.iter().all(lost_or_pending), "{:?}", results);
        let errors = results.iter().filter(|r| r.is_err()).count();
        if dropped == sent.len() - 1 {
            prop_assert_eq!(errors, 0);
            prop_assert_eq!(receiver.in_progress(), 1);
        } else {
            prop_assert_eq!(errors, 1);
            prop_assert_eq!(receiver.stats().sequence_errors, 1);
        }

        let next = vec![0x5A; 100];
        prop_assert_eq!(push_all(&mut receiver, 1, &frames(kind, 7, &next)?)?, vec![next]);
        prop_assert_eq!(receiver.stats().aborted, u64::from(dropped == sent.len() - 1));
    }

    /// Random frames, and first frames followed by random consecutive frames, never panic.
    #[test]
    fn garbage_never_panics(
        kind in kind(),
        inputs in vec((0u32..3, 0u64..40, any::<u8>(), 0usize..16, vec(any::<u8>(), 64)), 1..40),
    ) {
        let mut receiver = CanReassembler::<2, 128>::new(kind, 30);
        let mut now_ms = 0;
        for (id, dt_ms, pci, dlc, mut data) in inputs {
            now_ms += dt_ms;
            // Mostly the three PCI types in use, so deeper paths are reached.
            data[0] = if pci < 0xF0 { ((pci % 3) << 4) | ((pci >> 4) % 4) } else { pci };
            let frame = CanFrame::new(id, &data[..FD_LENGTHS[dlc]])?;
            if let Ok(Some(packet)) = receiver.push(now_ms, &frame) {
                prop_assert!(packet.len() <= 128);
            }
        }
    }
}

#[test]
fn garbage_many_cases() {
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig::with_cases(40_000));
    // Any id, any length byte (valid or not), any data.
    let strategy = vec((0u32..4, any::<u8>(), vec(any::<u8>(), 64)), 1..10);
    let result = runner.run(&strategy, |inputs| {
        let mut classic = CanReassembler::<2, 64>::new(CanKind::Classic, 3);
        let mut fd = CanReassembler::<2, 64>::new(CanKind::Fd, 3);
        for (now_ms, (id, len, data)) in inputs.iter().enumerate() {
            let mut frame = CanFrame { id: *id, len: *len % 80, data: [0; 64], extended: true };
            frame.data.copy_from_slice(data);
            frame.data[0] &= 0x2F;
            let _ = classic.push(now_ms as u64, &frame);
            let _ = fd.push(now_ms as u64, &frame);
        }
        Ok(())
    });
    assert!(result.is_ok(), "{result:?}");
}

#[test]
fn id_layout() {
    let id = can_id(Priority::Telemetry, NodeId(0x12), NodeId(0x34));
    assert_eq!(id, 4 << 26 | 0x34 << 8 | 0x12);
    assert!(id <= 0x1FFF_FFFF);
    assert_eq!(can_id_priority(id), Some(Priority::Telemetry));
    assert_eq!(can_id_source(id), NodeId(0x12));
    assert_eq!(can_id_destination(id), NodeId(0x34));
    assert_eq!(can_id_priority(7 << 26), None);
}

#[test]
fn more_urgent_priority_wins_arbitration() {
    // The lowest id wins on the bus, whatever the nodes involved.
    for pair in Priority::ALL.windows(2) {
        let urgent = can_id(pair[0], NodeId(0xFF), NodeId(0xFF));
        let less = can_id(pair[1], NodeId(0), NodeId(0));
        assert!(urgent < less, "{:?} vs {:?}", pair[0], pair[1]);
    }
}

#[test]
fn single_frame_encodings() {
    // Classic and short FD single frames: 0x0L, no padding.
    for kind in [CanKind::Classic, CanKind::Fd] {
        let sent = frames(kind, 1, &[9, 8, 7]).unwrap();
        assert_eq!(sent.len(), 1);
        assert_eq!(sent[0].data(), &[0x03, 9, 8, 7]);
        assert_eq!(frames(kind, 1, &[]).unwrap()[0].data(), &[0x00]);
    }
    // FD escape: 0x00, length, data, padded to 12.
    let sent = frames(CanKind::Fd, 1, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    assert_eq!(sent[0].data(), &[0x00, 8, 1, 2, 3, 4, 5, 6, 7, 8, PADDING, PADDING]);
    // Classic: 8 bytes already need a first frame.
    let sent = frames(CanKind::Classic, 1, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap();
    assert_eq!(sent.len(), 2);
    assert_eq!(sent[0].data(), &[0x10, 8, 1, 2, 3, 4, 5, 6]);
    assert_eq!(sent[1].data(), &[0x21, 7, 8]);
    // 62 bytes is the largest FD single frame.
    assert_eq!(frames(CanKind::Fd, 1, &[1; 62]).unwrap().len(), 1);
    assert_eq!(frames(CanKind::Fd, 1, &[1; 63]).unwrap().len(), 2);
}

#[test]
fn sequence_numbers_wrap() {
    let sent = frames(CanKind::Classic, 1, &[3; 6 + 7 * 20]).unwrap();
    let sequence: Vec<u8> = sent[1..].iter().map(|f| f.data()[0]).collect();
    let expected: Vec<u8> = (1..=20u8).map(|n| 0x20 | (n % 16)).collect();
    assert_eq!(sequence, expected);
}

#[test]
fn reordered_consecutive_frames_are_detected() {
    let packet: Vec<u8> = (0..100).collect();
    let mut sent = frames(CanKind::Classic, 1, &packet).unwrap();
    sent.swap(3, 4);
    let mut receiver = Receiver::new(CanKind::Classic, 1_000);
    let results: Vec<_> = sent.iter().map(|f| receiver.push(0, f).map(|p| p.is_some())).collect();
    assert_eq!(results[3], Err(FrameError::SequenceMismatch { expected: 3, got: 4 }));
    // The rest of the message is swallowed quietly: one loss, one error.
    assert!(results.iter().enumerate().all(|(i, r)| i == 3 || *r == Ok(false)));
    assert_eq!(receiver.stats().errors, 1);
}

#[test]
fn lost_first_frame_is_detected() {
    let sent = frames(CanKind::Fd, 1, &[4; 300]).unwrap();
    let mut receiver = Receiver::new(CanKind::Fd, 1_000);
    assert_eq!(receiver.push(0, &sent[1]), Err(FrameError::UnexpectedConsecutive));
}

#[test]
fn incomplete_message_expires() {
    let sent = frames(CanKind::Classic, 1, &[4; 100]).unwrap();
    let mut receiver = Receiver::new(CanKind::Classic, 50);
    assert_eq!(push_all(&mut receiver, 0, &sent[..5]).unwrap(), Vec::<Vec<u8>>::new());
    receiver.expire(49);
    assert_eq!(receiver.in_progress(), 1);
    receiver.expire(50);
    assert_eq!(receiver.in_progress(), 0);
    assert_eq!(receiver.stats().expired, 1);
    assert_eq!(receiver.push(60, &sent[5]), Err(FrameError::UnexpectedConsecutive));
}

#[test]
fn full_slots_evict_the_oldest() {
    let mut receiver = CanReassembler::<2, 1024>::new(CanKind::Classic, 1_000);
    let sent: Vec<Vec<CanFrame>> =
        (1..=3u32).map(|id| frames(CanKind::Classic, id, &[id as u8; 50]).unwrap()).collect();
    for (t, s) in sent.iter().enumerate() {
        assert_eq!(receiver.push(t as u64, &s[0]), Ok(None));
    }
    assert_eq!(receiver.stats().evicted, 1);
    assert_eq!(receiver.push(5, &sent[0][1]), Err(FrameError::UnexpectedConsecutive));
    assert_eq!(push_all(&mut receiver, 5, &sent[2][1..]).unwrap(), vec![vec![3u8; 50]]);
}

#[test]
fn message_longer_than_the_buffer_is_refused_once() {
    let sent = frames(CanKind::Classic, 1, &[4; 300]).unwrap();
    let mut receiver = CanReassembler::<2, 200>::new(CanKind::Classic, 1_000);
    assert_eq!(receiver.push(0, &sent[0]), Err(FrameError::MessageTooLong { len: 300, max: 200 }));
    // Its consecutive frames are swallowed rather than each reported.
    assert_eq!(push_all(&mut receiver, 0, &sent[1..]).unwrap(), Vec::<Vec<u8>>::new());
    assert_eq!(receiver.stats().errors, 1);
}

#[test]
fn frame_lengths_are_checked() {
    assert_eq!(CanFrame::new(1, &[0; 9]), Err(FrameError::InvalidCanLength(9)));
    assert_eq!(CanFrame::new(1, &[0; 65]), Err(FrameError::InvalidCanLength(65)));
    assert_eq!(CanFrame::new(0x2000_0000, &[0; 8]), Err(FrameError::InvalidCanId(0x2000_0000)));
    assert_eq!(segment(CanKind::Fd, 0x2000_0000, &[1], |_| {}), Err(FrameError::InvalidCanId(0x2000_0000)));
    assert_eq!(CanFrame::new(1, &[0; 12]).unwrap().data().len(), 12);

    // A classic bus never carries more than 8 bytes.
    let fd_frame = frames(CanKind::Fd, 1, &[1; 30]).unwrap()[0];
    let mut classic = Receiver::new(CanKind::Classic, 1_000);
    assert_eq!(classic.push(0, &fd_frame), Err(FrameError::InvalidCanLength(32)));
    // A hand-made frame with an impossible length is refused, not trusted.
    let bogus = CanFrame { id: 1, len: 200, data: [0; 64], extended: true };
    assert_eq!(bogus.data().len(), 64);
    let mut fd = Receiver::new(CanKind::Fd, 1_000);
    assert_eq!(fd.push(0, &bogus), Err(FrameError::InvalidCanLength(200)));
}

#[test]
fn malformed_control_bytes_are_refused() {
    let mut receiver = Receiver::new(CanKind::Fd, 1_000);
    for data in [
        &[][..],
        &[0x30, 0, 0][..],                              // flow control: never sent here
        &[0x05, 1, 2][..],                              // single frame longer than its frame
        &[0x10, 5, 1, 2, 3, 4, 5, 6][..],               // first frame holding the whole message
        &[0x10, 10, 1, 2, 3][..],                       // first frame shorter than 8 bytes
        &[0x01, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11][..], // escape single frame with a short length nibble
    ] {
        let frame = CanFrame::new(1, data).unwrap();
        assert_eq!(receiver.push(0, &frame), Err(FrameError::Malformed), "{data:?}");
    }
}

#[test]
fn wire_cost_per_frame() {
    assert_eq!(CLASSIC_FRAME_WIRE_BYTES, 20);
    assert_eq!(FD_FRAME_WIRE_BYTES, 92);
    // Short frames cost less, and cost grows with length.
    for kind in [CanKind::Classic, CanKind::Fd] {
        let mut previous = 0;
        for len in FD_LENGTHS.iter().copied().filter(|&l| l <= kind.max_data()) {
            let cost = frame_wire_bytes(kind, len);
            assert!(cost >= previous);
            previous = cost;
        }
    }
    // The largest packet on classic CAN: a first frame with 6 bytes, then 7 bytes per frame.
    assert_eq!(frame_count(CanKind::Classic, MAX_PACKET_BYTES), 1 + (MAX_PACKET_BYTES - 6).div_ceil(7));
    assert!(wire_bytes(CanKind::Classic, MAX_PACKET_BYTES) <= frame_count(CanKind::Classic, MAX_PACKET_BYTES) * 20);
}
