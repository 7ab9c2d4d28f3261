//! CANopen: frames, the emulated wheel drives and pan-tilt head, and the master, on a
//! `LoopbackCanBus` driven on a simulated clock in 1 ms steps (deterministic: every device and
//! the master see the same `now_ns`, and nothing reads the wall clock).
//!
//! Numbers are printed with `cargo test -p hal --test canopen -- --nocapture`.

// Helpers outside #[test] functions are test code too; clippy.toml only exempts the latter.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::f64::consts::{FRAC_PI_2, TAU};

use hal::can::{CanBus, CanFrame, LoopbackCanBus};
use hal::canopen::frame::abort_code;
use hal::canopen::{
    CanopenDecodeError, CanopenDevice, CanopenMaster, CanopenMessage, Emergency, MasterConfig, MasterEvent, NmtCommand,
    NmtState, NmtTarget, NodeHealth, NodeId, PAN_TILT_NODE, PanTiltNode, PdoData, PdoNumber, SdoData, SdoRequest,
    SdoResponse, SkidSteerKinematics, WHEEL_DRIVE_NODES, WheelDriveNode, WheelEncoders, service_devices,
};
use proptest::prelude::*;
use protocol::frame::can::CanKind;

const MS: u64 = 1_000_000;

fn node(id: u8) -> NodeId {
    NodeId::new(id).unwrap()
}

fn standard(id: u32, data: &[u8]) -> CanFrame {
    CanFrame::standard(id, data).unwrap()
}

fn round_trip(message: CanopenMessage) -> CanFrame {
    let frame = message.encode();
    assert!(!frame.extended && frame.id <= 0x7FF && frame.len <= 8, "{message:?} -> {frame:?}");
    assert_eq!(CanopenMessage::decode(&frame), Ok(message), "{frame:?}");
    frame
}

// ---------------------------------------------------------------------------------------------
// Frames
// ---------------------------------------------------------------------------------------------

#[test]
fn every_message_has_the_cia301_layout_and_round_trips() {
    let n = node(0x11);
    let cases: Vec<(CanopenMessage, u32, Vec<u8>)> = vec![
        (CanopenMessage::Nmt { command: NmtCommand::Start, target: NmtTarget::All }, 0x000, vec![0x01, 0x00]),
        (CanopenMessage::Nmt { command: NmtCommand::Stop, target: NmtTarget::Node(n) }, 0x000, vec![0x02, 0x11]),
        (
            CanopenMessage::Nmt { command: NmtCommand::EnterPreOperational, target: NmtTarget::Node(n) },
            0x000,
            vec![0x80, 0x11],
        ),
        (CanopenMessage::Nmt { command: NmtCommand::ResetNode, target: NmtTarget::All }, 0x000, vec![0x81, 0]),
        (CanopenMessage::Nmt { command: NmtCommand::ResetCommunication, target: NmtTarget::All }, 0x000, vec![0x82, 0]),
        (CanopenMessage::Sync { counter: None }, 0x080, vec![]),
        (CanopenMessage::Sync { counter: Some(7) }, 0x080, vec![7]),
        (
            CanopenMessage::Emergency {
                node: n,
                emergency: Emergency { error_code: 0x2310, error_register: 0x03, manufacturer: [1, 2, 3, 4, 5] },
            },
            0x091,
            vec![0x10, 0x23, 0x03, 1, 2, 3, 4, 5],
        ),
        (
            CanopenMessage::Tpdo { node: n, number: PdoNumber::Pdo1, data: PdoData::from_i32_pair(-2, 1000) },
            0x191,
            vec![0xFE, 0xFF, 0xFF, 0xFF, 0xE8, 0x03, 0, 0],
        ),
        (CanopenMessage::Tpdo { node: n, number: PdoNumber::Pdo4, data: PdoData::new(&[]).unwrap() }, 0x491, vec![]),
        (CanopenMessage::Rpdo { node: n, number: PdoNumber::Pdo1, data: PdoData::new(&[9]).unwrap() }, 0x211, vec![9]),
        (
            CanopenMessage::Rpdo { node: n, number: PdoNumber::Pdo3, data: PdoData::new(&[1, 2]).unwrap() },
            0x411,
            vec![1, 2],
        ),
        (
            CanopenMessage::SdoRequest { node: n, request: SdoRequest::Upload { index: 0x1018, subindex: 1 } },
            0x611,
            vec![0x40, 0x18, 0x10, 0x01, 0, 0, 0, 0],
        ),
        (
            CanopenMessage::SdoRequest {
                node: n,
                request: SdoRequest::Download { index: 0x1017, subindex: 0, data: SdoData::from_u16(500) },
            },
            0x611,
            vec![0x2B, 0x17, 0x10, 0x00, 0xF4, 0x01, 0, 0],
        ),
        (
            CanopenMessage::SdoRequest {
                node: n,
                request: SdoRequest::Abort { index: 0x2000, subindex: 3, code: abort_code::NO_OBJECT },
            },
            0x611,
            vec![0x80, 0x00, 0x20, 0x03, 0x00, 0x00, 0x02, 0x06],
        ),
        (
            CanopenMessage::SdoResponse {
                node: n,
                response: SdoResponse::Upload { index: 0x1000, subindex: 0, data: SdoData::from_u32(0x0002_0192) },
            },
            0x591,
            vec![0x43, 0x00, 0x10, 0x00, 0x92, 0x01, 0x02, 0x00],
        ),
        (
            CanopenMessage::SdoResponse {
                node: n,
                response: SdoResponse::Upload { index: 0x1017, subindex: 0, data: SdoData::from_u16(100) },
            },
            0x591,
            vec![0x4B, 0x17, 0x10, 0x00, 100, 0, 0, 0],
        ),
        (
            CanopenMessage::SdoResponse {
                node: n,
                response: SdoResponse::Upload { index: 0x1001, subindex: 0, data: SdoData::from_u8(1) },
            },
            0x591,
            vec![0x4F, 0x01, 0x10, 0x00, 1, 0, 0, 0],
        ),
        (
            CanopenMessage::SdoResponse { node: n, response: SdoResponse::DownloadAck { index: 0x1017, subindex: 0 } },
            0x591,
            vec![0x60, 0x17, 0x10, 0x00, 0, 0, 0, 0],
        ),
        (CanopenMessage::Heartbeat { node: n, state: NmtState::BootUp }, 0x711, vec![0x00]),
        (CanopenMessage::Heartbeat { node: n, state: NmtState::Stopped }, 0x711, vec![0x04]),
        (CanopenMessage::Heartbeat { node: n, state: NmtState::Operational }, 0x711, vec![0x05]),
        (CanopenMessage::Heartbeat { node: n, state: NmtState::PreOperational }, 0x711, vec![0x7F]),
    ];
    for (message, id, bytes) in cases {
        let frame = round_trip(message);
        assert_eq!((frame.id, frame.data()), (id, bytes.as_slice()), "{message:?}");
    }
}

#[test]
fn foreign_and_malformed_frames_are_told_apart() {
    let extended = CanFrame::new(0x0400_0102, &[1, 2]).unwrap();
    assert_eq!(CanopenMessage::decode(&extended), Err(CanopenDecodeError::ExtendedId(0x0400_0102)));
    for id in [0x001, 0x07F, 0x100, 0x180, 0x600, 0x700, 0x7E4, 0x7E5, 0x7FF] {
        let error = CanopenMessage::decode(&standard(id, &[0])).unwrap_err();
        assert!(error.is_foreign(), "{id:#x}: {error}");
    }
    let malformed = [
        standard(0x000, &[0x01]),
        standard(0x000, &[0x03, 0]),
        standard(0x000, &[0x01, 0x80]),
        standard(0x080, &[1, 2]),
        standard(0x091, &[0; 7]),
        standard(0x611, &[0x40, 0, 0x10, 0]),
        standard(0x711, &[0x05, 0]),
        standard(0x711, &[0x85]),
        standard(0x191, &[0; 12]),
    ];
    for frame in malformed {
        let error = CanopenMessage::decode(&frame).unwrap_err();
        assert!(!error.is_foreign(), "{frame:?}: {error}");
    }
    // Segmented transfers are kept raw, so a server can answer them with an abort.
    let segmented = standard(0x611, &[0x21, 0x00, 0x20, 0x00, 10, 0, 0, 0]);
    assert!(matches!(
        CanopenMessage::decode(&segmented),
        Ok(CanopenMessage::SdoRequest { request: SdoRequest::Unsupported(_), .. })
    ));
    // Expedited without a size: all four bytes are the value.
    let unsized_download = standard(0x611, &[0x22, 0x17, 0x10, 0x00, 1, 2, 3, 4]);
    let Ok(CanopenMessage::SdoRequest { request: SdoRequest::Download { data, .. }, .. }) =
        CanopenMessage::decode(&unsized_download)
    else {
        panic!("not decoded as an expedited download");
    };
    assert_eq!(data.as_slice(), &[1, 2, 3, 4]);
}

fn node_id() -> impl Strategy<Value = NodeId> {
    (1u8..=127).prop_map(node)
}

fn pdo_data() -> impl Strategy<Value = PdoData> {
    prop::collection::vec(any::<u8>(), 0..=8).prop_map(|bytes| PdoData::new(&bytes).unwrap())
}

fn sdo_data() -> impl Strategy<Value = SdoData> {
    prop::collection::vec(any::<u8>(), 1..=4).prop_map(|bytes| SdoData::new(&bytes).unwrap())
}

fn pdo_number() -> impl Strategy<Value = PdoNumber> {
    prop::sample::select(PdoNumber::ALL.to_vec())
}

/// Raw SDO frames of the transfers we do not decode: the segment and block specifiers of one
/// direction, and its initiate without the expedited bit.
fn unsupported_sdo(others: [u8; 5], non_expedited_initiate: u8) -> impl Strategy<Value = [u8; 8]> {
    let mut specifiers = others.to_vec();
    specifiers.push(non_expedited_initiate);
    (prop::sample::select(specifiers), any::<[u8; 8]>()).prop_map(move |(specifier, mut bytes)| {
        bytes[0] = (specifier << 5) | (bytes[0] & 0x1F);
        if specifier == non_expedited_initiate {
            bytes[0] &= !0x02;
        }
        bytes
    })
}

fn message() -> impl Strategy<Value = CanopenMessage> {
    let command = prop::sample::select(vec![
        NmtCommand::Start,
        NmtCommand::Stop,
        NmtCommand::EnterPreOperational,
        NmtCommand::ResetNode,
        NmtCommand::ResetCommunication,
    ]);
    let target = prop_oneof![Just(NmtTarget::All), node_id().prop_map(NmtTarget::Node)];
    let state = prop::sample::select(vec![
        NmtState::BootUp,
        NmtState::Stopped,
        NmtState::Operational,
        NmtState::PreOperational,
    ]);
    let request = prop_oneof![
        (any::<u16>(), any::<u8>()).prop_map(|(index, subindex)| SdoRequest::Upload { index, subindex }),
        (any::<u16>(), any::<u8>(), sdo_data()).prop_map(|(index, subindex, data)| SdoRequest::Download {
            index,
            subindex,
            data
        }),
        (any::<u16>(), any::<u8>(), any::<u32>()).prop_map(|(index, subindex, code)| SdoRequest::Abort {
            index,
            subindex,
            code
        }),
        unsupported_sdo([0, 3, 5, 6, 7], 1).prop_map(SdoRequest::Unsupported),
    ];
    let response = prop_oneof![
        (any::<u16>(), any::<u8>(), sdo_data()).prop_map(|(index, subindex, data)| SdoResponse::Upload {
            index,
            subindex,
            data
        }),
        (any::<u16>(), any::<u8>()).prop_map(|(index, subindex)| SdoResponse::DownloadAck { index, subindex }),
        (any::<u16>(), any::<u8>(), any::<u32>()).prop_map(|(index, subindex, code)| SdoResponse::Abort {
            index,
            subindex,
            code
        }),
        unsupported_sdo([0, 1, 5, 6, 7], 2).prop_map(SdoResponse::Unsupported),
    ];
    prop_oneof![
        (command, target).prop_map(|(command, target)| CanopenMessage::Nmt { command, target }),
        any::<Option<u8>>().prop_map(|counter| CanopenMessage::Sync { counter }),
        (node_id(), any::<u16>(), any::<u8>(), any::<[u8; 5]>()).prop_map(|(node, error_code, register, m)| {
            CanopenMessage::Emergency {
                node,
                emergency: Emergency { error_code, error_register: register, manufacturer: m },
            }
        }),
        (node_id(), pdo_number(), pdo_data()).prop_map(|(node, number, data)| CanopenMessage::Tpdo {
            node,
            number,
            data
        }),
        (node_id(), pdo_number(), pdo_data()).prop_map(|(node, number, data)| CanopenMessage::Rpdo {
            node,
            number,
            data
        }),
        (node_id(), request).prop_map(|(node, request)| CanopenMessage::SdoRequest { node, request }),
        (node_id(), response).prop_map(|(node, response)| CanopenMessage::SdoResponse { node, response }),
        (node_id(), state).prop_map(|(node, state)| CanopenMessage::Heartbeat { node, state }),
    ]
}

/// Any frame a bus could hand over, and some it could not (ids beyond 11 bits marked standard).
fn arbitrary_frame() -> impl Strategy<Value = CanFrame> {
    let id = prop_oneof![0u32..0x800, any::<u32>()];
    let len = prop_oneof![0u8..=8, prop::sample::select(vec![12u8, 16, 20, 24, 32, 48, 64, 65, 255])];
    (id, len, any::<bool>(), prop::collection::vec(any::<u8>(), 64)).prop_map(|(id, len, extended, bytes)| {
        let mut data = [0; 64];
        data.copy_from_slice(&bytes);
        CanFrame { id, len, data, extended }
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    #[test]
    fn every_message_round_trips(message in message()) {
        round_trip(message);
    }

    /// Total: no frame panics the decoder; whatever decodes re-encodes to a frame that decodes
    /// to the same message.
    #[test]
    fn the_decoder_is_total(frame in arbitrary_frame()) {
        if let Ok(message) = CanopenMessage::decode(&frame) {
            prop_assert!(!frame.extended);
            round_trip(message);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]

    /// Every device and the master take any frame without panicking or misbehaving.
    #[test]
    fn devices_and_master_take_arbitrary_frames(frames in prop::collection::vec(arbitrary_frame(), 1..40)) {
        let mut drive = WheelDriveNode::new(WHEEL_DRIVE_NODES[0]);
        let mut head = PanTiltNode::new(PAN_TILT_NODE);
        let mut master = CanopenMaster::new(MasterConfig::default()).unwrap();
        for (i, frame) in frames.iter().enumerate() {
            let now_ns = i as u64 * MS;
            drive.on_frame(frame, now_ns);
            head.on_frame(frame, now_ns);
            master.on_frame(frame, now_ns);
            for sent in drive.tick(now_ns).into_iter().chain(head.tick(now_ns)) {
                prop_assert!(CanopenMessage::decode(&sent).is_ok());
            }
        }
        prop_assert!(head.pan_rad().abs() <= std::f64::consts::PI && head.tilt_rad().abs() <= FRAC_PI_2);
        let counters = master.counters();
        prop_assert_eq!(counters.frames_received, frames.len() as u64);
    }
}

// ---------------------------------------------------------------------------------------------
// Kinematics
// ---------------------------------------------------------------------------------------------

fn encoders(positions_counts: [i32; 4]) -> WheelEncoders {
    WheelEncoders { cycle: 0, stamp_ns: 0, positions_counts, velocities_counts_per_s: [0; 4] }
}

#[test]
fn twist_from_encoders_is_wrap_safe_and_refuses_bad_intervals() {
    let k = SkidSteerKinematics::lru_like();
    // 1000 counts forward on every wheel across the i32 wrap.
    let prev = encoders([i32::MAX - 400; 4]);
    let cur = encoders([(i32::MAX - 400).wrapping_add(1000); 4]);
    let (v, omega) = k.twist_from_encoders(&prev, &cur, 0.02).unwrap();
    let expected = 1000.0 / f64::from(k.counts_per_rev) * TAU * k.wheel_radius_m / 0.02;
    assert!((v - expected).abs() < 1e-12 && omega.abs() < 1e-12, "{v} {omega}");
    assert!(k.twist_from_encoders(&prev, &cur, 0.0).is_none());
    assert!(k.twist_from_encoders(&prev, &cur, f64::NAN).is_none());
    let [fl, fr, rl, rr] = k.wheel_speeds_from_twist(0.3, 1.0);
    assert!((fl - 0.0).abs() < 1e-12 && fl == rl && fr == rr && (fr - 6.0).abs() < 1e-12);
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2_000))]

    /// Twist → wheel speeds → emulated drives integrating counts → twist again: within the
    /// quantisation bound `twist_resolution(dt)` (< 1 count per wheel), whatever the encoders'
    /// offsets (which put the interval across the i32 wrap for many cases).
    #[test]
    fn twist_round_trips_through_the_drives_to_the_counts_quantisation(
        v_mps in -1.5f64..1.5,
        omega_radps in -2.0f64..2.0,
        preroll_ms in 0u64..5_000,
        dt_ms in 5u64..200,
        offsets in any::<[i32; 4]>(),
    ) {
        let k = SkidSteerKinematics::lru_like();
        let speeds = k.wheel_speeds_from_twist(v_mps, omega_radps);
        let mut drives: Vec<WheelDriveNode> = WHEEL_DRIVE_NODES.iter().map(|&n| WheelDriveNode::new(n)).collect();
        let positions = |drives: &mut Vec<WheelDriveNode>, now_ns: u64| {
            let mut p = [0i32; 4];
            for (i, drive) in drives.iter_mut().enumerate() {
                drive.tick(now_ns);
                p[i] = drive.position_counts().wrapping_add(offsets[i]);
            }
            encoders(p)
        };
        positions(&mut drives, 0);
        for (drive, speed) in drives.iter_mut().zip(speeds) {
            drive.set_wheel_speed(speed);
        }
        let t1 = preroll_ms * MS;
        let t2 = t1 + dt_ms * MS;
        let prev = positions(&mut drives, t1);
        let cur = positions(&mut drives, t2);
        let dt_s = dt_ms as f64 * 1e-3;
        let (v, omega) = k.twist_from_encoders(&prev, &cur, dt_s).unwrap();
        let (v_bound, omega_bound) = k.twist_resolution(dt_s);
        prop_assert!((v - v_mps).abs() < v_bound, "v {v} vs {v_mps}, bound {v_bound}");
        prop_assert!((omega - omega_radps).abs() < omega_bound, "omega {omega} vs {omega_radps}, bound {omega_bound}");
    }
}

// ---------------------------------------------------------------------------------------------
// A master, four drives and the head on a loopback bus, on a simulated clock
// ---------------------------------------------------------------------------------------------

/// xorshift64: the babbler's ids and data, fixed by its seed.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
}

/// A node flooding the bus with random frames. It never uses an id another node transmits
/// (the master's NMT and SYNC, the supervised nodes' ids): CAN requires one transmitter per id,
/// and a node impersonating another is a different fault from babbling.
struct Babbler {
    bus: LoopbackCanBus,
    rng: Rng,
    frames_per_ms: usize,
    sent: u64,
}

impl Babbler {
    fn frame(&mut self) -> CanFrame {
        let r = self.rng.next();
        let len = (r % 9) as usize;
        let data = (r >> 8).to_le_bytes();
        if r >> 63 == 1 {
            return CanFrame::new((r >> 20) as u32 & 0x1FFF_FFFF, &data[..len]).unwrap();
        }
        loop {
            let id = (self.rng.next() % 0x800) as u32;
            let ours = id == 0x000
                || id == 0x080
                || WHEEL_DRIVE_NODES.iter().chain([&PAN_TILT_NODE]).any(|n| id & 0x7F == u32::from(n.get()));
            if !ours {
                return standard(id, &data[..len]);
            }
        }
    }

    fn babble(&mut self) {
        for _ in 0..self.frames_per_ms {
            let frame = self.frame();
            self.bus.send(&frame).unwrap();
            self.sent += 1;
        }
    }
}

/// What an observer on the bus saw, by kind.
#[derive(Debug, Default)]
struct Seen {
    syncs: u64,
    tpdos: u64,
    heartbeats: u64,
    sdo_responses: Vec<SdoResponse>,
}

struct Rig {
    now_ns: u64,
    kinematics: SkidSteerKinematics,
    master: CanopenMaster,
    master_bus: LoopbackCanBus,
    drives: Vec<(WheelDriveNode, LoopbackCanBus)>,
    head: (PanTiltNode, LoopbackCanBus),
    spy: LoopbackCanBus,
    seen: Seen,
    babbler: Option<Babbler>,
    events: Vec<(u64, MasterEvent)>,
    cycles: Vec<WheelEncoders>,
}

impl Rig {
    fn new() -> Rig {
        let mut buses = LoopbackCanBus::network(CanKind::Classic, 8).into_iter();
        let mut next = || buses.next().unwrap();
        let master_bus = next();
        let drives = WHEEL_DRIVE_NODES.iter().map(|&n| (WheelDriveNode::new(n), next())).collect();
        let head = (PanTiltNode::new(PAN_TILT_NODE), next());
        let spy = next();
        let babbler_bus = next();
        Rig {
            now_ns: 0,
            kinematics: SkidSteerKinematics::lru_like(),
            master: CanopenMaster::new(MasterConfig::default()).unwrap(),
            master_bus,
            drives,
            head,
            spy,
            seen: Seen::default(),
            babbler: Some(Babbler { bus: babbler_bus, rng: Rng(0x5EED), frames_per_ms: 0, sent: 0 }),
            events: Vec::new(),
            cycles: Vec::new(),
        }
    }

    /// One millisecond: the babbler, the master, every device, the observer.
    fn step(&mut self) {
        let now_ns = self.now_ns;
        if let Some(babbler) = &mut self.babbler {
            babbler.babble();
        }
        self.master.tick(now_ns, &mut self.master_bus).unwrap();
        for (drive, bus) in &mut self.drives {
            service_devices(&mut [drive as &mut dyn CanopenDevice], bus, now_ns).unwrap();
        }
        let (head, bus) = &mut self.head;
        service_devices(&mut [head as &mut dyn CanopenDevice], bus, now_ns).unwrap();
        while let Some(frame) = self.spy.recv(std::time::Duration::ZERO).unwrap() {
            match CanopenMessage::decode(&frame) {
                Ok(CanopenMessage::Sync { .. }) => self.seen.syncs += 1,
                Ok(CanopenMessage::Tpdo { .. }) => self.seen.tpdos += 1,
                Ok(CanopenMessage::Heartbeat { .. }) => self.seen.heartbeats += 1,
                Ok(CanopenMessage::SdoResponse { response, .. }) => self.seen.sdo_responses.push(response),
                _ => {}
            }
        }
        self.events.extend(self.master.drain_events().map(|event| (now_ns, event)));
        if let Some(cycle) = self.master.take_encoders() {
            self.cycles.push(cycle);
        }
        self.now_ns += MS;
    }

    fn run_ms(&mut self, ms: u64) {
        for _ in 0..ms {
            self.step();
        }
    }

    fn set_twist(&mut self, v_mps: f64, omega_radps: f64) {
        let speeds = self.kinematics.wheel_speeds_from_twist(v_mps, omega_radps);
        for ((drive, _), speed) in self.drives.iter_mut().zip(speeds) {
            drive.set_wheel_speed(speed);
        }
    }

    fn health(&self, n: NodeId) -> NodeHealth {
        self.master.health(n).unwrap()
    }

    fn all_operational(&self) -> bool {
        self.master.node_health().all(|(_, health)| health == NodeHealth::Operational)
    }

    /// Events of one kind since `since_ns`.
    fn events_since(&self, since_ns: u64, wanted: impl Fn(&MasterEvent) -> bool) -> Vec<(u64, MasterEvent)> {
        self.events.iter().filter(|(t, event)| *t >= since_ns && wanted(event)).copied().collect()
    }

    /// Brought up and one heartbeat period later: everyone operational.
    fn up() -> Rig {
        let mut rig = Rig::new();
        rig.run_ms(150);
        assert!(rig.all_operational(), "{:?}", rig.master.node_health().collect::<Vec<_>>());
        rig
    }
}

#[test]
fn boot_up_nmt_start_and_operational() {
    let mut rig = Rig::new();
    rig.step();
    // The master's start-all at t = 0 reaches devices still initialising: they ignore it and
    // boot; the boot-ups get each of them its own NMT start.
    assert!(rig.drives.iter().all(|(d, _)| d.nmt_state() == NmtState::PreOperational));
    rig.step();
    assert!(rig.drives.iter().all(|(d, _)| d.nmt_state() == NmtState::Operational));
    assert_eq!(rig.head.0.nmt_state(), NmtState::Operational);
    let booted = rig.events_since(0, |e| matches!(e, MasterEvent::NodeBooted { .. }));
    assert_eq!(booted.len(), 5);
    assert_eq!(rig.master.counters().nmt_starts_sent, 1 + 5);
    // Health comes from heartbeats: not operational until the first one (100 ms after boot).
    assert_eq!(rig.health(WHEEL_DRIVE_NODES[0]), NodeHealth::NotOperational(NmtState::BootUp));
    rig.run_ms(100);
    assert!(rig.all_operational());
    let first_cycle = rig.cycles.first().unwrap();
    println!(
        "bring-up: operational at 1 ms, first complete cycle {} at {} ms",
        first_cycle.cycle,
        first_cycle.stamp_ns / MS
    );
}

#[test]
fn sdo_server_answers_uploads_downloads_and_aborts() {
    let n = node(0x11);
    let mut drive = WheelDriveNode::new(n);
    drive.tick(0);
    let mut ask = |request: SdoRequest| {
        drive.on_frame(&CanopenMessage::SdoRequest { node: n, request }.encode(), MS);
        let frames = drive.tick(MS);
        let [frame] = frames.as_slice() else { panic!("expected one answer, got {frames:?}") };
        let Ok(CanopenMessage::SdoResponse { node, response }) = CanopenMessage::decode(frame) else {
            panic!("not an SDO response: {frame:?}")
        };
        assert_eq!(node, n);
        response
    };
    let upload = |index, subindex| SdoRequest::Upload { index, subindex };
    let value = |response: SdoResponse| match response {
        SdoResponse::Upload { data, .. } => data.to_u32(),
        other => panic!("{other:?}"),
    };
    assert_eq!(value(ask(upload(0x1000, 0))), 0x0002_0192);
    assert_eq!(value(ask(upload(0x1017, 0))), 100);
    assert_eq!(value(ask(upload(0x1018, 0))), 1);
    assert_eq!(value(ask(upload(0x1018, 1))), 0);
    let write = SdoRequest::Download { index: 0x1017, subindex: 0, data: SdoData::from_u16(250) };
    assert_eq!(ask(write), SdoResponse::DownloadAck { index: 0x1017, subindex: 0 });
    assert_eq!(value(ask(upload(0x1017, 0))), 250);
    let abort = |response: SdoResponse| match response {
        SdoResponse::Abort { code, .. } => code,
        other => panic!("{other:?}"),
    };
    assert_eq!(abort(ask(upload(0x6064, 0))), abort_code::NO_OBJECT);
    assert_eq!(abort(ask(upload(0x1018, 4))), abort_code::NO_SUBINDEX);
    let read_only = SdoRequest::Download { index: 0x1000, subindex: 0, data: SdoData::from_u32(1) };
    assert_eq!(abort(ask(read_only)), abort_code::READ_ONLY);
    let wrong_length = SdoRequest::Download { index: 0x1017, subindex: 0, data: SdoData::from_u32(1) };
    assert_eq!(abort(ask(wrong_length)), abort_code::LENGTH_MISMATCH);
    assert_eq!(abort(ask(SdoRequest::Unsupported([0x21, 0x17, 0x10, 0, 4, 0, 0, 0]))), abort_code::COMMAND_UNKNOWN);
}

#[test]
fn heartbeat_period_follows_object_0x1017() {
    let n = node(0x12);
    let mut drive = WheelDriveNode::new(n);
    let mut beats = Vec::new();
    for ms in 0..1000u64 {
        if ms == 500 {
            let request = SdoRequest::Download { index: 0x1017, subindex: 0, data: SdoData::from_u16(50) };
            drive.on_frame(&CanopenMessage::SdoRequest { node: n, request }.encode(), ms * MS);
        }
        for frame in drive.tick(ms * MS) {
            if let Ok(CanopenMessage::Heartbeat { state: NmtState::PreOperational, .. }) =
                CanopenMessage::decode(&frame)
            {
                beats.push(ms);
            }
        }
    }
    let before: Vec<u64> = beats.iter().copied().filter(|&ms| ms < 500).collect();
    let after: Vec<u64> = beats.iter().copied().filter(|&ms| ms > 500).collect();
    assert_eq!(before, vec![100, 200, 300, 400]);
    assert_eq!(after, (1..10).map(|i| 500 + 50 * i).collect::<Vec<_>>());
}

#[test]
fn hundred_sync_cycles_at_50_hz_give_the_integrated_positions() {
    let mut rig = Rig::new();
    // Set before the first tick: the drives' clocks start at 0 with these speeds.
    let (v_mps, omega_radps) = (0.3, 1.5);
    rig.set_twist(v_mps, omega_radps);
    let speeds = rig.kinematics.wheel_speeds_from_twist(v_mps, omega_radps);
    let counts_per_rad = f64::from(rig.kinematics.counts_per_rev) / TAU;
    rig.run_ms(2_020);
    let counters = rig.master.counters();
    assert_eq!(counters.syncs_sent, 101);
    // The first SYNC (t = 0) finds the drives initialising; the 100 after it are complete.
    assert_eq!((counters.cycles_complete, counters.cycles_incomplete), (100, 1));
    assert_eq!(rig.cycles.len(), 100);
    let mut worst_counts = 0.0f64;
    for cycle in &rig.cycles {
        let t_s = cycle.stamp_ns as f64 * 1e-9;
        for (wheel, speed_radps) in speeds.iter().enumerate() {
            let integrated = speed_radps * counts_per_rad * t_s;
            let error = f64::from(cycle.positions_counts[wheel]) - integrated.floor();
            worst_counts = worst_counts.max(error.abs());
            assert_eq!(cycle.velocities_counts_per_s[wheel], (speed_radps * counts_per_rad).round() as i32);
        }
    }
    assert!(worst_counts <= 1.0, "worst {worst_counts} counts");
    let (v_bound, omega_bound) = rig.kinematics.twist_resolution(0.02);
    let mut worst = (0.0f64, 0.0f64);
    for pair in rig.cycles.windows(2) {
        assert_eq!(pair[1].cycle, pair[0].cycle + 1);
        let dt_s = (pair[1].stamp_ns - pair[0].stamp_ns) as f64 * 1e-9;
        let (v, omega) = rig.kinematics.twist_from_encoders(&pair[0], &pair[1], dt_s).unwrap();
        worst = (worst.0.max((v - v_mps).abs()), worst.1.max((omega - omega_radps).abs()));
    }
    assert!(worst.0 < v_bound && worst.1 < omega_bound, "{worst:?} vs {v_bound} {omega_bound}");
    println!(
        "100 SYNCs at 50 Hz: {} complete cycles, positions within {worst_counts} counts of the integral; \
         twist error {:.2e} m/s, {:.2e} rad/s (bounds {v_bound:.2e}, {omega_bound:.2e})",
        rig.cycles.len(),
        worst.0,
        worst.1
    );
}

#[test]
fn head_follows_an_rpdo_target_at_the_rate_limit() {
    let mut rig = Rig::up();
    let start_ns = rig.now_ns;
    // Tilt beyond its limit: clamped to π/2 by the master (and the head).
    rig.master.command_head(1.2, 3.0, &mut rig.master_bus).unwrap();
    let mut samples = Vec::new();
    for _ in 0..2_000 {
        rig.step();
        if let Some(angles) = rig.master.head_angles()
            && samples.last().is_none_or(|&(t, _, _)| t != angles.stamp_ns)
        {
            samples.push((angles.stamp_ns, angles.pan_rad, angles.tilt_rad));
        }
    }
    let mut fastest_radps = 0.0f64;
    for pair in samples.windows(2) {
        let dt_s = (pair[1].0 - pair[0].0) as f64 * 1e-9;
        fastest_radps =
            fastest_radps.max((pair[1].1 - pair[0].1).abs() / dt_s).max((pair[1].2 - pair[0].2).abs() / dt_s);
    }
    // One µrad of rounding on each of two samples.
    assert!(fastest_radps <= 1.0 + 2e-6 / 0.02, "{fastest_radps}");
    let mut worst = 0.0f64;
    for &(t, pan, tilt) in &samples {
        let elapsed_s = t.saturating_sub(start_ns) as f64 * 1e-9;
        worst = worst.max((pan - elapsed_s.min(1.2)).abs()).max((tilt - elapsed_s.min(FRAC_PI_2)).abs());
    }
    assert!(worst <= 1e-6, "worst deviation from the rate-limited path {worst} rad");
    let last = samples.last().unwrap();
    assert!((last.1 - 1.2).abs() < 1e-6 && (last.2 - FRAC_PI_2).abs() < 1e-6);
    println!(
        "head: {} samples, fastest axis {fastest_radps:.6} rad/s, within {worst:.1e} rad of the 1 rad/s ramp, \
         at the target after {:.2} s",
        samples.len(),
        FRAC_PI_2
    );
}

#[test]
fn a_silent_drive_goes_missing_and_comes_back_by_itself() {
    let mut rig = Rig::up();
    rig.set_twist(0.5, 0.0);
    rig.run_ms(100);
    let silent_node = WHEEL_DRIVE_NODES[2];
    let silent_at = rig.now_ns;
    let complete_before = rig.master.counters().cycles_complete;
    rig.drives[2].0.set_silent(true);
    rig.run_ms(500);
    let lost = rig.events_since(silent_at, |e| matches!(e, MasterEvent::NodeLost { .. }));
    let [(lost_at, MasterEvent::NodeLost { node, last_heard_ns: Some(last_heard_ns) })] = lost.as_slice() else {
        panic!("expected one NodeLost, got {lost:?}")
    };
    assert_eq!(*node, silent_node);
    assert_eq!(rig.health(silent_node), NodeHealth::Missing { since_ns: *last_heard_ns });
    // Missing exactly when the consumer time (300 ms) has passed since the last heartbeat.
    assert_eq!(lost_at - last_heard_ns, 301 * MS);
    assert_eq!(rig.master.counters().cycles_complete, complete_before, "no cycle completes without the drive");
    let incomplete = rig.events_since(silent_at, |e| matches!(e, MasterEvent::CycleIncomplete { .. }));
    assert!(incomplete.len() >= 24, "{}", incomplete.len());
    assert!(incomplete.iter().all(
        |(_, e)| matches!(e, MasterEvent::CycleIncomplete { answered, .. } if answered == &[true, true, false, true])
    ));

    let resumed_at = rig.now_ns;
    rig.drives[2].0.set_silent(false);
    rig.run_ms(150);
    let back =
        rig.events_since(resumed_at, |e| matches!(e, MasterEvent::NodeBack { .. } | MasterEvent::NodeBooted { .. }));
    assert_eq!(back.len(), 2, "{back:?}");
    assert_eq!(back[0].1, MasterEvent::NodeBack { node: silent_node, state: NmtState::BootUp });
    assert_eq!(rig.drives[2].0.nmt_state(), NmtState::Operational);
    assert_eq!(rig.health(silent_node), NodeHealth::Operational);
    let first_complete = rig.cycles.iter().find(|c| c.stamp_ns >= resumed_at).unwrap();
    println!(
        "silent drive: lost {} ms after silence ({} ms after its last heartbeat), {} incomplete cycles reported, \
         back {} ms after resuming, first complete cycle {} ms after resuming",
        (lost_at - silent_at) / MS,
        (lost_at - last_heard_ns) / MS,
        incomplete.len(),
        (back[0].0 - resumed_at) / MS,
        (first_complete.stamp_ns - resumed_at) / MS
    );
}

#[test]
fn nmt_commands_drive_the_device_state_machine() {
    let mut rig = Rig::up();
    let n = WHEEL_DRIVE_NODES[1];
    let nmt = |rig: &mut Rig, command| {
        let frame = CanopenMessage::Nmt { command, target: NmtTarget::Node(n) }.encode();
        rig.master_bus.send(&frame).unwrap();
    };
    // Stopped: no PDOs, no SDO answers, heartbeats say so; the master leaves a stopped node alone.
    nmt(&mut rig, NmtCommand::Stop);
    rig.run_ms(150);
    assert_eq!(rig.drives[1].0.nmt_state(), NmtState::Stopped);
    assert_eq!(rig.health(n), NodeHealth::NotOperational(NmtState::Stopped));
    let incomplete = rig.master.counters().cycles_incomplete;
    let upload = CanopenMessage::SdoRequest { node: n, request: SdoRequest::Upload { index: 0x1017, subindex: 0 } };
    rig.master_bus.send(&upload.encode()).unwrap();
    rig.run_ms(100);
    assert!(rig.seen.sdo_responses.is_empty());
    assert_eq!(rig.master.counters().cycles_incomplete, incomplete + 5);
    assert_eq!(rig.drives[1].0.nmt_state(), NmtState::Stopped);

    // Pre-operational: its heartbeat makes the master start it again.
    nmt(&mut rig, NmtCommand::EnterPreOperational);
    let at = rig.now_ns;
    rig.run_ms(120);
    assert_eq!(rig.drives[1].0.nmt_state(), NmtState::Operational);
    rig.run_ms(100);
    assert_eq!(rig.health(n), NodeHealth::Operational);
    assert!(rig.events_since(at, |e| matches!(e, MasterEvent::NodeBooted { .. })).is_empty());

    // Reset communication restores the heartbeat time written before it, and the node boots.
    let write = SdoRequest::Download { index: 0x1017, subindex: 0, data: SdoData::from_u16(20) };
    rig.master_bus.send(&CanopenMessage::SdoRequest { node: n, request: write }.encode()).unwrap();
    rig.run_ms(2);
    nmt(&mut rig, NmtCommand::ResetCommunication);
    let reset_at = rig.now_ns;
    rig.run_ms(5);
    rig.master_bus.send(&upload.encode()).unwrap();
    rig.run_ms(5);
    assert_eq!(
        rig.seen.sdo_responses,
        vec![
            SdoResponse::DownloadAck { index: 0x1017, subindex: 0 },
            SdoResponse::Upload { index: 0x1017, subindex: 0, data: SdoData::from_u16(100) },
        ]
    );
    let booted = rig.events_since(reset_at, |e| matches!(e, MasterEvent::NodeBooted { .. }));
    assert_eq!(booted.len(), 1);
    assert_eq!(rig.drives[1].0.nmt_state(), NmtState::Operational);
}

#[test]
fn an_emergency_is_reported_with_its_code_and_cleared() {
    let mut rig = Rig::up();
    let drive = WHEEL_DRIVE_NODES[1];
    let at = rig.now_ns;
    // 0x2310: continuous over-current (CiA 301 class "current, device output side").
    rig.drives[1].0.set_fault(Some(0x2310));
    rig.run_ms(5);
    let emcy = rig.events_since(at, |e| matches!(e, MasterEvent::Emergency { .. }));
    assert_eq!(emcy.len(), 1);
    assert_eq!(emcy[0].1, MasterEvent::Emergency { node: drive, code: 0x2310, error_register: 0x03 });
    assert_eq!(rig.health(drive), NodeHealth::Fault { code: 0x2310 });
    // The drive keeps answering SYNC: a fault is reported, not a reason to stop odometry here.
    let cycles = rig.master.counters().cycles_complete;
    rig.run_ms(100);
    assert!(rig.master.counters().cycles_complete >= cycles + 4);
    let cleared_at = rig.now_ns;
    rig.drives[1].0.set_fault(None);
    rig.run_ms(5);
    let reset = rig.events_since(cleared_at, |e| matches!(e, MasterEvent::Emergency { .. }));
    assert_eq!(reset.len(), 1);
    assert_eq!(reset[0].1, MasterEvent::Emergency { node: drive, code: 0, error_register: 0 });
    assert_eq!(rig.health(drive), NodeHealth::Operational);
}

#[test]
fn without_sync_there_are_no_pdos_and_nothing_breaks() {
    let mut rig = Rig::up();
    rig.set_twist(0.2, 0.1);
    rig.run_ms(100);
    rig.master.set_sync_enabled(false, rig.now_ns);
    rig.run_ms(5);
    let stopped_at = rig.now_ns;
    let (tpdos, syncs, heartbeats) = (rig.seen.tpdos, rig.seen.syncs, rig.seen.heartbeats);
    let incomplete = rig.master.counters().cycles_incomplete;
    rig.run_ms(1_000);
    assert_eq!(rig.seen.syncs, syncs);
    assert_eq!(rig.seen.tpdos, tpdos, "PDOs without SYNC");
    assert!(rig.seen.heartbeats >= heartbeats + 5 * 9, "heartbeats continue");
    assert!(rig.all_operational());
    assert_eq!(rig.master.counters().cycles_incomplete, incomplete);
    assert!(rig.events_since(stopped_at, |_| true).is_empty(), "{:?}", rig.events_since(stopped_at, |_| true));
    let last = *rig.master.encoders().unwrap();
    rig.master.set_sync_enabled(true, rig.now_ns);
    rig.run_ms(200);
    let resumed = *rig.master.encoders().unwrap();
    assert_eq!(resumed.cycle, last.cycle + 10);
    let dt_s = (resumed.stamp_ns - last.stamp_ns) as f64 * 1e-9;
    let (v, omega) = rig.kinematics.twist_from_encoders(&last, &resumed, dt_s).unwrap();
    assert!((v - 0.2).abs() < 1e-4 && (omega - 0.1).abs() < 1e-3, "{v} {omega}");
}

#[test]
fn a_babbling_node_does_not_stop_the_cycles() {
    // 9 frames/ms saturates a 1 Mbit/s bus (about 9000 8-byte standard frames/s); 1000/ms and
    // 2000/ms are only possible on the loopback bus, which has no arbitration. Each step the
    // babbler's burst comes first, so its frames queue up in front of the drives' TPDOs: up to
    // about 1000 frames a millisecond every receive queue (1024 frames) holds them all; at
    // 2000/ms each burst evicts the TPDOs and heartbeats of the millisecond before from the
    // master's queue, and the measurement shows what that costs (and that it recovers).
    for (frames_per_ms, run_ms, min_complete_percent) in
        [(9usize, 1_000u64, 100.0), (1_000, 500, 100.0), (2_000, 400, 0.0)]
    {
        let mut rig = Rig::up();
        rig.babbler.as_mut().unwrap().frames_per_ms = frames_per_ms;
        let before = rig.master.counters();
        rig.run_ms(run_ms);
        let after = rig.master.counters();
        let cycles = after.syncs_sent - before.syncs_sent;
        let complete = after.cycles_complete - before.cycles_complete;
        let percent = 100.0 * complete as f64 / cycles as f64;
        println!(
            "babbler {frames_per_ms} frames/ms: {complete}/{cycles} cycles complete ({percent:.0} %), master: {} foreign, \
             {} malformed of {} frames, {} dropped by its queue; health {:?}",
            after.foreign_frames - before.foreign_frames,
            after.malformed_frames - before.malformed_frames,
            after.frames_received - before.frames_received,
            rig.master_bus.dropped_frames(),
            rig.master.node_health().map(|(_, h)| h).collect::<Vec<_>>(),
        );
        assert!(percent >= min_complete_percent, "{percent} %");
        assert!(after.foreign_frames > before.foreign_frames);
        if frames_per_ms <= 1_000 {
            assert!(rig.all_operational());
        }
        // The babbler stops: everything is back to normal within a heartbeat period.
        rig.babbler.as_mut().unwrap().frames_per_ms = 0;
        rig.run_ms(400);
        let settled = rig.master.counters();
        rig.run_ms(200);
        assert_eq!(rig.master.counters().cycles_complete - settled.cycles_complete, 10);
        assert!(rig.all_operational());
    }
}
