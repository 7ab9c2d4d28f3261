//! Per-frame IPC latency between two processes: a 1024×508 stereo pair (1 MB) and a 1024×508
//! disparity map (2 MB), through the iceoryx2 bus (written once into shared memory, read in
//! place) and, as the reference, through a Unix-domain stream socket (copied through the kernel
//! into the receiver's buffer).
//!
//! Latency is publish start → the receiver holds a usable frame, from a CLOCK_MONOTONIC stamp the
//! sender puts in the frame (`Instant` is not comparable across processes). The receiver polls
//! the bus with `yield` between polls and blocks in `read` on the socket.
//!
//! `cargo bench -p onboard --bench ipc_latency` runs 500 frames per case; without `--bench` (as
//! `cargo test --all-targets` runs it) 5 frames.

use std::io::{Read, Write};
use std::os::unix::net::{UnixListener, UnixStream};
use std::process::{Child, Command};
use std::time::{Duration, Instant};

use msgs::{DisparityHeader, DisparityPixel, StereoHeader};
use nix::time::{ClockId, clock_gettime};
use onboard::bus::{Bus, ImageGeometry, purge_robot};
use onboard::nodes::{Message, Outbox, Topic};

const ROLE: &str = "ONBOARD_IPC_BENCH_ROLE";
const GEOMETRY: ImageGeometry = ImageGeometry { width_px: 1024, height_px: 508 };
const PIXELS: usize = 1024 * 508;
/// Frames before the measured ones: enough to touch every sample slot of the publisher once
/// (page faults of fresh shared memory are start-up cost, not per-frame latency).
const WARMUP: u64 = 64;

type BenchResult<T> = Result<T, Box<dyn std::error::Error>>;

fn monotonic_ns() -> BenchResult<u64> {
    let t = clock_gettime(ClockId::CLOCK_MONOTONIC)?;
    Ok(u64::try_from(t.tv_sec())? * 1_000_000_000 + u64::try_from(t.tv_nsec())?)
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Payload {
    Stereo,
    Disparity,
}

impl Payload {
    fn name(self) -> &'static str {
        match self {
            Payload::Stereo => "stereo",
            Payload::Disparity => "disparity",
        }
    }

    fn bytes(self) -> usize {
        match self {
            Payload::Stereo => 2 * PIXELS,
            Payload::Disparity => PIXELS * std::mem::size_of::<DisparityPixel>(),
        }
    }

    fn topic(self) -> Topic {
        match self {
            Payload::Stereo => Topic::Stereo,
            Payload::Disparity => Topic::Disparity,
        }
    }

    fn parse(name: &str) -> Option<Payload> {
        [Payload::Stereo, Payload::Disparity].into_iter().find(|p| p.name() == name)
    }
}

#[derive(Debug, Clone, Copy)]
struct Plan {
    frames: u64,
    period: Duration,
}

/// The sending process: `shm <payload> <robot> <frames> <period_us>` or
/// `uds <payload> <socket path> <frames> <period_us>`.
fn sender(spec: &str) -> BenchResult<()> {
    let fields: Vec<&str> = spec.split(' ').collect();
    let [transport, payload, target, frames, period_us] = fields[..] else {
        return Err(format!("bad role {spec}").into());
    };
    let payload = Payload::parse(payload).ok_or("unknown payload")?;
    let frames: u64 = frames.parse()?;
    let period = Duration::from_micros(period_us.parse()?);
    let stereo: Vec<u8> = (0..2 * PIXELS).map(|i| (i % 251) as u8).collect();
    let disparity: Vec<DisparityPixel> =
        (0..PIXELS).map(|i| DisparityPixel { disparity_q4: (i % 4093) as u16, labels: 0, reserved: 0 }).collect();
    let start = Instant::now();
    let pace = |i: u64| {
        let due = start + period * u32::try_from(i).unwrap_or(u32::MAX);
        if let Some(wait) = due.checked_duration_since(Instant::now()) {
            std::thread::sleep(wait);
        }
    };
    match transport {
        "shm" => {
            let bus = Bus::open(target.parse()?, "vision", GEOMETRY)?;
            let mut outbox = bus.outbox(&[payload.topic()])?;
            for sequence in 0..frames {
                pace(sequence);
                let stamp_ns = monotonic_ns()?;
                let (w, h) = (GEOMETRY.width_px, GEOMETRY.height_px);
                match payload {
                    Payload::Stereo => {
                        let header =
                            StereoHeader { stamp_ns, sequence, pan_rad: 0.0, tilt_rad: 0.0, width_px: w, height_px: h };
                        outbox.publish(Message::Stereo(&header, &stereo))?;
                    }
                    Payload::Disparity => {
                        let header = DisparityHeader {
                            stamp_ns,
                            sequence,
                            pan_rad: 0.0,
                            tilt_rad: 0.0,
                            width_px: w,
                            height_px: h,
                        };
                        outbox.publish(Message::Disparity(&header, &disparity))?;
                    }
                }
            }
        }
        "uds" => {
            let mut stream = UnixStream::connect(target)?;
            let bytes: &[u8] = match payload {
                Payload::Stereo => &stereo,
                Payload::Disparity => bytemuck::cast_slice(&disparity),
            };
            for sequence in 0..frames {
                pace(sequence);
                stream.write_all(&monotonic_ns()?.to_le_bytes())?;
                stream.write_all(bytes)?;
            }
        }
        other => return Err(format!("unknown transport {other}").into()),
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

/// Latencies (ns) of the frames after the warm-up, received over the bus.
fn run_shm(payload: Payload, plan: Plan) -> BenchResult<Vec<u64>> {
    let robot = 60_000 + (std::process::id() % 5_000) as u16;
    let bus = Bus::open(robot, "mapper", GEOMETRY)?;
    let mut inbox = bus.inbox(&[payload.topic()])?;
    let child =
        spawn_sender(&format!("shm {} {robot} {} {}", payload.name(), plan.frames + WARMUP, plan.period.as_micros()))?;
    let mut latencies = Vec::with_capacity(plan.frames as usize);
    let mut received = 0;
    let deadline = Instant::now() + plan.period * u32::try_from(plan.frames + WARMUP)? + Duration::from_secs(20);
    while received < plan.frames + WARMUP && Instant::now() < deadline {
        if !inbox.has_pending()? {
            std::thread::yield_now();
            continue;
        }
        inbox.drain(&mut |message| {
            let now_ns = monotonic_ns().unwrap_or(0);
            let sequence = match message {
                Message::Stereo(h, _) => h.sequence,
                Message::Disparity(h, _) => h.sequence,
                _ => u64::MAX,
            };
            if (WARMUP..WARMUP + plan.frames).contains(&sequence) {
                latencies.push(now_ns.saturating_sub(message.stamp_ns()));
            }
            received += 1;
            Ok(())
        })?;
    }
    let lost = inbox.counters(payload.topic()).sequence_gaps;
    finish(child)?;
    drop((inbox, bus));
    purge_robot(robot)?;
    if lost > 0 {
        eprintln!("ipc_latency: {lost} {} frames dropped on the bus", payload.name());
    }
    Ok(latencies)
}

/// Latencies (ns) of the frames after the warm-up, copied through a Unix-domain socket.
fn run_uds(payload: Payload, plan: Plan) -> BenchResult<Vec<u64>> {
    let path = std::env::temp_dir().join(format!("onboard_ipc_latency_{}.sock", std::process::id()));
    let _ = std::fs::remove_file(&path);
    let listener = UnixListener::bind(&path)?;
    let child = spawn_sender(&format!(
        "uds {} {} {} {}",
        payload.name(),
        path.display(),
        plan.frames + WARMUP,
        plan.period.as_micros()
    ))?;
    let (mut stream, _) = listener.accept()?;
    let mut frame = vec![0u8; payload.bytes()];
    let mut stamp = [0u8; 8];
    let mut latencies = Vec::with_capacity(plan.frames as usize);
    for i in 0..plan.frames + WARMUP {
        stream.read_exact(&mut stamp)?;
        stream.read_exact(&mut frame)?;
        let now_ns = monotonic_ns()?;
        if i >= WARMUP {
            latencies.push(now_ns.saturating_sub(u64::from_le_bytes(stamp)));
        }
    }
    finish(child)?;
    let _ = std::fs::remove_file(&path);
    Ok(latencies)
}

#[derive(Debug, Clone, Copy)]
struct Stats {
    n: usize,
    p50_us: f64,
    p99_us: f64,
    max_us: f64,
}

fn stats(mut latencies_ns: Vec<u64>) -> Stats {
    latencies_ns.sort_unstable();
    let n = latencies_ns.len();
    let at = |q: f64| {
        let rank = ((q * n as f64).ceil() as usize).clamp(1, n.max(1)) - 1;
        latencies_ns.get(rank).copied().unwrap_or(0) as f64 / 1_000.0
    };
    Stats { n, p50_us: at(0.5), p99_us: at(0.99), max_us: latencies_ns.last().copied().unwrap_or(0) as f64 / 1_000.0 }
}

fn main() -> BenchResult<()> {
    if let Ok(spec) = std::env::var(ROLE) {
        return sender(&spec);
    }
    let heavy = std::env::args().any(|a| a == "--bench");
    let plan = if heavy {
        Plan { frames: 500, period: Duration::from_millis(10) }
    } else {
        Plan { frames: 5, period: Duration::from_millis(5) }
    };
    println!(
        "ipc_latency: {}x{} px, {} frames per case after {WARMUP} warm-up, one every {} ms{}",
        GEOMETRY.width_px,
        GEOMETRY.height_px,
        plan.frames,
        plan.period.as_millis(),
        if heavy { "" } else { " (smoke run; pass --bench for the full run)" }
    );
    println!(
        "{:<10} {:>9} {:<22} {:>5} {:>9} {:>9} {:>9}",
        "payload", "bytes", "transport", "n", "p50 µs", "p99 µs", "max µs"
    );
    for payload in [Payload::Stereo, Payload::Disparity] {
        let shm = stats(run_shm(payload, plan)?);
        let uds = stats(run_uds(payload, plan)?);
        for (transport, s) in [("iceoryx2 shm, in place", shm), ("unix socket, copied", uds)] {
            println!(
                "{:<10} {:>9} {:<22} {:>5} {:>9.1} {:>9.1} {:>9.1}",
                payload.name(),
                payload.bytes(),
                transport,
                s.n,
                s.p50_us,
                s.p99_us,
                s.max_us
            );
        }
        if shm.n != plan.frames as usize {
            return Err(
                format!("{}: only {} of {} frames arrived over the bus", payload.name(), shm.n, plan.frames).into()
            );
        }
        println!(
            "{:<10} socket / shm latency: p50 {:.1}x, p99 {:.1}x",
            payload.name(),
            uds.p50_us / shm.p50_us.max(1e-3),
            uds.p99_us / shm.p99_us.max(1e-3)
        );
    }
    Ok(())
}
