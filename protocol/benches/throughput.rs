//! Throughput of the whole protocol path: encode → frame → unframe → decode (→ verify MAC), per
//! framing, against bare postcard serialization of the same message bodies in the same run.
//!
//! `cargo bench -p protocol --bench throughput` measures; under `cargo test` (no `--bench`
//! argument) it runs one short round as a smoke test and checks every message comes back intact.

use std::hint::black_box;
use std::time::{Duration, Instant};

use protocol::frame::can::{self, CanKind, CanReassembler};
use protocol::frame::datagram::{MAX_DATAGRAM_BYTES, Reassembler, Segmenter};
use protocol::frame::stream::{self, StreamDecoder};
use protocol::message::*;
use protocol::{AuthKey, Cov6, MAX_PACKET_BYTES, NodeId, NodeRef, Pose3, RobotId, SubmapId};

/// The traffic of a rover during mapping, by message count per second of driving: pose
/// estimates at 10 Hz, telemetry at 1 Hz, a constraint and match records now and then, and a
/// 140 KB submap every ~25 s (≈ 6 chunks/s), plus commands and acks.
fn workload() -> Vec<AnyMessage> {
    let pose = Pose3 { translation_m: [12.5, -3.25, 0.4], rotation_wxyz: [0.98, 0.01, -0.02, 0.198] };
    let cov = Cov6::from_std_devs([0.05, 0.05, 0.02, 0.01, 0.01, 0.03]);
    let submap = SubmapId { robot: RobotId(1), index: 42 };
    let mut out = Vec::new();
    for i in 0..10u64 {
        out.push(AnyMessage::from(PoseEstimate {
            robot: RobotId(1),
            stamp_ns: 1_000_000_000 + i * 100_000_000,
            submap,
            t_submap_body: pose,
            covariance: cov,
        }));
    }
    let label = |s: &str| -> Label { heapless::String::from(s) };
    let mut telemetry = Telemetry {
        robot: RobotId(1),
        stamp_ns: 5,
        mode: Mode::Autonomous,
        filter: FilterHealth { status: FilterStatus::Nominal, position_std_m: 0.08, yaw_std_rad: 0.01, vo_age_ms: 80 },
        resources: ResourceUsage { cpu_permille: 640, mem_used_kib: 1_200_000, mem_total_kib: 4_000_000 },
        tasks: heapless::Vec::new(),
        queues: heapless::Vec::new(),
        links: heapless::Vec::new(),
        auth_rejections: 0,
        classes: heapless::Vec::new(),
        sensors: None,
    };
    for task in ["vision", "filter", "mapper", "comms"] {
        let _ = telemetry.tasks.push(TaskStats {
            task: label(task),
            period_us: 100_000,
            releases: 36_000,
            deadline_overruns: 3,
            jitter_p99_us: 450,
            jitter_max_us: 2_100,
        });
    }
    let _ = telemetry.queues.push(QueueStats { queue: label("imu"), depth: 3, capacity: 64, dropped: 0 });
    let _ = telemetry.links.push(LinkStats {
        link: label("radio"),
        tx_bytes: 9_000_000,
        rx_bytes: 2_000_000,
        tx_rate_bps: 56_000,
        rx_rate_bps: 9_000,
        retransmissions: 120,
        rejected: 2,
        loss_permille: 35,
        rtt_ms: 4_100,
        outages: 1,
    });
    out.push(telemetry.into());
    out.push(AnyMessage::from(Constraint {
        id: ConstraintId { robot: RobotId(1), seq: 7 },
        kind: ConstraintKind::SubmapMatch,
        stamp_ns: 77,
        from: NodeRef::SubmapOrigin(submap),
        to: NodeRef::SubmapOrigin(SubmapId { robot: RobotId(2), index: 9 }),
        t_from_to: pose,
        covariance: cov,
    }));
    out.push(AnyMessage::from(MatchAttempt {
        first: submap,
        second: SubmapId { robot: RobotId(2), index: 9 },
        by: RobotId(1),
        outcome: MatchOutcome::Rejected,
    }));
    for index in 0..6u16 {
        let mut data = heapless::Vec::new();
        // Compressed submap bytes look random.
        let mut x = 0x1234_5678u32.wrapping_add(u32::from(index));
        while data
            .push({
                x ^= x << 13;
                x ^= x >> 17;
                x ^= x << 5;
                x as u8
            })
            .is_ok()
        {}
        out.push(AnyMessage::from(SubmapChunk { submap, index, data }));
    }
    out.push(AnyMessage::from(Command { target: RobotId(1), id: 3, kind: CommandKind::SetMode(Mode::Waypoint) }));
    out.push(AnyMessage::from(CommandAck { robot: RobotId(1), command_id: 3, outcome: CommandOutcome::Executed }));
    out.push(AnyMessage::from(Ack { channel: 5, next_expected: 1234, received_mask: 0xF0 }));
    out
}

fn key() -> AuthKey {
    match AuthKey::from_bytes(b"benchmark key, 32 bytes of noise") {
        Ok(key) => key,
        Err(e) => panic!("{e}"),
    }
}

fn encode_packet(message: &AnyMessage, seq: u32, key: &AuthKey, out: &mut [u8]) -> usize {
    let result = if message.requires_authentication() {
        protocol::encode_authenticated(message, NodeId::GROUND, NodeId(1), seq, u64::from(seq), key, out)
    } else {
        protocol::encode(message, NodeId(1), NodeId::BROADCAST, seq, out)
    };
    match result {
        Ok(len) => len,
        Err(e) => panic!("encode: {e}"),
    }
}

fn decode_packet(bytes: &[u8], key: &AuthKey) -> AnyMessage {
    let packet = match protocol::decode(bytes) {
        Ok(packet) => packet,
        Err(e) => panic!("decode: {e}"),
    };
    if packet.auth.is_some() && key.verify(bytes).is_err() {
        panic!("MAC check failed on an intact packet");
    }
    packet.message
}

/// One pass over the workload through `path`; returns the decoded messages.
type Path = fn(&[AnyMessage], &AuthKey) -> Vec<AnyMessage>;

fn bare_postcard(messages: &[AnyMessage], _key: &AuthKey) -> Vec<AnyMessage> {
    // The floor: serialize and deserialize the message bodies, no header, framing or MAC.
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let mut out = Vec::with_capacity(messages.len());
    for message in messages {
        macro_rules! roundtrip {
            ($($ty:ident),*) => {
                match message {
                    $( AnyMessage::$ty(m) => {
                        let len = postcard::to_slice(m, &mut buf).map(|s| s.len()).unwrap_or(0);
                        AnyMessage::from(postcard::from_bytes::<$ty>(&buf[..len]).unwrap_or_else(|e| panic!("{e}")))
                    } )*
                }
            };
        }
        out.push(roundtrip!(
            Heartbeat,
            Ack,
            PoseEstimate,
            Telemetry,
            HazardCells,
            Constraint,
            MatchAttempt,
            SubmapHeader,
            SubmapChunk,
            Command,
            CommandAck
        ));
    }
    out
}

fn packets_only(messages: &[AnyMessage], key: &AuthKey) -> Vec<AnyMessage> {
    let mut buf = [0u8; MAX_PACKET_BYTES];
    messages
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let len = encode_packet(m, i as u32, key, &mut buf);
            decode_packet(&buf[..len], key)
        })
        .collect()
}

fn serial_cobs(messages: &[AnyMessage], key: &AuthKey) -> Vec<AnyMessage> {
    let mut packet = [0u8; MAX_PACKET_BYTES];
    let mut wire = Vec::with_capacity(messages.len() * 300);
    let mut frame = vec![0u8; stream::max_frame_len(MAX_PACKET_BYTES)];
    for (i, m) in messages.iter().enumerate() {
        let len = encode_packet(m, i as u32, key, &mut packet);
        let n = stream::encode_frame(&packet[..len], &mut frame).unwrap_or_else(|e| panic!("{e}"));
        wire.extend_from_slice(&frame[..n]);
    }
    let mut decoder = StreamDecoder::<{ MAX_PACKET_BYTES + 8 }>::new();
    let mut out = Vec::with_capacity(messages.len());
    // A serial port hands over bytes in driver-sized reads.
    for read in wire.chunks(256) {
        decoder.feed(read, |result| match result {
            Ok(bytes) => out.push(decode_packet(bytes, key)),
            Err(e) => panic!("frame: {e}"),
        });
    }
    out
}

fn udp_datagrams(messages: &[AnyMessage], key: &AuthKey) -> Vec<AnyMessage> {
    let mut packet = [0u8; MAX_PACKET_BYTES];
    let mut segmenter = Segmenter::new(MAX_DATAGRAM_BYTES).unwrap_or_else(|e| panic!("{e}"));
    let mut reassembler = Reassembler::<4, { 2 * MAX_PACKET_BYTES }>::new(1_000);
    let mut out = Vec::with_capacity(messages.len());
    for (i, m) in messages.iter().enumerate() {
        let len = encode_packet(m, i as u32, key, &mut packet);
        let mut datagrams: Vec<Vec<u8>> = Vec::new();
        segmenter.segment(&packet[..len], |d| datagrams.push(d.to_vec())).unwrap_or_else(|e| panic!("{e}"));
        for d in &datagrams {
            if let Some(bytes) = reassembler.push(0, 1, d).unwrap_or_else(|e| panic!("{e}")) {
                out.push(decode_packet(bytes, key));
            }
        }
    }
    out
}

fn can_bus(kind: CanKind, messages: &[AnyMessage], key: &AuthKey) -> Vec<AnyMessage> {
    let mut packet = [0u8; MAX_PACKET_BYTES];
    let mut reassembler = CanReassembler::<4, { 2 * MAX_PACKET_BYTES }>::new(kind, 1_000);
    let mut frames = Vec::with_capacity(200);
    let mut out = Vec::with_capacity(messages.len());
    for (i, m) in messages.iter().enumerate() {
        let len = encode_packet(m, i as u32, key, &mut packet);
        let id = can::can_id(m.priority(), NodeId(1), NodeId::BROADCAST);
        frames.clear();
        can::segment(kind, id, &packet[..len], |f| frames.push(*f)).unwrap_or_else(|e| panic!("{e}"));
        for f in &frames {
            if let Some(bytes) = reassembler.push(0, f).unwrap_or_else(|e| panic!("{e}")) {
                out.push(decode_packet(bytes, key));
            }
        }
    }
    out
}

fn can_classic(messages: &[AnyMessage], key: &AuthKey) -> Vec<AnyMessage> {
    can_bus(CanKind::Classic, messages, key)
}

fn can_fd(messages: &[AnyMessage], key: &AuthKey) -> Vec<AnyMessage> {
    can_bus(CanKind::Fd, messages, key)
}

/// Median time per pass over `rounds` timed batches of passes.
fn time_per_pass(path: Path, messages: &[AnyMessage], key: &AuthKey, budget: Duration) -> Duration {
    // Calibrate the batch so that each lasts ~budget/10.
    let start = Instant::now();
    black_box(path(black_box(messages), key));
    let once = start.elapsed().max(Duration::from_nanos(1));
    let per_batch = ((budget.as_secs_f64() / 10.0) / once.as_secs_f64()).clamp(1.0, 1e7) as u32;
    let mut samples: Vec<Duration> = (0..10)
        .map(|_| {
            let start = Instant::now();
            for _ in 0..per_batch {
                black_box(path(black_box(messages), key));
            }
            start.elapsed() / per_batch
        })
        .collect();
    samples.sort();
    samples[samples.len() / 2]
}

fn main() {
    let measuring = std::env::args().any(|a| a == "--bench");
    let messages = workload();
    let key = key();
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let packets: Vec<Vec<u8>> = messages
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let n = encode_packet(m, i as u32, &key, &mut buf);
            buf[..n].to_vec()
        })
        .collect();
    let packet_bytes: usize = packets.iter().map(Vec::len).sum();
    // (name, path, the link it feeds: byte rate and framing)
    type Row = (&'static str, Path, Option<(f64, protocol::frame::Framing)>);
    let paths: [Row; 6] = [
        ("postcard bodies only (reference)", bare_postcard, None),
        ("packet: header + body + MAC", packets_only, None),
        ("serial: COBS + CRC-32", serial_cobs, Some((115_200.0 / 10.0, protocol::frame::Framing::Stream))),
        (
            "UDP: 1200-byte datagrams",
            udp_datagrams,
            Some((100e6 / 8.0, protocol::frame::Framing::Datagram { mtu: MAX_DATAGRAM_BYTES as u16 })),
        ),
        ("CAN classic (8 B frames)", can_classic, Some((1e6 / 8.0, protocol::frame::Framing::Can(CanKind::Classic)))),
        ("CAN FD (64 B frames)", can_fd, Some((5e6 / 8.0, protocol::frame::Framing::Can(CanKind::Fd)))),
    ];

    // Every path must deliver the workload intact before anything is timed.
    for (name, path, _) in &paths {
        let decoded = path(&messages, &key);
        assert_eq!(decoded, messages, "{name} changed the messages");
    }
    if !measuring {
        println!("throughput smoke test: {} messages through {} paths intact", messages.len(), paths.len());
        return;
    }

    let budget = Duration::from_millis(1_500);
    println!(
        "workload: {} messages, {} packet bytes per pass (mix of a mapping rover's traffic)",
        messages.len(),
        packet_bytes
    );
    println!(
        "{:<34} {:>10} {:>12} {:>12} {:>14} {:>16}",
        "path", "µs/pass", "MB/s", "msgs/s", "vs postcard", "vs line rate"
    );
    let mut reference = None;
    for (name, path, line) in &paths {
        let t = time_per_pass(*path, &messages, &key, budget);
        let secs = t.as_secs_f64();
        let mbps = packet_bytes as f64 / secs / 1e6;
        let msgs = messages.len() as f64 / secs;
        let reference_secs = *reference.get_or_insert(secs);
        let line_ratio = match line {
            Some((bytes_per_s, framing)) => {
                let wire: usize = packets.iter().map(|p| framing.wire_bytes(p.len())).sum();
                // How many such links one core could feed: wire bytes per second we produce
                // over the link's byte rate.
                format!("{:>10.0}x", wire as f64 / secs / bytes_per_s)
            }
            None => "-".to_string(),
        };
        println!(
            "{:<34} {:>10.2} {:>12.1} {:>12.0} {:>13.2}x {:>16}",
            name,
            secs * 1e6,
            mbps,
            msgs,
            reference_secs / secs,
            line_ratio
        );
    }
    println!("line rates: serial 115200 baud, UDP 100 Mbit/s, CAN 1 Mbit/s, CAN FD 5 Mbit/s data phase");
}
