//! [`XsensDevice`]: an MTi-10 as the simulator and the HIL harness play it.
//!
//! A sans-IO core ([`XsensDevice::handle_bytes`], [`XsensDevice::encode_sample`]) with thin
//! wrappers for a port ([`XsensDevice::poll_commands`], [`XsensDevice::emit_sample`]), so one
//! thread can pace samples on the wall clock and answer commands between them:
//!
//! ```text
//! loop {
//!     device.poll_commands(&mut port)?;          // port with a short or zero read timeout
//!     device.emit_sample(&mut port, &sample, ticks, counter)?;   // no-op in config mode
//!     sleep until the next 5 ms release time
//! }
//! ```
//!
//! Behaviour: config mode after [`mid::GO_TO_CONFIG`] or [`mid::WAKE_UP_ACK`]; ReqDID answered
//! in both modes; SetOutputConfiguration (config mode only) stores the list and acknowledges
//! with it; GoToMeasurement starts the stream. Outputs are limited to packet counter,
//! SampleTimeFine, acceleration and rate of turn (any precision and frame); anything else is
//! refused with an Error message, as is a command the state does not allow.
//!
//! Rates: [`XsensDevice::emit_sample`] is called at the simulator's IMU rate (`sample_rate_hz`).
//! An output at `f` Hz goes into every `round(sample_rate_hz / f)`-th sample since
//! GoToMeasurement (every sample if `f` is at or above the sample rate); outputs at
//! [`OutputConfig::EVERY_PACKET`] go into every message sent. A sample in which no output is due
//! sends nothing. The packet counter and SampleTimeFine are the caller's, so a test can make
//! gaps or wraps.
//!
//! Writes are not flushed: give it an unbuffered port (a serialport, a pty, a socket).

use std::io::{Read, Write};

use super::message::{OutputConfig, error_code, mid};
use super::mtdata2::{DataId, MtData};
use super::xbus::{BUS_ID_MASTER, XbusCounters, XbusDecoder, encode_frame};
use super::{XsensError, end_of_stream, is_read_timeout, read_failure, write_failure};
use crate::sensor::ImuSample;

/// A device id with the type bits of a 5th-generation MTi-10 (0x0168xxxx; Xsens' public
/// `xsdid.h`: MTi-10 class 0x01000000 | MT-x0 0x00600000 | mk5 0x00080000).
pub const MTI10_DEVICE_ID: u32 = 0x0168_2A51;
/// Highest output frequency of an MTi-10.
pub const MAX_OUTPUT_HZ: u16 = 2000;
/// Bytes read from the port at once.
const READ_CHUNK_BYTES: usize = 1024;

/// The device's state.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DeviceMode {
    /// Accepting configuration; no samples sent.
    Config,
    /// Streaming MTData2.
    Measurement,
}

/// What the device did since it was created. Saturating.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeviceCounters {
    /// Commands received (any message from the host).
    pub commands: u64,
    /// Error messages sent in reply.
    pub errors_sent: u64,
    /// MTData2 messages sent.
    pub samples_sent: u64,
    /// The decoder's view of the host's bytes.
    pub xbus: XbusCounters,
}

/// An emulated MTi-10; see the module documentation.
#[derive(Debug)]
pub struct XsensDevice {
    device_id: u32,
    sample_rate_hz: u32,
    mode: DeviceMode,
    outputs: Vec<OutputConfig>,
    /// `emit_sample` calls since GoToMeasurement, for decimation.
    samples_offered: u64,
    decoder: XbusDecoder,
    rx: Box<[u8]>,
    tx: Vec<u8>,
    payload: Vec<u8>,
    name: String,
    counters: DeviceCounters,
}

impl XsensDevice {
    /// A device in config mode with no outputs, fed samples at `sample_rate_hz`.
    pub fn new(device_id: u32, sample_rate_hz: u32) -> Self {
        XsensDevice {
            device_id,
            sample_rate_hz: sample_rate_hz.max(1),
            mode: DeviceMode::Config,
            outputs: Vec::new(),
            samples_offered: 0,
            decoder: XbusDecoder::new().only_bus_id(BUS_ID_MASTER),
            rx: vec![0; READ_CHUNK_BYTES].into_boxed_slice(),
            tx: Vec::new(),
            payload: Vec::new(),
            name: "emulated MTi-10".to_string(),
            counters: DeviceCounters::default(),
        }
    }

    /// A device that powered up measuring with a stored configuration (nobody answered its
    /// WakeUp), as a host that connects late finds it.
    pub fn measuring(device_id: u32, sample_rate_hz: u32, outputs: &[OutputConfig]) -> Self {
        let mut device = Self::new(device_id, sample_rate_hz);
        device.outputs = outputs.to_vec();
        device.mode = DeviceMode::Measurement;
        device
    }

    /// Names the device in errors.
    pub fn set_name(&mut self, name: impl Into<String>) {
        self.name = name.into();
    }

    pub fn mode(&self) -> DeviceMode {
        self.mode
    }

    pub fn device_id(&self) -> u32 {
        self.device_id
    }

    /// The output configuration in force.
    pub fn outputs(&self) -> &[OutputConfig] {
        &self.outputs
    }

    pub fn counters(&self) -> DeviceCounters {
        DeviceCounters { xbus: self.decoder.counters(), ..self.counters }
    }

    /// Handles the host's bytes, appending the replies to `reply`; returns the commands handled.
    pub fn handle_bytes(&mut self, bytes: &[u8], reply: &mut Vec<u8>) -> usize {
        let mut input = bytes;
        let mut handled = 0;
        while let Some(frame) = self.decoder.next_frame(&mut input) {
            let command = frame.mid;
            self.payload.clear();
            self.payload.extend_from_slice(frame.payload);
            let payload = std::mem::take(&mut self.payload);
            self.handle_command(command, &payload, reply);
            self.payload = payload;
            handled += 1;
        }
        self.counters.commands = self.counters.commands.saturating_add(handled as u64);
        handled
    }

    fn handle_command(&mut self, command: u8, payload: &[u8], reply: &mut Vec<u8>) {
        match command {
            mid::GO_TO_CONFIG => {
                self.mode = DeviceMode::Config;
                put(reply, mid::GO_TO_CONFIG_ACK, &[]);
            }
            mid::WAKE_UP_ACK => self.mode = DeviceMode::Config,
            mid::GO_TO_MEASUREMENT => {
                self.mode = DeviceMode::Measurement;
                self.samples_offered = 0;
                put(reply, mid::GO_TO_MEASUREMENT_ACK, &[]);
            }
            mid::REQ_DID => put(reply, mid::DEVICE_ID, &self.device_id.to_be_bytes()),
            mid::SET_OUTPUT_CONFIGURATION => self.set_output_configuration(payload, reply),
            _ => self.refuse(error_code::INVALID_MESSAGE, reply),
        }
    }

    fn set_output_configuration(&mut self, payload: &[u8], reply: &mut Vec<u8>) {
        if payload.is_empty() {
            // The same message id without data asks for the configuration in force.
            let mut list = Vec::new();
            OutputConfig::encode_list(&self.outputs, &mut list);
            put(reply, mid::OUTPUT_CONFIGURATION, &list);
            return;
        }
        if self.mode != DeviceMode::Config {
            return self.refuse(error_code::INVALID_MESSAGE, reply);
        }
        let Some(list) = OutputConfig::decode_list(payload) else {
            return self.refuse(error_code::INVALID_PARAMETER, reply);
        };
        if list.iter().any(|entry| !supported(entry.data_id)) {
            return self.refuse(error_code::INVALID_PARAMETER, reply);
        }
        if list.iter().any(|e| {
            e.frequency_hz == 0 || (e.frequency_hz > MAX_OUTPUT_HZ && e.frequency_hz != OutputConfig::EVERY_PACKET)
        }) {
            return self.refuse(error_code::INVALID_PERIOD, reply);
        }
        self.outputs = list;
        let mut echo = Vec::new();
        OutputConfig::encode_list(&self.outputs, &mut echo);
        put(reply, mid::OUTPUT_CONFIGURATION, &echo);
    }

    fn refuse(&mut self, code: u8, reply: &mut Vec<u8>) {
        self.counters.errors_sent = self.counters.errors_sent.saturating_add(1);
        put(reply, mid::ERROR, &[code]);
    }

    /// Appends the MTData2 frame for `sample` (body frame, as the simulator produces it) to
    /// `out` if the device is measuring and an output is due; returns whether it did.
    pub fn encode_sample(
        &mut self,
        sample: &ImuSample,
        sample_time_fine: u32,
        packet_counter: u16,
        out: &mut Vec<u8>,
    ) -> bool {
        if self.mode != DeviceMode::Measurement {
            return false;
        }
        let index = self.samples_offered;
        self.samples_offered = self.samples_offered.saturating_add(1);
        let mut data = MtData::default();
        let mut due_outputs = 0usize;
        for entry in &self.outputs {
            if !is_due(entry.frequency_hz, self.sample_rate_hz, index) {
                continue;
            }
            if entry.frequency_hz != OutputConfig::EVERY_PACKET {
                due_outputs += 1;
            }
            let format = entry.data_id.format().unwrap_or_default();
            match entry.data_id {
                DataId::PACKET_COUNTER => data.packet_counter = Some(packet_counter),
                DataId::SAMPLE_TIME_FINE => data.sample_time_fine = Some(sample_time_fine),
                id if id.kind() == DataId::ACCELERATION => {
                    data.accel_mps2 = Some(sample.accel_mps2);
                    data.accel_format = format;
                }
                id if id.kind() == DataId::RATE_OF_TURN => {
                    data.gyro_radps = Some(sample.gyro_radps);
                    data.gyro_format = format;
                }
                _ => {}
            }
        }
        let only_every_packet = self.outputs.iter().all(|e| e.frequency_hz == OutputConfig::EVERY_PACKET);
        if self.outputs.is_empty() || (due_outputs == 0 && !only_every_packet) {
            return false;
        }
        self.payload.clear();
        data.encode(&mut self.payload);
        put(out, mid::MT_DATA2, &self.payload);
        self.counters.samples_sent = self.counters.samples_sent.saturating_add(1);
        true
    }

    /// Reads what the host sent (one read: give the port a short or zero timeout) and writes
    /// the replies; returns the commands handled, 0 when nothing came.
    pub fn poll_commands<P: Read + Write>(&mut self, port: &mut P) -> Result<usize, XsensError> {
        let len = match port.read(&mut self.rx) {
            Ok(0) => return Err(end_of_stream(&self.name)),
            Ok(len) => len.min(self.rx.len()),
            Err(error) if is_read_timeout(&error) => return Ok(0),
            Err(error) => return Err(read_failure(&self.name, error)),
        };
        let mut reply = std::mem::take(&mut self.tx);
        reply.clear();
        let rx = std::mem::take(&mut self.rx);
        let handled = self.handle_bytes(rx.get(..len).unwrap_or_default(), &mut reply);
        self.rx = rx;
        let written = self.write(port, &reply, "a reply");
        self.tx = reply;
        written.map(|()| handled)
    }

    /// Writes the MTData2 message of `sample` if one is due (see [`Self::encode_sample`]).
    pub fn emit_sample<P: Write>(
        &mut self,
        port: &mut P,
        sample: &ImuSample,
        sample_time_fine: u32,
        packet_counter: u16,
    ) -> Result<bool, XsensError> {
        let mut frame = std::mem::take(&mut self.tx);
        frame.clear();
        let sent = self.encode_sample(sample, sample_time_fine, packet_counter, &mut frame);
        let written = if sent { self.write(port, &frame, "MTData2") } else { Ok(()) };
        self.tx = frame;
        written.map(|()| sent)
    }

    /// Writes the WakeUp message a device sends at power-up.
    pub fn send_wake_up<P: Write>(&mut self, port: &mut P) -> Result<(), XsensError> {
        let mut frame = Vec::new();
        put(&mut frame, mid::WAKE_UP, &[]);
        self.write(port, &frame, "WakeUp")
    }

    fn write<P: Write>(&self, port: &mut P, bytes: &[u8], what: &str) -> Result<(), XsensError> {
        if bytes.is_empty() {
            return Ok(());
        }
        port.write_all(bytes)
            .map_err(|error| write_failure(&self.name, || format!("{}: writing {what}", self.name), error))
    }
}

/// Whether an output at `frequency_hz` goes into sample `index` of a stream at `rate_hz`.
fn is_due(frequency_hz: u16, rate_hz: u32, index: u64) -> bool {
    if frequency_hz == OutputConfig::EVERY_PACKET || u32::from(frequency_hz) >= rate_hz {
        return true;
    }
    let every = (f64::from(rate_hz) / f64::from(frequency_hz.max(1))).round().max(1.0) as u64;
    index.is_multiple_of(every)
}

/// The outputs the emulator can produce.
fn supported(id: DataId) -> bool {
    match id {
        DataId::PACKET_COUNTER | DataId::SAMPLE_TIME_FINE => true,
        _ => (id.kind() == DataId::ACCELERATION || id.kind() == DataId::RATE_OF_TURN) && id.format().is_some(),
    }
}

/// Appends a master-bus frame; our payloads are far below the Xbus limit.
fn put(out: &mut Vec<u8>, message: u8, payload: &[u8]) {
    let _fits = encode_frame(BUS_ID_MASTER, message, payload, out);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::xsens::xbus::XbusDecoder;
    use nalgebra::Vector3;

    fn replies(device: &mut XsensDevice, command: u8, payload: &[u8]) -> Vec<(u8, Vec<u8>)> {
        let mut request = Vec::new();
        encode_frame(BUS_ID_MASTER, command, payload, &mut request).unwrap();
        let mut reply = Vec::new();
        assert_eq!(device.handle_bytes(&request, &mut reply), 1);
        let mut frames = Vec::new();
        XbusDecoder::new().feed(&reply, |f| frames.push((f.mid, f.payload.to_vec())));
        frames
    }

    #[test]
    fn decimates_outputs_below_the_sample_rate() {
        let outputs = [
            OutputConfig::new(DataId::PACKET_COUNTER, OutputConfig::EVERY_PACKET),
            OutputConfig::new(DataId::ACCELERATION, 100),
            OutputConfig::new(DataId::RATE_OF_TURN, 50),
        ];
        let mut device = XsensDevice::measuring(MTI10_DEVICE_ID, 200, &outputs);
        let sample = ImuSample { stamp_ns: 0, gyro_radps: Vector3::new(0.1, 0.2, 0.3), accel_mps2: Vector3::z() };
        let mut kinds = Vec::new();
        for k in 0..8u16 {
            let mut out = Vec::new();
            if device.encode_sample(&sample, 0, k, &mut out) {
                XbusDecoder::new().feed(&out, |f| {
                    let data = MtData::parse(f.payload).unwrap();
                    kinds.push((data.packet_counter, data.accel_mps2.is_some(), data.gyro_radps.is_some()));
                });
            }
        }
        // Acceleration every 2nd sample, rate of turn every 4th; odd samples send nothing.
        assert_eq!(
            kinds,
            vec![(Some(0), true, true), (Some(2), true, false), (Some(4), true, true), (Some(6), true, false)]
        );
    }

    #[test]
    fn refuses_configuration_while_measuring_and_unsupported_outputs() {
        let mut device = XsensDevice::new(MTI10_DEVICE_ID, 200);
        let mut bad = Vec::new();
        OutputConfig::encode_list(&[OutputConfig::new(DataId(0x2010), 100)], &mut bad);
        assert_eq!(replies(&mut device, mid::SET_OUTPUT_CONFIGURATION, &bad), vec![(mid::ERROR, vec![0x21])]);
        let mut too_fast = Vec::new();
        OutputConfig::encode_list(&[OutputConfig::new(DataId::ACCELERATION, 4000)], &mut too_fast);
        assert_eq!(replies(&mut device, mid::SET_OUTPUT_CONFIGURATION, &too_fast), vec![(mid::ERROR, vec![0x03])]);
        assert_eq!(replies(&mut device, mid::GO_TO_MEASUREMENT, &[]), vec![(mid::GO_TO_MEASUREMENT_ACK, vec![])]);
        let mut good = Vec::new();
        OutputConfig::encode_list(&[OutputConfig::new(DataId::ACCELERATION, 100)], &mut good);
        assert_eq!(replies(&mut device, mid::SET_OUTPUT_CONFIGURATION, &good), vec![(mid::ERROR, vec![0x04])]);
        assert_eq!(replies(&mut device, 0x99, &[]), vec![(mid::ERROR, vec![0x04])]);
        assert_eq!(device.counters().errors_sent, 4);
        assert!(device.outputs().is_empty());
    }
}
