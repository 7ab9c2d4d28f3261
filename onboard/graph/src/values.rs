//! Variable values: poses by key, with dense indices for the solver.

use std::collections::HashMap;

use crate::error::GraphError;
use crate::factor::Key;
use crate::se3::Pose3;

/// Poses by key, in insertion order; the position is the solver's dense variable index.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Values {
    keys: Vec<Key>,
    poses: Vec<Pose3>,
    index: HashMap<Key, usize>,
}

impl Values {
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds a variable; a key can be inserted once.
    pub fn insert(&mut self, key: Key, pose: Pose3) -> Result<usize, GraphError> {
        if self.index.contains_key(&key) {
            return Err(GraphError::DuplicateVariable(key));
        }
        let index = self.keys.len();
        self.index.insert(key, index);
        self.keys.push(key);
        self.poses.push(pose);
        Ok(index)
    }

    pub fn len(&self) -> usize {
        self.keys.len()
    }

    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    pub fn get(&self, key: Key) -> Option<&Pose3> {
        self.index.get(&key).map(|&i| &self.poses[i])
    }

    /// Dense index of a key.
    pub fn index_of(&self, key: Key) -> Option<usize> {
        self.index.get(&key).copied()
    }

    pub fn contains(&self, key: Key) -> bool {
        self.index.contains_key(&key)
    }

    pub fn keys(&self) -> &[Key] {
        &self.keys
    }

    pub fn poses(&self) -> &[Pose3] {
        &self.poses
    }

    /// Drops the variables inserted after the first `len`.
    pub(crate) fn truncate(&mut self, len: usize) {
        for key in self.keys.drain(len.min(self.keys.len())..) {
            self.index.remove(&key);
        }
        self.poses.truncate(len);
    }

    pub(crate) fn poses_mut(&mut self) -> &mut [Pose3] {
        &mut self.poses
    }

    /// `(key, pose)` in insertion order.
    pub fn iter(&self) -> impl Iterator<Item = (Key, &Pose3)> {
        self.keys.iter().copied().zip(self.poses.iter())
    }
}
