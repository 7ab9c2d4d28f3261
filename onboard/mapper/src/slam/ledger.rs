//! Team-wide bookkeeping of submap-pair match attempts (thesis §3.3: "information about submap
//! match attempts to ensure that each pair is attempted to match at most once"; trap 22).
//!
//! Every robot keeps the same ledger from the attempt records it makes and receives. Which robot
//! tries a pair is decided by a rule every robot evaluates alike (the thesis leaves it open): a
//! pair of one robot's submaps belongs to that robot; a pair of two robots' submaps to one of the
//! two, chosen by a hash of the pair, so the work is shared evenly and no pair is tried twice.

use std::collections::BTreeMap;

use super::ids::{RobotId, SubmapId, SubmapPair};
use super::measurements::MatchAttempt;

/// How an attempt ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum AttemptOutcome {
    /// A match was found (and sent as a `SubmapMatch`).
    Matched,
    /// No acceptable alignment.
    Failed,
}

/// The attempts known to one robot.
#[derive(Debug, Clone, Default)]
pub struct MatchLedger {
    attempts: BTreeMap<SubmapPair, MatchAttempt>,
}

impl MatchLedger {
    pub fn new() -> Self {
        Self::default()
    }

    /// Records an attempt; returns false if the pair was already recorded (the first record wins,
    /// so a repeated message changes nothing).
    pub fn record(&mut self, attempt: MatchAttempt) -> bool {
        match self.attempts.entry(attempt.pair) {
            std::collections::btree_map::Entry::Occupied(_) => false,
            std::collections::btree_map::Entry::Vacant(slot) => {
                slot.insert(attempt);
                true
            }
        }
    }

    pub fn is_attempted(&self, pair: &SubmapPair) -> bool {
        self.attempts.contains_key(pair)
    }

    pub fn get(&self, pair: &SubmapPair) -> Option<&MatchAttempt> {
        self.attempts.get(pair)
    }

    pub fn len(&self) -> usize {
        self.attempts.len()
    }

    pub fn is_empty(&self) -> bool {
        self.attempts.is_empty()
    }

    pub fn iter(&self) -> impl Iterator<Item = &MatchAttempt> {
        self.attempts.values()
    }

    /// The robot whose matcher tries `pair`.
    pub fn owner(pair: &SubmapPair) -> RobotId {
        let (a, b) = (pair.first(), pair.second());
        if a.robot == b.robot {
            return a.robot;
        }
        // A high bit: FNV's lowest bit is only the parity of the input bytes.
        if (pair_hash(pair) >> 40) & 1 == 0 { a.robot } else { b.robot }
    }

    /// The pairs among `finished` that `robot` should try: not attempted by anyone, not
    /// consecutive submaps of one robot, owned by `robot`; in ascending order.
    pub fn open_pairs(&self, robot: RobotId, finished: &[SubmapId]) -> Vec<SubmapPair> {
        let mut sorted: Vec<SubmapId> = finished.to_vec();
        sorted.sort_unstable();
        sorted.dedup();
        let mut pairs = Vec::new();
        for (i, &a) in sorted.iter().enumerate() {
            for &b in &sorted[i + 1..] {
                let pair = SubmapPair::new(a, b);
                if !pair.is_consecutive() && !self.is_attempted(&pair) && Self::owner(&pair) == robot {
                    pairs.push(pair);
                }
            }
        }
        pairs
    }
}

/// A fixed mix of the pair's fields (FNV-1a over their bytes): the same on every robot and
/// every build, unlike `std`'s randomly seeded hasher.
fn pair_hash(pair: &SubmapPair) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let (a, b) = (pair.first(), pair.second());
    for byte in a
        .robot
        .to_le_bytes()
        .into_iter()
        .chain(a.index.to_le_bytes())
        .chain(b.robot.to_le_bytes())
        .chain(b.index.to_le_bytes())
    {
        h ^= u64::from(byte);
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    h
}
