//! Release jitter of the filter's 200 Hz task (deadline 5 ms) while the vision process loads the
//! machine: the `fpga_model` fast SGM matcher (Four paths, 128 disparities, 2 threads) on a
//! 1024×508 pair in a loop, in a separate process (this binary re-executed with `JITTER_LOAD_S`).
//! The task body is a real filter step: propagate one IMU sample through the error-state EKF and
//! build the `filter/state` message from the estimate (what the filter process publishes).
//!
//! Phases: (a) idle reference, (b) under load at normal priority, (c) under load with
//! `rt::apply` (SCHED_FIFO 80 + mlockall; reported as skipped where not permitted).
//!
//! `cargo bench -p onboard --bench jitter` measures 10 s per phase; without `--bench` (as
//! `cargo test --all-targets` runs it) 1 s per phase.

use std::hint::black_box;
use std::io::Read;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use fpga_model::config::{PathMode, SgmConfig};
use fpga_model::fast::Matcher;
use fpga_model::image::{DisparityImage, GrayImage};
use hal::sensor::ImuSample;
use msgs::{FilterStateMsg, Pose, ProcessKind, covariance_to_array};
use nalgebra::Vector3;
use onboard::task::rt::{self, RtReport, RtRequest};
use onboard::task::{FixedRateTask, TaskSpec};

const LOAD_ENV: &str = "JITTER_LOAD_S";
const PERIOD_NS: u64 = 5_000_000;
const DEADLINE_NS: u64 = 5_000_000;
const WIDTH: usize = 1024;
const HEIGHT: usize = 508;
/// The matcher allocates and warms up before the load is steady.
const LOAD_WARM_UP: Duration = Duration::from_millis(700);

fn main() {
    if let Ok(seconds) = std::env::var(LOAD_ENV) {
        let seconds: f64 = seconds.parse().unwrap_or(1.0);
        run_load(Duration::from_secs_f64(seconds));
        return;
    }
    let full = std::env::args().any(|a| a == "--bench");
    let duration = if full { Duration::from_secs(10) } else { Duration::from_secs(1) };
    println!(
        "filter task 200 Hz, deadline 5 ms, {} s per phase; load: SGM 1024x508, 4 paths, 2 threads",
        duration.as_secs()
    );

    let idle = measure("(a) idle", duration, None);
    let mut load = start_load(duration);
    let loaded = measure("(b) vision load", duration, None);
    let load_b = finish_load(&mut load);
    let mut load = start_load(duration);
    let rt_request = RtRequest { fifo_priority: Some(80), lock_memory: true, cpu: None };
    let realtime = measure("(c) vision load, SCHED_FIFO", duration, Some(rt_request));
    let load_c = finish_load(&mut load);

    println!();
    println!(
        "{:<30} {:>8} {:>9} {:>9} {:>9} {:>8} {:>7} {:>11} {:>9} {:>9}",
        "phase", "releases", "p50 µs", "p99 µs", "max µs", "overruns", "skipped", "exec max µs", "p99/idle", "max/idle"
    );
    for (phase, load) in [(&idle, None), (&loaded, load_b), (&realtime, load_c)] {
        let s = &phase.stats;
        let ratio = |v: u64, reference: u64| v as f64 / reference.max(1) as f64;
        println!(
            "{:<30} {:>8} {:>9.1} {:>9.1} {:>9.1} {:>8} {:>7} {:>11.1} {:>9.2} {:>9.2}",
            phase.name,
            s.releases,
            s.jitter_p50_ns as f64 / 1e3,
            s.jitter_p99_ns as f64 / 1e3,
            s.jitter_max_ns as f64 / 1e3,
            s.overruns,
            s.skipped,
            s.execution_max_ns as f64 / 1e3,
            ratio(s.jitter_p99_ns, idle.stats.jitter_p99_ns),
            ratio(s.jitter_max_ns, idle.stats.jitter_max_ns),
        );
        println!("{:<30} loadavg at start: {}", "", phase.loadavg);
        if let Some(load) = load {
            println!("{:<30} vision load: {load}", "");
        }
        if let Some(report) = &phase.rt {
            let applied = format!(
                "fifo {:?}, memory locked {}, cpu {:?}",
                report.fifo_priority, report.memory_locked, report.cpu
            );
            println!("{:<30} realtime applied: {applied}; skipped: {:?}", "", report.skipped);
        }
    }
}

struct Phase {
    name: &'static str,
    /// `/proc/loadavg` at the start: the machine is shared, and the idle reference is only as
    /// idle as it was.
    loadavg: String,
    stats: msgs::TaskStatsMsg,
    rt: Option<RtReport>,
}

/// Runs the filter task for `duration` on a fresh thread (so SCHED_FIFO ends with it).
fn measure(name: &'static str, duration: Duration, rt_request: Option<RtRequest>) -> Phase {
    let loadavg = std::fs::read_to_string("/proc/loadavg").unwrap_or_default().trim().to_string();
    let handle = std::thread::spawn(move || {
        let rt_report = rt_request.map(|r| rt::apply(&r));
        let spec = TaskSpec { name: "filter".into(), period_ns: PERIOD_NS, deadline_ns: DEADLINE_NS };
        let mut task = match FixedRateTask::monotonic(spec) {
            Ok(t) => t.with_identity(ProcessKind::Filter, 0),
            Err(e) => panic!("task spec: {e}"),
        };
        let mut step = FilterStep::new();
        let result = task.run_for_ns(duration.as_nanos() as u64, |release| step.run(release.index));
        if let Err(e) = result {
            panic!("filter step failed: {e}");
        }
        if rt_report.as_ref().is_some_and(|r| r.memory_locked) {
            let _ = nix::sys::mman::munlockall();
        }
        (task.stats(), rt_report)
    });
    match handle.join() {
        Ok((stats, rt)) => Phase { name, loadavg, stats, rt },
        Err(_) => panic!("measurement thread panicked"),
    }
}

/// The filter's work for one IMU sample.
struct FilterStep {
    filter: filter::Filter,
    checksum: f64,
}

impl FilterStep {
    fn new() -> FilterStep {
        let noise = filter::ImuNoise {
            gyro_noise_density: 1.7e-4,
            gyro_random_walk: 2e-5,
            accel_noise_density: 2e-3,
            accel_random_walk: 3e-3,
        };
        let mut f = filter::Filter::new(filter::FilterConfig::from_imu_noise(noise, 9.81));
        if let Err(e) = f.initialize_at_rest(0, &Vector3::new(0.0, 0.0, 9.81), &Vector3::zeros()) {
            panic!("filter init: {e}");
        }
        FilterStep { filter: f, checksum: 0.0 }
    }

    fn run(&mut self, index: u64) -> Result<(), filter::FilterError> {
        // Sensor time follows the release index: skipped releases are lost samples here.
        let stamp_ns = (index + 1) * PERIOD_NS;
        let t = stamp_ns as f64 * 1e-9;
        let sample = ImuSample {
            stamp_ns,
            gyro_radps: Vector3::new(0.01 * t.sin(), 0.02 * t.cos(), 0.05),
            accel_mps2: Vector3::new(0.1 * t.cos(), 0.0, 9.81),
        };
        self.filter.propagate(&sample)?;
        if let Some(state) = self.filter.state() {
            let msg = FilterStateMsg {
                stamp_ns: state.stamp_ns,
                t_local_body: Pose::from_isometry(&state.t_local_body),
                v_local_mps: state.v_local_mps.into(),
                accel_bias_mps2: state.accel_bias_mps2.into(),
                gyro_bias_radps: state.gyro_bias_radps.into(),
                pose_covariance: covariance_to_array(&self.filter.pose_covariance()),
                imu_received: index + 1,
                imu_lost: 0,
                frame_id: state.frame_id,
                status: FilterStateMsg::RUNNING,
                last_vo_capture_ns: FilterStateMsg::NEVER,
            };
            self.checksum += black_box(&msg).pose_covariance[0];
        }
        black_box(self.checksum);
        Ok(())
    }
}

fn start_load(duration: Duration) -> Option<Child> {
    let exe = std::env::current_exe().ok()?;
    let seconds = (duration + LOAD_WARM_UP + Duration::from_millis(300)).as_secs_f64();
    let child = Command::new(exe).env(LOAD_ENV, format!("{seconds}")).stdout(Stdio::piped()).spawn();
    match child {
        Ok(child) => {
            std::thread::sleep(LOAD_WARM_UP);
            Some(child)
        }
        Err(e) => {
            eprintln!("could not start the load process: {e}");
            None
        }
    }
}

/// Waits for the load process and returns its summary line.
fn finish_load(child: &mut Option<Child>) -> Option<String> {
    let mut child = child.take()?;
    let mut out = String::new();
    if let Some(stdout) = child.stdout.as_mut() {
        let _ = stdout.read_to_string(&mut out);
    }
    let _ = child.wait();
    Some(out.trim().to_string())
}

/// The vision process's stereo workload, for `duration`.
fn run_load(duration: Duration) {
    let config = SgmConfig { paths: PathMode::Four, disparities: 128, ..SgmConfig::default() };
    let mut matcher = match Matcher::new(config, WIDTH, HEIGHT, 2) {
        Ok(m) => m,
        Err(e) => panic!("matcher: {e}"),
    };
    // A textured pair with a 20 px shift: every stage has real work.
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let left: Vec<u8> = (0..WIDTH * HEIGHT)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            (state >> 56) as u8
        })
        .collect();
    let right: Vec<u8> =
        (0..WIDTH * HEIGHT).map(|i| left[(i / WIDTH) * WIDTH + (i % WIDTH + 20).min(WIDTH - 1)]).collect();
    let (left, right) = match (GrayImage::new(WIDTH, HEIGHT, left), GrayImage::new(WIDTH, HEIGHT, right)) {
        (Ok(l), Ok(r)) => (l, r),
        _ => panic!("bad synthetic images"),
    };
    let mut out = DisparityImage { width: WIDTH, height: HEIGHT, data: Vec::new() };
    let start = Instant::now();
    let mut frames = 0u64;
    while start.elapsed() < duration {
        if let Err(e) = matcher.compute_into(&left, &right, &mut out) {
            panic!("matcher: {e}");
        }
        frames += 1;
    }
    let wall_s = start.elapsed().as_secs_f64();
    let cpu_s = nix::sys::resource::getrusage(nix::sys::resource::UsageWho::RUSAGE_SELF)
        .map(|u| {
            use nix::sys::time::TimeValLike;
            (u.user_time().num_microseconds() + u.system_time().num_microseconds()) as f64 * 1e-6
        })
        .unwrap_or(0.0);
    println!(
        "{frames} frames in {wall_s:.1} s ({:.1} fps, {:.0} ms/frame), CPU {:.2} cores",
        frames as f64 / wall_s,
        wall_s * 1e3 / frames.max(1) as f64,
        cpu_s / wall_s
    );
}
