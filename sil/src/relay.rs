//! The radio between the robots of a simulated team, for the process runner: UDP on 127.0.0.1
//! through one [`hal::emulator::DuplexEmulator`] per pair of robots, on the wall clock.
//!
//! Robot `a`'s comms process has one UDP team link; its peers are the relay's sockets
//! `S[a][b]`, one per other robot `b`. A datagram arriving on `S[a][b]` is robot `a` talking to
//! `b`: it enters the `a → b` direction of the pair's emulator, and what the emulator delivers
//! leaves from `S[b][a]` to robot `b`'s link, so `b` sees it come from its configured peer
//! address. Datagrams are the emulator's packets (the link's fragments, each charged by the
//! emulator's framing), so loss hits fragments as a real radio's would.
//!
//! The ground link ([`Relay::enable_ground`]): robot `r`'s comms sends its ground link to the
//! relay's socket `G[r]` (`link.ground_feed`). The relay reassembles the datagrams into
//! `protocol` packets, delays them through a per-robot [`DuplexEmulator`] (the thesis's ground
//! link has a 4 s round trip; the default here is 1 s one way) and hands them to a
//! [`GroundEnd`]: the ground station at `--feed` (one address for the whole team) or the
//! in-process stand-in. What the ground sends back is routed by the packet's destination node,
//! delayed the same way, and sent from `G[r]` to the address robot `r`'s ground link sent from.
//! The [`GroundEnd`] records both directions in the mission's `ground_feed.log`.

use std::collections::BTreeMap;
use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};

use hal::emulator::{DuplexEmulator, EmulatorConfig, Side};
use protocol::NodeId;
use protocol::frame::Framing;
use protocol::frame::datagram::{Reassembler, Segmenter};

use crate::ground_end::{GroundEnd, GroundEndStats};

/// Larger than any datagram the UDP link sends.
const DATAGRAM_MAX: usize = 2048;
/// Datagrams taken from one socket per pump at most.
const MAX_PER_PUMP: usize = 256;

#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    #[error("relay socket: {0}")]
    Socket(std::io::Error),
}

/// MTU of the robots' ground links (`hal::udp` default), for re-framing uplink packets.
const GROUND_MTU: usize = 1200;
/// Rate of the emulated ground link: the robots' own rate caps are far below it, so it only
/// delays.
const GROUND_EMULATOR_RATE_BYTES_PER_S: u64 = 1_000_000;

/// What the emulated ground link does to every packet, both ways, on the mission clock.
#[derive(Debug, Clone, PartialEq)]
pub struct GroundLinkEmulation {
    /// One-way delay, ms.
    pub delay_ms: u64,
    /// Probability that a packet is lost (each direction, each packet: a lost submap chunk is
    /// retransmitted by the reliable stream, a lost pose is simply gone).
    pub loss: f64,
    /// Mission-time intervals `[start_ms, end_ms)` in which the link carries nothing.
    pub outages_ms: Vec<(u64, u64)>,
    /// Seed of the loss draws.
    pub seed: u64,
}

impl Default for GroundLinkEmulation {
    fn default() -> Self {
        GroundLinkEmulation { delay_ms: 1_000, loss: 0.0, outages_ms: Vec::new(), seed: 0 }
    }
}

type GroundReassembler = Reassembler<2, { hal::link::MAX_LINK_PACKET_BYTES }>;

/// One robot's side of the relayed ground link.
struct GroundPort {
    node: NodeId,
    socket: UdpSocket,
    /// Where the robot's ground link sends from (learnt from its datagrams).
    robot_addr: Option<SocketAddr>,
    reassembler: Box<GroundReassembler>,
    segmenter: Segmenter,
    /// Side A: the robot, side B: the ground.
    link: DuplexEmulator,
}

impl std::fmt::Debug for GroundPort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GroundPort").field("node", &self.node).field("robot_addr", &self.robot_addr).finish()
    }
}

#[derive(Debug)]
struct Ground {
    ports: Vec<GroundPort>,
    end: GroundEnd,
}

/// Counters of the relay.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RelayStats {
    pub received: u64,
    pub forwarded: u64,
    pub send_errors: u64,
    /// Datagrams before the destination robot's address was known.
    pub unroutable: u64,
    /// Ground packets (both directions) that entered the ground link emulation.
    pub ground_packets: u64,
    /// Ground datagrams that did not reassemble into a packet.
    pub ground_frame_errors: u64,
}

/// See the module documentation.
#[derive(Debug)]
pub struct Relay {
    robots: usize,
    /// `sockets[a][b]`: robot `a`'s peer address for robot `b` (`None` for `a == b`).
    sockets: Vec<Vec<Option<UdpSocket>>>,
    /// Each robot's team-link address.
    robot_addrs: Vec<Option<SocketAddr>>,
    /// Pair `(a, b)`, `a < b`; side A is robot `a`.
    radios: BTreeMap<(usize, usize), DuplexEmulator>,
    buf: Box<[u8]>,
    stats: RelayStats,
    ground: Option<Ground>,
}

impl Relay {
    /// Binds the sockets for `robots` robots; the pair `(a, b)`'s emulator is `radio` with the
    /// same seed the lockstep runner gives that pair.
    pub fn bind(robots: usize, radio: &EmulatorConfig, seed: u64) -> Result<Relay, RelayError> {
        let mut sockets = Vec::with_capacity(robots);
        for a in 0..robots {
            let mut row = Vec::with_capacity(robots);
            for b in 0..robots {
                row.push(if a == b {
                    None
                } else {
                    let socket = UdpSocket::bind("127.0.0.1:0").map_err(RelayError::Socket)?;
                    socket.set_nonblocking(true).map_err(RelayError::Socket)?;
                    Some(socket)
                });
            }
            sockets.push(row);
        }
        let mut radios = BTreeMap::new();
        for a in 0..robots {
            for b in a + 1..robots {
                let pair_seed = seed.wrapping_mul(1_000_003).wrapping_add((a * 64 + b) as u64);
                radios.insert((a, b), DuplexEmulator::symmetric(radio.clone().with_seed(pair_seed)));
            }
        }
        Ok(Relay {
            robots,
            sockets,
            robot_addrs: vec![None; robots],
            radios,
            buf: vec![0; DATAGRAM_MAX].into_boxed_slice(),
            stats: RelayStats::default(),
            ground: None,
        })
    }

    /// Relays every robot's ground link to `end` through `emulation` (see the module
    /// documentation); `nodes[r]` is robot `r`'s node id.
    pub fn enable_ground(
        &mut self,
        nodes: &[NodeId],
        end: GroundEnd,
        emulation: &GroundLinkEmulation,
    ) -> Result<(), RelayError> {
        let framing = Framing::Datagram { mtu: GROUND_MTU as u16 };
        let emulator = EmulatorConfig {
            latency_ms: emulation.delay_ms,
            loss: emulation.loss,
            outages: emulation.outages_ms.clone(),
            queue_bytes: 1 << 20,
            ..EmulatorConfig::ideal(GROUND_EMULATOR_RATE_BYTES_PER_S, framing)
        };
        let mut ports = Vec::with_capacity(nodes.len());
        for (i, &node) in nodes.iter().enumerate() {
            let socket = UdpSocket::bind("127.0.0.1:0").map_err(RelayError::Socket)?;
            socket.set_nonblocking(true).map_err(RelayError::Socket)?;
            ports.push(GroundPort {
                node,
                socket,
                robot_addr: None,
                reassembler: Box::new(GroundReassembler::new(2_000)),
                segmenter: Segmenter::new(GROUND_MTU).map_err(|e| RelayError::Socket(std::io::Error::other(e)))?,
                link: DuplexEmulator::symmetric(emulator.clone().with_seed(emulation.seed ^ (i as u64 + 1))),
            });
        }
        self.ground = Some(Ground { ports, end });
        Ok(())
    }

    /// The address robot `robot`'s ground link sends to (after [`Relay::enable_ground`]).
    pub fn ground_addr(&self, robot: usize) -> Option<SocketAddr> {
        self.ground.as_ref()?.ports.get(robot)?.socket.local_addr().ok()
    }

    /// The ground end's counters.
    pub fn ground_stats(&self) -> Option<GroundEndStats> {
        self.ground.as_ref().map(|g| g.end.stats())
    }

    /// Ends the relay's ground link: flushes and returns the ground end (its log complete).
    pub fn finish_ground(&mut self) -> Option<GroundEnd> {
        let mut ground = self.ground.take()?;
        let _ = ground.end.flush();
        Some(ground.end)
    }

    /// The address robot `robot` sends to for `peer`.
    pub fn peer_addr(&self, robot: usize, peer: usize) -> Option<SocketAddr> {
        self.sockets.get(robot)?.get(peer)?.as_ref()?.local_addr().ok()
    }

    /// Where robot `robot`'s team link receives.
    pub fn set_robot_addr(&mut self, robot: usize, addr: SocketAddr) {
        if let Some(slot) = self.robot_addrs.get_mut(robot) {
            *slot = Some(addr);
        }
    }

    pub fn stats(&self) -> RelayStats {
        self.stats
    }

    /// Moves what arrived into the emulators and what they deliver by `now_ms` to the robots
    /// and the ground.
    pub fn pump(&mut self, now_ms: u64) {
        self.pump_team(now_ms);
        if let Some(ground) = &mut self.ground {
            pump_ground(ground, now_ms, &mut self.buf, &mut self.stats);
        }
    }

    fn pump_team(&mut self, now_ms: u64) {
        for a in 0..self.robots {
            for b in 0..self.robots {
                let Some(Some(socket)) = self.sockets.get(a).and_then(|row| row.get(b)) else { continue };
                for _ in 0..MAX_PER_PUMP {
                    match socket.recv_from(&mut self.buf) {
                        Ok((len, _)) => {
                            self.stats.received += 1;
                            let (pair, side) = if a < b { ((a, b), Side::A) } else { ((b, a), Side::B) };
                            if let (Some(radio), Some(bytes)) = (self.radios.get_mut(&pair), self.buf.get(..len)) {
                                radio.send(side, now_ms, bytes);
                            }
                        }
                        Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                        // ICMP port-unreachable from a robot that is restarting, and the like.
                        Err(_) => {}
                    }
                }
            }
        }
        for (&(a, b), radio) in &mut self.radios {
            for (to, from, side) in [(b, a, Side::B), (a, b, Side::A)] {
                while let Some(packet) = radio.poll(side, now_ms) {
                    let socket = self.sockets.get(to).and_then(|row| row.get(from)).and_then(Option::as_ref);
                    match (socket, self.robot_addrs.get(to).copied().flatten()) {
                        (Some(socket), Some(addr)) => match socket.send_to(&packet, addr) {
                            Ok(_) => self.stats.forwarded += 1,
                            Err(_) => self.stats.send_errors += 1,
                        },
                        _ => self.stats.unroutable += 1,
                    }
                }
            }
        }
    }
}

fn pump_ground(ground: &mut Ground, now_ms: u64, buf: &mut [u8], stats: &mut RelayStats) {
    let now_ns = now_ms.saturating_mul(1_000_000);
    for port in &mut ground.ports {
        for _ in 0..MAX_PER_PUMP {
            match port.socket.recv_from(buf) {
                Ok((len, from)) => {
                    port.robot_addr = Some(from);
                    match port.reassembler.push(now_ms, 0, buf.get(..len).unwrap_or_default()) {
                        Ok(Some(packet)) => {
                            stats.ground_packets += 1;
                            port.link.send(Side::A, now_ms, packet);
                        }
                        Ok(None) => {}
                        Err(_) => stats.ground_frame_errors += 1,
                    }
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                Err(_) => {}
            }
        }
        while let Some(packet) = port.link.poll(Side::B, now_ms) {
            ground.end.downlink(now_ns, port.node, &packet);
        }
    }
    while let Some((node, packet)) = ground.end.poll_uplink(now_ns) {
        if let Some(port) = ground.ports.iter_mut().find(|p| p.node == node) {
            stats.ground_packets += 1;
            port.link.send(Side::B, now_ms, packet);
        }
    }
    for port in &mut ground.ports {
        while let Some(packet) = port.link.poll(Side::A, now_ms) {
            let Some(addr) = port.robot_addr else {
                stats.unroutable += 1;
                continue;
            };
            let socket = &port.socket;
            let result = port.segmenter.segment(&packet, |datagram| match socket.send_to(datagram, addr) {
                Ok(_) => stats.forwarded += 1,
                Err(_) => stats.send_errors += 1,
            });
            if result.is_err() {
                stats.ground_frame_errors += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use protocol::frame::datagram::FRAGMENT_HEADER_BYTES;
    use std::time::Duration;

    #[test]
    fn datagrams_cross_the_emulated_radio_to_the_peer() {
        let radio = EmulatorConfig::ideal(1_000_000, Framing::Datagram { mtu: 1200 });
        let mut relay = Relay::bind(3, &radio, 1).unwrap();
        let robot: Vec<UdpSocket> = (0..3).map(|_| UdpSocket::bind("127.0.0.1:0").unwrap()).collect();
        for (i, s) in robot.iter().enumerate() {
            relay.set_robot_addr(i, s.local_addr().unwrap());
            s.set_read_timeout(Some(Duration::from_millis(500))).unwrap();
        }
        robot[0].send_to(b"hello two", relay.peer_addr(0, 2).unwrap()).unwrap();
        robot[2].send_to(b"hello one", relay.peer_addr(2, 1).unwrap()).unwrap();
        std::thread::sleep(Duration::from_millis(20));
        relay.pump(0);
        relay.pump(10);
        let mut buf = [0u8; 64];
        let (len, from) = robot[2].recv_from(&mut buf).unwrap();
        assert_eq!(&buf[..len], b"hello two");
        assert_eq!(from, relay.peer_addr(2, 0).unwrap(), "arrives from robot 2's address for robot 0");
        let (len, from) = robot[1].recv_from(&mut buf).unwrap();
        assert_eq!(&buf[..len], b"hello one");
        assert_eq!(from, relay.peer_addr(1, 2).unwrap());
        assert_eq!(relay.stats().forwarded, 2);
        assert!(relay.peer_addr(1, 1).is_none());
    }

    fn heartbeat(from: NodeId, to: NodeId) -> Vec<u8> {
        let message = protocol::AnyMessage::from(protocol::message::Heartbeat {
            node: from,
            stamp_ns: 1,
            uptime_ms: 1,
            boot_id: 7,
            mode: protocol::message::Mode::Idle,
        });
        let mut buf = [0u8; protocol::MAX_PACKET_BYTES];
        let len = protocol::encode(&message, from, to, 0, &mut buf).unwrap();
        buf[..len].to_vec()
    }

    /// One datagram with fragment message id `id` (a receiver ignores a repeated id).
    fn framed(packet: &[u8], id: u16) -> Vec<u8> {
        let mut out = Vec::new();
        Segmenter::with_first_id(GROUND_MTU, id).unwrap().segment(packet, |d| out.extend_from_slice(d)).unwrap();
        out
    }

    #[test]
    fn ground_packets_cross_the_delayed_link_both_ways_and_are_recorded() {
        let radio = EmulatorConfig::ideal(1_000_000, Framing::Datagram { mtu: 1200 });
        let mut relay = Relay::bind(2, &radio, 1).unwrap();
        let station = UdpSocket::bind("127.0.0.1:0").unwrap();
        station.set_read_timeout(Some(Duration::from_millis(300))).unwrap();
        let log = std::env::temp_dir().join(format!("relay-ground-{}.log", std::process::id()));
        let nodes = [NodeId(1), NodeId(2)];
        let end = GroundEnd::new(Some(station.local_addr().unwrap()), &nodes, Some(&log)).unwrap();
        relay.enable_ground(&nodes, end, &GroundLinkEmulation { delay_ms: 100, ..Default::default() }).unwrap();
        let robot = UdpSocket::bind("127.0.0.1:0").unwrap();
        robot.set_read_timeout(Some(Duration::from_millis(300))).unwrap();

        // Robot index 1 (node 2) to the ground: held for the 100 ms delay.
        let down = heartbeat(NodeId(2), NodeId::GROUND);
        robot.send_to(&framed(&down, 0), relay.ground_addr(1).unwrap()).unwrap();
        std::thread::sleep(Duration::from_millis(20));
        relay.pump(0);
        relay.pump(99);
        station.set_nonblocking(true).unwrap();
        let mut buf = [0u8; 2048];
        assert!(station.recv_from(&mut buf).is_err(), "nothing before the delay");
        station.set_nonblocking(false).unwrap();
        // The delay plus the serialisation of the packet at the emulator's rate (under 1 ms).
        relay.pump(101);
        let (len, mission) = station.recv_from(&mut buf).unwrap();
        // One fragment (its message id is the sender's own): the packet whole.
        assert_eq!(&buf[FRAGMENT_HEADER_BYTES..len], down.as_slice());

        // The station answers the address it heard from; the relay routes by destination node.
        let up = heartbeat(NodeId::GROUND, NodeId(2));
        station.send_to(&framed(&up, 0), mission).unwrap();
        station.send_to(&framed(&heartbeat(NodeId::GROUND, NodeId(9)), 1), mission).unwrap();
        std::thread::sleep(Duration::from_millis(20));
        relay.pump(150);
        relay.pump(249);
        robot.set_nonblocking(true).unwrap();
        assert!(robot.recv_from(&mut buf).is_err(), "nothing before the delay");
        robot.set_nonblocking(false).unwrap();
        relay.pump(251);
        let (len, from) = robot.recv_from(&mut buf).unwrap();
        assert_eq!(&buf[FRAGMENT_HEADER_BYTES..len], up.as_slice());
        assert_eq!(from, relay.ground_addr(1).unwrap(), "from the robot's configured ground address");

        let stats = relay.ground_stats().unwrap();
        assert_eq!((stats.downlink_packets, stats.uplink_packets, stats.unroutable), (1, 1, 1));
        let end = relay.finish_ground().unwrap();
        assert_eq!(end.records(), 2);
        let records = hal::feedlog::read_feed_log(&log).unwrap().records;
        let got: Vec<_> = records.iter().map(|r| (r.recv_ns, r.source, r.packet.clone())).collect();
        assert_eq!(got, vec![(101_000_000, 2, down), (150_000_000, 2, up)]);
        std::fs::remove_file(&log).ok();
    }
}
