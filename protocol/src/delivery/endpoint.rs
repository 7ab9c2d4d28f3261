//! One node's delivery layer: queues, priorities, the rate cap, reliable channels, latest-wins
//! slots, authentication of incoming packets and the delivery queue.

use heapless::{Deque, Vec};

use crate::auth::{AuthError, AuthKey};
use crate::codec::{DecodeError, MAX_PACKET_BYTES, decode, decode_header, encode, encode_authenticated};
use crate::delivery::reliable::{Arrival, PushError, ReliableReceiver, ReliableSender, TxChoice};
use crate::delivery::rtt::{RtoConfig, RttEstimator};
use crate::delivery::token_bucket::TokenBucket;
use crate::delivery::{ConfigError, Delivered, EndpointStats, ReceiveError, SendError};
use crate::frame::Framing;
use crate::ids::NodeId;
use crate::message::{AnyMessage, Delivery, MessageKey, Priority};

/// Peers (nodes exchanging reliable traffic with this one) an endpoint can track.
pub const MAX_PEERS: usize = 4;
/// Reliable sender states, one per (peer, channel) this endpoint sends reliable data to; bound
/// on first use and kept (their sequence numbers must not start over). Eight covers e.g. two
/// peers with every reliable class (command, constraint, bulk), or four peers with two.
pub const TX_CHANNELS: usize = 8;
/// Default window `W`: packets stored per reliable sender (queued + in flight), and the reorder
/// window of each receiver. 32 matches the selective-ack mask, so every packet in flight can be
/// acknowledged selectively.
pub const DEFAULT_WINDOW: usize = 32;
/// Out-of-order (or not yet taken) reliable packets held, shared by all receive channels.
pub const REORDER_POOL: usize = 64;
/// Deliveries waiting for [`Endpoint::poll_deliver`].
pub const DELIVERY_QUEUE: usize = 16;
/// Latest-wins messages waiting for transmission (one per (destination, key, slot)).
pub const LATEST_SLOTS: usize = 16;

/// Configuration of an [`Endpoint`].
#[derive(Debug, Clone)]
pub struct EndpointConfig {
    /// This node. Packets from it are dropped (echoes on a shared medium).
    pub local: NodeId,
    /// Peers tracked, `1..=MAX_PEERS`.
    pub max_peers: usize,
    /// The link's framing: what each packet costs on the wire.
    pub framing: Framing,
    /// Rate cap, wire bytes per second. Set it at or below the link's capacity.
    pub rate_bytes_per_s: u64,
    /// Burst, wire bytes; at least the wire bytes of the largest packet (see
    /// [`EndpointConfig::min_burst_bytes`]) and at most what the link can queue.
    pub burst_bytes: u64,
    /// Key to verify incoming authenticated packets; without one they are rejected.
    pub auth_key: Option<AuthKey>,
    pub rto: RtoConfig,
}

impl EndpointConfig {
    /// A configuration with every peer slot, no key and the default RTO bounds.
    pub fn new(local: NodeId, framing: Framing, rate_bytes_per_s: u64, burst_bytes: u64) -> Self {
        EndpointConfig {
            local,
            max_peers: MAX_PEERS,
            framing,
            rate_bytes_per_s,
            burst_bytes,
            auth_key: None,
            rto: RtoConfig::default(),
        }
    }

    pub fn with_auth_key(mut self, key: AuthKey) -> Self {
        self.auth_key = Some(key);
        self
    }

    pub fn with_rto(mut self, rto: RtoConfig) -> Self {
        self.rto = rto;
        self
    }

    /// The smallest burst that lets the largest packet through on this framing.
    pub fn min_burst_bytes(framing: Framing) -> u64 {
        framing.wire_bytes(MAX_PACKET_BYTES) as u64
    }

    fn validate(&self) -> Result<(), ConfigError> {
        if !(1..=MAX_PEERS).contains(&self.max_peers) {
            return Err(ConfigError::MaxPeers { got: self.max_peers, max: MAX_PEERS });
        }
        if self.local == NodeId::BROADCAST {
            return Err(ConfigError::LocalNotUnicast(self.local));
        }
        if self.rate_bytes_per_s == 0 {
            return Err(ConfigError::ZeroRate);
        }
        let needed = Self::min_burst_bytes(self.framing);
        if self.burst_bytes < needed {
            return Err(ConfigError::BurstTooSmall { burst: self.burst_bytes, needed });
        }
        let RtoConfig { initial_ms, min_ms, max_ms } = self.rto;
        if !(1 <= min_ms && min_ms <= initial_ms && initial_ms <= max_ms) {
            return Err(ConfigError::RtoBounds { min: min_ms, initial: initial_ms, max: max_ms });
        }
        Ok(())
    }
}

#[derive(Debug, Clone)]
struct RxChannel<const W: usize> {
    /// Items are indices into the endpoint's reorder pool.
    receiver: ReliableReceiver<u16, W>,
    ack_pending: bool,
}

#[derive(Debug, Clone)]
struct PeerState<const W: usize> {
    node: NodeId,
    rtt: RttEstimator,
    rx: [RxChannel<W>; Priority::COUNT],
}

impl<const W: usize> PeerState<W> {
    fn new(node: NodeId, rto: RtoConfig) -> Self {
        PeerState {
            node,
            rtt: RttEstimator::new(rto),
            rx: core::array::from_fn(|_| RxChannel { receiver: ReliableReceiver::new(), ack_pending: false }),
        }
    }
}

#[derive(Debug, Clone)]
struct TxChannel<const W: usize> {
    /// Index into `peers` (peers are never removed, so indices are stable).
    peer: usize,
    node: NodeId,
    priority: Priority,
    sender: ReliableSender<W>,
}

#[derive(Debug, Clone)]
struct LatestSlot {
    destination: NodeId,
    key: MessageKey,
    slot: u16,
    message: AnyMessage,
}

/// The next packet to transmit.
#[derive(Debug, Clone, Copy)]
enum Candidate {
    Ack { peer: usize, channel: usize },
    Reliable { tx: usize, choice: TxChoice },
    Latest { index: usize },
}

/// One node's delivery layer (sans-IO; see the [module documentation](super)).
///
/// # Memory
///
/// Everything is inline and bounded; nothing is allocated. With the default `W` = 32, about
/// 400 KB ([`Endpoint::MEMORY_BYTES`] gives the exact figure for a `W`), dominated by:
/// - reliable send windows: `TX_CHANNELS · W · ~1.1 KB` (8 · 32 → ~285 KB): the encoded
///   packets, kept until acknowledged so retransmissions (authenticated ones included) are
///   byte-identical;
/// - the reorder pool: `REORDER_POOL` decoded messages (64 → ~70 KB);
/// - the delivery queue and the latest-wins slots: 16 messages each (~18 KB each);
/// - per peer, `Priority::COUNT` receive windows of `W` 4-byte handles (~1 KB per peer).
///
/// That is too much for a thread's stack on small targets: place it in a `static` (embedded)
/// or a `Box` (std).
#[derive(Debug, Clone)]
pub struct Endpoint<const W: usize = DEFAULT_WINDOW> {
    config: EndpointConfig,
    bucket: TokenBucket,
    peers: Vec<PeerState<W>, MAX_PEERS>,
    tx: Vec<TxChannel<W>, TX_CHANNELS>,
    latest: Vec<LatestSlot, LATEST_SLOTS>,
    pool: [Option<Delivered>; REORDER_POOL],
    deliveries: Deque<Delivered, DELIVERY_QUEUE>,
    /// Header `seq` of unreliable packets: a running counter of those sent.
    unreliable_seq: u32,
    /// Round-robin start among the reliable senders of a class.
    round_robin: usize,
    stats: EndpointStats,
}

impl<const W: usize> Endpoint<W> {
    /// Size of an endpoint with window `W`, bytes.
    pub const MEMORY_BYTES: usize = core::mem::size_of::<Self>();

    pub fn new(config: EndpointConfig) -> Result<Self, ConfigError> {
        config.validate()?;
        Ok(Endpoint {
            bucket: TokenBucket::new(config.rate_bytes_per_s, config.burst_bytes, 0),
            config,
            peers: Vec::new(),
            tx: Vec::new(),
            latest: Vec::new(),
            pool: [const { None }; REORDER_POOL],
            deliveries: Deque::new(),
            unreliable_seq: 0,
            round_robin: 0,
            stats: EndpointStats::default(),
        })
    }

    pub fn config(&self) -> &EndpointConfig {
        &self.config
    }

    pub fn local(&self) -> NodeId {
        self.config.local
    }

    pub fn stats(&self) -> &EndpointStats {
        &self.stats
    }

    /// The RTT estimate of a peer.
    pub fn rtt(&self, peer: NodeId) -> Option<&RttEstimator> {
        self.peers.iter().find(|p| p.node == peer).map(|p| &p.rtt)
    }

    /// How many more reliable messages of `priority` to `destination` [`Endpoint::send`] would
    /// accept now (0 when a new channel state could not be bound).
    pub fn queue_space(&self, destination: NodeId, priority: Priority) -> usize {
        match self.tx.iter().find(|t| t.node == destination && t.priority == priority) {
            Some(t) => W - t.sender.stored(),
            None if self.tx.is_full() => 0,
            None if self.peer_index(destination).is_none() && self.peers.len() >= self.config.max_peers => 0,
            None => W,
        }
    }

    /// Whether nothing is queued, in flight or waiting to be acknowledged.
    pub fn is_idle(&self) -> bool {
        self.latest.is_empty()
            && self.tx.iter().all(|t| t.sender.stored() == 0)
            && self.peers.iter().all(|p| p.rx.iter().all(|rx| !rx.ack_pending))
    }

    // ----------------------------------------------------------------------------- sending

    /// Queues a message that needs no authentication.
    ///
    /// Latest-wins messages take the slot (destination, key, [`AnyMessage::latest_slot`]),
    /// replacing an unsent older message there (counted). Reliable messages are encoded now,
    /// with their sequence number, into the window of their (destination, channel).
    ///
    /// Nothing in queueing depends on time yet; `now_ms` keeps every call on the same clock.
    pub fn send(&mut self, _now_ms: u64, destination: NodeId, message: &AnyMessage) -> Result<(), SendError> {
        if message.requires_authentication() {
            return Err(SendError::NeedsAuthentication(message.type_name()));
        }
        self.enqueue(destination, message, None)
    }

    /// Queues a message of an authenticated type (a [`crate::message::Command`]), signed now
    /// with `key` and `counter` (never reuse a counter with a key); retransmissions resend the
    /// same bytes.
    pub fn send_authenticated(
        &mut self,
        _now_ms: u64,
        destination: NodeId,
        message: &AnyMessage,
        counter: u64,
        key: &AuthKey,
    ) -> Result<(), SendError> {
        if !message.requires_authentication() {
            return Err(SendError::NotAuthenticated(message.type_name()));
        }
        self.enqueue(destination, message, Some((counter, key)))
    }

    fn enqueue(
        &mut self,
        destination: NodeId,
        message: &AnyMessage,
        auth: Option<(u64, &AuthKey)>,
    ) -> Result<(), SendError> {
        if matches!(message, AnyMessage::Ack(_)) {
            return Err(SendError::TransportMessage);
        }
        if destination == self.config.local {
            return Err(SendError::ToSelf);
        }
        let result = match message.delivery() {
            Delivery::LatestWins => self.enqueue_latest(destination, message, auth.is_some()),
            Delivery::Reliable => self.enqueue_reliable(destination, message, auth),
        };
        if let Err(SendError::QueueFull { .. }) = result {
            self.stats.queue_full += 1;
        }
        self.refresh_depths();
        result
    }

    fn enqueue_latest(
        &mut self,
        destination: NodeId,
        message: &AnyMessage,
        authenticated: bool,
    ) -> Result<(), SendError> {
        if authenticated {
            return Err(SendError::AuthenticatedLatestWins);
        }
        let (key, slot) = (message.key(), message.latest_slot());
        if let Some(queued) =
            self.latest.iter_mut().find(|s| s.destination == destination && s.key == key && s.slot == slot)
        {
            queued.message = message.clone();
            self.stats.latest_wins_replaced += 1;
            return Ok(());
        }
        self.latest
            .push(LatestSlot { destination, key, slot, message: message.clone() })
            .map_err(|_| SendError::QueueFull { destination, priority: message.priority() })
    }

    fn enqueue_reliable(
        &mut self,
        destination: NodeId,
        message: &AnyMessage,
        auth: Option<(u64, &AuthKey)>,
    ) -> Result<(), SendError> {
        if destination == NodeId::BROADCAST {
            return Err(SendError::ReliableBroadcast(message.type_name()));
        }
        let priority = message.priority();
        let tx = self.tx_channel(destination, priority)?;
        let local = self.config.local;
        let pushed = self.tx[tx].sender.push_with(|seq, buf| match auth {
            None => encode(message, local, destination, seq, buf),
            Some((counter, key)) => encode_authenticated(message, local, destination, seq, counter, key, buf),
        });
        match pushed {
            Ok(_) => Ok(()),
            Err(PushError::Full) => Err(SendError::QueueFull { destination, priority }),
            Err(PushError::Encode(e)) => Err(SendError::Encode(e)),
        }
    }

    fn peer_index(&self, node: NodeId) -> Option<usize> {
        self.peers.iter().position(|p| p.node == node)
    }

    fn peer_or_insert(&mut self, node: NodeId) -> Option<usize> {
        if let Some(index) = self.peer_index(node) {
            return Some(index);
        }
        if self.peers.len() >= self.config.max_peers {
            return None;
        }
        self.peers.push(PeerState::new(node, self.config.rto)).ok()?;
        Some(self.peers.len() - 1)
    }

    fn tx_channel(&mut self, destination: NodeId, priority: Priority) -> Result<usize, SendError> {
        if let Some(index) = self.tx.iter().position(|t| t.node == destination && t.priority == priority) {
            return Ok(index);
        }
        if self.tx.is_full() {
            return Err(SendError::TooManyChannels);
        }
        let peer = self.peer_or_insert(destination).ok_or(SendError::TooManyPeers(self.config.max_peers))?;
        self.tx
            .push(TxChannel { peer, node: destination, priority, sender: ReliableSender::new() })
            .map_err(|_| SendError::TooManyChannels)?;
        Ok(self.tx.len() - 1)
    }

    // ------------------------------------------------------------------------ transmitting

    /// The highest-priority packet that could go out now, tokens aside: per class (control
    /// first, bulk last) acknowledgements, then retransmissions, then new reliable data, then
    /// latest-wins messages; reliable senders of a class take turns.
    fn select(&self, now_ms: u64) -> Option<Candidate> {
        for priority in Priority::ALL {
            if priority == Priority::Control {
                for (peer, state) in self.peers.iter().enumerate() {
                    if let Some(channel) = state.rx.iter().position(|rx| rx.ack_pending) {
                        return Some(Candidate::Ack { peer, channel });
                    }
                }
            }
            let n = self.tx.len();
            let of_class = |k: usize| {
                let tx = (self.round_robin + k) % n;
                self.tx.get(tx).filter(|t| t.priority == priority).map(|t| (tx, t))
            };
            for k in 0..n {
                if let Some((tx, t)) = of_class(k)
                    && let Some(peer) = self.peers.get(t.peer)
                    && let Some(choice) = t.sender.due_retransmission(now_ms, &peer.rtt)
                {
                    return Some(Candidate::Reliable { tx, choice });
                }
            }
            for k in 0..n {
                if let Some((tx, t)) = of_class(k)
                    && let Some(choice) = t.sender.next_new()
                {
                    return Some(Candidate::Reliable { tx, choice });
                }
            }
            if let Some(index) = self.latest.iter().position(|s| s.message.priority() == priority) {
                return Some(Candidate::Latest { index });
            }
        }
        None
    }

    /// Writes the candidate's packet into `out`, returning its length.
    fn write(&self, candidate: Candidate, out: &mut [u8]) -> Option<usize> {
        let local = self.config.local;
        match candidate {
            Candidate::Ack { peer, channel } => {
                let state = self.peers.get(peer)?;
                let ack = state.rx.get(channel)?.receiver.ack(channel as u8);
                encode(&AnyMessage::Ack(ack), local, state.node, self.unreliable_seq, out).ok()
            }
            Candidate::Reliable { tx, choice } => {
                let packet = self.tx.get(tx)?.sender.packet(choice.seq)?;
                out.get_mut(..packet.len())?.copy_from_slice(packet);
                Some(packet.len())
            }
            Candidate::Latest { index } => {
                let slot = self.latest.get(index)?;
                encode(&slot.message, local, slot.destination, self.unreliable_seq, out).ok()
            }
        }
    }

    /// The next packet to put on the link, written into `out` (give it `MAX_PACKET_BYTES`),
    /// or `None` if there is nothing to send or the rate cap does not allow the next packet
    /// yet (see [`Endpoint::next_transmit_ms`]). A packet is returned only if the token bucket
    /// holds its wire bytes, which are then consumed: the endpoint never exceeds its rate.
    pub fn poll_transmit(&mut self, now_ms: u64, out: &mut [u8]) -> Option<usize> {
        let candidate = self.select(now_ms)?;
        let len = self.write(candidate, out)?;
        let wire = self.config.framing.wire_bytes(len) as u64;
        if !self.bucket.try_consume(now_ms, wire) {
            return None;
        }
        let class = match candidate {
            Candidate::Ack { peer, channel } => {
                if let Some(rx) = self.peers.get_mut(peer).and_then(|p| p.rx.get_mut(channel)) {
                    rx.ack_pending = false;
                }
                self.unreliable_seq = self.unreliable_seq.wrapping_add(1);
                Priority::Control
            }
            Candidate::Reliable { tx, choice } => {
                let t = self.tx.get_mut(tx)?;
                let previous = t.sender.mark_sent(now_ms, choice.seq);
                if choice.retransmission {
                    self.stats.retransmissions += 1;
                    if choice.fast {
                        self.stats.fast_retransmissions += 1;
                    } else if let (Some(sent_ms), Some(peer)) = (previous, self.peers.get_mut(t.peer)) {
                        peer.rtt.on_timeout(now_ms, sent_ms);
                    }
                }
                self.round_robin = tx + 1;
                t.priority
            }
            Candidate::Latest { index } => {
                let slot = self.latest.remove(index);
                self.unreliable_seq = self.unreliable_seq.wrapping_add(1);
                slot.message.priority()
            }
        };
        if let Some(counters) = self.stats.sent.get_mut(usize::from(class.channel())) {
            counters.packets += 1;
            counters.wire_bytes += wire;
        }
        self.refresh_depths();
        Some(len)
    }

    /// When to call [`Endpoint::poll_transmit`] next: `now_ms` if a packet can go now, the
    /// time the rate cap allows the next one, or the next retransmission timer. `None`: nothing
    /// to send until a message is queued or a packet arrives.
    pub fn next_transmit_ms(&self, now_ms: u64) -> Option<u64> {
        let timers = self
            .tx
            .iter()
            .filter_map(|t| t.sender.next_timer_ms(&self.peers.get(t.peer)?.rtt))
            .filter(|&at| at > now_ms)
            .min();
        let ready = self.select(now_ms).and_then(|candidate| {
            let mut scratch = [0u8; MAX_PACKET_BYTES];
            let len = self.write(candidate, &mut scratch)?;
            let wait = self.bucket.time_until(now_ms, self.config.framing.wire_bytes(len) as u64);
            Some(now_ms.saturating_add(wait))
        });
        match (ready, timers) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    // ---------------------------------------------------------------------------- receiving

    /// Handles one packet from the link. Total: any bytes give `Ok` or an error, never a
    /// panic. Order: header; source and destination (packets for other nodes and echoes of
    /// our own are dropped); the MAC of authenticated packets, before anything else is done
    /// with them; the body; then acknowledgements update the senders, reliable packets go
    /// through their channel's reorder buffer (an acknowledgement is queued, duplicates are
    /// re-acknowledged) and latest-wins packets straight to the delivery queue.
    pub fn handle_packet(&mut self, now_ms: u64, bytes: &[u8]) -> Result<(), ReceiveError> {
        let result = self.receive(now_ms, bytes);
        if let Err(error) = result {
            self.count_rejection(error);
        }
        self.refresh_depths();
        result
    }

    fn count_rejection(&mut self, error: ReceiveError) {
        let r = &mut self.stats.rejected;
        match error {
            ReceiveError::Malformed(_) => r.malformed += 1,
            ReceiveError::Unauthenticated { .. } => r.unauthenticated += 1,
            ReceiveError::Auth(_) => r.bad_mac += 1,
            ReceiveError::NoKey => r.no_key += 1,
            ReceiveError::NotForThisNode { .. } => r.not_for_this_node += 1,
            ReceiveError::InvalidSource => r.invalid_source += 1,
            ReceiveError::TooManyPeers => r.too_many_peers += 1,
            ReceiveError::ReliableBroadcast => r.reliable_broadcast += 1,
            ReceiveError::OutOfWindow { .. } => r.out_of_window += 1,
            ReceiveError::BogusAck => r.bogus_ack += 1,
            ReceiveError::DeliveryQueueFull => self.stats.dropped_delivery_full += 1,
            ReceiveError::ReorderBufferFull => self.stats.dropped_reorder_full += 1,
        }
    }

    fn receive(&mut self, now_ms: u64, bytes: &[u8]) -> Result<(), ReceiveError> {
        let (header, _) = decode_header(bytes).map_err(ReceiveError::Malformed)?;
        if header.source == self.config.local || header.source == NodeId::BROADCAST {
            return Err(ReceiveError::InvalidSource);
        }
        if header.destination != self.config.local && header.destination != NodeId::BROADCAST {
            return Err(ReceiveError::NotForThisNode { destination: header.destination });
        }
        let auth = if header.flags.authenticated() {
            let key = self.config.auth_key.as_ref().ok_or(ReceiveError::NoKey)?;
            Some(key.verify(bytes).map_err(|e| match e {
                AuthError::Malformed(d) => ReceiveError::Malformed(d),
                other => ReceiveError::Auth(other),
            })?)
        } else {
            None
        };
        let packet = decode(bytes).map_err(|e| match e {
            DecodeError::AuthenticationMismatch { key } if auth.is_none() => ReceiveError::Unauthenticated { key },
            other => ReceiveError::Malformed(other),
        })?;
        let priority = packet.message.priority();
        if let Some(counters) = self.stats.received.get_mut(usize::from(priority.channel())) {
            counters.packets += 1;
            counters.wire_bytes += self.config.framing.wire_bytes(bytes.len()) as u64;
        }
        let delivered = Delivered { header: packet.header, message: packet.message, auth, received_ms: now_ms };
        match &delivered.message {
            AnyMessage::Ack(ack) => {
                let ack = *ack;
                self.on_ack(now_ms, header.source, ack.channel, ack.next_expected, ack.received_mask)
            }
            message if message.delivery() == Delivery::Reliable => self.on_reliable(delivered),
            _ => self.deliveries.push_back(delivered).map_err(|_| ReceiveError::DeliveryQueueFull),
        }
    }

    fn on_ack(
        &mut self,
        now_ms: u64,
        source: NodeId,
        channel: u8,
        next_expected: u32,
        received_mask: u32,
    ) -> Result<(), ReceiveError> {
        // An acknowledgement for a channel we never sent on is stale or misdirected: ignore it.
        let Some(t) = self.tx.iter_mut().find(|t| t.node == source && t.priority.channel() == channel) else {
            return Ok(());
        };
        let outcome = t.sender.on_ack(now_ms, next_expected, received_mask).map_err(|_| ReceiveError::BogusAck)?;
        if let Some(sample) = outcome.rtt_sample_ms
            && let Some(peer) = self.peers.get_mut(t.peer)
        {
            peer.rtt.on_sample(sample);
            self.stats.srtt_ms = peer.rtt.srtt_ms();
            self.stats.rto_ms = Some(peer.rtt.rto_ms());
        }
        Ok(())
    }

    fn on_reliable(&mut self, delivered: Delivered) -> Result<(), ReceiveError> {
        let header = delivered.header;
        if header.destination == NodeId::BROADCAST {
            return Err(ReceiveError::ReliableBroadcast);
        }
        let peer = self.peer_or_insert(header.source).ok_or(ReceiveError::TooManyPeers)?;
        let channel = usize::from(delivered.message.priority().channel());
        let free_pool_slot = self.pool.iter().position(Option::is_none);
        let direct = !self.deliveries.is_full();
        let rx = self.peers.get_mut(peer).and_then(|p| p.rx.get_mut(channel)).ok_or(ReceiveError::TooManyPeers)?;
        match rx.receiver.classify(header.seq) {
            Arrival::Duplicate => {
                self.stats.duplicates += 1;
                rx.ack_pending = true;
                return Ok(());
            }
            Arrival::OutOfWindow => {
                return Err(ReceiveError::OutOfWindow { seq: header.seq, next_expected: rx.receiver.next_seq() });
            }
            Arrival::Next if direct => {
                rx.receiver.skip_next(header.seq);
                rx.ack_pending = true;
                // Cannot fail: checked not full above.
                self.deliveries.push_back(delivered).map_err(|_| ReceiveError::DeliveryQueueFull)?;
            }
            Arrival::Next | Arrival::Ahead => {
                let index = free_pool_slot.ok_or(ReceiveError::ReorderBufferFull)?;
                rx.receiver.insert(header.seq, index as u16).map_err(|_| ReceiveError::ReorderBufferFull)?;
                rx.ack_pending = true;
                if let Some(slot) = self.pool.get_mut(index) {
                    *slot = Some(delivered);
                }
            }
        }
        self.drain();
        Ok(())
    }

    /// Moves in-order packets from the reorder pool to the delivery queue while there is room.
    fn drain(&mut self) {
        for peer in self.peers.iter_mut() {
            for rx in peer.rx.iter_mut() {
                while !self.deliveries.is_full() && rx.receiver.has_ready() {
                    let Some((_, index)) = rx.receiver.pop_ready() else { break };
                    if let Some(delivered) = self.pool.get_mut(usize::from(index)).and_then(Option::take) {
                        // Cannot fail: checked not full above.
                        let _ = self.deliveries.push_back(delivered);
                    }
                }
            }
        }
    }

    /// The next message for the application: reliable ones in order per (peer, channel),
    /// exactly once.
    pub fn poll_deliver(&mut self) -> Option<Delivered> {
        let delivered = self.deliveries.pop_front();
        self.drain();
        self.refresh_depths();
        delivered
    }

    /// Forgets all channel state with `peer` (after it restarted, e.g. its
    /// [`crate::message::Heartbeat::boot_id`] changed): sequence numbers start over in both
    /// directions, and reliable messages not yet acknowledged by it are discarded. Returns how
    /// many were discarded.
    pub fn reset_peer(&mut self, peer: NodeId) -> usize {
        let Some(index) = self.peer_index(peer) else { return 0 };
        let rto = self.config.rto;
        let pool = &mut self.pool;
        if let Some(state) = self.peers.get_mut(index) {
            for rx in state.rx.iter_mut() {
                rx.receiver.reset(|slot| {
                    if let Some(entry) = pool.get_mut(usize::from(slot)) {
                        *entry = None;
                    }
                });
                rx.ack_pending = false;
            }
            state.rtt = RttEstimator::new(rto);
        }
        let mut discarded = 0;
        for t in self.tx.iter_mut().filter(|t| t.node == peer) {
            discarded += t.sender.stored();
            t.sender = ReliableSender::new();
        }
        self.refresh_depths();
        discarded
    }

    fn refresh_depths(&mut self) {
        let mut queued = [0u32; Priority::COUNT];
        let mut in_flight = [0u32; Priority::COUNT];
        for t in &self.tx {
            let class = usize::from(t.priority.channel());
            if let (Some(q), Some(f)) = (queued.get_mut(class), in_flight.get_mut(class)) {
                *q += t.sender.queued() as u32;
                *f += t.sender.in_flight() as u32;
            }
        }
        for slot in &self.latest {
            if let Some(q) = queued.get_mut(usize::from(slot.message.priority().channel())) {
                *q += 1;
            }
        }
        self.stats.queued = queued;
        self.stats.in_flight = in_flight;
        self.stats.reorder_buffered = self.pool.iter().filter(|slot| slot.is_some()).count() as u32;
        self.stats.delivery_queue = self.deliveries.len() as u32;
    }
}
