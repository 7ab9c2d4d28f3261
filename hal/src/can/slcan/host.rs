//! [`SlcanBus`]: the host end of an SLCAN adapter, as a [`CanBus`].

use std::collections::VecDeque;
use std::fmt;
use std::io;
use std::time::{Duration, Instant};

use protocol::frame::FrameError;
use protocol::frame::can::{CanFrame, CanKind};

use super::codec::{Command, Line, MAX_DATA_BYTES, Reply, SlcanBitrate, SlcanDecoder, SlcanError, SlcanFrame};
use super::{SlcanPort, is_timeout};
use crate::can::CanBus;
use crate::link::{LinkError, deadline_after};

/// Serial baud when none is given. USB adapters (CANable, USBtin) ignore it; it matters for
/// adapters behind a real UART, and is python-can's default too.
pub const DEFAULT_SERIAL_BAUD: u32 = 115_200;
/// Default wait for the adapter's reply to a command. A USB adapter answers within a few
/// milliseconds; one second also covers an adapter still enumerating after being plugged in.
pub const DEFAULT_REPLY_TIMEOUT: Duration = Duration::from_secs(1);
/// Default bound on writing one line. A line is at most 31 bytes, under 3 ms at 115 200 baud;
/// a port that cannot take it for this long is stuck.
pub const DEFAULT_WRITE_TIMEOUT: Duration = Duration::from_secs(1);
/// Bytes read from the port at once.
const READ_CHUNK_BYTES: usize = 4096;
/// Reads `recv` still makes once its timeout has passed, as long as bytes are already there (as
/// in `SerialLink`): a frame already received is returned even with a zero timeout, while a line
/// streaming remote frames or garbage cannot hold `recv` past its timeout.
const LATE_READS: usize = 4;
/// Frames kept while waiting for a command's reply, for the next `recv`s.
const PENDING_FRAMES: usize = 1024;
/// How long dropping an open bus tries to close the channel.
const CLOSE_ON_DROP_TIMEOUT: Duration = Duration::from_millis(50);

/// How [`SlcanBus`] talks to its adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SlcanConfig {
    pub bitrate: SlcanBitrate,
    /// Wait for each reply of the open and close handshakes.
    pub reply_timeout: Duration,
    /// Bound on writing one line.
    pub write_timeout: Duration,
}

impl SlcanConfig {
    pub fn new(bitrate: SlcanBitrate) -> Self {
        SlcanConfig { bitrate, reply_timeout: DEFAULT_REPLY_TIMEOUT, write_timeout: DEFAULT_WRITE_TIMEOUT }
    }
}

/// Counters of an [`SlcanBus`] since it was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SlcanBusStats {
    pub frames_sent: u64,
    pub frames_received: u64,
    /// Lines the decoder rejected (malformed, overlong, CAN FD).
    pub rejected_lines: u64,
    /// Remote frames received: not data, skipped.
    pub remote_frames: u64,
    /// Frames received before the channel was opened by us (an adapter left open streams until
    /// our `C`), or after we closed it: skipped, not counted as dropped.
    pub stale_frames: u64,
    /// Frames lost because more arrived during a command than the bus keeps for `recv`.
    pub pending_overflow: u64,
    /// OK, `z` and `Z` replies to frames we sent.
    pub acks: u64,
    /// BELL replies to frames we sent: the adapter refused them (channel closed or listen-only,
    /// transmit buffer full, bus off).
    pub refused: u64,
    /// Well-formed lines with no place on this side (commands, status or version replies
    /// nobody asked for).
    pub unexpected: u64,
}

/// A [`CanBus`] over an SLCAN adapter on port `P` (classic CAN, standard and extended ids).
///
/// Opening closes the channel (`C`), sets the bit rate (`S0`–`S8`) and opens it (`O`), waiting
/// for each reply; frames still streaming from an earlier session are skipped. After that,
/// `send` writes one line without waiting for its reply, and `recv` returns data frames and
/// consumes the replies as they come. Every line sent is answered by exactly one reply (OK,
/// BELL, `z` or `Z`), which is how a later command finds its own reply among those of earlier
/// frames: an adapter that leaves lines unanswered makes the next command time out.
///
/// A port that fails (a pty whose other end closed: end of file or EIO; an unplugged adapter)
/// makes `send` and `recv` return [`LinkError::Io`] naming the port: reopen it.
pub struct SlcanBus<P: SlcanPort> {
    port: P,
    name: String,
    config: SlcanConfig,
    open: bool,
    decoder: SlcanDecoder,
    rx: Box<[u8]>,
    rx_start: usize,
    rx_end: usize,
    /// Lines sent whose reply has not arrived yet.
    awaiting_replies: u64,
    /// Frames received while waiting for a command's reply.
    pending: VecDeque<CanFrame>,
    stats: SlcanBusStats,
}

impl<P: SlcanPort> fmt::Debug for SlcanBus<P> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SlcanBus")
            .field("port", &self.name)
            .field("config", &self.config)
            .field("open", &self.open)
            .field("awaiting_replies", &self.awaiting_replies)
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

/// Bounds a wait that may go on reading a little past its deadline (see [`LATE_READS`]).
struct Wait {
    deadline: Instant,
    late_reads: usize,
}

impl Wait {
    fn new(timeout: Duration) -> Self {
        Wait { deadline: deadline_after(timeout), late_reads: 0 }
    }
}

impl<P: SlcanPort> SlcanBus<P> {
    /// Opens the channel at `bitrate` on the adapter behind `port`.
    pub fn connect(port: P, bitrate: SlcanBitrate) -> Result<Self, LinkError> {
        Self::connect_with(port, SlcanConfig::new(bitrate))
    }

    pub fn connect_with(mut port: P, config: SlcanConfig) -> Result<Self, LinkError> {
        let name = port.port_name();
        // Replies and frames from an earlier session would be taken for this one's.
        port.discard_input().map_err(LinkError::io(|| format!("discarding stale input of {name}")))?;
        let mut bus = SlcanBus {
            port,
            name,
            config,
            open: false,
            decoder: SlcanDecoder::new(),
            rx: vec![0; READ_CHUNK_BYTES].into_boxed_slice(),
            rx_start: 0,
            rx_end: 0,
            awaiting_replies: 0,
            pending: VecDeque::new(),
            stats: SlcanBusStats::default(),
        };
        bus.open_channel()?;
        Ok(bus)
    }

    /// (Re)opens the channel: `C`, `S<n>`, `O`, each waiting for its reply. The adapter may
    /// refuse `C` (a Lawicel adapter does when already closed); a refused `S` or `O` is a
    /// [`LinkError::Config`] error, a missing reply an [`LinkError::Io`] error of kind
    /// `TimedOut`.
    pub fn open_channel(&mut self) -> Result<(), LinkError> {
        self.open = false;
        self.pending.clear();
        self.command(Command::Close)?;
        if !self.command(Command::SetBitrate(self.config.bitrate))? {
            return Err(self.refused(Command::SetBitrate(self.config.bitrate)));
        }
        if !self.command(Command::Open)? {
            return Err(self.refused(Command::Open));
        }
        self.open = true;
        Ok(())
    }

    /// Closes the channel (`C`) and waits for the reply. Frames that arrived before it are
    /// still returned by `recv`.
    pub fn close_channel(&mut self) -> Result<(), LinkError> {
        self.command(Command::Close)?;
        self.open = false;
        Ok(())
    }

    pub fn is_open(&self) -> bool {
        self.open
    }

    pub fn config(&self) -> &SlcanConfig {
        &self.config
    }

    pub fn port_name(&self) -> &str {
        &self.name
    }

    pub fn port(&self) -> &P {
        &self.port
    }

    pub fn stats(&self) -> SlcanBusStats {
        SlcanBusStats { rejected_lines: self.decoder.stats().rejected, ..self.stats }
    }

    fn refused(&self, command: Command) -> LinkError {
        let text = command_text(command);
        LinkError::Config(format!("SLCAN adapter on {} refused `{text}` (bit rate {})", self.name, self.config.bitrate))
    }

    /// Sends `command` and waits for its reply: `Ok(true)` for OK, `Ok(false)` for BELL.
    fn command(&mut self, command: Command) -> Result<bool, LinkError> {
        self.write_line(Line::Command(command))?;
        let mut wait = Wait::new(self.config.reply_timeout);
        loop {
            let Some(line) = self.next_line(&mut wait)? else {
                return Err(LinkError::Io {
                    context: format!(
                        "no reply to `{}` from SLCAN adapter on {} within {:?} (is it an SLCAN adapter, at the \
                         right serial baud?)",
                        command_text(command),
                        self.name,
                        self.config.reply_timeout
                    ),
                    source: io::ErrorKind::TimedOut.into(),
                });
            };
            // Replies come in the order of the lines they answer: ours is the last outstanding.
            let ours = self.awaiting_replies <= 1;
            match line {
                Ok(Line::Reply(Reply::Ok)) if ours => {
                    self.awaiting_replies = 0;
                    return Ok(true);
                }
                Ok(Line::Reply(Reply::Error)) if ours => {
                    self.awaiting_replies = 0;
                    return Ok(false);
                }
                other => {
                    if let Some(frame) = self.absorb(other) {
                        if self.pending.len() < PENDING_FRAMES {
                            self.pending.push_back(frame);
                        } else {
                            self.stats.pending_overflow += 1;
                        }
                    }
                }
            }
        }
    }

    /// Takes one line that is not a command's awaited reply; returns it if it is a data frame
    /// for the caller.
    fn absorb(&mut self, line: Result<Line, SlcanError>) -> Option<CanFrame> {
        match line {
            Ok(Line::Frame(frame)) if frame.is_remote() => self.stats.remote_frames += 1,
            Ok(Line::Frame(frame)) if self.open => {
                if let Some(frame) = frame.to_can() {
                    self.stats.frames_received += 1;
                    return Some(frame);
                }
            }
            Ok(Line::Frame(_)) => self.stats.stale_frames += 1,
            Ok(Line::Reply(Reply::Ok | Reply::TransmitAck { .. })) => {
                self.awaiting_replies = self.awaiting_replies.saturating_sub(1);
                self.stats.acks += 1;
            }
            Ok(Line::Reply(Reply::Error)) => {
                self.awaiting_replies = self.awaiting_replies.saturating_sub(1);
                self.stats.refused += 1;
            }
            Ok(Line::Reply(_) | Line::Command(_)) => self.stats.unexpected += 1,
            // Counted by the decoder.
            Err(_) => {}
        }
        None
    }

    fn write_line(&mut self, line: Line) -> Result<(), LinkError> {
        let encoded = line.encode();
        let name = &self.name;
        self.port
            .set_io_timeout(self.config.write_timeout)
            .and_then(|()| self.port.write_all(encoded.as_bytes()))
            .and_then(|()| self.port.flush_writes())
            .map_err(LinkError::io(|| {
                format!("writing `{}` to SLCAN adapter on {name}", encoded.as_bytes().escape_ascii())
            }))?;
        self.awaiting_replies += 1;
        Ok(())
    }

    /// The next line, reading the port as needed until `wait` ends; `None` then.
    fn next_line(&mut self, wait: &mut Wait) -> Result<Option<Result<Line, SlcanError>>, LinkError> {
        loop {
            while let Some(&byte) = self.rx.get(self.rx_start).filter(|_| self.rx_start < self.rx_end) {
                self.rx_start += 1;
                if let Some(line) = self.decoder.push(byte) {
                    return Ok(Some(line));
                }
            }
            let left = wait.deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                wait.late_reads += 1;
                if wait.late_reads > LATE_READS {
                    return Ok(None);
                }
            }
            if !self.fill(left)? && Instant::now() >= wait.deadline {
                return Ok(None);
            }
        }
    }

    /// Reads what the port has within `timeout`; `false` if nothing came.
    fn fill(&mut self, timeout: Duration) -> Result<bool, LinkError> {
        let name = &self.name;
        self.port.set_io_timeout(timeout).map_err(LinkError::io(|| format!("setting the timeout of {name}")))?;
        match self.port.read(&mut self.rx) {
            Ok(0) => Err(LinkError::Io {
                context: format!("SLCAN adapter port {name} closed (end of file); reopen it"),
                source: io::ErrorKind::UnexpectedEof.into(),
            }),
            Ok(len) => {
                self.rx_start = 0;
                self.rx_end = len.min(self.rx.len());
                Ok(true)
            }
            Err(error) if is_timeout(&error) => Ok(false),
            Err(source) => Err(LinkError::Io {
                context: format!("reading from SLCAN adapter on {name} (port gone? reopen it)"),
                source,
            }),
        }
    }
}

impl SlcanBus<Box<dyn serialport::SerialPort>> {
    /// Opens the adapter at serial device `path` (`serial_baud`, 8N1, no flow control; USB
    /// adapters ignore the baud) and its channel at `can_bitrate` bit/s, one of the `S0`–`S8`
    /// rates.
    pub fn open(path: &str, serial_baud: u32, can_bitrate: u32) -> Result<Self, LinkError> {
        let bitrate = SlcanBitrate::from_bits_per_second(can_bitrate).ok_or_else(|| {
            let rates: Vec<String> = SlcanBitrate::ALL.iter().map(|rate| rate.bits_per_second().to_string()).collect();
            LinkError::Config(format!(
                "SLCAN cannot run CAN at {can_bitrate} bit/s; its rates are {}",
                rates.join(", ")
            ))
        })?;
        let port = crate::serial::open_port(path, serial_baud, DEFAULT_WRITE_TIMEOUT).map_err(|source| {
            LinkError::Io { context: format!("opening SLCAN adapter {path} at {serial_baud} baud"), source }
        })?;
        Self::connect(port, bitrate)
    }
}

impl<P: SlcanPort> CanBus for SlcanBus<P> {
    /// Writes the frame's line; the adapter's reply is consumed by a later `recv` (a BELL is
    /// counted in [`SlcanBusStats::refused`]).
    fn send(&mut self, frame: &CanFrame) -> Result<(), LinkError> {
        let len = usize::from(frame.len);
        if len > MAX_DATA_BYTES {
            return Err(LinkError::CanFrameTooLong { len, max: MAX_DATA_BYTES });
        }
        if !self.open {
            return Err(LinkError::Closed(format!(
                "SLCAN channel on {} is closed (open_channel reopens it)",
                self.name
            )));
        }
        let line = SlcanFrame::from_can(frame).map_err(|error| match error {
            SlcanError::DataTooLong(len) => LinkError::CanFrameTooLong { len, max: MAX_DATA_BYTES },
            _ => FrameError::InvalidCanId(frame.id).into(),
        })?;
        self.write_line(Line::Frame(line))?;
        self.stats.frames_sent += 1;
        Ok(())
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, LinkError> {
        if let Some(frame) = self.pending.pop_front() {
            return Ok(Some(frame));
        }
        let mut wait = Wait::new(timeout);
        while let Some(line) = self.next_line(&mut wait)? {
            if let Some(frame) = self.absorb(line) {
                return Ok(Some(frame));
            }
        }
        Ok(None)
    }

    fn kind(&self) -> CanKind {
        CanKind::Classic
    }

    /// Rejected lines, remote frames and frames lost while waiting for a reply.
    fn dropped_frames(&self) -> u64 {
        let stats = self.stats();
        stats.rejected_lines.saturating_add(stats.remote_frames).saturating_add(stats.pending_overflow)
    }
}

impl<P: SlcanPort> Drop for SlcanBus<P> {
    /// Closes the channel, best effort and without waiting for the reply: an adapter left open
    /// goes on streaming every bus frame into a port nobody reads.
    fn drop(&mut self) {
        if self.open {
            self.config.write_timeout = CLOSE_ON_DROP_TIMEOUT;
            let _ = self.write_line(Line::Command(Command::Close));
        }
    }
}

/// A command as written, without its CR, for messages.
fn command_text(command: Command) -> String {
    let encoded = Line::Command(command).encode();
    let bytes = encoded.as_bytes();
    String::from_utf8_lossy(bytes.strip_suffix(b"\r").unwrap_or(bytes)).into_owned()
}
