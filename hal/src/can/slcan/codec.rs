//! The Lawicel SLCAN line format: encoding of every line either side sends, and a streaming
//! decoder that survives any byte sequence.

use std::fmt;

use protocol::frame::can::{CAN_ID_MASK, CAN_STANDARD_ID_MASK, CanFrame};

/// Ends every line in both directions, and is on its own the adapter's "OK".
pub const CR: u8 = b'\r';
/// The adapter's error reply. It replaces a line rather than ending one, so it has no CR.
pub const BELL: u8 = 0x07;
/// Longest line without its CR: an extended data frame with 8 bytes and a timestamp,
/// `T1FFFFFFF8` + 16 hex digits + 4 hex digits.
pub const MAX_LINE_BYTES: usize = 1 + 8 + 1 + 16 + 4;
/// Classic CAN carries at most this many data bytes; SLCAN's DLC digit is 0–8.
pub const MAX_DATA_BYTES: usize = 8;

const STANDARD_ID_DIGITS: usize = 3;
const EXTENDED_ID_DIGITS: usize = 8;
const TIMESTAMP_DIGITS: usize = 4;
const HEX_UPPER: &[u8; 16] = b"0123456789ABCDEF";

/// Why a line or a value is not valid SLCAN. The decoder counts these and goes on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum SlcanError {
    #[error("unknown SLCAN line starting with byte {0:#04x}")]
    UnknownCommand(u8),
    #[error("{what} of {len} bytes has the wrong length for its kind")]
    BadLength { what: &'static str, len: usize },
    #[error("non-hexadecimal digit in the {0}")]
    InvalidHex(&'static str),
    #[error("CAN id {id:#x} does not fit {} bits", if *extended { 29 } else { 11 })]
    IdOutOfRange { id: u32, extended: bool },
    #[error("DLC character {0:#04x} is not a classic CAN length 0-8")]
    InvalidDlc(u8),
    #[error("{0} data bytes do not fit a classic CAN frame (at most 8)")]
    DataTooLong(usize),
    #[error("bit rate command S{0} is not one of S0-S8")]
    UnsupportedBitrateCode(u8),
    #[error("CAN FD line (d, D, b, B): this SLCAN implementation carries classic CAN only")]
    FdFrame,
    #[error("line longer than {MAX_LINE_BYTES} bytes")]
    Overlong,
    #[error("version and serial number replies are 4 alphanumeric characters")]
    InvalidTag,
}

/// The bit rates of the `S0`–`S8` commands.
///
/// `S7` is 750 kbit/s as on the CANable and in python-can; Lawicel's original CAN232 used it for
/// 800 kbit/s, which no adapter we target implements.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum SlcanBitrate {
    B10k,
    B20k,
    B50k,
    B100k,
    B125k,
    B250k,
    B500k,
    B750k,
    B1M,
}

impl SlcanBitrate {
    /// Every rate, in command-code order (`S0` first).
    pub const ALL: [SlcanBitrate; 9] = [
        SlcanBitrate::B10k,
        SlcanBitrate::B20k,
        SlcanBitrate::B50k,
        SlcanBitrate::B100k,
        SlcanBitrate::B125k,
        SlcanBitrate::B250k,
        SlcanBitrate::B500k,
        SlcanBitrate::B750k,
        SlcanBitrate::B1M,
    ];

    pub const fn bits_per_second(self) -> u32 {
        match self {
            SlcanBitrate::B10k => 10_000,
            SlcanBitrate::B20k => 20_000,
            SlcanBitrate::B50k => 50_000,
            SlcanBitrate::B100k => 100_000,
            SlcanBitrate::B125k => 125_000,
            SlcanBitrate::B250k => 250_000,
            SlcanBitrate::B500k => 500_000,
            SlcanBitrate::B750k => 750_000,
            SlcanBitrate::B1M => 1_000_000,
        }
    }

    /// The digit of its `S` command.
    pub const fn code(self) -> u8 {
        self as u8
    }

    pub fn from_code(code: u8) -> Option<Self> {
        Self::ALL.get(usize::from(code)).copied()
    }

    pub fn from_bits_per_second(bits_per_second: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|rate| rate.bits_per_second() == bits_per_second)
    }
}

impl fmt::Display for SlcanBitrate {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} bit/s", self.bits_per_second())
    }
}

/// One CAN frame as SLCAN carries it: data or remote, standard or extended id, at most 8 data
/// bytes, and the adapter's optional millisecond timestamp. Always valid, so it always encodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlcanFrame {
    id: u32,
    extended: bool,
    remote: bool,
    /// Data length, or the requested length of a remote frame.
    dlc: u8,
    data: [u8; MAX_DATA_BYTES],
    timestamp: Option<u16>,
}

impl SlcanFrame {
    /// A data frame with `data` (at most 8 bytes).
    pub fn data(id: u32, extended: bool, data: &[u8]) -> Result<Self, SlcanError> {
        check_id(id, extended)?;
        if data.len() > MAX_DATA_BYTES {
            return Err(SlcanError::DataTooLong(data.len()));
        }
        let mut bytes = [0; MAX_DATA_BYTES];
        bytes.get_mut(..data.len()).ok_or(SlcanError::DataTooLong(data.len()))?.copy_from_slice(data);
        Ok(SlcanFrame { id, extended, remote: false, dlc: data.len() as u8, data: bytes, timestamp: None })
    }

    /// A remote (RTR) frame asking for `dlc` bytes.
    pub fn remote(id: u32, extended: bool, dlc: u8) -> Result<Self, SlcanError> {
        check_id(id, extended)?;
        if usize::from(dlc) > MAX_DATA_BYTES {
            return Err(SlcanError::InvalidDlc(dlc));
        }
        Ok(SlcanFrame { id, extended, remote: true, dlc, data: [0; MAX_DATA_BYTES], timestamp: None })
    }

    /// The data frame carrying `frame`; fails for ids out of range and frames over 8 bytes.
    pub fn from_can(frame: &CanFrame) -> Result<Self, SlcanError> {
        if usize::from(frame.len) > MAX_DATA_BYTES {
            return Err(SlcanError::DataTooLong(usize::from(frame.len)));
        }
        Self::data(frame.id, frame.extended, frame.data())
    }

    /// The same frame with the adapter's timestamp (milliseconds, Lawicel wraps it at 60 000).
    pub fn with_timestamp(mut self, timestamp: Option<u16>) -> Self {
        self.timestamp = timestamp;
        self
    }

    pub fn id(&self) -> u32 {
        self.id
    }

    pub fn is_extended(&self) -> bool {
        self.extended
    }

    pub fn is_remote(&self) -> bool {
        self.remote
    }

    /// The DLC: data length, or for a remote frame the length requested.
    pub fn dlc(&self) -> u8 {
        self.dlc
    }

    /// The data bytes; empty for a remote frame.
    pub fn payload(&self) -> &[u8] {
        if self.remote { &[] } else { self.data.get(..usize::from(self.dlc)).unwrap_or(&self.data) }
    }

    pub fn timestamp(&self) -> Option<u16> {
        self.timestamp
    }

    /// The frame as the rest of hal sees it; `None` for a remote frame, which [`CanFrame`]
    /// cannot express.
    pub fn to_can(&self) -> Option<CanFrame> {
        if self.remote {
            return None;
        }
        let frame = if self.extended {
            CanFrame::new(self.id, self.payload())
        } else {
            CanFrame::standard(self.id, self.payload())
        };
        frame.ok()
    }
}

fn check_id(id: u32, extended: bool) -> Result<(), SlcanError> {
    let max = if extended { CAN_ID_MASK } else { CAN_STANDARD_ID_MASK };
    if id > max {
        return Err(SlcanError::IdOutOfRange { id, extended });
    }
    Ok(())
}

/// Four alphanumeric characters: the payload of the version (`Vhhss`) and serial number
/// (`Nxxxx`) replies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Tag([u8; 4]);

impl Tag {
    pub fn new(chars: [u8; 4]) -> Result<Self, SlcanError> {
        if chars.iter().all(u8::is_ascii_alphanumeric) { Ok(Tag(chars)) } else { Err(SlcanError::InvalidTag) }
    }

    /// For constants: a character that is not alphanumeric becomes `0` (a `const fn` cannot
    /// return the error usefully).
    pub(super) const fn from_static(chars: [u8; 4]) -> Self {
        let mut chars = chars;
        let mut index = 0;
        while index < chars.len() {
            if !chars[index].is_ascii_alphanumeric() {
                chars[index] = b'0';
            }
            index += 1;
        }
        Tag(chars)
    }

    pub fn as_bytes(&self) -> &[u8; 4] {
        &self.0
    }

    pub fn as_str(&self) -> &str {
        // Alphanumeric ASCII by construction, so always UTF-8.
        std::str::from_utf8(&self.0).unwrap_or_default()
    }
}

impl fmt::Display for Tag {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// What a host asks of the adapter (every command but the frames, which are [`Line::Frame`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Command {
    /// `S0`–`S8`: the CAN bit rate; only while the channel is closed.
    SetBitrate(SlcanBitrate),
    /// `sXXYY`: SJA1000 bit timing registers BTR0 and BTR1 (python-can's `timing=`).
    SetBitTiming { btr0: u8, btr1: u8 },
    /// `O`: open the channel.
    Open,
    /// `L`: open the channel listening only (no transmission, no acknowledgement on the bus).
    ListenOnly,
    /// `C`: close the channel.
    Close,
    /// `F`: read (and clear) the status flags; only while open.
    Status,
    /// `V`: hardware and software version.
    Version,
    /// `N`: serial number.
    SerialNumber,
    /// `Z0` / `Z1`: millisecond timestamps on received frames off / on; only while closed.
    Timestamps(bool),
}

/// What an adapter answers.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Reply {
    /// An empty line: the command succeeded. (A host sending an empty line flushes the
    /// adapter's line buffer; adapters answer it like any command.)
    Ok,
    /// BELL: the command was refused or not understood.
    Error,
    /// `z` / `Z`: a Lawicel adapter's acknowledgement of a transmitted standard / extended frame
    /// (CANable-class adapters answer a plain OK instead).
    TransmitAck { extended: bool },
    /// `Fxx`: the status flags (bit 0 receive FIFO full, 1 transmit FIFO full, 2 error warning,
    /// 3 data overrun, 5 error passive, 6 arbitration lost, 7 bus error).
    Status(u8),
    /// `Vhhss`: hardware and software version.
    Version(Tag),
    /// `Nxxxx`: serial number.
    SerialNumber(Tag),
}

/// One line of SLCAN in either direction. The two directions never share a spelling (a
/// command has fewer characters than the reply of the same letter), so one decoder serves both.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Line {
    Frame(SlcanFrame),
    Command(Command),
    Reply(Reply),
}

/// Status flag bit: frames were lost (receive queue or host link overflowed).
pub const STATUS_DATA_OVERRUN: u8 = 1 << 3;

/// One encoded line, at most [`MAX_LINE_BYTES`] + 1 bytes, on the stack.
#[derive(Clone, Copy)]
pub struct EncodedLine {
    bytes: [u8; MAX_LINE_BYTES + 1],
    len: u8,
}

impl EncodedLine {
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.get(..usize::from(self.len)).unwrap_or(&self.bytes)
    }

    fn new() -> Self {
        EncodedLine { bytes: [0; MAX_LINE_BYTES + 1], len: 0 }
    }

    /// Appends `byte`; every caller stays within [`MAX_LINE_BYTES`] + 1 by construction, and a
    /// byte past that would be dropped rather than panic.
    fn push(&mut self, byte: u8) {
        if let Some(slot) = self.bytes.get_mut(usize::from(self.len)) {
            *slot = byte;
            self.len += 1;
        }
    }

    fn push_hex(&mut self, value: u32, digits: usize) {
        for shift in (0..digits).rev() {
            self.push(HEX_UPPER[((value >> (4 * shift)) & 0xF) as usize]);
        }
    }
}

impl fmt::Debug for EncodedLine {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:?}", self.as_bytes().escape_ascii().to_string())
    }
}

impl Line {
    /// The line's bytes, its CR included (BELL stands alone). Hex digits are upper case, as
    /// python-can and the CANable write them.
    pub fn encode(&self) -> EncodedLine {
        let mut out = EncodedLine::new();
        match self {
            Line::Frame(frame) => {
                let letter = match (frame.remote, frame.extended) {
                    (false, false) => b't',
                    (false, true) => b'T',
                    (true, false) => b'r',
                    (true, true) => b'R',
                };
                out.push(letter);
                out.push_hex(frame.id, if frame.extended { EXTENDED_ID_DIGITS } else { STANDARD_ID_DIGITS });
                out.push(b'0' + frame.dlc);
                for &byte in frame.payload() {
                    out.push_hex(u32::from(byte), 2);
                }
                if let Some(timestamp) = frame.timestamp {
                    out.push_hex(u32::from(timestamp), TIMESTAMP_DIGITS);
                }
            }
            Line::Command(command) => match *command {
                Command::SetBitrate(rate) => {
                    out.push(b'S');
                    out.push(b'0' + rate.code());
                }
                Command::SetBitTiming { btr0, btr1 } => {
                    out.push(b's');
                    out.push_hex(u32::from(btr0), 2);
                    out.push_hex(u32::from(btr1), 2);
                }
                Command::Open => out.push(b'O'),
                Command::ListenOnly => out.push(b'L'),
                Command::Close => out.push(b'C'),
                Command::Status => out.push(b'F'),
                Command::Version => out.push(b'V'),
                Command::SerialNumber => out.push(b'N'),
                Command::Timestamps(on) => {
                    out.push(b'Z');
                    out.push(if on { b'1' } else { b'0' });
                }
            },
            Line::Reply(reply) => match *reply {
                Reply::Ok => {}
                Reply::Error => {
                    out.push(BELL);
                    return out;
                }
                Reply::TransmitAck { extended } => out.push(if extended { b'Z' } else { b'z' }),
                Reply::Status(flags) => {
                    out.push(b'F');
                    out.push_hex(u32::from(flags), 2);
                }
                Reply::Version(tag) | Reply::SerialNumber(tag) => {
                    out.push(if matches!(reply, Reply::Version(_)) { b'V' } else { b'N' });
                    tag.0.iter().for_each(|&b| out.push(b));
                }
            },
        }
        out.push(CR);
        out
    }
}

/// Parses one line without its CR. An empty line is [`Reply::Ok`]; BELL is not a line (the
/// decoder handles it).
pub fn parse_line(line: &[u8]) -> Result<Line, SlcanError> {
    let Some((&first, rest)) = line.split_first() else {
        return Ok(Line::Reply(Reply::Ok));
    };
    let command = |command| Ok(Line::Command(command));
    match (first, rest.len()) {
        (b't', _) => parse_frame(rest, false, false),
        (b'T', _) => parse_frame(rest, true, false),
        (b'r', _) => parse_frame(rest, false, true),
        (b'R', _) => parse_frame(rest, true, true),
        (b'd' | b'D' | b'b' | b'B', _) => Err(SlcanError::FdFrame),
        (b'z', 0) => Ok(Line::Reply(Reply::TransmitAck { extended: false })),
        (b'Z', 0) => Ok(Line::Reply(Reply::TransmitAck { extended: true })),
        (b'Z', 1) => match rest {
            [b'0'] => command(Command::Timestamps(false)),
            [b'1'] => command(Command::Timestamps(true)),
            _ => Err(SlcanError::BadLength { what: "timestamp command", len: line.len() }),
        },
        (b'S', 1) => {
            let digit = rest.first().copied().unwrap_or_default();
            if !digit.is_ascii_digit() {
                return Err(SlcanError::InvalidHex("bit rate code"));
            }
            let code = digit - b'0';
            SlcanBitrate::from_code(code)
                .map(|rate| Line::Command(Command::SetBitrate(rate)))
                .ok_or(SlcanError::UnsupportedBitrateCode(code))
        }
        (b's', 4) => {
            let value = parse_hex(rest, "bit timing")?;
            command(Command::SetBitTiming { btr0: (value >> 8) as u8, btr1: value as u8 })
        }
        (b'O', 0) => command(Command::Open),
        (b'L', 0) => command(Command::ListenOnly),
        (b'C', 0) => command(Command::Close),
        (b'F', 0) => command(Command::Status),
        (b'F', 2) => Ok(Line::Reply(Reply::Status(parse_hex(rest, "status flags")? as u8))),
        (b'V', 0) => command(Command::Version),
        (b'N', 0) => command(Command::SerialNumber),
        (b'V' | b'N', 4) => {
            let mut chars = [0; 4];
            chars.copy_from_slice(rest);
            let tag = Tag::new(chars)?;
            Ok(Line::Reply(if first == b'V' { Reply::Version(tag) } else { Reply::SerialNumber(tag) }))
        }
        (b'z' | b'Z' | b'S' | b's' | b'O' | b'L' | b'C' | b'F' | b'V' | b'N', _) => {
            Err(SlcanError::BadLength { what: "command or reply", len: line.len() })
        }
        (other, _) => Err(SlcanError::UnknownCommand(other)),
    }
}

/// `rest` is the line after the frame letter: id, DLC digit, data, optional timestamp.
fn parse_frame(rest: &[u8], extended: bool, remote: bool) -> Result<Line, SlcanError> {
    let what = if remote { "remote frame" } else { "data frame" };
    let id_digits = if extended { EXTENDED_ID_DIGITS } else { STANDARD_ID_DIGITS };
    let bad_length = SlcanError::BadLength { what, len: rest.len() + 1 };
    let (id_text, rest) = rest.split_at_checked(id_digits).ok_or(bad_length)?;
    let id = parse_hex(id_text, "CAN id")?;
    let (&dlc_char, rest) = rest.split_first().ok_or(bad_length)?;
    if !(b'0'..=b'8').contains(&dlc_char) {
        return Err(SlcanError::InvalidDlc(dlc_char));
    }
    let dlc = dlc_char - b'0';
    let data_digits = if remote { 0 } else { 2 * usize::from(dlc) };
    let (data_text, timestamp_text) = rest.split_at_checked(data_digits).ok_or(bad_length)?;
    let timestamp = match timestamp_text.len() {
        0 => None,
        TIMESTAMP_DIGITS => Some(parse_hex(timestamp_text, "timestamp")? as u16),
        _ => return Err(bad_length),
    };
    let frame = if remote {
        SlcanFrame::remote(id, extended, dlc)?
    } else {
        let mut data = [0u8; MAX_DATA_BYTES];
        for (byte, pair) in data.iter_mut().zip(data_text.chunks_exact(2)) {
            *byte = parse_hex(pair, "data")? as u8;
        }
        SlcanFrame::data(id, extended, data.get(..usize::from(dlc)).unwrap_or_default())?
    };
    Ok(Line::Frame(frame.with_timestamp(timestamp)))
}

/// Upper- or lower-case hex of at most 8 digits.
fn parse_hex(digits: &[u8], what: &'static str) -> Result<u32, SlcanError> {
    digits.iter().try_fold(0u32, |value, &digit| {
        let nibble = char::from(digit).to_digit(16).ok_or(SlcanError::InvalidHex(what))?;
        Ok((value << 4) | nibble)
    })
}

/// Counts of a [`SlcanDecoder`] since it was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DecoderStats {
    /// Lines and BELLs decoded.
    pub lines: u64,
    /// Lines rejected: malformed, overlong, or cut short by a BELL.
    pub rejected: u64,
}

/// Streaming SLCAN decoder: feed it bytes as they come, in any pieces.
///
/// Every CR ends a line, which yields a [`Line`] or, if malformed, an error; every BELL yields
/// [`Reply::Error`] and discards a partial line before it (counted as rejected, not returned).
/// A line longer than [`MAX_LINE_BYTES`] is discarded up to its CR and yields
/// [`SlcanError::Overlong`] there, so the buffer is bounded and the next line decodes cleanly.
/// Line feeds are ignored, so a terminal's CR LF works. Any byte sequence is accepted.
#[derive(Clone)]
pub struct SlcanDecoder {
    line: [u8; MAX_LINE_BYTES],
    len: usize,
    /// The current line outgrew the buffer: skip to its CR.
    overlong: bool,
    stats: DecoderStats,
}

impl fmt::Debug for SlcanDecoder {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SlcanDecoder")
            .field("buffered", &self.len)
            .field("overlong", &self.overlong)
            .field("stats", &self.stats)
            .finish()
    }
}

impl Default for SlcanDecoder {
    fn default() -> Self {
        Self::new()
    }
}

impl SlcanDecoder {
    pub fn new() -> Self {
        SlcanDecoder { line: [0; MAX_LINE_BYTES], len: 0, overlong: false, stats: DecoderStats::default() }
    }

    /// Takes one byte; returns what it completed, if anything.
    pub fn push(&mut self, byte: u8) -> Option<Result<Line, SlcanError>> {
        match byte {
            CR => {
                let result = if self.overlong {
                    Err(SlcanError::Overlong)
                } else {
                    parse_line(self.line.get(..self.len).unwrap_or_default())
                };
                self.reset();
                self.stats.lines += 1;
                if result.is_err() {
                    self.stats.rejected += 1;
                }
                Some(result)
            }
            BELL => {
                if self.len > 0 || self.overlong {
                    self.stats.rejected += 1;
                }
                self.reset();
                self.stats.lines += 1;
                Some(Ok(Line::Reply(Reply::Error)))
            }
            b'\n' => None,
            _ => {
                match self.line.get_mut(self.len) {
                    Some(slot) if !self.overlong => {
                        *slot = byte;
                        self.len += 1;
                    }
                    _ => self.overlong = true,
                }
                None
            }
        }
    }

    /// Feeds `bytes`, calling `on_line` for each line completed.
    pub fn feed(&mut self, bytes: &[u8], mut on_line: impl FnMut(Result<Line, SlcanError>)) {
        for &byte in bytes {
            if let Some(line) = self.push(byte) {
                on_line(line);
            }
        }
    }

    /// Whether part of a line is waiting for its CR.
    pub fn is_mid_line(&self) -> bool {
        self.len > 0 || self.overlong
    }

    pub fn stats(&self) -> DecoderStats {
        self.stats
    }

    fn reset(&mut self) {
        self.len = 0;
        self.overlong = false;
    }
}
