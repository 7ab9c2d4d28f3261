//! [`XsensImu`]: the host driver of an MTi-10 on a serial port.
//!
//! ```text
//! let mut imu = XsensImu::open("/dev/ttyUSB0", 115_200)?.with_clock(Box::new(monotonic_ns));
//! imu.configure(200)?;                        // GoToConfig, ReqDID, SetOutputConfiguration, GoToMeasurement
//! loop {
//!     match imu.next_sample(Duration::from_millis(50)) {
//!         Ok(Some(reading)) => publish(reading.sample),   // stamp corrected from SampleTimeFine
//!         Ok(None) => {}                                   // nothing within the timeout
//!         Err(XsensError::Disconnected { .. }) => reopen and configure again,
//!         Err(other) => report,
//!     }
//! }
//! ```
//!
//! # Timeout contract
//!
//! As [`crate::serial::SerialLink`]: built with [`XsensImu::open`] or
//! [`XsensImu::from_serialport`] the driver sets the port's timeout before every read and write;
//! with [`XsensImu::new`] the port must bound its reads itself (return `TimedOut`/`WouldBlock`);
//! [`XsensImu::with_timeout_control`] supplies a timeout setter for other port types.
//!
//! # Disconnection
//!
//! A read of 0 bytes (end of stream) or any read error other than a timeout, and a write that
//! fails because the other end is gone, return [`XsensError::Disconnected`]: the port is
//! finished (a closed pty, an unplugged adapter). Drop the driver, reopen the port and call
//! [`XsensImu::configure`] again.

use std::fmt;
use std::io::{Read, Write};
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use super::message::{OutputConfig, error_meaning, mid};
use super::mtdata2::{DataId, MtData};
use super::stamp::{StampCorrector, StampCorrectorConfig};
use super::xbus::{BUS_ID_MASTER, XbusCounters, XbusDecoder, encode_frame};
use super::{XsensError, end_of_stream, is_read_timeout, read_failure, write_failure};
use crate::link::deadline_after;
use crate::sensor::ImuSample;
use crate::serial::SetTimeout;

/// A host clock in nanoseconds, read when bytes arrive.
pub type HostClock = Box<dyn FnMut() -> u64 + Send>;

/// Bound on writing one command.
pub const DEFAULT_WRITE_TIMEOUT: Duration = Duration::from_secs(1);
/// Bytes read from the port at once.
const READ_CHUNK_BYTES: usize = 4096;
/// Reads still made once a wait's deadline has passed, as long as bytes keep coming (see
/// `serial.rs`): a frame already in the OS buffer is returned even with a zero timeout.
const LATE_READS: usize = 4;
/// A packet-counter step this large is a device restart or reordering, not lost samples.
const COUNTER_RESET_GAP: u16 = 0x8000;

/// Nanoseconds on a monotonic clock since its first use in this process: the default
/// [`HostClock`]. The firmware injects its `CLOCK_MONOTONIC` reading instead (`with_clock`).
pub fn host_monotonic_ns() -> u64 {
    static EPOCH: OnceLock<Instant> = OnceLock::new();
    EPOCH.get_or_init(Instant::now).elapsed().as_nanos() as u64
}

/// How long a command waits for its acknowledgement, and how often it is sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CommandTimeouts {
    pub per_attempt: Duration,
    pub attempts: u32,
}

impl Default for CommandTimeouts {
    fn default() -> Self {
        // A device streaming at 2 kHz into a slow line may take a while to see GoToConfig
        // behind the data it is still sending; retrying covers a command lost on the line.
        CommandTimeouts { per_attempt: Duration::from_millis(250), attempts: 8 }
    }
}

/// One sample as the driver delivers it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuReading {
    /// Body-frame sample stamped with the corrected host time (the arrival stamp when the
    /// message carries no SampleTimeFine).
    pub sample: ImuSample,
    /// Host clock when the read that completed the message returned.
    pub arrival_ns: u64,
    pub packet_counter: Option<u16>,
    pub sample_time_fine: Option<u32>,
    /// Messages lost just before this one, by the packet counter.
    pub dropped_before: u16,
}

/// What the driver saw since it was created. Saturating.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct XsensCounters {
    /// Readings delivered.
    pub samples: u64,
    /// MTData2 messages lost, by gaps in the packet counter.
    pub dropped_samples: u64,
    /// Packet counter jumps too large to be losses (a device restart).
    pub counter_resets: u64,
    /// MTData2 messages without acceleration or rate of turn, skipped.
    pub incomplete: u64,
    /// MTData2 messages that passed the checksum but could not be parsed, skipped.
    pub malformed: u64,
    /// Frames that were neither the reply waited for nor a sample (stale acknowledgements,
    /// samples still streaming during configuration).
    pub ignored_frames: u64,
    /// Error messages from the device.
    pub device_errors: u64,
    /// The framing's counters.
    pub xbus: XbusCounters,
}

/// Host driver of an MTi-10; see the module documentation.
pub struct XsensImu<P> {
    port: P,
    name: String,
    set_timeout: Option<SetTimeout<P>>,
    /// A serialport's flush drains the UART (tcdrain); only ports buffering in user space
    /// need it.
    flush_after_write: bool,
    write_timeout: Duration,
    timeouts: CommandTimeouts,
    clock: HostClock,
    decoder: XbusDecoder,
    /// Bytes read but not yet decoded: `rx[rx_start..rx_end]`, read at `rx_arrival_ns`.
    rx: Box<[u8]>,
    rx_start: usize,
    rx_end: usize,
    rx_arrival_ns: u64,
    tx: Vec<u8>,
    /// Payload of the frame returned last by `next_frame`.
    payload: Vec<u8>,
    stamps: StampCorrector,
    last_counter: Option<u16>,
    device_id: Option<u64>,
    outputs: Vec<OutputConfig>,
    counters: XsensCounters,
}

impl<P> fmt::Debug for XsensImu<P> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("XsensImu")
            .field("port", &self.name)
            .field("timeout_control", &self.set_timeout.is_some())
            .field("device_id", &self.device_id)
            .field("outputs", &self.outputs)
            .field("counters", &self.counters)
            .finish_non_exhaustive()
    }
}

impl<P: Read + Write> XsensImu<P> {
    /// A driver over `port`, which must bound its reads (see the timeout contract).
    pub fn new(port: P) -> Self {
        Self::build(port, "byte stream".to_string(), None, true)
    }

    /// A driver over `port`, setting its timeouts with `set_timeout`.
    pub fn with_timeout_control(port: P, set_timeout: SetTimeout<P>) -> Self {
        Self::build(port, "byte stream".to_string(), Some(set_timeout), true)
    }

    fn build(port: P, name: String, set_timeout: Option<SetTimeout<P>>, flush_after_write: bool) -> Self {
        XsensImu {
            port,
            name,
            set_timeout,
            flush_after_write,
            write_timeout: DEFAULT_WRITE_TIMEOUT,
            timeouts: CommandTimeouts::default(),
            clock: Box::new(host_monotonic_ns),
            decoder: XbusDecoder::new().only_bus_id(BUS_ID_MASTER),
            rx: vec![0; READ_CHUNK_BYTES].into_boxed_slice(),
            rx_start: 0,
            rx_end: 0,
            rx_arrival_ns: 0,
            tx: Vec::new(),
            payload: Vec::new(),
            stamps: StampCorrector::default(),
            last_counter: None,
            device_id: None,
            outputs: Vec::new(),
            counters: XsensCounters::default(),
        }
    }

    /// Stamps arrivals with `clock` (nanoseconds, monotonic) instead of [`host_monotonic_ns`].
    pub fn with_clock(mut self, clock: HostClock) -> Self {
        self.clock = clock;
        self
    }

    pub fn set_command_timeouts(&mut self, timeouts: CommandTimeouts) {
        self.timeouts = timeouts;
    }

    pub fn set_write_timeout(&mut self, timeout: Duration) {
        self.write_timeout = timeout;
    }

    /// Replaces the stamp corrector's tuning (and forgets its state).
    pub fn set_stamp_config(&mut self, config: StampCorrectorConfig) {
        self.stamps = StampCorrector::new(config);
    }

    /// Names the port in errors.
    pub fn set_name(&mut self, name: impl Into<String>) {
        self.name = name.into();
    }

    pub fn name(&self) -> &str {
        &self.name
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

    /// The device id from the last [`Self::configure`] or [`Self::request_device_id`].
    pub fn device_id(&self) -> Option<u64> {
        self.device_id
    }

    /// The output configuration the device acknowledged last.
    pub fn output_configuration(&self) -> &[OutputConfig] {
        &self.outputs
    }

    pub fn stamp_corrector(&self) -> &StampCorrector {
        &self.stamps
    }

    pub fn counters(&self) -> XsensCounters {
        XsensCounters { xbus: self.decoder.counters(), ..self.counters }
    }

    /// Puts the device into measurement at `rate_hz` (1–2000): config mode, device id, rate of
    /// turn and acceleration as float32 at `rate_hz` with SampleTimeFine and the packet counter
    /// in every message, measurement mode. Samples still streaming meanwhile are skipped.
    pub fn configure(&mut self, rate_hz: u16) -> Result<(), XsensError> {
        if rate_hz == 0 || rate_hz > super::device::MAX_OUTPUT_HZ {
            return Err(XsensError::Invalid(format!("output rate of {rate_hz} Hz (the MTi-10 does 1–2000 Hz)")));
        }
        self.go_to_config()?;
        self.request_device_id()?;
        self.set_output_configuration(&[
            OutputConfig::new(DataId::PACKET_COUNTER, OutputConfig::EVERY_PACKET),
            OutputConfig::new(DataId::SAMPLE_TIME_FINE, OutputConfig::EVERY_PACKET),
            OutputConfig::new(DataId::ACCELERATION, rate_hz),
            OutputConfig::new(DataId::RATE_OF_TURN, rate_hz),
        ])?;
        self.go_to_measurement()
    }

    /// GoToConfig, sent until acknowledged.
    pub fn go_to_config(&mut self) -> Result<(), XsensError> {
        self.command(mid::GO_TO_CONFIG, &[], mid::GO_TO_CONFIG_ACK, "GoToConfig")
    }

    /// GoToMeasurement; the stream restarts, so the stamp corrector and counter tracking do too.
    pub fn go_to_measurement(&mut self) -> Result<(), XsensError> {
        self.command(mid::GO_TO_MEASUREMENT, &[], mid::GO_TO_MEASUREMENT_ACK, "GoToMeasurement")?;
        self.stamps.reset();
        self.last_counter = None;
        Ok(())
    }

    /// ReqDID: the device id (4 bytes, or 8 on devices with long ids).
    pub fn request_device_id(&mut self) -> Result<u64, XsensError> {
        self.command(mid::REQ_DID, &[], mid::DEVICE_ID, "ReqDID")?;
        let id = match self.payload.as_slice() {
            &[a, b, c, d] => u64::from(u32::from_be_bytes([a, b, c, d])),
            &[a, b, c, d, e, f, g, h] => u64::from_be_bytes([a, b, c, d, e, f, g, h]),
            other => return Err(XsensError::Invalid(format!("DeviceID reply of {} bytes", other.len()))),
        };
        self.device_id = Some(id);
        Ok(id)
    }

    /// SetOutputConfiguration (config mode); returns the configuration the device acknowledged,
    /// which must contain every data id asked for (the device may adjust frequencies).
    pub fn set_output_configuration(&mut self, outputs: &[OutputConfig]) -> Result<Vec<OutputConfig>, XsensError> {
        let mut request = Vec::with_capacity(4 * outputs.len());
        OutputConfig::encode_list(outputs, &mut request);
        self.command(mid::SET_OUTPUT_CONFIGURATION, &request, mid::OUTPUT_CONFIGURATION, "SetOutputConfiguration")?;
        let echoed = OutputConfig::decode_list(&self.payload).ok_or_else(|| {
            XsensError::Invalid(format!("output configuration reply of {} bytes", self.payload.len()))
        })?;
        if let Some(missing) = outputs.iter().find(|o| !echoed.iter().any(|e| e.data_id == o.data_id)) {
            return Err(XsensError::OutputRejected { data_id: missing.data_id.0 });
        }
        self.outputs = echoed.clone();
        Ok(echoed)
    }

    /// The next sample, waiting at most `timeout`; `Ok(None)` if none came. Other frames are
    /// counted and skipped; an Error message from the device is returned as an error.
    pub fn next_sample(&mut self, timeout: Duration) -> Result<Option<ImuReading>, XsensError> {
        let deadline = deadline_after(timeout);
        loop {
            let Some((message, arrival_ns)) = self.next_frame(deadline)? else {
                return Ok(None);
            };
            match message {
                mid::MT_DATA2 => match MtData::parse(&self.payload) {
                    Ok(data) => {
                        if let Some(reading) = self.reading(&data, arrival_ns) {
                            return Ok(Some(reading));
                        }
                    }
                    Err(_) => bump(&mut self.counters.malformed),
                },
                mid::ERROR => return Err(self.device_error("measurement")),
                _ => bump(&mut self.counters.ignored_frames),
            }
        }
    }

    fn reading(&mut self, data: &MtData, arrival_ns: u64) -> Option<ImuReading> {
        let mut dropped_before = 0;
        if let Some(counter) = data.packet_counter {
            if let Some(last) = self.last_counter {
                let gap = counter.wrapping_sub(last).wrapping_sub(1);
                if gap >= COUNTER_RESET_GAP {
                    bump(&mut self.counters.counter_resets);
                } else {
                    dropped_before = gap;
                    self.counters.dropped_samples = self.counters.dropped_samples.saturating_add(u64::from(gap));
                }
            }
            self.last_counter = Some(counter);
        }
        let (Some(accel_mps2), Some(gyro_radps)) = (data.accel_mps2, data.gyro_radps) else {
            bump(&mut self.counters.incomplete);
            return None;
        };
        let stamp_ns = match data.sample_time_fine {
            Some(ticks) => self.stamps.correct(ticks, arrival_ns),
            None => arrival_ns,
        };
        bump(&mut self.counters.samples);
        Some(ImuReading {
            sample: ImuSample { stamp_ns, gyro_radps, accel_mps2 },
            arrival_ns,
            packet_counter: data.packet_counter,
            sample_time_fine: data.sample_time_fine,
            dropped_before,
        })
    }

    /// Sends `message` until `ack` arrives; the ack's payload is left in `self.payload`.
    fn command(&mut self, message: u8, payload: &[u8], ack: u8, name: &'static str) -> Result<(), XsensError> {
        let attempts = self.timeouts.attempts.max(1);
        for _ in 0..attempts {
            self.send(message, payload, name)?;
            let deadline = deadline_after(self.timeouts.per_attempt);
            while let Some((reply, _)) = self.next_frame(deadline)? {
                if reply == ack {
                    return Ok(());
                }
                if reply == mid::ERROR {
                    return Err(self.device_error(name));
                }
                bump(&mut self.counters.ignored_frames);
            }
        }
        Err(XsensError::NoAck {
            command: name,
            port: self.name.clone(),
            attempts,
            per_attempt: self.timeouts.per_attempt,
        })
    }

    fn device_error(&mut self, command: &'static str) -> XsensError {
        bump(&mut self.counters.device_errors);
        let code = self.payload.first().copied().unwrap_or_default();
        XsensError::Device { code, meaning: error_meaning(code), command }
    }

    fn send(&mut self, message: u8, payload: &[u8], name: &'static str) -> Result<(), XsensError> {
        self.tx.clear();
        encode_frame(BUS_ID_MASTER, message, payload, &mut self.tx)
            .map_err(|error| XsensError::Invalid(format!("{name}: {error}")))?;
        self.apply_timeout(self.write_timeout)?;
        let flush = self.flush_after_write;
        let written = self.port.write_all(&self.tx).and_then(|()| if flush { self.port.flush() } else { Ok(()) });
        written.map_err(|error| write_failure(&self.name, || format!("{}: writing {name}", self.name), error))
    }

    fn apply_timeout(&mut self, timeout: Duration) -> Result<(), XsensError> {
        if let Some(set_timeout) = self.set_timeout {
            set_timeout(&mut self.port, timeout)
                .map_err(XsensError::io(|| format!("setting the timeout of {}", self.name)))?;
        }
        Ok(())
    }

    /// The next frame before `deadline`: its message id and arrival stamp, payload in
    /// `self.payload`.
    fn next_frame(&mut self, deadline: Instant) -> Result<Option<(u8, u64)>, XsensError> {
        let mut late_reads = 0usize;
        loop {
            let mut pending = self.rx.get(self.rx_start..self.rx_end).unwrap_or_default();
            let before = pending.len();
            let found = self.decoder.next_frame(&mut pending).map(|frame| {
                self.payload.clear();
                self.payload.extend_from_slice(frame.payload);
                frame.mid
            });
            self.rx_start += before - pending.len();
            if let Some(message) = found {
                return Ok(Some((message, self.rx_arrival_ns)));
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
                Ok(0) => return Err(end_of_stream(&self.name)),
                Ok(len) => {
                    self.rx_arrival_ns = (self.clock)();
                    self.rx_start = 0;
                    self.rx_end = len.min(self.rx.len());
                }
                Err(error) if is_read_timeout(&error) => {
                    if Instant::now() >= deadline {
                        return Ok(None);
                    }
                }
                Err(error) => return Err(read_failure(&self.name, error)),
            }
        }
    }
}

impl<P: serialport::SerialPort> XsensImu<P> {
    /// A driver over a serialport port, controlling its timeouts.
    pub fn from_serialport(port: P) -> Self {
        let name = port.name().unwrap_or_else(|| "serial port".to_string());
        Self::build(port, name, Some(|port: &mut P, timeout| Ok(port.set_timeout(timeout)?)), false)
    }
}

impl XsensImu<Box<dyn serialport::SerialPort>> {
    /// Opens the serial device at `path`, 8N1 without flow control (the MTi's setting; 115 200
    /// baud by default).
    pub fn open(path: &str, baud_rate: u32) -> Result<Self, XsensError> {
        let port = crate::serial::open_port(path, baud_rate, DEFAULT_WRITE_TIMEOUT).map_err(|source| {
            XsensError::Io { context: format!("opening serial port {path} at {baud_rate} baud"), source }
        })?;
        let set_timeout: SetTimeout<Box<dyn serialport::SerialPort>> = |port, timeout| Ok(port.set_timeout(timeout)?);
        Ok(Self::build(port, path.to_string(), Some(set_timeout), false))
    }
}

fn bump(counter: &mut u64) {
    *counter = counter.saturating_add(1);
}
