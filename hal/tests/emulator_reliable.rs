//! Two endpoints over emulated links: every reliable message arrives exactly once and in order
//! per channel, with 30 % loss, duplication and reordering in both directions (acknowledgements
//! are lost too), and on the 4 s Moon–Earth channel across an outage.

// Test helpers too may unwrap and panic: a panic is a failed test with a backtrace.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::VecDeque;

use hal::emulator::{DuplexEmulator, EmulatorConfig, Side};
use proptest::prelude::*;
use protocol::delivery::{Endpoint, EndpointConfig, SendError};
use protocol::frame::Framing;
use protocol::message::*;
use protocol::{AnyMessage, AuthKey, Cov6, MAX_PACKET_BYTES, NodeId, NodeRef, Pose3, ReplayGuard, RobotId, SubmapId};

const ROBOT: NodeId = NodeId(1);
const GROUND: NodeId = NodeId::GROUND;

fn key() -> AuthKey {
    AuthKey::from_bytes(b"emulator test key: 32 bytes long").unwrap()
}

fn constraint(seq: u32) -> AnyMessage {
    AnyMessage::from(Constraint {
        id: ConstraintId { robot: RobotId(1), seq },
        kind: ConstraintKind::SubmapMatch,
        stamp_ns: u64::from(seq),
        from: NodeRef::SubmapOrigin(SubmapId { robot: RobotId(1), index: seq }),
        to: NodeRef::SubmapOrigin(SubmapId { robot: RobotId(2), index: seq }),
        t_from_to: Pose3::IDENTITY,
        covariance: Cov6::from_std_devs([0.1; 6]),
    })
}

fn chunk(seq: u32) -> AnyMessage {
    // hal does not depend on heapless: build the chunk's buffer through `TryFrom<&[u8]>`.
    let data = TryFrom::try_from(&[seq as u8; SUBMAP_CHUNK_BYTES][..]).unwrap();
    AnyMessage::from(SubmapChunk { submap: SubmapId { robot: RobotId(1), index: seq / 64 }, index: seq as u16, data })
}

fn command(seq: u32) -> AnyMessage {
    AnyMessage::from(Command { target: RobotId(1), id: seq, kind: CommandKind::SetMode(Mode::Autonomous) })
}

fn pose(stamp_ms: u64) -> AnyMessage {
    AnyMessage::from(PoseEstimate {
        robot: RobotId(1),
        stamp_ns: stamp_ms * 1_000_000,
        submap: SubmapId { robot: RobotId(1), index: 0 },
        t_submap_body: Pose3::IDENTITY,
        covariance: Cov6::from_std_devs([0.1; 6]),
    })
}

fn heartbeat(stamp_ms: u64) -> AnyMessage {
    AnyMessage::from(Heartbeat {
        node: GROUND,
        stamp_ns: stamp_ms * 1_000_000,
        uptime_ms: stamp_ms,
        boot_id: 7,
        mode: Mode::Idle,
    })
}

/// The reliable streams of the test, each numbered from 0 in its message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Stream {
    Constraints,
    Chunks,
    Commands,
    CommandAcks,
}

impl Stream {
    const ALL: [Stream; 4] = [Stream::Constraints, Stream::Chunks, Stream::Commands, Stream::CommandAcks];

    fn index(self) -> usize {
        self as usize
    }

    /// Which stream a delivered message belongs to, and its number in it.
    fn of(message: &AnyMessage) -> Option<(Stream, u32)> {
        match message {
            AnyMessage::Constraint(c) => Some((Stream::Constraints, c.id.seq)),
            AnyMessage::SubmapChunk(c) => Some((Stream::Chunks, u32::from(c.index))),
            AnyMessage::Command(c) => Some((Stream::Commands, c.id)),
            AnyMessage::CommandAck(a) => Some((Stream::CommandAcks, a.command_id)),
            _ => None,
        }
    }
}

/// A message source: `total` messages, one every `period_ms`, retried on back-pressure.
#[derive(Debug, Clone)]
struct Source {
    stream: Stream,
    from: Side,
    total: u32,
    period_ms: u64,
    next: u32,
}

#[derive(Debug, Clone)]
struct Scenario {
    link: EmulatorConfig,
    rate_bytes_per_s: u64,
    sources: Vec<Source>,
    /// Latest-wins: a pose from the robot and a heartbeat from the ground, every this many ms.
    latest_period_ms: u64,
    /// Stop offering latest-wins traffic after this.
    latest_until_ms: u64,
    deadline_ms: u64,
    initial_rto_ms: u64,
}

#[derive(Debug, Default)]
struct Outcome {
    /// Per stream: numbers in delivery order.
    received: [Vec<u32>; 4],
    /// Per stream: delivery times.
    received_at: [Vec<u64>; 4],
    latest_received: u64,
    finished_ms: u64,
    retransmissions: u64,
    duplicates: u64,
    queue_full: u64,
    robot_srtt_ms: Option<u64>,
    wire_bytes: u64,
}

fn endpoint(local: NodeId, framing: Framing, rate: u64, initial_rto_ms: u64) -> Box<Endpoint> {
    let burst = EndpointConfig::min_burst_bytes(framing) * 2;
    let mut config = EndpointConfig::new(local, framing, rate, burst).with_auth_key(key());
    config.rto.initial_ms = initial_rto_ms;
    Box::new(Endpoint::new(config).unwrap())
}

fn run(scenario: &Scenario) -> Outcome {
    let mut duplex = DuplexEmulator::symmetric(scenario.link.clone());
    let framing = scenario.link.framing;
    let mut robot = endpoint(ROBOT, framing, scenario.rate_bytes_per_s, scenario.initial_rto_ms);
    let mut ground = endpoint(GROUND, framing, scenario.rate_bytes_per_s, scenario.initial_rto_ms);
    let mut sources = scenario.sources.clone();
    let mut acks_to_send: VecDeque<u32> = VecDeque::new();
    let mut guard = ReplayGuard::<4>::new();
    let mut out = Outcome::default();
    let expected: [u32; 4] = core::array::from_fn(|i| {
        sources.iter().filter(|s| s.stream.index() == i).map(|s| s.total).sum::<u32>()
            + if i == Stream::CommandAcks.index() {
                sources.iter().filter(|s| s.stream == Stream::Commands).map(|s| s.total).sum::<u32>()
            } else {
                0
            }
    });
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let mut now = 0u64;
    let mut next_latest = 0u64;
    loop {
        assert!(now <= scenario.deadline_ms, "not finished by {now} ms: {:?}", out.received.each_ref().map(Vec::len));
        // 1. Arrivals.
        while let Some(packet) = duplex.poll(Side::B, now) {
            let _ = ground.handle_packet(now, &packet);
        }
        while let Some(packet) = duplex.poll(Side::A, now) {
            let _ = robot.handle_packet(now, &packet);
        }
        // 2. Deliveries.
        for (side, node) in [(Side::A, &mut robot), (Side::B, &mut ground)] {
            while let Some(delivered) = node.poll_deliver() {
                let Some((stream, n)) = Stream::of(&delivered.message) else {
                    out.latest_received += 1;
                    continue;
                };
                if stream == Stream::Commands {
                    assert_eq!(side, Side::A);
                    // The application's replay check at execution time never fires.
                    let (sender, counter) = delivered.auth.unwrap();
                    guard.accept(sender, counter).unwrap();
                    acks_to_send.push_back(n);
                }
                out.received[stream.index()].push(n);
                out.received_at[stream.index()].push(now);
            }
        }
        if out.received.iter().zip(expected).all(|(r, e)| r.len() == e as usize) && robot.is_idle() {
            break;
        }
        // 3. The applications queue messages, as far as back-pressure allows.
        for source in &mut sources {
            while source.next < source.total && source.period_ms * u64::from(source.next) <= now {
                let (node, to) = match source.from {
                    Side::A => (&mut robot, GROUND),
                    Side::B => (&mut ground, ROBOT),
                };
                let n = source.next;
                let result = match source.stream {
                    Stream::Constraints => node.send(now, to, &constraint(n)),
                    Stream::Chunks => node.send(now, to, &chunk(n)),
                    Stream::Commands => node.send_authenticated(now, to, &command(n), u64::from(n) + 1, &key()),
                    Stream::CommandAcks => unreachable!(),
                };
                match result {
                    Ok(()) => source.next += 1,
                    Err(SendError::QueueFull { .. }) => break,
                    Err(e) => panic!("{e}"),
                }
            }
        }
        while let Some(&id) = acks_to_send.front() {
            let ack =
                AnyMessage::from(CommandAck { robot: RobotId(1), command_id: id, outcome: CommandOutcome::Executed });
            match robot.send(now, GROUND, &ack) {
                Ok(()) => {
                    acks_to_send.pop_front();
                }
                Err(SendError::QueueFull { .. }) => break,
                Err(e) => panic!("{e}"),
            }
        }
        if now >= next_latest && now < scenario.latest_until_ms {
            robot.send(now, GROUND, &pose(now)).unwrap();
            ground.send(now, ROBOT, &heartbeat(now)).unwrap();
            next_latest = now + scenario.latest_period_ms;
        }
        // 4. Transmissions.
        while let Some(len) = robot.poll_transmit(now, &mut buf) {
            duplex.send(Side::A, now, &buf[..len]);
        }
        while let Some(len) = ground.poll_transmit(now, &mut buf) {
            duplex.send(Side::B, now, &buf[..len]);
        }
        // 5. Sleep until the next event.
        let mut next = [robot.next_transmit_ms(now), ground.next_transmit_ms(now), duplex.next_event_ms()]
            .into_iter()
            .flatten()
            .min()
            .unwrap_or(u64::MAX);
        if now < scenario.latest_until_ms {
            next = next.min(next_latest);
        }
        for source in &sources {
            if source.next < source.total {
                next = next.min(source.period_ms * u64::from(source.next));
            }
        }
        assert!(next < u64::MAX, "nothing left to happen at {now} ms");
        now = next.max(now + 1);
    }
    out.finished_ms = now;
    out.retransmissions = robot.stats().retransmissions + ground.stats().retransmissions;
    out.duplicates = robot.stats().duplicates + ground.stats().duplicates;
    out.queue_full = robot.stats().queue_full + ground.stats().queue_full;
    out.robot_srtt_ms = robot.stats().srtt_ms;
    out.wire_bytes = robot.stats().sent_total().wire_bytes + ground.stats().sent_total().wire_bytes;
    for stream in Stream::ALL {
        let received = &out.received[stream.index()];
        assert_eq!(
            received,
            &(0..expected[stream.index()]).collect::<Vec<_>>(),
            "{stream:?}: not every message exactly once in order"
        );
    }
    out
}

fn lossy(seed: u64) -> Scenario {
    let link = EmulatorConfig {
        bandwidth_bytes_per_s: 200_000,
        latency_ms: 20,
        jitter_ms: 10,
        loss: 0.30,
        duplicate: 0.10,
        reorder: 0.20,
        reorder_delay_ms: 50,
        queue_bytes: 64 * 1024,
        ..EmulatorConfig::ideal(200_000, Framing::Datagram { mtu: 1200 })
    }
    .with_seed(seed);
    Scenario {
        link,
        rate_bytes_per_s: 200_000,
        sources: vec![
            Source { stream: Stream::Constraints, from: Side::A, total: 2_000, period_ms: 5, next: 0 },
            Source { stream: Stream::Chunks, from: Side::A, total: 600, period_ms: 10, next: 0 },
            Source { stream: Stream::Commands, from: Side::B, total: 300, period_ms: 30, next: 0 },
        ],
        latest_period_ms: 100,
        latest_until_ms: 10_000,
        deadline_ms: 120_000,
        initial_rto_ms: 200,
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 6, ..ProptestConfig::default() })]

    #[test]
    fn every_reliable_message_arrives_once_in_order_through_30_percent_loss(seed in any::<u64>()) {
        let outcome = run(&lossy(seed));
        println!(
            "seed {seed:#x}: done at {} ms, {} retransmissions, {} duplicates, {} latest-wins delivered, \
             {} back-pressure refusals, srtt {:?} ms",
            outcome.finished_ms, outcome.retransmissions, outcome.duplicates, outcome.latest_received,
            outcome.queue_full, outcome.robot_srtt_ms,
        );
        prop_assert!(outcome.retransmissions > 0 && outcome.duplicates > 0);
        prop_assert!(outcome.latest_received > 0);
    }
}

#[test]
fn everything_arrives_after_an_outage_on_the_moon_earth_link() {
    let (outage_start, outage_end) = (30_000, 60_000);
    let link = EmulatorConfig::moon_earth().with_seed(42).with_outage(outage_start, outage_end);
    let scenario = Scenario {
        rate_bytes_per_s: link.bandwidth_bytes_per_s,
        link,
        sources: vec![
            Source { stream: Stream::Constraints, from: Side::A, total: 600, period_ms: 150, next: 0 },
            Source { stream: Stream::Chunks, from: Side::A, total: 150, period_ms: 600, next: 0 },
            Source { stream: Stream::Commands, from: Side::B, total: 40, period_ms: 2_000, next: 0 },
        ],
        latest_period_ms: 1_000,
        latest_until_ms: 90_000,
        deadline_ms: 400_000,
        initial_rto_ms: 1_000,
    };
    let outcome = run(&scenario);
    println!(
        "moon–earth: done at {} ms, {} retransmissions, {} duplicates, srtt {:?} ms, {} wire bytes",
        outcome.finished_ms, outcome.retransmissions, outcome.duplicates, outcome.robot_srtt_ms, outcome.wire_bytes
    );
    // Traffic offered during the outage arrives after it.
    for stream in Stream::ALL {
        let at = &outcome.received_at[stream.index()];
        let after = at.iter().filter(|&&t| t >= outage_end).count();
        let during = at.iter().filter(|&&t| (outage_start + 2_100..outage_end).contains(&t)).count();
        println!("{stream:?}: {} delivered, {after} after the outage, {during} during it", at.len());
        assert_eq!(during, 0, "{stream:?} delivered during the outage");
        assert!(after > 0);
    }
    let first_after = outcome.received_at.iter().flatten().filter(|&&t| t >= outage_end).min().unwrap();
    println!("first delivery {} ms after the outage ended", first_after - outage_end);
    // Retransmission resumes within the RTO cap (30 s) plus a one-way trip.
    assert!(first_after - outage_end <= 32_100);
    let srtt = outcome.robot_srtt_ms.unwrap();
    assert!((4_000..4_600).contains(&srtt), "srtt {srtt} ms");
}
