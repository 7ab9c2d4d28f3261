//! [`CanInterface`]: which CAN bus a node uses, named in one string (a config value or a
//! command-line argument) and opened as a `Box<dyn CanBus>`.
//!
//! ```text
//! socketcan:<ifname>                          SocketCAN, classic CAN (Linux)
//! socketcan-fd:<ifname>                       SocketCAN, CAN FD (Linux)
//! slcan:<serial path>@<bit rate>[,<baud>]     SLCAN adapter; bit rate one of S0-S8's
//! ```
//!
//! For example `socketcan:can0`, `slcan:/dev/ttyACM0@500000`, `slcan:/dev/ttyUSB0@1000000,921600`.
//! The serial baud defaults to [`DEFAULT_SERIAL_BAUD`] (115 200; USB adapters ignore it). The
//! path is everything before the last `@`, so it may contain `@` itself. There is no `loopback`:
//! an in-memory bus is shared by nodes of one process, so it is built with
//! [`LoopbackCanBus::network`](super::LoopbackCanBus::network), never opened by name.

use std::fmt;
use std::str::FromStr;

use protocol::frame::can::CanKind;

use super::CanBus;
use super::slcan::{DEFAULT_SERIAL_BAUD, SlcanBitrate, SlcanBus};
use crate::link::LinkError;

/// Longest Linux interface name (IFNAMSIZ less its NUL).
const MAX_IFNAME_BYTES: usize = 15;
const SYNTAX: &str =
    "expected socketcan:<ifname>, socketcan-fd:<ifname> or slcan:<serial path>@<bit rate>[,<serial baud>]";

/// A CAN bus to open, parsed from its name (see the module doc).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum CanInterface {
    SocketCan { interface: String, kind: CanKind },
    Slcan { path: String, bitrate: SlcanBitrate, serial_baud: u32 },
}

/// Why a CAN interface name does not parse. Each message quotes the part at fault.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InterfaceError {
    #[error("empty CAN interface name; {SYNTAX}")]
    Empty,
    #[error("CAN interface {0:?} has no `scheme:`; {SYNTAX}")]
    MissingScheme(String),
    #[error("unknown CAN interface scheme {0:?}; {SYNTAX}")]
    UnknownScheme(String),
    #[error("SocketCAN interface name {name:?} {reason}")]
    InvalidInterfaceName { name: String, reason: &'static str },
    #[error("slcan interface without a serial path; e.g. slcan:/dev/ttyACM0@500000")]
    MissingPath,
    #[error("slcan:{0} has no CAN bit rate; write slcan:{0}@<bit rate>, e.g. slcan:{0}@500000")]
    MissingBitrate(String),
    #[error("{what} {text:?} is not a number")]
    InvalidNumber { what: &'static str, text: String },
    #[error(
        "SLCAN cannot run CAN at {0} bit/s; its rates are 10000, 20000, 50000, 100000, 125000, 250000, 500000, \
         750000 and 1000000"
    )]
    UnsupportedBitrate(u32),
    #[error("serial baud must be positive, got 0")]
    ZeroSerialBaud,
}

impl CanInterface {
    /// Opens the bus: a SocketCAN socket, or the SLCAN adapter with its channel open.
    pub fn open(&self) -> Result<Box<dyn CanBus>, LinkError> {
        match self {
            CanInterface::SocketCan { interface, kind } => open_socketcan(interface, *kind),
            CanInterface::Slcan { path, bitrate, serial_baud } => {
                Ok(Box::new(SlcanBus::open(path, *serial_baud, bitrate.bits_per_second())?))
            }
        }
    }

    /// The kind of bus this interface carries (SLCAN: classic only).
    pub fn kind(&self) -> CanKind {
        match self {
            CanInterface::SocketCan { kind, .. } => *kind,
            CanInterface::Slcan { .. } => CanKind::Classic,
        }
    }
}

#[cfg(target_os = "linux")]
fn open_socketcan(interface: &str, kind: CanKind) -> Result<Box<dyn CanBus>, LinkError> {
    Ok(Box::new(super::SocketCanBus::open(interface, kind)?))
}

#[cfg(not(target_os = "linux"))]
fn open_socketcan(interface: &str, _kind: CanKind) -> Result<Box<dyn CanBus>, LinkError> {
    Err(LinkError::Config(format!("SocketCAN interface {interface}: SocketCAN exists on Linux only; use slcan:")))
}

impl FromStr for CanInterface {
    type Err = InterfaceError;

    /// Surrounding whitespace is ignored; everything else must fit the syntax exactly.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let text = text.trim();
        if text.is_empty() {
            return Err(InterfaceError::Empty);
        }
        let (scheme, rest) = text.split_once(':').ok_or_else(|| InterfaceError::MissingScheme(text.to_string()))?;
        match scheme {
            "socketcan" => {
                parse_ifname(rest).map(|interface| CanInterface::SocketCan { interface, kind: CanKind::Classic })
            }
            "socketcan-fd" => {
                parse_ifname(rest).map(|interface| CanInterface::SocketCan { interface, kind: CanKind::Fd })
            }
            "slcan" => parse_slcan(rest),
            other => Err(InterfaceError::UnknownScheme(other.to_string())),
        }
    }
}

/// Linux's own rules for a device name (`dev_valid_name`).
fn parse_ifname(name: &str) -> Result<String, InterfaceError> {
    let invalid = |reason| Err(InterfaceError::InvalidInterfaceName { name: name.to_string(), reason });
    if name.is_empty() {
        return invalid("is empty");
    }
    if name.len() > MAX_IFNAME_BYTES {
        return invalid("is longer than 15 bytes");
    }
    if name == "." || name == ".." {
        return invalid("is not a device name");
    }
    if name.chars().any(|c| c == '/' || c == ':' || c.is_whitespace() || c.is_control()) {
        return invalid("contains '/', ':', whitespace or a control character");
    }
    Ok(name.to_string())
}

fn parse_slcan(rest: &str) -> Result<CanInterface, InterfaceError> {
    if rest.is_empty() {
        return Err(InterfaceError::MissingPath);
    }
    let (path, settings) = rest.rsplit_once('@').ok_or_else(|| InterfaceError::MissingBitrate(rest.to_string()))?;
    if path.is_empty() {
        return Err(InterfaceError::MissingPath);
    }
    let (bitrate_text, baud_text) = match settings.split_once(',') {
        Some((bitrate, baud)) => (bitrate, Some(baud)),
        None => (settings, None),
    };
    let bitrate_value = parse_number(bitrate_text, "CAN bit rate")?;
    let bitrate =
        SlcanBitrate::from_bits_per_second(bitrate_value).ok_or(InterfaceError::UnsupportedBitrate(bitrate_value))?;
    let serial_baud = match baud_text {
        Some(text) => parse_number(text, "serial baud")?,
        None => DEFAULT_SERIAL_BAUD,
    };
    if serial_baud == 0 {
        return Err(InterfaceError::ZeroSerialBaud);
    }
    Ok(CanInterface::Slcan { path: path.to_string(), bitrate, serial_baud })
}

/// Decimal digits only: `u32::from_str` would also take a leading `+`.
fn parse_number(text: &str, what: &'static str) -> Result<u32, InterfaceError> {
    let invalid = || InterfaceError::InvalidNumber { what, text: text.to_string() };
    if text.is_empty() || !text.bytes().all(|b| b.is_ascii_digit()) {
        return Err(invalid());
    }
    text.parse().map_err(|_| invalid())
}

impl fmt::Display for CanInterface {
    /// The name `from_str` parses back to the same interface (the serial baud always written).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CanInterface::SocketCan { interface, kind: CanKind::Classic } => write!(f, "socketcan:{interface}"),
            CanInterface::SocketCan { interface, kind: CanKind::Fd } => write!(f, "socketcan-fd:{interface}"),
            CanInterface::Slcan { path, bitrate, serial_baud } => {
                write!(f, "slcan:{path}@{},{serial_baud}", bitrate.bits_per_second())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    fn parse(text: &str) -> Result<CanInterface, InterfaceError> {
        text.parse()
    }

    #[test]
    fn socketcan_names() {
        assert_eq!(
            parse("socketcan:can0"),
            Ok(CanInterface::SocketCan { interface: "can0".into(), kind: CanKind::Classic })
        );
        assert_eq!(
            parse("  socketcan-fd:vcan0\n"),
            Ok(CanInterface::SocketCan { interface: "vcan0".into(), kind: CanKind::Fd })
        );
        assert_eq!(parse("socketcan:can0").map(|i| i.kind()), Ok(CanKind::Classic));
    }

    #[test]
    fn slcan_names() {
        assert_eq!(
            parse("slcan:/dev/ttyACM0@1000000"),
            Ok(CanInterface::Slcan {
                path: "/dev/ttyACM0".into(),
                bitrate: SlcanBitrate::B1M,
                serial_baud: DEFAULT_SERIAL_BAUD
            })
        );
        assert_eq!(
            parse("slcan:/dev/ttyUSB0@500000,921600"),
            Ok(CanInterface::Slcan { path: "/dev/ttyUSB0".into(), bitrate: SlcanBitrate::B500k, serial_baud: 921_600 })
        );
        // The path keeps its own '@'; the last one starts the settings.
        assert_eq!(
            parse("slcan:/dev/serial/by-id/usb-x@y@125000"),
            Ok(CanInterface::Slcan {
                path: "/dev/serial/by-id/usb-x@y".into(),
                bitrate: SlcanBitrate::B125k,
                serial_baud: DEFAULT_SERIAL_BAUD
            })
        );
        assert_eq!(parse("slcan:/dev/ttyACM0@500000").map(|i| i.kind()), Ok(CanKind::Classic));
    }

    #[test]
    fn errors_name_the_fault() {
        assert_eq!(parse(""), Err(InterfaceError::Empty));
        assert_eq!(parse("   "), Err(InterfaceError::Empty));
        assert_eq!(parse("can0"), Err(InterfaceError::MissingScheme("can0".into())));
        assert_eq!(parse("loopback:x"), Err(InterfaceError::UnknownScheme("loopback".into())));
        assert_eq!(parse("SocketCAN:can0"), Err(InterfaceError::UnknownScheme("SocketCAN".into())));
        assert!(matches!(parse("socketcan:"), Err(InterfaceError::InvalidInterfaceName { reason: "is empty", .. })));
        assert!(matches!(parse("socketcan:abcdefghijklmnop"), Err(InterfaceError::InvalidInterfaceName { .. })));
        assert!(matches!(parse("socketcan:can 0"), Err(InterfaceError::InvalidInterfaceName { .. })));
        assert!(matches!(parse("socketcan:a/b"), Err(InterfaceError::InvalidInterfaceName { .. })));
        assert!(matches!(parse("socketcan:.."), Err(InterfaceError::InvalidInterfaceName { .. })));
        assert_eq!(parse("slcan:"), Err(InterfaceError::MissingPath));
        assert_eq!(parse("slcan:@500000"), Err(InterfaceError::MissingPath));
        assert_eq!(parse("slcan:/dev/ttyACM0"), Err(InterfaceError::MissingBitrate("/dev/ttyACM0".into())));
        assert_eq!(
            parse("slcan:/dev/ttyACM0@"),
            Err(InterfaceError::InvalidNumber { what: "CAN bit rate", text: String::new() })
        );
        assert_eq!(
            parse("slcan:/dev/ttyACM0@500k"),
            Err(InterfaceError::InvalidNumber { what: "CAN bit rate", text: "500k".into() })
        );
        assert_eq!(parse("slcan:/dev/ttyACM0@800000"), Err(InterfaceError::UnsupportedBitrate(800_000)));
        assert_eq!(
            parse("slcan:/dev/ttyACM0@99999999999"),
            Err(InterfaceError::InvalidNumber { what: "CAN bit rate", text: "99999999999".into() })
        );
        assert_eq!(
            parse("slcan:/dev/ttyACM0@500000,+9600"),
            Err(InterfaceError::InvalidNumber { what: "serial baud", text: "+9600".into() })
        );
        assert_eq!(
            parse("slcan:/dev/ttyACM0@500000,9600,8N1"),
            Err(InterfaceError::InvalidNumber { what: "serial baud", text: "9600,8N1".into() })
        );
        assert_eq!(parse("slcan:/dev/ttyACM0@500000,0"), Err(InterfaceError::ZeroSerialBaud));
        // Every message carries the syntax or the offending text.
        let message = parse("can0").unwrap_err().to_string();
        assert!(message.contains("slcan:<serial path>@<bit rate>"), "{message}");
    }

    #[test]
    fn every_slcan_rate_parses() {
        for rate in SlcanBitrate::ALL {
            let text = format!("slcan:/dev/ttyACM0@{}", rate.bits_per_second());
            assert!(matches!(parse(&text), Ok(CanInterface::Slcan { bitrate, .. }) if bitrate == rate), "{text}");
        }
    }

    #[test]
    fn opening_a_missing_adapter_is_an_io_error() {
        let interface = parse("slcan:/dev/nonexistent-slcan-adapter@500000").unwrap();
        match interface.open() {
            Err(LinkError::Io { context, .. }) => {
                assert!(context.contains("/dev/nonexistent-slcan-adapter"), "{context}")
            }
            Err(other) => panic!("expected an Io error, got {other:?}"),
            Ok(_) => panic!("opened an adapter that does not exist"),
        }
    }

    proptest! {
        #[test]
        fn parser_is_total(text in ".{0,64}") {
            let _ = parse(&text);
        }

        #[test]
        fn display_parses_back(
            path in "/[a-zA-Z0-9_/@.-]{1,30}",
            rate in 0usize..9,
            baud in 1u32..=4_000_000,
            ifname in "[a-z][a-z0-9_.-]{0,14}",
            fd in any::<bool>(),
        ) {
            let slcan = CanInterface::Slcan { path, bitrate: SlcanBitrate::ALL[rate], serial_baud: baud };
            prop_assert_eq!(parse(&slcan.to_string()), Ok(slcan));
            let kind = if fd { CanKind::Fd } else { CanKind::Classic };
            let socketcan = CanInterface::SocketCan { interface: ifname, kind };
            prop_assert_eq!(parse(&socketcan.to_string()), Ok(socketcan));
        }
    }
}
