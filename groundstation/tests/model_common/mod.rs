//! Robots as the ground sees them: real protocol endpoints, real submaps from the mapper crate.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)]

use groundstation::model::TeamModel;
use mapper::{MapPoint, Submap};
use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion};
use protocol::delivery::{Endpoint, EndpointConfig};
use protocol::frame::Framing;
use protocol::message::{
    ClassBytes, Constraint, ConstraintId, ConstraintKind, FilterHealth, FilterStatus, Mode, PoseEstimate,
    ResourceUsage, SubmapHeader, Telemetry,
};
use protocol::{AnyMessage, AuthKey, Cov6, MAX_PACKET_BYTES, NodeId, NodeRef, Pose3, RobotId, SubmapId};

pub const FRAMING: Framing = Framing::Datagram { mtu: 1200 };

pub fn key() -> AuthKey {
    AuthKey::from_bytes(&[0x5a; 32]).unwrap()
}

/// One robot's ground-link endpoint.
pub struct SimRobot {
    pub id: u8,
    pub endpoint: Box<Endpoint>,
    /// Reliable messages waiting for room in the send window (as the comms node's backlog).
    backlog: std::collections::VecDeque<AnyMessage>,
}

impl SimRobot {
    pub fn new(id: u8, key: Option<AuthKey>) -> SimRobot {
        let mut config = EndpointConfig::new(NodeId(id), FRAMING, 10_000_000, 10_000_000);
        if let Some(key) = key {
            config = config.with_auth_key(key);
        }
        SimRobot { id, endpoint: Box::new(Endpoint::new(config).unwrap()), backlog: Default::default() }
    }

    pub fn send(&mut self, now_ns: u64, message: impl Into<AnyMessage>) {
        self.backlog.push_back(message.into());
        self.flush(now_ns);
    }

    fn flush(&mut self, now_ns: u64) {
        while let Some(m) = self.backlog.front() {
            match self.endpoint.send(now_ns / 1_000_000, NodeId::GROUND, m) {
                Ok(()) => {
                    self.backlog.pop_front();
                }
                Err(protocol::delivery::SendError::QueueFull { .. }) => return,
                Err(e) => panic!("{e}"),
            }
        }
    }

    /// Everything the robot transmits now.
    pub fn transmit(&mut self, now_ns: u64) -> Vec<Vec<u8>> {
        let mut out = Vec::new();
        let mut buf = vec![0u8; MAX_PACKET_BYTES];
        self.flush(now_ns);
        while let Some(len) = self.endpoint.poll_transmit(now_ns / 1_000_000, &mut buf) {
            out.push(buf[..len].to_vec());
        }
        out
    }
}

/// Moves packets both ways between robots and model at `now_ns`; returns what reached the ground.
pub fn exchange(model: &mut TeamModel, robots: &mut [&mut SimRobot], now_ns: u64) -> Vec<Vec<u8>> {
    let mut delivered = Vec::new();
    for _ in 0..100_000 {
        let mut moved = false;
        for robot in robots.iter_mut() {
            for packet in robot.transmit(now_ns) {
                model.ingest(now_ns, &packet);
                delivered.push(packet);
                moved = true;
            }
        }
        while let Some((to, packet)) = model.poll_transmit(now_ns) {
            if let Some(robot) = robots.iter_mut().find(|r| r.id == to) {
                let _ = robot.endpoint.handle_packet(now_ns / 1_000_000, &packet);
                while robot.endpoint.poll_deliver().is_some() {}
                moved = true;
            }
        }
        if !moved {
            break;
        }
    }
    delivered
}

pub fn cov(sigma: f64) -> Cov6 {
    let mut full = [[0.0; 6]; 6];
    for (i, row) in full.iter_mut().enumerate() {
        row[i] = sigma * sigma;
    }
    Cov6::from_full(&full)
}

pub fn pose3(t: &Isometry3<f64>) -> Pose3 {
    mapper::wire::pose3(t)
}

pub fn planar(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(x, y, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw))
}

pub fn pose(robot: u8, stamp_ns: u64, submap: u32, t: &Isometry3<f64>) -> PoseEstimate {
    PoseEstimate {
        robot: RobotId(robot),
        stamp_ns,
        submap: SubmapId { robot: RobotId(robot), index: submap },
        t_submap_body: pose3(t),
        covariance: cov(0.05),
    }
}

pub fn telemetry(robot: u8, stamp_ns: u64, telemetry_bytes: u64) -> Telemetry {
    let mut classes = heapless::Vec::new();
    classes.push(ClassBytes { message_key: 0x11, tx_bytes: telemetry_bytes, tx_packets: 1 }).unwrap();
    Telemetry {
        robot: RobotId(robot),
        stamp_ns,
        mode: Mode::Autonomous,
        filter: FilterHealth { status: FilterStatus::Nominal, position_std_m: 0.1, yaw_std_rad: 0.01, vo_age_ms: 50 },
        resources: ResourceUsage { cpu_permille: 400, mem_used_kib: 1000, mem_total_kib: 4000 },
        tasks: heapless::Vec::new(),
        queues: heapless::Vec::new(),
        links: heapless::Vec::new(),
        auth_rejections: 0,
        classes,
    }
}

/// A flat square patch of terrain `size_m` wide at height `z_m` (submap frame), one obstacle
/// point in its middle.
pub fn patch_submap(robot: u8, index: u32, size_m: f32, z_m: f32) -> Submap {
    let mut s = Submap::new(u16::from(robot), index, 0, Isometry3::identity(), Matrix6::zeros());
    let n = (size_m / 0.05) as i32;
    for i in 0..n {
        for j in 0..n {
            let p = Point3::new(i as f32 * 0.05 + 0.025, j as f32 * 0.05 + 0.025, z_m);
            s.cloud.points.push(MapPoint { position_m: p, intensity: 90, obstacle: i == n / 2 && j == n / 2 });
        }
    }
    s
}

/// The header and chunks a robot sends for a finished submap.
pub fn submap_messages(submap: &Submap, switch: Option<Isometry3<f64>>) -> Vec<AnyMessage> {
    let mut payload = Vec::new();
    mapper::exchange::encode_submap(submap, &mut payload);
    let id = SubmapId { robot: RobotId(submap.robot_id as u8), index: submap.index };
    let (payload_bytes, chunk_count, payload_crc32) = mapper::wire::payload_fields(&payload).unwrap();
    let header = SubmapHeader {
        submap: id,
        started_stamp_ns: submap.start_stamp_ns,
        finished_stamp_ns: submap.end_stamp_ns,
        switch: switch.map(|t| mapper::wire::frame_switch(&t, &Matrix6::identity().scale(1e-4))),
        encoding: mapper::wire::SUBMAP_ENCODING_EXCHANGE_V1,
        payload_bytes,
        chunk_count,
        payload_crc32,
    };
    let mut out = vec![AnyMessage::from(header)];
    for i in 0..usize::from(chunk_count) {
        out.push(mapper::wire::chunk(id, &payload, i).unwrap().into());
    }
    out
}

/// A submap match between two robots' first submaps: `t_a_b` maps b's frame into a's.
pub fn submap_match(by: u8, seq: u32, a: (u8, u32), b: (u8, u32), t_a_b: &Isometry3<f64>) -> Constraint {
    let node = |(robot, index): (u8, u32)| NodeRef::SubmapOrigin(SubmapId { robot: RobotId(robot), index });
    Constraint {
        id: ConstraintId { robot: RobotId(by), seq },
        kind: ConstraintKind::SubmapMatch,
        stamp_ns: 0,
        from: node(a),
        to: node(b),
        t_from_to: pose3(t_a_b),
        covariance: cov(0.01),
    }
}
