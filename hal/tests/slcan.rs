//! SLCAN: the codec (round trips, malformed lines, property tests on arbitrary bytes), the
//! adapter's answers byte for byte, and host and adapter against each other over a real pty pair
//! (serialport's `TTYPort::pair`, raw mode): open handshake, 1000 frames each way, a closed
//! channel, a closed pty, and a `CanLink` running over SLCAN.

// Helpers outside #[test] functions are test code too; clippy.toml only exempts the latter.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::io::{ErrorKind, Read, Write};
use std::os::unix::net::UnixStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use hal::can::slcan::{
    AdapterStats, BELL, ChannelState, Command, Line, MAX_LINE_BYTES, Reply, SlcanAdapter, SlcanBitrate, SlcanBus,
    SlcanConfig, SlcanDecoder, SlcanError, SlcanFrame, Tag, TimedPort, parse_line,
};
use hal::can::{CanBus, CanFrame, CanLink, LoopbackCanBus};
use hal::link::{Link, LinkError, MAX_LINK_PACKET_BYTES};
use proptest::prelude::*;
use protocol::NodeId;
use protocol::frame::FrameError;
use protocol::frame::can::CanKind;
use serialport::{SerialPort, TTYPort};

const WAIT: Duration = Duration::from_secs(3);

// ---------------------------------------------------------------------------------------------
// Codec

fn encode(line: Line) -> String {
    String::from_utf8(line.encode().as_bytes().to_vec()).unwrap()
}

fn data(id: u32, extended: bool, bytes: &[u8]) -> SlcanFrame {
    SlcanFrame::data(id, extended, bytes).unwrap()
}

#[test]
fn frames_encode_as_python_can_writes_them() {
    assert_eq!(encode(Line::Frame(data(0x123, false, &[0xAA, 0xBB]))), "t1232AABB\r");
    assert_eq!(encode(Line::Frame(data(0x1ABC_DEF0, true, &[]))), "T1ABCDEF00\r");
    assert_eq!(encode(Line::Frame(data(0x7FF, false, &[0; 8]))), "t7FF80000000000000000\r");
    assert_eq!(encode(Line::Frame(SlcanFrame::remote(0x7FF, false, 8).unwrap())), "r7FF8\r");
    assert_eq!(encode(Line::Frame(SlcanFrame::remote(0x1F, true, 0).unwrap())), "R0000001F0\r");
    assert_eq!(encode(Line::Frame(data(0x1, false, &[0x5A]).with_timestamp(Some(0xEA5F)))), "t00115AEA5F\r");
    let longest = data(0x1FFF_FFFF, true, &[0xFF; 8]).with_timestamp(Some(0xFFFF));
    assert_eq!(encode(Line::Frame(longest)).len(), MAX_LINE_BYTES + 1);
}

#[test]
fn frames_round_trip_every_kind_and_length() {
    let mut count = 0;
    for extended in [false, true] {
        for id in if extended { [0, 0x1234_5678, 0x1FFF_FFFF] } else { [0, 0x2A5, 0x7FF] } {
            for len in 0..=8u8 {
                for timestamp in [None, Some(0), Some(59_999)] {
                    let payload: Vec<u8> = (0..len).map(|i| i.wrapping_mul(0x35) ^ 0xA5).collect();
                    let frames = [
                        data(id, extended, &payload).with_timestamp(timestamp),
                        SlcanFrame::remote(id, extended, len).unwrap().with_timestamp(timestamp),
                    ];
                    for frame in frames {
                        let encoded = frame_line(frame);
                        let body = encoded.strip_suffix(b"\r").unwrap();
                        assert_eq!(parse_line(body), Ok(Line::Frame(frame)), "{:?}", encoded.escape_ascii());
                        // Lower-case hex is read too (some adapters write it).
                        let lower: Vec<u8> = body
                            .iter()
                            .enumerate()
                            .map(|(i, b)| if i == 0 { *b } else { b.to_ascii_lowercase() })
                            .collect();
                        assert_eq!(parse_line(&lower), Ok(Line::Frame(frame)));
                        count += 1;
                    }
                    let can = data(id, extended, &payload).to_can().unwrap();
                    assert_eq!(can.extended, extended);
                    assert_eq!(can.data(), payload.as_slice());
                    assert_eq!(SlcanFrame::from_can(&can).unwrap(), data(id, extended, &payload));
                }
            }
        }
    }
    assert_eq!(count, 2 * 3 * 9 * 3 * 2);
    assert_eq!(SlcanFrame::remote(1, false, 3).unwrap().to_can(), None);
}

fn frame_line(frame: SlcanFrame) -> Vec<u8> {
    Line::Frame(frame).encode().as_bytes().to_vec()
}

#[test]
fn commands_and_replies_round_trip() {
    let tag = Tag::new(*b"1013").unwrap();
    let cases = [
        (Line::Command(Command::SetBitrate(SlcanBitrate::B10k)), "S0\r"),
        (Line::Command(Command::SetBitrate(SlcanBitrate::B750k)), "S7\r"),
        (Line::Command(Command::SetBitrate(SlcanBitrate::B1M)), "S8\r"),
        (Line::Command(Command::SetBitTiming { btr0: 0x03, btr1: 0x1C }), "s031C\r"),
        (Line::Command(Command::Open), "O\r"),
        (Line::Command(Command::ListenOnly), "L\r"),
        (Line::Command(Command::Close), "C\r"),
        (Line::Command(Command::Status), "F\r"),
        (Line::Command(Command::Version), "V\r"),
        (Line::Command(Command::SerialNumber), "N\r"),
        (Line::Command(Command::Timestamps(false)), "Z0\r"),
        (Line::Command(Command::Timestamps(true)), "Z1\r"),
        (Line::Reply(Reply::Ok), "\r"),
        (Line::Reply(Reply::Error), "\x07"),
        (Line::Reply(Reply::TransmitAck { extended: false }), "z\r"),
        (Line::Reply(Reply::TransmitAck { extended: true }), "Z\r"),
        (Line::Reply(Reply::Status(0x08)), "F08\r"),
        (Line::Reply(Reply::Version(tag)), "V1013\r"),
        (Line::Reply(Reply::SerialNumber(Tag::new(*b"A123").unwrap())), "NA123\r"),
    ];
    for (line, text) in cases {
        assert_eq!(encode(line), text);
        let mut decoder = SlcanDecoder::new();
        let mut decoded = Vec::new();
        decoder.feed(text.as_bytes(), |l| decoded.push(l));
        assert_eq!(decoded, [Ok(line)], "{text:?}");
    }
    for (code, rate) in SlcanBitrate::ALL.iter().enumerate() {
        assert_eq!(usize::from(rate.code()), code);
        assert_eq!(SlcanBitrate::from_bits_per_second(rate.bits_per_second()), Some(*rate));
    }
    assert_eq!(SlcanBitrate::from_bits_per_second(800_000), None);
    assert_eq!(Tag::new(*b"V1.0"), Err(SlcanError::InvalidTag));
}

#[test]
fn malformed_lines_are_rejected_with_the_reason() {
    let cases: [(&str, SlcanError); 16] = [
        ("t8000", SlcanError::IdOutOfRange { id: 0x800, extended: false }),
        ("T200000000", SlcanError::IdOutOfRange { id: 0x2000_0000, extended: true }),
        ("t1239", SlcanError::InvalidDlc(b'9')),
        ("t123F", SlcanError::InvalidDlc(b'F')),
        ("t1232AA", SlcanError::BadLength { what: "data frame", len: 7 }),
        ("t12", SlcanError::BadLength { what: "data frame", len: 3 }),
        ("t1231GG", SlcanError::InvalidHex("data")),
        ("tX230", SlcanError::InvalidHex("CAN id")),
        ("t123100EA5", SlcanError::BadLength { what: "data frame", len: 10 }),
        ("r12301", SlcanError::BadLength { what: "remote frame", len: 6 }),
        ("d1230", SlcanError::FdFrame),
        ("x", SlcanError::UnknownCommand(b'x')),
        ("S9", SlcanError::UnsupportedBitrateCode(9)),
        ("Z2", SlcanError::BadLength { what: "timestamp command", len: 2 }),
        ("OO", SlcanError::BadLength { what: "command or reply", len: 2 }),
        ("V1.03", SlcanError::InvalidTag),
    ];
    for (text, error) in cases {
        assert_eq!(parse_line(text.as_bytes()), Err(error), "{text:?}");
    }
}

fn decode_all(bytes: &[u8]) -> (Vec<Result<Line, SlcanError>>, SlcanDecoder) {
    let mut decoder = SlcanDecoder::new();
    let mut lines = Vec::new();
    decoder.feed(bytes, |line| lines.push(line));
    (lines, decoder)
}

#[test]
fn decoder_resynchronises_after_garbage_overlong_lines_and_bells() {
    let frame = data(0x321, false, &[1, 2, 3]);
    let mut stream = Vec::new();
    stream.extend_from_slice(b"\xFF\x00garbage\r");
    stream.extend_from_slice(&frame_line(frame));
    stream.extend_from_slice(&[b'A'; 500]);
    stream.push(b'\r');
    stream.extend_from_slice(&frame_line(frame));
    stream.extend_from_slice(b"t12"); // cut short by a BELL
    stream.push(BELL);
    stream.extend_from_slice(b"t3213010203\r\n"); // CR LF: the LF is ignored
    stream.extend_from_slice(&frame_line(frame));

    // Whole, and one byte at a time: the same lines.
    let (lines, decoder) = decode_all(&stream);
    let mut bytewise = SlcanDecoder::new();
    let one_by_one: Vec<_> = stream.iter().filter_map(|&b| bytewise.push(b)).collect();
    assert_eq!(lines, one_by_one);
    assert_eq!(
        lines,
        [
            Err(SlcanError::UnknownCommand(0xFF)),
            Ok(Line::Frame(frame)),
            Err(SlcanError::Overlong),
            Ok(Line::Frame(frame)),
            Ok(Line::Reply(Reply::Error)),
            Ok(Line::Frame(frame)),
            Ok(Line::Frame(frame)),
        ]
    );
    // The partial line before the BELL is rejected too, though not returned.
    assert_eq!(decoder.stats().rejected, 3);
    assert_eq!(decoder.stats().lines, 7);
    assert!(!decoder.is_mid_line());
}

fn arb_frame() -> impl Strategy<Value = SlcanFrame> {
    (any::<bool>(), any::<u32>(), any::<bool>(), proptest::collection::vec(any::<u8>(), 0..=8), any::<Option<u16>>())
        .prop_map(|(extended, id, remote, payload, timestamp)| {
            let id = if extended { id & 0x1FFF_FFFF } else { id & 0x7FF };
            let frame = if remote {
                SlcanFrame::remote(id, extended, payload.len() as u8).unwrap()
            } else {
                SlcanFrame::data(id, extended, &payload).unwrap()
            };
            frame.with_timestamp(timestamp)
        })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// Any bytes: no panic, and exactly one result per CR and per BELL (nothing else ends a
    /// line), so a caller answering each result answers each line once.
    #[test]
    fn decoder_is_total_and_answers_every_terminator(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        let (lines, decoder) = decode_all(&bytes);
        let terminators = bytes.iter().filter(|&&b| b == b'\r' || b == BELL).count();
        prop_assert_eq!(lines.len(), terminators);
        prop_assert_eq!(decoder.stats().lines, terminators as u64);
        prop_assert!(decoder.stats().rejected <= decoder.stats().lines);
    }

    /// Valid frame lines with arbitrary garbage between them, each garbage run ending in CR
    /// (which is what separates a line from what came before it on a noisy wire, and may be
    /// as long as it likes): every frame line is recovered, in order. Garbage may happen to
    /// contain frame lines of its own, so the sent frames must be a subsequence of the decoded.
    #[test]
    fn decoder_recovers_every_frame_between_garbage(
        items in proptest::collection::vec((proptest::collection::vec(any::<u8>(), 0..80), arb_frame()), 1..20),
        split in 1usize..64,
    ) {
        let mut stream = Vec::new();
        for (garbage, frame) in &items {
            stream.extend_from_slice(garbage);
            stream.push(b'\r');
            stream.extend_from_slice(&frame_line(*frame));
        }
        let mut decoder = SlcanDecoder::new();
        let mut decoded = Vec::new();
        for chunk in stream.chunks(split) {
            decoder.feed(chunk, |line| {
                if let Ok(Line::Frame(frame)) = line {
                    decoded.push(frame);
                }
            });
        }
        let mut wanted = items.iter().map(|(_, frame)| *frame).peekable();
        for frame in decoded {
            if wanted.peek() == Some(&frame) {
                wanted.next();
            }
        }
        prop_assert!(wanted.peek().is_none(), "frame {:?} not recovered", wanted.peek());
    }

    #[test]
    fn every_valid_frame_round_trips(frame in arb_frame()) {
        let (lines, _) = decode_all(&frame_line(frame));
        prop_assert_eq!(lines, vec![Ok(Line::Frame(frame))]);
    }
}

// ---------------------------------------------------------------------------------------------
// The adapter's replies, byte for byte

/// Frame `i` of a test sequence: standard and extended ids alternating in runs, every length.
fn test_frame(i: usize, salt: u8) -> CanFrame {
    let len = i % 9;
    let bytes: Vec<u8> = (0..len).map(|k| (i as u8).wrapping_mul(31).wrapping_add(k as u8) ^ salt).collect();
    if (i / 3).is_multiple_of(2) {
        CanFrame::standard((i as u32 * 37 + u32::from(salt)) & 0x7FF, &bytes).unwrap()
    } else {
        CanFrame::new((i as u32).wrapping_mul(2_654_435_761) & 0x1FFF_FFFF, &bytes).unwrap()
    }
}

/// Reads what arrives until the port stays quiet for 50 ms.
fn read_quiet(port: &mut TTYPort) -> Vec<u8> {
    port.set_timeout(Duration::from_millis(50)).unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        match port.read(&mut buf) {
            Ok(0) => break,
            Ok(len) => got.extend_from_slice(&buf[..len]),
            Err(e) if e.kind() == ErrorKind::TimedOut => break,
            Err(e) => panic!("reading the pty: {e}"),
        }
    }
    got
}

/// Writes `line` as the host, lets the adapter serve it, returns what the adapter answered.
fn ask(adapter: &mut SlcanAdapter<TTYPort, LoopbackCanBus>, host: &mut TTYPort, line: &[u8]) -> Vec<u8> {
    host.write_all(line).unwrap();
    let before = adapter.stats().host_lines;
    let expected = line.iter().filter(|&&b| b == b'\r' || b == BELL).count() as u64;
    let deadline = Instant::now() + WAIT;
    while adapter.stats().host_lines < before + expected {
        assert!(Instant::now() < deadline, "adapter did not serve {:?}", line.escape_ascii().to_string());
        adapter.poll(Duration::from_millis(5)).unwrap();
    }
    read_quiet(host)
}

fn adapter_on_pty(queue_frames: usize) -> (SlcanAdapter<TTYPort, LoopbackCanBus>, TTYPort, LoopbackCanBus) {
    let (master, slave) = TTYPort::pair().expect("cannot open a pty pair");
    let mut nodes = LoopbackCanBus::network_with_queue(CanKind::Classic, 2, queue_frames).into_iter();
    let adapter = SlcanAdapter::new(master, nodes.next().unwrap());
    (adapter, slave, nodes.next().unwrap())
}

#[test]
fn adapter_answers_commands_like_a_canable() {
    let (mut adapter, mut host, mut peer) = adapter_on_pty(64);
    let ok = b"\r".as_slice();
    let bell = b"\x07".as_slice();
    assert_eq!(adapter.state(), ChannelState::Closed);

    assert_eq!(ask(&mut adapter, &mut host, b"V\r"), b"V0101\r");
    assert_eq!(ask(&mut adapter, &mut host, b"N\r"), b"NHAL1\r");
    assert_eq!(ask(&mut adapter, &mut host, b"F\r"), bell, "status only while open");
    assert_eq!(ask(&mut adapter, &mut host, b"t1230\r"), bell, "no transmission while closed");
    assert_eq!(ask(&mut adapter, &mut host, b"S9\r"), bell);
    assert_eq!(ask(&mut adapter, &mut host, b"S6\r"), ok);
    assert_eq!(adapter.bitrate(), Some(SlcanBitrate::B500k));
    assert_eq!(ask(&mut adapter, &mut host, b"\r"), ok, "an empty line is a no-op");
    assert_eq!(ask(&mut adapter, &mut host, b"C\r"), ok, "C is accepted while closed, as on a CANable");
    assert_eq!(ask(&mut adapter, &mut host, b"O\r"), ok);
    assert_eq!(adapter.state(), ChannelState::Open);
    assert_eq!(ask(&mut adapter, &mut host, b"O\r"), ok, "O while open is accepted: python-can sends it twice");
    assert_eq!(ask(&mut adapter, &mut host, b"L\r"), bell, "but not a switch to listen-only");
    assert_eq!(ask(&mut adapter, &mut host, b"S5\r"), bell, "bit rate only while closed");
    assert_eq!(ask(&mut adapter, &mut host, b"Z1\r"), bell, "timestamps only while closed");
    assert_eq!(ask(&mut adapter, &mut host, b"F\r"), b"F00\r");

    assert_eq!(ask(&mut adapter, &mut host, b"t1232AABB\r"), ok);
    assert_eq!(peer.recv(WAIT).unwrap(), Some(CanFrame::standard(0x123, &[0xAA, 0xBB]).unwrap()));
    assert_eq!(ask(&mut adapter, &mut host, b"T1abcdef01ff\r"), ok);
    assert_eq!(peer.recv(WAIT).unwrap(), Some(CanFrame::new(0x1ABC_DEF0, &[0xFF]).unwrap()));
    assert_eq!(ask(&mut adapter, &mut host, b"r1230\r"), bell, "a CanBus carries no remote frames");
    assert_eq!(ask(&mut adapter, &mut host, b"hello\r"), bell);
    assert_eq!(ask(&mut adapter, &mut host, b"d12380011223344556677\r"), bell, "no CAN FD");
    let mut overlong = vec![b'T'; 200];
    overlong.push(b'\r');
    assert_eq!(ask(&mut adapter, &mut host, &overlong), bell, "one BELL for one overlong line");
    // Several lines in one write: one reply each, in order.
    assert_eq!(ask(&mut adapter, &mut host, b"t0010\rxx\rt0020\r"), b"\r\x07\r");
    assert_eq!(peer.recv(WAIT).unwrap().map(|f| f.id), Some(1));
    assert_eq!(peer.recv(WAIT).unwrap().map(|f| f.id), Some(2));

    // Bus to host while open.
    peer.send(&CanFrame::standard(0x321, &[1, 2, 3]).unwrap()).unwrap();
    peer.send(&CanFrame::new(0x0ABC_DEF0, &[]).unwrap()).unwrap();
    adapter.poll(Duration::ZERO).unwrap();
    assert_eq!(read_quiet(&mut host), b"t3213010203\rT0ABCDEF00\r");

    // Timestamps after Z1: four more hex digits, milliseconds below 60 000.
    assert_eq!(ask(&mut adapter, &mut host, b"C\rZ1\rO\r"), b"\r\r\r");
    assert!(adapter.timestamps());
    peer.send(&CanFrame::standard(0x7FF, &[9]).unwrap()).unwrap();
    adapter.poll(Duration::ZERO).unwrap();
    let line = read_quiet(&mut host);
    assert_eq!(line.len(), "t7FF109".len() + 4 + 1, "{:?}", line.escape_ascii().to_string());
    match parse_line(line.strip_suffix(b"\r").unwrap()) {
        Ok(Line::Frame(frame)) => assert!(frame.timestamp().is_some_and(|ms| ms < 60_000), "{frame:?}"),
        other => panic!("{other:?}"),
    }

    // Listen-only: frames reach the host, the host may not transmit.
    assert_eq!(ask(&mut adapter, &mut host, b"C\rZ0\rL\r"), b"\r\r\r");
    assert_eq!(adapter.state(), ChannelState::ListenOnly);
    assert_eq!(ask(&mut adapter, &mut host, b"t1230\r"), bell);
    peer.send(&CanFrame::standard(0x100, &[]).unwrap()).unwrap();
    adapter.poll(Duration::ZERO).unwrap();
    assert_eq!(read_quiet(&mut host), b"t1000\r");

    // Lawicel acknowledgements.
    adapter.set_lawicel_acks(true);
    assert_eq!(ask(&mut adapter, &mut host, b"C\rO\rt1230\rT000000010\r"), b"\r\rz\rZ\r");

    let stats = adapter.stats();
    assert_eq!(stats.rejected_lines, 5, "{stats:?}"); // S9, hello, d…, overlong, xx
    assert_eq!(stats.frames_to_bus, 6, "{stats:?}");
    assert_eq!(stats.frames_to_host, 4, "{stats:?}");
    assert_eq!(stats.bus_send_errors, 0, "{stats:?}");
}

#[test]
fn adapter_reports_lost_frames_in_the_status_flags() {
    let (mut adapter, mut host, mut peer) = adapter_on_pty(4);
    assert_eq!(ask(&mut adapter, &mut host, b"S8\rO\r"), b"\r\r");
    for i in 0..10 {
        peer.send(&test_frame(i, 0)).unwrap();
    }
    adapter.poll(Duration::ZERO).unwrap();
    let forwarded = read_quiet(&mut host);
    assert_eq!(forwarded.iter().filter(|&&b| b == b'\r').count(), 4, "the queue kept the last 4");
    assert_eq!(ask(&mut adapter, &mut host, b"F\r"), b"F08\r", "data overrun");
    assert_eq!(ask(&mut adapter, &mut host, b"F\r"), b"F00\r", "reading the flags clears them");
}

#[test]
fn a_slow_host_loses_frames_whole_and_counted() {
    const FLOOD: usize = 12_000; // 22 bytes a line: far more than the pty holds
    const QUEUE: usize = 256;
    let (mut adapter, mut host, mut peer) = adapter_on_pty(QUEUE);
    assert_eq!(ask(&mut adapter, &mut host, b"O\r"), b"\r");
    let adapter = Running::start(adapter);
    for i in 0..FLOOD {
        peer.send(&CanFrame::standard(0x123, &(i as u64).to_le_bytes()).unwrap()).unwrap();
    }
    // The host reads only now: the pty filled, the adapter's writes waited, its bus queue
    // overflowed. What arrives is whole lines in order, with gaps.
    let mut decoder = SlcanDecoder::new();
    let mut last = None;
    let mut received = 0u64;
    loop {
        let got = read_quiet(&mut host);
        if got.is_empty() {
            break;
        }
        decoder.feed(&got, |line| match line {
            Ok(Line::Frame(frame)) => {
                let seq = u64::from_le_bytes(frame.payload().try_into().unwrap());
                assert!(last.is_none_or(|last| seq > last), "{seq} after {last:?}");
                last = Some(seq);
                received += 1;
            }
            other => panic!("{other:?}"),
        });
    }
    assert_eq!(last, Some(FLOOD as u64 - 1), "the newest frames are kept");
    host.write_all(b"F\r").unwrap();
    assert_eq!(read_quiet(&mut host), b"F08\r", "data overrun");
    let adapter = adapter.stop();
    let lost = adapter.bus().dropped_frames();
    assert!(lost > 0);
    assert_eq!(received, adapter.stats().frames_to_host);
    assert_eq!(received + lost, FLOOD as u64);
}

#[test]
fn closed_adapter_discards_bus_frames() {
    let (mut adapter, mut host, mut peer) = adapter_on_pty(64);
    for i in 0..5 {
        peer.send(&test_frame(i, 1)).unwrap();
    }
    adapter.poll(Duration::from_millis(5)).unwrap();
    assert!(read_quiet(&mut host).is_empty());
    // Frames that reach the bus between two passes are not forwarded by a later O either.
    peer.send(&test_frame(5, 1)).unwrap();
    assert_eq!(ask(&mut adapter, &mut host, b"O\r"), b"\r");
    adapter.poll(Duration::ZERO).unwrap();
    assert!(read_quiet(&mut host).is_empty());
    assert_eq!(adapter.stats().discarded_closed, 6);
    assert_eq!(adapter.stats().frames_to_host, 0);
}

// ---------------------------------------------------------------------------------------------
// Host against adapter over a pty

struct Running {
    stop: Arc<AtomicBool>,
    thread: JoinHandle<(SlcanAdapter<TTYPort, LoopbackCanBus>, Result<(), LinkError>)>,
}

impl Running {
    fn start(mut adapter: SlcanAdapter<TTYPort, LoopbackCanBus>) -> Running {
        let stop = Arc::new(AtomicBool::new(false));
        let flag = Arc::clone(&stop);
        let thread = thread::spawn(move || {
            let result = adapter.run_until(&flag);
            (adapter, result)
        });
        Running { stop, thread }
    }

    fn stop(self) -> SlcanAdapter<TTYPort, LoopbackCanBus> {
        self.stop.store(true, Ordering::Release);
        let (adapter, result) = self.thread.join().unwrap();
        result.unwrap();
        adapter
    }
}

struct Bridge {
    host: SlcanBus<TTYPort>,
    /// The other node of the adapter's loopback bus: where simulated devices would sit.
    peer: LoopbackCanBus,
    adapter: Running,
}

fn bridge(lawicel_acks: bool) -> Bridge {
    let (master, slave) = TTYPort::pair().expect("cannot open a pty pair");
    let mut nodes = LoopbackCanBus::network_with_queue(CanKind::Classic, 2, 4096).into_iter();
    let mut adapter = SlcanAdapter::new(master, nodes.next().unwrap());
    adapter.set_lawicel_acks(lawicel_acks);
    let adapter = Running::start(adapter);
    let host = SlcanBus::connect(slave, SlcanBitrate::B500k).expect("open handshake failed");
    Bridge { host, peer: nodes.next().unwrap(), adapter }
}

fn exchange_frames(bridge: &mut Bridge, count: usize) {
    let to_bus: Vec<CanFrame> = (0..count).map(|i| test_frame(i, 0x11)).collect();
    let to_host: Vec<CanFrame> = (0..count).map(|i| test_frame(i + 7, 0x22)).collect();
    let (mut on_bus, mut on_host) = (Vec::new(), Vec::new());
    for i in 0..count {
        bridge.host.send(&to_bus[i]).unwrap();
        bridge.peer.send(&to_host[i]).unwrap();
        while let Some(frame) = bridge.host.recv(Duration::ZERO).unwrap() {
            on_host.push(frame);
        }
        while let Some(frame) = bridge.peer.recv(Duration::ZERO).unwrap() {
            on_bus.push(frame);
        }
    }
    let deadline = Instant::now() + WAIT;
    while on_bus.len() < count || on_host.len() < count {
        assert!(Instant::now() < deadline, "{} of {count} on the bus, {} at the host", on_bus.len(), on_host.len());
        if let Some(frame) = bridge.host.recv(Duration::from_millis(5)).unwrap() {
            on_host.push(frame);
        }
        while let Some(frame) = bridge.peer.recv(Duration::ZERO).unwrap() {
            on_bus.push(frame);
        }
    }
    assert_eq!(on_bus, to_bus, "host to bus");
    assert_eq!(on_host, to_host, "bus to host");
    // Lets the last replies arrive, so the counts below are final.
    assert_eq!(bridge.host.recv(Duration::from_millis(100)).unwrap(), None);
}

#[test]
fn open_handshake_opens_the_adapter_at_the_bit_rate() {
    let bridge = bridge(false);
    assert!(bridge.host.is_open());
    assert_eq!(bridge.host.kind(), CanKind::Classic);
    assert!(bridge.host.port_name().starts_with("/dev/pts/"), "{}", bridge.host.port_name());
    let adapter = bridge.adapter.stop();
    assert_eq!(adapter.state(), ChannelState::Open);
    assert_eq!(adapter.bitrate(), Some(SlcanBitrate::B500k));
    assert_eq!(adapter.stats().host_lines, 3);
    assert_eq!(adapter.stats().refused, 0);
}

#[test]
fn thousand_frames_each_way_arrive_equal_and_in_order() {
    let mut bridge = bridge(false);
    exchange_frames(&mut bridge, 1000);
    let host = bridge.host.stats();
    assert_eq!((host.frames_sent, host.frames_received), (1000, 1000), "{host:?}");
    assert_eq!(host.acks, 1000, "{host:?}");
    assert_eq!((host.refused, host.unexpected, host.stale_frames), (0, 0, 0), "{host:?}");
    assert_eq!(bridge.host.dropped_frames(), 0, "{host:?}");
    let adapter = bridge.adapter.stop().stats();
    assert_eq!(
        adapter,
        AdapterStats { host_lines: 1003, frames_to_bus: 1000, frames_to_host: 1000, ..AdapterStats::default() }
    );
}

#[test]
fn lawicel_acknowledgements_are_consumed() {
    let mut bridge = bridge(true);
    exchange_frames(&mut bridge, 100);
    let host = bridge.host.stats();
    assert_eq!((host.acks, host.refused, host.unexpected), (100, 0, 0), "{host:?}");
    // The close handshake finds its reply after all those acknowledgements.
    bridge.host.close_channel().unwrap();
    assert_eq!(bridge.adapter.stop().state(), ChannelState::Closed);
}

#[test]
fn closed_channel_discards_and_reopens() {
    let mut bridge = bridge(false);
    bridge.host.send(&test_frame(1, 0)).unwrap();
    bridge.host.close_channel().unwrap();
    assert!(!bridge.host.is_open());
    assert!(matches!(bridge.host.send(&test_frame(2, 0)), Err(LinkError::Closed(_))));
    assert_eq!(bridge.peer.recv(WAIT).unwrap(), Some(test_frame(1, 0)));
    for i in 0..5 {
        bridge.peer.send(&test_frame(i, 9)).unwrap();
    }
    assert_eq!(bridge.host.recv(Duration::from_millis(100)).unwrap(), None);
    let adapter = bridge.adapter.stop();
    assert_eq!(adapter.state(), ChannelState::Closed);
    assert_eq!(adapter.stats().discarded_closed, 5);
    assert_eq!(adapter.stats().frames_to_host, 0);

    bridge.adapter = Running::start(adapter);
    bridge.host.open_channel().unwrap();
    let fresh = test_frame(8, 3);
    bridge.peer.send(&fresh).unwrap();
    assert_eq!(bridge.host.recv(WAIT).unwrap(), Some(fresh));
    // Only the frame's OK was an acknowledgement; the commands' replies were awaited.
    assert_eq!(bridge.host.stats().acks, 1);
}

#[test]
fn host_refuses_frames_slcan_cannot_carry() {
    let mut bridge = bridge(false);
    let fd = CanFrame::new(0x10, &[0; 12]).unwrap();
    assert!(matches!(bridge.host.send(&fd), Err(LinkError::CanFrameTooLong { len: 12, max: 8 })));
    let wide_standard = CanFrame { id: 0x800, len: 0, data: [0; 64], extended: false };
    assert!(matches!(bridge.host.send(&wide_standard), Err(LinkError::Framing(FrameError::InvalidCanId(0x800)))));
    assert_eq!(bridge.host.stats().frames_sent, 0);
}

#[test]
fn closing_the_pty_is_an_io_error_at_the_host() {
    let bridge = bridge(false);
    let Bridge { mut host, adapter, peer } = bridge;
    drop(adapter.stop()); // closes the master
    drop(peer);
    let started = Instant::now();
    match host.recv(WAIT) {
        Err(LinkError::Io { context, source }) => {
            assert!(context.contains(host.port_name()), "{context}");
            assert!(started.elapsed() < Duration::from_secs(1), "noticed only after {:?}", started.elapsed());
            eprintln!("host recv: {context}: {source} ({:?})", source.kind());
        }
        other => panic!("expected LinkError::Io, got {other:?}"),
    }
    match host.send(&test_frame(0, 0)) {
        Err(LinkError::Io { context, .. }) => assert!(context.contains(host.port_name()), "{context}"),
        other => panic!("expected LinkError::Io, got {other:?}"),
    }
}

#[test]
fn closing_the_pty_is_an_io_error_at_the_adapter() {
    let (mut adapter, host, _peer) = adapter_on_pty(64);
    drop(host); // closes the slave, the host's end
    let deadline = Instant::now() + WAIT;
    loop {
        match adapter.poll(Duration::from_millis(20)) {
            Err(LinkError::Io { context, source }) => {
                eprintln!("adapter poll: {context}: {source} ({:?})", source.kind());
                break;
            }
            Err(other) => panic!("expected LinkError::Io, got {other:?}"),
            Ok(_) => assert!(Instant::now() < deadline, "adapter did not notice the closed pty"),
        }
    }
}

#[test]
fn can_link_packets_cross_slcan_both_ways() {
    let bridge = bridge(false);
    let Bridge { host, peer, adapter } = bridge;
    let mut rover = CanLink::new(host, NodeId(1));
    let mut ground = CanLink::new(peer, NodeId(2));
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    for (i, size) in [0usize, 7, 8, 300, MAX_LINK_PACKET_BYTES].into_iter().enumerate() {
        let packet: Vec<u8> = (0..size).map(|k| (k * 13 + i) as u8).collect();
        rover.send(&packet).unwrap();
        let len = ground.recv(&mut buf, WAIT).unwrap().expect("packet over SLCAN did not arrive");
        assert_eq!(&buf[..len], packet.as_slice(), "{size} bytes rover to ground");
        ground.send(&packet).unwrap();
        let len = rover.recv(&mut buf, WAIT).unwrap().expect("packet over SLCAN did not arrive");
        assert_eq!(&buf[..len], packet.as_slice(), "{size} bytes ground to rover");
    }
    assert_eq!(rover.counters().rejected.total(), 0, "{:?}", rover.counters());
    assert_eq!(rover.counters().dropped_frames, 0, "{:?}", rover.counters());
    assert_eq!(ground.counters().rejected.total(), 0, "{:?}", ground.counters());
    let frames = rover.counters().frames_sent;
    assert!(frames > 150, "a full-size packet is ~150 classic frames, sent {frames}");
    let stats = adapter.stop().stats();
    assert_eq!(stats.frames_to_bus, frames);
    assert_eq!(stats.refused, 0);
}

// ---------------------------------------------------------------------------------------------
// A scripted adapter, for what ours never does

/// A fake adapter on the pty master: answers each line the host sends with `reply(line)`,
/// writing `before_reply` first (frames streaming from an earlier session). Returns the lines
/// it received once the host has been quiet for 300 ms.
fn scripted_adapter(
    mut master: TTYPort,
    before_reply: &'static [u8],
    reply: fn(&[u8]) -> Option<&'static [u8]>,
    after_open: &'static [u8],
) -> JoinHandle<Vec<String>> {
    thread::spawn(move || {
        master.set_timeout(Duration::from_millis(300)).unwrap();
        let mut lines = Vec::new();
        let mut line = Vec::new();
        let mut buf = [0u8; 256];
        loop {
            let len = match master.read(&mut buf) {
                Ok(0) => break,
                Ok(len) => len,
                Err(_) => break,
            };
            for &byte in &buf[..len] {
                if byte != b'\r' {
                    line.push(byte);
                    continue;
                }
                master.write_all(before_reply).unwrap();
                if let Some(answer) = reply(&line) {
                    master.write_all(answer).unwrap();
                }
                if line == b"O" {
                    master.write_all(after_open).unwrap();
                }
                lines.push(String::from_utf8_lossy(&line).into_owned());
                line.clear();
            }
        }
        lines
    })
}

#[test]
fn host_open_handshake_tolerates_frames_already_streaming() {
    let (master, slave) = TTYPort::pair().unwrap();
    let fake = scripted_adapter(master, b"t1230\rT000000011AA\r", |_| Some(b"\r"), b"t4561AA\r");
    let mut host = SlcanBus::connect(slave, SlcanBitrate::B1M).unwrap();
    assert_eq!(host.recv(WAIT).unwrap(), Some(CanFrame::standard(0x456, &[0xAA]).unwrap()));
    let stats = host.stats();
    assert_eq!(stats.stale_frames, 6, "two before each reply: {stats:?}");
    assert_eq!(host.dropped_frames(), 0);
    host.close_channel().unwrap();
    // Frames before the reply to C came while the channel was still ours: kept for recv.
    assert_eq!(host.recv(WAIT).unwrap(), Some(CanFrame::standard(0x123, &[]).unwrap()));
    assert_eq!(host.recv(WAIT).unwrap(), Some(CanFrame::new(1, &[0xAA]).unwrap()));
    assert_eq!(host.stats().stale_frames, 6);
    assert_eq!(fake.join().unwrap(), ["C", "S8", "O", "C"]);
}

#[test]
fn host_reports_a_refused_bit_rate_and_a_silent_adapter() {
    let (master, slave) = TTYPort::pair().unwrap();
    let fake = scripted_adapter(master, b"", |line| Some(if line.starts_with(b"S") { b"\x07" } else { b"\r" }), b"");
    match SlcanBus::connect(slave, SlcanBitrate::B250k) {
        Err(LinkError::Config(message)) => assert!(message.contains("refused `S5`"), "{message}"),
        other => panic!("expected a configuration error, got {other:?}"),
    }
    assert_eq!(fake.join().unwrap(), ["C", "S5"]);

    let (_master, slave) = TTYPort::pair().unwrap();
    let config = SlcanConfig { reply_timeout: Duration::from_millis(200), ..SlcanConfig::new(SlcanBitrate::B500k) };
    let started = Instant::now();
    match SlcanBus::connect_with(slave, config) {
        Err(LinkError::Io { context, source }) => {
            assert_eq!(source.kind(), ErrorKind::TimedOut);
            assert!(context.contains("no reply to `C`"), "{context}");
        }
        other => panic!("expected a timeout, got {other:?}"),
    }
    assert!(started.elapsed() < Duration::from_secs(1));
}

#[test]
fn host_skips_remote_frames_and_garbage_and_ignores_timestamps() {
    let (master, slave) = TTYPort::pair().unwrap();
    let fake =
        scripted_adapter(master, b"", |_| Some(b"\r"), b"r1230\rR000000018\rt12320102EA5F\rzz!\rT000000FF0\rF00\r");
    let mut host = SlcanBus::connect(slave, SlcanBitrate::B125k).unwrap();
    assert_eq!(host.recv(WAIT).unwrap(), Some(CanFrame::standard(0x123, &[1, 2]).unwrap()));
    assert_eq!(host.recv(WAIT).unwrap(), Some(CanFrame::new(0xFF, &[]).unwrap()));
    assert_eq!(host.recv(Duration::from_millis(50)).unwrap(), None);
    let stats = host.stats();
    assert_eq!((stats.remote_frames, stats.rejected_lines, stats.unexpected), (2, 1, 1), "{stats:?}");
    assert_eq!(host.dropped_frames(), 3);
    drop(host);
    fake.join().unwrap();
}

// ---------------------------------------------------------------------------------------------
// Any stream with timeouts

fn socket_port(stream: UnixStream, name: &str) -> TimedPort<UnixStream> {
    TimedPort::new(stream, name, |s, timeout| {
        s.set_read_timeout(Some(timeout))?;
        s.set_write_timeout(Some(timeout))
    })
}

#[test]
fn host_and_adapter_run_over_any_timed_stream() {
    let (a, b) = UnixStream::pair().unwrap();
    let mut nodes = LoopbackCanBus::network(CanKind::Classic, 2).into_iter();
    let mut adapter = SlcanAdapter::new(socket_port(a, "socket a"), nodes.next().unwrap());
    let mut peer = nodes.next().unwrap();
    let stop = AtomicBool::new(false);
    let (result, state, stats) = thread::scope(|scope| {
        let thread = scope.spawn(|| {
            let result = adapter.run_until(&stop);
            (result, adapter.state(), adapter.stats())
        });
        let mut host = SlcanBus::connect(socket_port(b, "socket b"), SlcanBitrate::B20k).unwrap();
        for i in 0..50 {
            host.send(&test_frame(i, 5)).unwrap();
            assert_eq!(peer.recv(WAIT).unwrap(), Some(test_frame(i, 5)));
            peer.send(&test_frame(i, 6)).unwrap();
            assert_eq!(host.recv(WAIT).unwrap(), Some(test_frame(i, 6)));
        }
        // Dropping the host closes the channel, then its end of the stream.
        drop(host);
        let outcome = thread.join().unwrap();
        stop.store(true, Ordering::Release);
        outcome
    });
    assert_eq!(state, ChannelState::Closed, "the host's drop sent C");
    assert_eq!((stats.frames_to_bus, stats.frames_to_host, stats.refused), (50, 50, 0));
    match result {
        Err(LinkError::Io { context, source }) => {
            // End of stream; or, if the host closed with our reply to its C unread, a reset
            // when reading or a broken pipe when writing the next reply.
            assert!(
                matches!(source.kind(), ErrorKind::UnexpectedEof | ErrorKind::ConnectionReset | ErrorKind::BrokenPipe),
                "{source}"
            );
            assert!(context.contains("socket a"), "{context}");
        }
        other => panic!("expected end of stream, got {other:?}"),
    }
}
