//! The comms node's ground link without sockets: what goes to the ground (own graph inputs and
//! submaps, not the peers'), Telemetry v2's bytes per class, and a truthful acknowledgement for
//! every command kind (SetMode, waypoint, parameter, resend, recording).

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use msgs::{FilterStateMsg, Pose, TeamHeader};
use onboard::nodes::comms::{CommsConfig, CommsNode, LinkConfig, LinkId};
use onboard::nodes::{Message, Node, NodeError, Outbox};
use protocol::frame::Framing;
use protocol::message::*;
use protocol::{AnyMessage, AuthKey, Cov6, MAX_PACKET_BYTES, NodeId, NodeRef, Pose3, RobotId, SubmapId};

const GROUND: LinkId = LinkId(0);
const TEAM: LinkId = LinkId(1);
const KEY: &[u8; 32] = b"comms ground test key: 32 bytes!";

struct Sink;

impl Outbox for Sink {
    fn publish(&mut self, _: Message<'_>) -> Result<(), NodeError> {
        Ok(())
    }
}

fn node() -> CommsNode {
    let framing = Framing::Datagram { mtu: 1200 };
    let links = vec![
        LinkConfig::ground(GROUND, framing, 1_000_000),
        LinkConfig::team(TEAM, "radio", framing, 1_000_000, vec![RobotId(2)]),
    ];
    let mut config = CommsConfig::new(RobotId(1), links);
    config.auth_key = Some(AuthKey::from_bytes(KEY).unwrap());
    CommsNode::new(config).unwrap()
}

/// A broadcast from the mapper, as sent by `source` (the own mapper uses the own node id).
fn broadcast(node: &mut CommsNode, now_ns: u64, source: u8, message: &AnyMessage) {
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let len = protocol::encode(message, NodeId(source), NodeId::BROADCAST, 0, &mut buf).unwrap();
    let header =
        TeamHeader { stamp_ns: now_ns, robot_id: TeamHeader::BROADCAST, message_key: u32::from(message.key().0) };
    node.on_message(Message::ToComms(&header, &buf[..len]), &mut Sink).unwrap();
}

fn ground_output(node: &mut CommsNode, now_ns: u64) -> Vec<AnyMessage> {
    let mut messages = Vec::new();
    while let Some(packet) = node.poll_transmit_on(now_ns, GROUND) {
        messages.push(protocol::decode(packet).unwrap().message);
    }
    messages
}

fn submap(robot: u8, index: u32, chunks: u16) -> Vec<AnyMessage> {
    let id = SubmapId { robot: RobotId(robot), index };
    let mut out = vec![AnyMessage::from(SubmapHeader {
        submap: id,
        started_stamp_ns: 0,
        finished_stamp_ns: 1,
        switch: None,
        encoding: SubmapEncoding(1),
        payload_bytes: u32::from(chunks) * 100,
        chunk_count: chunks,
        payload_crc32: 0,
    })];
    for i in 0..chunks {
        out.push(AnyMessage::from(SubmapChunk {
            submap: id,
            index: i,
            data: TryFrom::try_from(&[i as u8; 100][..]).unwrap(),
        }));
    }
    out
}

fn constraint(robot: u8) -> AnyMessage {
    AnyMessage::from(Constraint {
        id: ConstraintId { robot: RobotId(robot), seq: 1 },
        kind: ConstraintKind::RobotDetection,
        stamp_ns: 5,
        from: NodeRef::SubmapOrigin(SubmapId { robot: RobotId(robot), index: 0 }),
        to: NodeRef::RobotPose { robot: RobotId(3 - robot), stamp_ns: 5 },
        t_from_to: Pose3::IDENTITY,
        covariance: Cov6::from_std_devs([0.05; 6]),
    })
}

fn filter_state(stamp_ns: u64) -> FilterStateMsg {
    FilterStateMsg {
        stamp_ns,
        t_local_body: Pose { translation_m: [1.0, 2.0, 0.0], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] },
        v_local_mps: [0.0; 3],
        accel_bias_mps2: [0.0; 3],
        gyro_bias_radps: [0.0; 3],
        pose_covariance: [0.0; 36],
        imu_received: 1,
        imu_lost: 0,
        frame_id: 0,
        status: FilterStateMsg::RUNNING,
        last_vo_capture_ns: FilterStateMsg::NEVER,
    }
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

#[test]
fn own_graph_inputs_and_submaps_go_to_the_ground_and_the_peers_do_not() {
    let mut node = node();
    let t = 1_000_000_000;
    let mut own = submap(1, 0, 3);
    own.push(constraint(1));
    own.push(pose(1, t));
    own.push(AnyMessage::from(MatchAttempt {
        first: SubmapId { robot: RobotId(1), index: 0 },
        second: SubmapId { robot: RobotId(2), index: 0 },
        by: RobotId(1),
        outcome: MatchOutcome::Rejected,
    }));
    for message in &own {
        broadcast(&mut node, t, 1, message);
    }
    // A peer's data relayed by the mapper (source robot 2) stays off the ground link.
    for message in submap(2, 0, 2).iter().chain([&constraint(2)]) {
        broadcast(&mut node, t, 2, message);
    }
    let sent = ground_output(&mut node, t);
    let count = |f: &dyn Fn(&AnyMessage) -> bool| sent.iter().filter(|m| f(m)).count();
    assert_eq!(count(&|m| matches!(m, AnyMessage::SubmapHeader(h) if h.submap.robot == RobotId(1))), 1);
    assert_eq!(count(&|m| matches!(m, AnyMessage::SubmapChunk(c) if c.submap.robot == RobotId(1))), 3);
    assert_eq!(count(&|m| matches!(m, AnyMessage::Constraint(c) if c.id.robot == RobotId(1))), 1);
    assert_eq!(count(&|m| matches!(m, AnyMessage::MatchAttempt(_))), 1);
    assert_eq!(count(&|m| matches!(m, AnyMessage::PoseEstimate(_))), 1);
    assert_eq!(count(&|m| matches!(m, AnyMessage::SubmapHeader(h) if h.submap.robot == RobotId(2))), 0);
    assert_eq!(count(&|m| matches!(m, AnyMessage::Constraint(c) if c.id.robot == RobotId(2))), 0);
    // Priorities: the pose leaves before the constraint, the constraint before bulk.
    let position = |f: &dyn Fn(&AnyMessage) -> bool| sent.iter().position(f).unwrap();
    let pose_at = position(&|m| matches!(m, AnyMessage::PoseEstimate(_)));
    let constraint_at = position(&|m| matches!(m, AnyMessage::Constraint(_)));
    let bulk_at = position(&|m| matches!(m, AnyMessage::SubmapHeader(_)));
    assert!(constraint_at < pose_at && pose_at < bulk_at, "{sent:?}");
    assert_eq!(node.stats().ground_sent_by_class["SubmapChunk"].packets, 3);

    // With the mapper sending poses, the feed's filter pose stays out; telemetry v2 carries the
    // bytes per class of everything sent so far.
    node.on_message(Message::FilterState(&filter_state(t)), &mut Sink).unwrap();
    node.on_tick(t, &mut Sink).unwrap();
    let sent = ground_output(&mut node, t);
    let telemetry = sent
        .iter()
        .find_map(|m| match m {
            AnyMessage::Telemetry(t) => Some(t.clone()),
            _ => None,
        })
        .expect("telemetry on the tick");
    assert!(!sent.iter().any(|m| matches!(m, AnyMessage::PoseEstimate(_))));
    let stats = node.stats();
    for class in &telemetry.classes {
        let name = AnyMessage::name_of(MessageKey(class.message_key)).unwrap();
        assert_eq!(class.tx_bytes, stats.sent_by_class[name].wire_bytes, "{name}");
        assert_eq!(u64::from(class.tx_packets), stats.sent_by_class[name].packets, "{name}");
    }
    assert!(telemetry.classes.iter().any(|c| c.message_key == 0x31 && c.tx_packets >= 3));

    // Without a mapper pose for over 3 s, the filter's pose goes with the telemetry.
    let later = t + 4_000_000_000;
    node.on_message(Message::FilterState(&filter_state(later)), &mut Sink).unwrap();
    node.on_tick(later, &mut Sink).unwrap();
    let sent = ground_output(&mut node, later);
    assert!(sent.iter().any(|m| matches!(m, AnyMessage::PoseEstimate(p) if p.stamp_ns == later)), "{sent:?}");
}

#[test]
fn every_command_kind_gets_a_truthful_ack() {
    let mut node = node();
    let key = AuthKey::from_bytes(KEY).unwrap();
    let t = 1_000_000_000;
    for message in submap(1, 4, 3) {
        broadcast(&mut node, t, 1, &message);
    }
    let _ = ground_output(&mut node, t);
    let mut counter: u32 = 0;
    let mut command = |node: &mut CommsNode, id: u32, kind: CommandKind| -> (CommandOutcome, Vec<AnyMessage>) {
        counter += 1;
        let message = AnyMessage::from(Command { target: RobotId(1), id, kind });
        let mut buf = [0u8; MAX_PACKET_BYTES];
        let len = protocol::encode_authenticated(
            &message,
            NodeId::GROUND,
            NodeId(1),
            // The channel's sequence numbers start at 0; the auth counters must only increase.
            counter - 1,
            u64::from(counter),
            &key,
            &mut buf,
        )
        .unwrap();
        // Time moves on, so that the rate cap lets the previous resend's burst drain.
        let now_ns = t + u64::from(counter) * 100_000_000;
        node.handle_packet(now_ns, GROUND, &buf[..len]);
        let sent = ground_output(node, now_ns);
        let ack = sent
            .iter()
            .find_map(|m| match m {
                AnyMessage::CommandAck(a) if a.command_id == id => Some(*a),
                _ => None,
            })
            .unwrap_or_else(|| panic!("no ack for command {id}: {sent:?}"));
        (ack.outcome, sent)
    };
    let param = |name: &str, value| CommandKind::SetParameter { name: ParamName::from(name), value };
    let waypoint = CommandKind::GoToWaypoint { x_m: 3.0, y_m: -1.0, z_m: 0.0, speed_mps: 0.2 };

    assert_eq!(
        command(&mut node, 1, param("comms.telemetry_period_ms", ParamValue::Int(500))).0,
        CommandOutcome::Executed
    );
    assert_eq!(node.telemetry_period_ns(), 500_000_000);
    assert_eq!(
        command(&mut node, 2, param("comms.telemetry_period_ms", ParamValue::Int(5))).0,
        CommandOutcome::Invalid
    );
    assert_eq!(command(&mut node, 3, param("mapper.voxel_m", ParamValue::Float(0.1))).0, CommandOutcome::Invalid);
    assert_eq!(node.telemetry_period_ns(), 500_000_000);

    // A resend of the whole submap queues its header and chunks again; a range only those.
    let resend = |chunks| CommandKind::RequestResend { submap: SubmapId { robot: RobotId(1), index: 4 }, chunks };
    let (outcome, sent) = command(&mut node, 4, resend(None));
    assert_eq!(outcome, CommandOutcome::Accepted);
    assert_eq!(sent.iter().filter(|m| matches!(m, AnyMessage::SubmapHeader(_))).count(), 1);
    assert_eq!(sent.iter().filter(|m| matches!(m, AnyMessage::SubmapChunk(_))).count(), 3);
    let (outcome, sent) = command(&mut node, 5, resend(Some((1, 2))));
    assert_eq!(outcome, CommandOutcome::Accepted);
    let chunks: Vec<u16> = sent
        .iter()
        .filter_map(|m| match m {
            AnyMessage::SubmapChunk(c) => Some(c.index),
            _ => None,
        })
        .collect();
    assert_eq!(chunks, [1, 2]);
    assert_eq!(command(&mut node, 6, resend(Some((2, 9)))).0, CommandOutcome::Invalid);
    let peer_submap = CommandKind::RequestResend { submap: SubmapId { robot: RobotId(2), index: 0 }, chunks: None };
    assert_eq!(command(&mut node, 7, peer_submap).0, CommandOutcome::Invalid);

    // A waypoint is kept and reported as accepted, never as executed; in Safe mode refused.
    assert_eq!(command(&mut node, 8, waypoint.clone()).0, CommandOutcome::Accepted);
    assert_eq!(node.last_waypoint().map(|w| (w.command_id, w.x_m)), Some((8, 3.0)));
    assert_eq!(command(&mut node, 9, CommandKind::SetMode(Mode::Safe)).0, CommandOutcome::Executed);
    assert_eq!(command(&mut node, 10, waypoint).0, CommandOutcome::Refused);
    assert_eq!(node.last_waypoint().map(|w| w.command_id), Some(8));
    let label = ParamName::from("survey");
    assert_eq!(command(&mut node, 11, CommandKind::StartRecording { label }).0, CommandOutcome::Refused);
    assert_eq!(command(&mut node, 12, CommandKind::StopRecording).0, CommandOutcome::Refused);

    let c = node.stats().commands;
    assert_eq!((c.executed, c.accepted, c.invalid, c.refused), (2, 3, 4, 3));
    assert_eq!((c.waypoints, c.resends, c.acks_sent), (1, 2, 12));
}

#[test]
fn the_ground_key_file_and_rate_are_validated_with_the_configuration() {
    use std::os::unix::fs::PermissionsExt;
    let dir = std::env::temp_dir().join(format!("comms-ground-config-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let key = dir.join("ground.key");
    std::fs::write(&key, KEY.iter().map(|b| format!("{b:02x}")).collect::<String>()).unwrap();
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o600)).unwrap();
    let toml = |extra: &str| {
        format!(
            "[robot]\nid = 0\n[driver]\nreplay_path = \"data/x\"\n[link]\nground_feed = \"127.0.0.1:7700\"\n{extra}\n"
        )
    };
    let config = onboard::config::RoverConfig::from_toml_str(&toml(&format!("ground_key_file = {:?}", key))).unwrap();
    assert_eq!(config.link.ground_key_file.as_deref(), Some(key.as_path()));
    assert_eq!(config.link.ground_bandwidth_bytes_per_s, onboard::nodes::comms::GROUND_RATE_BYTES_PER_S);

    let missing = dir.join("missing.key");
    let error = onboard::config::RoverConfig::from_toml_str(&toml(&format!("ground_key_file = {missing:?}")))
        .unwrap_err()
        .to_string();
    assert!(error.contains("link.ground_key_file") && error.contains("missing.key"), "{error}");
    std::fs::set_permissions(&key, std::fs::Permissions::from_mode(0o644)).unwrap();
    let error = onboard::config::RoverConfig::from_toml_str(&toml(&format!("ground_key_file = {key:?}")))
        .unwrap_err()
        .to_string();
    // The key must not leak into the message. One byte's hex ("63") is too short a witness: the
    // directory name carries the process id, which may contain it; four bytes hold letters.
    let key_prefix: String = KEY[..4].iter().map(|b| format!("{b:02x}")).collect();
    assert!(error.contains("link.ground_key_file") && !error.contains(&key_prefix), "{error}");
    let error = onboard::config::RoverConfig::from_toml_str(&toml("ground_bandwidth_bytes_per_s = 10")).unwrap_err();
    assert!(error.to_string().contains("link.ground_bandwidth_bytes_per_s"), "{error}");
    std::fs::remove_dir_all(&dir).ok();
}

fn hazards_msg(stamp_ns: u64, cells: &[[i16; 2]]) -> Box<msgs::HazardCellsMsg> {
    let mut msg = Box::new(msgs::HazardCellsMsg {
        stamp_ns,
        t_local_body: Pose { translation_m: [0.01, 0.01, 0.0], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] },
        frame_id: 2,
        cell_size_m: 0.05,
        origin_cell: [0, 0],
        count: cells.len() as u32,
        omitted: 0,
        cells: [[0; 2]; msgs::HAZARD_CELLS_MAX],
    });
    msg.cells[..cells.len()].copy_from_slice(cells);
    msg
}

fn hazards_sent(node: &mut CommsNode, now_ns: u64, team: &mut Vec<AnyMessage>) -> Vec<HazardCells> {
    node.on_tick(now_ns, &mut Sink).unwrap();
    while let Some(packet) = node.poll_transmit_on(now_ns, TEAM) {
        team.push(protocol::decode(packet).unwrap().message);
    }
    ground_output(node, now_ns)
        .into_iter()
        .filter_map(|m| match m {
            AnyMessage::HazardCells(h) => Some(h),
            _ => None,
        })
        .collect()
}

#[test]
fn hazard_cells_go_to_the_ground_at_most_once_per_period_newest_first() {
    let mut node = node();
    assert!(node.subscriptions().contains(&onboard::nodes::Topic::Hazards));
    let s = 1_000_000_000;
    let mut team = Vec::new();
    // Two fine cells 1 m ahead that merge into one wire cell, one 0.5 m to the left.
    let first = hazards_msg(s, &[[20, 0], [19, 0], [0, 10]]);
    node.on_message(Message::Hazards(&first), &mut Sink).unwrap();
    let sent = hazards_sent(&mut node, s, &mut team);
    assert_eq!(sent.len(), 1);
    assert_eq!((sent[0].robot, sent[0].stamp_ns, sent[0].submap.index), (RobotId(1), s, 2));
    assert_eq!(sent[0].cells.as_slice(), &[[0, 5], [10, 0]]);

    // Within the 2 s period nothing goes, and a newer picture replaces the waiting one.
    for (t, stamp) in [(s + s / 2, 1), (2 * s, 2), (2 * s + s / 2, 3)] {
        node.on_message(Message::Hazards(&hazards_msg(stamp, &[[stamp as i16, 0]])), &mut Sink).unwrap();
        assert!(hazards_sent(&mut node, t, &mut team).is_empty(), "at {t} ns");
    }
    let sent = hazards_sent(&mut node, 3 * s, &mut team);
    assert_eq!(sent.iter().map(|h| h.stamp_ns).collect::<Vec<_>>(), [3]);
    // Nothing new, nothing sent; the team link never carries them.
    assert!(hazards_sent(&mut node, 6 * s, &mut team).is_empty());
    assert!(!team.is_empty() && !team.iter().any(|m| matches!(m, AnyMessage::HazardCells(_))));

    // A picture without a pose is counted, not sent.
    let mut broken = hazards_msg(7 * s, &[[1, 1]]);
    broken.t_local_body.rotation_wxyz = [0.0; 4];
    node.on_message(Message::Hazards(&broken), &mut Sink).unwrap();
    assert!(hazards_sent(&mut node, 7 * s, &mut team).is_empty());
    assert_eq!(node.stats().hazard_rejections, 1);
    assert_eq!(node.stats().ground_sent_by_class["HazardCells"].packets, 2);
}
