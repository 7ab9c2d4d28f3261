//! The ground link: where it is ([`LinkSpec`]) and the network thread that owns it.
//!
//! The thread talks to the rest only through bounded `sync_channel`s and never blocks on them:
//! an incoming packet that finds its channel full is dropped and counted (the robots' reliable
//! streams retransmit it), and the engine's sends use `try_send` the same way.
//!
//! UDP: the ground binds the address (what the mission's `--feed HOST:PORT` sends to). A datagram
//! is either a whole protocol packet (the lockstep mission's feed) or a fragment of the
//! `protocol::frame::datagram` framing (`hal::udp::UdpLink` senders); each sender address is
//! answered in the form it used, at its last address, by the robot id in the packets' headers.
//! Serial: a `hal::serial::SerialLink` (COBS + CRC-32 frames); replies go out on the same line.

use std::collections::BTreeMap;
use std::fmt;
use std::net::{SocketAddr, UdpSocket};
use std::str::FromStr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{Receiver, SyncSender, TryRecvError, TrySendError, sync_channel};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use hal::link::Link;
use protocol::frame::datagram::{MAX_DATAGRAM_BYTES, Reassembler, Segmenter};
use protocol::{MAX_PACKET_BYTES, NodeId};

/// Packets waiting for the engine.
pub const INCOMING_CAPACITY: usize = 1024;
/// Packets waiting for the link.
pub const OUTGOING_CAPACITY: usize = 256;
/// How long the thread waits on the link before it looks at the outgoing queue again.
const POLL: Duration = Duration::from_millis(5);
const DEFAULT_BAUD: u32 = 57_600;

/// Where the ground link is.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum LinkSpec {
    /// `udp://HOST:PORT`: bind this address.
    Udp { bind: SocketAddr },
    /// `serial:///dev/ttyUSB0?baud=57600`.
    Serial { path: String, baud: u32 },
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LinkSpecError {
    #[error("link {0:?}: expected udp://HOST:PORT or serial:///dev/ttyX?baud=N")]
    Scheme(String),
    #[error("link {0:?}: expected udp://IP:PORT (e.g. udp://0.0.0.0:47800)")]
    UdpAddress(String),
    #[error("link {0:?}: serial device path missing")]
    SerialPath(String),
    #[error("link {0:?}: bad serial option (only baud=N with N in 50..=4000000)")]
    SerialOption(String),
}

impl FromStr for LinkSpec {
    type Err = LinkSpecError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        if let Some(rest) = text.strip_prefix("udp://") {
            let rest = rest.strip_suffix('/').unwrap_or(rest);
            let with_ip = match rest.strip_prefix("localhost:") {
                Some(port) => format!("127.0.0.1:{port}"),
                None => rest.to_string(),
            };
            return with_ip
                .parse::<SocketAddr>()
                .map(|bind| LinkSpec::Udp { bind })
                .map_err(|_| LinkSpecError::UdpAddress(text.to_string()));
        }
        if let Some(rest) = text.strip_prefix("serial://") {
            let (path, query) = match rest.split_once('?') {
                Some((path, query)) => (path, Some(query)),
                None => (rest, None),
            };
            if path.is_empty() {
                return Err(LinkSpecError::SerialPath(text.to_string()));
            }
            let mut baud = DEFAULT_BAUD;
            for option in query.into_iter().flat_map(|q| q.split('&')) {
                baud = option
                    .strip_prefix("baud=")
                    .and_then(|n| n.parse::<u32>().ok())
                    .filter(|n| (50..=4_000_000).contains(n))
                    .ok_or_else(|| LinkSpecError::SerialOption(text.to_string()))?;
            }
            return Ok(LinkSpec::Serial { path: path.to_string(), baud });
        }
        Err(LinkSpecError::Scheme(text.to_string()))
    }
}

impl fmt::Display for LinkSpec {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LinkSpec::Udp { bind } => write!(f, "udp://{bind}"),
            LinkSpec::Serial { path, baud } => write!(f, "serial://{path}?baud={baud}"),
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum NetError {
    #[error("binding {addr}: {source}")]
    Bind { addr: SocketAddr, source: std::io::Error },
    #[error("{0}")]
    Link(#[from] hal::link::LinkError),
    #[error("starting the network thread: {0}")]
    Thread(std::io::Error),
}

/// A packet from the link with its ground receive time.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Incoming {
    /// Nanoseconds since the epoch given to [`spawn`].
    pub recv_ns: u64,
    pub packet: Vec<u8>,
}

/// Counters of the network thread.
#[derive(Debug, Default)]
pub struct NetCounters {
    pub packets_in: AtomicU64,
    pub packets_out: AtomicU64,
    /// Incoming packets dropped because the engine's channel was full.
    pub dropped_incoming: AtomicU64,
    /// Outgoing packets for a robot never heard (no address to send to).
    pub dropped_unroutable: AtomicU64,
    pub send_errors: AtomicU64,
    pub receive_errors: AtomicU64,
}

/// The running network thread. Dropping it stops and joins the thread.
#[derive(Debug)]
pub struct NetHandle {
    pub incoming: Receiver<Incoming>,
    pub outgoing: SyncSender<(u8, Vec<u8>)>,
    pub counters: Arc<NetCounters>,
    local_addr: Option<SocketAddr>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
}

impl NetHandle {
    /// The bound UDP address (with the port the OS chose for port 0).
    pub fn local_addr(&self) -> Option<SocketAddr> {
        self.local_addr
    }
}

impl Drop for NetHandle {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

/// Opens the link and starts its thread; receive times count from `epoch`.
pub fn spawn(spec: &LinkSpec, epoch: Instant) -> Result<NetHandle, NetError> {
    let (in_tx, incoming) = sync_channel(INCOMING_CAPACITY);
    let (outgoing, out_rx) = sync_channel(OUTGOING_CAPACITY);
    let counters = Arc::new(NetCounters::default());
    let stop = Arc::new(AtomicBool::new(false));
    let (thread_counters, thread_stop) = (Arc::clone(&counters), Arc::clone(&stop));
    let (local_addr, run): (Option<SocketAddr>, Box<dyn FnOnce() + Send>) = match spec {
        LinkSpec::Udp { bind } => {
            let socket = UdpSocket::bind(bind).map_err(|source| NetError::Bind { addr: *bind, source })?;
            let local = socket.local_addr().map_err(|source| NetError::Bind { addr: *bind, source })?;
            socket.set_read_timeout(Some(POLL)).map_err(|source| NetError::Bind { addr: *bind, source })?;
            let mut udp = UdpSide::new(socket);
            (
                Some(local),
                Box::new(move || {
                    while !thread_stop.load(Ordering::Relaxed) {
                        udp.receive(epoch, &in_tx, &thread_counters);
                        if !drain_outgoing(&out_rx, |robot, packet| udp.send(robot, packet, &thread_counters)) {
                            break;
                        }
                    }
                }),
            )
        }
        LinkSpec::Serial { path, baud } => {
            let mut link = hal::serial::SerialLink::open(path, *baud)?;
            (
                None,
                Box::new(move || {
                    let mut buf = vec![0u8; hal::link::MAX_LINK_PACKET_BYTES];
                    while !thread_stop.load(Ordering::Relaxed) {
                        match link.recv(&mut buf, POLL) {
                            Ok(Some(len)) => {
                                let packet = buf.get(..len).unwrap_or_default().to_vec();
                                forward(epoch, packet, &in_tx, &thread_counters);
                            }
                            Ok(None) => {}
                            Err(hal::link::LinkError::Closed(_)) => break,
                            Err(_) => {
                                thread_counters.receive_errors.fetch_add(1, Ordering::Relaxed);
                            }
                        }
                        let sent = drain_outgoing(&out_rx, |_, packet| match link.send(&packet) {
                            Ok(()) => thread_counters.packets_out.fetch_add(1, Ordering::Relaxed),
                            Err(_) => thread_counters.send_errors.fetch_add(1, Ordering::Relaxed),
                        });
                        if !sent {
                            break;
                        }
                    }
                }),
            )
        }
    };
    let thread = std::thread::Builder::new().name("gs-net".into()).spawn(run).map_err(NetError::Thread)?;
    Ok(NetHandle { incoming, outgoing, counters, local_addr, stop, thread: Some(thread) })
}

fn forward(epoch: Instant, packet: Vec<u8>, tx: &SyncSender<Incoming>, counters: &NetCounters) {
    let recv_ns = u64::try_from(epoch.elapsed().as_nanos()).unwrap_or(u64::MAX);
    counters.packets_in.fetch_add(1, Ordering::Relaxed);
    if let Err(TrySendError::Full(_)) = tx.try_send(Incoming { recv_ns, packet }) {
        counters.dropped_incoming.fetch_add(1, Ordering::Relaxed);
    }
}

/// Sends what is queued; false once the engine is gone.
fn drain_outgoing(rx: &Receiver<(u8, Vec<u8>)>, mut send: impl FnMut(u8, Vec<u8>) -> u64) -> bool {
    loop {
        match rx.try_recv() {
            Ok((robot, packet)) => {
                send(robot, packet);
            }
            Err(TryRecvError::Empty) => return true,
            Err(TryRecvError::Disconnected) => return false,
        }
    }
}

/// How a sender framed its datagrams.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Form {
    Whole,
    Fragments,
}

struct UdpSide {
    socket: UdpSocket,
    reassembler: Box<Reassembler<8, MAX_PACKET_BYTES>>,
    segmenter: Segmenter,
    /// Each robot's last address and form.
    robots: BTreeMap<u8, (SocketAddr, Form)>,
    buf: Vec<u8>,
    epoch: Instant,
}

impl UdpSide {
    fn new(socket: UdpSocket) -> Self {
        let segmenter = match Segmenter::new(MAX_DATAGRAM_BYTES) {
            Ok(s) => s,
            Err(e) => unreachable!("the default MTU is valid: {e}"),
        };
        UdpSide {
            socket,
            reassembler: Box::new(Reassembler::new(2_000)),
            segmenter,
            robots: BTreeMap::new(),
            buf: vec![0; 2048],
            epoch: Instant::now(),
        }
    }

    /// Takes the datagrams that arrive within one poll period.
    fn receive(&mut self, epoch: Instant, tx: &SyncSender<Incoming>, counters: &NetCounters) {
        let deadline = Instant::now() + POLL;
        loop {
            let (len, from) = match self.socket.recv_from(&mut self.buf) {
                Ok(r) => r,
                Err(e) if matches!(e.kind(), std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut) => return,
                Err(_) => {
                    counters.receive_errors.fetch_add(1, Ordering::Relaxed);
                    return;
                }
            };
            let datagram = self.buf.get(..len).unwrap_or_default().to_vec();
            if let Ok(packet) = protocol::decode(&datagram) {
                self.learn(packet.header.source, from, Form::Whole);
                forward(epoch, datagram, tx, counters);
            } else {
                let now_ms = self.epoch.elapsed().as_millis() as u64;
                let key = source_key(&from);
                match self.reassembler.push(now_ms, key, &datagram) {
                    Ok(Some(packet)) => {
                        let packet = packet.to_vec();
                        if let Ok((header, _)) = protocol::codec::decode_header(&packet) {
                            self.learn(header.source, from, Form::Fragments);
                        }
                        forward(epoch, packet, tx, counters);
                    }
                    Ok(None) => {}
                    // Neither a packet nor a fragment: the model counts garbage, so pass it on.
                    Err(_) => forward(epoch, datagram, tx, counters),
                }
            }
            if Instant::now() >= deadline {
                return;
            }
        }
    }

    fn learn(&mut self, source: NodeId, from: SocketAddr, form: Form) {
        if source.is_robot() {
            self.robots.insert(source.0, (from, form));
        }
    }

    fn send(&mut self, robot: u8, packet: Vec<u8>, counters: &NetCounters) -> u64 {
        let Some(&(addr, form)) = self.robots.get(&robot) else {
            return counters.dropped_unroutable.fetch_add(1, Ordering::Relaxed);
        };
        let socket = &self.socket;
        let mut failed = false;
        match form {
            Form::Whole => failed = socket.send_to(&packet, addr).is_err(),
            Form::Fragments => {
                let segmented = self.segmenter.segment(&packet, |datagram| {
                    failed |= socket.send_to(datagram, addr).is_err();
                });
                failed |= segmented.is_err();
            }
        }
        if failed {
            counters.send_errors.fetch_add(1, Ordering::Relaxed)
        } else {
            counters.packets_out.fetch_add(1, Ordering::Relaxed)
        }
    }
}

fn source_key(addr: &SocketAddr) -> u64 {
    use std::hash::{Hash, Hasher};
    let mut hasher = std::collections::hash_map::DefaultHasher::new();
    addr.hash(&mut hasher);
    hasher.finish()
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use proptest::prelude::*;

    #[test]
    fn link_specs_parse_and_print() {
        assert_eq!(
            "udp://0.0.0.0:47800".parse::<LinkSpec>().unwrap(),
            LinkSpec::Udp { bind: "0.0.0.0:47800".parse().unwrap() }
        );
        assert_eq!(
            "udp://localhost:7700".parse::<LinkSpec>().unwrap(),
            LinkSpec::Udp { bind: "127.0.0.1:7700".parse().unwrap() }
        );
        assert_eq!(
            "serial:///dev/ttyUSB0?baud=115200".parse::<LinkSpec>().unwrap(),
            LinkSpec::Serial { path: "/dev/ttyUSB0".into(), baud: 115_200 }
        );
        assert_eq!(
            "serial:///dev/ttyS1".parse::<LinkSpec>().unwrap(),
            LinkSpec::Serial { path: "/dev/ttyS1".into(), baud: 57_600 }
        );
        for bad in ["tcp://1.2.3.4:5", "udp://nohost", "udp://1.2.3.4", "serial://", "serial:///dev/x?baud=fast", ""] {
            assert!(bad.parse::<LinkSpec>().is_err(), "{bad}");
        }
        for spec in ["udp://127.0.0.1:9", "serial:///dev/ttyS0?baud=9600"] {
            assert_eq!(spec.parse::<LinkSpec>().unwrap().to_string(), spec);
        }
        let error = "udp://x".parse::<LinkSpec>().unwrap_err().to_string();
        assert!(error.contains("udp://x"), "{error}");
    }

    proptest! {
        #[test]
        fn the_parser_is_total(text in ".{0,40}") {
            let _ = text.parse::<LinkSpec>();
        }

        #[test]
        fn udp_like_text_never_panics(port in any::<u32>(), host in "[a-z0-9.:]{0,20}") {
            let _ = format!("udp://{host}:{port}").parse::<LinkSpec>();
            let _ = format!("serial://{host}?baud={port}").parse::<LinkSpec>();
        }
    }
}
