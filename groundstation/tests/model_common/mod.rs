//! Robots as the ground sees them: real protocol endpoints, real submaps from the mapper crate.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)]

use std::time::Duration;

use groundstation::model::TeamModel;
use mapper::{MapPoint, Submap};
use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion};
use protocol::delivery::{Endpoint, EndpointConfig};
use protocol::frame::Framing;
use protocol::message::{
    ClassBytes, Command, CommandAck, CommandOutcome, Constraint, ConstraintId, ConstraintKind, FilterHealth,
    FilterStatus, Mode, PoseEstimate, ResourceUsage, SubmapHeader, Telemetry,
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

impl SimRobot {
    /// Sends everything the robot transmits now over a real link.
    pub fn transmit_over(&mut self, link: &mut impl hal::link::Link, now_ms: u64) {
        for packet in self.transmit(now_ms * 1_000_000) {
            link.send(&packet).unwrap();
        }
    }

    /// Handles what arrives on `link` within `wait`, and executes the ground's commands as a
    /// robot would: each must carry the ground's verified HMAC, and is acknowledged `Executed`.
    /// Returns the commands executed.
    pub fn receive_over(&mut self, link: &mut impl hal::link::Link, now_ms: u64, wait: Duration) -> Vec<Command> {
        let mut buf = vec![0u8; hal::link::MAX_LINK_PACKET_BYTES];
        while let Some(len) = link.recv(&mut buf, wait).unwrap() {
            self.endpoint.handle_packet(now_ms, &buf[..len]).unwrap();
        }
        let mut executed = Vec::new();
        while let Some(delivered) = self.endpoint.poll_deliver() {
            if let AnyMessage::Command(command) = delivered.message {
                assert_eq!(delivered.auth.map(|(sender, _)| sender), Some(NodeId::GROUND), "verified by HMAC");
                let ack =
                    CommandAck { robot: RobotId(self.id), command_id: command.id, outcome: CommandOutcome::Executed };
                self.send(now_ms * 1_000_000, ack);
                executed.push(command);
            }
        }
        executed
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
        sensors: None,
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

/// A 4-robot mission over 200 m × 200 m at benchmark scale: each robot maps its 100 m quadrant
/// (`side`² submaps of 10 m × 10 m, points every `spacing_m`) in boustrophedon lanes, with poses
/// and one match to robot 1 each.
pub struct ScaleMission {
    /// Per 10 s step: (robot index, stamp, message) in sending order.
    pub steps: Vec<Vec<(usize, u64, AnyMessage)>>,
    pub payload_bytes: usize,
    pub end_ns: u64,
}

pub const S: u64 = 1_000_000_000;

pub fn terrain(x: f64, y: f64) -> f32 {
    (0.8 * (x * 0.15).sin() + 0.5 * (y * 0.11).cos() + 0.1 * ((x + y) * 0.9).sin()) as f32
}

/// Submap `index` of a robot whose frame sits at `quadrant` in the world: a 10 m square.
pub fn scale_submap(robot: u8, index: u32, origin_world: [f64; 2], spacing_m: f32) -> Submap {
    let mut s =
        Submap::new(u16::from(robot), index, u64::from(index) * 10 * S, Isometry3::identity(), Matrix6::zeros());
    s.end_stamp_ns = s.start_stamp_ns + 10 * S;
    let n = (10.0 / spacing_m) as i32;
    for i in 0..n {
        for j in 0..n {
            let (x, y) = (i as f32 * spacing_m + 0.02, j as f32 * spacing_m + 0.02);
            let z = terrain(origin_world[0] + f64::from(x), origin_world[1] + f64::from(y));
            let obstacle = (i * 7 + j * 13) % 997 == 0;
            s.cloud.points.push(MapPoint { position_m: Point3::new(x, y, z), intensity: 80, obstacle });
        }
    }
    s
}

pub fn scale_mission(side: u32, spacing: f32) -> ScaleMission {
    let quadrants = [[0.0, 0.0], [100.0, 0.0], [0.0, 100.0], [100.0, 100.0]];
    // Everything the robots send, encoded before the clock starts: (step, robot, message).
    let mut payload_bytes = 0usize;
    let mut steps: Vec<Vec<(usize, u64, AnyMessage)>> = Vec::new();
    let mut now = 0u64;
    for index in 0..side * side {
        let mut step = Vec::new();
        let (row, col) = (index / side, index % side);
        let col = if row % 2 == 0 { col } else { side - 1 - col };
        let local = [f64::from(col) * 10.0, f64::from(row) * 10.0];
        for (r, quadrant) in quadrants.iter().enumerate() {
            let id = r as u8 + 1;
            let world = [quadrant[0] + local[0], quadrant[1] + local[1]];
            let s = scale_submap(id, index, world, spacing);
            let switch = (index > 0).then(|| {
                let (prow, pcol) = ((index - 1) / side, (index - 1) % side);
                let pcol = if prow % 2 == 0 { pcol } else { side - 1 - pcol };
                Isometry3::from_parts(
                    Translation3::new(local[0] - f64::from(pcol) * 10.0, local[1] - f64::from(prow) * 10.0, 0.0),
                    Default::default(),
                )
            });
            for m in submap_messages(&s, switch) {
                if let AnyMessage::SubmapChunk(c) = &m {
                    payload_bytes += c.data.len();
                }
                step.push((r, now, m));
            }
            for k in 0..10u64 {
                let t = now + k * S;
                step.push((r, t, pose(id, t, index, &planar(k as f64, 5.0, 0.0)).into()));
            }
            if index == 0 && id > 1 {
                let offset = planar(quadrant[0], quadrant[1], 0.0);
                step.push((r, now, submap_match(id, 0, (1, 0), (id, 0), &offset).into()));
            }
        }
        steps.push(step);
        now += 10 * S;
    }

    ScaleMission { steps, payload_bytes, end_ns: now }
}
