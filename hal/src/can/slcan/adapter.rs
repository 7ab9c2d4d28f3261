//! [`SlcanAdapter`]: the adapter end of SLCAN, bridging a serial port to a [`CanBus`].

use std::fmt;
use std::io;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::codec::{
    Command, Line, MAX_DATA_BYTES, Reply, STATUS_DATA_OVERRUN, SlcanBitrate, SlcanDecoder, SlcanError, SlcanFrame, Tag,
};
use super::{SlcanPort, is_timeout};
use crate::can::CanBus;
use crate::link::LinkError;

/// `V` reply: hardware 01, software 01 (python-can's `get_version` reads `(1, 1)`).
pub const DEFAULT_VERSION: Tag = Tag::from_static(*b"0101");
/// `N` reply.
pub const DEFAULT_SERIAL_NUMBER: Tag = Tag::from_static(*b"HAL1");
/// One `run_until` pass waits this long for the host: a USB full-speed adapter is polled once
/// per 1 ms frame, so a bus frame reaches the host no later than through a real adapter.
const POLL_SLICE: Duration = Duration::from_millis(1);
/// Bus frames forwarded in one pass before the host gets its turn.
const FORWARD_BATCH: usize = 256;
/// Output waiting for a host that does not read; past this, bus frames are dropped (counted),
/// as a real adapter's USB buffer overflows. Only ports whose writes time out fill it (see
/// [`SlcanAdapter::poll`]).
const OUT_LIMIT_BYTES: usize = 64 * 1024;
/// Output bound for replies, so memory stays bounded even for a host that never reads.
const REPLY_LIMIT_BYTES: usize = 4 * OUT_LIMIT_BYTES;
/// Bound on one write attempt; what the host did not take waits for the next pass.
const WRITE_TIMEOUT: Duration = Duration::from_millis(10);
/// Bytes read from the host at once.
const READ_CHUNK_BYTES: usize = 4096;
/// Lawicel timestamps count milliseconds and wrap at one minute.
const TIMESTAMP_WRAP_MS: u128 = 60_000;

/// The adapter's CAN channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ChannelState {
    Closed,
    Open,
    /// Opened with `L`: frames reach the host, the host may not transmit.
    ListenOnly,
}

/// What one [`SlcanAdapter::poll`] did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AdapterActivity {
    /// Lines (commands and frames) received from the host.
    pub host_lines: usize,
    /// Host frames put on the bus.
    pub frames_to_bus: usize,
    /// Bus frames written to the host.
    pub frames_to_host: usize,
    /// Bus frames discarded (channel closed, longer than 8 bytes, host not reading).
    pub discarded: usize,
}

impl AdapterActivity {
    pub fn is_idle(&self) -> bool {
        *self == AdapterActivity::default()
    }

    fn add(&mut self, other: AdapterActivity) {
        self.host_lines += other.host_lines;
        self.frames_to_bus += other.frames_to_bus;
        self.frames_to_host += other.frames_to_host;
        self.discarded += other.discarded;
    }
}

/// Counters of an [`SlcanAdapter`] since it was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AdapterStats {
    /// Lines received from the host, frames included.
    pub host_lines: u64,
    /// BELLs answered: commands refused or not understood.
    pub refused: u64,
    /// Lines the decoder rejected (malformed, overlong, CAN FD); each was answered with BELL.
    pub rejected_lines: u64,
    pub frames_to_bus: u64,
    pub frames_to_host: u64,
    /// Bus frames that arrived while the channel was closed.
    pub discarded_closed: u64,
    /// Bus frames longer than SLCAN's 8 bytes (from an FD bus).
    pub discarded_too_long: u64,
    /// Bus frames (and, past a larger bound, replies) dropped because the host stopped reading.
    pub discarded_overflow: u64,
    /// Host frames the bus refused (answered with BELL).
    pub bus_send_errors: u64,
}

/// Emulates a USB-CAN adapter speaking SLCAN on port `P`, its CAN side being bus `B`.
///
/// It answers like a CANable: every line gets exactly one reply, OK (`\r`) or BELL (`\x07`),
/// with `Vhhss\r`, `Nxxxx\r` and `Fxx\r` for the queries. Frames sent while open are
/// acknowledged with OK, or with Lawicel's `z\r` / `Z\r` after
/// [`set_lawicel_acks`](Self::set_lawicel_acks). Following Lawicel, `S`, `s` and `Z0/Z1` are
/// refused while open, `F` and frames while closed (frames also while listen-only). As on a
/// CANable, `C` is always accepted (python-can starts with it), `O` while open too (python-can
/// sends it twice), and an empty line is a no-op; only switching between `O` and `L` without
/// `C` is refused.
/// Remote frames from the host are refused: a [`CanBus`] carries data frames only.
///
/// Bus frames go to the host only while the channel is open, with a timestamp after `Z1`; a
/// closed adapter discards them (counted in [`AdapterStats::discarded_closed`]).
pub struct SlcanAdapter<P: SlcanPort, B: CanBus> {
    port: P,
    bus: B,
    name: String,
    decoder: SlcanDecoder,
    state: ChannelState,
    /// `None` until `S` is given, or after `s` (custom bit timing).
    bitrate: Option<SlcanBitrate>,
    timestamps: bool,
    lawicel_acks: bool,
    version: Tag,
    serial_number: Tag,
    /// Origin of the timestamps.
    epoch: Instant,
    /// Replies and frames not yet taken by the host.
    out: Vec<u8>,
    rx: Box<[u8]>,
    /// Frames were lost since the host last read the status flags.
    overrun: bool,
    /// The bus's own drop count when last looked at.
    bus_dropped_seen: u64,
    stats: AdapterStats,
}

impl<P: SlcanPort, B: CanBus> fmt::Debug for SlcanAdapter<P, B> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SlcanAdapter")
            .field("port", &self.name)
            .field("state", &self.state)
            .field("bitrate", &self.bitrate)
            .field("timestamps", &self.timestamps)
            .field("pending_output_bytes", &self.out.len())
            .field("stats", &self.stats())
            .finish_non_exhaustive()
    }
}

impl<P: SlcanPort, B: CanBus> SlcanAdapter<P, B> {
    /// An adapter with its channel closed and no bit rate set, as after power-up.
    pub fn new(port: P, bus: B) -> Self {
        let name = port.port_name();
        SlcanAdapter {
            port,
            bus,
            name,
            decoder: SlcanDecoder::new(),
            state: ChannelState::Closed,
            bitrate: None,
            timestamps: false,
            lawicel_acks: false,
            version: DEFAULT_VERSION,
            serial_number: DEFAULT_SERIAL_NUMBER,
            epoch: Instant::now(),
            out: Vec::new(),
            rx: vec![0; READ_CHUNK_BYTES].into_boxed_slice(),
            overrun: false,
            bus_dropped_seen: 0,
            stats: AdapterStats::default(),
        }
    }

    /// Acknowledges transmitted frames with `z\r` / `Z\r` (Lawicel, USBtin) instead of OK.
    pub fn set_lawicel_acks(&mut self, on: bool) {
        self.lawicel_acks = on;
    }

    pub fn set_version(&mut self, version: Tag) {
        self.version = version;
    }

    pub fn set_serial_number(&mut self, serial_number: Tag) {
        self.serial_number = serial_number;
    }

    pub fn state(&self) -> ChannelState {
        self.state
    }

    /// The bit rate the host set with `S`, if any.
    pub fn bitrate(&self) -> Option<SlcanBitrate> {
        self.bitrate
    }

    pub fn timestamps(&self) -> bool {
        self.timestamps
    }

    pub fn stats(&self) -> AdapterStats {
        AdapterStats { rejected_lines: self.decoder.stats().rejected, ..self.stats }
    }

    pub fn bus(&self) -> &B {
        &self.bus
    }

    pub fn bus_mut(&mut self) -> &mut B {
        &mut self.bus
    }

    pub fn port(&self) -> &P {
        &self.port
    }

    pub fn into_parts(self) -> (P, B) {
        (self.port, self.bus)
    }

    /// One service pass: forwards the bus frames waiting, waits at most `timeout` for bytes
    /// from the host and answers every line they complete, forwards the bus frames that came
    /// meanwhile. Fails only when the port or the bus does (a closed pty: [`LinkError::Io`]).
    ///
    /// A pass takes longer than `timeout` when the host does not read: a tty (a pty included)
    /// blocks a write while the host's input buffer is full, until the host reads. Bus frames
    /// then wait in `B`'s queue, and what overflows it is lost there, counted by
    /// `B::dropped_frames` and reported to the host as data overrun in the `F` flags. Ports
    /// whose writes time out instead (a socket in a [`TimedPort`](super::TimedPort)) keep the
    /// pass short and drop bus frames here, in [`AdapterStats::discarded_overflow`].
    pub fn poll(&mut self, timeout: Duration) -> Result<AdapterActivity, LinkError> {
        let mut activity = self.forward_bus()?;
        self.write_out()?;
        activity.add(self.serve_host(timeout)?);
        activity.add(self.forward_bus()?);
        self.write_out()?;
        Ok(activity)
    }

    /// Polls until `stop` is set (for a thread of its own); returns early with the error of a
    /// failed port or bus.
    pub fn run_until(&mut self, stop: &AtomicBool) -> Result<(), LinkError> {
        while !stop.load(Ordering::Acquire) {
            self.poll(POLL_SLICE)?;
        }
        Ok(())
    }

    fn serve_host(&mut self, timeout: Duration) -> Result<AdapterActivity, LinkError> {
        let mut activity = AdapterActivity::default();
        let name = &self.name;
        self.port.set_io_timeout(timeout).map_err(LinkError::io(|| format!("setting the timeout of {name}")))?;
        let len = match self.port.read(&mut self.rx) {
            Ok(0) => {
                return Err(LinkError::Io {
                    context: format!("SLCAN host on {name} closed the port (end of file)"),
                    source: io::ErrorKind::UnexpectedEof.into(),
                });
            }
            Ok(len) => len.min(self.rx.len()),
            Err(error) if is_timeout(&error) => 0,
            Err(source) => {
                return Err(LinkError::Io { context: format!("reading SLCAN commands from {name}"), source });
            }
        };
        for index in 0..len {
            let byte = self.rx.get(index).copied().unwrap_or_default();
            if let Some(line) = self.decoder.push(byte) {
                activity.host_lines += 1;
                self.stats.host_lines += 1;
                if self.handle(line) {
                    activity.frames_to_bus += 1;
                }
            }
        }
        Ok(activity)
    }

    /// Answers one line from the host; `true` if it put a frame on the bus.
    fn handle(&mut self, line: Result<Line, SlcanError>) -> bool {
        let closed = self.state == ChannelState::Closed;
        let reply = match line {
            Ok(Line::Frame(frame)) => return self.transmit(&frame),
            Ok(Line::Reply(Reply::Ok)) => Reply::Ok,
            Ok(Line::Command(command)) => match command {
                Command::SetBitrate(rate) if closed => {
                    self.bitrate = Some(rate);
                    Reply::Ok
                }
                Command::SetBitTiming { .. } if closed => {
                    self.bitrate = None;
                    Reply::Ok
                }
                Command::Timestamps(on) if closed => {
                    self.timestamps = on;
                    Reply::Ok
                }
                Command::Open | Command::ListenOnly => {
                    let wanted = if command == Command::Open { ChannelState::Open } else { ChannelState::ListenOnly };
                    if closed {
                        // What reached the bus before the channel opened is not the host's.
                        self.discard_backlog();
                        self.state = wanted;
                        Reply::Ok
                    } else if self.state == wanted {
                        // python-can opens twice (at the end of set_bitrate and again in its
                        // constructor); a CANable accepts that, so must we.
                        Reply::Ok
                    } else {
                        Reply::Error
                    }
                }
                Command::Close => {
                    self.state = ChannelState::Closed;
                    Reply::Ok
                }
                Command::Status if !closed => {
                    self.note_bus_drops();
                    let flags = if self.overrun { STATUS_DATA_OVERRUN } else { 0 };
                    self.overrun = false;
                    Reply::Status(flags)
                }
                Command::Version => Reply::Version(self.version),
                Command::SerialNumber => Reply::SerialNumber(self.serial_number),
                _ => Reply::Error,
            },
            // A BELL or a reply from the host, or a line the decoder refused.
            Ok(Line::Reply(_)) | Err(_) => Reply::Error,
        };
        self.reply(reply);
        false
    }

    fn transmit(&mut self, frame: &SlcanFrame) -> bool {
        let can = frame.to_can().filter(|_| self.state == ChannelState::Open);
        let sent = can.is_some_and(|can| match self.bus.send(&can) {
            Ok(()) => true,
            Err(_) => {
                self.stats.bus_send_errors += 1;
                false
            }
        });
        if sent {
            self.stats.frames_to_bus += 1;
            let ack = if self.lawicel_acks { Reply::TransmitAck { extended: frame.is_extended() } } else { Reply::Ok };
            self.reply(ack);
        } else {
            self.reply(Reply::Error);
        }
        sent
    }

    fn reply(&mut self, reply: Reply) {
        if reply == Reply::Error {
            self.stats.refused += 1;
        }
        // Replies are not dropped at OUT_LIMIT_BYTES like bus frames: a host counts on one
        // reply per line. Only a host that writes and never reads reaches this bound.
        if self.out.len() >= REPLY_LIMIT_BYTES {
            self.stats.discarded_overflow += 1;
            return;
        }
        self.out.extend_from_slice(Line::Reply(reply).encode().as_bytes());
    }

    /// Takes the frames waiting on the bus, writing them for the host if the channel is open.
    fn forward_bus(&mut self) -> Result<AdapterActivity, LinkError> {
        let mut activity = AdapterActivity::default();
        for _ in 0..FORWARD_BATCH {
            let Some(frame) = self.bus.recv(Duration::ZERO)? else {
                break;
            };
            if self.state == ChannelState::Closed {
                self.stats.discarded_closed += 1;
                activity.discarded += 1;
                continue;
            }
            if usize::from(frame.len) > MAX_DATA_BYTES {
                self.stats.discarded_too_long += 1;
                activity.discarded += 1;
                continue;
            }
            if self.out.len() >= OUT_LIMIT_BYTES {
                self.stats.discarded_overflow += 1;
                self.overrun = true;
                activity.discarded += 1;
                continue;
            }
            let Ok(line) = SlcanFrame::from_can(&frame) else {
                // An id out of range: no bus we have delivers one, and no line could carry it.
                self.stats.discarded_too_long += 1;
                activity.discarded += 1;
                continue;
            };
            let timestamp = self.timestamps.then(|| (self.epoch.elapsed().as_millis() % TIMESTAMP_WRAP_MS) as u16);
            self.out.extend_from_slice(Line::Frame(line.with_timestamp(timestamp)).encode().as_bytes());
            self.stats.frames_to_host += 1;
            activity.frames_to_host += 1;
        }
        Ok(activity)
    }

    /// Discards every frame waiting on the bus (the channel is about to open).
    fn discard_backlog(&mut self) {
        while let Ok(Some(_)) = self.bus.recv(Duration::ZERO) {
            self.stats.discarded_closed += 1;
        }
    }

    fn note_bus_drops(&mut self) {
        let dropped = self.bus.dropped_frames();
        if dropped > self.bus_dropped_seen {
            self.overrun = true;
        }
        self.bus_dropped_seen = dropped;
    }

    /// Writes what the host takes; what is left when a write times out waits for the next pass.
    fn write_out(&mut self) -> Result<(), LinkError> {
        if self.out.is_empty() {
            return Ok(());
        }
        let name = &self.name;
        self.port.set_io_timeout(WRITE_TIMEOUT).map_err(LinkError::io(|| format!("setting the timeout of {name}")))?;
        let mut written = 0;
        let result = loop {
            let Some(rest) = self.out.get(written..).filter(|rest| !rest.is_empty()) else {
                break self.port.flush_writes();
            };
            match self.port.write(rest) {
                Ok(0) => break Err(io::ErrorKind::WriteZero.into()),
                Ok(len) => written += len,
                Err(error) if is_timeout(&error) => break Ok(()),
                Err(error) => break Err(error),
            }
        };
        self.out.drain(..written.min(self.out.len()));
        result
            .map_err(|source| LinkError::Io { context: format!("writing SLCAN replies and frames to {name}"), source })
    }
}
