//! Operator commands to a robot (authenticated uplink) and the robot's acknowledgements.

use heapless::String;
use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

use crate::ids::{RobotId, SubmapId};
use crate::message::state::Mode;

/// Name of a run-time parameter, e.g. `mapper.submap_max_distance_m`.
pub type ParamName = String<32>;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, MaxSize)]
pub enum ParamValue {
    Bool(bool),
    Int(i64),
    Float(f64),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, MaxSize)]
pub enum CommandKind {
    SetMode(Mode),
    /// Drive to a point given in the target robot's own global frame (every robot has its own;
    /// there is no shared one).
    GoToWaypoint {
        x_m: f64,
        y_m: f64,
        z_m: f64,
        speed_mps: f32,
    },
    SetParameter {
        name: ParamName,
        value: ParamValue,
    },
    /// Send a submap again, whole or a chunk range `[first, last]`.
    RequestResend {
        submap: SubmapId,
        chunks: Option<(u16, u16)>,
    },
    StartRecording {
        label: String<32>,
    },
    StopRecording,
}

/// A command to one robot. It travels only inside an authenticated packet.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, MaxSize)]
pub struct Command {
    pub target: RobotId,
    /// Chosen by the sender, echoed in the [`CommandAck`].
    pub id: u32,
    pub kind: CommandKind,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub enum CommandOutcome {
    /// Authenticated and queued for execution.
    Accepted,
    /// Carried out.
    Executed,
    /// Authentic but not executable (unknown parameter, value out of range, wrong robot).
    Invalid,
    /// Authentic but cannot run now (e.g. in `Safe` mode).
    Refused,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct CommandAck {
    pub robot: RobotId,
    pub command_id: u32,
    pub outcome: CommandOutcome,
}
