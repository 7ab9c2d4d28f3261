//! Strategies that generate every message type, shared by the protocol's property tests.
#![allow(dead_code)]

use heapless::{String, Vec};
use proptest::prelude::*;
use protocol::message::state::{MAX_CLASSES, MAX_LINKS, MAX_QUEUES, MAX_TASKS};
use protocol::message::*;
use protocol::{Cov6, NodeId, NodeRef, Pose3, RobotId, SubmapId};

/// Floats that compare equal after a round trip (no NaN), over the full exponent range.
pub fn real64() -> impl Strategy<Value = f64> {
    prop_oneof![-1.0e4..1.0e4, proptest::num::f64::NORMAL | proptest::num::f64::ZERO | proptest::num::f64::SUBNORMAL]
}

pub fn real32() -> impl Strategy<Value = f32> {
    prop_oneof![-1.0e3f32..1.0e3, proptest::num::f32::NORMAL | proptest::num::f32::ZERO]
}

pub fn robot() -> impl Strategy<Value = RobotId> {
    any::<u8>().prop_map(RobotId)
}

pub fn node() -> impl Strategy<Value = NodeId> {
    any::<u8>().prop_map(NodeId)
}

pub fn submap() -> impl Strategy<Value = SubmapId> {
    (robot(), any::<u32>()).prop_map(|(robot, index)| SubmapId { robot, index })
}

pub fn pose() -> impl Strategy<Value = Pose3> {
    ([real64(), real64(), real64()], [real64(), real64(), real64(), real64()])
        .prop_map(|(translation_m, rotation_wxyz)| Pose3 { translation_m, rotation_wxyz })
}

pub fn cov() -> impl Strategy<Value = Cov6> {
    proptest::collection::vec(real32(), 21).prop_map(|v| {
        let mut upper = [0.0f32; 21];
        upper.copy_from_slice(&v);
        Cov6 { upper }
    })
}

pub fn node_ref() -> impl Strategy<Value = NodeRef> {
    prop_oneof![
        submap().prop_map(NodeRef::SubmapOrigin),
        (robot(), any::<u64>()).prop_map(|(robot, stamp_ns)| NodeRef::RobotPose { robot, stamp_ns }),
        any::<u32>().prop_map(|id| NodeRef::Landmark { id }),
    ]
}

pub fn text<const N: usize>() -> impl Strategy<Value = String<N>> {
    // Any unicode, truncated at a char boundary to fit N bytes.
    proptest::collection::vec(any::<char>(), 0..N).prop_map(|chars| {
        let mut s = String::<N>::new();
        for c in chars {
            if s.push(c).is_err() {
                break;
            }
        }
        s
    })
}

pub fn mode() -> impl Strategy<Value = Mode> {
    prop_oneof![
        Just(Mode::Idle),
        Just(Mode::Waypoint),
        Just(Mode::Autonomous),
        Just(Mode::Teleoperated),
        Just(Mode::Safe)
    ]
}

fn heapless_vec<T: core::fmt::Debug, const N: usize>(
    element: impl Strategy<Value = T>,
) -> impl Strategy<Value = Vec<T, N>> {
    proptest::collection::vec(element, 0..=N).prop_map(|items| {
        let mut out = Vec::<T, N>::new();
        for item in items {
            let _ = out.push(item);
        }
        out
    })
}

pub fn pose_estimate() -> impl Strategy<Value = PoseEstimate> {
    (robot(), any::<u64>(), submap(), pose(), cov()).prop_map(|(robot, stamp_ns, submap, t_submap_body, covariance)| {
        PoseEstimate { robot, stamp_ns, submap, t_submap_body, covariance }
    })
}

pub fn heartbeat() -> impl Strategy<Value = Heartbeat> {
    (node(), any::<u64>(), any::<u64>(), any::<u32>(), mode())
        .prop_map(|(node, stamp_ns, uptime_ms, boot_id, mode)| Heartbeat { node, stamp_ns, uptime_ms, boot_id, mode })
}

pub fn telemetry() -> impl Strategy<Value = Telemetry> {
    let filter = (
        prop_oneof![
            Just(FilterStatus::Initializing),
            Just(FilterStatus::Nominal),
            Just(FilterStatus::Degraded),
            Just(FilterStatus::Diverged)
        ],
        real32(),
        real32(),
        any::<u32>(),
    )
        .prop_map(|(status, position_std_m, yaw_std_rad, vo_age_ms)| FilterHealth {
            status,
            position_std_m,
            yaw_std_rad,
            vo_age_ms,
        });
    let task = (text::<12>(), any::<u32>(), any::<u32>(), any::<u32>(), any::<u32>(), any::<u32>()).prop_map(
        |(task, period_us, releases, deadline_overruns, jitter_p99_us, jitter_max_us)| TaskStats {
            task,
            period_us,
            releases,
            deadline_overruns,
            jitter_p99_us,
            jitter_max_us,
        },
    );
    let queue = (text::<12>(), any::<u16>(), any::<u16>(), any::<u32>())
        .prop_map(|(queue, depth, capacity, dropped)| QueueStats { queue, depth, capacity, dropped });
    let link = (
        text::<12>(),
        any::<u64>(),
        any::<u64>(),
        any::<u32>(),
        any::<u32>(),
        any::<u32>(),
        any::<u32>(),
        any::<u16>(),
        any::<u32>(),
        any::<u32>(),
    )
        .prop_map(
            |(
                link,
                tx_bytes,
                rx_bytes,
                tx_rate_bps,
                rx_rate_bps,
                retransmissions,
                rejected,
                loss_permille,
                rtt_ms,
                outages,
            )| {
                LinkStats {
                    link,
                    tx_bytes,
                    rx_bytes,
                    tx_rate_bps,
                    rx_rate_bps,
                    retransmissions,
                    rejected,
                    loss_permille,
                    rtt_ms,
                    outages,
                }
            },
        );
    let class = (any::<u8>(), any::<u64>(), any::<u32>()).prop_map(|(message_key, tx_bytes, tx_packets)| ClassBytes {
        message_key,
        tx_bytes,
        tx_packets,
    });
    let resources =
        (any::<u16>(), any::<u32>(), any::<u32>()).prop_map(|(cpu_permille, mem_used_kib, mem_total_kib)| {
            ResourceUsage { cpu_permille, mem_used_kib, mem_total_kib }
        });
    (
        robot(),
        any::<u64>(),
        mode(),
        filter,
        resources,
        heapless_vec::<_, MAX_TASKS>(task),
        heapless_vec::<_, MAX_QUEUES>(queue),
        heapless_vec::<_, MAX_LINKS>(link),
        any::<u32>(),
        heapless_vec::<_, MAX_CLASSES>(class),
        proptest::option::of(
            any::<(bool, bool, bool)>().prop_map(|(imu, wheels, head)| protocol::message::SensorAvailability {
                imu,
                wheels,
                head,
            }),
        ),
    )
        .prop_map(
            |(robot, stamp_ns, mode, filter, resources, tasks, queues, links, auth_rejections, classes, sensors)| {
                Telemetry {
                    robot,
                    stamp_ns,
                    mode,
                    filter,
                    resources,
                    tasks,
                    queues,
                    links,
                    auth_rejections,
                    classes,
                    sensors,
                }
            },
        )
}

pub fn hazard_cells() -> impl Strategy<Value = HazardCells> {
    (
        robot(),
        any::<u64>(),
        submap(),
        pose(),
        real32(),
        any::<u16>(),
        heapless_vec::<_, HAZARD_CELLS_MAX>(any::<[i8; 2]>()),
    )
        .prop_map(|(robot, stamp_ns, submap, t_submap_body, cell_size_m, omitted, cells)| HazardCells {
            robot,
            stamp_ns,
            submap,
            t_submap_body,
            cell_size_m,
            omitted,
            cells,
        })
}

pub fn constraint_id() -> impl Strategy<Value = ConstraintId> {
    (robot(), any::<u32>()).prop_map(|(robot, seq)| ConstraintId { robot, seq })
}

pub fn constraint() -> impl Strategy<Value = Constraint> {
    let kind = prop_oneof![
        Just(ConstraintKind::SubmapMatch),
        Just(ConstraintKind::RobotDetection),
        Just(ConstraintKind::LandmarkObservation)
    ];
    (constraint_id(), kind, any::<u64>(), node_ref(), node_ref(), pose(), cov()).prop_map(
        |(id, kind, stamp_ns, from, to, t_from_to, covariance)| Constraint {
            id,
            kind,
            stamp_ns,
            from,
            to,
            t_from_to,
            covariance,
        },
    )
}

pub fn match_attempt() -> impl Strategy<Value = MatchAttempt> {
    let outcome = prop_oneof![
        Just(MatchOutcome::Claimed),
        Just(MatchOutcome::Rejected),
        constraint_id().prop_map(MatchOutcome::Matched)
    ];
    (submap(), submap(), robot(), outcome).prop_map(|(a, b, by, outcome)| {
        let (first, second) = MatchAttempt::ordered_pair(a, b);
        MatchAttempt { first, second, by, outcome }
    })
}

pub fn submap_header() -> impl Strategy<Value = SubmapHeader> {
    let switch = proptest::option::of(
        (pose(), cov()).prop_map(|(t_previous_this, covariance)| SubmapLink { t_previous_this, covariance }),
    );
    (submap(), any::<u64>(), any::<u64>(), switch, any::<u8>(), any::<u32>(), any::<u16>(), any::<u32>()).prop_map(
        |(submap, started_stamp_ns, finished_stamp_ns, switch, encoding, payload_bytes, chunk_count, payload_crc32)| {
            SubmapHeader {
                submap,
                started_stamp_ns,
                finished_stamp_ns,
                switch,
                encoding: SubmapEncoding(encoding),
                payload_bytes,
                chunk_count,
                payload_crc32,
            }
        },
    )
}

pub fn submap_chunk() -> impl Strategy<Value = SubmapChunk> {
    (submap(), any::<u16>(), proptest::collection::vec(any::<u8>(), 0..=SUBMAP_CHUNK_BYTES)).prop_map(
        |(submap, index, bytes)| {
            let mut data = Vec::new();
            let _ = data.extend_from_slice(&bytes);
            SubmapChunk { submap, index, data }
        },
    )
}

pub fn command() -> impl Strategy<Value = Command> {
    let value = prop_oneof![
        any::<bool>().prop_map(ParamValue::Bool),
        any::<i64>().prop_map(ParamValue::Int),
        real64().prop_map(ParamValue::Float)
    ];
    let kind = prop_oneof![
        mode().prop_map(CommandKind::SetMode),
        (real64(), real64(), real64(), real32()).prop_map(|(x_m, y_m, z_m, speed_mps)| CommandKind::GoToWaypoint {
            x_m,
            y_m,
            z_m,
            speed_mps
        }),
        (text::<32>(), value).prop_map(|(name, value)| CommandKind::SetParameter { name, value }),
        (submap(), proptest::option::of((any::<u16>(), any::<u16>())))
            .prop_map(|(submap, chunks)| CommandKind::RequestResend { submap, chunks }),
        text::<32>().prop_map(|label| CommandKind::StartRecording { label }),
        Just(CommandKind::StopRecording),
    ];
    (robot(), any::<u32>(), kind).prop_map(|(target, id, kind)| Command { target, id, kind })
}

pub fn command_ack() -> impl Strategy<Value = CommandAck> {
    let outcome = prop_oneof![
        Just(CommandOutcome::Accepted),
        Just(CommandOutcome::Executed),
        Just(CommandOutcome::Invalid),
        Just(CommandOutcome::Refused)
    ];
    (robot(), any::<u32>(), outcome).prop_map(|(robot, command_id, outcome)| CommandAck { robot, command_id, outcome })
}

pub fn ack() -> impl Strategy<Value = Ack> {
    (any::<u8>(), any::<u32>(), any::<u32>()).prop_map(|(channel, next_expected, received_mask)| Ack {
        channel,
        next_expected,
        received_mask,
    })
}

/// Any message of the protocol.
pub fn any_message() -> impl Strategy<Value = AnyMessage> {
    prop_oneof![
        heartbeat().prop_map(AnyMessage::from),
        ack().prop_map(AnyMessage::from),
        pose_estimate().prop_map(AnyMessage::from),
        telemetry().prop_map(AnyMessage::from),
        hazard_cells().prop_map(AnyMessage::from),
        constraint().prop_map(AnyMessage::from),
        match_attempt().prop_map(AnyMessage::from),
        submap_header().prop_map(AnyMessage::from),
        submap_chunk().prop_map(AnyMessage::from),
        command().prop_map(AnyMessage::from),
        command_ack().prop_map(AnyMessage::from),
    ]
}

/// A fixed key for tests (never a deployed one).
pub fn test_key() -> protocol::AuthKey {
    match protocol::AuthKey::from_bytes(b"test key: 32 bytes of secret!!!!") {
        Ok(key) => key,
        Err(e) => panic!("test key rejected: {e}"),
    }
}

/// Encodes `message` the way a sender must: authenticated if its type requires it.
pub fn encode_any(message: &AnyMessage, seq: u32, out: &mut [u8]) -> usize {
    let result = if message.requires_authentication() {
        protocol::encode_authenticated(message, NodeId::GROUND, NodeId(1), seq, u64::from(seq) + 1, &test_key(), out)
    } else {
        protocol::encode(message, NodeId(1), NodeId::BROADCAST, seq, out)
    };
    match result {
        Ok(len) => len,
        Err(e) => panic!("encode failed: {e}"),
    }
}
