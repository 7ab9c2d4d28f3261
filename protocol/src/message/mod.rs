//! Every message type, its stable key, version, delivery class and priority.

pub mod command;
pub mod hazards;
pub mod mapping;
pub mod state;
pub mod transport;

use postcard::experimental::max_size::MaxSize;
use serde::{Serialize, de::DeserializeOwned};

pub use command::{Command, CommandAck, CommandKind, CommandOutcome, ParamName, ParamValue};
pub use hazards::{HAZARD_CELLS_MAX, HazardCells};
pub use mapping::{
    Constraint, ConstraintId, ConstraintKind, MatchAttempt, MatchOutcome, SUBMAP_CHUNK_BYTES, SubmapChunk,
    SubmapEncoding, SubmapHeader, SubmapLink,
};
pub use state::{
    ClassBytes, FilterHealth, FilterStatus, Heartbeat, Label, LinkStats, Mode, PoseEstimate, QueueStats, ResourceUsage,
    SensorAvailability, TaskStats, Telemetry,
};
pub use transport::Ack;

/// The stable key of a message type on the wire. Keys are never reused for another type.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct MessageKey(pub u8);

/// How a message type is delivered.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Delivery {
    /// Unreliable; a newer message of the same slot replaces an unsent older one.
    LatestWins,
    /// Reliable, in order per channel: sequence numbers, acknowledgements, retransmission.
    Reliable,
}

/// Transmit priority; lower values go first. Each reliable priority is its own ordered channel,
/// so a long submap transfer never holds up a command.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Priority {
    /// Acknowledgements and heartbeats.
    Control = 0,
    /// Operator commands and their acknowledgements.
    Command = 1,
    /// Loop-closure constraints and match-attempt records.
    Constraint = 2,
    /// Pose estimates.
    State = 3,
    /// Health reports and the hazard cells around a robot.
    Telemetry = 4,
    /// Finished submaps.
    Bulk = 5,
}

impl Priority {
    pub const COUNT: usize = 6;
    pub const ALL: [Priority; Self::COUNT] = [
        Priority::Control,
        Priority::Command,
        Priority::Constraint,
        Priority::State,
        Priority::Telemetry,
        Priority::Bulk,
    ];

    /// The channel number of this priority (its index in [`Priority::ALL`]).
    pub fn channel(self) -> u8 {
        self as u8
    }

    pub fn from_channel(channel: u8) -> Option<Priority> {
        Self::ALL.get(usize::from(channel)).copied()
    }
}

/// A message type of the protocol.
pub trait Message: Serialize + DeserializeOwned + MaxSize {
    const KEY: MessageKey;
    /// Bumped whenever the encoding of the type changes; decoders reject versions they do not know.
    const VERSION: u8;
    const DELIVERY: Delivery;
    const PRIORITY: Priority;
    /// Whether the packet must carry a MAC and a monotonic counter.
    const AUTHENTICATED: bool = false;
}

macro_rules! messages {
    ($( $ty:ident = $key:literal, v $ver:literal, $delivery:ident, $prio:ident $(, $auth:ident)? ; )*) => {
        $(
            impl Message for $ty {
                const KEY: MessageKey = MessageKey($key);
                const VERSION: u8 = $ver;
                const DELIVERY: Delivery = Delivery::$delivery;
                const PRIORITY: Priority = Priority::$prio;
                $( const AUTHENTICATED: bool = messages!(@auth $auth); )?
            }
        )*

        /// Any message of the protocol.
        #[derive(Debug, Clone, PartialEq)]
        pub enum AnyMessage {
            $( $ty($ty), )*
        }

        $(
            impl From<$ty> for AnyMessage {
                fn from(message: $ty) -> Self {
                    AnyMessage::$ty(message)
                }
            }
        )*

        impl AnyMessage {
            /// Keys of every message type, in declaration order.
            pub const KEYS: &'static [MessageKey] = &[$( MessageKey($key), )*];

            /// Largest postcard encoding of any message body.
            pub const MAX_BODY_SIZE: usize = {
                let mut max = 0;
                $( if <$ty as MaxSize>::POSTCARD_MAX_SIZE > max { max = <$ty as MaxSize>::POSTCARD_MAX_SIZE; } )*
                max
            };

            pub fn key(&self) -> MessageKey {
                match self { $( AnyMessage::$ty(_) => <$ty as Message>::KEY, )* }
            }

            pub fn version(&self) -> u8 {
                match self { $( AnyMessage::$ty(_) => <$ty as Message>::VERSION, )* }
            }

            pub fn delivery(&self) -> Delivery {
                match self { $( AnyMessage::$ty(_) => <$ty as Message>::DELIVERY, )* }
            }

            pub fn priority(&self) -> Priority {
                match self { $( AnyMessage::$ty(_) => <$ty as Message>::PRIORITY, )* }
            }

            pub fn requires_authentication(&self) -> bool {
                match self { $( AnyMessage::$ty(_) => <$ty as Message>::AUTHENTICATED, )* }
            }

            /// Name of the message type, for logs and link statistics.
            pub fn type_name(&self) -> &'static str {
                match self { $( AnyMessage::$ty(_) => stringify!($ty), )* }
            }

            /// Encodes the body (without header) into `out`, returning the bytes written.
            pub(crate) fn encode_body<'a>(&self, out: &'a mut [u8]) -> Result<&'a mut [u8], postcard::Error> {
                match self { $( AnyMessage::$ty(m) => postcard::to_slice(m, out), )* }
            }

            /// Decodes a body of the given key and version; the body must be consumed exactly.
            pub(crate) fn decode_body(key: MessageKey, version: u8, body: &[u8]) -> Result<AnyMessage, crate::codec::DecodeError> {
                use crate::codec::DecodeError;
                match key.0 {
                    $(
                        $key => {
                            if version != $ver {
                                return Err(DecodeError::UnsupportedVersion { key: $key, version });
                            }
                            let (message, rest) = postcard::take_from_bytes::<$ty>(body)
                                .map_err(|_| DecodeError::MalformedBody { key: $key })?;
                            if !rest.is_empty() {
                                return Err(DecodeError::TrailingBytes { count: rest.len() });
                            }
                            Ok(AnyMessage::$ty(message))
                        }
                    )*
                    other => Err(DecodeError::UnknownKey(other)),
                }
            }

            /// Priority of the type with this key, if the key is known: lets a link pick a CAN id
            /// from the header alone, without decoding the body.
            pub fn priority_of(key: MessageKey) -> Option<Priority> {
                match key.0 { $( $key => Some(Priority::$prio), )* _ => None }
            }

            /// Name of the type with this key, if the key is known.
            pub fn name_of(key: MessageKey) -> Option<&'static str> {
                match key.0 { $( $key => Some(stringify!($ty)), )* _ => None }
            }
        }
    };
    (@auth authenticated) => { true };
}

// Keys are stable forever: add new types with new keys, bump a version when an encoding changes.
messages! {
    Heartbeat       = 0x01, v 1, LatestWins, Control;
    Ack             = 0x02, v 1, LatestWins, Control;
    PoseEstimate    = 0x10, v 1, LatestWins, State;
    Telemetry       = 0x11, v 3, LatestWins, Telemetry;
    // Ahead of the submaps: the operator's picture of now, rate-limited at its source.
    HazardCells     = 0x12, v 1, LatestWins, Telemetry;
    Constraint      = 0x20, v 1, Reliable,   Constraint;
    MatchAttempt    = 0x21, v 1, Reliable,   Constraint;
    SubmapHeader    = 0x30, v 1, Reliable,   Bulk;
    SubmapChunk     = 0x31, v 1, Reliable,   Bulk;
    Command         = 0x40, v 1, Reliable,   Command, authenticated;
    CommandAck      = 0x41, v 1, Reliable,   Command;
}

impl AnyMessage {
    /// For latest-wins messages: which queued message a new one replaces (same key, same slot).
    /// Reliable messages never replace each other.
    pub fn latest_slot(&self) -> u16 {
        match self {
            AnyMessage::Heartbeat(m) => u16::from(m.node.0),
            AnyMessage::Ack(m) => u16::from(m.channel),
            AnyMessage::PoseEstimate(m) => u16::from(m.robot.0),
            AnyMessage::Telemetry(m) => u16::from(m.robot.0),
            AnyMessage::HazardCells(m) => u16::from(m.robot.0),
            _ => 0,
        }
    }
}
