//! Command authentication: forged, corrupted and replayed commands are rejected.

mod common;

use common::test_key;
use protocol::message::{AnyMessage, Command, CommandKind, Mode};
use protocol::{AuthError, AuthKey, MAX_PACKET_BYTES, NodeId, ReplayGuard, RobotId, encode_authenticated};

fn signed_command(counter: u64, key: &AuthKey) -> Vec<u8> {
    let message = AnyMessage::from(Command { target: RobotId(2), id: 17, kind: CommandKind::SetMode(Mode::Safe) });
    let mut buf = [0u8; MAX_PACKET_BYTES];
    let Ok(len) = encode_authenticated(&message, NodeId::GROUND, NodeId(2), 5, counter, key, &mut buf) else {
        panic!("a command always fits a packet buffer");
    };
    buf[..len].to_vec()
}

#[test]
fn genuine_command_verifies_with_its_counter() {
    let packet = signed_command(41, &test_key());
    assert_eq!(test_key().verify(&packet), Ok((NodeId::GROUND, 41)));
}

#[test]
fn every_single_bit_flip_is_rejected() {
    let key = test_key();
    let packet = signed_command(41, &key);
    for byte in 0..packet.len() {
        for bit in 0..8 {
            let mut corrupt = packet.clone();
            corrupt[byte] ^= 1 << bit;
            assert!(key.verify(&corrupt).is_err(), "flip of bit {bit} in byte {byte} verified");
        }
    }
}

#[test]
fn a_different_key_is_rejected() {
    let other = AuthKey::from_bytes(b"another key, also 32 bytes long!").unwrap();
    let packet = signed_command(41, &other);
    assert_eq!(test_key().verify(&packet), Err(AuthError::BadTag));
}

#[test]
fn a_changed_counter_is_rejected() {
    // An attacker who replays a packet with a fresh counter cannot fix up the tag.
    let key = test_key();
    let mut packet = signed_command(41, &key);
    let counter_at = packet.len() - protocol::auth::AUTH_TRAILER_BYTES;
    packet[counter_at..counter_at + 8].copy_from_slice(&1000u64.to_le_bytes());
    assert_eq!(key.verify(&packet), Err(AuthError::BadTag));
}

#[test]
fn replay_guard_accepts_only_increasing_counters_per_sender() {
    let mut guard = ReplayGuard::<4>::new();
    assert_eq!(guard.accept(NodeId::GROUND, 5), Ok(()));
    assert_eq!(guard.accept(NodeId::GROUND, 6), Ok(()));
    assert_eq!(
        guard.accept(NodeId::GROUND, 6),
        Err(AuthError::Replayed { sender: NodeId::GROUND, counter: 6, last: 6 })
    );
    assert!(guard.accept(NodeId::GROUND, 2).is_err());
    // Counters are per sender.
    assert_eq!(guard.accept(NodeId(7), 1), Ok(()));
    // Persisted state survives a restart: the old packet stays rejected.
    let restored = ReplayGuard::<4>::restore(guard.entries()).unwrap();
    let mut restored = restored;
    assert!(restored.accept(NodeId::GROUND, 6).is_err());
    assert_eq!(restored.accept(NodeId::GROUND, 7), Ok(()));
}

#[test]
fn replay_guard_is_bounded() {
    let mut guard = ReplayGuard::<2>::new();
    guard.accept(NodeId(1), 1).unwrap();
    guard.accept(NodeId(2), 1).unwrap();
    assert_eq!(guard.accept(NodeId(3), 1), Err(AuthError::TooManySenders));
}

#[test]
fn keys_of_unsafe_length_are_refused_and_never_printed() {
    assert_eq!(AuthKey::from_bytes(&[1u8; 15]).unwrap_err(), AuthError::KeyLength(15));
    assert!(AuthKey::from_bytes(&[1u8; 65]).is_err());
    let key = AuthKey::from_bytes(b"super secret key material 123456").unwrap();
    assert!(!format!("{key:?}").contains("secret"));
}

#[test]
fn unauthenticated_packets_are_not_verified() {
    let message = AnyMessage::from(protocol::message::CommandAck {
        robot: RobotId(2),
        command_id: 1,
        outcome: protocol::message::CommandOutcome::Executed,
    });
    let mut buf = [0u8; 64];
    let len = protocol::encode(&message, NodeId(2), NodeId::GROUND, 1, &mut buf).unwrap();
    assert_eq!(test_key().verify(&buf[..len]), Err(AuthError::NotAuthenticated));
    assert!(matches!(test_key().verify(&[1, 2]), Err(AuthError::Malformed(_))));
}
