//! Transport control: acknowledgements of reliable channels.

use postcard::experimental::max_size::MaxSize;
use serde::{Deserialize, Serialize};

/// Receiver state of one reliable channel, sent back to the sender (latest wins).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, MaxSize)]
pub struct Ack {
    /// The reliable channel acknowledged (see [`crate::Priority::channel`]).
    pub channel: u8,
    /// Every sequence number below this one has been received.
    pub next_expected: u32,
    /// Bit `i` set: `next_expected + 1 + i` has been received too (selective acknowledgement).
    pub received_mask: u32,
}
