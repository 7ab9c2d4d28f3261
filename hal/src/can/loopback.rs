//! [`LoopbackCanBus`]: an in-memory CAN bus between nodes of one process, for tests and
//! simulation. It keeps what a real bus guarantees to the framing (every other node sees every
//! frame, in one global order) and what it does not (a slow receiver loses frames when its
//! queue overflows), so code tested on it meets no surprise on SocketCAN.

use std::collections::VecDeque;
use std::fmt;
use std::sync::{Arc, Condvar, Mutex, MutexGuard, PoisonError};
use std::time::{Duration, Instant};

use protocol::frame::FrameError;
use protocol::frame::can::{CAN_ID_MASK, CanFrame, CanKind};

use super::CanBus;
use crate::link::{LinkError, deadline_after};

/// Default receive queue per node: a few full-size packets on a classic bus (a 1 KiB packet is
/// about 150 frames), like the receive buffer of a SocketCAN socket.
pub const DEFAULT_QUEUE_FRAMES: usize = 1024;

struct Queue {
    frames: VecDeque<CanFrame>,
    /// Frames dropped because the queue was full (the oldest go first, as in a ring buffer).
    overflowed: u64,
    /// False once the node's handle is dropped: nobody will read its queue again.
    attached: bool,
}

struct Bus {
    queues: Mutex<Vec<Queue>>,
    /// Signalled on every frame; each waiter checks its own queue.
    frame_sent: Condvar,
    kind: CanKind,
    capacity_frames: usize,
}

impl Bus {
    /// The state is consistent at every unlock (no code panics while holding it), so a poisoned
    /// lock is still safe to use: a panicking test thread must not take the others down.
    fn lock(&self) -> MutexGuard<'_, Vec<Queue>> {
        self.queues.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

/// One node's attachment to an in-memory CAN bus.
pub struct LoopbackCanBus {
    bus: Arc<Bus>,
    node: usize,
}

impl fmt::Debug for LoopbackCanBus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LoopbackCanBus")
            .field("kind", &self.bus.kind)
            .field("node", &self.node)
            .field("queue_frames", &self.bus.capacity_frames)
            .finish()
    }
}

impl LoopbackCanBus {
    /// A bus of `kind` with `nodes` attachments, each with a queue of [`DEFAULT_QUEUE_FRAMES`].
    pub fn network(kind: CanKind, nodes: usize) -> Vec<LoopbackCanBus> {
        Self::network_with_queue(kind, nodes, DEFAULT_QUEUE_FRAMES)
    }

    /// Like [`LoopbackCanBus::network`] with `queue_frames` per node (at least 1).
    pub fn network_with_queue(kind: CanKind, nodes: usize, queue_frames: usize) -> Vec<LoopbackCanBus> {
        let capacity_frames = queue_frames.max(1);
        let queues = (0..nodes)
            .map(|_| Queue { frames: VecDeque::with_capacity(capacity_frames), overflowed: 0, attached: true })
            .collect();
        let bus = Arc::new(Bus { queues: Mutex::new(queues), frame_sent: Condvar::new(), kind, capacity_frames });
        (0..nodes).map(|node| LoopbackCanBus { bus: Arc::clone(&bus), node }).collect()
    }

    /// This node's index in the network.
    pub fn node(&self) -> usize {
        self.node
    }
}

impl Drop for LoopbackCanBus {
    fn drop(&mut self) {
        if let Some(queue) = self.bus.lock().get_mut(self.node) {
            queue.attached = false;
            queue.frames.clear();
        }
    }
}

impl CanBus for LoopbackCanBus {
    /// Refuses what a real controller of this kind would: ids wider than 29 bits and lengths the
    /// bus cannot carry.
    fn send(&mut self, frame: &CanFrame) -> Result<(), LinkError> {
        if frame.id > CAN_ID_MASK {
            return Err(FrameError::InvalidCanId(frame.id).into());
        }
        let len = usize::from(frame.len);
        if len > self.bus.kind.max_data() {
            return Err(LinkError::CanFrameTooLong { len, max: self.bus.kind.max_data() });
        }
        if self.bus.kind.padded_len(len) != Some(len) {
            return Err(FrameError::InvalidCanLength(len).into());
        }
        let mut queues = self.bus.lock();
        for (node, queue) in queues.iter_mut().enumerate() {
            if node == self.node || !queue.attached {
                continue;
            }
            if queue.frames.len() >= self.bus.capacity_frames {
                queue.frames.pop_front();
                queue.overflowed = queue.overflowed.saturating_add(1);
            }
            queue.frames.push_back(*frame);
        }
        drop(queues);
        self.bus.frame_sent.notify_all();
        Ok(())
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, LinkError> {
        let deadline = deadline_after(timeout);
        let mut queues = self.bus.lock();
        loop {
            let Some(queue) = queues.get_mut(self.node) else {
                return Err(LinkError::Closed(format!("loopback CAN node {} does not exist", self.node)));
            };
            if let Some(frame) = queue.frames.pop_front() {
                return Ok(Some(frame));
            }
            let Some(left) = deadline.checked_duration_since(Instant::now()).filter(|left| !left.is_zero()) else {
                return Ok(None);
            };
            queues = self.bus.frame_sent.wait_timeout(queues, left).unwrap_or_else(PoisonError::into_inner).0;
        }
    }

    fn kind(&self) -> CanKind {
        self.bus.kind
    }

    fn dropped_frames(&self) -> u64 {
        self.bus.lock().get(self.node).map_or(0, |queue| queue.overflowed)
    }
}
