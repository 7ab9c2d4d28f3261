//! The rover's devices as the driver's live sensor source (`driver.kind = "devices"`).
//!
//! - **IMU**: an Xsens MTi over a serial port (`hal::xsens::XsensImu`): configured at start
//!   (rate of turn, acceleration, SampleTimeFine, packet counter at the IMU rate), each sample
//!   stamped with the device's clock mapped onto the host's (`hal::xsens::stamp`), so the USB and
//!   scheduling jitter of its arrival does not reach the filter.
//! - **Wheels and head**: CANopen (`hal::canopen::CanopenMaster`) over the configured CAN
//!   interface (SocketCAN or an SLCAN adapter): SYNC at `sync_period_ms`, one wheel odometry
//!   sample per two complete SYNC cycles' encoder positions (skid-steer kinematics), stamped at
//!   the middle of the interval the positions span (the twist is that interval's mean).
//! - **Cameras** are not read here: they publish their pairs on the robot's bus themselves.
//!
//! Each device has its own thread. A device that disappears (a serial port that hangs up, a CAN
//! interface that errors, a drive whose heartbeat stops) is marked unavailable
//! ([`SensorSource::device_health`]), logged once with the reason, and reopened every
//! [`REOPEN_PERIOD`] until it is back; the driver goes on publishing what the others deliver,
//! and the filter propagates through the gap. Stamps are the host's `CLOCK_MONOTONIC`. Samples
//! go to the driver as they arrive: each device's stream is in stamp order, the streams are not
//! with each other (a wheel sample stamped mid-interval arrives after IMU samples stamped later),
//! and nothing waits to sort them: the driver keeps each kind's order, the bus's readers merge by
//! stamp, and the filter applies wheel odometry on arrival.

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TrySendError};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::JoinHandle;
use std::time::Duration;

use hal::can::interface::CanInterface;
use hal::canopen::{CanopenMaster, MasterConfig, MasterEvent, NodeId, SkidSteerKinematics, WheelEncoders};
use hal::sensor::{
    DeviceHealth, DeviceStatus, HeadTarget, SensorError, SensorEvent, SensorSource, StereoCalibration, WheelOdomSample,
};
use hal::xsens::XsensImu;
use nalgebra::Vector3;

use super::SensorSetupError;
use crate::config::DevicesConfig;
use crate::process::monotonic_ns;

/// Samples in flight from the device threads to the driver (5 s of IMU and wheels): a stalled
/// driver cannot grow memory; beyond, samples are dropped.
const CHANNEL_CAPACITY: usize = 1024;
/// A lost device is reopened this often.
pub const REOPEN_PERIOD: Duration = Duration::from_millis(200);
/// The IMU counts as lost after this long without a sample (40 periods at 200 Hz).
const IMU_SILENCE: Duration = Duration::from_millis(200);
/// A line silent this long is closed and reopened, the device configured again: a hung-up
/// serial port does not always fail its reads (a pty whose other end closed only times out), and
/// a device that lost power needs its configuration again anyway.
const IMU_REOPEN_AFTER: Duration = Duration::from_millis(600);
/// The claimed noise of the wheel odometry (as `sim::wheel` claims it): white noise per sample
/// plus a part proportional to the measured speed for slip and scale; the unobserved components
/// (lateral and vertical speed, roll and pitch rate) get a large sigma.
const WHEEL_SPEED_NOISE_MPS: f64 = 0.005;
const WHEEL_YAW_RATE_NOISE_RADPS: f64 = 0.005;
const WHEEL_UNOBSERVED_SIGMA: f64 = 0.5;
const MIN_SIGMA: f64 = 1e-3;

/// Device changes kept for the driver's report (the oldest are dropped).
const DEVICE_LOG_LINES: usize = 256;

/// Health as the device threads update it, and the log of its changes (`CLOCK_MONOTONIC`, line).
#[derive(Debug, Default)]
struct SharedHealth(Mutex<(DeviceHealth, VecDeque<(u64, String)>)>);

impl SharedHealth {
    fn update(&self, f: impl FnOnce(&mut DeviceHealth, &mut VecDeque<(u64, String)>)) {
        let mut guard = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        let (health, log) = &mut *guard;
        f(health, log);
        while log.len() > DEVICE_LOG_LINES {
            log.pop_front();
        }
    }

    fn get(&self) -> DeviceHealth {
        self.0.lock().unwrap_or_else(PoisonError::into_inner).0
    }

    fn log(&self) -> Vec<(u64, String)> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner).1.iter().cloned().collect()
    }
}

/// Marks a device available or not; logs (standard error and the device log) and counts a change.
fn set_available(
    status: &mut DeviceStatus,
    available: bool,
    name: &str,
    reason: &str,
    log: &mut VecDeque<(u64, String)>,
) {
    if status.available == available {
        return;
    }
    let line = if available {
        format!("{name} available")
    } else {
        status.dropouts += 1;
        format!("{name} unavailable: {reason}")
    };
    eprintln!("driver: {line}");
    log.push_back((monotonic_ns(), line));
    status.available = available;
}

/// The live source over the rover's devices (module documentation).
pub struct DevicesSource {
    events: Receiver<SensorEvent>,
    /// The newest gaze target (pan, tilt) for the CAN thread to send; only the newest counts.
    head_target: Arc<Mutex<Option<(f64, f64)>>>,
    has_head: bool,
    health: Arc<SharedHealth>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
}

impl std::fmt::Debug for DevicesSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DevicesSource").field("health", &self.health.get()).finish_non_exhaustive()
    }
}

impl DevicesSource {
    /// Starts the device threads. The IMU is opened and configured here, so a wrong port or a
    /// silent device stops the driver at start with the reason; later losses are survived.
    pub fn open(config: &DevicesConfig, imu_rate_hz: f64) -> Result<DevicesSource, SensorSetupError> {
        let interface: CanInterface = config
            .can_interface
            .parse()
            .map_err(|e| SensorSetupError::Invalid(format!("driver.devices.can_interface: {e}")))?;
        let master_config = master_config(config)?;
        let rate_hz = imu_rate_hz.round().clamp(1.0, 2000.0) as u16;
        let imu = open_imu(&config.imu_port, config.imu_baud, rate_hz)
            .map_err(|e| SensorSetupError::Invalid(format!("IMU {}: {e}", config.imu_port)))?;
        let bus =
            interface.open().map_err(|e| SensorSetupError::Invalid(format!("CAN {}: {e}", config.can_interface)))?;

        let (sender, events) = mpsc::sync_channel(CHANNEL_CAPACITY);
        let health = Arc::new(SharedHealth::default());
        health.update(|h, _| {
            h.imu.available = true;
            h.wheels.available = false;
            h.head.available = false;
        });
        let stop = Arc::new(AtomicBool::new(false));
        let head_target = Arc::new(Mutex::new(None));
        let has_head = master_config.head.is_some();
        let mut threads = Vec::new();
        let imu_thread = ImuThread {
            port: config.imu_port.clone(),
            baud: config.imu_baud,
            rate_hz,
            sender: sender.clone(),
            health: Arc::clone(&health),
            stop: Arc::clone(&stop),
        };
        threads.push(spawn("driver-imu", move || imu_thread.run(imu))?);
        let can_thread = CanThread {
            interface,
            master_config,
            kinematics: SkidSteerKinematics {
                wheel_radius_m: config.wheel_radius_m,
                track_width_m: config.track_width_m,
                counts_per_rev: config.counts_per_rev,
            },
            relative_sigma: config.wheel_relative_sigma,
            sender,
            head_target: Arc::clone(&head_target),
            health: Arc::clone(&health),
            stop: Arc::clone(&stop),
        };
        threads.push(spawn("driver-can", move || can_thread.run(bus))?);
        Ok(DevicesSource { events, head_target, has_head, health, stop, threads })
    }
}

impl Drop for DevicesSource {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for thread in self.threads.drain(..) {
            // A thread that panicked has nothing left to release.
            let _ = thread.join();
        }
    }
}

fn spawn(name: &str, body: impl FnOnce() + Send + 'static) -> Result<JoinHandle<()>, SensorSetupError> {
    std::thread::Builder::new()
        .name(name.to_owned())
        .spawn(body)
        .map_err(|e| SensorSetupError::Invalid(format!("cannot start thread {name}: {e}")))
}

fn master_config(config: &DevicesConfig) -> Result<MasterConfig, SensorSetupError> {
    let node = |id: u8| {
        NodeId::new(id).ok_or_else(|| SensorSetupError::Invalid(format!("CANopen node id {id}: expected 1..=127")))
    };
    let mut drives = [node(config.wheel_nodes[0])?; 4];
    for (drive, id) in drives.iter_mut().zip(config.wheel_nodes) {
        *drive = node(id)?;
    }
    Ok(MasterConfig {
        drives,
        head: config.head_node.map(node).transpose()?,
        sync_period_ns: u64::from(config.sync_period_ms) * 1_000_000,
        heartbeat_consumer_ns: u64::from(config.heartbeat_timeout_ms) * 1_000_000,
        ..MasterConfig::default()
    })
}

fn open_imu(
    port: &str,
    baud: u32,
    rate_hz: u16,
) -> Result<XsensImu<Box<dyn serialport::SerialPort>>, hal::xsens::XsensError> {
    let mut imu = XsensImu::open(port, baud)?.with_clock(Box::new(monotonic_ns));
    imu.configure(rate_hz)?;
    Ok(imu)
}

/// Hands a sample to the driver; a full channel (a stalled driver) drops it.
fn deliver(sender: &SyncSender<SensorEvent>, event: SensorEvent) -> bool {
    match sender.try_send(event) {
        Ok(()) | Err(TrySendError::Full(_)) => true,
        Err(TrySendError::Disconnected(_)) => false,
    }
}

struct ImuThread {
    port: String,
    baud: u32,
    rate_hz: u16,
    sender: SyncSender<SensorEvent>,
    health: Arc<SharedHealth>,
    stop: Arc<AtomicBool>,
}

impl ImuThread {
    fn run(self, mut imu: XsensImu<Box<dyn serialport::SerialPort>>) {
        let mut errors_seen = 0u64;
        while !self.stop.load(Ordering::Relaxed) {
            let reason = self.stream(&mut imu, &mut errors_seen);
            self.health.update(|h, log| set_available(&mut h.imu, false, "IMU", &reason, log));
            // Reopen until the device is back (a replugged adapter, a restarted IMU).
            loop {
                if self.stop.load(Ordering::Relaxed) {
                    return;
                }
                std::thread::sleep(REOPEN_PERIOD);
                match open_imu(&self.port, self.baud, self.rate_hz) {
                    Ok(reopened) => {
                        imu = reopened;
                        errors_seen = 0;
                        break;
                    }
                    Err(_) => continue,
                }
            }
        }
    }

    /// Streams until the device is lost; returns why.
    fn stream(&self, imu: &mut XsensImu<Box<dyn serialport::SerialPort>>, errors_seen: &mut u64) -> String {
        // Silence counts only once the device streams: a configured IMU waits for the rover's
        // start as long as it takes.
        let mut last_sample_ns = None;
        while !self.stop.load(Ordering::Relaxed) {
            match imu.next_sample(Duration::from_millis(20)) {
                Ok(Some(reading)) => {
                    last_sample_ns = Some(monotonic_ns());
                    let counters = imu.counters();
                    let errors = counters.xbus.checksum_errors + counters.malformed;
                    self.health.update(|h, log| {
                        set_available(&mut h.imu, true, "IMU", "", log);
                        h.imu.samples += 1;
                        h.imu.errors += errors.saturating_sub(*errors_seen);
                    });
                    *errors_seen = errors;
                    if !deliver(&self.sender, SensorEvent::Imu(reading.sample)) {
                        return "the driver is gone".into();
                    }
                }
                Ok(None) => {
                    let Some(last_ns) = last_sample_ns else { continue };
                    let silent_ns = monotonic_ns().saturating_sub(last_ns);
                    if silent_ns > IMU_REOPEN_AFTER.as_nanos() as u64 {
                        return format!("no sample for {} ms", silent_ns / 1_000_000);
                    }
                    if silent_ns > IMU_SILENCE.as_nanos() as u64 {
                        self.health.update(|h, log| {
                            let reason = format!("no sample for {} ms", silent_ns / 1_000_000);
                            set_available(&mut h.imu, false, "IMU", &reason, log)
                        });
                    }
                }
                Err(e) => return e.to_string(),
            }
        }
        "stopped".into()
    }
}

struct CanThread {
    interface: CanInterface,
    master_config: MasterConfig,
    kinematics: SkidSteerKinematics,
    relative_sigma: f64,
    sender: SyncSender<SensorEvent>,
    head_target: Arc<Mutex<Option<(f64, f64)>>>,
    health: Arc<SharedHealth>,
    stop: Arc<AtomicBool>,
}

impl CanThread {
    fn run(self, mut bus: Box<dyn hal::can::CanBus>) {
        while !self.stop.load(Ordering::Relaxed) {
            let reason = match CanopenMaster::new(self.master_config) {
                Ok(mut master) => self.serve(&mut master, bus.as_mut()),
                Err(e) => {
                    eprintln!("driver: CANopen master: {e}");
                    return;
                }
            };
            self.health.update(|h, log| {
                set_available(&mut h.wheels, false, "wheels", &reason, log);
                set_available(&mut h.head, false, "head", &reason, log);
            });
            loop {
                if self.stop.load(Ordering::Relaxed) {
                    return;
                }
                std::thread::sleep(REOPEN_PERIOD);
                if let Ok(reopened) = self.interface.open() {
                    bus = reopened;
                    break;
                }
            }
        }
    }

    /// Runs the master until the bus fails; returns why.
    fn serve(&self, master: &mut CanopenMaster, bus: &mut dyn hal::can::CanBus) -> String {
        let mut previous: Option<WheelEncoders> = None;
        let mut last_head_ns = None;
        let mut last_cycle_ns = monotonic_ns();
        // As long as a drive's heartbeat may be late: a loaded board (or a loaded HIL machine)
        // delays a cycle by tens of milliseconds without anything being lost.
        let cycle_silence_ns = self.master_config.heartbeat_consumer_ns;
        while !self.stop.load(Ordering::Relaxed) {
            let now_ns = monotonic_ns();
            if let Err(e) = master.tick(now_ns, bus) {
                return e.to_string();
            }
            for event in master.drain_events() {
                // An incomplete cycle is counted, not logged: without SYNC there is one every
                // period. Its consequence, no wheel odometry, is logged once below.
                if matches!(event, MasterEvent::CycleIncomplete { .. }) {
                    self.health.update(|h, _| h.wheels.errors += 1);
                    continue;
                }
                let line = format!("CANopen {event:?}");
                eprintln!("driver: {line}");
                self.health.update(|_, log| log.push_back((monotonic_ns(), line)));
            }
            // The gaze policy's newest target as RPDO1; the unit moves at its own joint rate.
            let target = self.head_target.lock().unwrap_or_else(PoisonError::into_inner).take();
            if let Some((pan_rad, tilt_rad)) = target
                && let Err(e) = master.command_head(pan_rad, tilt_rad, bus)
            {
                self.health.update(|h, log| {
                    h.head.errors += 1;
                    log.push_back((monotonic_ns(), format!("head command not sent: {e}")));
                });
            }
            if let Some(encoders) = master.take_encoders() {
                last_cycle_ns = now_ns;
                if let Some(sample) = previous.as_ref().and_then(|p| self.odometry(p, &encoders))
                    && !deliver(&self.sender, SensorEvent::WheelOdom(sample))
                {
                    return "the driver is gone".into();
                }
                previous = Some(encoders);
                self.health.update(|h, _| h.wheels.samples += 1);
            }
            let drives_up = self
                .master_config
                .drives
                .iter()
                .all(|&n| matches!(master.health(n), Some(hal::canopen::NodeHealth::Operational)));
            let cycles_flow = now_ns.saturating_sub(last_cycle_ns) <= cycle_silence_ns;
            let wheels_up = drives_up && cycles_flow;
            let wheels_reason =
                if drives_up { "no complete SYNC cycle (lost SYNC or PDOs)" } else { "a drive is missing or in fault" };
            let head_up = self
                .master_config
                .head
                .is_some_and(|n| matches!(master.health(n), Some(hal::canopen::NodeHealth::Operational)));
            self.health.update(|h, log| {
                set_available(&mut h.wheels, wheels_up, "wheels", wheels_reason, log);
                set_available(&mut h.head, head_up, "head", "the pan-tilt unit is missing or in fault", log);

                if let Some(angles) = master.head_angles()
                    && last_head_ns != Some(angles.stamp_ns)
                {
                    last_head_ns = Some(angles.stamp_ns);
                    h.head.samples += 1;
                }
            });
            if !wheels_up {
                // Positions across a drive's outage span an unknown interval: start over.
                previous = None;
            }
            let wait_ns = master.next_deadline_ns().map_or(1_000_000, |d| d.saturating_sub(monotonic_ns()));
            std::thread::sleep(Duration::from_nanos(wait_ns.clamp(100_000, 1_000_000)));
        }
        "stopped".into()
    }

    fn odometry(&self, previous: &WheelEncoders, current: &WheelEncoders) -> Option<WheelOdomSample> {
        let dt_s = current.stamp_ns.checked_sub(previous.stamp_ns)? as f64 * 1e-9;
        let (v_mps, omega_radps) = self.kinematics.twist_from_encoders(previous, current, dt_s)?;
        let relative = self.relative_sigma;
        Some(WheelOdomSample {
            stamp_ns: previous.stamp_ns + (current.stamp_ns - previous.stamp_ns) / 2,
            linear_mps: Vector3::new(v_mps, 0.0, 0.0),
            angular_radps: Vector3::new(0.0, 0.0, omega_radps),
            sigma: [
                (WHEEL_SPEED_NOISE_MPS + relative * v_mps.abs()).max(MIN_SIGMA),
                WHEEL_UNOBSERVED_SIGMA,
                WHEEL_UNOBSERVED_SIGMA,
                WHEEL_UNOBSERVED_SIGMA,
                WHEEL_UNOBSERVED_SIGMA,
                (WHEEL_YAW_RATE_NOISE_RADPS + relative * omega_radps.abs()).max(MIN_SIGMA),
            ],
        })
    }
}

impl SensorSource for DevicesSource {
    fn stereo_calibration(&self) -> Option<StereoCalibration> {
        None
    }

    fn next_event(&mut self) -> Result<Option<SensorEvent>, SensorError> {
        Ok(self.events.try_recv().ok())
    }

    fn read_stereo(&mut self, _left: &mut [u8], _right: &mut [u8]) -> Result<(), SensorError> {
        Err(SensorError::Source("the devices source has no cameras: they publish their pairs themselves".into()))
    }

    fn is_live(&self) -> bool {
        true
    }

    fn device_health(&self) -> Option<DeviceHealth> {
        Some(self.health.get())
    }

    fn device_log(&self) -> Vec<(u64, String)> {
        self.health.log()
    }

    /// Queued for the CAN thread, which sends it as the head's RPDO1 (a newer target replaces
    /// one not sent yet). The commanded rate is the unit's own: CiA 402 profile velocity is not
    /// configured by the firmware.
    fn command_head(&mut self, target: &HeadTarget) -> Result<bool, SensorError> {
        if !self.has_head {
            return Ok(false);
        }
        *self.head_target.lock().unwrap_or_else(PoisonError::into_inner) = Some((target.pan_rad, target.tilt_rad));
        Ok(true)
    }
}
