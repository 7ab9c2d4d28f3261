//! Size budget per message type: the worst-case encoding stays within what the links carry.
#![allow(clippy::expect_used, reason = "builders of test data")]

use postcard::experimental::max_size::MaxSize;
use protocol::codec::HEADER_MAX_BYTES;
use protocol::frame::Framing;
use protocol::frame::datagram::{FRAGMENT_HEADER_BYTES, IP_UDP_HEADER_BYTES, MAX_DATAGRAM_BYTES};
use protocol::message::*;
use protocol::{MAX_PACKET_BYTES, NodeId, RobotId, SubmapId};

/// (type, worst-case body bytes, budget). The budgets are the contract with link planning
/// (`protocol/README.md`); raising one is a deliberate decision, not a test fix.
const BUDGETS: &[(&str, usize, usize)] = &[
    ("Heartbeat", Heartbeat::POSTCARD_MAX_SIZE, 32),
    ("Ack", Ack::POSTCARD_MAX_SIZE, 16),
    ("PoseEstimate", PoseEstimate::POSTCARD_MAX_SIZE, 160),
    ("Telemetry", Telemetry::POSTCARD_MAX_SIZE, 1024),
    ("HazardCells", HazardCells::POSTCARD_MAX_SIZE, 600),
    ("Constraint", Constraint::POSTCARD_MAX_SIZE, 192),
    ("MatchAttempt", MatchAttempt::POSTCARD_MAX_SIZE, 24),
    ("SubmapHeader", SubmapHeader::POSTCARD_MAX_SIZE, 192),
    ("SubmapChunk", SubmapChunk::POSTCARD_MAX_SIZE, SUBMAP_CHUNK_BYTES + 16),
    ("Command", Command::POSTCARD_MAX_SIZE, 64),
    ("CommandAck", CommandAck::POSTCARD_MAX_SIZE, 8),
];

#[test]
fn every_type_is_within_its_budget() {
    assert_eq!(BUDGETS.len(), AnyMessage::KEYS.len(), "a message type has no budget");
    for (name, max, budget) in BUDGETS {
        assert!(max <= budget, "{name}: worst case {max} B exceeds budget {budget} B");
    }
}

#[test]
fn telemetry_v2_is_never_the_largest_body() {
    // Per-class counters must not raise the packet bound that sizes every reliable window.
    const { assert!(Telemetry::POSTCARD_MAX_SIZE <= SubmapChunk::POSTCARD_MAX_SIZE) };
    assert_eq!(AnyMessage::MAX_BODY_SIZE, SubmapChunk::POSTCARD_MAX_SIZE);
}

#[test]
fn every_packet_fits_one_udp_datagram() {
    const { assert!(MAX_PACKET_BYTES + FRAGMENT_HEADER_BYTES <= MAX_DATAGRAM_BYTES) };
    const { assert!(HEADER_MAX_BYTES <= 12) };
}

/// A message with every field at its largest encoding, to check the computed bound is a bound.
fn largest_chunk() -> SubmapChunk {
    let mut data = heapless::Vec::new();
    data.extend_from_slice(&[0xFF; SUBMAP_CHUNK_BYTES]).expect("exactly the capacity");
    SubmapChunk { submap: SubmapId { robot: RobotId(255), index: u32::MAX }, index: u16::MAX, data }
}

fn largest_telemetry() -> Telemetry {
    let label = || -> Label { heapless::String::from("ABCDEFGHIJKL") };
    let mut telemetry = Telemetry {
        robot: RobotId(255),
        stamp_ns: u64::MAX,
        mode: Mode::Safe,
        filter: FilterHealth {
            status: FilterStatus::Diverged,
            position_std_m: 1.0,
            yaw_std_rad: 1.0,
            vo_age_ms: u32::MAX,
        },
        resources: ResourceUsage { cpu_permille: u16::MAX, mem_used_kib: u32::MAX, mem_total_kib: u32::MAX },
        tasks: heapless::Vec::new(),
        queues: heapless::Vec::new(),
        links: heapless::Vec::new(),
        auth_rejections: u32::MAX,
        classes: heapless::Vec::new(),
        sensors: Some(protocol::message::SensorAvailability { imu: true, wheels: true, head: true }),
    };
    while telemetry
        .tasks
        .push(TaskStats {
            task: label(),
            period_us: u32::MAX,
            releases: u32::MAX,
            deadline_overruns: u32::MAX,
            jitter_p99_us: u32::MAX,
            jitter_max_us: u32::MAX,
        })
        .is_ok()
    {}
    while telemetry
        .queues
        .push(QueueStats { queue: label(), depth: u16::MAX, capacity: u16::MAX, dropped: u32::MAX })
        .is_ok()
    {}
    while telemetry
        .links
        .push(LinkStats {
            link: label(),
            tx_bytes: u64::MAX,
            rx_bytes: u64::MAX,
            tx_rate_bps: u32::MAX,
            rx_rate_bps: u32::MAX,
            retransmissions: u32::MAX,
            rejected: u32::MAX,
            loss_permille: u16::MAX,
            rtt_ms: u32::MAX,
            outages: u32::MAX,
        })
        .is_ok()
    {}
    while telemetry.classes.push(ClassBytes { message_key: u8::MAX, tx_bytes: u64::MAX, tx_packets: u32::MAX }).is_ok()
    {
    }
    telemetry
}

fn largest_hazard_cells() -> HazardCells {
    let mut cells = heapless::Vec::new();
    while cells.push([i8::MIN, i8::MAX]).is_ok() {}
    HazardCells {
        robot: RobotId(255),
        stamp_ns: u64::MAX,
        submap: SubmapId { robot: RobotId(255), index: u32::MAX },
        t_submap_body: protocol::Pose3 { translation_m: [f64::MAX; 3], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] },
        cell_size_m: 0.1,
        omitted: u16::MAX,
        cells,
    }
}

#[test]
fn hazard_cells_are_a_small_share_of_a_serial_radio() {
    // Sent every 2 s on a ground link that may be a shared 57.6 kbit/s serial radio (7200 B/s):
    // the largest one, framed, must stay a small share of it, and fit one UDP datagram.
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let message = AnyMessage::from(largest_hazard_cells());
    let len = protocol::encode(&message, NodeId(200), NodeId::GROUND, u32::MAX, &mut buf).unwrap();
    assert!(len <= HEADER_MAX_BYTES + HazardCells::POSTCARD_MAX_SIZE);
    let serial = Framing::Stream.wire_bytes(len);
    assert!(serial <= 620, "{serial} B on a serial radio");
    let one_datagram = len + FRAGMENT_HEADER_BYTES + IP_UDP_HEADER_BYTES;
    assert_eq!(Framing::Datagram { mtu: MAX_DATAGRAM_BYTES as u16 }.wire_bytes(len), one_datagram);
    // A hazard packet every 2 s is under 5 % of the serial radio.
    assert!(serial as f64 / 2.0 / 7200.0 < 0.05);
}

#[test]
fn the_largest_messages_reach_but_do_not_exceed_their_bound() {
    let mut buf = [0u8; 2 * MAX_PACKET_BYTES];
    let hazards = postcard::to_slice(&largest_hazard_cells(), &mut buf).unwrap().len();
    assert_eq!(hazards, HazardCells::POSTCARD_MAX_SIZE);
    let chunk = postcard::to_slice(&largest_chunk(), &mut buf).unwrap().len();
    assert_eq!(chunk, SubmapChunk::POSTCARD_MAX_SIZE);
    let telemetry = postcard::to_slice(&largest_telemetry(), &mut buf).unwrap().len();
    assert_eq!(telemetry, Telemetry::POSTCARD_MAX_SIZE);
    let packet =
        protocol::encode(&AnyMessage::from(largest_chunk()), NodeId(200), NodeId::BROADCAST, u32::MAX, &mut buf)
            .unwrap();
    assert!(packet <= MAX_PACKET_BYTES);
}
