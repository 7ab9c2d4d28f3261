//! Interop with a third-party CANopen stack: python-canopen 2.4.1 on python-can 4.6.1's `slcan`
//! interface, over a real pseudo-terminal whose other end is our `SlcanAdapter` bridging to a
//! `LoopbackCanBus` (`scripts/canopen_peer.py` is the python side).
//!
//! - python as NMT master and SDO client of our emulated drives and head: NMT start, SDO
//!   upload of 0x1000 / 0x1017 / 0x1018:1, download of 0x1017 (and the heartbeat period that
//!   follows), an abort for a missing object, SYNC → TPDO1 from every device, RPDO1 to the head;
//! - python as a device (a `canopen.LocalNode` playing wheel drive 0x14, with heartbeat, TPDO on
//!   SYNC and EMCY) in a network run by our `CanopenMaster` beside three of our drives and the
//!   head.
//!
//! Everything runs on the wall clock (the python side has no other), so the checks leave room
//! for scheduling jitter. The venv at `../.venv` with canopen and python-can is required: without
//! it the tests fail, saying how to make it.

// Helpers outside #[test] functions are test code too; clippy.toml only exempts the latter.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::HashMap;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::{self, JoinHandle};
use std::time::{Duration, Instant};

use hal::can::LoopbackCanBus;
use hal::can::slcan::{AdapterStats, SlcanAdapter};
use hal::canopen::{
    CanopenDevice, CanopenMaster, MasterConfig, MasterEvent, NodeHealth, NodeId, PAN_TILT_NODE, PanTiltNode,
    WHEEL_DRIVE_NODES, WheelDriveNode, WheelEncoders, service_devices,
};
use hal::link::LinkError;
use protocol::frame::can::CanKind;
use serialport::{SerialPort, TTYPort};

/// The python side finishes in about 3 s; this only catches a hung peer.
const PEER_TIMEOUT: Duration = Duration::from_secs(30);

fn python() -> PathBuf {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../.venv/bin/python");
    assert!(
        path.exists(),
        "{} is missing: the CANopen interop tests need a venv with python-canopen and python-can \
         (python3 -m venv .venv && .venv/bin/pip install canopen==2.4.1 'python-can[serial]==4.6.1')",
        path.display()
    );
    path
}

/// Our SLCAN adapter on a pty master, in a thread of its own; python opens the slave.
struct Bridge {
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<Result<AdapterStats, LinkError>>>,
    channel: String,
    /// Kept open so the pty stays up whatever python does with its end.
    _slave: TTYPort,
}

impl Bridge {
    fn new(bus: LoopbackCanBus) -> Bridge {
        let (master, slave) = TTYPort::pair().expect("cannot open a pty pair");
        let channel = slave.name().expect("pty slave without a name");
        let stop = Arc::new(AtomicBool::new(false));
        let thread_stop = Arc::clone(&stop);
        let thread = thread::spawn(move || {
            let mut adapter = SlcanAdapter::new(master, bus);
            adapter.run_until(&thread_stop).map(|()| adapter.stats())
        });
        Bridge { stop, thread: Some(thread), channel, _slave: slave }
    }

    fn finish(mut self) -> AdapterStats {
        self.stop.store(true, Ordering::Release);
        self.thread.take().unwrap().join().unwrap().expect("SLCAN adapter failed")
    }
}

impl Drop for Bridge {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
    }
}

/// Runs the python peer in `mode` while calling `step(now_ns)` about every millisecond; returns
/// its `key=value` results.
fn run_peer(mode: &str, channel: &str, mut step: impl FnMut(u64)) -> HashMap<String, String> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/canopen_peer.py");
    let mut child = Command::new(python())
        .arg(&script)
        .arg(mode)
        .arg(channel)
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("cannot start the python peer");
    let epoch = Instant::now();
    let status = loop {
        step(epoch.elapsed().as_nanos() as u64);
        if let Some(status) = child.try_wait().unwrap() {
            break status;
        }
        if epoch.elapsed() > PEER_TIMEOUT {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("python peer ({mode}) did not finish within {PEER_TIMEOUT:?}");
        }
        thread::sleep(Duration::from_millis(1));
    };
    let (mut stdout, mut stderr) = (String::new(), String::new());
    child.stdout.take().unwrap().read_to_string(&mut stdout).unwrap();
    child.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    println!("python peer ({mode}), {:.1} s:\n{stdout}", epoch.elapsed().as_secs_f64());
    assert!(status.success(), "python peer ({mode}) failed ({status}):\n{stdout}\n{stderr}");
    stdout.lines().filter_map(|line| line.split_once('=')).map(|(k, v)| (k.to_string(), v.to_string())).collect()
}

fn get<'a>(results: &'a HashMap<String, String>, key: &str) -> &'a str {
    results.get(key).unwrap_or_else(|| panic!("python peer did not report {key}: {results:?}"))
}

fn number(results: &HashMap<String, String>, key: &str) -> f64 {
    get(results, key).parse().unwrap_or_else(|_| panic!("{key} is not a number: {results:?}"))
}

#[test]
fn python_canopen_master_talks_to_our_devices() {
    let mut buses = LoopbackCanBus::network(CanKind::Classic, 2).into_iter();
    let bridge = Bridge::new(buses.next().unwrap());
    let mut device_bus = buses.next().unwrap();
    let mut drives: Vec<WheelDriveNode> = WHEEL_DRIVE_NODES.iter().map(|&n| WheelDriveNode::new(n)).collect();
    drives[0].set_wheel_speed(1.0);
    let mut head = PanTiltNode::new(PAN_TILT_NODE);

    let results = run_peer("client", &bridge.channel, |now_ns| {
        let mut devices: Vec<&mut dyn CanopenDevice> = drives.iter_mut().map(|d| d as &mut dyn CanopenDevice).collect();
        devices.push(&mut head);
        service_devices(&mut devices, &mut device_bus, now_ns).unwrap();
    });
    let stats = bridge.finish();
    println!("adapter: {stats:?}");

    assert_eq!(get(&results, "state_before"), "PRE-OPERATIONAL");
    assert_eq!(get(&results, "state_after"), "OPERATIONAL");
    assert_eq!(get(&results, "head_state_after"), "OPERATIONAL");
    assert_eq!(get(&results, "device_type"), "0x00020192");
    assert_eq!(get(&results, "head_device_type"), "0x00000000");
    assert_eq!(get(&results, "vendor_id"), "0x00000000");
    assert_eq!(get(&results, "heartbeat_ms_before"), "100");
    assert_eq!(get(&results, "heartbeat_ms_after"), "50");
    assert_eq!(get(&results, "abort_code"), "0x06020000");
    let interval_ms = number(&results, "heartbeat_interval_ms");
    assert!((45.0..=56.0).contains(&interval_ms), "heartbeat every {interval_ms} ms after writing 50");
    assert_eq!(get(&results, "tpdos"), "25,25,25,25,25", "TPDO1 per device for 25 SYNCs");
    let expected_velocity = (1.0 * f64::from(drives[0].counts_per_rev()) / std::f64::consts::TAU).round();
    assert_eq!(number(&results, "fl_velocity_counts_per_s"), expected_velocity);
    let rate = number(&results, "fl_position_rate_counts_per_s");
    assert!((rate / expected_velocity - 1.0).abs() < 0.05, "positions advance at {rate} counts/s");
    assert_eq!(number(&results, "head_pan_microrad"), 300_000.0);
    assert_eq!(number(&results, "head_tilt_microrad"), -200_000.0);
    assert!(drives.iter().all(|d| d.nmt_state() == hal::canopen::NmtState::Operational));
    assert_eq!(stats.rejected_lines, 0);
    assert_eq!(stats.bus_send_errors, 0);
}

#[test]
fn our_master_runs_a_python_canopen_device() {
    let python_drive: NodeId = WHEEL_DRIVE_NODES[3];
    let mut buses = LoopbackCanBus::network(CanKind::Classic, 3).into_iter();
    let bridge = Bridge::new(buses.next().unwrap());
    let mut master_bus = buses.next().unwrap();
    let mut device_bus = buses.next().unwrap();
    let mut master = CanopenMaster::new(MasterConfig::default()).unwrap();
    let mut drives: Vec<WheelDriveNode> = WHEEL_DRIVE_NODES[..3].iter().map(|&n| WheelDriveNode::new(n)).collect();
    let mut head = PanTiltNode::new(PAN_TILT_NODE);
    let mut events = Vec::new();
    let mut cycles: Vec<WheelEncoders> = Vec::new();
    let mut python_operational_seen = false;

    let results = run_peer("device", &bridge.channel, |now_ns| {
        master.tick(now_ns, &mut master_bus).unwrap();
        let mut devices: Vec<&mut dyn CanopenDevice> = drives.iter_mut().map(|d| d as &mut dyn CanopenDevice).collect();
        devices.push(&mut head);
        service_devices(&mut devices, &mut device_bus, now_ns).unwrap();
        events.extend(master.drain_events());
        cycles.extend(master.take_encoders());
        python_operational_seen |= master.health(python_drive) == Some(NodeHealth::Operational);
    });
    let stats = bridge.finish();
    let counters = master.counters();
    println!("adapter: {stats:?}\nmaster: {counters:?}");

    // Our master's targeted NMT start reached python (node 0x14 = 0x01 0x14).
    assert!(get(&results, "nmt_frames").split(' ').any(|frame| frame == "0114"), "{results:?}");
    let booted_at = events.iter().position(|e| *e == MasterEvent::NodeBooted { node: python_drive });
    assert!(booted_at.is_some(), "no boot-up from python seen: {events:?}");
    assert!(python_operational_seen, "python's operational heartbeat never seen");
    let emergencies: Vec<MasterEvent> =
        events.iter().copied().filter(|e| matches!(e, MasterEvent::Emergency { .. })).collect();
    assert_eq!(
        emergencies,
        vec![
            MasterEvent::Emergency { node: python_drive, code: 0x2310, error_register: 0x03 },
            MasterEvent::Emergency { node: python_drive, code: 0, error_register: 0 },
        ]
    );

    // Python numbers its TPDOs by the SYNCs it saw: 1000 counts per SYNC.
    let python_syncs = number(&results, "syncs");
    let python_tpdos = number(&results, "tpdos");
    let pairs: Vec<(&WheelEncoders, &WheelEncoders)> = cycles.iter().zip(cycles.iter().skip(1)).collect();
    let consistent = pairs
        .iter()
        .filter(|(a, b)| {
            i64::from(b.positions_counts[3]) - i64::from(a.positions_counts[3]) == 1000 * (b.cycle - a.cycle) as i64
        })
        .count();
    println!(
        "python drive: {python_syncs} SYNCs seen, {python_tpdos} TPDOs sent; master: {} complete cycles \
         ({} incomplete, most before python booted), {consistent}/{} consecutive cycles with python's \
         position advancing by 1000 counts per SYNC",
        counters.cycles_complete,
        counters.cycles_incomplete,
        pairs.len()
    );
    assert!(python_tpdos >= 60.0, "{python_tpdos} TPDOs from python");
    assert!(counters.cycles_complete as f64 >= 0.9 * python_tpdos, "{counters:?}");
    assert!(consistent as f64 >= 0.9 * pairs.len() as f64);
    assert_eq!((counters.malformed_frames, counters.foreign_frames), (0, 0));
    assert_eq!(stats.rejected_lines, 0);
}
