//! The engine on real sockets: a UDP "robot" sends to the bound address and the published view
//! shows it; the ground's transport acks come back; replay through the engine.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod model_common;

use std::net::UdpSocket;
use std::sync::Arc;
use std::time::{Duration, Instant};

use groundstation::engine::Engine;
use groundstation::model::ModelConfig;
use groundstation::view::{TeamView, UiAction};
use hal::link::Link;
use model_common::*;
use protocol::message::Mode;
use protocol::{AnyMessage, MAX_PACKET_BYTES, NodeId, decode, encode};

fn config() -> ModelConfig {
    ModelConfig { auth_key: None, source: "test".into() }
}

fn wait_for(engine: &Engine, what: &str, pred: impl Fn(&TeamView) -> bool) -> Arc<TeamView> {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let view = engine.view();
        if pred(&view) {
            return view;
        }
        assert!(Instant::now() < deadline, "timed out waiting for {what}: {view:#?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn udp_packets_reach_the_view_and_acks_come_back() {
    let engine = Engine::live("udp://127.0.0.1:0".parse().unwrap(), config()).unwrap();
    let addr = engine.local_addr().unwrap();

    // A lockstep-style feed: whole packets, one per datagram.
    let robot = UdpSocket::bind("127.0.0.1:0").unwrap();
    robot.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut buf = vec![0u8; MAX_PACKET_BYTES];
    let len = encode(&telemetry(3, 0, 0).into(), NodeId(3), NodeId::GROUND, 0, &mut buf).unwrap();
    robot.send_to(&buf[..len], addr).unwrap();
    let len = encode(&pose(3, 0, 0, &planar(1.0, 2.0, 0.0)).into(), NodeId(3), NodeId::GROUND, 1, &mut buf).unwrap();
    robot.send_to(&buf[..len], addr).unwrap();
    let view = wait_for(&engine, "robot 3", |v| v.robots.get(&3).is_some_and(|r| r.mode.is_some()));
    assert_eq!(view.robots[&3].mode, Some(Mode::Autonomous));
    wait_for(&engine, "robot 3's pose", |v| v.robots[&3].t_ref_body.is_some());

    // A reliable message is acknowledged to the address it came from.
    let mut sim = SimRobot::new(3, None);
    let header = submap_messages(&patch_submap(3, 0, 1.0, 0.0), None).remove(0);
    sim.send(0, header);
    for packet in sim.transmit(0) {
        robot.send_to(&packet, addr).unwrap();
    }
    let (n, _) = robot.recv_from(&mut buf).expect("the ground acknowledges");
    let ack = decode(&buf[..n]).unwrap();
    assert!(matches!(ack.message, AnyMessage::Ack(_)), "{ack:?}");
    assert_eq!((ack.header.source, ack.header.destination), (NodeId::GROUND, NodeId(3)));

    // A hal UDP link (fragment framing), as the process runner's robots use.
    let mut link = hal::udp::UdpLink::bind("127.0.0.1:0").unwrap().with_peers([addr]);
    let len = encode(&telemetry(4, 0, 0).into(), NodeId(4), NodeId::GROUND, 0, &mut buf).unwrap();
    link.send(&buf[..len]).unwrap();
    let view = wait_for(&engine, "robot 4", |v| v.robots.contains_key(&4));
    assert!(view.link.packets_received >= 4);
    assert!(view.source.contains("test"));

    // Garbage is counted, not fatal.
    robot.send_to(b"\x07garbage", addr).unwrap();
    wait_for(&engine, "the rejected datagram", |v| v.link.packets_rejected >= 1);
    drop(engine);
}

/// `--connect serial://PATH`: the engine on one end of a real pseudo-terminal pair, a robot's
/// `hal::serial::SerialLink` (COBS + CRC frames, as on a serial radio) on the other.
#[test]
fn serial_pty_carries_telemetry_submaps_and_authenticated_commands() {
    let (master, slave) = serialport::TTYPort::pair().expect("cannot open a pty pair");
    let path = serialport::SerialPort::name(&slave).expect("the pty's device path");
    let spec: groundstation::net::LinkSpec = format!("serial://{path}?baud=115200").parse().unwrap();
    let engine = Engine::live(spec, ModelConfig { auth_key: Some(key()), source: "pty".into() }).unwrap();
    assert!(engine.local_addr().is_none());
    let mut link = hal::serial::SerialLink::from_serialport(master);
    let mut robot = SimRobot::new(2, Some(key()));
    let start = Instant::now();
    let pump = |robot: &mut SimRobot, link: &mut hal::serial::SerialLink<serialport::TTYPort>| {
        let now_ms = start.elapsed().as_millis() as u64;
        robot.transmit_over(link, now_ms);
        robot.receive_over(link, now_ms, Duration::from_millis(5))
    };

    // Telemetry, a pose and a whole submap (header + reliable chunks, acked over the line).
    robot.send(0, telemetry(2, 0, 0));
    robot.send(0, pose(2, 0, 0, &planar(3.0, -1.0, 0.2)));
    for message in submap_messages(&patch_submap(2, 0, 2.0, 0.5), None) {
        robot.send(0, message);
    }
    let deadline = Instant::now() + Duration::from_secs(10);
    while !engine.view().robots.get(&2).is_some_and(|r| r.submaps.iter().any(|s| s.bounds_submap_m.is_some())) {
        assert!(Instant::now() < deadline, "the submap did not arrive: {:#?}", engine.view());
        pump(&mut robot, &mut link);
    }
    let view = engine.view();
    assert_eq!(view.robots[&2].mode, Some(Mode::Autonomous));
    assert!(view.robots[&2].t_ref_body.is_some());
    assert!(view.source.contains("pty"));

    // A command from the operator crosses the line authenticated; the ack comes back.
    engine.act(UiAction::SetMode { robot: 2, mode: Mode::Idle }).unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut executed = 0;
    loop {
        assert!(Instant::now() < deadline, "no acknowledgement: {:#?}", engine.view().commands);
        for command in pump(&mut robot, &mut link) {
            assert_eq!(command.kind, protocol::message::CommandKind::SetMode(Mode::Idle));
            executed += 1;
        }
        if engine.view().commands.first().is_some_and(|c| {
            matches!(
                c.state,
                groundstation::view::CommandState::Acknowledged {
                    outcome: protocol::message::CommandOutcome::Executed,
                    ..
                }
            )
        }) {
            break;
        }
    }
    assert_eq!(executed, 1);
    drop(engine);
    drop(slave);
}

#[test]
fn the_engine_replays_a_recorded_mission() {
    let dir = std::env::temp_dir().join(format!("gs-engine-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut writer = hal::feedlog::FeedLogWriter::create(dir.join("ground_feed.log")).unwrap();
    let mut buf = vec![0u8; MAX_PACKET_BYTES];
    for s in 0..20u64 {
        let t = s * 1_000_000_000;
        let len =
            encode(&pose(1, t, 0, &planar(s as f64, 0.0, 0.0)).into(), NodeId(1), NodeId::GROUND, s as u32, &mut buf)
                .unwrap();
        writer.append(t, 1, &buf[..len]).unwrap();
    }
    drop(writer);
    let engine = Engine::replay(&dir, config()).unwrap();
    engine.act(UiAction::ReplayPlay(false)).unwrap();
    engine.act(UiAction::ReplaySeek(19_000_000_000)).unwrap();
    let view =
        wait_for(&engine, "the end", |v| v.replay.is_some_and(|r| r.position_ns == 19_000_000_000 && !r.playing));
    assert_eq!(view.robots[&1].trajectory_ref_m.len(), 20);
    assert!(!view.can_command);
    engine.act(UiAction::ReplaySeek(5_000_000_000)).unwrap();
    let view = wait_for(&engine, "5 s", |v| v.replay.is_some_and(|r| r.position_ns == 5_000_000_000));
    assert_eq!(view.robots[&1].trajectory_ref_m.len(), 6);
    engine.act(UiAction::SetMode { robot: 1, mode: Mode::Idle }).unwrap();
    wait_for(&engine, "the refusal", |v| v.notices.iter().any(|n| n.contains("replaying")));
    drop(engine);

    let missing = Engine::replay(&dir.join("absent"), config()).unwrap_err().to_string();
    assert!(missing.contains("absent/ground_feed.log"), "{missing}");
    std::fs::remove_dir_all(&dir).ok();
}
