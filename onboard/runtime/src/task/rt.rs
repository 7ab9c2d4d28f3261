//! Real-time set-up of a process: SCHED_FIFO for the calling thread, locked memory, CPU affinity
//! of the calling thread. Each is attempted on its own; one that is not permitted (no
//! CAP_SYS_NICE / RLIMIT_RTPRIO, a container's seccomp or cgroup, a CPU that is not there) is
//! skipped with one log line, and the process runs on with normal scheduling. Call it from the
//! thread that runs the fixed-rate task, before the loop starts (new threads inherit both).

use nix::sched::{CpuSet, sched_setaffinity};
use nix::sys::mman::{MlockAllFlags, mlockall};
use nix::unistd::Pid;
use thread_priority::{
    RealtimeThreadSchedulePolicy, ThreadPriority, ThreadPriorityValue, ThreadSchedulePolicy,
    set_thread_priority_and_policy, thread_native_id,
};

/// What to ask for.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct RtRequest {
    /// SCHED_FIFO priority 1..=99 for the calling thread; `None` keeps normal scheduling.
    pub fifo_priority: Option<u8>,
    /// `mlockall(MCL_CURRENT | MCL_FUTURE)`: no page fault on the task's path after start.
    pub lock_memory: bool,
    /// Pin the calling thread to this CPU.
    pub cpu: Option<usize>,
}

/// What was actually applied, and why the rest was not.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct RtReport {
    pub fifo_priority: Option<u8>,
    pub memory_locked: bool,
    pub cpu: Option<usize>,
    /// One line per requested item that was skipped (also written to stderr).
    pub skipped: Vec<String>,
}

impl RtReport {
    /// Everything requested was applied.
    pub fn complete(&self) -> bool {
        self.skipped.is_empty()
    }
}

/// Applies what is permitted of `request`; never fails.
pub fn apply(request: &RtRequest) -> RtReport {
    let mut report = RtReport::default();
    let mut skip = |line: String| {
        eprintln!("realtime: {line}; continuing without it");
        report.skipped.push(line);
    };

    let mut applied_cpu = None;
    if let Some(cpu) = request.cpu {
        match pin_to_cpu(cpu) {
            Ok(()) => applied_cpu = Some(cpu),
            Err(why) => skip(format!("CPU affinity to CPU {cpu} not applied: {why}")),
        }
    }
    let mut memory_locked = false;
    if request.lock_memory {
        match mlockall(MlockAllFlags::MCL_CURRENT | MlockAllFlags::MCL_FUTURE) {
            Ok(()) => memory_locked = true,
            Err(errno) => skip(format!("mlockall(MCL_CURRENT|MCL_FUTURE) not applied: {}", explain(errno))),
        }
    }
    let mut fifo_priority = None;
    if let Some(priority) = request.fifo_priority {
        match set_fifo(priority) {
            Ok(()) => fifo_priority = Some(priority),
            Err(why) => skip(format!("SCHED_FIFO priority {priority} not applied: {why}")),
        }
    }
    report.cpu = applied_cpu;
    report.memory_locked = memory_locked;
    report.fifo_priority = fifo_priority;
    report
}

fn pin_to_cpu(cpu: usize) -> Result<(), String> {
    let mut set = CpuSet::new();
    set.set(cpu).map_err(|_| format!("CPU index beyond the {} a CPU set holds", CpuSet::count()))?;
    // Pid 0 is the calling thread.
    sched_setaffinity(Pid::from_raw(0), &set).map_err(explain)
}

fn set_fifo(priority: u8) -> Result<(), String> {
    if !(1..=99).contains(&priority) {
        return Err("priority must be 1..=99".into());
    }
    let value = ThreadPriorityValue::try_from(priority).map_err(|e| e.to_string())?;
    set_thread_priority_and_policy(
        thread_native_id(),
        ThreadPriority::Crossplatform(value),
        ThreadSchedulePolicy::Realtime(RealtimeThreadSchedulePolicy::Fifo),
    )
    .map_err(|e| match e {
        thread_priority::Error::OS(code) => explain(nix::errno::Errno::from_raw(code)),
        other => other.to_string(),
    })
}

fn explain(errno: nix::errno::Errno) -> String {
    use nix::errno::Errno;
    match errno {
        Errno::EPERM => "not permitted (EPERM: needs CAP_SYS_NICE/CAP_IPC_LOCK or a raised rlimit)".into(),
        Errno::ENOMEM => "ENOMEM (RLIMIT_MEMLOCK too small to lock the process)".into(),
        Errno::EINVAL => "EINVAL (not available here)".into(),
        other => format!("{other}"),
    }
}

/// For a background thread of a real-time process (the mapper's matcher): `SCHED_IDLE`, so it
/// runs only when no other thread of the machine wants the CPU, and every online CPU, undoing
/// the task thread's pinning it inherited. What is not permitted is skipped with one log line.
pub fn idle_background_thread() {
    let idle = ThreadSchedulePolicy::Normal(thread_priority::NormalThreadSchedulePolicy::Idle);
    if let Err(e) = set_thread_priority_and_policy(thread_native_id(), ThreadPriority::Min, idle) {
        eprintln!("realtime: SCHED_IDLE for a background thread not applied: {e}; it keeps the task's class");
    }
    // Every bit: the kernel keeps the CPUs that exist (the inherited pinning hides how many).
    let mut all = CpuSet::new();
    for cpu in 0..CpuSet::count() {
        let _ = all.set(cpu);
    }
    if let Err(errno) = sched_setaffinity(Pid::from_raw(0), &all) {
        eprintln!("realtime: CPU affinity of a background thread not widened: {}", explain(errno));
    }
}
