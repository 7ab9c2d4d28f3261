//! The robot's own submaps as they went to the ground, kept so that a ground `RequestResend`
//! can queue them again without asking the mapper (which has no request path on the bus).
//!
//! Bounded by payload bytes: the oldest submaps are forgotten first. A resend of a forgotten or
//! unknown submap is answered `Invalid` by the node.

use std::collections::{BTreeMap, VecDeque};

use protocol::message::{SubmapChunk, SubmapHeader};
use protocol::{AnyMessage, SubmapId};

/// Chunk payload bytes kept for resends (about ten of the simulated rovers' submaps).
pub const RESEND_STORE_BYTES: usize = 4 << 20;

#[derive(Debug, Default)]
struct Stored {
    header: Option<SubmapHeader>,
    chunks: BTreeMap<u16, SubmapChunk>,
    bytes: usize,
}

#[derive(Debug)]
pub(super) struct SubmapStore {
    submaps: BTreeMap<(u8, u32), Stored>,
    /// First-seen order, oldest first.
    order: VecDeque<(u8, u32)>,
    bytes: usize,
    max_bytes: usize,
}

fn key(id: SubmapId) -> (u8, u32) {
    (id.robot.0, id.index)
}

impl SubmapStore {
    pub fn new(max_bytes: usize) -> Self {
        SubmapStore { submaps: BTreeMap::new(), order: VecDeque::new(), bytes: 0, max_bytes }
    }

    fn entry(&mut self, id: SubmapId) -> &mut Stored {
        let k = key(id);
        if !self.submaps.contains_key(&k) {
            self.order.push_back(k);
        }
        self.submaps.entry(k).or_default()
    }

    pub fn on_header(&mut self, header: &SubmapHeader) {
        self.entry(header.submap).header = Some(*header);
    }

    pub fn on_chunk(&mut self, chunk: &SubmapChunk) {
        let len = chunk.data.len();
        let stored = self.entry(chunk.submap);
        let replaced = stored.chunks.insert(chunk.index, chunk.clone()).map_or(0, |old| old.data.len());
        stored.bytes = stored.bytes + len - replaced;
        self.bytes = self.bytes + len - replaced;
        self.evict();
    }

    /// Forgets the oldest submaps until the store fits, never the newest (still being sent).
    fn evict(&mut self) {
        while self.bytes > self.max_bytes && self.order.len() > 1 {
            let Some(oldest) = self.order.pop_front() else { break };
            if let Some(stored) = self.submaps.remove(&oldest) {
                self.bytes -= stored.bytes;
            }
        }
    }

    /// The messages to send again: header and every chunk for `None`, the held chunks of the
    /// inclusive range otherwise. `None` when the submap is not held (never sent, forgotten, or
    /// its header never seen) or the range is not within the submap.
    pub fn resend(&self, id: SubmapId, range: Option<(u16, u16)>) -> Option<Vec<AnyMessage>> {
        let stored = self.submaps.get(&key(id))?;
        let header = stored.header?;
        match range {
            None => {
                let mut out = vec![AnyMessage::from(header)];
                out.extend(stored.chunks.values().cloned().map(AnyMessage::from));
                Some(out)
            }
            Some((first, last)) if first <= last && last < header.chunk_count => {
                Some(stored.chunks.range(first..=last).map(|(_, c)| AnyMessage::from(c.clone())).collect())
            }
            Some(_) => None,
        }
    }

    #[cfg(test)]
    fn held(&self) -> Vec<(u8, u32)> {
        self.submaps.keys().copied().collect()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;
    use protocol::RobotId;
    use protocol::message::SubmapEncoding;

    fn id(index: u32) -> SubmapId {
        SubmapId { robot: RobotId(1), index }
    }

    fn header(index: u32, chunk_count: u16) -> SubmapHeader {
        SubmapHeader {
            submap: id(index),
            started_stamp_ns: 0,
            finished_stamp_ns: 1,
            switch: None,
            encoding: SubmapEncoding(1),
            payload_bytes: u32::from(chunk_count) * 100,
            chunk_count,
            payload_crc32: 0,
        }
    }

    fn chunk(index: u32, i: u16) -> SubmapChunk {
        SubmapChunk { submap: id(index), index: i, data: TryFrom::try_from(&[i as u8; 100][..]).unwrap() }
    }

    #[test]
    fn resends_whole_submaps_and_ranges_and_forgets_the_oldest() {
        let mut store = SubmapStore::new(450);
        store.on_header(&header(0, 3));
        for i in 0..3 {
            store.on_chunk(&chunk(0, i));
        }
        let all = store.resend(id(0), None).unwrap();
        assert_eq!(all.len(), 4);
        assert!(matches!(all[0], AnyMessage::SubmapHeader(_)));
        let range = store.resend(id(0), Some((1, 2))).unwrap();
        assert_eq!(range, vec![AnyMessage::from(chunk(0, 1)), AnyMessage::from(chunk(0, 2))]);
        assert!(store.resend(id(0), Some((2, 3))).is_none(), "beyond the submap's chunks");
        assert!(store.resend(id(0), Some((2, 1))).is_none());
        assert!(store.resend(id(7), None).is_none());
        // A second submap overflows the 450-byte budget: the first is forgotten.
        store.on_header(&header(1, 2));
        store.on_chunk(&chunk(1, 0));
        store.on_chunk(&chunk(1, 1));
        assert_eq!(store.held(), vec![(1, 1)]);
        assert!(store.resend(id(0), None).is_none());
        assert_eq!(store.resend(id(1), None).unwrap().len(), 3);
    }
}
