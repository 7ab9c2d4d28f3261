//! The model is total: any bytes, valid packets cut or flipped, never a panic.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod model_common;

use groundstation::model::{ModelConfig, TeamModel};
use model_common::*;
use proptest::prelude::*;
use protocol::{MAX_PACKET_BYTES, NodeId, encode};

fn valid_packets() -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let mut buf = vec![0u8; MAX_PACKET_BYTES];
    let len = encode(&telemetry(1, 0, 0).into(), NodeId(1), NodeId::GROUND, 0, &mut buf).unwrap();
    out.push(buf[..len].to_vec());
    let len = encode(&pose(1, 5, 0, &planar(1.0, 0.0, 0.3)).into(), NodeId(1), NodeId::GROUND, 1, &mut buf).unwrap();
    out.push(buf[..len].to_vec());
    let mut robot = SimRobot::new(1, None);
    for m in submap_messages(&patch_submap(1, 0, 1.0, 0.0), None) {
        robot.send(0, m);
    }
    robot.send(0, submap_match(1, 0, (1, 0), (2, 0), &planar(1.0, 1.0, 0.0)));
    out.extend(robot.transmit(0));
    out
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]

    #[test]
    fn any_bytes_are_used_or_counted(packets in proptest::collection::vec(proptest::collection::vec(any::<u8>(), 0..300), 1..20)) {
        let mut model = TeamModel::new(ModelConfig { auth_key: Some(key()), source: String::new() });
        for (i, p) in packets.iter().enumerate() {
            model.ingest(i as u64 * 100_000_000, p);
        }
        model.tick(10_000_000_000);
        let link = &model.view().link;
        prop_assert!(link.packets_received + link.packets_rejected + model.counters().uplink_echoes <= packets.len() as u64);
    }

    #[test]
    fn damaged_packets_never_panic(cut in 0usize..1200, flip in 0usize..1200, bit in 0u8..8, which in 0usize..64) {
        let packets = valid_packets();
        let mut model = TeamModel::new(ModelConfig { auth_key: None, source: String::new() });
        let mut damaged = packets[which % packets.len()].clone();
        if !damaged.is_empty() {
            let at = flip % damaged.len();
            damaged[at] ^= 1 << bit;
            damaged.truncate(cut.max(1).min(damaged.len()));
        }
        for (i, p) in packets.iter().enumerate() {
            model.ingest(i as u64, if i == which % packets.len() { &damaged } else { p });
        }
        model.tick(1_000_000_000);
    }
}
