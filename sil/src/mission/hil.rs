//! Hardware-in-the-loop: the simulator plays a robot's devices at the far end of real serial
//! lines, and the unmodified firmware (`driver.kind = "devices"`) talks to them as to hardware.
//!
//! Per robot a [`DeviceBench`] holds
//! - an **Xsens MTi-10** (`hal::xsens::XsensDevice`) on a pseudo-terminal: it answers the
//!   firmware's configuration handshake and streams MTData2 at the simulated IMU's rate;
//! - the **CANopen nodes** (four wheel drives, the pan-tilt unit: `hal::canopen`) on an in-memory
//!   CAN bus behind an **SLCAN adapter** (`hal::can::slcan::SlcanAdapter`) on a second
//!   pseudo-terminal, which the firmware opens as `slcan:PATH@1000000`;
//! - the **cameras**, which publish their pairs on the robot's iceoryx2 bus themselves (a camera
//!   driver is out of scope), stamped in the robot's sensor time.
//!
//! The firmware opens each device by a stable path, `robotN/dev/imu` and `robotN/dev/can`:
//! symbolic links to the current pseudo-terminals, so that an unplugged device can come back
//! under the same name, as a USB adapter does under udev's by-id links.
//!
//! One pacer thread per robot reads the simulator's sensor stream (the same
//! `sil::sim_source::SimSources` source the in-memory runners use) and hands each event to its
//! device when the wall clock reaches the event's stamp past the mission's epoch: IMU samples to
//! the Xsens device, the wheel odometry's twist as wheel speeds to the drives (skid-steer
//! kinematics, `hal::canopen`), the head's angles to the pan-tilt unit, pairs to the bus.

use std::os::unix::fs::symlink;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc::{self, Receiver, RecvTimeoutError, SyncSender};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use hal::can::{CanBus, CanFrame, LoopbackCanBus, SlcanAdapter};
use hal::canopen::{CanopenDevice, PAN_TILT_NODE, PanTiltNode, WHEEL_DRIVE_NODES, WheelDriveNode, service_devices};
use hal::sensor::{ImuSample, SensorEvent, SensorSource};
use hal::xsens::XsensDevice;
use msgs::StereoHeader;
use onboard::bus::{Bus, ImageGeometry};
use onboard::config::{DevicesConfig, DriverKind, RoverConfig};
use onboard::nodes::{NodeError, Outbox};
use onboard::process::monotonic_ns;
use onboard::sensors::SourceProvider;
use onboard::topics::Topic;
use protocol::frame::can::CanKind;
use serialport::{SerialPort, TTYPort};

use super::MissionError;
use crate::sim_source::SimSources;

/// The SLCAN adapter's CAN bit rate (the firmware's `slcan:PATH@RATE`).
pub const CAN_BITRATE: u32 = 1_000_000;
/// Serial rate of the IMU line (a pty ignores it; the firmware's configuration carries it).
pub const IMU_BAUD: u32 = 921_600;
/// How often the device threads serve their lines.
const SERVICE_PERIOD: Duration = Duration::from_millis(1);

fn setup(e: impl std::fmt::Display) -> MissionError {
    MissionError::Setup(e.to_string())
}

/// A pseudo-terminal playing a device's serial line, reachable by a stable path.
#[derive(Debug)]
pub struct PtyLine {
    link: PathBuf,
    /// The firmware's end stays open here too, so that reads on the device's end do not fail
    /// with EIO while the firmware has not opened (or is reopening) it.
    slave: TTYPort,
}

impl PtyLine {
    /// A new pseudo-terminal pair; `link` becomes a symbolic link to its firmware end. Returns
    /// the device's end.
    pub fn open(link: &Path) -> Result<(PtyLine, TTYPort), MissionError> {
        let (master, slave) = TTYPort::pair().map_err(|e| setup(format!("pseudo-terminal: {e}")))?;
        let name = slave.name().ok_or_else(|| setup("the pseudo-terminal has no name"))?;
        let tmp = link.with_extension("new");
        if tmp.symlink_metadata().is_ok() {
            std::fs::remove_file(&tmp).map_err(|e| MissionError::Io { path: tmp.clone(), source: e })?;
        }
        symlink(&name, &tmp).map_err(|e| MissionError::Io { path: tmp.clone(), source: e })?;
        // A rename replaces the old link atomically: the firmware never sees no device file.
        std::fs::rename(&tmp, link).map_err(|e| MissionError::Io { path: link.to_owned(), source: e })?;
        Ok((PtyLine { link: link.to_owned(), slave }, master))
    }

    pub fn path(&self) -> &Path {
        &self.link
    }

    /// The pseudo-terminal the link points at now.
    pub fn device_name(&self) -> Option<String> {
        self.slave.name()
    }
}

/// Wheel speeds and head angles the pacer sets and the CAN thread's nodes report.
#[derive(Debug, Clone, Copy, Default)]
pub struct DeviceInputs {
    pub wheel_speeds_radps: [f64; 4],
    pub pan_rad: f64,
    pub tilt_rad: f64,
}

/// What the pacer hands to the devices: IMU samples to the Xsens thread, wheel speeds and head
/// angles to the CAN thread.
#[derive(Debug)]
struct Feeds {
    imu: SyncSender<ImuSample>,
    inputs: Arc<Mutex<DeviceInputs>>,
    /// Wheel speeds take effect this long before their sample's stamp.
    wheel_lead_ns: u64,
    /// The rover's wheels as the firmware is configured to see them ([`devices_config`]), so
    /// the drives turn as the firmware's odometry expects.
    kinematics: hal::canopen::SkidSteerKinematics,
}

/// Faults the harness can inject into a robot's devices while it runs.
#[derive(Debug, Default)]
pub struct DeviceFaults {
    /// The IMU's serial line is unplugged (its pseudo-terminal closed) while set; a new one
    /// appears under the same path when cleared.
    pub imu_unplugged: AtomicBool,
    /// The IMU line carries garbage and flipped bits while set ([`LineNoise`]).
    pub imu_noisy: AtomicBool,
    /// This wheel drive (index 0..4) falls silent while set (`u64::MAX`: none).
    pub silent_drive: AtomicU64,
    /// A node floods the CAN bus while set.
    pub babbling: AtomicBool,
    /// The firmware's SYNC frames do not reach the bus while set (the adapter drops them).
    pub sync_lost: AtomicBool,
}

/// One robot's emulated devices (module documentation).
#[derive(Debug)]
pub struct DeviceBench {
    pub imu_path: PathBuf,
    pub can_path: PathBuf,
    pub faults: Arc<DeviceFaults>,
    stop: Arc<AtomicBool>,
    epoch_ns: Arc<AtomicU64>,
    threads: Vec<JoinHandle<Result<(), String>>>,
}

/// The `[driver.devices]` table that points a robot's firmware at its bench.
pub fn devices_config(imu_path: &Path, can_path: &Path) -> DevicesConfig {
    DevicesConfig {
        imu_port: imu_path.display().to_string(),
        imu_baud: IMU_BAUD,
        can_interface: format!("slcan:{}@{CAN_BITRATE}", can_path.display()),
        ..DevicesConfig::default()
    }
}

impl DeviceBench {
    /// Starts robot `config`'s devices (`config.driver.kind = "sim"`: the simulated robot they
    /// play) under `dir/dev/`. They answer the firmware from now on; the sensor stream starts at
    /// [`DeviceBench::start`]'s epoch.
    pub fn open(config: &RoverConfig, dir: &Path, geometry: ImageGeometry) -> Result<DeviceBench, MissionError> {
        if config.driver.kind != DriverKind::Sim {
            return Err(setup("the device bench plays a simulated robot (driver.kind = \"sim\")"));
        }
        let dev = dir.join("dev");
        std::fs::create_dir_all(&dev).map_err(|e| MissionError::Io { path: dev.clone(), source: e })?;
        let imu_path = dev.join("imu");
        let can_path = dev.join("can");
        // Two copies of the deterministic simulated robot: the cameras render on their own
        // thread, so a slow frame never delays the IMU's stream (separate devices on a rover).
        let device_source = SimSources.open(config).map_err(setup)?;
        let camera_source = SimSources.open(config).map_err(setup)?;
        let imu_rate_hz = config.rates.imu_hz.round() as u32;
        let stop = Arc::new(AtomicBool::new(false));
        let epoch_ns = Arc::new(AtomicU64::new(0));
        let faults = Arc::new(DeviceFaults { silent_drive: AtomicU64::new(u64::MAX), ..DeviceFaults::default() });
        let (imu_sender, imu_samples) = mpsc::sync_channel(4096);
        let inputs = Arc::new(Mutex::new(DeviceInputs::default()));

        let (imu_line, imu_port) = PtyLine::open(&imu_path)?;
        let (can_line, can_port) = PtyLine::open(&can_path)?;
        let mut threads = Vec::new();
        let spawn = |name: String, body: Box<dyn FnOnce() -> Result<(), String> + Send>| {
            std::thread::Builder::new().name(name).spawn(body).map_err(setup)
        };
        {
            let (stop, faults) = (Arc::clone(&stop), Arc::clone(&faults));
            threads.push(spawn(
                format!("hil-imu-{}", config.robot.id),
                Box::new(move || imu_device(imu_line, imu_port, imu_samples, imu_rate_hz, &faults, &stop)),
            )?);
        }
        {
            let (stop, faults, inputs) = (Arc::clone(&stop), Arc::clone(&faults), Arc::clone(&inputs));
            threads.push(spawn(
                format!("hil-can-{}", config.robot.id),
                Box::new(move || can_devices(can_line, can_port, &inputs, &faults, &stop)),
            )?);
        }
        let camera_bus = Bus::open(config.robot.bus_id(), "hil_cameras", geometry).map_err(setup)?;
        let end_ns = config.driver.end_stamp_ns();
        {
            let (stop, epoch) = (Arc::clone(&stop), Arc::clone(&epoch_ns));
            // A wheel sample is the speed at its stamp: it takes effect up to half a period early
            // (as early as the stream's order allows), so the drives' encoder counts integrate
            // the motion around the stamp rather than after it.
            let wheel_lead_ns = (0.5e9 / config.rates.wheel_hz.max(1.0)) as u64;
            let wheels = devices_config(&imu_path, &can_path);
            let kinematics = hal::canopen::SkidSteerKinematics {
                wheel_radius_m: wheels.wheel_radius_m,
                track_width_m: wheels.track_width_m,
                counts_per_rev: wheels.counts_per_rev,
            };
            let feeds = Feeds { imu: imu_sender, inputs, wheel_lead_ns, kinematics };
            threads.push(spawn(
                format!("hil-pacer-{}", config.robot.id),
                Box::new(move || pace(device_source, Sink::Devices(feeds), end_ns, &epoch, &stop)),
            )?);
        }
        {
            let (stop, epoch) = (Arc::clone(&stop), Arc::clone(&epoch_ns));
            threads.push(spawn(
                format!("hil-cameras-{}", config.robot.id),
                Box::new(move || pace(camera_source, Sink::Cameras(camera_bus), end_ns, &epoch, &stop)),
            )?);
        }
        Ok(DeviceBench { imu_path, can_path, faults, stop, epoch_ns, threads })
    }

    /// Starts the sensor stream: sensor time 0 is `epoch_ns` on `CLOCK_MONOTONIC`.
    pub fn start(&self, epoch_ns: u64) {
        self.epoch_ns.store(epoch_ns.max(1), Ordering::Release);
    }

    /// Stops the devices; the first error a device thread met, if any.
    pub fn stop(mut self) -> Result<(), MissionError> {
        self.stop.store(true, Ordering::Relaxed);
        let mut first = Ok(());
        for thread in self.threads.drain(..) {
            let result = thread.join().map_err(|_| "a device thread panicked".to_owned()).and_then(|r| r);
            if let (Err(e), Ok(())) = (result, &first) {
                first = Err(MissionError::Process(format!("devices: {e}")));
            }
        }
        first
    }
}

/// Where a pacer's events go: the IMU, wheels and head, or the cameras.
enum Sink {
    Devices(Feeds),
    Cameras(Bus),
}

/// Waits for the epoch, then hands each event to its device when it is due. A camera pacer
/// renders only the pairs; a device pacer never reads a pair, so nothing is rendered for it.
fn pace(
    mut source: Box<dyn SensorSource + Send>,
    sink: Sink,
    end_ns: Option<u64>,
    epoch: &AtomicU64,
    stop: &AtomicBool,
) -> Result<(), String> {
    let (feeds, mut cameras) = match sink {
        Sink::Devices(feeds) => (Some(feeds), None),
        Sink::Cameras(bus) => (None, Some(bus.outbox(&[Topic::Stereo]).map_err(|e| e.to_string())?)),
    };
    let epoch_ns = loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(());
        }
        match epoch.load(Ordering::Acquire) {
            0 => std::thread::sleep(SERVICE_PERIOD),
            epoch_ns => break epoch_ns,
        }
    };
    while !stop.load(Ordering::Relaxed) {
        let Some(event) = source.next_event().map_err(|e| e.to_string())? else { return Ok(()) };
        let stamp_ns = event.stamp_ns();
        if end_ns.is_some_and(|end| stamp_ns > end) {
            return Ok(());
        }
        // The device pacer takes a pair's announcement for the head's angles, never its pixels.
        if matches!(event, SensorEvent::Imu(_) | SensorEvent::WheelOdom(_)) && feeds.is_none() {
            continue;
        }
        let lead_ns = match (&event, &feeds) {
            (SensorEvent::WheelOdom(_), Some(feeds)) => feeds.wheel_lead_ns,
            _ => 0,
        };
        // Due on the wall clock: sleep in short steps so a stop is seen.
        loop {
            let now_ns = monotonic_ns();
            let due_ns = (epoch_ns + stamp_ns).saturating_sub(lead_ns);
            if now_ns >= due_ns || stop.load(Ordering::Relaxed) {
                break;
            }
            std::thread::sleep(Duration::from_nanos((due_ns - now_ns).min(2_000_000)));
        }
        match (event, &feeds, &mut cameras) {
            (SensorEvent::Imu(sample), Some(feeds), _) => {
                // A full queue means the IMU thread is stuck on a dead line: the sample is lost,
                // as on a real line.
                let _ = feeds.imu.try_send(sample);
            }
            (SensorEvent::WheelOdom(sample), Some(feeds), _) => {
                let speeds = feeds.kinematics.wheel_speeds_from_twist(sample.linear_mps.x, sample.angular_radps.z);
                feeds.inputs.lock().unwrap_or_else(std::sync::PoisonError::into_inner).wheel_speeds_radps = speeds;
            }
            (SensorEvent::Stereo(info), Some(feeds), _) => {
                let mut inputs = feeds.inputs.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
                inputs.pan_rad = info.pan_rad;
                inputs.tilt_rad = info.tilt_rad;
            }
            (SensorEvent::Stereo(info), None, Some(cameras)) => {
                let header = StereoHeader {
                    stamp_ns,
                    sequence: info.sequence,
                    pan_rad: info.pan_rad,
                    tilt_rad: info.tilt_rad,
                    width_px: info.width_px,
                    height_px: info.height_px,
                };
                cameras
                    .publish_stereo_with(&header, &mut |bytes| {
                        let (left, right) = bytes.split_at_mut(bytes.len() / 2);
                        source
                            .read_stereo(left, right)
                            .map_err(|e| NodeError::Failed { node: "hil_cameras", reason: e.to_string() })
                    })
                    .map_err(|e| e.to_string())?;
            }
            _ => {}
        }
    }
    Ok(())
}

/// The emulated MTi-10's device id (MTi-10 series ids start with 0x01A).
const XSENS_DEVICE_ID: u32 = 0x01A0_0001;

/// Serves the IMU's line: the configuration handshake at any time, MTData2 for each sample the
/// pacer hands over, and the line's faults.
fn imu_device(
    line: PtyLine,
    port: TTYPort,
    samples: Receiver<ImuSample>,
    rate_hz: u32,
    faults: &DeviceFaults,
    stop: &AtomicBool,
) -> Result<(), String> {
    let path = line.path().to_owned();
    let mut plugged = Some((line, timed(port)?));
    let mut device = XsensDevice::new(XSENS_DEVICE_ID, rate_hz);
    let mut noise = LineNoise::new(0x1A);
    let mut frame = Vec::new();
    let mut packet_counter = 0u16;
    let mut lost_writes = 0u64;
    while !stop.load(Ordering::Relaxed) {
        let unplug = faults.imu_unplugged.load(Ordering::Relaxed);
        match (&mut plugged, unplug) {
            (Some(_), true) => {
                // Both ends of the pty close: the firmware's reads fail as on a pulled USB cable.
                plugged = None;
                eprintln!("hil: IMU {} unplugged", path.display());
            }
            (None, false) => {
                let (line, port) = PtyLine::open(&path).map_err(|e| e.to_string())?;
                eprintln!("hil: IMU {} plugged in as {}", path.display(), line.device_name().unwrap_or_default());
                plugged = Some((line, timed(port)?));
                // Powered up again: it wakes up measuring with its stored configuration.
                device = XsensDevice::measuring(XSENS_DEVICE_ID, rate_hz, device.outputs());
            }
            _ => {}
        }
        // The stream ends before the firmware stops: the device stays powered and answering
        // until the bench stops, as a rover's IMU does when the mission's data ends.
        let sample = match samples.recv_timeout(SERVICE_PERIOD) {
            Ok(sample) => Some(sample),
            Err(RecvTimeoutError::Timeout) => None,
            Err(RecvTimeoutError::Disconnected) => {
                std::thread::sleep(SERVICE_PERIOD);
                None
            }
        };
        let Some((_, port)) = &mut plugged else { continue };
        // A UART sends whether anyone listens: bytes a full line cannot take are lost (the
        // firmware has not opened the replugged line yet), never a reason for the device to stop.
        if device.poll_commands(port).is_err() {
            lost_writes += 1;
        }
        let Some(sample) = sample else { continue };
        // SampleTimeFine counts 10 kHz ticks of the device's clock: the simulator's time here.
        let sample_time_fine = (sample.stamp_ns / 100_000) as u32;
        frame.clear();
        if device.encode_sample(&sample, sample_time_fine, packet_counter, &mut frame) {
            packet_counter = packet_counter.wrapping_add(1);
            if faults.imu_noisy.load(Ordering::Relaxed) {
                noise.corrupt(&mut frame);
            }
            use std::io::Write;
            if port.write_all(&frame).is_err() {
                lost_writes += 1;
            }
        }
    }
    if lost_writes > 0 {
        eprintln!("hil: IMU {}: {lost_writes} writes lost on a line nobody read", path.display());
    }
    Ok(())
}

fn timed(mut port: TTYPort) -> Result<TTYPort, String> {
    port.set_timeout(Duration::from_micros(200)).map_err(|e| format!("pty timeout: {e}"))?;
    Ok(port)
}

/// Garbage and flipped bits on a serial line, deterministic for a seed: every third frame gets
/// one bit flipped, and every frame is followed by a few bytes of garbage that include the Xbus
/// preamble.
#[derive(Debug)]
struct LineNoise {
    state: u64,
    frames: u64,
    /// Bits flipped and garbage bytes written so far.
    pub flipped: u64,
    pub garbage: u64,
}

impl LineNoise {
    fn new(seed: u64) -> LineNoise {
        LineNoise { state: seed, frames: 0, flipped: 0, garbage: 0 }
    }

    fn next(&mut self) -> u64 {
        // SplitMix64: a test pattern, not statistics.
        self.state = self.state.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.state;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    fn corrupt(&mut self, frame: &mut Vec<u8>) {
        self.frames += 1;
        if self.frames.is_multiple_of(3) && !frame.is_empty() {
            let bit = (self.next() % (frame.len() as u64 * 8)) as usize;
            if let Some(byte) = frame.get_mut(bit / 8) {
                *byte ^= 1 << (bit % 8);
                self.flipped += 1;
            }
        }
        let garbage = 1 + self.next() % 6;
        for k in 0..garbage {
            let byte = if k == 0 { 0xFA } else { self.next() as u8 };
            frame.push(byte);
        }
        self.garbage += garbage;
    }
}

/// A CAN bus whose SYNC frames can be lost (the fault `sync_lost`).
struct SyncFilter<B> {
    inner: B,
    faults: Arc<DeviceFaults>,
}

impl<B: CanBus> CanBus for SyncFilter<B> {
    fn send(&mut self, frame: &CanFrame) -> Result<(), hal::link::LinkError> {
        if !frame.extended && frame.id == 0x080 && self.faults.sync_lost.load(Ordering::Relaxed) {
            return Ok(());
        }
        self.inner.send(frame)
    }

    fn recv(&mut self, timeout: Duration) -> Result<Option<CanFrame>, hal::link::LinkError> {
        self.inner.recv(timeout)
    }

    fn kind(&self) -> CanKind {
        self.inner.kind()
    }
}

/// Serves the CAN side: the SLCAN adapter on the line, the wheel drives and the pan-tilt unit on
/// the bus behind it, and the bus's faults.
fn can_devices(
    line: PtyLine,
    port: TTYPort,
    inputs: &Mutex<DeviceInputs>,
    faults: &Arc<DeviceFaults>,
    stop: &AtomicBool,
) -> Result<(), String> {
    let mut network = LoopbackCanBus::network(CanKind::Classic, 3).into_iter();
    let (Some(adapter_bus), Some(mut device_bus), Some(mut babbler)) = (network.next(), network.next(), network.next())
    else {
        return Err("loopback CAN network".into());
    };
    let mut adapter = SlcanAdapter::new(timed(port)?, SyncFilter { inner: adapter_bus, faults: Arc::clone(faults) });
    let _line = line;
    let mut drives = WHEEL_DRIVE_NODES.map(WheelDriveNode::new);
    let mut head = PanTiltNode::new(PAN_TILT_NODE);
    let mut noise = LineNoise::new(0xCA);
    let mut line_errors = 0u64;
    while !stop.load(Ordering::Relaxed) {
        // As on the IMU's line: what the host does not read is lost, the adapter goes on.
        if adapter.poll(SERVICE_PERIOD).is_err() {
            line_errors += 1;
            std::thread::sleep(SERVICE_PERIOD);
        }
        let now_ns = monotonic_ns();
        let current = *inputs.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        let silent = faults.silent_drive.load(Ordering::Relaxed);
        for (index, (drive, speed)) in drives.iter_mut().zip(current.wheel_speeds_radps).enumerate() {
            drive.set_wheel_speed(speed);
            drive.set_silent(silent == index as u64);
        }
        head.set_joint_angles(current.pan_rad, current.tilt_rad);
        let [fl, fr, rl, rr] = &mut drives;
        let mut devices: [&mut dyn CanopenDevice; 5] = [fl, fr, rl, rr, &mut head];
        service_devices(&mut devices, &mut device_bus, now_ns).map_err(|e| format!("CAN devices: {e}"))?;
        if faults.babbling.load(Ordering::Relaxed) {
            // Nine frames a millisecond fill a 1 Mbit/s bus; ids stay clear of the supervised
            // nodes' own (CAN allows one transmitter per id).
            for _ in 0..9 {
                let id = 0x600 + (noise.next() % 0x7F) as u32;
                let data = noise.next().to_le_bytes();
                if let Ok(frame) = CanFrame::standard(id, &data) {
                    // A full bus drops the babbler's frames, as arbitration would.
                    let _ = babbler.send(&frame);
                }
            }
        }
        // The babbler hears everything too; its queue is emptied so it never overflows.
        while babbler.recv(Duration::ZERO).map_err(|e| format!("babbler: {e}"))?.is_some() {}
    }
    if line_errors > 0 {
        eprintln!("hil: CAN adapter: {line_errors} passes with a line error (a host that did not read)");
    }
    Ok(())
}

impl Drop for DeviceBench {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for thread in self.threads.drain(..) {
            // Errors of a bench dropped on an error path are not the error being reported.
            let _ = thread.join();
        }
    }
}

/// A device fault of a HIL run.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum DeviceFault {
    /// The IMU's serial line is unplugged.
    ImuUnplugged,
    /// Garbage and flipped bits on the IMU's line.
    ImuNoise,
    /// Wheel drive `0..4` (front-left, front-right, rear-left, rear-right) falls silent: its
    /// heartbeat times out in the firmware.
    DriveSilent(u8),
    /// A node floods the CAN bus.
    Babbling,
    /// The firmware's SYNC frames are lost.
    SyncLost,
}

/// A fault on robot `robot` from `at_s` for `for_s` seconds of sensor time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DeviceFaultEvent {
    pub robot: usize,
    pub fault: DeviceFault,
    pub at_s: f64,
    pub for_s: f64,
}

impl std::str::FromStr for DeviceFaultEvent {
    type Err = String;

    /// `[ROBOT:]FAULT@START+DURATION`, FAULT one of `imu-unplug`, `imu-noise`, `drive-silent:K`,
    /// `babble`, `sync-lost`: `1:imu-unplug@30+5`.
    fn from_str(text: &str) -> Result<Self, String> {
        let usage = || {
            format!(
                "{text:?}: expected [ROBOT:]FAULT@START+DURATION with FAULT imu-unplug, imu-noise, \
                 drive-silent:K (0..4), babble or sync-lost, e.g. 1:imu-unplug@30+5"
            )
        };
        let (target, when) = text.split_once('@').ok_or_else(usage)?;
        let (start, duration) = when.split_once('+').ok_or_else(usage)?;
        let seconds = |t: &str| t.parse::<f64>().ok().filter(|s| s.is_finite() && *s >= 0.0).ok_or_else(usage);
        let (at_s, for_s) = (seconds(start)?, seconds(duration)?);
        let (robot, fault) = match target.split_once(':') {
            Some((robot, fault)) if robot.chars().all(|c| c.is_ascii_digit()) => {
                (robot.parse::<usize>().map_err(|_| usage())?, fault)
            }
            _ => (0, target),
        };
        let fault = match fault.split_once(':') {
            Some(("drive-silent", wheel)) => {
                DeviceFault::DriveSilent(wheel.parse::<u8>().ok().filter(|w| *w < 4).ok_or_else(usage)?)
            }
            None if fault == "imu-unplug" => DeviceFault::ImuUnplugged,
            None if fault == "imu-noise" => DeviceFault::ImuNoise,
            None if fault == "babble" => DeviceFault::Babbling,
            None if fault == "sync-lost" => DeviceFault::SyncLost,
            _ => return Err(usage()),
        };
        Ok(DeviceFaultEvent { robot, fault, at_s, for_s })
    }
}

impl DeviceFault {
    pub fn name(self) -> String {
        match self {
            DeviceFault::ImuUnplugged => "imu-unplug".into(),
            DeviceFault::ImuNoise => "imu-noise".into(),
            DeviceFault::DriveSilent(wheel) => format!("drive-silent:{wheel}"),
            DeviceFault::Babbling => "babble".into(),
            DeviceFault::SyncLost => "sync-lost".into(),
        }
    }

    fn set(self, faults: &DeviceFaults, on: bool) {
        match self {
            DeviceFault::ImuUnplugged => faults.imu_unplugged.store(on, Ordering::Relaxed),
            DeviceFault::ImuNoise => faults.imu_noisy.store(on, Ordering::Relaxed),
            DeviceFault::DriveSilent(wheel) => {
                faults.silent_drive.store(if on { u64::from(wheel) } else { u64::MAX }, Ordering::Relaxed)
            }
            DeviceFault::Babbling => faults.babbling.store(on, Ordering::Relaxed),
            DeviceFault::SyncLost => faults.sync_lost.store(on, Ordering::Relaxed),
        }
    }
}

/// The device faults of a run, each switched on and off once at its times.
#[derive(Debug)]
pub struct DeviceFaultPlan {
    events: Vec<(DeviceFaultEvent, bool, bool)>,
    /// One record per switch: what, when it was planned and done.
    pub done: Vec<serde_json::Value>,
}

impl DeviceFaultPlan {
    pub fn new(events: &[DeviceFaultEvent]) -> DeviceFaultPlan {
        DeviceFaultPlan { events: events.iter().map(|e| (*e, false, false)).collect(), done: Vec::new() }
    }

    /// Switches the faults due at sensor time `now_s`.
    pub fn apply_due(&mut self, now_s: f64, benches: &[DeviceBench]) {
        for (event, started, ended) in &mut self.events {
            let Some(bench) = benches.get(event.robot) else { continue };
            let switch = if !*started && now_s >= event.at_s {
                *started = true;
                Some((true, event.at_s))
            } else if *started && !*ended && now_s >= event.at_s + event.for_s {
                *ended = true;
                Some((false, event.at_s + event.for_s))
            } else {
                None
            };
            let Some((on, planned_s)) = switch else { continue };
            event.fault.set(&bench.faults, on);
            let record = serde_json::json!({
                "robot": event.robot, "fault": event.fault.name(), "on": on,
                "planned_s": planned_s, "done_s": now_s,
            });
            eprintln!("hil: device fault {record}");
            self.done.push(record);
        }
    }
}
