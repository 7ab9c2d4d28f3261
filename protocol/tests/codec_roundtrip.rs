//! Every message survives encode → decode unchanged, with its header.

mod common;

use common::{any_message, encode_any, test_key};
use proptest::prelude::*;
use protocol::message::AnyMessage;
use protocol::{DecodeError, MAX_PACKET_BYTES, NodeId, decode};

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    #[test]
    fn every_message_round_trips(message in any_message(), seq in any::<u32>()) {
        let mut buf = [0u8; MAX_PACKET_BYTES];
        let len = encode_any(&message, seq, &mut buf);
        prop_assert!(len <= MAX_PACKET_BYTES);
        let packet = decode(&buf[..len]).map_err(|e| TestCaseError::fail(format!("{e}")))?;
        prop_assert_eq!(&packet.message, &message);
        prop_assert_eq!(packet.header.seq, seq);
        prop_assert_eq!(packet.header.key, message.key().0);
        prop_assert_eq!(packet.header.version, message.version());
        prop_assert_eq!(packet.header.flags.reliable(), message.delivery() == protocol::Delivery::Reliable);
        prop_assert_eq!(packet.auth.is_some(), message.requires_authentication());
        if message.requires_authentication() {
            let (sender, counter) = test_key().verify(&buf[..len]).map_err(|e| TestCaseError::fail(format!("{e}")))?;
            prop_assert_eq!(sender, NodeId::GROUND);
            prop_assert_eq!(counter, u64::from(seq) + 1);
        }
    }

    #[test]
    fn every_strict_prefix_is_rejected(message in any_message(), cut in any::<prop::sample::Index>()) {
        let mut buf = [0u8; MAX_PACKET_BYTES];
        let len = encode_any(&message, 7, &mut buf);
        let cut = cut.index(len);
        prop_assert!(decode(&buf[..cut]).is_err());
    }

    #[test]
    fn trailing_bytes_are_rejected(message in any_message().prop_filter("unauthenticated", |m| !m.requires_authentication()), extra in 1usize..8) {
        let mut buf = [0u8; MAX_PACKET_BYTES + 8];
        let len = encode_any(&message, 7, &mut buf);
        prop_assert_eq!(decode(&buf[..len + extra]), Err(DecodeError::TrailingBytes { count: extra }));
    }
}

#[test]
fn keys_are_unique_and_named() {
    let mut keys: Vec<u8> = AnyMessage::KEYS.iter().map(|k| k.0).collect();
    keys.sort_unstable();
    keys.dedup();
    assert_eq!(keys.len(), AnyMessage::KEYS.len());
    for key in AnyMessage::KEYS {
        assert!(AnyMessage::name_of(*key).is_some());
    }
}

#[test]
fn encoding_is_stable_for_a_known_message() {
    // Pins the wire format: if this changes, the message's VERSION must be bumped.
    let message = AnyMessage::from(protocol::message::CommandAck {
        robot: protocol::RobotId(3),
        command_id: 300,
        outcome: protocol::message::CommandOutcome::Executed,
    });
    let mut buf = [0u8; 64];
    let len = protocol::encode(&message, NodeId(3), NodeId::GROUND, 129, &mut buf).unwrap();
    // protocol, key, version, flags (reliable), source, destination, seq varint(129) | robot, id varint(300), outcome
    assert_eq!(&buf[..len], &[1, 0x41, 1, 0x01, 3, 0xF0, 0x81, 0x01, 3, 0xAC, 0x02, 1]);
}

#[test]
fn unknown_key_and_version_are_typed_errors() {
    let message = AnyMessage::from(protocol::message::CommandAck {
        robot: protocol::RobotId(3),
        command_id: 1,
        outcome: protocol::message::CommandOutcome::Accepted,
    });
    let mut buf = [0u8; 64];
    let len = protocol::encode(&message, NodeId(3), NodeId::GROUND, 1, &mut buf).unwrap();
    let mut bad = buf;
    bad[1] = 0x7F;
    assert_eq!(decode(&bad[..len]), Err(DecodeError::UnknownKey(0x7F)));
    let mut bad = buf;
    bad[2] = 9;
    assert_eq!(decode(&bad[..len]), Err(DecodeError::UnsupportedVersion { key: 0x41, version: 9 }));
    let mut bad = buf;
    bad[0] = 2;
    assert_eq!(decode(&bad[..len]), Err(DecodeError::WrongProtocol(2)));
    let mut bad = buf;
    bad[3] = 0x00;
    assert_eq!(decode(&bad[..len]), Err(DecodeError::DeliveryMismatch { key: 0x41 }));
    let mut bad = buf;
    bad[3] = 0x81;
    assert_eq!(decode(&bad[..len]), Err(DecodeError::UnknownFlags(0x81)));
}

#[test]
fn commands_cannot_be_sent_unauthenticated_and_others_cannot_be_signed() {
    let command = AnyMessage::from(protocol::message::Command {
        target: protocol::RobotId(1),
        id: 1,
        kind: protocol::message::CommandKind::StopRecording,
    });
    let mut buf = [0u8; 128];
    assert!(protocol::encode(&command, NodeId::GROUND, NodeId(1), 0, &mut buf).is_err());
    let ack = AnyMessage::from(protocol::message::Ack { channel: 1, next_expected: 0, received_mask: 0 });
    assert!(protocol::encode_authenticated(&ack, NodeId::GROUND, NodeId(1), 0, 1, &test_key(), &mut buf).is_err());
}

proptest! {
    #[test]
    fn telemetry_v3_round_trips_and_older_versions_are_refused(telemetry in common::telemetry(), seq in any::<u32>()) {
        let message = AnyMessage::from(telemetry);
        let mut buf = [0u8; MAX_PACKET_BYTES];
        let len = encode_any(&message, seq, &mut buf);
        prop_assert_eq!(buf[2], 3, "Telemetry travels as version 3 (v2 + the devices' availability)");
        prop_assert_eq!(&decode(&buf[..len]).map_err(|e| TestCaseError::fail(format!("{e}")))?.message, &message);
        // An older sender's packet (same key, old version) must not be read as v3.
        for old in [1, 2] {
            buf[2] = old;
            prop_assert_eq!(decode(&buf[..len]), Err(DecodeError::UnsupportedVersion { key: 0x11, version: old }));
        }
    }
}

proptest! {
    #[test]
    fn hazard_cells_round_trip(hazards in common::hazard_cells(), seq in any::<u32>()) {
        let message = AnyMessage::from(hazards);
        let mut buf = [0u8; MAX_PACKET_BYTES];
        let len = encode_any(&message, seq, &mut buf);
        prop_assert!(!packet_is_reliable(&buf[..len]), "latest wins");
        prop_assert_eq!(&decode(&buf[..len]).map_err(|e| TestCaseError::fail(format!("{e}")))?.message, &message);
    }
}

fn packet_is_reliable(packet: &[u8]) -> bool {
    packet[3] & protocol::codec::Flags::RELIABLE != 0
}

#[test]
fn hazard_cells_encoding_is_stable_and_overlong_lists_are_refused() {
    use protocol::message::{HAZARD_CELLS_MAX, HazardCells};
    let mut cells = heapless::Vec::new();
    cells.extend_from_slice(&[[1, -2], [-128, 127]]).unwrap();
    let hazards = HazardCells {
        robot: protocol::RobotId(2),
        stamp_ns: 5,
        submap: protocol::SubmapId { robot: protocol::RobotId(2), index: 1 },
        t_submap_body: protocol::Pose3::IDENTITY,
        cell_size_m: 0.5,
        omitted: 3,
        cells,
    };
    assert!(hazards.is_valid());
    let message = AnyMessage::from(hazards.clone());
    let mut buf = [0u8; 128];
    let len = protocol::encode(&message, NodeId(2), NodeId::GROUND, 1, &mut buf).unwrap();
    // protocol, key, version, flags (latest wins), source, destination, seq | robot, stamp,
    // submap (robot, index), pose (7 × f64 LE), cell size (f32 LE), omitted, cells (len, i8 pairs)
    let mut want = vec![1, 0x12, 1, 0x00, 2, 0xF0, 1, 2, 5, 2, 1];
    for v in [0.0f64, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0] {
        want.extend_from_slice(&v.to_le_bytes());
    }
    want.extend_from_slice(&0.5f32.to_le_bytes());
    want.extend_from_slice(&[3, 2, 1, 0xFE, 0x80, 0x7F]);
    assert_eq!(&buf[..len], &want[..]);
    assert_eq!(decode(&buf[..len]).unwrap().message, message);

    // A list longer than the type's bound is a typed error, not a panic or a truncation.
    let mut long = want[..want.len() - 5].to_vec();
    long.extend_from_slice(&[0x81, 0x02]); // varint 257
    long.extend(std::iter::repeat_n(0u8, 2 * (HAZARD_CELLS_MAX + 1)));
    assert_eq!(decode(&long), Err(DecodeError::MalformedBody { key: 0x12 }));

    // Decoders accept any floats; consumers check before placing the cells.
    let bad_size = HazardCells { cell_size_m: f32::NAN, ..hazards.clone() };
    assert!(!bad_size.is_valid());
    let bad_pose = HazardCells {
        t_submap_body: protocol::Pose3 { translation_m: [0.0; 3], rotation_wxyz: [2.0, 0.0, 0.0, 0.0] },
        ..hazards
    };
    assert!(!bad_pose.is_valid());
}
