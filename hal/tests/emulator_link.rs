//! `EmulatedLink`: the emulator behind the `Link` trait, on the wall clock.

// Test helpers too may unwrap and panic: a panic is a failed test with a backtrace.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::time::{Duration, Instant};

use hal::emulator::{EmulatedLink, EmulatorConfig};
use hal::link::{Link, LinkError};
use protocol::frame::Framing;

#[test]
fn packets_arrive_after_the_latency_in_order() {
    let config = EmulatorConfig { latency_ms: 30, ..EmulatorConfig::ideal(1_000_000, Framing::Datagram { mtu: 1200 }) };
    let (mut a, mut b) = EmulatedLink::pair(config.clone(), config);
    assert_eq!(a.framing(), Framing::Datagram { mtu: 1200 });
    let start = Instant::now();
    for i in 0..5u8 {
        a.send(&[i; 100]).unwrap();
    }
    let mut buf = [0u8; hal::link::MAX_LINK_PACKET_BYTES];
    for i in 0..5u8 {
        let len = b.recv(&mut buf, Duration::from_secs(2)).unwrap().unwrap();
        assert_eq!(&buf[..len], &[i; 100][..]);
    }
    assert!(start.elapsed() >= Duration::from_millis(30));
    assert_eq!(b.recv(&mut buf, Duration::from_millis(20)).unwrap(), None);
    // And back.
    b.send(b"pong").unwrap();
    let len = a.recv(&mut buf, Duration::from_secs(2)).unwrap().unwrap();
    assert_eq!(&buf[..len], b"pong");
    assert_eq!(a.counters().packets_sent, 5);
    assert_eq!(b.counters().packets_received, 5);
    assert_eq!(a.tx_stats().delivered_packets, 5);
}

#[test]
fn a_receiver_waiting_in_another_thread_wakes_up() {
    let config = EmulatorConfig::ideal(1_000_000, Framing::Stream);
    let (mut a, mut b) = EmulatedLink::pair(config.clone(), config);
    let receiver = std::thread::spawn(move || {
        let mut buf = [0u8; 64];
        b.recv(&mut buf, Duration::from_secs(5)).map(|len| len.map(|len| buf[..len].to_vec()))
    });
    std::thread::sleep(Duration::from_millis(20));
    a.send(b"hello").unwrap();
    assert_eq!(receiver.join().unwrap().unwrap(), Some(b"hello".to_vec()));
}

#[test]
fn oversized_packets_and_small_buffers_are_errors() {
    let config = EmulatorConfig::ideal(1_000_000, Framing::Stream);
    let (mut a, mut b) = EmulatedLink::pair(config.clone(), config);
    let too_big = vec![0u8; hal::link::MAX_LINK_PACKET_BYTES + 1];
    assert!(matches!(a.send(&too_big), Err(LinkError::PacketTooLarge { .. })));
    a.send(&[1; 10]).unwrap();
    let mut small = [0u8; 4];
    assert!(matches!(b.recv(&mut small, Duration::from_secs(1)), Err(LinkError::BufferTooSmall { needed: 10, .. })));
}
