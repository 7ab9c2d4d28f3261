//! Replay of a recorded mission: `DIR/ground_feed.log` (`hal::feedlog`) fed into a
//! [`TeamModel`] up to a position.
//!
//! Forward: the records between the old and the new position are ingested, then the model ticks
//! at the new position. Backward: the model restarts from the latest checkpoint at or before the
//! position (a clone taken every [`CHECKPOINT_PERIOD_NS`] of mission time while moving forward;
//! tiles are shared, the graph is rebuilt from its measurement log) or from zero.

use std::path::{Path, PathBuf};

use hal::feedlog::{FeedLogError, FeedRecord, read_feed_log};

use crate::model::{ActionError, ModelConfig, TeamModel};
use crate::view::{ReplayView, UiAction};

/// The feed log's name inside a mission directory.
pub const FEED_LOG_NAME: &str = "ground_feed.log";
/// Mission time between model checkpoints.
pub const CHECKPOINT_PERIOD_NS: u64 = 30_000_000_000;
/// Checkpoints kept (the oldest beyond are thinned out).
const MAX_CHECKPOINTS: usize = 64;
/// Clock steps while catching up, so link samples see time pass as they did live (the graph and
/// the map are brought up to date once, at the target).
const CATCH_UP_TICK_NS: u64 = 1_000_000_000;

#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    #[error("{} does not exist: a recorded mission directory holds {FEED_LOG_NAME}", path.display())]
    Missing { path: PathBuf },
    #[error("{0}")]
    FeedLog(#[from] FeedLogError),
    #[error("{} holds no records", path.display())]
    Empty { path: PathBuf },
}

#[derive(Debug, Clone)]
struct Checkpoint {
    cursor: usize,
    position_ns: u64,
    model: TeamModel,
}

/// A recorded mission and a model positioned in it.
#[derive(Debug)]
pub struct Replay {
    path: PathBuf,
    records: Vec<FeedRecord>,
    config: ModelConfig,
    model: TeamModel,
    /// Records before this index are in the model.
    cursor: usize,
    position_ns: u64,
    checkpoints: Vec<Checkpoint>,
    /// The operator's reference robot, kept across restores from checkpoints.
    reference: Option<u8>,
    /// Bytes of the log that belonged to no intact record.
    pub ignored_bytes: usize,
}

impl Replay {
    /// Opens `dir/ground_feed.log` and positions the model at the recording's start.
    pub fn open(dir: &Path, config: ModelConfig) -> Result<Replay, ReplayError> {
        let path = dir.join(FEED_LOG_NAME);
        if !path.is_file() {
            return Err(ReplayError::Missing { path });
        }
        let log = read_feed_log(&path)?;
        let mut records = log.records;
        if records.is_empty() {
            return Err(ReplayError::Empty { path });
        }
        // Stable: packets of one instant keep their recorded order.
        records.sort_by_key(|r| r.recv_ns);
        let start_ns = records.first().map_or(0, |r| r.recv_ns);
        let model = TeamModel::new(config.clone());
        let mut replay = Replay {
            path,
            records,
            config,
            model,
            cursor: 0,
            position_ns: start_ns,
            checkpoints: Vec::new(),
            reference: None,
            ignored_bytes: log.ignored_bytes,
        };
        replay.seek(start_ns);
        Ok(replay)
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    pub fn start_ns(&self) -> u64 {
        self.records.first().map_or(0, |r| r.recv_ns)
    }

    pub fn end_ns(&self) -> u64 {
        self.records.last().map_or(0, |r| r.recv_ns)
    }

    pub fn position_ns(&self) -> u64 {
        self.position_ns
    }

    pub fn records(&self) -> usize {
        self.records.len()
    }

    pub fn model(&self) -> &TeamModel {
        &self.model
    }

    /// Marks the model's view with the replay state (commands are refused while replaying).
    pub fn publish_state(&mut self, playing: bool, speed: f64) {
        let view = ReplayView {
            start_ns: self.start_ns(),
            end_ns: self.end_ns(),
            position_ns: self.position_ns,
            playing,
            speed,
        };
        self.model.set_replay(Some(view));
    }

    /// Moves to `position_ns` (clamped to the recording).
    pub fn seek(&mut self, position_ns: u64) {
        let target = position_ns.clamp(self.start_ns(), self.end_ns());
        if target < self.position_ns || self.cursor == 0 {
            self.restore(target);
        }
        let replay_state = self.model.view().replay;
        let mut next_tick = self.position_ns.saturating_add(CATCH_UP_TICK_NS);
        while let Some(recv_ns) = self.records.get(self.cursor).map(|r| r.recv_ns).filter(|t| *t <= target) {
            while next_tick < recv_ns {
                self.model.advance_clock(next_tick);
                next_tick += CATCH_UP_TICK_NS;
            }
            if self.checkpoints.last().is_none_or(|c| recv_ns >= c.position_ns + CHECKPOINT_PERIOD_NS) {
                self.checkpoint(recv_ns);
            }
            if let Some(record) = self.records.get(self.cursor) {
                self.model.ingest(recv_ns, &record.packet);
            }
            self.cursor += 1;
        }
        self.position_ns = target;
        self.model.set_replay(replay_state);
        if let Some(reference) = self.reference.filter(|r| self.model.view().reference_robot != Some(*r)) {
            // Not known yet at this position: the model keeps its own choice until it is.
            let _ = self.model.apply(target, &UiAction::SetReference(reference));
        }
        if target >= self.end_ns() {
            // The clock stops here: the last measurements must not wait for a graph period.
            self.model.settle(target);
        } else {
            self.model.tick(target);
        }
    }

    /// An operator action on the replayed model: a reference change is kept across seeks;
    /// commands are refused (a recording cannot be commanded).
    pub fn apply(&mut self, now_ns: u64, action: &UiAction) -> Result<(), ActionError> {
        if let UiAction::SetReference(robot) = action {
            self.reference = Some(*robot);
        }
        self.model.apply(now_ns, action)
    }

    fn checkpoint(&mut self, position_ns: u64) {
        self.checkpoints.push(Checkpoint { cursor: self.cursor, position_ns, model: self.model.clone() });
        if self.checkpoints.len() > MAX_CHECKPOINTS {
            // Keep the first; drop every other one of the rest.
            let mut i = 0;
            self.checkpoints.retain(|_| {
                i += 1;
                i == 1 || i % 2 == 0
            });
        }
    }

    fn restore(&mut self, target_ns: u64) {
        let replay_state = self.model.view().replay;
        match self.checkpoints.iter().rev().find(|c| c.position_ns <= target_ns) {
            Some(c) => {
                self.model = c.model.clone();
                self.cursor = c.cursor;
                self.position_ns = c.position_ns;
            }
            None => {
                self.model = TeamModel::new(self.config.clone());
                self.cursor = 0;
                self.position_ns = self.start_ns();
            }
        }
        self.model.set_replay(replay_state);
    }
}
