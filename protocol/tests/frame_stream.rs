//! Stream framing (COBS + CRC-32): round trips through arbitrary chunking, corruption detection,
//! resynchronisation and totality on garbage.

use proptest::collection::vec;
use proptest::prelude::*;
use protocol::MAX_PACKET_BYTES;
use protocol::frame::FrameError;
use protocol::frame::stream::{CRC_BYTES, StreamDecoder, StreamStats, encode_frame, max_frame_len};

/// Decoder sized for the largest packet of the protocol.
type Decoder = StreamDecoder<{ MAX_PACKET_BYTES + CRC_BYTES }>;

#[derive(Debug, PartialEq, Eq)]
enum Event {
    Packet(Vec<u8>),
    Error(FrameError),
}

fn frame(packet: &[u8]) -> Result<Vec<u8>, FrameError> {
    let mut out = vec![0u8; max_frame_len(packet.len())];
    let len = encode_frame(packet, &mut out)?;
    out.truncate(len);
    Ok(out)
}

fn feed<const N: usize>(decoder: &mut StreamDecoder<N>, bytes: &[u8], events: &mut Vec<Event>) {
    decoder.feed(bytes, |result| {
        events.push(match result {
            Ok(packet) => Event::Packet(packet.to_vec()),
            Err(error) => Event::Error(error),
        })
    });
}

fn packet() -> impl Strategy<Value = Vec<u8>> {
    // Zero-heavy and zero-free packets exercise both COBS block kinds.
    prop_oneof![
        vec(any::<u8>(), 0..=MAX_PACKET_BYTES),
        vec(prop_oneof![Just(0u8), any::<u8>()], 0..=MAX_PACKET_BYTES),
        vec(1u8..=255, 0..=MAX_PACKET_BYTES),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// One frame decodes to exactly its packet, and never exceeds `max_frame_len`.
    #[test]
    fn round_trip(packet in packet()) {
        let wire = frame(&packet)?;
        prop_assert!(wire.len() <= max_frame_len(packet.len()));
        prop_assert_eq!(wire.first(), Some(&0u8));
        prop_assert_eq!(wire.last(), Some(&0u8));
        prop_assert!(!wire[1..wire.len() - 1].contains(&0), "COBS must remove every zero");

        let mut decoder = Decoder::new();
        let mut events = Vec::new();
        feed(&mut decoder, &wire, &mut events);
        prop_assert_eq!(events, vec![Event::Packet(packet)]);
        prop_assert_eq!(decoder.stats(), StreamStats { frames_ok: 1, ..StreamStats::default() });
    }

    /// Several frames back to back, with stray delimiters between them, cut into chunks at
    /// random points, decode to the packets in order.
    #[test]
    fn concatenated_stream_split_anywhere(
        packets in vec(packet(), 1..6),
        extra_delimiters in vec(0usize..3, 6),
        cuts in vec(any::<prop::sample::Index>(), 0..20),
    ) {
        let mut wire = Vec::new();
        for (packet, extra) in packets.iter().zip(&extra_delimiters) {
            wire.extend(std::iter::repeat_n(0u8, *extra));
            wire.extend(frame(packet)?);
        }
        let mut cuts: Vec<usize> = cuts.iter().map(|i| i.index(wire.len() + 1)).collect();
        cuts.push(0);
        cuts.push(wire.len());
        cuts.sort_unstable();

        let mut decoder = Decoder::new();
        let mut events = Vec::new();
        for window in cuts.windows(2) {
            feed(&mut decoder, &wire[window[0]..window[1]], &mut events);
        }
        let expected: Vec<Event> = packets.into_iter().map(Event::Packet).collect();
        prop_assert_eq!(events, expected);
    }

    /// Any single corrupted byte is reported and never yields a packet; a changed data byte is
    /// a CRC error, and the frame after the corrupted one decodes. (A corrupted code byte can
    /// also make the frame decode longer than the buffer: an overflow.)
    #[test]
    fn single_byte_corruption_is_detected(
        packet in packet(),
        position in any::<prop::sample::Index>(),
        value in any::<u8>(),
    ) {
        let wire = frame(&packet)?;
        // The delimiters stay: losing them is the next test's subject.
        let at = 1 + position.index(wire.len() - 2);
        prop_assume!(wire[at] != value);
        let mut corrupted = wire.clone();
        corrupted[at] = value;

        let mut decoder = Decoder::new();
        let mut events = Vec::new();
        feed(&mut decoder, &corrupted, &mut events);
        prop_assert!(!events.is_empty());
        prop_assert!(events.iter().all(|e| matches!(e, Event::Error(FrameError::Crc | FrameError::Cobs | FrameError::Overflow))), "{:?}", events);
        if value != 0 && !code_byte_positions(&wire).contains(&at) {
            prop_assert_eq!(&events, &vec![Event::Error(FrameError::Crc)]);
        }

        events.clear();
        feed(&mut decoder, &wire, &mut events);
        prop_assert_eq!(events, vec![Event::Packet(packet)]);
    }

    /// Either one of the two delimiters between frames may be lost without losing a frame;
    /// losing both merges two frames into one that fails its check, and the decoder carries on
    /// with the next frame.
    #[test]
    fn lost_delimiters_lose_at_most_the_merged_frames(a in packet(), b in packet(), c in packet(), lost in 0usize..3) {
        let mut wire = frame(&a)?;
        let mut second = frame(&b)?;
        match lost {
            0 => { wire.pop(); }
            1 => { second.remove(0); }
            _ => { wire.pop(); second.remove(0); }
        }
        wire.extend(second);
        let tail = frame(&c)?;

        let mut decoder = Decoder::new();
        let mut events = Vec::new();
        feed(&mut decoder, &wire, &mut events);
        feed(&mut decoder, &tail, &mut events);
        if lost < 2 {
            prop_assert_eq!(events, vec![Event::Packet(a), Event::Packet(b), Event::Packet(c)]);
        } else {
            prop_assert_eq!(events.len(), 2);
            prop_assert!(matches!(events[0], Event::Error(_)));
            prop_assert_eq!(&events[1], &Event::Packet(c));
        }
    }

    /// Garbage never panics, and every completed frame is accounted for exactly once.
    #[test]
    fn garbage_never_panics(
        chunks in vec(prop_oneof![
            vec(any::<u8>(), 0..200),
            vec(prop_oneof![Just(0u8), 1u8..4, Just(0xFF)], 0..200),
        ], 1..8),
    ) {
        let mut decoder = StreamDecoder::<64>::new();
        let mut events = Vec::new();
        for chunk in &chunks {
            feed(&mut decoder, chunk, &mut events);
        }
        let stats = decoder.stats();
        let packets = events.iter().filter(|e| matches!(e, Event::Packet(_))).count() as u64;
        prop_assert_eq!(stats.frames_ok, packets);
        prop_assert_eq!(stats.frames_ok + stats.crc_errors + stats.cobs_errors + stats.overflows, events.len() as u64);
        for event in &events {
            if let Event::Packet(packet) = event {
                prop_assert!(packet.len() <= 64 - CRC_BYTES);
            }
        }
    }
}

/// Positions of COBS code bytes in an encoded frame (a code byte says where the next one is).
fn code_byte_positions(wire: &[u8]) -> Vec<usize> {
    let mut positions = Vec::new();
    // Skip the leading delimiter.
    let mut at = 1;
    while let Some(&code) = wire.get(at) {
        if code == 0 {
            break;
        }
        positions.push(at);
        at += usize::from(code);
    }
    positions
}

#[test]
fn garbage_many_cases() {
    // Cheap, so many: random bytes in random chunkings.
    let mut runner = proptest::test_runner::TestRunner::new(ProptestConfig::with_cases(40_000));
    let result = runner.run(&vec(any::<u8>(), 0..400), |bytes| {
        let mut decoder = StreamDecoder::<32>::new();
        let mut count = 0u64;
        let (a, b) = bytes.split_at(bytes.len() / 3);
        decoder.feed(a, |_| count += 1);
        decoder.feed(b, |_| count += 1);
        let stats = decoder.stats();
        prop_assert_eq!(stats.frames_ok + stats.crc_errors + stats.cobs_errors + stats.overflows, count);
        Ok(())
    });
    assert!(result.is_ok(), "{result:?}");
}

#[test]
fn empty_frames_are_ignored() {
    let mut decoder = Decoder::new();
    let mut events = Vec::new();
    feed(&mut decoder, &[0, 0, 0, 0], &mut events);
    assert!(events.is_empty());
    assert_eq!(decoder.stats(), StreamStats::default());
}

#[test]
fn empty_packet_round_trips() {
    let wire = frame(&[]).unwrap();
    let mut decoder = Decoder::new();
    let mut events = Vec::new();
    feed(&mut decoder, &wire, &mut events);
    assert_eq!(events, vec![Event::Packet(Vec::new())]);
}

#[test]
fn frame_too_short_for_crc_is_a_crc_error() {
    let mut decoder = Decoder::new();
    let mut events = Vec::new();
    // COBS of [0x11, 0x22]: a valid encoding, but only 2 bytes where 4 of CRC are due.
    feed(&mut decoder, &[0x03, 0x11, 0x22, 0x00], &mut events);
    assert_eq!(events, vec![Event::Error(FrameError::Crc)]);
    assert_eq!(decoder.stats().crc_errors, 1);
}

#[test]
fn truncated_block_is_a_cobs_error() {
    let mut decoder = Decoder::new();
    let mut events = Vec::new();
    // The code byte announces 9 data bytes, the frame ends after 2.
    feed(&mut decoder, &[0x0A, 0x11, 0x22, 0x00], &mut events);
    assert_eq!(events, vec![Event::Error(FrameError::Cobs)]);
    assert_eq!(decoder.stats().cobs_errors, 1);
}

#[test]
fn overlong_frame_is_reported_once_then_resyncs() {
    let mut decoder = StreamDecoder::<{ 16 + CRC_BYTES }>::new();
    let fits = [7u8; 16];
    let too_long = [7u8; 17];
    let mut events = Vec::new();
    feed(&mut decoder, &frame(&fits).unwrap(), &mut events);
    let long = frame(&too_long).unwrap();
    // Fed byte by byte and padded with more non-zero junk: still one report.
    for byte in &long[..long.len() - 1] {
        feed(&mut decoder, std::slice::from_ref(byte), &mut events);
    }
    feed(&mut decoder, &[0x55; 100], &mut events);
    feed(&mut decoder, &[0], &mut events);
    feed(&mut decoder, &frame(&fits).unwrap(), &mut events);
    assert_eq!(
        events,
        vec![Event::Packet(fits.to_vec()), Event::Error(FrameError::Overflow), Event::Packet(fits.to_vec())]
    );
    assert_eq!(decoder.stats(), StreamStats { frames_ok: 2, crc_errors: 0, cobs_errors: 0, overflows: 1 });
}

#[test]
fn joining_mid_frame_loses_only_that_frame() {
    let wire = frame(&[1, 2, 3, 0, 4, 5]).unwrap();
    let next = frame(&[9, 8, 7]).unwrap();
    let mut decoder = Decoder::new();
    let mut events = Vec::new();
    feed(&mut decoder, &wire[3..], &mut events);
    feed(&mut decoder, &next, &mut events);
    assert_eq!(events.len(), 2);
    assert!(matches!(events[0], Event::Error(_)));
    assert_eq!(events[1], Event::Packet(vec![9, 8, 7]));
}

#[test]
fn max_frame_len_is_reached_by_zero_free_data() {
    // A packet whose bytes and CRC contain no zero hits the bound exactly.
    let mut hits = 0;
    for len in [0usize, 1, 249, 250, 251, 500, 1000, MAX_PACKET_BYTES] {
        for fill in 1..=255u8 {
            let packet = vec![fill; len];
            let wire = frame(&packet).unwrap();
            assert!(wire.len() <= max_frame_len(len));
            if wire.len() == max_frame_len(len) {
                hits += 1;
                break;
            }
        }
    }
    assert_eq!(hits, 8);
    assert_eq!(max_frame_len(0), 1 + 1 + CRC_BYTES + 1);
    assert_eq!(max_frame_len(250), 1 + 254 + 1 + 1);
    assert_eq!(max_frame_len(251), 1 + 255 + 2 + 1);
}

#[test]
fn small_output_buffer_is_refused() {
    let mut out = [0u8; 8];
    assert_eq!(encode_frame(&[1; 16], &mut out), Err(FrameError::BufferTooSmall));
}
