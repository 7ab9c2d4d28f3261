//! The Xbus messages the driver and the emulator exchange: message ids, the output
//! configuration list and the device's error codes.
//!
//! A request's acknowledgement has the request's message id plus one.

use super::mtdata2::DataId;

/// Message ids (MID).
pub mod mid {
    /// Host → device: which device is this?
    pub const REQ_DID: u8 = 0x00;
    /// Device → host: the 4-byte big-endian device id.
    pub const DEVICE_ID: u8 = 0x01;
    pub const GO_TO_MEASUREMENT: u8 = 0x10;
    pub const GO_TO_MEASUREMENT_ACK: u8 = 0x11;
    pub const GO_TO_CONFIG: u8 = 0x30;
    pub const GO_TO_CONFIG_ACK: u8 = 0x31;
    /// Device → host: a sample, as (data id, size, data) packets.
    pub const MT_DATA2: u8 = 0x36;
    /// Device → host at power-up; answered with [`WAKE_UP_ACK`] it stays in config mode.
    pub const WAKE_UP: u8 = 0x3E;
    pub const WAKE_UP_ACK: u8 = 0x3F;
    /// Device → host: the previous message failed; one byte of error code.
    pub const ERROR: u8 = 0x42;
    /// Host → device: (data id, frequency) pairs; with no payload, a request for the current list.
    pub const SET_OUTPUT_CONFIGURATION: u8 = 0xC0;
    /// Device → host: the configuration now in force.
    pub const OUTPUT_CONFIGURATION: u8 = 0xC1;
}

/// Error codes of the Error message (MID 0x42).
pub mod error_code {
    /// A period or frequency outside the valid range.
    pub const INVALID_PERIOD: u8 = 0x03;
    /// The message is invalid, or not valid in the current state.
    pub const INVALID_MESSAGE: u8 = 0x04;
    /// A parameter is invalid or out of range.
    pub const INVALID_PARAMETER: u8 = 0x21;
}

/// What an error code means, for messages.
pub fn error_meaning(code: u8) -> &'static str {
    match code {
        error_code::INVALID_PERIOD => "period out of range",
        error_code::INVALID_MESSAGE => "message invalid or not valid in this state",
        error_code::INVALID_PARAMETER => "invalid parameter",
        _ => "unknown error code",
    }
}

/// One entry of SetOutputConfiguration: a data id (with its format bits) and the rate at which
/// the device sends it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct OutputConfig {
    pub data_id: DataId,
    /// Output frequency, or [`OutputConfig::EVERY_PACKET`].
    pub frequency_hz: u16,
}

impl OutputConfig {
    /// "In every MTData2 the device sends", for counters and time stamps.
    pub const EVERY_PACKET: u16 = 0xFFFF;

    pub fn new(data_id: DataId, frequency_hz: u16) -> Self {
        OutputConfig { data_id, frequency_hz }
    }

    /// Appends the configuration list as SetOutputConfiguration's payload.
    pub fn encode_list(list: &[OutputConfig], out: &mut Vec<u8>) {
        for entry in list {
            out.extend_from_slice(&entry.data_id.0.to_be_bytes());
            out.extend_from_slice(&entry.frequency_hz.to_be_bytes());
        }
    }

    /// Parses a SetOutputConfiguration (or its acknowledgement) payload; `None` if its length is
    /// not a multiple of 4.
    pub fn decode_list(payload: &[u8]) -> Option<Vec<OutputConfig>> {
        if !payload.len().is_multiple_of(4) {
            return None;
        }
        Some(
            payload
                .chunks_exact(4)
                .map(|c| OutputConfig {
                    data_id: DataId(u16::from_be_bytes([c[0], c[1]])),
                    frequency_hz: u16::from_be_bytes([c[2], c[3]]),
                })
                .collect(),
        )
    }
}
