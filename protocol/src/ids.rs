//! Identifiers of nodes, submaps and graph variables.

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

/// A participant on a link: a robot (1..=239), the ground station, or everyone.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize, MaxSize)]
pub struct NodeId(pub u8);

impl NodeId {
    /// The ground station.
    pub const GROUND: NodeId = NodeId(0xF0);
    /// Every node that hears the link.
    pub const BROADCAST: NodeId = NodeId(0xFF);

    /// Whether this is a robot's id (as opposed to the ground station or broadcast).
    pub fn is_robot(self) -> bool {
        (1..=0xEF).contains(&self.0)
    }
}

/// A robot of the team. Robot ids double as [`NodeId`]s on the links.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize, MaxSize)]
pub struct RobotId(pub u8);

impl From<RobotId> for NodeId {
    fn from(robot: RobotId) -> Self {
        NodeId(robot.0)
    }
}

/// A submap, unique team-wide: the robot that made it and its running index on that robot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize, MaxSize)]
pub struct SubmapId {
    pub robot: RobotId,
    pub index: u32,
}

/// A variable node of the team's pose graph that a constraint refers to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum NodeRef {
    /// The origin of a submap.
    SubmapOrigin(SubmapId),
    /// A robot's body pose at a capture time (attached through that robot's filter-pose buffer).
    RobotPose { robot: RobotId, stamp_ns: u64 },
    /// A global landmark, numbered team-wide.
    Landmark { id: u32 },
}
