//! The lockstep mission's ground link against a real UDP socket acting as the ground station:
//! Telemetry v2 with bytes per class and measured values (the robots' real mode, CPU, memory, VO
//! age), the robots' poses and submap headers arrive; an authenticated `SetMode` is executed and
//! acknowledged; `OUT/ground_feed.log` holds exactly the
//! packets that crossed the link, both ways.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::net::{SocketAddr, UdpSocket};
use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use hal::link::MAX_LINK_PACKET_BYTES;
use protocol::delivery::{Endpoint, EndpointConfig};
use protocol::frame::Framing;
use protocol::frame::datagram::{Reassembler, Segmenter};
use protocol::message::{Command, CommandAck, CommandKind, CommandOutcome, Mode, Telemetry};
use protocol::{AnyMessage, AuthKey, MAX_PACKET_BYTES, NodeId, RobotId};
use sil::mission::{self, MissionOptions, Runner};

const KEY: &[u8; 32] = b"mission ground key, 32 bytes ok!";
const COMMAND_ID: u32 = 7;

fn key_file(dir: &Path) -> PathBuf {
    let path = dir.join("ground.key");
    let hex: String = KEY.iter().map(|b| format!("{b:02x}")).collect();
    std::fs::write(&path, hex + "\n").unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o600)).unwrap();
    path
}

/// A minimal ground station: a UDP socket, `hal::udp` framing and the protocol endpoint.
struct Station {
    socket: UdpSocket,
    mission: Option<SocketAddr>,
    reassembler: Box<Reassembler<4, MAX_LINK_PACKET_BYTES>>,
    segmenter: Segmenter,
    endpoint: Box<Endpoint>,
    key: AuthKey,
    start: Instant,
    /// Every packet received, per sending robot node, in arrival order.
    received: BTreeMap<u8, Vec<Vec<u8>>>,
    /// Every packet sent, per destination robot node.
    sent: BTreeMap<u8, Vec<Vec<u8>>>,
    telemetry: Vec<Telemetry>,
    poses: BTreeMap<u8, usize>,
    submap_headers: usize,
    acks: Vec<CommandAck>,
    command_sent: bool,
}

impl Station {
    fn new() -> Station {
        let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
        socket.set_read_timeout(Some(Duration::from_millis(2))).unwrap();
        let framing = Framing::Datagram { mtu: 1200 };
        let config =
            EndpointConfig::new(NodeId::GROUND, framing, 200_000, 8 * EndpointConfig::min_burst_bytes(framing));
        Station {
            socket,
            mission: None,
            reassembler: Box::new(Reassembler::new(2_000)),
            segmenter: Segmenter::new(1200).unwrap(),
            endpoint: Box::new(Endpoint::new(config).unwrap()),
            key: AuthKey::from_bytes(KEY).unwrap(),
            start: Instant::now(),
            received: BTreeMap::new(),
            sent: BTreeMap::new(),
            telemetry: Vec::new(),
            poses: BTreeMap::new(),
            submap_headers: 0,
            acks: Vec::new(),
            command_sent: false,
        }
    }

    fn now_ms(&self) -> u64 {
        self.start.elapsed().as_millis() as u64
    }

    fn pump(&mut self) {
        let mut datagram = [0u8; 2048];
        while let Ok((len, from)) = self.socket.recv_from(&mut datagram) {
            self.mission = Some(from);
            let now_ms = self.now_ms();
            let Ok(Some(packet)) = self.reassembler.push(now_ms, 0, &datagram[..len]) else { continue };
            let packet = packet.to_vec();
            let (header, _) = protocol::codec::decode_header(&packet).unwrap();
            self.received.entry(header.source.0).or_default().push(packet.clone());
            let _ = self.endpoint.handle_packet(now_ms, &packet);
            while let Some(delivered) = self.endpoint.poll_deliver() {
                match delivered.message {
                    AnyMessage::Telemetry(t) => self.telemetry.push(t),
                    AnyMessage::PoseEstimate(p) => *self.poses.entry(p.robot.0).or_default() += 1,
                    AnyMessage::SubmapHeader(_) => self.submap_headers += 1,
                    AnyMessage::CommandAck(a) => self.acks.push(a),
                    _ => {}
                }
            }
        }
        // Command robot 1 once it is heard from.
        if !self.command_sent && self.telemetry.iter().any(|t| t.robot == RobotId(1)) {
            let command = Command { target: RobotId(1), id: COMMAND_ID, kind: CommandKind::SetMode(Mode::Safe) };
            let now_ms = self.now_ms();
            self.endpoint.send_authenticated(now_ms, NodeId(1), &AnyMessage::from(command), 1, &self.key).unwrap();
            self.command_sent = true;
        }
        let Some(mission) = self.mission else { return };
        let mut buf = [0u8; MAX_PACKET_BYTES];
        let now_ms = self.now_ms();
        while let Some(len) = self.endpoint.poll_transmit(now_ms, &mut buf) {
            let (header, _) = protocol::codec::decode_header(&buf[..len]).unwrap();
            self.sent.entry(header.destination.0).or_default().push(buf[..len].to_vec());
            let socket = &self.socket;
            self.segmenter
                .segment(&buf[..len], |d| {
                    socket.send_to(d, mission).unwrap();
                })
                .unwrap();
        }
    }
}

#[test]
fn a_udp_ground_station_gets_the_feed_commands_robots_and_the_log_holds_the_same_packets() {
    let dir = std::env::temp_dir().join(format!("onboard-ground-link-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut station = Station::new();
    let options = MissionOptions {
        robots: 2,
        duration_s: 20.0,
        seed: 3,
        downscale: 4,
        out: dir.join("out"),
        runner: Runner::Lockstep,
        feed: Some(station.socket.local_addr().unwrap()),
        ground_key: Some(key_file(&dir)),
        // The rovers drive about a metre in 30 s: short submaps, so that some are finished.
        submap_max_distance_m: Some(0.3),
        ..MissionOptions::default()
    };
    let mission = {
        let options = options.clone();
        std::thread::spawn(move || mission::run(&options))
    };
    while !mission.is_finished() {
        station.pump();
    }
    let report = mission.join().unwrap().unwrap();
    // The last datagrams are on their way.
    let drain = Instant::now();
    while drain.elapsed() < Duration::from_millis(300) {
        station.pump();
    }

    // Telemetry v2 from both robots, with the bytes per message class.
    for robot in [RobotId(1), RobotId(2)] {
        let last = station.telemetry.iter().rev().find(|t| t.robot == robot).expect("telemetry from every robot");
        let keys: Vec<u8> = last.classes.iter().map(|c| c.message_key).collect();
        assert!(keys.windows(2).all(|w| w[0] < w[1]), "classes in key order: {keys:?}");
        for key in [0x01, 0x11, 0x10] {
            let class = last.classes.iter().find(|c| c.message_key == key).unwrap_or_else(|| panic!("class {key:#x}"));
            assert!(class.tx_bytes > 0 && class.tx_packets > 0, "{class:?}");
        }
        assert!(station.poses.get(&robot.0).copied().unwrap_or(0) >= 5, "poses of {robot:?}: {:?}", station.poses);
        // Measured, not placeholders: the nodes' CPU (handler time per second of sensor time),
        // the process's memory and the board's, a VO result a moment ago.
        let r = &last.resources;
        assert!(r.cpu_permille > 0 && r.mem_used_kib > 0 && r.mem_total_kib >= r.mem_used_kib, "{r:?}");
        assert!(last.filter.vo_age_ms < 2_000, "VO age {} ms", last.filter.vo_age_ms);
        assert!(last.tasks.is_empty(), "the lockstep runner has no tasks to time: {:?}", last.tasks);
    }
    assert!(station.submap_headers >= 1, "no SubmapHeader reached the ground");
    // The command was executed, acknowledged, and robot 1's later telemetry reports the mode.
    assert!(station.command_sent);
    let ack = station.acks.iter().find(|a| a.command_id == COMMAND_ID).expect("the SetMode is acknowledged");
    assert_eq!((ack.robot, ack.outcome), (RobotId(1), CommandOutcome::Executed));
    assert_eq!(station.telemetry.iter().rev().find(|t| t.robot == RobotId(1)).unwrap().mode, Mode::Safe);
    // The other one reports what it is doing: exploring on its own.
    assert_eq!(station.telemetry.iter().rev().find(|t| t.robot == RobotId(2)).unwrap().mode, Mode::Autonomous);

    // The recording holds exactly what crossed the link: downlink per robot in order, and the
    // station's packets (acks, the command) as the uplink of the addressed robot.
    let log = hal::feedlog::read_feed_log(options.out.join("ground_feed.log")).unwrap();
    assert_eq!(log.ignored_bytes, 0);
    let mut down: BTreeMap<u8, Vec<Vec<u8>>> = BTreeMap::new();
    let mut up: BTreeMap<u8, Vec<Vec<u8>>> = BTreeMap::new();
    let mut last_ns = 0;
    for record in &log.records {
        assert!(record.recv_ns >= last_ns, "mission time never goes back");
        last_ns = record.recv_ns;
        let (header, _) = protocol::codec::decode_header(&record.packet).unwrap();
        if header.source == NodeId::GROUND {
            assert_eq!(header.destination.0, record.source);
            up.entry(record.source).or_default().push(record.packet.clone());
        } else {
            assert_eq!(header.source.0, record.source, "source is the sending robot");
            down.entry(record.source).or_default().push(record.packet.clone());
        }
    }
    assert!(last_ns <= 20_000_000_000);
    assert_eq!(down, station.received, "the log's downlink is what the station received");
    assert_eq!(up, station.sent, "the log's uplink is what the station sent");
    // The report's class bytes include the ground link's submap traffic.
    for robot in &report.robots {
        assert!(robot.bytes_sent_by_class.get("Telemetry").copied().unwrap_or(0) > 0);
    }
    std::fs::remove_dir_all(&dir).ok();
}
