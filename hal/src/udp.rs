//! [`UdpLink`]: packets over UDP, segmented into datagrams of at most `mtu_bytes`.
//!
//! The link models a shared radio medium: every packet goes to every peer address, and every
//! datagram that arrives is taken, whoever sent it. Addressing is the packet header's business
//! (receivers above this layer drop packets for other nodes), so the same link works for a
//! point-to-point pair, a mesh of rovers, or a broadcast address.

use std::collections::hash_map::{DefaultHasher, RandomState};
use std::fmt;
use std::hash::{BuildHasher, Hash, Hasher};
use std::io::ErrorKind;
use std::net::{SocketAddr, ToSocketAddrs, UdpSocket};
use std::time::{Duration, Instant};

use protocol::frame::Framing;
use protocol::frame::datagram::{MAX_DATAGRAM_BYTES, MAX_FRAGMENTS, MIN_MTU, Reassembler, Segmenter};

use crate::link::{
    Link, LinkCounters, LinkError, MAX_LINK_PACKET_BYTES, bump, check_packet_len, deadline_after, deliver,
};

/// Default and largest MTU: the segmenter's ceiling, which keeps clear of IP fragmentation.
pub const DEFAULT_MTU_BYTES: usize = MAX_DATAGRAM_BYTES;
/// How long a partly received packet waits for its missing fragments. Long enough for a slow
/// radio to deliver a packet's fragments, short enough that a lost fragment frees its slot soon.
pub const DEFAULT_REASSEMBLY_TIMEOUT: Duration = Duration::from_secs(2);
/// Packets being reassembled at once; each costs `MAX_LINK_PACKET_BYTES` plus a little. A few
/// peers each with one packet in flight (senders send a packet's fragments back to back).
const REASSEMBLY_SLOTS: usize = 8;
/// Larger than any datagram of ours, so an oversized datagram is seen whole (and refused)
/// instead of being silently truncated into a plausible one.
const RECV_BUF_BYTES: usize = 2048;

/// Datagrams `recv` still takes once its timeout has passed, as long as they are already
/// there: a packet whose fragments have all arrived is returned even with a zero timeout, while
/// a flood of datagrams cannot hold `recv` past its timeout by more than this many.
const LATE_DATAGRAMS: usize = MAX_FRAGMENTS;

type UdpReassembler = Reassembler<REASSEMBLY_SLOTS, MAX_LINK_PACKET_BYTES>;

/// A [`Link`] over a UDP socket that sends every packet to each of its peers.
pub struct UdpLink {
    socket: UdpSocket,
    local_addr: SocketAddr,
    peers: Vec<SocketAddr>,
    segmenter: Segmenter,
    reassembler: Box<UdpReassembler>,
    reassembly_timeout: Duration,
    /// Origin of the reassembler's millisecond clock.
    epoch: Instant,
    recv_buf: Box<[u8]>,
    counters: LinkCounters,
}

impl fmt::Debug for UdpLink {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("UdpLink")
            .field("local_addr", &self.local_addr)
            .field("peers", &self.peers)
            .field("mtu_bytes", &self.segmenter.mtu())
            .field("reassembly_timeout", &self.reassembly_timeout)
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

impl UdpLink {
    /// Binds a socket to `addr` (port 0 picks a free port, see [`UdpLink::local_addr`]), with no
    /// peers yet, the default MTU and reassembly timeout.
    ///
    /// Broadcast is enabled on IPv4 sockets, so a peer may be a broadcast address: that is how a
    /// LAN stands in for a radio channel.
    pub fn bind(addr: impl ToSocketAddrs + fmt::Debug) -> Result<Self, LinkError> {
        let socket = UdpSocket::bind(&addr).map_err(LinkError::io(|| format!("binding UDP socket to {addr:?}")))?;
        let local_addr = socket.local_addr().map_err(LinkError::io(|| "reading the bound UDP address"))?;
        if local_addr.is_ipv4() {
            socket
                .set_broadcast(true)
                .map_err(LinkError::io(|| format!("enabling broadcast on UDP socket {local_addr}")))?;
        }
        // A random first message id, so receivers that still remember this node's messages from
        // before a restart do not drop its new ones as duplicates.
        let first_id = RandomState::new().hash_one(Instant::now()) as u16;
        let segmenter = Segmenter::with_first_id(DEFAULT_MTU_BYTES, first_id)?;
        Ok(UdpLink {
            socket,
            local_addr,
            peers: Vec::new(),
            segmenter,
            reassembler: new_reassembler(DEFAULT_REASSEMBLY_TIMEOUT),
            reassembly_timeout: DEFAULT_REASSEMBLY_TIMEOUT,
            epoch: Instant::now(),
            recv_buf: vec![0; RECV_BUF_BYTES].into_boxed_slice(),
            counters: LinkCounters::default(),
        })
    }

    /// The address the socket is bound to, with the port the OS chose for port 0.
    pub fn local_addr(&self) -> SocketAddr {
        self.local_addr
    }

    /// Replaces the peers every packet is sent to. Datagrams from other addresses are still
    /// received, and counted in [`LinkCounters::unknown_sources`].
    pub fn set_peers(&mut self, peers: impl IntoIterator<Item = SocketAddr>) {
        self.peers = peers.into_iter().collect();
    }

    pub fn with_peers(mut self, peers: impl IntoIterator<Item = SocketAddr>) -> Self {
        self.set_peers(peers);
        self
    }

    pub fn peers(&self) -> &[SocketAddr] {
        &self.peers
    }

    /// Sets the largest datagram sent, `7..=1200` bytes; a radio with small frames wants a small
    /// MTU, so one lost radio frame costs one fragment rather than a whole IP datagram.
    pub fn set_mtu(&mut self, mtu_bytes: usize) -> Result<(), LinkError> {
        if !(MIN_MTU..=MAX_DATAGRAM_BYTES).contains(&mtu_bytes) {
            return Err(LinkError::Config(format!(
                "UDP mtu_bytes {mtu_bytes} outside {MIN_MTU}..={MAX_DATAGRAM_BYTES}"
            )));
        }
        self.segmenter = Segmenter::with_first_id(mtu_bytes, self.segmenter.next_id())?;
        Ok(())
    }

    pub fn with_mtu(mut self, mtu_bytes: usize) -> Result<Self, LinkError> {
        self.set_mtu(mtu_bytes)?;
        Ok(self)
    }

    pub fn mtu_bytes(&self) -> usize {
        self.segmenter.mtu()
    }

    /// Sets how long a partly received packet waits for its missing fragments. Drops the
    /// packets being reassembled.
    pub fn set_reassembly_timeout(&mut self, timeout: Duration) {
        self.reassembly_timeout = timeout;
        self.reassembler = new_reassembler(timeout);
    }

    fn now_ms(&self) -> u64 {
        self.epoch.elapsed().as_millis() as u64
    }
}

fn new_reassembler(timeout: Duration) -> Box<UdpReassembler> {
    let timeout_ms = u64::try_from(timeout.as_millis()).unwrap_or(u64::MAX);
    Box::new(Reassembler::new(timeout_ms))
}

/// Reassembly key of a sender: its socket address, hashed with fixed keys so the key is stable
/// for the life of the link.
fn source_key(addr: &SocketAddr) -> u64 {
    let mut hasher = DefaultHasher::new();
    addr.hash(&mut hasher);
    hasher.finish()
}

impl Link for UdpLink {
    /// Sends the packet's datagrams to every peer. A peer that cannot be reached does not keep
    /// the packet from the others; the first such failure is returned after all were tried.
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkError> {
        check_packet_len(packet)?;
        if self.peers.is_empty() {
            return Err(LinkError::NoPeers);
        }
        let mut first_error = None;
        let mut datagrams_sent = 0usize;
        let socket = &self.socket;
        let peers = &self.peers;
        self.segmenter.segment(packet, |datagram| {
            for peer in peers {
                match socket.send_to(datagram, peer) {
                    Ok(_) => datagrams_sent += 1,
                    Err(source) => {
                        if first_error.is_none() {
                            first_error =
                                Some(LinkError::Io { context: format!("sending UDP datagram to {peer}"), source });
                        }
                    }
                }
            }
        })?;
        bump(&mut self.counters.frames_sent, datagrams_sent);
        if let Some(error) = first_error {
            return Err(error);
        }
        bump(&mut self.counters.packets_sent, 1);
        bump(&mut self.counters.packet_bytes_sent, packet.len());
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<Option<usize>, LinkError> {
        let deadline = deadline_after(timeout);
        let mut late_datagrams = 0usize;
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                late_datagrams += 1;
                if late_datagrams > LATE_DATAGRAMS {
                    return Ok(None);
                }
            }
            // A zero read timeout means "block forever" to the OS: wait a microsecond instead,
            // so a zero `timeout` still takes a datagram that is already there.
            self.socket
                .set_read_timeout(Some(left.max(Duration::from_micros(1))))
                .map_err(LinkError::io(|| format!("setting read timeout on UDP socket {}", self.local_addr)))?;
            let (len, from) = match self.socket.recv_from(&mut self.recv_buf) {
                Ok(received) => received,
                // Timeouts, signals, and ICMP errors some systems report for an earlier send to
                // a peer that was down: none of them is this link's failure.
                Err(error)
                    if matches!(
                        error.kind(),
                        ErrorKind::WouldBlock
                            | ErrorKind::TimedOut
                            | ErrorKind::Interrupted
                            | ErrorKind::ConnectionRefused
                            | ErrorKind::ConnectionReset
                    ) =>
                {
                    if Instant::now() >= deadline {
                        let now_ms = self.now_ms();
                        self.reassembler.expire(now_ms);
                        return Ok(None);
                    }
                    continue;
                }
                Err(source) => {
                    return Err(LinkError::Io {
                        context: format!("receiving on UDP socket {}", self.local_addr),
                        source,
                    });
                }
            };
            bump(&mut self.counters.frames_received, 1);
            if !self.peers.contains(&from) {
                bump(&mut self.counters.unknown_sources, 1);
            }
            let now_ms = self.now_ms();
            let datagram = self.recv_buf.get(..len).unwrap_or_default();
            match self.reassembler.push(now_ms, source_key(&from), datagram) {
                Ok(Some(packet)) => return deliver(packet, buf, &mut self.counters).map(Some),
                Ok(None) => {}
                Err(error) => self.counters.rejected.count(error),
            }
        }
    }

    fn framing(&self) -> Framing {
        Framing::Datagram { mtu: self.segmenter.mtu() as u16 }
    }

    fn counters(&self) -> LinkCounters {
        let stats = self.reassembler.stats();
        let mut counters = self.counters;
        counters.rejected.expired = stats.expired;
        counters.rejected.evicted = stats.evicted;
        counters
    }
}
