//! [`SocketCanBus`]: a Linux SocketCAN interface (`can0`, `vcan0`), standard and extended ids.

use std::fmt;
use std::io::ErrorKind;
use std::thread;
use std::time::{Duration, Instant};

use ::socketcan::{
    CanAnyFrame, CanDataFrame, CanFdFrame, CanFdSocket, CanFrame as SocketCanFrame, CanSocket, EmbeddedFrame,
    ExtendedId, Frame, Socket, StandardId,
};
use protocol::frame::FrameError;
use protocol::frame::can::{CanFrame, CanKind};

use super::CanBus;
use crate::link::{LinkError, deadline_after};

/// Default bound on waiting for room in the interface's transmit queue. A real controller's
/// queue is short (often 10 frames) and empties at the bus rate, so a full queue is normal
/// under load; one that stays full this long means the bus is down or flooded.
pub const DEFAULT_WRITE_TIMEOUT: Duration = Duration::from_secs(1);
/// Linux's "no buffer space": the transmit queue is full. Not an `ErrorKind` std names.
const ENOBUFS: i32 = 105;
/// Pause before retrying a full transmit queue: a few frames' time at 500 kbit/s.
const RETRY_PAUSE: Duration = Duration::from_micros(500);

enum Sock {
    Classic(CanSocket),
    Fd(CanFdSocket),
}

/// A SocketCAN interface as a [`CanBus`]. Frames that are not ours (standard ids, remote and
/// error frames) are skipped and counted in [`CanBus::dropped_frames`].
pub struct SocketCanBus {
    sock: Sock,
    interface: String,
    write_timeout: Duration,
    foreign_frames: u64,
}

impl fmt::Debug for SocketCanBus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("SocketCanBus")
            .field("interface", &self.interface)
            .field("kind", &self.kind())
            .field("foreign_frames", &self.foreign_frames)
            .finish_non_exhaustive()
    }
}

impl SocketCanBus {
    /// Opens `interface` for frames of `kind`. An FD bus needs an FD-capable interface (for a
    /// vcan: `ip link set <name> mtu 72`).
    pub fn open(interface: &str, kind: CanKind) -> Result<Self, LinkError> {
        let context = || format!("opening SocketCAN interface {interface} ({kind:?})");
        let sock = match kind {
            CanKind::Classic => Sock::Classic(CanSocket::open(interface).map_err(LinkError::io(context))?),
            CanKind::Fd => Sock::Fd(CanFdSocket::open(interface).map_err(LinkError::io(context))?),
        };
        Ok(SocketCanBus {
            sock,
            interface: interface.to_string(),
            write_timeout: DEFAULT_WRITE_TIMEOUT,
            foreign_frames: 0,
        })
    }

    pub fn interface(&self) -> &str {
        &self.interface
    }

    /// Bounds the wait for room in a full transmit queue.
    pub fn set_write_timeout(&mut self, timeout: Duration) {
        self.write_timeout = timeout;
    }

    fn write(&self, frame: &CanFrame) -> std::io::Result<()> {
        let invalid = |error: FrameError| std::io::Error::new(ErrorKind::InvalidInput, error);
        let id: socketcan::Id = if frame.extended {
            ExtendedId::new(frame.id).ok_or_else(|| invalid(FrameError::InvalidCanId(frame.id)))?.into()
        } else {
            StandardId::new(frame.id as u16)
                .filter(|_| frame.id <= u32::from(StandardId::MAX.as_raw()))
                .ok_or_else(|| invalid(FrameError::InvalidCanId(frame.id)))?
                .into()
        };
        let len = usize::from(frame.len);
        match &self.sock {
            Sock::Classic(sock) => {
                let data =
                    CanDataFrame::new(id, frame.data()).ok_or_else(|| invalid(FrameError::InvalidCanLength(len)))?;
                sock.write_frame(&data)
            }
            Sock::Fd(sock) => {
                let data =
                    CanFdFrame::new(id, frame.data()).ok_or_else(|| invalid(FrameError::InvalidCanLength(len)))?;
                sock.write_frame(&data)
            }
        }
    }

    /// Reads one frame, `None` on timeout or for a frame that is not ours.
    fn read(&mut self, timeout: Duration) -> std::io::Result<Option<CanFrame>> {
        let received = match &self.sock {
            Sock::Classic(sock) => sock.read_frame_timeout(timeout).map(|frame| match frame {
                SocketCanFrame::Data(data) => ours(&data),
                SocketCanFrame::Remote(_) | SocketCanFrame::Error(_) => None,
            }),
            Sock::Fd(sock) => sock.read_frame_timeout(timeout).map(|frame| match frame {
                CanAnyFrame::Normal(data) => ours(&data),
                CanAnyFrame::Fd(data) => ours(&data),
                CanAnyFrame::Remote(_) | CanAnyFrame::Error(_) => None,
            }),
        };
        match received {
            Ok(Some(frame)) => Ok(Some(frame)),
            Ok(None) => {
                self.foreign_frames = self.foreign_frames.saturating_add(1);
                Ok(None)
            }
            Err(error)
                if matches!(error.kind(), ErrorKind::TimedOut | ErrorKind::WouldBlock | ErrorKind::Interrupted) =>
            {
                Ok(None)
            }
            Err(error) => Err(error),
        }
    }
}

/// Our frame for a SocketCAN data frame (standard or extended id), `None` for any other.
fn ours<F: Frame>(frame: &F) -> Option<CanFrame> {
    if frame.is_extended() {
        CanFrame::new(frame.raw_id(), frame.data()).ok()
    } else {
        CanFrame::standard(frame.raw_id(), frame.data()).ok()
    }
}

impl CanBus for SocketCanBus {
    fn send(&mut self, frame: &CanFrame) -> Result<(), LinkError> {
        let len = usize::from(frame.len);
        let max = self.kind().max_data();
        if len > max {
            return Err(LinkError::CanFrameTooLong { len, max });
        }
        let deadline = deadline_after(self.write_timeout);
        loop {
            match self.write(frame) {
                Ok(()) => return Ok(()),
                Err(error)
                    if (error.raw_os_error() == Some(ENOBUFS)
                        || matches!(error.kind(), ErrorKind::WouldBlock | ErrorKind::Interrupted))
                        && Instant::now() < deadline =>
                {
                    thread::sleep(RETRY_PAUSE);
                }
                Err(source) => {
                    return Err(LinkError::Io {
                        context: format!("writing CAN frame {:#010x} to {}", frame.id, self.interface),
                        source,
                    });
                }
            }
        }
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, LinkError> {
        let deadline = deadline_after(timeout);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            match self.read(left) {
                Ok(Some(frame)) => return Ok(Some(frame)),
                Ok(None) if Instant::now() >= deadline => return Ok(None),
                Ok(None) => {}
                Err(source) => {
                    return Err(LinkError::Io {
                        context: format!("reading from CAN interface {}", self.interface),
                        source,
                    });
                }
            }
        }
    }

    fn kind(&self) -> CanKind {
        match self.sock {
            Sock::Classic(_) => CanKind::Classic,
            Sock::Fd(_) => CanKind::Fd,
        }
    }

    fn dropped_frames(&self) -> u64 {
        self.foreign_frames
    }
}
