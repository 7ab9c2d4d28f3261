//! Per-frame IPC latency of stereo pairs between two processes, from 256×127 to 2048×1016
//! pixels, three ways:
//!
//! - **iceoryx2, written in place** (what the driver does since the images went zero-copy): the
//!   sender renders the pair straight into a loaned shared-memory sample
//!   (`Outbox::publish_stereo_with`), stamps it as the last write and sends; the receiver reads it
//!   where it lies. The latency is publish → usable, and it does not grow with the image.
//! - **iceoryx2, copied in** (what the driver did before): the pair is stamped in the sender's own
//!   buffer, then copied into the sample by `Outbox::publish`; the copy is inside the latency.
//! - **Unix-domain socket** (reference): stamped, written, copied by the kernel into the
//!   receiver's buffer.
//!
//! The stamp is a CLOCK_MONOTONIC reading in the payload's first 8 bytes (`Instant` is not
//! comparable across processes). The bus receiver polls with `yield` between polls; the socket
//! receiver blocks in `read`. iceoryx2's own published figure (its README, "Performance": 240 ns
//! at 64 B and at 64 kB, busy-waiting subscribers on an i7-10875H) is the reference for the shape:
//! flat in the payload size.
//!
//! `cargo bench -p onboard --bench ipc_latency` runs 300 frames per case; without `--bench` (as
//! `cargo test --all-targets` runs it) 3.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use msgs::StereoHeader;
use nix::time::{ClockId, clock_gettime};
use onboard::bus::{Bus, ImageGeometry, purge_robot};
use onboard::nodes::{Message, Outbox, Topic};

const ROLE: &str = "ONBOARD_IPC_BENCH_ROLE";
const SIZES: [(u32, u32); 4] = [(256, 127), (512, 254), (1024, 508), (2048, 1016)];

type BenchResult<T> = Result<T, Box<dyn std::error::Error>>;

fn monotonic_ns() -> u64 {
    clock_gettime(ClockId::CLOCK_MONOTONIC)
        .map(|t| (t.tv_sec().max(0) as u64) * 1_000_000_000 + t.tv_nsec().max(0) as u64)
        .unwrap_or(0)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Transport {
    InPlace,
    CopiedIn,
    Socket,
}

impl Transport {
    const ALL: [Transport; 3] = [Transport::InPlace, Transport::CopiedIn, Transport::Socket];

    fn name(self) -> &'static str {
        match self {
            Transport::InPlace => "shm-in-place",
            Transport::CopiedIn => "shm-copied-in",
            Transport::Socket => "unix-socket",
        }
    }

    fn parse(name: &str) -> Option<Transport> {
        Transport::ALL.into_iter().find(|t| t.name() == name)
    }
}

#[derive(Debug, Clone, Copy)]
struct Plan {
    warmup: u64,
    frames: u64,
    period: Duration,
}

/// A pair's bytes as a renderer would leave them (any pattern: the receiver does not check it).
fn render(bytes: &mut [u8], sequence: u64) {
    for (i, b) in bytes.iter_mut().enumerate() {
        *b = (i as u64).wrapping_add(sequence) as u8;
    }
}

fn stamp(bytes: &mut [u8]) {
    bytes[..8].copy_from_slice(&monotonic_ns().to_le_bytes());
}

fn stamp_of(bytes: &[u8]) -> u64 {
    bytes.get(..8).and_then(|b| b.try_into().ok()).map_or(0, u64::from_le_bytes)
}

/// The sending process: `<transport> <width> <height> <robot or socket path> <frames> <period_us>`.
fn sender(spec: &str) -> BenchResult<()> {
    let fields: Vec<&str> = spec.split(' ').collect();
    let [transport, width, height, target, frames, period_us] = fields[..] else {
        return Err(format!("bad role {spec}").into());
    };
    let transport = Transport::parse(transport).ok_or("unknown transport")?;
    let (width_px, height_px): (u32, u32) = (width.parse()?, height.parse()?);
    let frames: u64 = frames.parse()?;
    let period = Duration::from_micros(period_us.parse()?);
    let len = 2 * width_px as usize * height_px as usize;
    let start = Instant::now();
    let pace = |i: u64| {
        let due = start + period * u32::try_from(i).unwrap_or(u32::MAX);
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    };
    let header = |sequence| StereoHeader { stamp_ns: 0, sequence, pan_rad: 0.0, tilt_rad: 0.0, width_px, height_px };
    match transport {
        Transport::InPlace | Transport::CopiedIn => {
            let bus = Bus::open(target.parse()?, "driver", ImageGeometry { width_px, height_px })?;
            let mut outbox = bus.outbox(&[Topic::Stereo])?;
            let mut own = vec![0u8; len];
            for sequence in 0..frames {
                pace(sequence);
                if transport == Transport::InPlace {
                    outbox.publish_stereo_with(&header(sequence), &mut |bytes| {
                        render(bytes, sequence);
                        stamp(bytes);
                        Ok(())
                    })?;
                } else {
                    render(&mut own, sequence);
                    stamp(&mut own);
                    outbox.publish(Message::Stereo(&header(sequence), &own))?;
                }
            }
        }
        Transport::Socket => {
            let mut stream = UnixStream::connect(target)?;
            let mut own = vec![0u8; len];
            for sequence in 0..frames {
                pace(sequence);
                render(&mut own, sequence);
                stamp(&mut own);
                stream.write_all(&own)?;
            }
        }
    }
    Ok(())
}

fn spawn_sender(spec: &str) -> BenchResult<Child> {
    Ok(Command::new(std::env::current_exe()?).env(ROLE, spec).spawn()?)
}

fn finish(mut child: Child) -> BenchResult<()> {
    let status = child.wait()?;
    if !status.success() {
        return Err(format!("sender failed: {status}").into());
    }
    Ok(())
}

/// Latencies (ns) of the frames after the warm-up.
fn run(transport: Transport, (width_px, height_px): (u32, u32), plan: Plan) -> BenchResult<Vec<u64>> {
    let total = plan.warmup + plan.frames;
    let tail = format!("{width_px} {height_px}");
    let mut latencies = Vec::with_capacity(plan.frames as usize);
    if transport == Transport::Socket {
        let path = std::env::temp_dir().join(format!("onboard_ipc_latency_{}.sock", std::process::id()));
        let _ = std::fs::remove_file(&path);
        let listener = UnixListener::bind(&path)?;
        let child = spawn_sender(&format!(
            "{} {tail} {} {total} {}",
            transport.name(),
            path.display(),
            plan.period.as_micros()
        ))?;
        let (mut stream, _) = listener.accept()?;
        let mut frame = vec![0u8; 2 * width_px as usize * height_px as usize];
        for i in 0..total {
            stream.read_exact(&mut frame)?;
            let now_ns = monotonic_ns();
            if i >= plan.warmup {
                latencies.push(now_ns.saturating_sub(stamp_of(&frame)));
            }
        }
        finish(child)?;
        let _ = std::fs::remove_file(&path);
        return Ok(latencies);
    }
    let robot = 60_000 + (std::process::id() % 5_000) as u16;
    let bus = Bus::open(robot, "vision", ImageGeometry { width_px, height_px })?;
    let mut inbox = bus.inbox(&[Topic::Stereo])?;
    let child = spawn_sender(&format!("{} {tail} {robot} {total} {}", transport.name(), plan.period.as_micros()))?;
    let mut received = 0;
    let deadline = Instant::now() + plan.period * u32::try_from(total)? + Duration::from_secs(20);
    while received < total && Instant::now() < deadline {
        if !inbox.has_pending()? {
            std::thread::yield_now();
            continue;
        }
        inbox.drain(&mut |message| {
            let now_ns = monotonic_ns();
            if let Message::Stereo(header, bytes) = message
                && (plan.warmup..total).contains(&header.sequence)
            {
                latencies.push(now_ns.saturating_sub(stamp_of(bytes)));
            }
            received += 1;
            Ok(())
        })?;
    }
    let lost = inbox.counters(Topic::Stereo).sequence_gaps;
    finish(child)?;
    drop((inbox, bus));
    purge_robot(robot)?;
    if lost > 0 {
        eprintln!("ipc_latency: {lost} frames dropped on the bus");
    }
    Ok(latencies)
}

#[derive(Debug, Clone, Copy)]
struct Stats {
    n: usize,
    p50_us: f64,
    p99_us: f64,
}

fn stats(mut latencies_ns: Vec<u64>) -> Stats {
    latencies_ns.sort_unstable();
    let n = latencies_ns.len();
    let at = |q: f64| {
        let rank = ((q * n as f64).ceil() as usize).clamp(1, n.max(1)) - 1;
        latencies_ns.get(rank).copied().unwrap_or(0) as f64 / 1_000.0
    };
    Stats { n, p50_us: at(0.5), p99_us: at(0.99) }
}

fn main() -> BenchResult<()> {
    if let Ok(spec) = std::env::var(ROLE) {
        return sender(&spec);
    }
    let heavy = std::env::args().any(|a| a == "--bench");
    let plan = if heavy {
        // The warm-up touches every sample slot of the publisher once: page faults of fresh shared
        // memory are start-up cost, not per-frame latency.
        Plan { warmup: 64, frames: 300, period: Duration::from_millis(10) }
    } else {
        Plan { warmup: 4, frames: 3, period: Duration::from_millis(5) }
    };
    println!(
        "ipc_latency: stereo pairs, {} frames per case after {} warm-up, one every {} ms{}",
        plan.frames,
        plan.warmup,
        plan.period.as_millis(),
        if heavy { "" } else { " (smoke run; pass --bench for the full run)" }
    );
    println!("{:<11} {:>10} {:<14} {:>5} {:>10} {:>10}", "size", "bytes", "transport", "n", "p50 µs", "p99 µs");
    let mut in_place_p50 = Vec::new();
    for size in SIZES {
        let bytes = 2 * size.0 as usize * size.1 as usize;
        for transport in Transport::ALL {
            let s = stats(run(transport, size, plan)?);
            println!(
                "{:<11} {:>10} {:<14} {:>5} {:>10.1} {:>10.1}",
                format!("{}x{}", size.0, size.1),
                bytes,
                transport.name(),
                s.n,
                s.p50_us,
                s.p99_us
            );
            if s.n != plan.frames as usize {
                return Err(format!("{}: {} of {} frames arrived", transport.name(), s.n, plan.frames).into());
            }
            if transport == Transport::InPlace {
                in_place_p50.push(s.p50_us);
            }
        }
    }
    let (low, high) = in_place_p50.iter().fold((f64::MAX, 0.0_f64), |(l, h), &v| (l.min(v), h.max(v)));
    println!(
        "in place: p50 from {low:.1} to {high:.1} µs over a {}x range of sizes (iceoryx2's published 240 ns is \
         flat from 64 B to 64 kB, busy-waiting)",
        (SIZES[3].0 * SIZES[3].1) / (SIZES[0].0 * SIZES[0].1)
    );
    Ok(())
}
