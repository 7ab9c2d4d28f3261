//! [`SerialLink`]: packets over a byte stream (serial radio, UART, pty) as COBS frames with a
//! CRC-32 (see `protocol::frame::stream`).
//!
//! Every frame starts with a delimiter as well as ending with one (part of the stream framing):
//! noise on an idle line, or a frame cut short by a failed write, cannot merge with the next
//! frame and lose it too.

use std::fmt;
use std::io::{ErrorKind, Read, Write};
use std::time::{Duration, Instant};

use protocol::frame::Framing;
use protocol::frame::stream::{CRC_BYTES, DELIMITER, StreamDecoder, encode_frame, max_frame_len};

use crate::link::{
    Link, LinkCounters, LinkError, MAX_LINK_PACKET_BYTES, bump, check_packet_len, deadline_after, deliver,
};

/// Default bound on writing one frame. A 1 KiB frame takes 0.2 s at 57 600 baud once the OS
/// buffer is full; a port stuck longer than this is reported rather than waited on.
pub const DEFAULT_WRITE_TIMEOUT: Duration = Duration::from_secs(2);
/// Bytes read from the port at once.
const READ_CHUNK_BYTES: usize = 4096;
/// Reads `recv` still makes once its timeout has passed, as long as bytes are already there: a
/// frame that has fully arrived is returned even with a zero timeout, while a line streaming
/// garbage cannot hold `recv` past its timeout by more than this many reads.
const LATE_READS: usize = 4;
/// Decoded frame bound: the largest packet and its CRC.
const DECODER_BYTES: usize = MAX_LINK_PACKET_BYTES + CRC_BYTES;

/// Sets the port's timeout for the next read or write.
pub type SetTimeout<P> = fn(&mut P, Duration) -> std::io::Result<()>;

/// A [`Link`] over any byte stream `P`.
///
/// # Timeout contract
///
/// Built with [`SerialLink::from_serialport`] or [`SerialLink::open`], the link sets the port's
/// own timeout before every read (to what is left of `recv`'s timeout) and every write (to the
/// write timeout), so `recv` returns `Ok(None)` on time.
///
/// Built with [`SerialLink::new`] from any other `P`, the link cannot set a timeout, so `P`
/// must bound its reads itself: a read must return within a short time, with data or with an
/// error of kind `TimedOut` or `WouldBlock` (a non-blocking or timed port). `recv` then returns
/// at most one such read period after its timeout. A read that blocks indefinitely blocks
/// `recv` with it. A read of 0 bytes means end of stream and makes `recv` fail with
/// [`LinkError::Closed`]. Writes are flushed after every frame, so a buffered `P` works.
/// [`SerialLink::with_timeout_control`] supplies the timeout setter for other port types.
pub struct SerialLink<P> {
    port: P,
    /// Names the port in errors.
    name: String,
    set_timeout: Option<SetTimeout<P>>,
    /// A serialport's flush waits until every byte has left the UART (tcdrain), which costs the
    /// frame's transmission time per frame: skipped for ports that do not buffer in user space.
    flush_after_write: bool,
    write_timeout: Duration,
    decoder: Box<StreamDecoder<DECODER_BYTES>>,
    encode_buf: Box<[u8]>,
    /// Bytes read but not yet fed to the decoder: `rx[rx_start..rx_end]`. A read may bring
    /// several frames and `recv` returns one packet, so the rest waits here.
    rx: Box<[u8]>,
    rx_start: usize,
    rx_end: usize,
    counters: LinkCounters,
}

impl<P> fmt::Debug for SerialLink<P> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SerialLink")
            .field("port", &self.name)
            .field("timeout_control", &self.set_timeout.is_some())
            .field("write_timeout", &self.write_timeout)
            .field("buffered_bytes", &(self.rx_end - self.rx_start))
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

impl<P: Read + Write + Send> SerialLink<P> {
    /// A link over `port`, which must honour the timeout contract in the type's documentation.
    pub fn new(port: P) -> Self {
        Self::build(port, "byte stream".to_string(), None, true)
    }

    /// A link over `port`, setting its timeouts with `set_timeout`.
    pub fn with_timeout_control(port: P, set_timeout: SetTimeout<P>) -> Self {
        Self::build(port, "byte stream".to_string(), Some(set_timeout), true)
    }

    fn build(port: P, name: String, set_timeout: Option<SetTimeout<P>>, flush_after_write: bool) -> Self {
        SerialLink {
            port,
            name,
            set_timeout,
            flush_after_write,
            write_timeout: DEFAULT_WRITE_TIMEOUT,
            decoder: Box::new(StreamDecoder::new()),
            // Leading delimiter, then the frame with its own.
            encode_buf: vec![0; max_frame_len(MAX_LINK_PACKET_BYTES)].into_boxed_slice(),
            rx: vec![0; READ_CHUNK_BYTES].into_boxed_slice(),
            rx_start: 0,
            rx_end: 0,
            counters: LinkCounters::default(),
        }
    }

    /// Bounds the time spent writing one frame (only with timeout control).
    pub fn set_write_timeout(&mut self, timeout: Duration) {
        self.write_timeout = timeout;
    }

    /// Names the port in error messages (a device path, "radio 2").
    pub fn set_name(&mut self, name: impl Into<String>) {
        self.name = name.into();
    }

    pub fn port(&self) -> &P {
        &self.port
    }

    pub fn port_mut(&mut self) -> &mut P {
        &mut self.port
    }

    pub fn into_port(self) -> P {
        self.port
    }

    fn apply_timeout(&mut self, timeout: Duration) -> Result<(), LinkError> {
        if let Some(set_timeout) = self.set_timeout {
            set_timeout(&mut self.port, timeout)
                .map_err(LinkError::io(|| format!("setting the timeout of {}", self.name)))?;
        }
        Ok(())
    }

    /// Feeds buffered bytes to the decoder up to the end of the next frame that yields a packet,
    /// and delivers it. Feeding one delimiter-ended chunk at a time yields at most one packet
    /// per call, and the bytes after it stay buffered for the next `recv`.
    fn decode_buffered(&mut self, buf: &mut [u8]) -> Option<Result<usize, LinkError>> {
        while self.rx_start < self.rx_end {
            let pending = self.rx.get(self.rx_start..self.rx_end).unwrap_or_default();
            let chunk_len = pending.iter().position(|&b| b == DELIMITER).map_or(pending.len(), |i| i + 1);
            let chunk = pending.get(..chunk_len).unwrap_or_default();
            self.rx_start += chunk_len;
            let mut delivered = None;
            let counters = &mut self.counters;
            self.decoder.feed(chunk, |frame| {
                bump(&mut counters.frames_received, 1);
                match frame {
                    Ok(packet) => delivered = Some(deliver(packet, buf, counters)),
                    Err(error) => counters.rejected.count(error),
                }
            });
            if delivered.is_some() {
                return delivered;
            }
        }
        self.rx_start = 0;
        self.rx_end = 0;
        None
    }
}

impl<P: serialport::SerialPort> SerialLink<P> {
    /// A link over a serialport port, controlling its timeout (see the type's documentation).
    pub fn from_serialport(port: P) -> Self {
        let name = port.name().unwrap_or_else(|| "serial port".to_string());
        Self::build(port, name, Some(|port: &mut P, timeout| Ok(port.set_timeout(timeout)?)), false)
    }
}

/// Opens the serial device at `path`, 8 data bits, no parity, one stop bit, no flow control,
/// writes bounded by `write_timeout`: every serial device of the rover (radio, IMU, SLCAN
/// adapter) is opened here.
pub fn open_port(
    path: &str,
    baud_rate: u32,
    write_timeout: Duration,
) -> std::io::Result<Box<dyn serialport::SerialPort>> {
    Ok(serialport::new(path, baud_rate).timeout(write_timeout).open()?)
}

impl SerialLink<Box<dyn serialport::SerialPort>> {
    /// Opens the serial device at `path` (8 data bits, no parity, one stop bit, no flow
    /// control: what serial radios expect).
    pub fn open(path: &str, baud_rate: u32) -> Result<Self, LinkError> {
        let port = open_port(path, baud_rate, DEFAULT_WRITE_TIMEOUT).map_err(|source| LinkError::Io {
            context: format!("opening serial port {path} at {baud_rate} baud"),
            source,
        })?;
        let set_timeout: SetTimeout<Box<dyn serialport::SerialPort>> = |port, timeout| Ok(port.set_timeout(timeout)?);
        Ok(Self::build(port, path.to_string(), Some(set_timeout), false))
    }
}

impl<P: Read + Write + Send> Link for SerialLink<P> {
    fn send(&mut self, packet: &[u8]) -> Result<(), LinkError> {
        check_packet_len(packet)?;
        let frame_len = encode_frame(packet, &mut self.encode_buf)?;
        self.apply_timeout(self.write_timeout)?;
        let wire = self.encode_buf.get(..frame_len).unwrap_or_default();
        let write =
            self.port.write_all(wire).and_then(|()| if self.flush_after_write { self.port.flush() } else { Ok(()) });
        if let Err(source) = write {
            if source.kind() == ErrorKind::BrokenPipe {
                return Err(LinkError::Closed(format!("{} hung up", self.name)));
            }
            return Err(LinkError::Io {
                context: format!("writing a {frame_len}-byte frame to {}", self.name),
                source,
            });
        }
        bump(&mut self.counters.frames_sent, 1);
        bump(&mut self.counters.packets_sent, 1);
        bump(&mut self.counters.packet_bytes_sent, packet.len());
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<Option<usize>, LinkError> {
        let deadline = deadline_after(timeout);
        let mut late_reads = 0usize;
        loop {
            if let Some(result) = self.decode_buffered(buf) {
                return result.map(Some);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                late_reads += 1;
                if late_reads > LATE_READS {
                    return Ok(None);
                }
            }
            // A zero port timeout may mean "wait forever" to some drivers.
            self.apply_timeout(left.max(Duration::from_millis(1)))?;
            match self.port.read(&mut self.rx) {
                Ok(0) => return Err(LinkError::Closed(format!("{} reached end of stream", self.name))),
                Ok(len) => {
                    self.rx_start = 0;
                    self.rx_end = len.min(self.rx.len());
                }
                Err(error)
                    if matches!(error.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted) =>
                {
                    if Instant::now() >= deadline {
                        return Ok(None);
                    }
                }
                Err(error) if error.kind() == ErrorKind::BrokenPipe => {
                    return Err(LinkError::Closed(format!("{} hung up", self.name)));
                }
                Err(source) => return Err(LinkError::Io { context: format!("reading from {}", self.name), source }),
            }
        }
    }

    fn framing(&self) -> Framing {
        Framing::Stream
    }

    fn counters(&self) -> LinkCounters {
        self.counters
    }
}
