//! Datagram framing: segmentation bounds, reassembly in any order with duplicates, several
//! senders, expiry, eviction, inconsistent fragments and totality on garbage.

use proptest::collection::vec;
use proptest::prelude::*;
use protocol::MAX_PACKET_BYTES;
use protocol::frame::can::CanKind;
use protocol::frame::datagram::{
    FRAGMENT_HEADER_BYTES, IP_UDP_HEADER_BYTES, MAX_DATAGRAM_BYTES, MAX_FRAGMENTS, MIN_MTU, Reassembler,
    ReassemblyStats, Segmenter, fragment_count, wire_bytes,
};
use protocol::frame::{FrameError, Framing, can, stream};

const BIG: usize = 16 * 1024;
type Big = Reassembler<4, BIG>;

fn segment(mtu: usize, packet: &[u8]) -> Result<Vec<Vec<u8>>, FrameError> {
    let mut segmenter = Segmenter::new(mtu)?;
    let mut datagrams = Vec::new();
    let count = segmenter.segment(packet, |d| datagrams.push(d.to_vec()))?;
    assert_eq!(count, datagrams.len());
    Ok(datagrams)
}

/// Pushes every datagram and collects the packets delivered.
fn push_all<const S: usize, const M: usize>(
    reassembler: &mut Reassembler<S, M>,
    now_ms: u64,
    source: u64,
    datagrams: &[Vec<u8>],
) -> Result<Vec<Vec<u8>>, FrameError> {
    let mut delivered = Vec::new();
    for datagram in datagrams {
        if let Some(packet) = reassembler.push(now_ms, source, datagram)? {
            delivered.push(packet.to_vec());
        }
    }
    Ok(delivered)
}

fn datagram(id: u16, index: u16, count: u16, payload: &[u8]) -> Vec<u8> {
    let mut d = Vec::new();
    d.extend(id.to_le_bytes());
    d.extend(index.to_le_bytes());
    d.extend(count.to_le_bytes());
    d.extend(payload);
    d
}

/// A deterministic shuffle from a seed (xorshift), so proptest can still report the case.
fn shuffle<T>(items: &mut [T], mut seed: u64) {
    for i in (1..items.len()).rev() {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        items.swap(i, (seed % (i as u64 + 1)) as usize);
    }
}

/// MTUs and packet lengths whose fragment count the segmenter supports, 16 KiB packets included.
fn mtu_and_packet() -> impl Strategy<Value = (usize, Vec<u8>)> {
    prop_oneof![
        (MIN_MTU..=14usize, vec(any::<u8>(), 0..=MAX_PACKET_BYTES)),
        (prop_oneof![Just(64usize), 14..=MAX_DATAGRAM_BYTES], vec(any::<u8>(), 0..=BIG)),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// In order: exactly one packet, equal to the input, from datagrams within the MTU whose
    /// cost `wire_bytes` bounds.
    #[test]
    fn round_trip((mtu, packet) in mtu_and_packet()) {
        let datagrams = segment(mtu, &packet)?;
        prop_assert_eq!(datagrams.len(), fragment_count(mtu, packet.len()));
        prop_assert!(datagrams.iter().all(|d| d.len() <= mtu && d.len() > FRAGMENT_HEADER_BYTES || packet.is_empty()));
        let on_wire: usize = datagrams.iter().map(|d| d.len() + IP_UDP_HEADER_BYTES).sum();
        prop_assert!(on_wire <= wire_bytes(mtu, packet.len()), "{} > {}", on_wire, wire_bytes(mtu, packet.len()));

        let mut reassembler = Big::new(1_000);
        let delivered = push_all(&mut reassembler, 0, 7, &datagrams)?;
        prop_assert_eq!(delivered, vec![packet]);
        prop_assert_eq!(reassembler.in_progress(), 0);
        let stats = reassembler.stats();
        prop_assert_eq!(stats.messages, 1);
        prop_assert_eq!(stats.fragments, datagrams.len() as u64);
    }

    /// Shuffled, with some fragments repeated (also after completion): delivered exactly once.
    #[test]
    fn shuffled_duplicated_fragments_reassemble_once(
        (mtu, packet) in mtu_and_packet(),
        repeats in vec(1usize..=3, 1..64),
        seed in any::<u64>().prop_map(|s| s | 1),
    ) {
        let datagrams = segment(mtu, &packet)?;
        let mut sent = Vec::new();
        for (i, d) in datagrams.iter().enumerate() {
            for _ in 0..repeats[i % repeats.len()] {
                sent.push(d.clone());
            }
        }
        shuffle(&mut sent, seed);

        let mut reassembler = Big::new(1_000);
        let delivered = push_all(&mut reassembler, 0, 7, &sent)?;
        prop_assert_eq!(delivered, vec![packet]);
        prop_assert_eq!(reassembler.in_progress(), 0, "a late duplicate must not start a new message");
        let stats = reassembler.stats();
        prop_assert_eq!(stats.duplicates, (sent.len() - datagrams.len()) as u64);
        prop_assert_eq!(stats.errors, 0);
    }

    /// Two senders whose message ids collide, fragments interleaved and shuffled: each packet
    /// arrives once, intact.
    #[test]
    fn interleaved_senders(
        a in vec(any::<u8>(), 0..3000),
        b in vec(any::<u8>(), 0..3000),
        seed in any::<u64>().prop_map(|s| s | 1),
    ) {
        let mut sent: Vec<(u64, Vec<u8>)> = segment(100, &a)?.into_iter().map(|d| (1, d)).collect();
        sent.extend(segment(100, &b)?.into_iter().map(|d| (2, d)));
        shuffle(&mut sent, seed);

        let mut reassembler = Reassembler::<2, 4096>::new(1_000);
        let mut from_a = Vec::new();
        let mut from_b = Vec::new();
        for (source, d) in &sent {
            if let Some(packet) = reassembler.push(5, *source, d)? {
                if *source == 1 { from_a.push(packet.to_vec()) } else { from_b.push(packet.to_vec()) }
            }
        }
        prop_assert_eq!(from_a, vec![a]);
        prop_assert_eq!(from_b, vec![b]);
        prop_assert_eq!(reassembler.stats().evicted, 0);
    }

    /// Random datagrams, and mutations of real ones, from a few sources at random times never
    /// panic, and whatever is delivered fits the buffer.
    #[test]
    fn garbage_never_panics(
        inputs in vec((0u64..3, 0u64..50, prop_oneof![
            vec(any::<u8>(), 0..80),
            (any::<u8>(), 0u16..4, 0u16..5, 1u16..6, vec(any::<u8>(), 0..40))
                .prop_map(|(id, _, index, count, payload)| datagram(u16::from(id % 3), index, count, &payload)),
        ]), 1..40),
    ) {
        let mut reassembler = Reassembler::<2, 64>::new(20);
        let mut now_ms = 0;
        for (source, dt_ms, bytes) in &inputs {
            now_ms += dt_ms;
            if let Ok(Some(packet)) = reassembler.push(now_ms, *source, bytes) {
                prop_assert!(packet.len() <= 64);
            }
        }
        prop_assert!(reassembler.in_progress() <= 2);
    }
}

#[test]
fn garbage_many_cases() {
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig::with_cases(30_000));
    let strategy = vec((0u64..2, vec(any::<u8>(), 0..24)), 1..12);
    let result = runner.run(&strategy, |inputs| {
        let mut reassembler = Reassembler::<2, 32>::new(5);
        for (now_ms, (source, bytes)) in inputs.iter().enumerate() {
            // Shrink header fields into range now and then so deeper paths are reached.
            let mut bytes = bytes.clone();
            if let [_, _, index, 0, count, 0, ..] = bytes.as_mut_slice() {
                *index %= 4;
                *count %= 4;
            }
            let _ = reassembler.push(now_ms as u64, *source, &bytes);
        }
        Ok(())
    });
    assert!(result.is_ok(), "{result:?}");
}

#[test]
fn header_layout() {
    // MTU 9: three payload bytes per datagram.
    let mut segmenter = Segmenter::with_first_id(MIN_MTU + 2, 0x1234).unwrap();
    let mut datagrams = Vec::new();
    assert_eq!(segmenter.segment(&[1, 2, 3, 4, 5, 6, 7], |d| datagrams.push(d.to_vec())), Ok(3));
    assert_eq!(
        datagrams,
        vec![
            vec![0x34, 0x12, 0, 0, 3, 0, 1, 2, 3],
            vec![0x34, 0x12, 1, 0, 3, 0, 4, 5, 6],
            vec![0x34, 0x12, 2, 0, 3, 0, 7],
        ]
    );
    assert_eq!(segmenter.next_id(), 0x1235);
}

#[test]
fn empty_packet_is_one_empty_fragment() {
    let datagrams = segment(64, &[]).unwrap();
    assert_eq!(datagrams, vec![vec![0, 0, 0, 0, 1, 0]]);
    let mut reassembler = Big::new(1_000);
    assert_eq!(push_all(&mut reassembler, 0, 1, &datagrams).unwrap(), vec![Vec::<u8>::new()]);
}

#[test]
fn message_ids_increase_and_wrap() {
    let mut segmenter = Segmenter::with_first_id(64, u16::MAX).unwrap();
    let mut ids = Vec::new();
    for _ in 0..3 {
        segmenter.segment(&[9; 100], |d| ids.push(u16::from_le_bytes([d[0], d[1]]))).unwrap();
    }
    assert_eq!(ids, vec![u16::MAX, u16::MAX, 0, 0, 1, 1]);
}

#[test]
fn mtu_is_checked() {
    assert_eq!(Segmenter::new(MIN_MTU - 1).unwrap_err(), FrameError::InvalidMtu(MIN_MTU - 1));
    assert_eq!(Segmenter::new(MAX_DATAGRAM_BYTES + 1).unwrap_err(), FrameError::InvalidMtu(MAX_DATAGRAM_BYTES + 1));
    assert!(Segmenter::new(MIN_MTU).is_ok());
    assert!(Segmenter::new(MAX_DATAGRAM_BYTES).is_ok());
}

#[test]
fn small_mtus_carry_large_packets() {
    // 16 KiB at an MTU of 64, and the largest protocol packet at the smallest MTU.
    for (mtu, len) in [(64, BIG), (MIN_MTU, MAX_PACKET_BYTES), (14, BIG)] {
        let packet: Vec<u8> = (0..len).map(|i| (i * 7 + 3) as u8).collect();
        let datagrams = segment(mtu, &packet).unwrap();
        let mut reassembler = Big::new(1_000);
        assert_eq!(push_all(&mut reassembler, 0, 1, &datagrams).unwrap(), vec![packet], "mtu {mtu}");
    }
    // Past MAX_FRAGMENTS the segmenter refuses rather than emitting what no receiver takes.
    let too_many = vec![1u8; MAX_FRAGMENTS + 1];
    assert_eq!(
        Segmenter::new(MIN_MTU).unwrap().segment(&too_many, |_| {}),
        Err(FrameError::PacketTooLong { len: MAX_FRAGMENTS + 1, max: MAX_FRAGMENTS })
    );
}

#[test]
fn wire_bytes_examples() {
    // One datagram: packet + 6 + 28.
    assert_eq!(wire_bytes(MAX_DATAGRAM_BYTES, MAX_PACKET_BYTES), MAX_PACKET_BYTES + 34);
    // 58 bytes per datagram at MTU 64.
    assert_eq!(wire_bytes(64, 1070), 1070 + 19 * 34);
    assert_eq!(wire_bytes(64, 0), 34);
    // Unsupported MTUs are clamped rather than dividing by zero.
    assert_eq!(wire_bytes(0, 10), wire_bytes(MIN_MTU, 10));
    assert_eq!(wire_bytes(9000, 10), wire_bytes(MAX_DATAGRAM_BYTES, 10));
}

#[test]
fn last_fragment_first_is_placed_once_the_size_is_known() {
    let packet: Vec<u8> = (0..200u8).collect();
    let mut datagrams = segment(64, &packet).unwrap();
    datagrams.reverse();
    let mut reassembler = Reassembler::<1, 200>::new(1_000);
    assert_eq!(push_all(&mut reassembler, 0, 1, &datagrams).unwrap(), vec![packet]);
}

#[test]
fn lost_fragment_expires_after_timeout() {
    let packet = vec![0xAB; 500];
    let datagrams = segment(64, &packet).unwrap();
    let mut reassembler = Reassembler::<2, 1024>::new(100);
    let (lost, rest) = datagrams.split_at(1);
    assert_eq!(push_all(&mut reassembler, 1_000, 1, rest).unwrap(), Vec::<Vec<u8>>::new());
    assert_eq!(reassembler.in_progress(), 1);

    reassembler.expire(1_099);
    assert_eq!(reassembler.in_progress(), 1, "not yet timed out");
    reassembler.expire(1_100);
    assert_eq!(reassembler.in_progress(), 0);
    assert_eq!(reassembler.stats().expired, 1);

    // The lost fragment turning up late starts a message that cannot complete.
    assert_eq!(reassembler.push(1_150, 1, &lost[0]), Ok(None));
    assert_eq!(reassembler.in_progress(), 1);
    // push expires too.
    let single = segment(64, &[1, 2, 3]).unwrap();
    assert_eq!(reassembler.push(1_250, 1, &single[0]), Ok(Some(&[1u8, 2, 3][..])));
    assert_eq!(reassembler.in_progress(), 0);
    assert_eq!(reassembler.stats().expired, 2);
}

#[test]
fn progress_keeps_a_slow_message_alive() {
    let packet = vec![0x11; 300];
    let datagrams = segment(64, &packet).unwrap();
    let mut reassembler = Reassembler::<1, 1024>::new(100);
    let mut delivered = Vec::new();
    for (i, d) in datagrams.iter().enumerate() {
        // 90 ms apart: the whole message takes longer than the timeout, each gap does not.
        if let Some(p) = reassembler.push(90 * i as u64, 1, d).unwrap() {
            delivered.push(p.to_vec());
        }
    }
    assert_eq!(delivered, vec![packet]);
    assert_eq!(reassembler.stats().expired, 0);
}

#[test]
fn full_slots_evict_the_oldest() {
    let packets: Vec<Vec<u8>> = (0..3u8).map(|i| vec![i; 150]).collect();
    let sent: Vec<Vec<Vec<u8>>> = packets.iter().map(|p| segment(64, p).unwrap()).collect();
    let mut reassembler = Reassembler::<2, 1024>::new(1_000);
    // First fragments of three messages from three sources: the third evicts the first.
    for (source, datagrams) in sent.iter().enumerate() {
        assert_eq!(reassembler.push(source as u64 * 10, source as u64, &datagrams[0]), Ok(None));
    }
    assert_eq!(reassembler.stats().evicted, 1);
    assert_eq!(reassembler.in_progress(), 2);
    // Single-fragment packets neither need nor take a slot.
    assert!(reassembler.push(40, 9, &segment(64, &[5; 10]).unwrap()[0]).unwrap().is_some());
    assert_eq!(reassembler.stats().evicted, 1);

    let second = push_all(&mut reassembler, 50, 1, &sent[1][1..]).unwrap();
    let third = push_all(&mut reassembler, 50, 2, &sent[2][1..]).unwrap();
    assert_eq!((second, third), (vec![packets[1].clone()], vec![packets[2].clone()]));
    // The evicted message cannot complete from its remaining fragments.
    assert_eq!(push_all(&mut reassembler, 60, 0, &sent[0][1..]).unwrap(), Vec::<Vec<u8>>::new());
}

#[test]
fn inconsistent_fragment_count_drops_the_message() {
    let mut reassembler = Reassembler::<2, 1024>::new(1_000);
    assert_eq!(reassembler.push(0, 1, &datagram(5, 0, 3, &[1; 10])), Ok(None));
    assert_eq!(reassembler.push(0, 1, &datagram(5, 1, 4, &[1; 10])), Err(FrameError::InconsistentFragments));
    assert_eq!(reassembler.in_progress(), 0);
    // The remaining fragments of the first message start afresh and cannot complete it.
    assert_eq!(reassembler.push(0, 1, &datagram(5, 1, 3, &[1; 10])), Ok(None));
    assert_eq!(reassembler.push(0, 1, &datagram(5, 2, 3, &[1; 4])), Ok(None));
    // The same id from another source is another message.
    assert_eq!(reassembler.push(0, 2, &datagram(5, 0, 1, &[7])), Ok(Some(&[7u8][..])));
    assert_eq!(reassembler.stats().errors, 1);
}

#[test]
fn inconsistent_fragment_sizes_are_refused() {
    let mut reassembler = Reassembler::<2, 1024>::new(1_000);
    assert_eq!(reassembler.push(0, 1, &datagram(1, 0, 3, &[1; 10])), Ok(None));
    assert_eq!(reassembler.push(0, 1, &datagram(1, 1, 3, &[1; 9])), Err(FrameError::InconsistentFragments));
    // A last fragment longer than the others.
    assert_eq!(reassembler.push(0, 1, &datagram(2, 2, 3, &[1; 11])), Ok(None));
    assert_eq!(reassembler.push(0, 1, &datagram(2, 0, 3, &[1; 10])), Err(FrameError::InconsistentFragments));
    assert_eq!(reassembler.in_progress(), 0);
}

#[test]
fn malformed_headers_are_refused() {
    let mut reassembler = Reassembler::<2, 1024>::new(1_000);
    for bad in [
        vec![],
        vec![1, 0, 0, 0, 1],           // shorter than the header
        datagram(1, 0, 0, &[1]),       // no fragments
        datagram(1, 3, 3, &[1]),       // index past count
        datagram(1, 0, 2, &[]),        // empty fragment of a multi-fragment message
        datagram(1, 0, 2049, &[1]),    // more fragments than any sender emits
        datagram(1, 0, 1, &[0; 1201]), // larger than any datagram of ours
    ] {
        assert_eq!(reassembler.push(0, 1, &bad), Err(FrameError::Malformed), "{bad:?}");
    }
    assert_eq!(reassembler.stats(), ReassemblyStats { errors: 7, ..ReassemblyStats::default() });
}

#[test]
fn message_longer_than_the_buffer_is_refused() {
    let datagrams = segment(64, &[3; 300]).unwrap();
    let mut reassembler = Reassembler::<2, 200>::new(1_000);
    assert!(matches!(reassembler.push(0, 1, &datagrams[0]), Err(FrameError::MessageTooLong { max: 200, .. })));
    // Arriving last-first, the bound is caught once the fragment size is known.
    let mut reassembler = Reassembler::<2, 200>::new(1_000);
    assert_eq!(reassembler.push(0, 1, datagrams.last().unwrap()), Ok(None));
    assert!(matches!(reassembler.push(0, 1, &datagrams[0]), Err(FrameError::MessageTooLong { max: 200, .. })));
    assert_eq!(reassembler.in_progress(), 0);
    // A single datagram too long for the buffer.
    let mut small = Reassembler::<1, 8>::new(1_000);
    assert_eq!(small.push(0, 1, &datagram(0, 0, 1, &[1; 9])), Err(FrameError::MessageTooLong { len: 9, max: 8 }));
}

#[test]
fn framing_charges_each_links_cost() {
    for len in [0, 1, 100, MAX_PACKET_BYTES] {
        assert_eq!(Framing::Stream.wire_bytes(len), stream::max_frame_len(len));
        assert_eq!(Framing::Datagram { mtu: 64 }.wire_bytes(len), wire_bytes(64, len));
        assert_eq!(Framing::Can(CanKind::Fd).wire_bytes(len), can::wire_bytes(CanKind::Fd, len));
    }
}
