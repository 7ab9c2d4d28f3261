//! The endpoint: latest-wins replacement, priorities, back-pressure, authentication of incoming
//! packets, the rate cap and timers.

// Test helpers too may unwrap and panic: a panic is a failed test with a backtrace.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use proptest::prelude::*;
use protocol::delivery::{
    ConfigError, DEFAULT_WINDOW, Endpoint, EndpointConfig, LATEST_SLOTS, ReceiveError, RtoConfig, SendError,
};
use protocol::frame::Framing;
use protocol::frame::can::CanKind;
use protocol::message::*;
use protocol::{
    AnyMessage, AuthKey, Cov6, MAX_PACKET_BYTES, NodeId, NodeRef, Pose3, Priority, RobotId, SubmapId, decode,
};

const ROBOT: NodeId = NodeId(1);
const GROUND: NodeId = NodeId::GROUND;

fn key() -> AuthKey {
    AuthKey::from_bytes(b"delivery test key, 32 bytes long").unwrap()
}

fn endpoint(local: NodeId) -> Box<Endpoint> {
    let config = EndpointConfig::new(local, Framing::Stream, 20_000, 4_000).with_auth_key(key());
    Box::new(Endpoint::new(config).unwrap())
}

fn pose(robot: u8, stamp_ns: u64) -> AnyMessage {
    AnyMessage::from(PoseEstimate {
        robot: RobotId(robot),
        stamp_ns,
        submap: SubmapId { robot: RobotId(robot), index: 0 },
        t_submap_body: Pose3::IDENTITY,
        covariance: Cov6::from_std_devs([0.1; 6]),
    })
}

fn constraint(seq: u32) -> AnyMessage {
    AnyMessage::from(Constraint {
        id: ConstraintId { robot: RobotId(1), seq },
        kind: ConstraintKind::RobotDetection,
        stamp_ns: 5,
        from: NodeRef::Landmark { id: 1 },
        to: NodeRef::Landmark { id: 2 },
        t_from_to: Pose3::IDENTITY,
        covariance: Cov6::from_std_devs([0.1; 6]),
    })
}

fn chunk(index: u16) -> AnyMessage {
    let mut data = heapless::Vec::new();
    data.extend_from_slice(&[index as u8; SUBMAP_CHUNK_BYTES]).unwrap();
    AnyMessage::from(SubmapChunk { submap: SubmapId { robot: RobotId(1), index: 3 }, index, data })
}

fn command(id: u32) -> AnyMessage {
    AnyMessage::from(Command { target: RobotId(1), id, kind: CommandKind::SetMode(Mode::Safe) })
}

fn telemetry() -> AnyMessage {
    AnyMessage::from(Telemetry {
        robot: RobotId(1),
        stamp_ns: 1,
        mode: Mode::Idle,
        filter: FilterHealth { status: FilterStatus::Nominal, position_std_m: 0.1, yaw_std_rad: 0.1, vo_age_ms: 5 },
        resources: ResourceUsage { cpu_permille: 1, mem_used_kib: 1, mem_total_kib: 2 },
        tasks: heapless::Vec::new(),
        queues: heapless::Vec::new(),
        links: heapless::Vec::new(),
        auth_rejections: 0,
        classes: Default::default(),
        sensors: None,
    })
}

/// Every packet `endpoint` transmits at `now_ms`, decoded.
fn drain(endpoint: &mut Endpoint, now_ms: u64) -> Vec<(Vec<u8>, protocol::Packet)> {
    let mut out = Vec::new();
    let mut buf = [0u8; MAX_PACKET_BYTES];
    while let Some(len) = endpoint.poll_transmit(now_ms, &mut buf) {
        out.push((buf[..len].to_vec(), decode(&buf[..len]).unwrap()));
    }
    out
}

#[test]
fn latest_wins_replaces_an_unsent_message_of_the_same_slot() {
    let mut robot = endpoint(ROBOT);
    robot.send(0, GROUND, &pose(1, 100)).unwrap();
    robot.send(0, GROUND, &pose(2, 100)).unwrap();
    robot.send(0, GROUND, &pose(1, 200)).unwrap(); // replaces robot 1's stamp 100
    robot.send(0, NodeId(2), &pose(1, 300)).unwrap(); // another destination: its own slot
    assert_eq!(robot.stats().latest_wins_replaced, 1);
    assert_eq!(robot.stats().queued[Priority::State.channel() as usize], 3);
    let sent: Vec<_> = drain(&mut robot, 0).into_iter().map(|(_, p)| (p.header.destination, p.message)).collect();
    assert_eq!(sent, vec![(GROUND, pose(1, 200)), (GROUND, pose(2, 100)), (NodeId(2), pose(1, 300))]);
    // Sent messages are not replaced any more: a new one is queued again.
    robot.send(1, GROUND, &pose(1, 400)).unwrap();
    assert_eq!(robot.stats().latest_wins_replaced, 1);
    // The latest-wins table is bounded too: a full table is back-pressure, not a silent drop.
    for robot_id in 10..(10 + LATEST_SLOTS as u8 - 1) {
        robot.send(1, GROUND, &pose(robot_id, 1)).unwrap();
    }
    assert_eq!(
        robot.send(1, GROUND, &pose(200, 1)),
        Err(SendError::QueueFull { destination: GROUND, priority: Priority::State })
    );
}

#[test]
fn higher_priorities_go_first_acks_before_everything() {
    let mut ground = endpoint(GROUND);
    let mut robot = endpoint(ROBOT);
    for i in 0..3 {
        robot.send(0, GROUND, &chunk(i)).unwrap();
    }
    robot.send(0, GROUND, &telemetry()).unwrap();
    robot.send(0, GROUND, &pose(1, 1)).unwrap();
    robot.send(0, GROUND, &constraint(0)).unwrap();
    robot
        .send(
            0,
            GROUND,
            &AnyMessage::from(CommandAck { robot: RobotId(1), command_id: 9, outcome: CommandOutcome::Accepted }),
        )
        .unwrap();
    // A command from the ground arrives: its acknowledgement jumps the queue.
    ground.send_authenticated(0, ROBOT, &command(9), 1, &key()).unwrap();
    for (bytes, _) in drain(&mut ground, 0) {
        robot.handle_packet(0, &bytes).unwrap();
    }
    let order: Vec<&str> = drain(&mut robot, 0).iter().map(|(_, p)| p.message.type_name()).collect();
    assert_eq!(
        order,
        ["Ack", "CommandAck", "Constraint", "PoseEstimate", "Telemetry", "SubmapChunk", "SubmapChunk", "SubmapChunk"]
    );
    let delivered = robot.poll_deliver().unwrap();
    assert_eq!(delivered.message, command(9));
    assert_eq!(delivered.auth, Some((GROUND, 1)));
}

#[test]
fn a_queued_command_goes_before_queued_bulk_data_under_the_rate_cap() {
    // Bulk queued first, the command later: once the link has room, the command goes next.
    let mut ground = endpoint(GROUND);
    for i in 0..5 {
        ground.send(0, ROBOT, &chunk(i)).unwrap();
    }
    let first = drain(&mut ground, 0);
    assert!(first.len() < 5, "the burst lets only some chunks through");
    ground.send_authenticated(1, ROBOT, &command(1), 7, &key()).unwrap();
    let at = ground.next_transmit_ms(1).unwrap();
    let next = drain(&mut ground, at);
    assert_eq!(next[0].1.message, command(1));
}

#[test]
fn retransmissions_go_before_new_data_of_their_channel() {
    let config = EndpointConfig::new(ROBOT, Framing::Stream, 100_000, 4_000).with_rto(RtoConfig {
        initial_ms: 100,
        min_ms: 5,
        max_ms: 10_000,
    });
    let mut robot: Box<Endpoint> = Box::new(Endpoint::new(config).unwrap());
    robot.send(0, GROUND, &constraint(0)).unwrap();
    robot.send(0, GROUND, &constraint(1)).unwrap();
    assert_eq!(drain(&mut robot, 0).len(), 2);
    assert_eq!(robot.next_transmit_ms(0), Some(100));
    robot.send(50, GROUND, &constraint(2)).unwrap();
    let seqs: Vec<(u32, AnyMessage)> =
        drain(&mut robot, 50).into_iter().map(|(_, p)| (p.header.seq, p.message)).collect();
    assert_eq!(seqs, vec![(2, constraint(2))]);
    // The first timeout: packet 0 goes again, before new data, and the timeout doubles, for
    // the packets of that round too (1 and 2 now wait 200 ms from their first transmission).
    robot.send(100, GROUND, &constraint(3)).unwrap();
    let seqs: Vec<u32> = drain(&mut robot, 100).into_iter().map(|(_, p)| p.header.seq).collect();
    assert_eq!(seqs, vec![0, 3]);
    assert_eq!(robot.stats().retransmissions, 1);
    assert_eq!(robot.rtt(GROUND).unwrap().timeout_ms(), 200);
    let mut timeline = Vec::new();
    let mut now = 100;
    while robot.stats().retransmissions < 8 {
        now = robot.next_transmit_ms(now).unwrap();
        for (_, p) in drain(&mut robot, now) {
            timeline.push((now, p.header.seq, robot.rtt(GROUND).unwrap().timeout_ms()));
        }
    }
    // (time, seq, timeout after it): packets of the old round do not double the timeout again;
    // packet 0, resent after the backoff, times out once more and doubles it.
    assert_eq!(
        timeline,
        vec![(200, 1, 200), (250, 2, 200), (300, 0, 400), (500, 3, 400), (600, 1, 400), (650, 2, 400), (700, 0, 800)]
    );
}

#[test]
fn a_full_window_is_back_pressure_until_acknowledged() {
    let mut robot = endpoint(ROBOT);
    let mut ground = endpoint(GROUND);
    for i in 0..DEFAULT_WINDOW as u32 {
        robot.send(0, GROUND, &constraint(i)).unwrap();
    }
    assert_eq!(robot.queue_space(GROUND, Priority::Constraint), 0);
    assert_eq!(
        robot.send(0, GROUND, &constraint(99)),
        Err(SendError::QueueFull { destination: GROUND, priority: Priority::Constraint })
    );
    assert_eq!(robot.stats().queue_full, 1);
    // Other classes are not held up by it.
    robot.send(0, GROUND, &chunk(0)).unwrap();
    let mut now = 0;
    while robot.stats().in_flight[Priority::Constraint.channel() as usize] < DEFAULT_WINDOW as u32 {
        for (bytes, _) in drain(&mut robot, now) {
            ground.handle_packet(now, &bytes).unwrap();
        }
        now += 10;
    }
    for (bytes, p) in drain(&mut ground, now) {
        assert_eq!(p.message.type_name(), "Ack");
        robot.handle_packet(now, &bytes).unwrap();
    }
    assert_eq!(robot.queue_space(GROUND, Priority::Constraint), DEFAULT_WINDOW);
    robot.send(now, GROUND, &constraint(99)).unwrap();
    let mut delivered = Vec::new();
    while let Some(d) = ground.poll_deliver() {
        delivered.push(d.message);
    }
    assert_eq!(delivered, (0..DEFAULT_WINDOW as u32).map(constraint).collect::<Vec<_>>());
    assert!(robot.stats().srtt_ms.is_some());
}

#[test]
fn send_refuses_what_it_cannot_deliver() {
    let mut robot = endpoint(ROBOT);
    assert_eq!(robot.send(0, GROUND, &command(1)), Err(SendError::NeedsAuthentication("Command")));
    assert_eq!(
        robot.send_authenticated(0, GROUND, &constraint(1), 1, &key()),
        Err(SendError::NotAuthenticated("Constraint"))
    );
    let ack = AnyMessage::from(Ack { channel: 2, next_expected: 0, received_mask: 0 });
    assert_eq!(robot.send(0, GROUND, &ack), Err(SendError::TransportMessage));
    assert_eq!(robot.send(0, NodeId::BROADCAST, &constraint(1)), Err(SendError::ReliableBroadcast("Constraint")));
    assert_eq!(robot.send(0, ROBOT, &pose(1, 1)), Err(SendError::ToSelf));
    // Latest-wins may be broadcast.
    robot.send(0, NodeId::BROADCAST, &pose(1, 1)).unwrap();
    for peer in 2..=5 {
        robot.send(0, NodeId(peer), &constraint(1)).unwrap();
    }
    assert_eq!(robot.send(0, NodeId(6), &constraint(1)), Err(SendError::TooManyPeers(4)));
}

#[test]
fn configurations_that_cannot_work_are_refused() {
    let small = EndpointConfig::new(ROBOT, Framing::Can(CanKind::Classic), 50_000, 1_000);
    let needed = EndpointConfig::min_burst_bytes(Framing::Can(CanKind::Classic));
    assert_eq!(Endpoint::<32>::new(small).err(), Some(ConfigError::BurstTooSmall { burst: 1_000, needed }));
    let zero = EndpointConfig::new(ROBOT, Framing::Stream, 0, 4_000);
    assert_eq!(Endpoint::<32>::new(zero).err(), Some(ConfigError::ZeroRate));
    let broadcast = EndpointConfig::new(NodeId::BROADCAST, Framing::Stream, 1, 4_000);
    assert!(Endpoint::<32>::new(broadcast).is_err());
}

// Checked at compile time: an endpoint with the default window takes ~390 KB, one with a
// 64-packet window ~675 KB.
const _: () = assert!(Endpoint::<DEFAULT_WINDOW>::MEMORY_BYTES < 450_000);
const _: () = assert!(Endpoint::<64>::MEMORY_BYTES < 1_000_000);

#[test]
fn memory_stays_well_under_a_megabyte() {
    println!(
        "Endpoint<{DEFAULT_WINDOW}>: {} bytes; Endpoint<64>: {} bytes",
        Endpoint::<DEFAULT_WINDOW>::MEMORY_BYTES,
        Endpoint::<64>::MEMORY_BYTES
    );
}

// -------------------------------------------------------------------------- authentication

/// A valid authenticated command packet from the ground to the robot, as the ground sends it.
fn command_packet(counter: u64, key: &AuthKey) -> Vec<u8> {
    let mut ground = endpoint(GROUND);
    ground.send_authenticated(0, ROBOT, &command(42), counter, key).unwrap();
    drain(&mut ground, 0).remove(0).0
}

fn assert_rejected_quietly(robot: &mut Endpoint, bytes: &[u8]) -> ReceiveError {
    let before = robot.stats().rejected.total();
    let error = robot.handle_packet(0, bytes).unwrap_err();
    assert_eq!(robot.stats().rejected.total(), before + 1, "{error}");
    assert!(robot.poll_deliver().is_none(), "delivered after {error}");
    assert!(robot.is_idle(), "acknowledged after {error}");
    assert_eq!(robot.next_transmit_ms(0), None);
    error
}

#[test]
fn forged_commands_are_rejected_counted_and_never_delivered() {
    let mut robot = endpoint(ROBOT);
    let forger = AuthKey::from_bytes(b"not the key: 32 bytes of guess!!").unwrap();
    let error = assert_rejected_quietly(&mut robot, &command_packet(1, &forger));
    assert!(matches!(error, ReceiveError::Auth(protocol::AuthError::BadTag)), "{error}");
    assert_eq!(robot.stats().rejected.bad_mac, 1);
    // An endpoint without a key rejects every authenticated packet.
    let mut keyless: Box<Endpoint> =
        Box::new(Endpoint::new(EndpointConfig::new(ROBOT, Framing::Stream, 20_000, 4_000)).unwrap());
    assert_eq!(assert_rejected_quietly(&mut keyless, &command_packet(1, &key())), ReceiveError::NoKey);
}

#[test]
fn every_single_bit_flip_of_a_command_is_rejected() {
    let mut robot = endpoint(ROBOT);
    let packet = command_packet(5, &key());
    for bit in 0..packet.len() * 8 {
        let mut corrupted = packet.clone();
        corrupted[bit / 8] ^= 1 << (bit % 8);
        assert_rejected_quietly(&mut robot, &corrupted);
    }
    let flips = (packet.len() * 8) as u64;
    let rejected = robot.stats().rejected;
    println!("{flips} bit flips: {rejected:?}");
    assert_eq!(rejected.total(), flips);
    assert!(rejected.bad_mac > flips / 2);
    // The genuine packet still goes through, once, and is acknowledged.
    robot.handle_packet(0, &packet).unwrap();
    robot.handle_packet(0, &packet).unwrap();
    assert_eq!(robot.poll_deliver().map(|d| (d.message, d.auth)), Some((command(42), Some((GROUND, 5)))));
    assert!(robot.poll_deliver().is_none());
    assert_eq!(robot.stats().duplicates, 1);
    assert!(!robot.is_idle());
}

#[test]
fn unauthenticated_commands_are_rejected() {
    let mut robot = endpoint(ROBOT);
    let packet = command_packet(5, &key());
    // The same command without its trailer and with the authentication flag cleared.
    let mut stripped = packet[..packet.len() - protocol::auth::AUTH_TRAILER_BYTES].to_vec();
    stripped[3] &= !protocol::codec::Flags::AUTHENTICATED;
    let error = assert_rejected_quietly(&mut robot, &stripped);
    assert_eq!(error, ReceiveError::Unauthenticated { key: 0x40 });
    assert_eq!(robot.stats().rejected.unauthenticated, 1);
}

#[test]
fn packets_for_other_nodes_and_echoes_are_dropped() {
    let mut robot = endpoint(ROBOT);
    let mut other = endpoint(NodeId(3));
    other.send(0, NodeId(2), &constraint(0)).unwrap();
    let (bytes, _) = drain(&mut other, 0).remove(0);
    assert_eq!(assert_rejected_quietly(&mut robot, &bytes), ReceiveError::NotForThisNode { destination: NodeId(2) });
    robot.send(0, GROUND, &constraint(0)).unwrap();
    let (echo, _) = drain(&mut robot, 0).remove(0);
    let mut fresh = endpoint(ROBOT);
    assert_eq!(assert_rejected_quietly(&mut fresh, &echo), ReceiveError::InvalidSource);
    // Garbage of any kind is an error, not a panic.
    for len in 0..64 {
        let junk: Vec<u8> = (0..len).map(|i| (i * 37 + len) as u8).collect();
        assert!(fresh.handle_packet(0, &junk).is_err());
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// Whatever the application queues and however often it polls, the wire bytes an endpoint
    /// emits over any interval stay within `rate·T/1000 + burst`.
    #[test]
    fn endpoint_never_exceeds_its_rate(
        rate in 2_000u64..50_000,
        extra_burst in 0u64..3_000,
        framing in prop_oneof![
            Just(Framing::Stream),
            Just(Framing::Datagram { mtu: 1200 }),
            Just(Framing::Datagram { mtu: 300 }),
            Just(Framing::Can(CanKind::Classic)),
            Just(Framing::Can(CanKind::Fd)),
        ],
        steps in proptest::collection::vec((0u64..40, 0u8..6), 1..400),
    ) {
        let burst = EndpointConfig::min_burst_bytes(framing) + extra_burst;
        let mut robot: Box<Endpoint> =
            Box::new(Endpoint::new(EndpointConfig::new(ROBOT, framing, rate, burst)).unwrap());
        let mut now = 0;
        let mut emitted: Vec<(u64, u64)> = Vec::new();
        let mut buf = [0u8; MAX_PACKET_BYTES];
        for (i, (dt, what)) in steps.into_iter().enumerate() {
            now += dt;
            let _ = match what {
                0 => robot.send(now, GROUND, &chunk(i as u16)),
                1 => robot.send(now, GROUND, &constraint(i as u32)),
                2 => robot.send(now, GROUND, &pose((i % 5) as u8, i as u64)),
                3 => robot.send(now, NodeId(2), &telemetry()),
                _ => Ok(()),
            };
            while let Some(len) = robot.poll_transmit(now, &mut buf) {
                emitted.push((now, framing.wire_bytes(len) as u64));
            }
        }
        let total: u64 = emitted.iter().map(|e| e.1).sum();
        prop_assert_eq!(total, robot.stats().sent_total().wire_bytes);
        for i in 0..emitted.len() {
            let mut bytes = 0;
            for j in i..emitted.len() {
                bytes += emitted[j].1;
                let span = emitted[j].0 - emitted[i].0;
                prop_assert!(1000 * bytes <= rate * span + 1000 * burst);
            }
        }
    }
}
