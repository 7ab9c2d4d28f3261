//! The team model fed the packets robots send: trajectories, map, connection, staleness,
//! authenticated commands through outages, and replay of a recorded feed.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod model_common;

use groundstation::model::{ActionError, ModelConfig, TeamModel};
use groundstation::replay::Replay;
use groundstation::view::{CommandState, EdgeKind, Staleness, UiAction};
use hal::feedlog::FeedLogWriter;
use model_common::*;
use nalgebra::Point3;
use protocol::message::{CommandAck, CommandKind, CommandOutcome, MatchAttempt, MatchOutcome, Mode};
use protocol::{AnyMessage, NodeId, RobotId, SubmapId};

const S: u64 = 1_000_000_000;

fn model(key: bool) -> TeamModel {
    TeamModel::new(ModelConfig { auth_key: key.then(key_fn), source: "test".into() })
}

fn key_fn() -> protocol::AuthKey {
    key()
}

/// The relative pose the test's match claims between robot 1's and robot 2's first submaps.
fn t_1_2() -> nalgebra::Isometry3<f64> {
    planar(10.0, 5.0, std::f64::consts::FRAC_PI_2)
}

/// Two robots for `seconds`: telemetry and poses every second (robot 2 goes silent after
/// `robot2_until_s`), robot 1's first submap after 2 s, the match after `match_at_s`. Returns every
/// packet that reached the ground with its receive time.
fn mission(model: &mut TeamModel, seconds: u64, robot2_until_s: u64, match_at_s: u64) -> Vec<(u64, Vec<u8>)> {
    let (mut r1, mut r2) = (SimRobot::new(1, Some(key())), SimRobot::new(2, Some(key())));
    let mut log = Vec::new();
    for s in 0..=seconds {
        for step in 0..10 {
            let now = s * S + step * S / 10;
            if step == 0 {
                r1.send(now, telemetry(1, now, 100 * s));
                r1.send(now, pose(1, now, 0, &planar(0.5 * s as f64, 0.0, 0.0)));
                if s <= robot2_until_s {
                    r2.send(now, telemetry(2, now, 100 * s));
                    r2.send(now, pose(2, now, 0, &planar(0.5 * s as f64, 0.0, 0.0)));
                }
                if s == 2 {
                    for m in submap_messages(&patch_submap(1, 0, 4.0, 0.2), None) {
                        r1.send(now, m);
                    }
                }
                if s == match_at_s {
                    r2.send(now, submap_match(2, 0, (1, 0), (2, 0), &t_1_2()));
                    let (first, second) =
                        (SubmapId { robot: RobotId(1), index: 0 }, SubmapId { robot: RobotId(2), index: 0 });
                    r2.send(
                        now,
                        MatchAttempt {
                            first,
                            second,
                            by: RobotId(2),
                            outcome: MatchOutcome::Matched(protocol::message::ConstraintId {
                                robot: RobotId(2),
                                seq: 0,
                            }),
                        },
                    );
                }
            }
            for packet in exchange(model, &mut [&mut r1, &mut r2], now) {
                log.push((now, packet));
            }
            model.tick(now);
        }
    }
    log
}

#[test]
fn trajectories_map_connection_and_staleness() {
    let mut m = model(false);
    mission(&mut m, 6, 6, 1000);
    let v = m.view().clone();
    assert_eq!(v.reference_robot, Some(1));
    let r1 = &v.robots[&1];
    assert!(r1.connected);
    assert_eq!(r1.trajectory_ref_m.len(), 7);
    for (i, p) in r1.trajectory_ref_m.iter().enumerate() {
        assert!((p[0] - 0.5 * i as f64).abs() < 1e-6 && p[1].abs() < 1e-6, "{p:?}");
    }
    assert_eq!(r1.mode, Some(Mode::Autonomous));
    assert!(r1.position_cov_xy_m2.is_some());
    // Robot 2 is heard but not connected: listed, drawn nowhere.
    let r2 = &v.robots[&2];
    assert!(!r2.connected);
    assert!(r2.trajectory_ref_m.is_empty() && r2.t_ref_body.is_none());
    // The submap's patch is on the map at its height, the obstacle marked.
    let grid = v.map.clone().expect("a map once a submap arrived");
    assert_eq!(groundstation::model::grid_height(&grid, 2.0, 2.0).map(|h| (h - 0.2).abs() < 1e-3), Some(true));
    assert_eq!(groundstation::model::grid_height(&grid, 6.0, 6.0), None);
    assert_eq!(grid.obstacle.iter().filter(|o| **o).count(), 1);
    assert!(!v.points.points_ref_m.is_empty());
    assert_eq!(r1.submaps.len(), 1);
    assert_eq!(r1.submaps[0].bounds_submap_m.map(|b| b[2] > 3.9), Some(true));
    // Link: a sample per second, telemetry bytes from the robots' class counters.
    assert!(v.link.samples.len() >= 5);
    let sample = &v.link.samples[3];
    assert!(sample.rx_bytes_per_s_by_class["Telemetry"] > 0.0);
    assert_eq!(sample.tx_bytes_per_s_by_class["Telemetry"], 200.0);
    assert!(v.link.packets_received > 20);
    assert_eq!(v.link.packets_rejected, 0);

    // Robot 2 silent for more than 5 s of ground time: stale; robot 1 keeps talking.
    let mut m = model(false);
    mission(&mut m, 12, 5, 1000);
    let v = m.view();
    assert_eq!(v.robots[&1].staleness, Staleness::Fresh);
    assert_eq!(v.robots[&2].staleness, Staleness::Stale);
    assert_eq!(v.robots[&2].last_message_ns, Some(5 * S));
}

#[test]
fn a_match_connects_the_second_robot_at_the_right_pose() {
    let mut m = model(false);
    mission(&mut m, 8, 8, 4);
    let v = m.view();
    let r2 = &v.robots[&2];
    assert!(r2.connected);
    assert_eq!(r2.trajectory_ref_m.len(), 9);
    for (i, p) in r2.trajectory_ref_m.iter().enumerate() {
        let expected = t_1_2() * Point3::new(0.5 * i as f64, 0.0, 0.0);
        assert!((p[0] - expected.x).abs() < 1e-3 && (p[1] - expected.y).abs() < 1e-3, "{i}: {p:?} vs {expected:?}");
    }
    let edge = v.edges.iter().find(|e| e.kind == EdgeKind::SubmapMatch).expect("the match edge");
    assert!(
        edge.from_ref_m[0].abs() < 1e-3
            && (edge.to_ref_m[0] - 10.0).abs() < 1e-3
            && (edge.to_ref_m[1] - 5.0).abs() < 1e-3
    );

    // In robot 2's frame robot 1 sits at t_2_1.
    let mut m2 = m.clone();
    m2.apply(9 * S, &UiAction::SetReference(2)).unwrap();
    m2.tick(10 * S);
    let v = m2.view();
    assert_eq!(v.reference_robot, Some(2));
    let last = v.robots[&1].trajectory_ref_m.last().copied().unwrap();
    let expected = t_1_2().inverse() * Point3::new(4.0, 0.0, 0.0);
    assert!((last[0] - expected.x).abs() < 1e-3 && (last[1] - expected.y).abs() < 1e-3, "{last:?} vs {expected:?}");
}

#[test]
fn a_waypoint_becomes_an_authenticated_command_in_the_targets_frame() {
    let mut m = model(true).with_counter_start(1_000);
    mission(&mut m, 6, 6, 3);
    let now = 6 * S + 500_000_000;
    m.apply(now, &UiAction::Waypoint { robot: 2, x_ref_m: 10.0, y_ref_m: 7.0 }).unwrap();
    assert!(matches!(m.view().commands.last().unwrap().state, CommandState::Queued));
    let (to, packet) = std::iter::from_fn(|| m.poll_transmit(now))
        .find(|(_, p)| matches!(protocol::decode(p).map(|d| d.message), Ok(AnyMessage::Command(_))))
        .expect("the command packet");
    assert_eq!(to, 2);
    let (sender, counter) = key().verify(&packet).expect("HMAC verifies with the shared key");
    assert_eq!((sender, counter), (NodeId::GROUND, 1_000));
    let decoded = protocol::decode(&packet).unwrap();
    let AnyMessage::Command(command) = decoded.message else { unreachable!() };
    assert_eq!(command.target, RobotId(2));
    let CommandKind::GoToWaypoint { x_m, y_m, .. } = command.kind else { panic!("{command:?}") };
    // (10, 7) in robot 1's frame is (2, 0) in robot 2's (t_1_2: +(10, 5), 90°).
    assert!((x_m - 2.0).abs() < 1e-3 && y_m.abs() < 1e-3, "({x_m}, {y_m})");
    assert!(matches!(m.view().commands.last().unwrap().state, CommandState::Sent { attempts: 1, .. }));
    // A forged copy does not verify.
    let mut forged = packet.clone();
    let at = forged.len() - 30;
    forged[at] ^= 1;
    assert!(key().verify(&forged).is_err());

    // The robot's endpoint accepts it and its acknowledgement closes the command.
    let mut r2 = SimRobot::new(2, Some(key()));
    r2.endpoint.handle_packet(now / 1_000_000, &packet).unwrap();
    let delivered = r2.endpoint.poll_deliver().unwrap();
    assert_eq!(delivered.auth, Some((NodeId::GROUND, 1_000)));
    let later = now + 2 * S;
    r2.send(later, CommandAck { robot: RobotId(2), command_id: command.id, outcome: CommandOutcome::Accepted });
    for p in r2.transmit(later) {
        m.ingest(later, &p);
    }
    m.tick(later);
    let shown = m.view().commands.last().unwrap().clone();
    assert_eq!(shown.state, CommandState::Acknowledged { outcome: CommandOutcome::Accepted, rtt_ms: 2_000 });
    assert!(shown.summary.contains("waypoint"), "{}", shown.summary);

    // Unconnected or unknown targets and a model without a key are refused, with a notice.
    let mut m = model(true);
    mission(&mut m, 3, 3, 1000);
    let refused = m.apply(4 * S, &UiAction::Waypoint { robot: 2, x_ref_m: 1.0, y_ref_m: 1.0 }).unwrap_err();
    assert_eq!(refused, ActionError::NotConnected { robot: 2, reference: 1 });
    assert!(m.view().notices.last().unwrap().contains("not connected"), "{:?}", m.view().notices);
    let mut m = model(false);
    mission(&mut m, 1, 1, 1000);
    assert_eq!(m.apply(S, &UiAction::SetMode { robot: 1, mode: Mode::Safe }), Err(ActionError::NoKey));
    assert!(!m.view().can_command);
}

#[test]
fn commands_wait_through_an_outage_and_go_out_after() {
    let mut m = model(true);
    let mut r1 = SimRobot::new(1, Some(key()));
    r1.send(0, telemetry(1, 0, 0));
    exchange(&mut m, &mut [&mut r1], 0);
    m.tick(0);
    // Ten seconds of silence: the link is down.
    let t = 10 * S;
    m.tick(t);
    m.apply(t, &UiAction::SetMode { robot: 1, mode: Mode::Idle }).unwrap();
    for step in 0..50 {
        let now = t + step * 100_000_000;
        m.tick(now);
        assert!(m.poll_transmit(now).is_none(), "nothing may go out into the outage");
    }
    assert_eq!(m.view().commands[0].state, CommandState::Queued);
    assert!(m.view().link.samples.iter().any(|s| s.outage));
    assert!(m.view().link.outages >= 1);
    // The robot is heard again: the command goes out, the robot executes and acknowledges it.
    let back = 16 * S;
    r1.send(back, telemetry(1, back, 0));
    let heard = exchange(&mut m, &mut [&mut r1], back);
    assert!(!heard.is_empty());
    m.tick(back);
    let mut robot_got = None;
    while let Some((to, packet)) = m.poll_transmit(back) {
        assert_eq!(to, 1);
        r1.endpoint.handle_packet(back / 1_000_000, &packet).unwrap();
        while let Some(d) = r1.endpoint.poll_deliver() {
            if let AnyMessage::Command(c) = d.message {
                robot_got = Some(c);
            }
        }
    }
    let command = robot_got.expect("the queued command reached the robot");
    assert_eq!(command.kind, CommandKind::SetMode(Mode::Idle));
    assert!(matches!(m.view().commands[0].state, CommandState::Sent { .. }));
    let acked = back + 3 * S;
    r1.send(acked, CommandAck { robot: RobotId(1), command_id: command.id, outcome: CommandOutcome::Executed });
    exchange(&mut m, &mut [&mut r1], acked);
    m.tick(acked);
    assert_eq!(
        m.view().commands[0].state,
        CommandState::Acknowledged { outcome: CommandOutcome::Executed, rtt_ms: 3_000 }
    );
}

#[test]
fn replaying_the_feed_log_reproduces_the_live_view() {
    let mut live = model(false);
    let packets = mission(&mut live, 8, 8, 4);
    let end = packets.last().unwrap().0;
    live.tick(end);
    let dir = std::env::temp_dir().join(format!("gs-model-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut writer = FeedLogWriter::create(dir.join("ground_feed.log")).unwrap();
    for (t, p) in &packets {
        let source = protocol::codec::decode_header(p).unwrap().0.source.0;
        writer.append(*t, source, p).unwrap();
    }
    writer.flush().unwrap();
    drop(writer);

    let mut replay = Replay::open(&dir, ModelConfig { auth_key: None, source: "replay".into() }).unwrap();
    assert_eq!((replay.start_ns(), replay.end_ns()), (packets[0].0, end));
    replay.seek(end);
    let (a, b) = (live.view(), replay.model().view());
    assert_eq!(a.robots.keys().collect::<Vec<_>>(), b.robots.keys().collect::<Vec<_>>());
    for (robot, ra) in &a.robots {
        let rb = &b.robots[robot];
        assert_eq!(ra.connected, rb.connected);
        assert_eq!(ra.trajectory_ref_m.len(), rb.trajectory_ref_m.len());
        for (p, q) in ra.trajectory_ref_m.iter().zip(&rb.trajectory_ref_m) {
            assert!((0..3).all(|i| (p[i] - q[i]).abs() < 1e-6), "{p:?} vs {q:?}");
        }
        assert_eq!(ra.mode, rb.mode);
        assert_eq!(ra.last_message_ns, rb.last_message_ns);
    }
    let (ga, gb) = (a.map.clone().unwrap(), b.map.clone().unwrap());
    assert_eq!((ga.origin_xy_m, ga.width, ga.height), (gb.origin_xy_m, gb.width, gb.height));
    assert!(ga.height_m.iter().zip(&gb.height_m).all(|(x, y)| x.to_bits() == y.to_bits() || (x - y).abs() < 1e-6));
    assert_eq!(a.link.samples.len(), b.link.samples.len());
    for (x, y) in a.link.samples.iter().zip(&b.link.samples) {
        assert_eq!(x.rx_bytes_per_s_by_class, y.rx_bytes_per_s_by_class);
        assert_eq!(x.outage, y.outage);
    }
    assert_eq!(a.link.packets_received, b.link.packets_received);
    assert_eq!(b.edges.len(), a.edges.len());

    // Seeking back rebuilds: at 3 s robot 2 is not connected yet; forward again it is.
    replay.seek(3 * S);
    assert!(!replay.model().view().robots[&2].connected);
    assert!(replay.model().view().robots[&1].trajectory_ref_m.len() <= 4);
    replay.seek(end);
    assert!(replay.model().view().robots[&2].connected);
    // A recording cannot be commanded.
    replay.publish_state(false, 1.0);
    assert!(!replay.model().view().can_command);

    let missing = Replay::open(&dir.join("nope"), ModelConfig { auth_key: None, source: String::new() }).unwrap_err();
    assert!(missing.to_string().contains("nope/ground_feed.log"), "{missing}");
    std::fs::remove_dir_all(&dir).ok();
}
