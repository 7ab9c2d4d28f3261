//! The comms node: team traffic over an emulated 57.6 kbit/s radio with 1 s latency, loss and
//! an outage (simulated time); over real UDP sockets through `LinkDriver` (wall clock); the
//! ground feed and authenticated commands with a UDP socket as the ground station; totality.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use hal::emulator::{DuplexEmulator, EmulatorConfig};
use hal::link::Link;
use hal::udp::UdpLink;
use msgs::{FilterStateMsg, Pose, ProcessKind, TaskStatsMsg, TeamHeader};
use onboard::nodes::comms::{CommsConfig, CommsNode, LinkConfig, LinkDriver, LinkId, step_duplex};
use onboard::nodes::{Message, Node, NodeError, Outbox, Topic};
use proptest::prelude::*;
use protocol::delivery::{Endpoint, EndpointConfig, RtoConfig};
use protocol::frame::Framing;
use protocol::message::*;
use protocol::{AnyMessage, AuthKey, Cov6, MAX_PACKET_BYTES, NodeId, NodeRef, Pose3, RobotId, SubmapId};

const TEAM: LinkId = LinkId(0);
const GROUND_LINK: LinkId = LinkId(9);

/// Collects what a node publishes for the mapper.
#[derive(Debug, Default)]
struct Collect {
    to_mapper: Vec<(TeamHeader, Vec<u8>)>,
}

impl Outbox for Collect {
    fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError> {
        if let Message::ToMapper(header, bytes) = message {
            self.to_mapper.push((*header, bytes.to_vec()));
        }
        Ok(())
    }
}

/// What the mapper would send: one encoded packet in a `ToComms` message.
fn to_comms(node: &mut CommsNode, out: &mut Collect, now_ns: u64, destination: u32, message: &AnyMessage) {
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let to = if destination == TeamHeader::BROADCAST { NodeId::BROADCAST } else { NodeId(destination as u8) };
    let len = protocol::encode(message, NodeId::from(node.robot()), to, 0, &mut buf).unwrap();
    let header = TeamHeader { stamp_ns: now_ns, robot_id: destination, message_key: u32::from(message.key().0) };
    node.on_message(Message::ToComms(&header, &buf[..len]), out).unwrap();
}

fn submap_id(robot: u8) -> SubmapId {
    SubmapId { robot: RobotId(robot), index: 4 }
}

fn constraint(robot: u8, seq: u32) -> AnyMessage {
    AnyMessage::from(Constraint {
        id: ConstraintId { robot: RobotId(robot), seq },
        kind: ConstraintKind::RobotDetection,
        stamp_ns: u64::from(seq),
        from: NodeRef::SubmapOrigin(submap_id(robot)),
        to: NodeRef::RobotPose { robot: RobotId(3 - robot), stamp_ns: u64::from(seq) },
        t_from_to: Pose3::IDENTITY,
        covariance: Cov6::from_std_devs([0.05; 6]),
    })
}

fn match_attempt(robot: u8, n: u32) -> AnyMessage {
    AnyMessage::from(MatchAttempt {
        first: SubmapId { robot: RobotId(robot), index: n },
        second: SubmapId { robot: RobotId(3 - robot), index: n },
        by: RobotId(robot),
        outcome: MatchOutcome::Rejected,
    })
}

/// A submap of `bytes` payload bytes: its header and chunks.
fn submap(robot: u8, bytes: usize) -> Vec<AnyMessage> {
    let payload: Vec<u8> = (0..bytes).map(|i| (i * 7 + 3) as u8).collect();
    let chunks: Vec<&[u8]> = payload.chunks(SUBMAP_CHUNK_BYTES).collect();
    let mut messages = vec![AnyMessage::from(SubmapHeader {
        submap: submap_id(robot),
        started_stamp_ns: 0,
        finished_stamp_ns: 1,
        switch: None,
        encoding: SubmapEncoding(1),
        payload_bytes: bytes as u32,
        chunk_count: chunks.len() as u16,
        payload_crc32: 0,
    })];
    for (index, chunk) in chunks.iter().enumerate() {
        messages.push(AnyMessage::from(SubmapChunk {
            submap: submap_id(robot),
            index: index as u16,
            data: TryFrom::try_from(*chunk).unwrap(),
        }));
    }
    messages
}

fn pose(robot: u8, stamp_ns: u64) -> AnyMessage {
    AnyMessage::from(PoseEstimate {
        robot: RobotId(robot),
        stamp_ns,
        submap: submap_id(robot),
        t_submap_body: Pose3 { translation_m: [stamp_ns as f64 * 1e-9, 0.0, 0.0], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] },
        covariance: Cov6::from_std_devs([0.1; 6]),
    })
}

/// Identity of a delivered message, to check exactly-once delivery.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Item {
    Header,
    Chunk(u16),
    Constraint(u32),
    Attempt(u32),
    Pose(u64),
}

fn item(message: &AnyMessage) -> Item {
    match message {
        AnyMessage::SubmapHeader(_) => Item::Header,
        AnyMessage::SubmapChunk(c) => Item::Chunk(c.index),
        AnyMessage::Constraint(c) => Item::Constraint(c.id.seq),
        AnyMessage::MatchAttempt(m) => Item::Attempt(m.first.index),
        AnyMessage::PoseEstimate(p) => Item::Pose(p.stamp_ns),
        other => panic!("unexpected message for the mapper: {other:?}"),
    }
}

/// Decodes a node's ToMapper output: (receive time ns, sender, item, message).
fn received(out: &Collect) -> Vec<(u64, u32, Item, AnyMessage)> {
    out.to_mapper
        .iter()
        .map(|(header, bytes)| {
            let packet = protocol::decode(bytes).expect("ToMapper payload is a valid packet");
            assert_eq!(header.message_key, u32::from(packet.message.key().0));
            (header.stamp_ns, header.robot_id, item(&packet.message), packet.message)
        })
        .collect()
}

fn team_node(robot: u8, peer: u8, framing: Framing, rate: u64, rto: RtoConfig) -> CommsNode {
    let link = LinkConfig::team(TEAM, "radio", framing, rate, vec![RobotId(peer)]).with_rto(rto);
    let mut config = CommsConfig::new(RobotId(robot), vec![link]);
    config.boot_id = u32::from(robot) * 1000;
    CommsNode::new(config).unwrap()
}

// ------------------------------------------------------------------------------ emulated radio

struct RadioRun {
    /// Robot 2's ToMapper output: (receive ns, sender, item, message).
    at_2: Vec<(u64, u32, Item, AnyMessage)>,
    at_1: Vec<(u64, u32, Item, AnyMessage)>,
    /// When robot 1 handed each pose to its comms node.
    pose_sent_ns: BTreeMap<u64, u64>,
    finished_ns: u64,
    node_1: CommsNode,
    node_2: CommsNode,
    wire_bytes_1: u64,
}

const RELIABLE_FROM_1: usize = 1 + 20 + 10 + 5;
const RELIABLE_FROM_2: usize = 4;

/// Robot 1 sends 50 mapper messages (a 20 kB submap as a header and 20 chunks, 10 constraints,
/// 5 match records, 14 poses), robot 2 sends 4 constraints back, over a 57.6 kbit/s serial radio
/// with 1 s latency and 5 % loss each way, optionally with an outage.
fn radio_run(outage_ms: Option<(u64, u64)>) -> RadioRun {
    let mut radio =
        EmulatorConfig { latency_ms: 1_000, loss: 0.05, ..EmulatorConfig::serial_radio_57k6() }.with_seed(7);
    if let Some((start, end)) = outage_ms {
        radio = radio.with_outage(start, end);
    }
    // Below the radio's 5760 B/s so its 4 KiB buffer never overflows.
    let rate = 5_000;
    let rto = RtoConfig { initial_ms: 3_000, ..RtoConfig::default() };
    let mut duplex = DuplexEmulator::symmetric(radio);
    let mut node_1 = team_node(1, 2, Framing::Stream, rate, rto);
    let mut node_2 = team_node(2, 1, Framing::Stream, rate, rto);
    let (mut out_1, mut out_2) = (Collect::default(), Collect::default());

    // Robot 1's offered traffic: (time ms, destination, message).
    let mut plan: Vec<(u64, u32, AnyMessage)> = Vec::new();
    for message in submap(1, 20 * SUBMAP_CHUNK_BYTES) {
        plan.push((500, 2, message));
    }
    for seq in 0..10 {
        plan.push((1_000 + 700 * u64::from(seq), TeamHeader::BROADCAST, constraint(1, seq)));
    }
    for n in 0..5 {
        plan.push((1_200 + 900 * u64::from(n), 2, match_attempt(1, n)));
    }
    let mut pose_sent_ns = BTreeMap::new();
    for k in 0..14u64 {
        let at_ms = 1_000 + 500 * k;
        pose_sent_ns.insert(at_ms * 1_000_000, at_ms * 1_000_000);
        plan.push((at_ms, TeamHeader::BROADCAST, pose(1, at_ms * 1_000_000)));
    }
    assert_eq!(plan.len(), 50);
    plan.sort_by_key(|(at, _, _)| *at);
    let mut next = 0;

    let mut finished_ns = None;
    for now_ms in 0..180_000u64 {
        let now_ns = now_ms * 1_000_000;
        while let Some((at, destination, message)) = plan.get(next)
            && *at <= now_ms
        {
            to_comms(&mut node_1, &mut out_1, now_ns, *destination, message);
            next += 1;
        }
        if now_ms % 1_500 == 0 && now_ms / 1_500 < RELIABLE_FROM_2 as u64 {
            to_comms(&mut node_2, &mut out_2, now_ns, 1, &constraint(2, (now_ms / 1_500) as u32));
        }
        // The comms task runs at 10 Hz; packets move every millisecond.
        if now_ms % 100 == 0 {
            node_1.on_tick(now_ns, &mut out_1).unwrap();
            node_2.on_tick(now_ns, &mut out_2).unwrap();
        }
        step_duplex(&mut duplex, now_ns, (&mut node_1, TEAM), (&mut node_2, TEAM));
        let reliable_at = |out: &Collect| received(out).iter().filter(|r| !matches!(r.2, Item::Pose(_))).count();
        if now_ms % 100 == 0
            && next == plan.len()
            && reliable_at(&out_2) == RELIABLE_FROM_1
            && reliable_at(&out_1) == RELIABLE_FROM_2
        {
            finished_ns = Some(now_ns);
            break;
        }
    }
    let finished_ns = finished_ns
        .unwrap_or_else(|| panic!("not all reliable messages arrived: {} at robot 2", received(&out_2).len()));
    RadioRun {
        at_2: received(&out_2),
        at_1: received(&out_1),
        pose_sent_ns,
        finished_ns,
        wire_bytes_1: duplex.a_to_b.stats().offered_wire_bytes,
        node_1,
        node_2,
    }
}

/// Every reliable message exactly once, chunks in order after their header, sender ids right.
fn assert_reliable_exactly_once(run: &RadioRun) {
    let reliable: Vec<Item> = run.at_2.iter().map(|r| r.2).filter(|i| !matches!(i, Item::Pose(_))).collect();
    let mut sorted = reliable.clone();
    sorted.sort();
    sorted.dedup();
    assert_eq!(sorted.len(), reliable.len(), "a reliable message arrived twice");
    let mut expected: Vec<Item> = vec![Item::Header];
    expected.extend((0..20).map(Item::Chunk));
    expected.extend((0..10).map(Item::Constraint));
    expected.extend((0..5).map(Item::Attempt));
    expected.sort();
    assert_eq!(sorted, expected);
    let bulk: Vec<Item> = reliable.iter().copied().filter(|i| matches!(i, Item::Header | Item::Chunk(_))).collect();
    let mut in_order = vec![Item::Header];
    in_order.extend((0..20).map(Item::Chunk));
    assert_eq!(bulk, in_order, "submap header and chunks out of order");
    assert!(run.at_2.iter().all(|r| r.1 == 1), "sender id of robot 1's messages");
    // The payload arrives intact.
    let payload: Vec<u8> = run
        .at_2
        .iter()
        .filter_map(|r| match &r.3 {
            AnyMessage::SubmapChunk(c) => Some(c.data.to_vec()),
            _ => None,
        })
        .flatten()
        .collect();
    let expected_payload: Vec<u8> = (0..20 * SUBMAP_CHUNK_BYTES).map(|i| (i * 7 + 3) as u8).collect();
    assert_eq!(payload, expected_payload);
    let back: Vec<Item> = run.at_1.iter().map(|r| r.2).collect();
    assert_eq!(back, (0..RELIABLE_FROM_2 as u32).map(Item::Constraint).collect::<Vec<_>>());
    assert!(run.at_1.iter().all(|r| r.1 == 2));
}

#[test]
fn team_traffic_over_a_lossy_slow_radio_arrives_exactly_once_and_poses_do_not_wait() {
    let run = radio_run(None);
    assert_reliable_exactly_once(&run);

    // Poses: latest-wins, so a lost one stays lost, but none arrives twice, most arrive, and
    // each within the 1 s latency plus a few packet times: never behind the submap's 20 chunks
    // (20 × ~190 ms of serialisation on this radio).
    let poses: Vec<(u64, u64)> = run
        .at_2
        .iter()
        .filter_map(|r| match r.2 {
            Item::Pose(stamp) => Some((stamp, r.0)),
            _ => None,
        })
        .collect();
    let mut stamps: Vec<u64> = poses.iter().map(|p| p.0).collect();
    stamps.dedup();
    assert_eq!(stamps.len(), poses.len(), "a pose arrived twice");
    assert!(poses.len() >= 11, "only {} of 14 poses arrived", poses.len());
    let worst_latency_ms = poses.iter().map(|&(stamp, at)| (at - run.pose_sent_ns[&stamp]) / 1_000_000).max().unwrap();
    assert!(worst_latency_ms < 1_700, "a pose took {worst_latency_ms} ms");
    let chunk_times: Vec<u64> = run.at_2.iter().filter(|r| matches!(r.2, Item::Chunk(_))).map(|r| r.0).collect();
    let (first_chunk, last_chunk) = (chunk_times[0], *chunk_times.last().unwrap());
    assert!(last_chunk - first_chunk > 3_000_000_000, "the submap transfer should take seconds");
    let overtaking = poses.iter().filter(|&&(_, at)| at > first_chunk && at < last_chunk).count();
    assert!(overtaking >= 4, "only {overtaking} poses arrived during the submap transfer");

    // Bytes per class, both ends, and the link's rate cap.
    let sent = run.node_1.stats();
    let chunks = sent.sent_by_class["SubmapChunk"];
    assert!(chunks.packets >= 20 && chunks.packet_bytes >= 20 * SUBMAP_CHUNK_BYTES as u64, "{chunks:?}");
    assert!(chunks.wire_bytes > chunks.packet_bytes, "stream framing costs bytes");
    assert!(sent.sent_by_class["Constraint"].packets >= 10);
    assert!(sent.sent_by_class["MatchAttempt"].packets >= 5);
    assert!(sent.sent_by_class["PoseEstimate"].packets >= poses.len() as u64);
    assert!(sent.sent_by_class["Heartbeat"].packets >= 1);
    assert!(sent.sent_by_class["Ack"].packets >= 1, "robot 1 acknowledges robot 2's constraints");
    assert!(sent.retransmissions > 0, "5 % loss must cost retransmissions");
    assert_eq!(sent.retransmissions, sent.sent_by_class.values().map(|c| c.retransmissions).sum::<u64>());
    let wire_total: u64 = sent.sent_by_class.values().map(|c| c.wire_bytes).sum();
    assert_eq!(wire_total, run.wire_bytes_1, "counted wire bytes = what the radio carried");
    let seconds = run.finished_ns as f64 / 1e9;
    assert!(wire_total as f64 <= 5_000.0 * seconds + 2.0 * 1_100.0, "rate cap exceeded");
    let got = run.node_2.stats();
    assert!(got.received_by_class["SubmapChunk"].packets >= 20);
    assert_eq!(got.delivered_to_mapper, run.at_2.len() as u64);
    assert_eq!(got.decode_rejections, 0);
    println!(
        "radio: finished at {seconds:.1} s, {} retransmissions, chunk bytes {} (wire {}), worst pose latency {worst_latency_ms} ms",
        sent.retransmissions, chunks.packet_bytes, chunks.wire_bytes
    );
}

#[test]
fn a_ten_second_outage_delays_but_loses_nothing_reliable() {
    let clear = radio_run(None);
    let outage = radio_run(Some((2_000, 12_000)));
    assert_reliable_exactly_once(&outage);
    let last_reliable = outage.at_2.iter().filter(|r| !matches!(r.2, Item::Pose(_))).map(|r| r.0).max().unwrap();
    assert!(last_reliable >= 12_000_000_000, "the submap cannot finish inside the outage");
    assert!(outage.finished_ns > clear.finished_ns + 5_000_000_000);
    let stats = outage.node_1.stats();
    assert!(stats.retransmissions > clear.node_1.stats().retransmissions);
    assert_eq!(stats.drops.backlog_full, 0);
    println!(
        "outage: finished at {:.1} s (clear: {:.1} s), {} retransmissions",
        outage.finished_ns as f64 / 1e9,
        clear.finished_ns as f64 / 1e9,
        stats.retransmissions
    );
}

// ---------------------------------------------------------------------------------- real UDP

fn udp_pair() -> (UdpLink, UdpLink) {
    let a = UdpLink::bind("127.0.0.1:0").unwrap();
    let b = UdpLink::bind("127.0.0.1:0").unwrap();
    let (a_addr, b_addr) = (a.local_addr(), b.local_addr());
    (a.with_peers([b_addr]), b.with_peers([a_addr]))
}

#[test]
fn two_nodes_over_real_udp_sockets() {
    let (link_1, link_2) = udp_pair();
    let framing = link_1.framing();
    let mut node_1 = team_node(1, 2, framing, 1_000_000, RtoConfig::default());
    let mut node_2 = team_node(2, 1, framing, 1_000_000, RtoConfig::default());
    let mut driver_1 = LinkDriver::new().with(TEAM, Box::new(link_1));
    let mut driver_2 = LinkDriver::new().with(TEAM, Box::new(link_2));
    let (mut out_1, mut out_2) = (Collect::default(), Collect::default());

    let start = Instant::now();
    let now = || start.elapsed().as_nanos() as u64;
    for message in submap(1, 8 * SUBMAP_CHUNK_BYTES) {
        to_comms(&mut node_1, &mut out_1, now(), 2, &message);
    }
    for seq in 0..5 {
        to_comms(&mut node_1, &mut out_1, now(), TeamHeader::BROADCAST, &constraint(1, seq));
        to_comms(&mut node_1, &mut out_1, now(), TeamHeader::BROADCAST, &pose(1, u64::from(seq) + 1));
    }
    for seq in 0..3 {
        to_comms(&mut node_2, &mut out_2, now(), 1, &constraint(2, seq));
    }
    let mut next_tick = 0;
    loop {
        let t = now();
        assert!(t < 10_000_000_000, "not delivered within 10 s: {} at robot 2", out_2.to_mapper.len());
        driver_1.pump(&mut node_1, t).unwrap();
        driver_2.pump(&mut node_2, t).unwrap();
        if t >= next_tick {
            node_1.on_tick(t, &mut out_1).unwrap();
            node_2.on_tick(t, &mut out_2).unwrap();
            next_tick = t + 20_000_000;
        }
        let at_2 = received(&out_2);
        let reliable_2 = at_2.iter().filter(|r| !matches!(r.2, Item::Pose(_))).count();
        if reliable_2 == 1 + 8 + 5 && out_1.to_mapper.len() == 3 && node_1.is_idle() && node_2.is_idle() {
            break;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    let at_2: Vec<Item> = received(&out_2).into_iter().map(|r| r.2).collect();
    let mut reliable: Vec<Item> = at_2.iter().copied().filter(|i| !matches!(i, Item::Pose(_))).collect();
    let bulk: Vec<Item> = reliable.iter().copied().filter(|i| matches!(i, Item::Header | Item::Chunk(_))).collect();
    let mut in_order = vec![Item::Header];
    in_order.extend((0..8).map(Item::Chunk));
    assert_eq!(bulk, in_order);
    reliable.sort();
    reliable.dedup();
    assert_eq!(reliable.len(), 14, "exactly once");
    assert!(at_2.iter().any(|i| matches!(i, Item::Pose(_))), "a pose over loopback arrives");
    let at_1: Vec<Item> = received(&out_1).into_iter().map(|r| r.2).collect();
    assert_eq!(at_1, vec![Item::Constraint(0), Item::Constraint(1), Item::Constraint(2)]);
    assert!(driver_1.stats().packets_sent >= 14 && driver_2.stats().packets_received >= 14);
    assert_eq!(driver_1.stats().send_errors, 0);
    assert!(node_1.stats().sent_by_class["SubmapChunk"].packet_bytes >= 8 * SUBMAP_CHUNK_BYTES as u64);
    println!("udp: done in {:.0} ms", start.elapsed().as_secs_f64() * 1e3);
}

// -------------------------------------------------------------------------------- ground feed

const KEY_BYTES: &[u8; 32] = b"ground station key: 32 bytes ok!";

fn key_file() -> PathBuf {
    use std::io::Write;
    use std::os::unix::fs::OpenOptionsExt;
    let path = std::env::temp_dir().join(format!("nodes_comms_key_{}_{}", std::process::id(), line!()));
    let _ = std::fs::remove_file(&path);
    let mut file = std::fs::OpenOptions::new().write(true).create_new(true).mode(0o600).open(&path).unwrap();
    let hex: String = KEY_BYTES.iter().map(|b| format!("{b:02x}")).collect();
    writeln!(file, "{hex}").unwrap();
    path
}

/// The ground station: a UDP socket and the real protocol endpoint.
struct Ground {
    link: UdpLink,
    endpoint: Box<Endpoint>,
    telemetry: Vec<Telemetry>,
    poses: Vec<PoseEstimate>,
    acks: Vec<CommandAck>,
}

impl Ground {
    fn pump(&mut self, now_ms: u64) {
        let mut buf = [0u8; MAX_PACKET_BYTES];
        while let Some(len) = self.link.recv(&mut buf, Duration::ZERO).unwrap() {
            let _ = self.endpoint.handle_packet(now_ms, &buf[..len]);
        }
        while let Some(delivered) = self.endpoint.poll_deliver() {
            match delivered.message {
                AnyMessage::Telemetry(t) => self.telemetry.push(t),
                AnyMessage::PoseEstimate(p) => self.poses.push(p),
                AnyMessage::CommandAck(a) => self.acks.push(a),
                _ => {}
            }
        }
        while let Some(len) = self.endpoint.poll_transmit(now_ms, &mut buf) {
            self.link.send(&buf[..len]).unwrap();
        }
    }
}

fn task_stats(process: ProcessKind, overruns: u64, stamp_ns: u64, cpu_ns: u64) -> TaskStatsMsg {
    TaskStatsMsg {
        stamp_ns,
        period_ns: 5_000_000,
        deadline_ns: 5_000_000,
        releases: 1000,
        overruns,
        skipped: 0,
        jitter_p50_ns: 20_000,
        jitter_p99_ns: 250_000,
        jitter_max_ns: 900_000,
        execution_max_ns: 1_000_000,
        process_cpu_ns: cpu_ns,
        process_rss_bytes: 50 << 20,
        process: process as u32,
        task: 0,
        // The filter's IMU queue held 7 of its 512 samples at its fullest.
        queue_topic: if process == ProcessKind::Filter { u32::from(Topic::Imu.code()) } else { 0 },
        queue_depth_max: if process == ProcessKind::Filter { 7 } else { 0 },
        queue_capacity: if process == ProcessKind::Filter { 512 } else { 0 },
        devices: 0,
    }
}

fn filter_state(stamp_ns: u64) -> FilterStateMsg {
    let mut covariance = [0.0; 36];
    covariance[0] = 0.04; // σx = 0.2 m
    covariance[35] = 0.0001; // σyaw = 0.01 rad
    FilterStateMsg {
        stamp_ns,
        t_local_body: Pose { translation_m: [1.5, -2.0, 0.25], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] },
        v_local_mps: [0.0; 3],
        accel_bias_mps2: [0.0; 3],
        gyro_bias_radps: [0.0; 3],
        pose_covariance: covariance,
        imu_received: stamp_ns / 5_000_000,
        imu_lost: 0,
        frame_id: 3,
        status: FilterStateMsg::RUNNING,
        last_vo_capture_ns: stamp_ns.saturating_sub(300_000_000),
    }
}

#[test]
fn ground_station_gets_telemetry_and_commands_are_authenticated() {
    let ground_socket = UdpLink::bind("127.0.0.1:0").unwrap();
    let robot_socket = UdpLink::bind("127.0.0.1:0").unwrap().with_peers([ground_socket.local_addr()]);
    let ground_socket = ground_socket.with_peers([robot_socket.local_addr()]);
    let framing = robot_socket.framing();
    let path = key_file();
    let mut config = CommsConfig::new(RobotId(3), vec![LinkConfig::ground(GROUND_LINK, framing, 20_000)])
        .with_key_file(&path)
        .unwrap();
    let _ = std::fs::remove_file(&path);
    config.telemetry_period_ns = 200_000_000;
    config.heartbeat_period_ns = 200_000_000;
    let mut node = CommsNode::new(config).unwrap();
    let mut driver = LinkDriver::new().with(GROUND_LINK, Box::new(robot_socket));
    let mut out = Collect::default();
    let ground_config = EndpointConfig::new(NodeId::GROUND, framing, 20_000, 4 * 1_300);
    let mut ground = Ground {
        link: ground_socket,
        endpoint: Box::new(Endpoint::new(ground_config).unwrap()),
        telemetry: Vec::new(),
        poses: Vec::new(),
        acks: Vec::new(),
    };
    let key = AuthKey::from_bytes(KEY_BYTES).unwrap();
    let forged_key = AuthKey::from_bytes(b"not the ground station's key!!!!").unwrap();

    let start = Instant::now();
    let now = || start.elapsed().as_nanos() as u64;
    // Runs the robot and the ground station until `done` holds (at most 5 s).
    let mut run = |node: &mut CommsNode, ground: &mut Ground, done: &dyn Fn(&Ground, &CommsNode) -> bool| {
        let until = now() + 5_000_000_000;
        let mut next_tick = 0;
        loop {
            let t = now();
            assert!(t < until, "condition not reached");
            node.on_message(Message::FilterState(&filter_state(t)), &mut out).unwrap();
            node.on_message(Message::TaskStats(&task_stats(ProcessKind::Filter, 3, t, t / 4)), &mut out).unwrap();
            node.on_message(Message::TaskStats(&task_stats(ProcessKind::Vision, 1, t, t / 2)), &mut out).unwrap();
            // The driver reads devices: IMU and head deliver, the wheels do not.
            let driver_stats = TaskStatsMsg {
                devices: TaskStatsMsg::DEVICES_REPORTED | TaskStatsMsg::DEVICE_IMU | TaskStatsMsg::DEVICE_HEAD,
                ..task_stats(ProcessKind::Driver, 0, t, 0)
            };
            node.on_message(Message::TaskStats(&driver_stats), &mut out).unwrap();
            if t >= next_tick {
                node.on_tick(t, &mut out).unwrap();
                next_tick = t + 50_000_000;
            }
            driver.pump(node, t).unwrap();
            ground.pump(t / 1_000_000);
            if done(ground, node) {
                return;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    };

    // Telemetry carries what was fed in; a later one has measured the CPU load.
    run(&mut node, &mut ground, &|g, _| {
        g.telemetry.len() >= 3
            && !g.poses.is_empty()
            && g.telemetry.last().is_some_and(|t| t.resources.cpu_permille > 0)
    });
    let t = ground.telemetry.last().unwrap().clone();
    assert_eq!(t.robot, RobotId(3));
    assert_eq!(t.mode, Mode::Idle);
    assert_eq!(t.filter.status, FilterStatus::Nominal);
    assert_eq!(t.sensors, Some(SensorAvailability { imu: true, wheels: false, head: true }));
    assert!((t.filter.position_std_m - 0.2).abs() < 1e-4 && (t.filter.yaw_std_rad - 0.01).abs() < 1e-5);
    let task = |name: &str| t.tasks.iter().find(|s| s.task.as_str() == name).cloned().unwrap();
    let filter_task = task("filter.0");
    assert_eq!((filter_task.deadline_overruns, filter_task.jitter_p99_us, filter_task.jitter_max_us), (3, 250, 900));
    assert_eq!((filter_task.period_us, filter_task.releases), (5_000, 1000));
    assert_eq!(task("vision.0").deadline_overruns, 1);
    assert_eq!(t.resources.mem_used_kib, 3 * (50 << 10));
    // Filter 1/4 core + vision 1/2 core on one configured core: 750 ‰ (± clock steps).
    assert!((700..=800).contains(&t.resources.cpu_permille), "cpu {}", t.resources.cpu_permille);
    let filter_queue = t.queues.iter().find(|q| q.queue.as_str() == "filter").unwrap();
    assert_eq!((filter_queue.depth, filter_queue.capacity, filter_queue.dropped), (7, 512, 0));
    assert!(t.queues.iter().all(|q| q.queue.as_str() != "vision"), "vision reported no queue");
    // The state says the last odometry result applied was captured 300 ms before it.
    assert!((300..=400).contains(&t.filter.vo_age_ms), "VO age {} ms", t.filter.vo_age_ms);
    let link = t.links.iter().find(|l| l.link.as_str() == "ground").unwrap();
    assert!(link.tx_bytes > 0 && link.tx_rate_bps > 0);
    let pose = ground.poses.last().unwrap();
    assert_eq!((pose.robot, pose.submap.index), (RobotId(3), 3));
    assert_eq!(pose.t_submap_body.translation_m, [1.5, -2.0, 0.25]);

    // An authenticated SetMode is executed and acknowledged; the next telemetry reports it.
    let set_mode = |id, mode| AnyMessage::from(Command { target: RobotId(3), id, kind: CommandKind::SetMode(mode) });
    let t_ms = now() / 1_000_000;
    ground.endpoint.send_authenticated(t_ms, NodeId(3), &set_mode(42, Mode::Autonomous), 1, &key).unwrap();
    let waypoint = Command {
        target: RobotId(3),
        id: 43,
        kind: CommandKind::GoToWaypoint { x_m: 1.0, y_m: 2.0, z_m: 0.0, speed_mps: 0.1 },
    };
    ground.endpoint.send_authenticated(t_ms, NodeId(3), &AnyMessage::from(waypoint), 2, &key).unwrap();
    let recording = Command { target: RobotId(3), id: 44, kind: CommandKind::StopRecording };
    ground.endpoint.send_authenticated(t_ms, NodeId(3), &AnyMessage::from(recording), 3, &key).unwrap();
    run(&mut node, &mut ground, &|g, _| {
        g.acks.len() >= 3 && g.telemetry.last().is_some_and(|t| t.mode == Mode::Autonomous)
    });
    let outcome = |g: &Ground, id| g.acks.iter().find(|a| a.command_id == id).map(|a| a.outcome);
    assert_eq!(outcome(&ground, 42), Some(CommandOutcome::Executed));
    assert_eq!(outcome(&ground, 43), Some(CommandOutcome::Accepted));
    // Recording is chosen at start: refused, not pretended.
    assert_eq!(outcome(&ground, 44), Some(CommandOutcome::Refused));
    assert_eq!(node.mode(), Mode::Autonomous);

    // A forged SetMode is rejected: not executed, not acknowledged, counted and reported.
    let t_ms = now() / 1_000_000;
    ground.endpoint.send_authenticated(t_ms, NodeId(3), &set_mode(45, Mode::Safe), 4, &forged_key).unwrap();
    run(&mut node, &mut ground, &|g, n| {
        n.stats().auth_rejections >= 1 && g.telemetry.last().is_some_and(|t| t.auth_rejections >= 1)
    });
    assert_eq!(node.mode(), Mode::Autonomous);
    assert_eq!(outcome(&ground, 45), None);
    let stats = node.stats();
    let c = stats.commands;
    assert_eq!((c.executed, c.accepted, c.invalid, c.refused, c.waypoints), (1, 1, 0, 1, 1));
    assert_eq!(node.last_waypoint().map(|w| (w.command_id, w.x_m, w.y_m)), Some((43, 1.0, 2.0)));
    assert_eq!(stats.commands.acks_sent, 3);
    assert!(stats.sent_by_class["Telemetry"].packets >= 3);
}

// ------------------------------------------------------------------------------------- totality

fn fuzz_node() -> CommsNode {
    let team = LinkConfig::team(TEAM, "radio", Framing::Stream, 5_000, vec![RobotId(2)]);
    let ground = LinkConfig::ground(GROUND_LINK, Framing::Datagram { mtu: 1200 }, 20_000);
    let mut config = CommsConfig::new(RobotId(1), vec![team, ground]);
    config.auth_key = Some(AuthKey::from_bytes(KEY_BYTES).unwrap());
    CommsNode::new(config).unwrap()
}

/// A valid packet from robot 2 to robot 1, to mutate.
fn valid_packet(n: u32) -> Vec<u8> {
    let message = match n % 3 {
        0 => constraint(2, n),
        1 => pose(2, u64::from(n)),
        _ => submap(2, 300).pop().unwrap(),
    };
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let len = protocol::encode(&message, NodeId(2), NodeId(1), n, &mut buf).unwrap();
    buf[..len].to_vec()
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    #[test]
    fn arbitrary_bytes_never_panic(
        packets in proptest::collection::vec((0u8..12, proptest::collection::vec(any::<u8>(), 0..1300)), 1..12),
        payloads in proptest::collection::vec((any::<u32>(), any::<u32>(), proptest::collection::vec(any::<u8>(), 0..1300)), 1..12),
        mutations in proptest::collection::vec((any::<u32>(), any::<usize>(), any::<u8>()), 0..12),
    ) {
        let mut node = fuzz_node();
        let mut out = Collect::default();
        let mut now_ns = 0u64;
        for (link, bytes) in &packets {
            now_ns += 3_000_000;
            node.handle_packet(now_ns, LinkId(*link), bytes);
        }
        for (n, at, value) in &mutations {
            let mut packet = valid_packet(*n);
            let index = at % packet.len();
            packet[index] ^= value | 1;
            node.handle_packet(now_ns, TEAM, &packet);
            node.handle_packet(now_ns, GROUND_LINK, &packet[..index]);
        }
        for (robot_id, key, bytes) in &payloads {
            let header = TeamHeader { stamp_ns: now_ns, robot_id: *robot_id, message_key: *key };
            node.on_message(Message::ToComms(&header, bytes), &mut out).unwrap();
            // A valid payload with the arbitrary header too.
            let valid = valid_packet(*key);
            node.on_message(Message::ToComms(&header, &valid), &mut out).unwrap();
        }
        node.on_tick(now_ns, &mut out).unwrap();
        for _ in 0..1000 {
            now_ns += 1_000_000;
            if node.poll_transmit(now_ns).is_none() {
                break;
            }
        }
        let stats = node.stats();
        let garbage = payloads.iter().filter(|p| protocol::decode(&p.2).is_err()).count() as u64;
        prop_assert_eq!(stats.decode_rejections, garbage);
        for (_, bytes) in &out.to_mapper {
            prop_assert!(protocol::decode(bytes).is_ok());
        }
    }
}

// ---------------------------------------------------------------------------- replay guard

/// The ground link's packets of a node, decoded.
fn ground_output(node: &mut CommsNode, now_ns: u64) -> Vec<AnyMessage> {
    let mut messages = Vec::new();
    while let Some(packet) = node.poll_transmit_on(now_ns, GROUND_LINK) {
        messages.push(protocol::decode(packet).unwrap().message);
    }
    messages
}

#[test]
fn a_command_recorded_before_a_restart_is_refused_after_it() {
    let state = std::env::temp_dir().join(format!("nodes_comms_replay_{}", std::process::id()));
    let _ = std::fs::remove_file(&state);
    let make = || {
        let ground = LinkConfig::ground(GROUND_LINK, Framing::Datagram { mtu: 1200 }, 20_000);
        let mut config = CommsConfig::new(RobotId(1), vec![ground]);
        config.auth_key = Some(AuthKey::from_bytes(KEY_BYTES).unwrap());
        config.replay_state = Some(state.clone());
        CommsNode::new(config).unwrap()
    };
    let key = AuthKey::from_bytes(KEY_BYTES).unwrap();
    let command = AnyMessage::from(Command { target: RobotId(1), id: 7, kind: CommandKind::SetMode(Mode::Safe) });
    let mut recorded = [0u8; MAX_PACKET_BYTES];
    let len = protocol::encode_authenticated(&command, NodeId::GROUND, NodeId(1), 0, 1, &key, &mut recorded).unwrap();
    let recorded = &recorded[..len];
    let mut out = Collect::default();
    let acks = |messages: Vec<AnyMessage>| -> Vec<CommandAck> {
        messages
            .into_iter()
            .filter_map(|m| match m {
                AnyMessage::CommandAck(a) => Some(a),
                _ => None,
            })
            .collect()
    };

    let mut first = make();
    first.handle_packet(1_000_000, GROUND_LINK, recorded);
    first.on_tick(1_000_000, &mut out).unwrap();
    assert_eq!(first.mode(), Mode::Safe);
    let outcomes: Vec<_> = acks(ground_output(&mut first, 2_000_000)).iter().map(|a| a.outcome).collect();
    assert_eq!(outcomes, [CommandOutcome::Executed]);
    drop(first);

    // The restarted node's endpoint has forgotten the channel: only the guard stops the replay.
    let mut second = make();
    second.handle_packet(1_000_000, GROUND_LINK, recorded);
    second.on_tick(1_000_000, &mut out).unwrap();
    assert_eq!(second.mode(), Mode::Idle);
    let outcomes: Vec<_> = acks(ground_output(&mut second, 2_000_000)).iter().map(|a| a.outcome).collect();
    assert_eq!(outcomes, [CommandOutcome::Refused]);
    assert_eq!(second.stats().commands.replayed, 1);

    // A corrupt guard file stops the node from starting rather than forgetting the counters.
    std::fs::write(&state, b"240 1\ngarbage\n").unwrap();
    let ground = LinkConfig::ground(GROUND_LINK, Framing::Datagram { mtu: 1200 }, 20_000);
    let mut config = CommsConfig::new(RobotId(1), vec![ground]);
    config.replay_state = Some(state.clone());
    assert!(matches!(CommsNode::new(config), Err(onboard::nodes::comms::CommsError::ReplayState(_))));
    let _ = std::fs::remove_file(&state);
}

proptest! {
    #[test]
    fn replay_guard_files_parse_totally(bytes in proptest::collection::vec(any::<u8>(), 0..300)) {
        let _ = onboard::nodes::comms::replay::parse(&bytes);
    }
}
