//! Identities of graph nodes, stable across robots (every robot names a node the same way).

/// A robot of the team.
pub type RobotId = u16;

/// The `index`-th submap of `robot` (submap 0 starts with the robot's filter).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SubmapId {
    pub robot: RobotId,
    pub index: u32,
}

impl SubmapId {
    pub fn new(robot: RobotId, index: u32) -> Self {
        SubmapId { robot, index }
    }
}

/// The pose of `robot` at `stamp_ns` (thesis trap 9: one node per robot and image stamp, shared by
/// every detection in that image).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct PoseId {
    pub robot: RobotId,
    pub stamp_ns: u64,
}

/// A variable of the graph.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum NodeId {
    Submap(SubmapId),
    Pose(PoseId),
    Landmark(u32),
}

/// An unordered pair of submaps, stored in ascending order so both robots name it alike.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct SubmapPair {
    first: SubmapId,
    second: SubmapId,
}

impl SubmapPair {
    pub fn new(a: SubmapId, b: SubmapId) -> Self {
        if a <= b { SubmapPair { first: a, second: b } } else { SubmapPair { first: b, second: a } }
    }

    pub fn first(&self) -> SubmapId {
        self.first
    }

    pub fn second(&self) -> SubmapId {
        self.second
    }

    /// Consecutive submaps of one robot: already linked by the frame switch, never matched (thesis
    /// §6.1.1 (e) 4).
    pub fn is_consecutive(&self) -> bool {
        self.first.robot == self.second.robot && self.first.index + 1 == self.second.index
    }

    pub fn contains(&self, id: SubmapId) -> bool {
        self.first == id || self.second == id
    }
}
