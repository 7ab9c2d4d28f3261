//! UdpLink over real sockets on 127.0.0.1.

// Helpers outside #[test] functions are test code too; clippy.toml only exempts the latter.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use hal::link::{Link, LinkError, MAX_LINK_PACKET_BYTES};
use hal::udp::UdpLink;
use protocol::frame::Framing;

const WAIT: Duration = Duration::from_secs(2);

/// Deterministic bytes for packet `seq` of `len` bytes, so a receiver can check content.
fn packet(seq: u32, len: usize) -> Vec<u8> {
    let mut state = 0x9E37_79B9_7F4A_7C15u64 ^ (u64::from(seq) << 17) ^ len as u64;
    (0..len)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u8
        })
        .collect()
}

fn pair(mtu_a: usize, mtu_b: usize) -> (UdpLink, UdpLink) {
    let a = UdpLink::bind("127.0.0.1:0").unwrap().with_mtu(mtu_a).unwrap();
    let b = UdpLink::bind("127.0.0.1:0").unwrap().with_mtu(mtu_b).unwrap();
    let (a_addr, b_addr) = (a.local_addr(), b.local_addr());
    (a.with_peers([b_addr]), b.with_peers([a_addr]))
}

fn sizes() -> Vec<usize> {
    let mut sizes = vec![0, 1, 2, 6, 7, 193, 194, 195, 200, 388, 389, 500, 1069, MAX_LINK_PACKET_BYTES];
    sizes.extend((0..60u32).map(|i| (i as usize * 7919) % (MAX_LINK_PACKET_BYTES + 1)));
    sizes
}

fn expect_packet(link: &mut UdpLink, expected: &[u8]) {
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    let len = link.recv(&mut buf, WAIT).unwrap().expect("packet did not arrive in time");
    assert_eq!(&buf[..len], expected, "packet of {} bytes corrupted", expected.len());
}

#[test]
fn packets_of_every_size_cross_both_ways_with_fragmentation() {
    // a fragments at 200 bytes (up to 6 datagrams per packet), b sends whole datagrams.
    let (mut a, mut b) = pair(200, 1200);
    assert_eq!(a.framing(), Framing::Datagram { mtu: 200 });
    let sizes = sizes();
    for (seq, &len) in sizes.iter().enumerate() {
        let p = packet(seq as u32, len);
        a.send(&p).unwrap();
        expect_packet(&mut b, &p);
        let q = packet(seq as u32 + 10_000, len);
        b.send(&q).unwrap();
        expect_packet(&mut a, &q);
    }
    let (ca, cb) = (a.counters(), b.counters());
    let n = sizes.len() as u64;
    assert_eq!((ca.packets_sent, ca.packets_received, cb.packets_sent, cb.packets_received), (n, n, n, n));
    let bytes: u64 = sizes.iter().map(|&s| s as u64).sum();
    assert_eq!(ca.packet_bytes_sent, bytes);
    assert_eq!(cb.packet_bytes_received, bytes);
    // Fragmentation really happened on a's side only.
    assert!(ca.frames_sent > n, "{ca:?}");
    assert_eq!(cb.frames_sent, n);
    assert_eq!(cb.frames_received, ca.frames_sent);
    assert_eq!(ca.rejected.total() + cb.rejected.total(), 0);
    assert_eq!(ca.unknown_sources + cb.unknown_sources, 0);
}

#[test]
fn burst_of_fragmented_packets_arrives_in_order() {
    // Sent back to back without waiting for the receiver: the socket buffer (about 200 KiB by
    // default, counting per-datagram overhead) holds these 80 datagrams.
    let (mut a, mut b) = pair(200, 200);
    let packets: Vec<Vec<u8>> = (0..20).map(|seq| packet(seq, 300 + seq as usize * 37)).collect();
    for p in &packets {
        a.send(p).unwrap();
    }
    for p in &packets {
        expect_packet(&mut b, p);
    }
}

#[test]
fn garbage_datagrams_are_counted_and_do_not_disturb_the_stream() {
    let (mut a, mut b) = pair(200, 1200);
    let noise = UdpSocket::bind("127.0.0.1:0").unwrap();
    let garbage: Vec<Vec<u8>> = vec![
        vec![],                       // no fragment header at all
        vec![1, 2, 3],                // truncated header
        vec![0, 0, 0, 0, 0, 0, 1, 2], // fragment count 0
        vec![7, 0, 5, 0, 2, 0, 9, 9], // index beyond count
        vec![0xAB; 1500],             // larger than any datagram of ours
    ];
    let mut packets = Vec::new();
    for seq in 0..20u32 {
        let p = packet(seq, 150 + seq as usize * 47);
        a.send(&p).unwrap();
        noise.send_to(&garbage[seq as usize % garbage.len()], b.local_addr()).unwrap();
        packets.push(p);
    }
    // A plausible first fragment from the stranger, with a's next message id: keyed by sender
    // address, it cannot mix into a's messages.
    noise.send_to(&[0, 0, 0, 0, 3, 0, 0xEE, 0xEE], b.local_addr()).unwrap();
    for p in &packets {
        expect_packet(&mut b, p);
    }
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    assert_eq!(b.recv(&mut buf, Duration::from_millis(100)).unwrap(), None, "garbage became a packet");
    let counters = b.counters();
    assert_eq!(counters.packets_received, packets.len() as u64);
    assert_eq!(counters.rejected.malformed, 20, "{counters:?}");
    assert_eq!(counters.unknown_sources, 21);
}

#[test]
fn recv_times_out_with_none() {
    let (_a, mut b) = pair(1200, 1200);
    let mut buf = vec![0u8; MAX_LINK_PACKET_BYTES];
    let start = Instant::now();
    assert_eq!(b.recv(&mut buf, Duration::from_millis(100)).unwrap(), None);
    let waited = start.elapsed();
    assert!(waited >= Duration::from_millis(100) && waited < Duration::from_secs(1), "{waited:?}");
    // A zero timeout polls without blocking.
    let start = Instant::now();
    assert_eq!(b.recv(&mut buf, Duration::ZERO).unwrap(), None);
    assert!(start.elapsed() < Duration::from_millis(50));
}

#[test]
fn zero_timeout_takes_a_packet_already_there() {
    let (mut a, mut b) = pair(1200, 1200);
    a.send(b"ready").unwrap();
    std::thread::sleep(Duration::from_millis(50));
    let mut buf = [0u8; 16];
    assert_eq!(b.recv(&mut buf, Duration::ZERO).unwrap(), Some(5));
}

#[test]
fn sends_to_every_peer() {
    let mut hub = UdpLink::bind("127.0.0.1:0").unwrap();
    let mut spokes: Vec<UdpLink> = (0..3).map(|_| UdpLink::bind("127.0.0.1:0").unwrap()).collect();
    hub.set_peers(spokes.iter().map(UdpLink::local_addr));
    let p = packet(7, 900);
    hub.send(&p).unwrap();
    for spoke in &mut spokes {
        expect_packet(spoke, &p);
        // Not configured with the hub as a peer: accepted, but counted as unknown.
        assert_eq!(spoke.counters().unknown_sources, 1);
    }
    assert_eq!(hub.counters().frames_sent, 3);
}

#[test]
fn refuses_what_it_cannot_carry() {
    let (mut a, mut b) = pair(1200, 1200);
    assert!(matches!(a.send(&vec![0; MAX_LINK_PACKET_BYTES + 1]), Err(LinkError::PacketTooLarge { .. })));
    assert!(matches!(a.set_mtu(1201), Err(LinkError::Config(_))));
    assert!(matches!(a.set_mtu(6), Err(LinkError::Config(_))));
    let mut lonely = UdpLink::bind("127.0.0.1:0").unwrap();
    assert!(matches!(lonely.send(b"hello"), Err(LinkError::NoPeers)));
    // A buffer too small loses the packet with an error naming both sizes.
    a.send(&packet(1, 100)).unwrap();
    let mut small = [0u8; 10];
    let error = b.recv(&mut small, WAIT).unwrap_err();
    assert!(matches!(error, LinkError::BufferTooSmall { needed: 100, available: 10 }), "{error}");
    assert_eq!(b.counters().packets_too_large_for_buffer, 1);
}
