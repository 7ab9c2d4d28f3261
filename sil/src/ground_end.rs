//! The ground end of the robots' ground links, for the mission runners.
//!
//! With a feed address it is a [`UdpLink`] to the ground station (`hal::udp` framing: one
//! `protocol::frame::datagram` fragment per datagram, MTU 1200; every packet fits one): robots'
//! packets go to the feed address from this one socket, and whatever arrives on the socket is
//! taken as uplink and routed by its destination node. Without a feed address an in-process
//! stand-in (one `protocol` [`Endpoint`] as node [`NodeId::GROUND`] per robot, since an endpoint
//! tracks at most `MAX_PEERS` robots) acknowledges what a ground station would, so the robots'
//! reliable ground traffic flows as in a mission with a ground station and the recording holds
//! the whole mission rather than a window of retransmissions.
//!
//! Either way every packet is recorded in a feed log (`hal::feedlog`), with the times a ground
//! station sees: a downlink packet when it reaches the ground, an uplink packet when it leaves
//! it; `source` is the robot's node id (the ground link the packet travelled on, for both
//! directions; the packet's own header tells the direction).

use std::net::SocketAddr;
use std::path::Path;
use std::time::Duration;

use hal::feedlog::{FeedLogError, FeedLogWriter};
use hal::link::{Link, LinkError, MAX_LINK_PACKET_BYTES};
use hal::udp::UdpLink;
use protocol::delivery::{Endpoint, EndpointConfig};
use protocol::frame::Framing;
use protocol::{MAX_PACKET_BYTES, NodeId};

/// The stand-in's rate: far above any robot's ground cap, so it never holds an ack back.
const SINK_RATE_BYTES_PER_S: u64 = 1_000_000;
/// Uplink packets taken from the socket per poll at most.
const MAX_UPLINK_PER_POLL: usize = 256;

#[derive(Debug, thiserror::Error)]
pub enum GroundEndError {
    #[error("ground feed socket: {0}")]
    Link(#[from] LinkError),
    #[error("ground feed log: {0}")]
    Log(#[from] FeedLogError),
    #[error("ground stand-in: {0}")]
    Endpoint(#[from] protocol::delivery::ConfigError),
}

/// Counters of a [`GroundEnd`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct GroundEndStats {
    pub downlink_packets: u64,
    pub downlink_bytes: u64,
    pub uplink_packets: u64,
    pub uplink_bytes: u64,
    /// Uplink packets for no robot of the mission, or that did not decode.
    pub unroutable: u64,
    /// Datagrams the feed socket could not send (no ground station listening, …).
    pub send_errors: u64,
    /// Records the feed log could not take (the first error is kept in `log_error`).
    pub log_errors: u64,
}

enum Far {
    Udp(Box<UdpLink>),
    /// Per robot node id: the stand-in's endpoint for that robot's ground link.
    StandIn(Vec<(NodeId, Box<Endpoint>)>),
}

/// See the module documentation.
pub struct GroundEnd {
    far: Far,
    robots: Vec<NodeId>,
    log: Option<FeedLogWriter>,
    log_error: Option<FeedLogError>,
    buf: Box<[u8]>,
    stats: GroundEndStats,
}

impl std::fmt::Debug for GroundEnd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let far = match &self.far {
            Far::Udp(link) => format!("udp {} -> {:?}", link.local_addr(), link.peers()),
            Far::StandIn(_) => "stand-in".to_owned(),
        };
        f.debug_struct("GroundEnd").field("far", &far).field("stats", &self.stats).finish_non_exhaustive()
    }
}

fn destination(packet: &[u8]) -> Option<NodeId> {
    protocol::codec::decode_header(packet).ok().map(|(header, _)| header.destination)
}

impl GroundEnd {
    /// The ground end for the robots `robots` (node ids): UDP to `feed` (from a socket bound to
    /// `0.0.0.0:0`) or the stand-in; recording into `log` when given.
    pub fn new(feed: Option<SocketAddr>, robots: &[NodeId], log: Option<&Path>) -> Result<Self, GroundEndError> {
        let far = match feed {
            Some(addr) => Far::Udp(Box::new(UdpLink::bind("0.0.0.0:0")?.with_peers([addr]))),
            None => {
                let framing = Framing::Datagram { mtu: 1200 };
                let burst = 4 * EndpointConfig::min_burst_bytes(framing);
                let mut endpoints = Vec::with_capacity(robots.len());
                for &robot in robots {
                    let config = EndpointConfig::new(NodeId::GROUND, framing, SINK_RATE_BYTES_PER_S, burst);
                    endpoints.push((robot, Box::new(Endpoint::new(config)?)));
                }
                Far::StandIn(endpoints)
            }
        };
        Ok(GroundEnd {
            far,
            robots: robots.to_vec(),
            log: log.map(FeedLogWriter::create).transpose()?,
            log_error: None,
            buf: vec![0; MAX_LINK_PACKET_BYTES.max(MAX_PACKET_BYTES)].into_boxed_slice(),
            stats: GroundEndStats::default(),
        })
    }

    /// The UDP address the ground station's packets must be sent to (`None` for the stand-in).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        match &self.far {
            Far::Udp(link) => Some(link.local_addr()),
            Far::StandIn(_) => None,
        }
    }

    pub fn stats(&self) -> GroundEndStats {
        self.stats
    }

    /// Whether a real ground station is at the far end.
    pub fn is_udp(&self) -> bool {
        matches!(self.far, Far::Udp(_))
    }

    fn record(&mut self, now_ns: u64, robot: NodeId, packet: &[u8]) {
        let Some(log) = &mut self.log else { return };
        if let Err(e) = log.append(now_ns, robot.0, packet) {
            self.stats.log_errors += 1;
            self.log_error.get_or_insert(e);
        }
    }

    /// A packet robot `robot` put on its ground link reaches the ground at `now_ns`.
    pub fn downlink(&mut self, now_ns: u64, robot: NodeId, packet: &[u8]) {
        self.stats.downlink_packets += 1;
        self.stats.downlink_bytes += packet.len() as u64;
        self.record(now_ns, robot, packet);
        match &mut self.far {
            Far::Udp(link) => {
                // No ground station listening is not the mission's problem; counted.
                if link.send(packet).is_err() {
                    self.stats.send_errors += 1;
                }
            }
            Far::StandIn(endpoints) => {
                if let Some((_, endpoint)) = endpoints.iter_mut().find(|(r, _)| *r == robot) {
                    let now_ms = now_ns / 1_000_000;
                    // Rejected packets are the robot's business; the stand-in only acknowledges.
                    let _ = endpoint.handle_packet(now_ms, packet);
                    while endpoint.poll_deliver().is_some() {}
                }
            }
        }
    }

    /// The next packet from the ground to a robot, with the robot's node id; recorded. Never
    /// waits. The bytes are valid until the next call.
    pub fn poll_uplink(&mut self, now_ns: u64) -> Option<(NodeId, &[u8])> {
        let (robot, len) = match &mut self.far {
            Far::Udp(link) => {
                let mut found = None;
                for _ in 0..MAX_UPLINK_PER_POLL {
                    let len = match link.recv(&mut self.buf, Duration::ZERO) {
                        Ok(Some(len)) => len,
                        Ok(None) => break,
                        // A transient socket error or an oversized datagram costs that datagram.
                        Err(_) => {
                            self.stats.unroutable += 1;
                            continue;
                        }
                    };
                    match self.buf.get(..len).and_then(destination) {
                        Some(robot) if self.robots.contains(&robot) => {
                            found = Some((robot, len));
                            break;
                        }
                        _ => self.stats.unroutable += 1,
                    }
                }
                found?
            }
            Far::StandIn(endpoints) => {
                let now_ms = now_ns / 1_000_000;
                let buf = &mut self.buf[..MAX_PACKET_BYTES];
                endpoints
                    .iter_mut()
                    .find_map(|(robot, endpoint)| Some((*robot, endpoint.poll_transmit(now_ms, buf)?)))?
            }
        };
        self.stats.uplink_packets += 1;
        self.stats.uplink_bytes += len as u64;
        let packet = std::mem::take(&mut self.buf);
        self.record(now_ns, robot, packet.get(..len).unwrap_or_default());
        self.buf = packet;
        Some((robot, self.buf.get(..len).unwrap_or_default()))
    }

    /// Writes the log's buffered records; reports the first recording error since the start.
    pub fn flush(&mut self) -> Result<(), FeedLogError> {
        if let Some(e) = self.log_error.take() {
            return Err(e);
        }
        match &mut self.log {
            Some(log) => log.flush(),
            None => Ok(()),
        }
    }

    /// Records written to the feed log.
    pub fn records(&self) -> u64 {
        self.log.as_ref().map_or(0, FeedLogWriter::records)
    }
}
