//! The rate cap holds on every framing: with the send queue always full (bulk submap chunks and
//! telemetry) for 60 simulated seconds, the wire bytes an endpoint emits stay within
//! `rate·T/1000 + burst` over every window, the emulated link (serialising at exactly that rate,
//! with a transmit queue of exactly `burst` bytes) never drops a packet for a full queue, and the
//! link is at least 90 % utilised.

// Test helpers too may unwrap and panic: a panic is a failed test with a backtrace.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use hal::emulator::{DuplexEmulator, EmulatorConfig, Side};
use protocol::delivery::{Endpoint, EndpointConfig, SendError};
use protocol::frame::Framing;
use protocol::frame::can::CanKind;
use protocol::message::*;
use protocol::{AnyMessage, MAX_PACKET_BYTES, NodeId, Priority, RobotId, SubmapId};

const ROBOT: NodeId = NodeId(1);
const GROUND: NodeId = NodeId::GROUND;
const DURATION_MS: u64 = 60_000;

fn chunk(seq: u32) -> AnyMessage {
    let data = TryFrom::try_from(&[seq as u8; SUBMAP_CHUNK_BYTES][..]).unwrap();
    AnyMessage::from(SubmapChunk { submap: SubmapId { robot: RobotId(1), index: seq / 100 }, index: seq as u16, data })
}

fn telemetry(stamp_ms: u64) -> AnyMessage {
    AnyMessage::from(Telemetry {
        robot: RobotId(1),
        stamp_ns: stamp_ms * 1_000_000,
        mode: Mode::Autonomous,
        filter: FilterHealth { status: FilterStatus::Nominal, position_std_m: 0.1, yaw_std_rad: 0.01, vo_age_ms: 50 },
        resources: ResourceUsage { cpu_permille: 500, mem_used_kib: 1 << 20, mem_total_kib: 4 << 20 },
        tasks: Default::default(),
        queues: Default::default(),
        links: Default::default(),
        auth_rejections: 0,
        classes: Default::default(),
        sensors: None,
    })
}

struct Report {
    emitted: Vec<(u64, u64)>,
    burst: u64,
    dropped_queue: u64,
    max_queue_bytes: u64,
    delivered_chunks: u64,
    telemetry_replaced: u64,
}

/// The robot streams chunks and telemetry to the ground for `DURATION_MS`, keeping its queues
/// full; the ground acknowledges over the reverse link.
fn saturate(framing: Framing, rate: u64, latency_ms: u64) -> Report {
    let burst = EndpointConfig::min_burst_bytes(framing) + 2_000;
    let link = EmulatorConfig { latency_ms, jitter_ms: 2, queue_bytes: burst, ..EmulatorConfig::ideal(rate, framing) };
    let mut duplex = DuplexEmulator::symmetric(link);
    let mut robot: Box<Endpoint> = Box::new(Endpoint::new(EndpointConfig::new(ROBOT, framing, rate, burst)).unwrap());
    let mut ground: Box<Endpoint> = Box::new(Endpoint::new(EndpointConfig::new(GROUND, framing, rate, burst)).unwrap());
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let mut emitted = Vec::new();
    let mut next_chunk = 0u32;
    let mut delivered_chunks = 0;
    let mut next_telemetry = 0;
    let mut now = 0;
    while now <= DURATION_MS {
        while let Some(packet) = duplex.poll(Side::B, now) {
            ground.handle_packet(now, &packet).unwrap();
        }
        while let Some(packet) = duplex.poll(Side::A, now) {
            robot.handle_packet(now, &packet).unwrap();
        }
        while let Some(d) = ground.poll_deliver() {
            if matches!(d.message, AnyMessage::SubmapChunk(_)) {
                delivered_chunks += 1;
            }
        }
        // Keep the bulk window full, and offer telemetry at 10 Hz (latest wins: a report not
        // sent by the time the next one comes is replaced).
        if now >= next_telemetry {
            robot.send(now, GROUND, &telemetry(now)).unwrap();
            next_telemetry += 100;
        }
        loop {
            match robot.send(now, GROUND, &chunk(next_chunk)) {
                Ok(()) => next_chunk += 1,
                Err(SendError::QueueFull { .. }) => break,
                Err(e) => panic!("{e}"),
            }
        }
        assert!(robot.stats().queued[Priority::Bulk.channel() as usize] > 0, "bulk queue ran dry at {now} ms");
        while let Some(len) = robot.poll_transmit(now, &mut buf) {
            emitted.push((now, framing.wire_bytes(len) as u64));
            duplex.send(Side::A, now, &buf[..len]);
        }
        while let Some(len) = ground.poll_transmit(now, &mut buf) {
            duplex.send(Side::B, now, &buf[..len]);
        }
        let next = [robot.next_transmit_ms(now), ground.next_transmit_ms(now), duplex.next_event_ms()]
            .into_iter()
            .flatten()
            .min()
            .unwrap()
            .min(next_telemetry);
        now = next.max(now + 1);
    }
    assert_eq!(emitted.iter().map(|e| e.1).sum::<u64>(), robot.stats().sent_total().wire_bytes);
    Report {
        emitted,
        burst,
        dropped_queue: duplex.a_to_b.stats().dropped_queue + duplex.b_to_a.stats().dropped_queue,
        max_queue_bytes: duplex.a_to_b.stats().max_queue_bytes,
        delivered_chunks,
        telemetry_replaced: robot.stats().latest_wins_replaced,
    }
}

/// Checks every window `[t_i, t_j]` between two emissions (which covers every window: the worst
/// one starts and ends on an emission) and the total utilisation.
fn check(name: &str, framing: Framing, rate: u64, latency_ms: u64) {
    let report = saturate(framing, rate, latency_ms);
    let emitted = &report.emitted;
    // The worst window ending at emission j starts at the emission i <= j maximising
    // rate·t_i − 1000·(bytes before i): one pass, exact integers, every window checked.
    let mut worst_excess = i128::MIN;
    let mut best_start = i128::MIN;
    let mut before = 0i128; // 1000 × wire bytes emitted before the current emission
    for &(t, bytes) in emitted {
        best_start = best_start.max(i128::from(rate * t) - before);
        before += 1000 * i128::from(bytes);
        let excess = before - i128::from(rate * t) + best_start - 1000 * i128::from(report.burst);
        worst_excess = worst_excess.max(excess);
    }
    assert!(worst_excess <= 0, "{name}: a window exceeds rate·T + burst by {} B", worst_excess / 1000);
    let total: u64 = emitted.iter().filter(|e| e.0 < DURATION_MS).map(|e| e.1).sum();
    let cap = rate * DURATION_MS / 1000;
    let utilisation = total as f64 / cap as f64;
    println!(
        "{name}: {} packets, {total} wire bytes in {DURATION_MS} ms = {:.1} % of {rate} B/s; closest window \
         {} B under rate·T + burst ({} B); link queue peak {} of {} B, {} queue drops; {} chunks delivered, \
         {} telemetry replaced",
        emitted.len(),
        utilisation * 100.0,
        -worst_excess / 1000,
        report.burst,
        report.max_queue_bytes,
        report.burst,
        report.dropped_queue,
        report.delivered_chunks,
        report.telemetry_replaced,
    );
    assert_eq!(report.dropped_queue, 0, "{name}: the link dropped packets for a full queue");
    assert!(report.max_queue_bytes <= report.burst);
    assert!(utilisation >= 0.90, "{name}: utilisation {:.1} %", utilisation * 100.0);
    assert!(utilisation <= 1.0 + report.burst as f64 / cap as f64);
    assert!(report.delivered_chunks > 0);
}

#[test]
fn stream_framing_on_a_57k6_serial_radio() {
    // 57.6 kbit/s at 10 bits a byte.
    check("stream 5760 B/s", Framing::Stream, 5_760, 5);
}

#[test]
fn datagram_framing_on_udp() {
    check("datagram 200 kB/s", Framing::Datagram { mtu: 1200 }, 200_000, 10);
    check("datagram 50 kB/s, mtu 576", Framing::Datagram { mtu: 576 }, 50_000, 10);
}

#[test]
fn can_classic_framing() {
    // 500 kbit/s nominal.
    check("CAN classic 62.5 kB/s", Framing::Can(CanKind::Classic), 62_500, 1);
}

#[test]
fn can_fd_framing() {
    check("CAN FD 250 kB/s", Framing::Can(CanKind::Fd), 250_000, 1);
}
