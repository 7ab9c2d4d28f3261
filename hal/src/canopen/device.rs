//! Emulated CANopen devices: the rover's wheel drives and pan-tilt head as the simulator and the
//! HIL harness play them.
//!
//! A device is a state machine on the caller's clock (`now_ns`, any monotonic origin): frames
//! go in through [`CanopenDevice::on_frame`], and [`CanopenDevice::tick`] returns what the device
//! sends by `now_ns`. Nothing reads a clock or a bus here, so tests drive devices on simulated
//! time, and [`service_devices`] puts them on any [`CanBus`] (a `LoopbackCanBus` on the wall
//! clock in the HIL harness).
//!
//! Every device has
//! - the NMT state machine: it boots (boot-up message) into pre-operational on its first tick,
//!   sends PDOs only when operational, answers SDO only when not stopped, and boots again on
//!   reset node / reset communication;
//! - a heartbeat every object 0x1017 ms (0 = none);
//! - a small SDO server (expedited transfers): 0x1000 device type, 0x1001 error register, 0x1017
//!   heartbeat producer time (writable), 0x1018 sub 0 and 1 (vendor id); anything else is
//!   aborted with the CiA 301 code that says why;
//! - EMCY when a fault is injected ([`CanopenDevice::set_fault`]) and the error-reset EMCY (code
//!   0) when it clears;
//! - [`CanopenDevice::set_silent`]: the device sends and hears nothing, as if unplugged; when
//!   silence ends it boots again, as a replugged device does.

use std::f64::consts::{FRAC_PI_2, PI, TAU};

use super::frame::{
    CanopenMessage, Emergency, NmtCommand, NmtState, NodeId, PdoData, PdoNumber, SdoData, SdoRequest, SdoResponse,
    abort_code,
};
use crate::can::{CanBus, CanFrame};
use crate::link::LinkError;

/// Default heartbeat producer time: 10 heartbeats a second cost 0.1 % of a 1 Mbit/s bus per node
/// and let a master notice a lost node within a few hundred milliseconds.
pub const DEFAULT_HEARTBEAT_MS: u16 = 100;

/// Device type (object 0x1000) of the wheel drives: CiA 402 profile (0x0192), servo drive (0x0002).
pub const DEVICE_TYPE_CIA402_SERVO: u32 = 0x0002_0192;
/// Device type of the pan-tilt head: 0 means "no standardised device profile" in CiA 301.
pub const DEVICE_TYPE_NO_PROFILE: u32 = 0;

const OBJECT_DEVICE_TYPE: u16 = 0x1000;
const OBJECT_ERROR_REGISTER: u16 = 0x1001;
const OBJECT_HEARTBEAT: u16 = 0x1017;
const OBJECT_IDENTITY: u16 = 0x1018;

/// Frames a device takes per [`service_devices`] call: bounded, so a flooded bus cannot keep a
/// device from ticking.
const MAX_FRAMES_PER_SERVICE: usize = 4096;

/// The CiA 301 identity of one device.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DeviceConfig {
    pub node: NodeId,
    /// Power-on value of object 0x1017; reset node and reset communication restore it.
    pub heartbeat_ms: u16,
    /// Object 0x1000.
    pub device_type: u32,
    /// Object 0x1018 sub 1. Vendor ids are assigned by CiA; 0 says the hardware is emulated.
    pub vendor_id: u32,
}

impl DeviceConfig {
    pub fn new(node: NodeId, device_type: u32) -> Self {
        DeviceConfig { node, heartbeat_ms: DEFAULT_HEARTBEAT_MS, device_type, vendor_id: 0 }
    }
}

/// What the simulator, the HIL harness and the tests do with any emulated device.
pub trait CanopenDevice {
    fn node(&self) -> NodeId;

    /// The device's NMT state; [`NmtState::BootUp`] until its first tick has sent the boot-up.
    fn nmt_state(&self) -> NmtState;

    /// Takes one frame from the bus, received at `now_ns`.
    fn on_frame(&mut self, frame: &CanFrame, now_ns: u64);

    /// Advances the device to `now_ns` and returns the frames it sends, in order.
    fn tick(&mut self, now_ns: u64) -> Vec<CanFrame>;

    /// `true`: the device sends and hears nothing (unplugged, or a heartbeat-timeout test);
    /// `false` after `true`: it boots again.
    fn set_silent(&mut self, silent: bool);

    /// Injects (`Some(code)`, a CiA 301 error code) or clears (`None`) a fault: an EMCY with the
    /// code, or the error-reset EMCY, is sent at the next tick.
    fn set_fault(&mut self, code: Option<u16>);
}

/// Delivers the frames waiting on `bus` to every device, then sends what each device has to send
/// at `now_ns`. The devices share the one attachment, so they do not hear each other (none of
/// them needs to). Returns the number of frames sent.
pub fn service_devices<B: CanBus + ?Sized>(
    devices: &mut [&mut dyn CanopenDevice],
    bus: &mut B,
    now_ns: u64,
) -> Result<usize, LinkError> {
    for _ in 0..MAX_FRAMES_PER_SERVICE {
        let Some(frame) = bus.recv(std::time::Duration::ZERO)? else { break };
        for device in devices.iter_mut() {
            device.on_frame(&frame, now_ns);
        }
    }
    let mut sent = 0;
    for device in devices.iter_mut() {
        for frame in device.tick(now_ns) {
            bus.send(&frame)?;
            sent += 1;
        }
    }
    Ok(sent)
}

/// The error register (object 0x1001) that goes with an error code: bit 0 for any error, plus the
/// class bit of the code's CiA 301 group.
fn error_register(code: u16) -> u8 {
    if code == 0 {
        return 0;
    }
    let class = match code >> 12 {
        0x2 => 0x02,
        0x3 => 0x04,
        0x4 => 0x08,
        0x8 => 0x10,
        _ => 0,
    };
    0x01 | class
}

/// What every device shares: NMT, heartbeat, SDO server, EMCY, silence.
#[derive(Debug, Clone)]
struct DeviceCore {
    config: DeviceConfig,
    /// `BootUp` while initialising: the boot-up message is sent at the next tick.
    state: NmtState,
    heartbeat_ms: u16,
    next_heartbeat_ns: Option<u64>,
    silent: bool,
    fault: Option<u16>,
    /// The fault state last announced by EMCY, so each change is sent once.
    announced_fault: Option<u16>,
    outbox: Vec<CanFrame>,
}

impl DeviceCore {
    fn new(config: DeviceConfig) -> Self {
        DeviceCore {
            config,
            state: NmtState::BootUp,
            heartbeat_ms: config.heartbeat_ms,
            next_heartbeat_ns: None,
            silent: false,
            fault: None,
            announced_fault: None,
            outbox: Vec::new(),
        }
    }

    fn node(&self) -> NodeId {
        self.config.node
    }

    fn send(&mut self, message: CanopenMessage) {
        self.outbox.push(message.encode());
    }

    fn reboot(&mut self) {
        self.state = NmtState::BootUp;
        self.heartbeat_ms = self.config.heartbeat_ms;
        self.next_heartbeat_ns = None;
        self.outbox.clear();
        // A booting device has announced nothing yet: a fault still present is sent again.
        self.announced_fault = None;
    }

    /// Applies the message if it is an NMT command or SDO request for this node; returns the
    /// message back if the device itself has to look at it.
    fn on_message(&mut self, message: CanopenMessage) -> Option<CanopenMessage> {
        if self.silent {
            return None;
        }
        match message {
            CanopenMessage::Nmt { command, target } if target.addresses(self.node()) => {
                // A device still initialising does not take NMT commands yet.
                if self.state != NmtState::BootUp {
                    self.apply_nmt(command);
                }
                None
            }
            CanopenMessage::SdoRequest { node, request } if node == self.node() => {
                let answers = matches!(self.state, NmtState::PreOperational | NmtState::Operational);
                if answers && let Some(response) = self.serve_sdo(request) {
                    self.send(CanopenMessage::SdoResponse { node, response });
                }
                None
            }
            other => Some(other),
        }
    }

    fn apply_nmt(&mut self, command: NmtCommand) {
        match command {
            NmtCommand::Start => self.state = NmtState::Operational,
            NmtCommand::Stop => self.state = NmtState::Stopped,
            NmtCommand::EnterPreOperational => self.state = NmtState::PreOperational,
            NmtCommand::ResetNode | NmtCommand::ResetCommunication => self.reboot(),
        }
    }

    /// The answer to an SDO request; `None` for an abort from the client (it is not answered).
    fn serve_sdo(&mut self, request: SdoRequest) -> Option<SdoResponse> {
        let abort = |index, subindex, code| Some(SdoResponse::Abort { index, subindex, code });
        match request {
            SdoRequest::Upload { index, subindex } => match self.read_object(index, subindex) {
                Ok(data) => Some(SdoResponse::Upload { index, subindex, data }),
                Err(code) => abort(index, subindex, code),
            },
            SdoRequest::Download { index, subindex, data } => match self.write_object(index, subindex, data) {
                Ok(()) => Some(SdoResponse::DownloadAck { index, subindex }),
                Err(code) => abort(index, subindex, code),
            },
            SdoRequest::Abort { .. } => None,
            SdoRequest::Unsupported(bytes) => {
                let [_, i0, i1, subindex, ..] = bytes;
                abort(u16::from_le_bytes([i0, i1]), subindex, abort_code::COMMAND_UNKNOWN)
            }
        }
    }

    fn read_object(&self, index: u16, subindex: u8) -> Result<SdoData, u32> {
        match (index, subindex) {
            (OBJECT_DEVICE_TYPE, 0) => Ok(SdoData::from_u32(self.config.device_type)),
            (OBJECT_ERROR_REGISTER, 0) => Ok(SdoData::from_u8(error_register(self.fault.unwrap_or(0)))),
            (OBJECT_HEARTBEAT, 0) => Ok(SdoData::from_u16(self.heartbeat_ms)),
            // Sub 0 of a record is its highest sub-index.
            (OBJECT_IDENTITY, 0) => Ok(SdoData::from_u8(1)),
            (OBJECT_IDENTITY, 1) => Ok(SdoData::from_u32(self.config.vendor_id)),
            (OBJECT_DEVICE_TYPE | OBJECT_ERROR_REGISTER | OBJECT_HEARTBEAT | OBJECT_IDENTITY, _) => {
                Err(abort_code::NO_SUBINDEX)
            }
            _ => Err(abort_code::NO_OBJECT),
        }
    }

    fn write_object(&mut self, index: u16, subindex: u8, data: SdoData) -> Result<(), u32> {
        match (index, subindex) {
            (OBJECT_HEARTBEAT, 0) => {
                let &[b0, b1] = data.as_slice() else { return Err(abort_code::LENGTH_MISMATCH) };
                self.heartbeat_ms = u16::from_le_bytes([b0, b1]);
                // The new period counts from now (set at the next tick), not from the last beat.
                self.next_heartbeat_ns = None;
                Ok(())
            }
            (OBJECT_DEVICE_TYPE | OBJECT_ERROR_REGISTER, 0) | (OBJECT_IDENTITY, 0 | 1) => Err(abort_code::READ_ONLY),
            (OBJECT_DEVICE_TYPE | OBJECT_ERROR_REGISTER | OBJECT_HEARTBEAT | OBJECT_IDENTITY, _) => {
                Err(abort_code::NO_SUBINDEX)
            }
            _ => Err(abort_code::NO_OBJECT),
        }
    }

    /// Boot-up, EMCY and heartbeat due at `now_ns`, then whatever `on_frame` queued.
    fn tick(&mut self, now_ns: u64) -> Vec<CanFrame> {
        if self.silent {
            return Vec::new();
        }
        // Most ticks send nothing, and an empty Vec does not allocate.
        let mut frames = Vec::new();
        let node = self.node();
        if self.state == NmtState::BootUp {
            frames.push(CanopenMessage::Heartbeat { node, state: NmtState::BootUp }.encode());
            self.state = NmtState::PreOperational;
        }
        // CiA 301 allows EMCY in pre-operational and operational only.
        if self.fault != self.announced_fault && self.state != NmtState::Stopped {
            let error_code = self.fault.unwrap_or(0);
            let emergency = Emergency { error_code, error_register: error_register(error_code), manufacturer: [0; 5] };
            frames.push(CanopenMessage::Emergency { node, emergency }.encode());
            self.announced_fault = self.fault;
        }
        if self.heartbeat_ms > 0 {
            let period_ns = u64::from(self.heartbeat_ms) * 1_000_000;
            match self.next_heartbeat_ns {
                None => self.next_heartbeat_ns = Some(now_ns.saturating_add(period_ns)),
                Some(due) if now_ns >= due => {
                    frames.push(CanopenMessage::Heartbeat { node, state: self.state }.encode());
                    // Keep the period's phase, but never send a burst to catch up after a stall.
                    let next = due.saturating_add(period_ns);
                    self.next_heartbeat_ns = Some(if next <= now_ns { now_ns.saturating_add(period_ns) } else { next });
                }
                Some(_) => {}
            }
        }
        frames.append(&mut self.outbox);
        frames
    }

    fn set_silent(&mut self, silent: bool) {
        if self.silent && !silent {
            self.reboot();
        }
        if silent {
            self.outbox.clear();
        }
        self.silent = silent;
    }
}

/// Configuration of an emulated wheel drive.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WheelDriveConfig {
    pub device: DeviceConfig,
    /// Encoder counts per wheel revolution.
    pub counts_per_rev: u32,
}

/// The default wheel drive node ids, in the wheel order front-left, front-right, rear-left,
/// rear-right.
pub const WHEEL_DRIVE_NODES: [NodeId; 4] =
    [NodeId::from_const(0x11), NodeId::from_const(0x12), NodeId::from_const(0x13), NodeId::from_const(0x14)];

/// Default encoder resolution: a 1024-line quadrature encoder on the motor (4096 counts per motor
/// revolution) behind a 100:1 gear, typical of brushless hub drives of rovers of the LRU's size (our
/// assumption). 409 600 counts per wheel revolution: at 1 m/s on a 0.1 m wheel (1.6 rev/s) that is
/// 650 000 counts/s, so the i32 position wraps after about an hour of driving in one direction,
/// which is why every consumer takes wrap-safe differences.
pub const DEFAULT_COUNTS_PER_REV: u32 = 4096 * 100;

impl WheelDriveConfig {
    pub fn new(node: NodeId) -> Self {
        WheelDriveConfig {
            device: DeviceConfig::new(node, DEVICE_TYPE_CIA402_SERVO),
            counts_per_rev: DEFAULT_COUNTS_PER_REV,
        }
    }
}

/// An emulated wheel drive. On every SYNC while operational it sends TPDO1: encoder position
/// (i32 LE, counts, wrapping) and velocity (i32 LE, counts/s), both sampled at the SYNC.
#[derive(Debug, Clone)]
pub struct WheelDriveNode {
    core: DeviceCore,
    counts_per_rev: u32,
    speed_radps: f64,
    /// Whole counts (wrapping) and the fraction not yet counted, so no precision is lost over
    /// long runs as it would be in one growing float.
    position_counts: i64,
    fraction_counts: f64,
    clock_ns: Option<u64>,
}

impl WheelDriveNode {
    /// A drive with the default configuration at `node`.
    pub fn new(node: NodeId) -> Self {
        Self::with_config(WheelDriveConfig::new(node))
    }

    pub fn with_config(config: WheelDriveConfig) -> Self {
        WheelDriveNode {
            core: DeviceCore::new(config.device),
            counts_per_rev: config.counts_per_rev,
            speed_radps: 0.0,
            position_counts: 0,
            fraction_counts: 0.0,
            clock_ns: None,
        }
    }

    /// The wheel's speed from the node's last clock time on (the last `on_frame` or `tick`).
    /// A non-finite speed stops the wheel, as a drive would refuse a garbage set point.
    pub fn set_wheel_speed(&mut self, speed_radps: f64) {
        self.speed_radps = if speed_radps.is_finite() { speed_radps } else { 0.0 };
    }

    pub fn wheel_speed_radps(&self) -> f64 {
        self.speed_radps
    }

    /// The encoder position as the drive reports it (wraps at the i32 range).
    pub fn position_counts(&self) -> i32 {
        self.position_counts as i32
    }

    /// The velocity as the drive reports it, rounded and saturated to i32.
    pub fn velocity_counts_per_s(&self) -> i32 {
        (self.speed_radps * f64::from(self.counts_per_rev) / TAU).round() as i32
    }

    pub fn counts_per_rev(&self) -> u32 {
        self.counts_per_rev
    }

    fn advance(&mut self, now_ns: u64) {
        if let Some(last_ns) = self.clock_ns
            && now_ns > last_ns
        {
            let dt_s = (now_ns - last_ns) as f64 * 1e-9;
            self.fraction_counts += self.speed_radps * f64::from(self.counts_per_rev) / TAU * dt_s;
            let whole = self.fraction_counts.floor();
            self.fraction_counts -= whole;
            self.position_counts = self.position_counts.wrapping_add(whole as i64);
        }
        self.clock_ns = Some(self.clock_ns.map_or(now_ns, |last_ns| last_ns.max(now_ns)));
    }
}

impl CanopenDevice for WheelDriveNode {
    fn node(&self) -> NodeId {
        self.core.node()
    }

    fn nmt_state(&self) -> NmtState {
        self.core.state
    }

    fn on_frame(&mut self, frame: &CanFrame, now_ns: u64) {
        self.advance(now_ns);
        let Ok(message) = CanopenMessage::decode(frame) else { return };
        if let Some(CanopenMessage::Sync { .. }) = self.core.on_message(message)
            && self.core.state == NmtState::Operational
        {
            let data = PdoData::from_i32_pair(self.position_counts(), self.velocity_counts_per_s());
            self.core.send(CanopenMessage::Tpdo { node: self.node(), number: PdoNumber::Pdo1, data });
        }
    }

    fn tick(&mut self, now_ns: u64) -> Vec<CanFrame> {
        self.advance(now_ns);
        self.core.tick(now_ns)
    }

    fn set_silent(&mut self, silent: bool) {
        self.core.set_silent(silent);
    }

    fn set_fault(&mut self, code: Option<u16>) {
        self.core.fault = code;
    }
}

/// The default pan-tilt head node id.
pub const PAN_TILT_NODE: NodeId = NodeId::from_const(0x20);

/// Angles in the head's PDOs are i32 micro-radians: ±π is ±3 141 593, far inside the i32 range,
/// and 1 µrad is 1 µm at 1 m, well below what the head's mechanics can hold.
pub const MICRORAD_PER_RAD: f64 = 1e6;

/// Configuration of an emulated pan-tilt head.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PanTiltConfig {
    pub device: DeviceConfig,
    /// Fastest motion of each axis.
    pub rate_limit_radps: f64,
    /// Mechanical limits: targets beyond ±limit are clamped.
    pub pan_limit_rad: f64,
    pub tilt_limit_rad: f64,
}

impl PanTiltConfig {
    /// 1 rad/s per axis; the LRU head's limits (±π pan, ±π/2 tilt, as `sensor::PanTiltHead::lru`).
    pub fn new(node: NodeId) -> Self {
        PanTiltConfig {
            device: DeviceConfig::new(node, DEVICE_TYPE_NO_PROFILE),
            rate_limit_radps: 1.0,
            pan_limit_rad: PI,
            tilt_limit_rad: FRAC_PI_2,
        }
    }
}

/// An emulated pan-tilt head: RPDO1 = target pan and tilt, TPDO1 on SYNC = current pan and tilt,
/// each i32 LE micro-radians ([`MICRORAD_PER_RAD`]). Each axis moves toward its target at the
/// rate limit.
#[derive(Debug, Clone)]
pub struct PanTiltNode {
    core: DeviceCore,
    config: PanTiltConfig,
    pan_rad: f64,
    tilt_rad: f64,
    target_pan_rad: f64,
    target_tilt_rad: f64,
    clock_ns: Option<u64>,
}

/// Micro-radians of an angle, rounded and saturated to i32.
pub fn angle_to_microrad(angle_rad: f64) -> i32 {
    (angle_rad * MICRORAD_PER_RAD).round() as i32
}

pub fn microrad_to_angle(angle_microrad: i32) -> f64 {
    f64::from(angle_microrad) / MICRORAD_PER_RAD
}

fn clamp_angle(angle_rad: f64, limit_rad: f64) -> f64 {
    angle_rad.clamp(-limit_rad.abs(), limit_rad.abs())
}

fn step_toward(current: f64, target: f64, max_step: f64) -> f64 {
    current + (target - current).clamp(-max_step, max_step)
}

impl PanTiltNode {
    pub fn new(node: NodeId) -> Self {
        Self::with_config(PanTiltConfig::new(node))
    }

    pub fn with_config(config: PanTiltConfig) -> Self {
        PanTiltNode {
            core: DeviceCore::new(config.device),
            config,
            pan_rad: 0.0,
            tilt_rad: 0.0,
            target_pan_rad: 0.0,
            target_tilt_rad: 0.0,
            clock_ns: None,
        }
    }

    pub fn pan_rad(&self) -> f64 {
        self.pan_rad
    }

    pub fn tilt_rad(&self) -> f64 {
        self.tilt_rad
    }

    /// The target (after clamping to the limits).
    pub fn target_rad(&self) -> (f64, f64) {
        (self.target_pan_rad, self.target_tilt_rad)
    }

    /// Places the joints where a simulated head is (clamped to the limits) and makes that the
    /// target: the HIL harness's head follows the simulator's script, not the bus's commands.
    pub fn set_joint_angles(&mut self, pan_rad: f64, tilt_rad: f64) {
        self.pan_rad = clamp_angle(pan_rad, self.config.pan_limit_rad);
        self.tilt_rad = clamp_angle(tilt_rad, self.config.tilt_limit_rad);
        self.target_pan_rad = self.pan_rad;
        self.target_tilt_rad = self.tilt_rad;
    }

    fn advance(&mut self, now_ns: u64) {
        if let Some(last_ns) = self.clock_ns
            && now_ns > last_ns
        {
            let max_step = self.config.rate_limit_radps.abs() * (now_ns - last_ns) as f64 * 1e-9;
            self.pan_rad = step_toward(self.pan_rad, self.target_pan_rad, max_step);
            self.tilt_rad = step_toward(self.tilt_rad, self.target_tilt_rad, max_step);
        }
        self.clock_ns = Some(self.clock_ns.map_or(now_ns, |last_ns| last_ns.max(now_ns)));
    }
}

impl CanopenDevice for PanTiltNode {
    fn node(&self) -> NodeId {
        self.core.node()
    }

    fn nmt_state(&self) -> NmtState {
        self.core.state
    }

    fn on_frame(&mut self, frame: &CanFrame, now_ns: u64) {
        self.advance(now_ns);
        let Ok(message) = CanopenMessage::decode(frame) else { return };
        let operational = self.core.state == NmtState::Operational;
        match self.core.on_message(message) {
            Some(CanopenMessage::Sync { .. }) if operational => {
                let data = PdoData::from_i32_pair(angle_to_microrad(self.pan_rad), angle_to_microrad(self.tilt_rad));
                self.core.send(CanopenMessage::Tpdo { node: self.node(), number: PdoNumber::Pdo1, data });
            }
            Some(CanopenMessage::Rpdo { node, number: PdoNumber::Pdo1, data })
                if operational && node == self.node() =>
            {
                // A PDO of the wrong length is ignored, as CiA 301 has devices do (they may send EMCY 0x8210).
                if let Some((pan_microrad, tilt_microrad)) = data.i32_pair() {
                    self.target_pan_rad = clamp_angle(microrad_to_angle(pan_microrad), self.config.pan_limit_rad);
                    self.target_tilt_rad = clamp_angle(microrad_to_angle(tilt_microrad), self.config.tilt_limit_rad);
                }
            }
            _ => {}
        }
    }

    fn tick(&mut self, now_ns: u64) -> Vec<CanFrame> {
        self.advance(now_ns);
        self.core.tick(now_ns)
    }

    fn set_silent(&mut self, silent: bool) {
        self.core.set_silent(silent);
    }

    fn set_fault(&mut self, code: Option<u16>) {
        self.core.fault = code;
    }
}
