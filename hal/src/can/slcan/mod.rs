//! SLCAN, the Lawicel ASCII protocol of USB-CAN adapters (CANable, USBtin, CANtact, Lawicel
//! CANUSB), from both ends of the serial line:
//!
//! - [`SlcanBus`], the host: a [`CanBus`](super::CanBus) over an adapter's serial port, so a
//!   [`CanLink`](super::CanLink) or a device driver runs over a USB-CAN adapter where the
//!   computer has no SocketCAN (or the kernel no `slcan` driver).
//! - [`SlcanAdapter`], the adapter: emulates one on a serial port (a pty in the HIL harness),
//!   bridging the host's frames to and from any `CanBus`, so host software, ours or python-can,
//!   can be tested against simulated devices on a [`LoopbackCanBus`](super::LoopbackCanBus).
//!
//! # Wire format
//!
//! ```text
//! tIIIL[DD..][TTTT]\r        data frame, 11-bit id, L = 0..8 data bytes, optional timestamp (ms)
//! TIIIIIIIIL[DD..][TTTT]\r   data frame, 29-bit id
//! rIIIL[TTTT]\r  RIIIIIIIIL[TTTT]\r   remote frames (no data)
//! S0..S8\r  O\r  L\r  C\r  F\r  V\r  N\r  Z0\r  Z1\r  sXXYY\r     host commands
//! \r (OK)   \x07 (BELL: error)   z\r / Z\r (Lawicel transmit ack)   Fxx\r  Vhhss\r  Nxxxx\r
//! ```
//!
//! `S0`–`S8` are 10k, 20k, 50k, 100k, 125k, 250k, 500k, 750k and 1M bit/s. Hex digits are
//! written upper case and read in either case. CAN FD lines (`d`, `D`, `b`, `B`) are rejected:
//! this module carries classic CAN only.

mod adapter;
mod codec;
mod host;

use std::io::{self, Read, Write};
use std::time::Duration;

pub use adapter::{AdapterActivity, AdapterStats, ChannelState, DEFAULT_SERIAL_NUMBER, DEFAULT_VERSION, SlcanAdapter};
pub use codec::{
    BELL, CR, Command, DecoderStats, EncodedLine, Line, MAX_DATA_BYTES, MAX_LINE_BYTES, Reply, STATUS_DATA_OVERRUN,
    SlcanBitrate, SlcanDecoder, SlcanError, SlcanFrame, Tag, parse_line,
};
pub use host::{DEFAULT_SERIAL_BAUD, SlcanBus, SlcanBusStats, SlcanConfig};

/// A byte port SLCAN runs over: a serial port, a pty, or any stream wrapped in [`TimedPort`].
pub trait SlcanPort: Read + Write + Send {
    /// Bounds every following read and write: each returns within `timeout`, with data or an
    /// error of kind `TimedOut` or `WouldBlock`. A zero `timeout` asks for what is already there.
    fn set_io_timeout(&mut self, timeout: Duration) -> io::Result<()>;

    /// Names the port in error messages.
    fn port_name(&self) -> String;

    /// Discards bytes received and not read yet. Ports that cannot, do nothing.
    fn discard_input(&mut self) -> io::Result<()> {
        Ok(())
    }

    /// Pushes out what `write` buffered in user space. Serial ports write straight to the
    /// driver, and their `flush` would wait for the bytes to leave the UART, so they skip it.
    fn flush_writes(&mut self) -> io::Result<()> {
        self.flush()
    }
}

#[cfg(unix)]
impl SlcanPort for serialport::TTYPort {
    fn set_io_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        Ok(serialport::SerialPort::set_timeout(self, timeout)?)
    }

    fn port_name(&self) -> String {
        serialport::SerialPort::name(self).unwrap_or_else(|| "pty master".to_string())
    }

    fn discard_input(&mut self) -> io::Result<()> {
        Ok(serialport::SerialPort::clear(self, serialport::ClearBuffer::Input)?)
    }

    fn flush_writes(&mut self) -> io::Result<()> {
        Ok(())
    }
}

impl SlcanPort for Box<dyn serialport::SerialPort> {
    fn set_io_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        // Some drivers (Windows') read a zero timeout as "wait forever".
        let timeout = if cfg!(unix) { timeout } else { timeout.max(Duration::from_millis(1)) };
        Ok(self.set_timeout(timeout)?)
    }

    fn port_name(&self) -> String {
        self.name().unwrap_or_else(|| "serial port".to_string())
    }

    fn discard_input(&mut self) -> io::Result<()> {
        Ok(self.clear(serialport::ClearBuffer::Input)?)
    }

    fn flush_writes(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// Any `Read + Write` stream as an [`SlcanPort`], given how to bound its reads and writes (for
/// a socket: `set_read_timeout` and `set_write_timeout`).
pub struct TimedPort<P> {
    port: P,
    name: String,
    set_timeout: fn(&mut P, Duration) -> io::Result<()>,
}

impl<P> std::fmt::Debug for TimedPort<P> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TimedPort").field("name", &self.name).finish_non_exhaustive()
    }
}

impl<P> TimedPort<P> {
    /// `set_timeout` is never given zero: std's sockets refuse it, so it is raised to 1 ms.
    pub fn new(port: P, name: impl Into<String>, set_timeout: fn(&mut P, Duration) -> io::Result<()>) -> Self {
        TimedPort { port, name: name.into(), set_timeout }
    }

    pub fn get_ref(&self) -> &P {
        &self.port
    }

    pub fn into_inner(self) -> P {
        self.port
    }
}

impl<P: Read> Read for TimedPort<P> {
    fn read(&mut self, buf: &mut [u8]) -> io::Result<usize> {
        self.port.read(buf)
    }
}

impl<P: Write> Write for TimedPort<P> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.port.write(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.port.flush()
    }
}

impl<P: Read + Write + Send> SlcanPort for TimedPort<P> {
    fn set_io_timeout(&mut self, timeout: Duration) -> io::Result<()> {
        (self.set_timeout)(&mut self.port, timeout.max(Duration::from_millis(1)))
    }

    fn port_name(&self) -> String {
        self.name.clone()
    }
}

/// Read errors that only mean "nothing yet".
fn is_timeout(error: &io::Error) -> bool {
    matches!(error.kind(), io::ErrorKind::TimedOut | io::ErrorKind::WouldBlock | io::ErrorKind::Interrupted)
}
