//! SerialLink over a real pseudo-terminal pair (serialport's `TTYPort::pair`, which puts the
//! pty in raw mode, so every byte value passes unchanged), and over a Unix socket for the
//! generic-port contract.

// Helpers outside #[test] functions are test code too; clippy.toml only exempts the latter.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::io::Write;
use std::os::unix::net::UnixStream;
use std::thread;
use std::time::{Duration, Instant};

use hal::link::{Link, LinkError, MAX_LINK_PACKET_BYTES};
use hal::serial::SerialLink;
use protocol::frame::Framing;
use protocol::frame::stream::{encode_frame, max_frame_len};
use serialport::TTYPort;

const WAIT: Duration = Duration::from_secs(3);

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    fn bytes(&mut self, len: usize) -> Vec<u8> {
        (0..len).map(|_| self.next() as u8).collect()
    }

    /// Random sizes, with the extremes and many zero bytes (what COBS has to escape).
    fn packet(&mut self) -> Vec<u8> {
        let len = match self.next() % 10 {
            0 => 0,
            1 => MAX_LINK_PACKET_BYTES,
            _ => (self.next() % (MAX_LINK_PACKET_BYTES as u64 + 1)) as usize,
        };
        let mut p = self.bytes(len);
        for byte in p.iter_mut().filter(|b| **b < 0x40) {
            *byte = 0;
        }
        p
    }
}

fn pty_links() -> (SerialLink<TTYPort>, SerialLink<TTYPort>) {
    let (master, slave) = TTYPort::pair().expect("cannot open a pty pair");
    (SerialLink::from_serialport(master), SerialLink::from_serialport(slave))
}

fn recv_packet<L: Link>(link: &mut L) -> Vec<u8> {
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    let len = link.recv(&mut buf, WAIT).unwrap().expect("packet did not arrive in time");
    buf.truncate(len);
    buf
}

/// Sends `packets` from `tx` on a thread while `rx` receives them here, then hands `tx` back.
fn stream<L: Link + 'static>(mut tx: L, rx: &mut impl Link, packets: Vec<Vec<u8>>) -> L {
    let expected = packets.clone();
    let sender = thread::spawn(move || {
        for p in &packets {
            tx.send(p).unwrap();
        }
        tx
    });
    for (i, p) in expected.iter().enumerate() {
        assert_eq!(recv_packet(rx), *p, "packet {i} of {} bytes corrupted", p.len());
    }
    sender.join().unwrap()
}

#[test]
fn many_random_packets_cross_the_pty_both_ways() {
    let (a, mut b) = pty_links();
    assert_eq!(a.framing(), Framing::Stream);
    let mut rng = Rng(0x1234_5678_9ABC_DEF1);
    let forward: Vec<Vec<u8>> = (0..150).map(|_| rng.packet()).collect();
    let backward: Vec<Vec<u8>> = (0..150).map(|_| rng.packet()).collect();
    let mut a = stream(a, &mut b, forward.clone());
    let b = stream(b, &mut a, backward.clone());
    let (ca, cb) = (a.counters(), b.counters());
    assert_eq!((ca.packets_sent, cb.packets_received), (150, 150));
    assert_eq!((cb.packets_sent, ca.packets_received), (150, 150));
    let bytes: u64 = forward.iter().map(|p| p.len() as u64).sum();
    assert_eq!(cb.packet_bytes_received, bytes);
    assert_eq!(ca.rejected.total() + cb.rejected.total(), 0, "{ca:?} {cb:?}");
}

#[test]
fn garbage_between_frames_is_skipped_and_counted() {
    let (mut a, mut b) = pty_links();
    let mut rng = Rng(42);
    let bursts: Vec<Vec<u8>> = vec![
        b"\xff\x13\x37 line noise".to_vec(),
        vec![0x55; 2000], // no delimiter for longer than any frame: decoder overflow
        rng.bytes(300),   // random, with delimiters inside: several bad frames
        vec![0x00, 0x01, 0x02, 0x00],
        vec![0x03, 0x11, 0x22], // COBS block cut short by the next frame's delimiter
    ];
    let mut packets = Vec::new();
    for (i, burst) in bursts.iter().enumerate() {
        let p = rng.packet();
        a.send(&p).unwrap();
        a.port_mut().write_all(burst).unwrap();
        packets.push(p);
        // One packet at a time: the pty buffer is a few KiB and nobody reads concurrently.
        assert_eq!(recv_packet(&mut b), packets[i], "packet after garbage burst {i}");
    }
    let p = rng.packet();
    a.send(&p).unwrap();
    assert_eq!(recv_packet(&mut b), p);
    let counters = b.counters();
    assert_eq!(counters.packets_received, bursts.len() as u64 + 1);
    assert!(counters.rejected.overflow >= 1, "{counters:?}");
    // Which check catches random bytes depends on the bytes; together they catch all bursts.
    assert!(counters.rejected.crc + counters.rejected.cobs >= 4, "{counters:?}");
    assert!(counters.rejected.total() >= bursts.len() as u64, "{counters:?}");
    assert_eq!(counters.frames_received, counters.packets_received + counters.rejected.total());
}

#[test]
fn frame_split_over_several_writes_arrives() {
    let (mut master, slave) = TTYPort::pair().unwrap();
    let mut rx = SerialLink::from_serialport(slave);
    let mut rng = Rng(7);
    let packet = rng.packet();
    let mut frame = vec![0u8; max_frame_len(packet.len())];
    let len = encode_frame(&packet, &mut frame).unwrap();
    frame.truncate(len);

    // Half a frame, then a recv that times out: the half must stay buffered for the next call.
    let (head, tail) = frame.split_at(len / 2);
    master.write_all(head).unwrap();
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    assert_eq!(rx.recv(&mut buf, Duration::from_millis(50)).unwrap(), None);

    // The rest dribbles in over several writes while recv is waiting.
    let tail = tail.to_vec();
    let writer = thread::spawn(move || {
        for piece in tail.chunks(tail.len().div_ceil(5).max(1)) {
            thread::sleep(Duration::from_millis(20));
            master.write_all(piece).unwrap();
        }
        master
    });
    assert_eq!(recv_packet(&mut rx), packet);
    let _master = writer.join().unwrap();
    assert_eq!(rx.counters().rejected.total(), 0);
}

#[test]
fn several_frames_in_one_read_are_returned_one_per_recv() {
    let (mut master, slave) = TTYPort::pair().unwrap();
    let mut rx = SerialLink::from_serialport(slave);
    let packets: Vec<Vec<u8>> = (0..5u8).map(|i| vec![i; 10 + usize::from(i)]).collect();
    let mut wire = Vec::new();
    for p in &packets {
        let mut frame = vec![0u8; max_frame_len(p.len())];
        let len = encode_frame(p, &mut frame).unwrap();
        wire.extend_from_slice(&frame[..len]);
    }
    master.write_all(&wire).unwrap();
    for p in &packets {
        assert_eq!(recv_packet(&mut rx), *p);
    }
}

#[test]
fn recv_times_out_with_none() {
    let (_a, mut b) = pty_links();
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    let start = Instant::now();
    assert_eq!(b.recv(&mut buf, Duration::from_millis(100)).unwrap(), None);
    let waited = start.elapsed();
    assert!(waited >= Duration::from_millis(100) && waited < Duration::from_secs(1), "{waited:?}");
}

#[test]
fn generic_port_honours_timeout_control_and_reports_a_closed_peer() {
    let (left, right) = UnixStream::pair().unwrap();
    let set_timeout = |stream: &mut UnixStream, timeout| stream.set_read_timeout(Some(timeout));
    let mut a = SerialLink::with_timeout_control(left, set_timeout);
    let mut b = SerialLink::with_timeout_control(right, set_timeout);
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    let start = Instant::now();
    assert_eq!(b.recv(&mut buf, Duration::from_millis(50)).unwrap(), None);
    assert!(start.elapsed() < Duration::from_secs(1));
    a.send(&[0, 0, 0, 1]).unwrap();
    assert_eq!(recv_packet(&mut b), vec![0, 0, 0, 1]);
    drop(a);
    assert!(matches!(b.recv(&mut buf, WAIT), Err(LinkError::Closed(_))));
}

#[test]
fn refuses_oversized_packets() {
    let (mut a, _b) = pty_links();
    let error = a.send(&vec![1; MAX_LINK_PACKET_BYTES + 1]).unwrap_err();
    assert!(matches!(error, LinkError::PacketTooLarge { len: 1071, max: 1070 }), "{error}");
}
