//! The Xsens MT binary protocol ("Xbus") of an MTi-10 IMU over a serial line: framing
//! ([`xbus`]), the messages we use ([`message`]), MTData2 sample packets ([`mtdata2`]), the
//! host driver ([`XsensImu`]), a device emulator for the simulator and tests ([`XsensDevice`]),
//! and the correction of sample stamps from the device's clock ([`StampCorrector`]).
//!
//! References: Xsens "MT Low Level Communication Protocol Documentation" (MT0101P) and its
//! worked example at <https://mtidocs.movella.com/mt-low-level-communication-protocol-example>,
//! the "MTi User Manual" (MT0605P, §5.3), and the knowledge-base article "An explanation of the
//! MTi fixed point output formats". Tests quote their frames verbatim.
//!
//! # Frames
//!
//! The MTi's sensor frame is marked on its housing; mounted as our IMU it is the body frame
//! (x forward, y left, z up), and that is what acceleration and rate of turn are in with the
//! default ENU setting. See [`mtdata2::CoordinateFrame`] for NED and NWU.

pub mod device;
pub mod host;
pub mod message;
pub mod mtdata2;
pub mod stamp;
pub mod xbus;

use std::io::ErrorKind;

pub use device::{DeviceCounters, DeviceMode, MTI10_DEVICE_ID, XsensDevice};
pub use host::{CommandTimeouts, HostClock, ImuReading, XsensCounters, XsensImu, host_monotonic_ns};
pub use message::OutputConfig;
pub use mtdata2::{CoordinateFrame, DataFormat, DataId, MtData, Precision};
pub use stamp::{StampCorrector, StampCorrectorConfig};
pub use xbus::{XbusCounters, XbusDecoder, XbusFrame, encode_frame};

/// Why an Xsens operation failed. Corrupt frames are not errors: they are counted
/// ([`XbusCounters`], [`XsensCounters`]) and skipped.
#[derive(Debug, thiserror::Error)]
pub enum XsensError {
    /// The OS refused an operation on the port (opening it, setting a timeout, a write that
    /// timed out); `context` says which.
    #[error("{context}: {source}")]
    Io {
        context: String,
        #[source]
        source: std::io::Error,
    },
    /// The port is gone: end of stream, a hung-up pty or unplugged USB adapter, or any read
    /// error other than a timeout. The port cannot recover; reopen it and configure again.
    #[error("{port} disconnected: {source}")]
    Disconnected {
        port: String,
        #[source]
        source: std::io::Error,
    },
    /// The device did not acknowledge a command in time, retries included.
    #[error("no acknowledgement of {command} from {port} after {attempts} attempts of {per_attempt:?}")]
    NoAck { command: &'static str, port: String, attempts: u32, per_attempt: std::time::Duration },
    /// The device answered with an Error message (MID 0x42).
    #[error("device error 0x{code:02X} ({meaning}) in reply to {command}")]
    Device { code: u8, meaning: &'static str, command: &'static str },
    /// The device acknowledged an output configuration without an output we asked for.
    #[error("the device's output configuration lacks data id {data_id:#06x} that was requested")]
    OutputRejected { data_id: u16 },
    /// An argument the protocol or the device cannot carry (a frame too long, a rate of 0 Hz).
    #[error("invalid request: {0}")]
    Invalid(String),
}

impl XsensError {
    /// For `map_err`: an [`XsensError::Io`] whose context is only built on error.
    pub(crate) fn io<C: Into<String>>(context: impl FnOnce() -> C) -> impl FnOnce(std::io::Error) -> XsensError {
        move |source| XsensError::Io { context: context().into(), source }
    }
}

/// A read that found nothing within the port's timeout (not a failure).
pub(crate) fn is_read_timeout(error: &std::io::Error) -> bool {
    matches!(error.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted)
}

/// A read failure: a serial port that fails a read (EOF, hang-up, EIO after an unplug) does not
/// come back, so every one is a disconnection.
pub(crate) fn read_failure(port: &str, source: std::io::Error) -> XsensError {
    XsensError::Disconnected { port: port.to_string(), source }
}

/// The end of stream as a disconnection.
pub(crate) fn end_of_stream(port: &str) -> XsensError {
    read_failure(port, std::io::Error::new(ErrorKind::UnexpectedEof, "end of stream"))
}

/// A write failure: a disconnection when the other end or the device is gone, otherwise (a
/// write timeout on a stuck line) an I/O error.
pub(crate) fn write_failure(port: &str, context: impl FnOnce() -> String, source: std::io::Error) -> XsensError {
    // EIO, ENXIO and ENODEV (Linux) are what a write to an unplugged USB adapter returns.
    const GONE_ERRNOS: [i32; 3] = [5, 6, 19];
    let gone = matches!(
        source.kind(),
        ErrorKind::BrokenPipe
            | ErrorKind::ConnectionReset
            | ErrorKind::ConnectionAborted
            | ErrorKind::NotConnected
            | ErrorKind::UnexpectedEof
    ) || source.raw_os_error().is_some_and(|errno| GONE_ERRNOS.contains(&errno));
    if gone {
        XsensError::Disconnected { port: port.to_string(), source }
    } else {
        XsensError::Io { context: context(), source }
    }
}
