//! [`CanopenMaster`]: the firmware driver's side of the rover's CANopen network: NMT master, SYNC
//! producer, heartbeat consumer, and consumer of the drives' and the head's PDOs.
//!
//! # Cycles
//!
//! Each SYNC opens a cycle. The drives sample their encoders at the SYNC and answer with TPDO1;
//! a cycle is complete when all four have answered, and then becomes the latest
//! [`WheelEncoders`] (stamped with the SYNC's time: the instant the positions were sampled). A
//! cycle still incomplete when the next SYNC goes out is reported
//! ([`MasterEvent::CycleIncomplete`], [`MasterCounters::cycles_incomplete`]) and its partial
//! values are never delivered, so consumers only ever difference whole, simultaneous samples.
//! A TPDO belongs to the cycle of the last SYNC: drives answer within a millisecond, far inside
//! a SYNC period.
//!
//! # Supervision
//!
//! Every supervised node (the drives and the head) is a heartbeat consumer entry: silent for
//! longer than the consumer time, it is [`NodeHealth::Missing`] ([`MasterEvent::NodeLost`]);
//! its next heartbeat or boot-up brings it back ([`MasterEvent::NodeBack`]). A boot-up or a
//! pre-operational heartbeat gets an NMT start for that node, so a replugged or reset device
//! comes back into operation without anyone asking. EMCY sets [`NodeHealth::Fault`] until the
//! error-reset EMCY (code 0) or a boot-up clears it.
//!
//! Frames from nodes that are not supervised are counted and otherwise ignored, so a misbehaving
//! device elsewhere on the bus cannot fill the event queue.

use std::collections::VecDeque;
use std::time::Duration;

use super::device::{PAN_TILT_NODE, WHEEL_DRIVE_NODES, angle_to_microrad, microrad_to_angle};
use super::frame::{CanopenMessage, NmtCommand, NmtState, NmtTarget, NodeId, PdoData, PdoNumber};
use crate::can::{CanBus, CanFrame};
use crate::link::LinkError;

/// Wheels in the order of [`WheelEncoders`] and [`MasterConfig::drives`]: front-left,
/// front-right, rear-left, rear-right.
pub const WHEELS: usize = 4;

/// Events kept for [`CanopenMaster::drain_events`]; beyond this the oldest are dropped (and
/// counted), so a caller that never drains cannot make the master grow.
const EVENT_QUEUE: usize = 256;

/// The master's configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MasterConfig {
    /// Drive node ids in wheel order (front-left, front-right, rear-left, rear-right).
    pub drives: [NodeId; WHEELS],
    pub head: Option<NodeId>,
    /// 20 ms: the 50 Hz platform control rate (as the simulator's wheel odometry).
    pub sync_period_ns: u64,
    /// `Some(n)`: SYNC carries a counter 1..=n (n in 2..=240); `None`: SYNC has no data, which
    /// every device accepts.
    pub sync_counter_overflow: Option<u8>,
    /// Heartbeat consumer time: 3 × the devices' 100 ms producer time, so one or two lost
    /// heartbeats are not yet a lost node.
    pub heartbeat_consumer_ns: u64,
    /// Frames [`CanopenMaster::tick`] takes from the bus at most, so a flooded bus cannot hold
    /// the driver in one tick.
    pub max_frames_per_tick: usize,
    /// Head mechanical limits: commands are clamped to them.
    pub pan_limit_rad: f64,
    pub tilt_limit_rad: f64,
}

impl Default for MasterConfig {
    fn default() -> Self {
        MasterConfig {
            drives: WHEEL_DRIVE_NODES,
            head: Some(PAN_TILT_NODE),
            sync_period_ns: 20_000_000,
            sync_counter_overflow: None,
            heartbeat_consumer_ns: 300_000_000,
            max_frames_per_tick: 1024,
            pan_limit_rad: std::f64::consts::PI,
            tilt_limit_rad: std::f64::consts::FRAC_PI_2,
        }
    }
}

/// One complete SYNC cycle of the four drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct WheelEncoders {
    /// SYNCs sent by the master before and including this one (1 for the first); a gap between
    /// two delivered cycles means incomplete cycles in between.
    pub cycle: u64,
    /// When the SYNC was sent, on the master's clock.
    pub stamp_ns: u64,
    /// Encoder positions (wrapping i32) in wheel order.
    pub positions_counts: [i32; WHEELS],
    pub velocities_counts_per_s: [i32; WHEELS],
}

/// The head's latest reported angles.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HeadAngles {
    pub pan_rad: f64,
    pub tilt_rad: f64,
    /// The SYNC the head sampled at (or the reception time without one).
    pub stamp_ns: u64,
}

/// What the master knows of a supervised node.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NodeHealth {
    /// Not heard from since the master started, and the consumer time has not passed yet.
    Unknown,
    /// Alive but not delivering PDOs (booting, pre-operational or stopped).
    NotOperational(NmtState),
    Operational,
    /// No heartbeat within the consumer time; `since_ns` is the last one heard (or the master's
    /// start if none was).
    Missing {
        since_ns: u64,
    },
    /// Alive and reporting an error by EMCY.
    Fault {
        code: u16,
    },
}

/// Something a driver logs.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MasterEvent {
    NodeLost {
        node: NodeId,
        last_heard_ns: Option<u64>,
    },
    NodeBack {
        node: NodeId,
        state: NmtState,
    },
    /// A boot-up: the node was (re)started, and gets an NMT start.
    NodeBooted {
        node: NodeId,
    },
    /// `code` 0 is the error reset.
    Emergency {
        node: NodeId,
        code: u16,
        error_register: u8,
    },
    /// Which drives had answered when the next SYNC closed the cycle.
    CycleIncomplete {
        cycle: u64,
        answered: [bool; WHEELS],
    },
}

/// Running totals since the master was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MasterCounters {
    pub frames_received: u64,
    pub frames_sent: u64,
    /// Frames of other protocols (extended ids, ids CANopen does not use here).
    pub foreign_frames: u64,
    /// CANopen ids with content that does not decode, or PDOs of a supervised node with the
    /// wrong length.
    pub malformed_frames: u64,
    pub syncs_sent: u64,
    pub cycles_complete: u64,
    pub cycles_incomplete: u64,
    pub nmt_starts_sent: u64,
    pub events_dropped: u64,
    pub send_errors: u64,
}

#[derive(Debug, thiserror::Error)]
pub enum MasterError {
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error("invalid CANopen master configuration: {0}")]
    Config(String),
    #[error("no pan-tilt head configured")]
    NoHead,
    #[error("head angles must be finite, got pan {pan_rad} rad, tilt {tilt_rad} rad")]
    InvalidAngle { pan_rad: f64, tilt_rad: f64 },
}

#[derive(Debug, Clone, Copy)]
struct Supervised {
    node: NodeId,
    last_heard_ns: Option<u64>,
    state: Option<NmtState>,
    fault: Option<u16>,
    missing: bool,
}

#[derive(Debug, Clone, Copy)]
struct Cycle {
    number: u64,
    stamp_ns: u64,
    positions_counts: [i32; WHEELS],
    velocities_counts_per_s: [i32; WHEELS],
    answered: [bool; WHEELS],
    delivered: bool,
}

/// The CANopen master. Call [`CanopenMaster::tick`] often (every millisecond or so, or at
/// [`CanopenMaster::next_deadline_ns`] and whenever frames arrive).
#[derive(Debug)]
pub struct CanopenMaster {
    config: MasterConfig,
    start_ns: Option<u64>,
    sync_enabled: bool,
    next_sync_ns: u64,
    sync_counter: u8,
    cycle: Option<Cycle>,
    encoders: Option<WheelEncoders>,
    fresh_encoders: bool,
    head: Option<HeadAngles>,
    nodes: Vec<Supervised>,
    pending_starts: Vec<NodeId>,
    events: VecDeque<MasterEvent>,
    counters: MasterCounters,
}

impl CanopenMaster {
    pub fn new(config: MasterConfig) -> Result<Self, MasterError> {
        let mut ids: Vec<NodeId> = config.drives.iter().copied().chain(config.head).collect();
        ids.sort_unstable();
        if ids.windows(2).any(|pair| pair[0] == pair[1]) {
            return Err(MasterError::Config(format!("node ids must be distinct: {ids:?}")));
        }
        if config.sync_period_ns == 0 || config.heartbeat_consumer_ns == 0 || config.max_frames_per_tick == 0 {
            return Err(MasterError::Config(
                "sync period, heartbeat consumer time and frames per tick must be positive".into(),
            ));
        }
        if let Some(overflow) = config.sync_counter_overflow
            && !(2..=240).contains(&overflow)
        {
            return Err(MasterError::Config(format!("SYNC counter overflow {overflow} outside 2..=240")));
        }
        let nodes = config
            .drives
            .iter()
            .copied()
            .chain(config.head)
            .map(|node| Supervised { node, last_heard_ns: None, state: None, fault: None, missing: false })
            .collect();
        Ok(CanopenMaster {
            config,
            start_ns: None,
            sync_enabled: true,
            next_sync_ns: 0,
            sync_counter: 0,
            cycle: None,
            encoders: None,
            fresh_encoders: false,
            head: None,
            nodes,
            pending_starts: Vec::new(),
            events: VecDeque::new(),
            counters: MasterCounters::default(),
        })
    }

    pub fn config(&self) -> &MasterConfig {
        &self.config
    }

    /// One step: takes the frames waiting on `bus`, starts the network on the first call (NMT
    /// start to all), sends the NMT starts booted nodes need, checks heartbeats, and sends SYNC
    /// when due. On a bus error the master's state stays consistent and the next tick retries.
    pub fn tick<B: CanBus + ?Sized>(&mut self, now_ns: u64, bus: &mut B) -> Result<(), MasterError> {
        for _ in 0..self.config.max_frames_per_tick {
            let Some(frame) = bus.recv(Duration::ZERO)? else { break };
            self.on_frame(&frame, now_ns);
        }
        if self.start_ns.is_none() {
            self.send(bus, CanopenMessage::Nmt { command: NmtCommand::Start, target: NmtTarget::All })?;
            self.counters.nmt_starts_sent += 1;
            self.start_ns = Some(now_ns);
            self.next_sync_ns = now_ns;
        }
        while let Some(&node) = self.pending_starts.first() {
            self.send(bus, CanopenMessage::Nmt { command: NmtCommand::Start, target: NmtTarget::Node(node) })?;
            self.counters.nmt_starts_sent += 1;
            self.pending_starts.remove(0);
        }
        self.supervise(now_ns);
        if self.sync_due(now_ns) {
            self.send_sync(now_ns, bus)?;
        }
        Ok(())
    }

    /// Takes one received frame (what `tick` does with each frame from the bus).
    pub fn on_frame(&mut self, frame: &CanFrame, now_ns: u64) {
        self.counters.frames_received += 1;
        let message = match CanopenMessage::decode(frame) {
            Ok(message) => message,
            Err(error) if error.is_foreign() => {
                self.counters.foreign_frames += 1;
                return;
            }
            Err(_) => {
                self.counters.malformed_frames += 1;
                return;
            }
        };
        match message {
            CanopenMessage::Heartbeat { node, state } => self.on_heartbeat(node, state, now_ns),
            CanopenMessage::Emergency { node, emergency } => {
                if let Some(entry) = self.nodes.iter_mut().find(|entry| entry.node == node) {
                    entry.fault = (emergency.error_code != 0).then_some(emergency.error_code);
                    let event = MasterEvent::Emergency {
                        node,
                        code: emergency.error_code,
                        error_register: emergency.error_register,
                    };
                    self.push_event(event);
                }
            }
            CanopenMessage::Tpdo { node, number: PdoNumber::Pdo1, data } => self.on_tpdo1(node, &data, now_ns),
            _ => {}
        }
    }

    fn on_heartbeat(&mut self, node: NodeId, state: NmtState, now_ns: u64) {
        let Some(entry) = self.nodes.iter_mut().find(|entry| entry.node == node) else { return };
        entry.last_heard_ns = Some(now_ns);
        entry.state = Some(state);
        let back = std::mem::take(&mut entry.missing);
        if state == NmtState::BootUp {
            // A freshly booted device has no error until it says so again.
            entry.fault = None;
        }
        if back {
            self.push_event(MasterEvent::NodeBack { node, state });
        }
        if state == NmtState::BootUp {
            self.push_event(MasterEvent::NodeBooted { node });
        }
        if matches!(state, NmtState::BootUp | NmtState::PreOperational) && !self.pending_starts.contains(&node) {
            self.pending_starts.push(node);
        }
    }

    fn on_tpdo1(&mut self, node: NodeId, data: &PdoData, now_ns: u64) {
        let drive = self.config.drives.iter().position(|&drive| drive == node);
        let is_head = self.config.head == Some(node);
        if drive.is_none() && !is_head {
            return;
        }
        let Some((first, second)) = data.i32_pair() else {
            self.counters.malformed_frames += 1;
            return;
        };
        if is_head {
            let stamp_ns = self.cycle.map_or(now_ns, |cycle| cycle.stamp_ns);
            self.head =
                Some(HeadAngles { pan_rad: microrad_to_angle(first), tilt_rad: microrad_to_angle(second), stamp_ns });
            return;
        }
        let (Some(wheel), Some(cycle)) = (drive, self.cycle.as_mut()) else { return };
        if cycle.delivered {
            return;
        }
        cycle.positions_counts[wheel] = first;
        cycle.velocities_counts_per_s[wheel] = second;
        cycle.answered[wheel] = true;
        if cycle.answered.iter().all(|&answered| answered) {
            cycle.delivered = true;
            self.encoders = Some(WheelEncoders {
                cycle: cycle.number,
                stamp_ns: cycle.stamp_ns,
                positions_counts: cycle.positions_counts,
                velocities_counts_per_s: cycle.velocities_counts_per_s,
            });
            self.fresh_encoders = true;
            self.counters.cycles_complete += 1;
        }
    }

    fn supervise(&mut self, now_ns: u64) {
        let start_ns = self.start_ns.unwrap_or(now_ns);
        let consumer_ns = self.config.heartbeat_consumer_ns;
        let mut lost = Vec::new();
        for entry in &mut self.nodes {
            let reference_ns = entry.last_heard_ns.unwrap_or(start_ns);
            if !entry.missing && now_ns.saturating_sub(reference_ns) > consumer_ns {
                entry.missing = true;
                lost.push(MasterEvent::NodeLost { node: entry.node, last_heard_ns: entry.last_heard_ns });
            }
        }
        for event in lost {
            self.push_event(event);
        }
    }

    /// SYNC is enabled and its time has come.
    pub fn sync_due(&self, now_ns: u64) -> bool {
        self.sync_enabled && self.start_ns.is_some() && now_ns >= self.next_sync_ns
    }

    /// Stops (and resumes) the SYNC; devices then send no PDOs (a lost-SYNC test, or a driver
    /// pausing the platform). Resuming sends the next SYNC at once.
    pub fn set_sync_enabled(&mut self, enabled: bool, now_ns: u64) {
        if enabled && !self.sync_enabled {
            self.next_sync_ns = now_ns;
        }
        self.sync_enabled = enabled;
    }

    fn send_sync<B: CanBus + ?Sized>(&mut self, now_ns: u64, bus: &mut B) -> Result<(), MasterError> {
        self.close_cycle();
        let period_ns = self.config.sync_period_ns;
        let next = self.next_sync_ns.saturating_add(period_ns);
        // Keep the phase; after a stall longer than a period, skip rather than burst.
        self.next_sync_ns = if next <= now_ns { now_ns.saturating_add(period_ns) } else { next };
        let counter = self.config.sync_counter_overflow.map(|overflow| {
            self.sync_counter = if self.sync_counter >= overflow { 1 } else { self.sync_counter + 1 };
            self.sync_counter
        });
        self.send(bus, CanopenMessage::Sync { counter })?;
        self.counters.syncs_sent += 1;
        self.cycle = Some(Cycle {
            number: self.counters.syncs_sent,
            stamp_ns: now_ns,
            positions_counts: [0; WHEELS],
            velocities_counts_per_s: [0; WHEELS],
            answered: [false; WHEELS],
            delivered: false,
        });
        Ok(())
    }

    fn close_cycle(&mut self) {
        if let Some(cycle) = self.cycle.take()
            && !cycle.delivered
        {
            self.counters.cycles_incomplete += 1;
            self.push_event(MasterEvent::CycleIncomplete { cycle: cycle.number, answered: cycle.answered });
        }
    }

    /// Sends RPDO1 to the head: target pan and tilt, clamped to the configured limits.
    pub fn command_head<B: CanBus + ?Sized>(
        &mut self,
        pan_rad: f64,
        tilt_rad: f64,
        bus: &mut B,
    ) -> Result<(), MasterError> {
        let head = self.config.head.ok_or(MasterError::NoHead)?;
        if !pan_rad.is_finite() || !tilt_rad.is_finite() {
            return Err(MasterError::InvalidAngle { pan_rad, tilt_rad });
        }
        let pan = angle_to_microrad(pan_rad.clamp(-self.config.pan_limit_rad, self.config.pan_limit_rad));
        let tilt = angle_to_microrad(tilt_rad.clamp(-self.config.tilt_limit_rad, self.config.tilt_limit_rad));
        let data = PdoData::from_i32_pair(pan, tilt);
        self.send(bus, CanopenMessage::Rpdo { node: head, number: PdoNumber::Pdo1, data })
    }

    fn send<B: CanBus + ?Sized>(&mut self, bus: &mut B, message: CanopenMessage) -> Result<(), MasterError> {
        match bus.send(&message.encode()) {
            Ok(()) => {
                self.counters.frames_sent += 1;
                Ok(())
            }
            Err(error) => {
                self.counters.send_errors += 1;
                Err(error.into())
            }
        }
    }

    fn push_event(&mut self, event: MasterEvent) {
        if self.events.len() >= EVENT_QUEUE {
            self.events.pop_front();
            self.counters.events_dropped += 1;
        }
        self.events.push_back(event);
    }

    /// The events since the last call, oldest first.
    pub fn drain_events(&mut self) -> impl Iterator<Item = MasterEvent> + '_ {
        self.events.drain(..)
    }

    /// The latest complete cycle.
    pub fn encoders(&self) -> Option<&WheelEncoders> {
        self.encoders.as_ref()
    }

    /// The latest complete cycle if it has not been taken yet.
    pub fn take_encoders(&mut self) -> Option<WheelEncoders> {
        if std::mem::take(&mut self.fresh_encoders) { self.encoders } else { None }
    }

    pub fn head_angles(&self) -> Option<HeadAngles> {
        self.head
    }

    /// The health of a supervised node, `None` for any other node.
    pub fn health(&self, node: NodeId) -> Option<NodeHealth> {
        self.nodes.iter().find(|entry| entry.node == node).map(|entry| {
            if entry.missing {
                NodeHealth::Missing { since_ns: entry.last_heard_ns.or(self.start_ns).unwrap_or(0) }
            } else if let Some(code) = entry.fault {
                NodeHealth::Fault { code }
            } else {
                match entry.state {
                    None => NodeHealth::Unknown,
                    Some(NmtState::Operational) => NodeHealth::Operational,
                    Some(state) => NodeHealth::NotOperational(state),
                }
            }
        })
    }

    /// Every supervised node with its health: drives in wheel order, then the head.
    pub fn node_health(&self) -> impl Iterator<Item = (NodeId, NodeHealth)> + '_ {
        self.nodes.iter().filter_map(|entry| Some((entry.node, self.health(entry.node)?)))
    }

    /// When `tick` next has something to do without a frame arriving: the next SYNC or the
    /// earliest heartbeat deadline.
    pub fn next_deadline_ns(&self) -> Option<u64> {
        let start_ns = self.start_ns?;
        let heartbeat = self
            .nodes
            .iter()
            .filter(|entry| !entry.missing)
            .map(|entry| {
                entry
                    .last_heard_ns
                    .unwrap_or(start_ns)
                    .saturating_add(self.config.heartbeat_consumer_ns)
                    .saturating_add(1)
            })
            .min();
        let sync = self.sync_enabled.then_some(self.next_sync_ns);
        [heartbeat, sync].into_iter().flatten().min()
    }

    pub fn counters(&self) -> MasterCounters {
        self.counters
    }
}
