//! Adapters that move the comms node's packets: real links on the wall clock ([`LinkDriver`])
//! and emulated links on simulated time ([`step_duplex`]).

use std::fmt;
use std::time::Duration;

use hal::emulator::{DuplexEmulator, Side};
use hal::link::{Link, LinkError, MAX_LINK_PACKET_BYTES};

use super::{CommsNode, LinkId};

/// Packets taken from one link per [`LinkDriver::pump`] at most, so a flood on one link cannot
/// hold the node's task past its deadline.
const MAX_RECEIVE_PER_PUMP: usize = 256;

/// Counters of a [`LinkDriver`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct DriverStats {
    pub packets_sent: u64,
    pub packets_received: u64,
    /// Sends the link refused (unreachable peer, full OS buffer): the packet is lost, and the
    /// delivery layer retransmits it if it is reliable.
    pub send_errors: u64,
    /// Receive errors that cost one packet (too large for the buffer).
    pub receive_errors: u64,
    /// Packets the node produced for a link id no transport is bound to.
    pub unbound: u64,
}

/// Binds real [`Link`]s to a node's [`LinkId`]s for the process runner.
pub struct LinkDriver {
    links: Vec<(LinkId, Box<dyn Link>)>,
    rx_buf: Box<[u8]>,
    stats: DriverStats,
}

impl fmt::Debug for LinkDriver {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LinkDriver")
            .field("links", &self.links.iter().map(|(id, _)| *id).collect::<Vec<_>>())
            .field("stats", &self.stats)
            .finish_non_exhaustive()
    }
}

impl Default for LinkDriver {
    fn default() -> Self {
        Self::new()
    }
}

impl LinkDriver {
    pub fn new() -> Self {
        LinkDriver {
            links: Vec::new(),
            rx_buf: vec![0; MAX_LINK_PACKET_BYTES].into_boxed_slice(),
            stats: DriverStats::default(),
        }
    }

    /// Binds `link` to `id` (replacing an earlier binding). Give the node's link the same
    /// framing as `link.framing()`, so its rate cap charges what the link really carries.
    pub fn add(&mut self, id: LinkId, link: Box<dyn Link>) {
        self.links.retain(|(bound, _)| *bound != id);
        self.links.push((id, link));
    }

    pub fn with(mut self, id: LinkId, link: Box<dyn Link>) -> Self {
        self.add(id, link);
        self
    }

    pub fn stats(&self) -> DriverStats {
        self.stats
    }

    pub fn link(&self, id: LinkId) -> Option<&dyn Link> {
        self.links.iter().find(|(bound, _)| *bound == id).map(|(_, link)| link.as_ref() as &dyn Link)
    }

    /// Feeds the node what arrived on every link (without waiting), then sends what is due.
    /// Errors only for a link that is gone for good ([`LinkError::Closed`]) or a failing device;
    /// lost packets are counted.
    pub fn pump(&mut self, node: &mut CommsNode, now_ns: u64) -> Result<(), LinkError> {
        self.receive(node, now_ns, Duration::ZERO)?;
        self.transmit(node, now_ns)
    }

    /// Like [`LinkDriver::pump`], but waits up to `timeout` for a first packet on the first
    /// link (the others are polled): for a runner that has nothing else to do.
    pub fn pump_waiting(&mut self, node: &mut CommsNode, now_ns: u64, timeout: Duration) -> Result<(), LinkError> {
        self.receive(node, now_ns, timeout)?;
        self.transmit(node, now_ns)
    }

    fn receive(&mut self, node: &mut CommsNode, now_ns: u64, first_wait: Duration) -> Result<(), LinkError> {
        let mut wait = first_wait;
        for (id, link) in &mut self.links {
            for _ in 0..MAX_RECEIVE_PER_PUMP {
                match link.recv(&mut self.rx_buf, std::mem::take(&mut wait)) {
                    Ok(Some(len)) => {
                        self.stats.packets_received += 1;
                        node.handle_packet(now_ns, *id, self.rx_buf.get(..len).unwrap_or_default());
                    }
                    Ok(None) => break,
                    Err(LinkError::BufferTooSmall { .. }) => self.stats.receive_errors += 1,
                    Err(error) => return Err(error),
                }
            }
        }
        Ok(())
    }

    fn transmit(&mut self, node: &mut CommsNode, now_ns: u64) -> Result<(), LinkError> {
        while let Some((id, packet)) = node.poll_transmit(now_ns) {
            let Some((_, link)) = self.links.iter_mut().find(|(bound, _)| *bound == id) else {
                self.stats.unbound += 1;
                continue;
            };
            match link.send(packet) {
                Ok(()) => self.stats.packets_sent += 1,
                Err(error @ LinkError::Closed(_)) => return Err(error),
                Err(_) => self.stats.send_errors += 1,
            }
        }
        Ok(())
    }
}

/// One step of two nodes joined by an emulated link on simulated time: `a` is side A of
/// `duplex` on its link `a_link`, `b` side B on `b_link`. Delivers what arrived by `now_ns`,
/// then hands the emulator what each node may send now.
pub fn step_duplex(
    duplex: &mut DuplexEmulator,
    now_ns: u64,
    (a, a_link): (&mut CommsNode, LinkId),
    (b, b_link): (&mut CommsNode, LinkId),
) {
    let now_ms = now_ns / 1_000_000;
    while let Some(packet) = duplex.poll(Side::A, now_ms) {
        a.handle_packet(now_ns, a_link, &packet);
    }
    while let Some(packet) = duplex.poll(Side::B, now_ms) {
        b.handle_packet(now_ns, b_link, &packet);
    }
    while let Some(packet) = a.poll_transmit_on(now_ns, a_link) {
        duplex.send(Side::A, now_ms, packet);
    }
    while let Some(packet) = b.poll_transmit_on(now_ns, b_link) {
        duplex.send(Side::B, now_ms, packet);
    }
}
