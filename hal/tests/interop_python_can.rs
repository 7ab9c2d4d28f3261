//! Interoperability with python-can: its `slcan` interface (the project venv's python-can) as
//! the host, on the slave of a pty pair, and our `SlcanAdapter` on the master, bridging to a
//! `LoopbackCanBus`. Frames cross both ways and must arrive equal and in order, and the adapter
//! must understand every line python-can sends (no BELL, no rejected line).
//!
//! The venv is required: without `../.venv/bin/python` (next to the workspace root) the test
//! fails and says how to make it, never passes silently.

// Helpers outside #[test] functions are test code too; clippy.toml only exempts the latter.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread;
use std::time::{Duration, Instant};

use hal::can::slcan::{ChannelState, SlcanAdapter, SlcanBitrate};
use hal::can::{CanBus, CanFrame, LoopbackCanBus};
use protocol::frame::can::CanKind;
use serialport::{SerialPort, TTYPort};

/// Frames python sends, and frames it receives.
const TO_BUS: usize = 200;
const TO_PYTHON: usize = 200;
const WAIT: Duration = Duration::from_secs(4);

fn venv_python() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let python = manifest.join("../.venv/bin/python");
    assert!(
        python.exists(),
        "python-can interop needs the project venv at {} (python-can 4.6.1 and pyserial installed in it); \
         create it with `python3 -m venv .venv && .venv/bin/pip install python-can==4.6.1 pyserial` at the \
         workspace root",
        python.display()
    );
    python
}

/// Frame `i`: standard and extended ids in alternating runs of three, every length 0–8.
fn frame(i: usize, salt: u8) -> CanFrame {
    let len = i % 9;
    let bytes: Vec<u8> = (0..len).map(|k| (i as u8).wrapping_mul(29).wrapping_add(k as u8) ^ salt).collect();
    if (i / 3).is_multiple_of(2) {
        CanFrame::standard((i as u32 * 41 + u32::from(salt)) & 0x7FF, &bytes).unwrap()
    } else {
        CanFrame::new((i as u32 ^ u32::from(salt)).wrapping_mul(2_654_435_761) & 0x1FFF_FFFF, &bytes).unwrap()
    }
}

fn hex(data: &[u8]) -> String {
    if data.is_empty() { "-".to_string() } else { data.iter().map(|b| format!("{b:02x}")).collect() }
}

/// The line the script prints for a frame it received (data frame, not FD).
fn as_python_prints(frame: &CanFrame) -> String {
    format!("frame {} {:x} {} {} 0 0", u8::from(frame.extended), frame.id, frame.len, hex(frame.data()))
}

#[test]
fn python_can_slcan_host_and_our_adapter_exchange_frames() {
    let python = venv_python();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/python_can_peer.py");
    let started = Instant::now();

    let (master, slave) = TTYPort::pair().expect("cannot open a pty pair");
    // Kept open until the end: when the last slave descriptor closes (python exiting), the
    // master reads a hang-up, and the adapter would stop before reading python's last `C`.
    let slave_path = slave.name().expect("pty slave has a path");
    let mut nodes = LoopbackCanBus::network_with_queue(CanKind::Classic, 2, 4096).into_iter();
    let adapter = SlcanAdapter::new(master, nodes.next().unwrap());
    let mut peer = nodes.next().unwrap();
    let stop = AtomicBool::new(false);

    let to_bus: Vec<CanFrame> = (0..TO_BUS).map(|i| frame(i, 0x5A)).collect();
    let to_python: Vec<CanFrame> = (0..TO_PYTHON).map(|i| frame(i + 4, 0xC3)).collect();

    let (adapter, output, on_bus) = thread::scope(|scope| {
        let bridge = scope.spawn(|| {
            let mut adapter = adapter;
            let result = adapter.run_until(&stop);
            (adapter, result)
        });

        let mut child = Command::new(&python)
            .arg(&script)
            .args([&slave_path, "500000", &TO_PYTHON.to_string()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap_or_else(|e| panic!("cannot run {}: {e}", python.display()));
        let mut stdin = child.stdin.take().unwrap();
        for f in &to_bus {
            writeln!(stdin, "{} {:x} {}", u8::from(f.extended), f.id, hex(f.data())).unwrap();
        }
        drop(stdin);

        // python's frames reach the bus; only then is its channel surely open for ours.
        let mut on_bus = Vec::new();
        let deadline = Instant::now() + WAIT;
        while on_bus.len() < TO_BUS && Instant::now() < deadline {
            if let Some(f) = peer.recv(Duration::from_millis(20)).unwrap() {
                on_bus.push(f);
            }
            if child.try_wait().unwrap().is_some() {
                break;
            }
        }
        while let Some(f) = peer.recv(Duration::ZERO).unwrap() {
            on_bus.push(f);
        }
        if on_bus.len() == TO_BUS {
            for f in &to_python {
                peer.send(f).unwrap();
            }
        }

        let output = child.wait_with_output().unwrap();
        stop.store(true, Ordering::Release);
        let (mut adapter, result) = bridge.join().unwrap();
        result.unwrap();
        // What python wrote before exiting (its closing `C`) is in the pty: serve it.
        adapter.poll(Duration::from_millis(50)).unwrap();
        (adapter, output, on_bus)
    });
    drop(slave);

    let stdout = String::from_utf8_lossy(&output.stdout);
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(output.status.success(), "python-can peer failed ({}):\n{stderr}\n{stdout}", output.status);
    assert_eq!(on_bus, to_bus, "python-can to our bus; python said:\n{stderr}");

    let lines: Vec<&str> = stdout.lines().collect();
    assert_eq!(lines.first(), Some(&"version 1 1"), "python-can's get_version parses our V reply\n{stdout}");
    assert_eq!(lines.get(1), Some(&"serial HAL1"), "python-can's get_serial_number parses our N reply");
    assert_eq!(lines.last(), Some(&"done"), "{stdout}");
    let received: Vec<&str> = lines.iter().copied().filter(|l| l.starts_with("frame ")).collect();
    let expected: Vec<String> = to_python.iter().map(as_python_prints).collect();
    assert_eq!(received, expected, "our bus to python-can");

    let stats = adapter.stats();
    assert_eq!(stats.refused, 0, "the adapter refused a line python-can sent: {stats:?}");
    assert_eq!(stats.rejected_lines, 0, "{stats:?}");
    assert_eq!(stats.frames_to_bus, TO_BUS as u64, "{stats:?}");
    assert_eq!(stats.frames_to_host, TO_PYTHON as u64, "{stats:?}");
    assert_eq!(adapter.bitrate(), Some(SlcanBitrate::B500k), "python-can's bitrate=500000 is S6");
    assert_eq!(adapter.state(), ChannelState::Closed, "python-can's shutdown closes the channel");
    // C, S6, an empty line (no data bit rate), O, O again, V, N, the frames, C.
    assert_eq!(stats.host_lines, 8 + TO_BUS as u64, "{stats:?}");
    eprintln!("python-can interop: {TO_BUS} + {TO_PYTHON} frames in {:?}", started.elapsed());
}
