//! Clocks a fixed-rate task runs on: the monotonic wall clock of the process runner, and a
//! simulated clock that makes the release logic testable without timing.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use nix::errno::Errno;
use nix::sys::time::TimeSpec;
use nix::time::{ClockId, ClockNanosleepFlags, clock_gettime, clock_nanosleep};

/// A source of time for [`super::FixedRateTask`]: nanoseconds on a monotonic axis, and a sleep
/// until an absolute point of that axis.
pub trait Clock {
    fn now_ns(&self) -> u64;
    /// Returns at or after `t_ns` (immediately if it has passed).
    fn sleep_until_ns(&self, t_ns: u64);
}

impl<C: Clock + ?Sized> Clock for &C {
    fn now_ns(&self) -> u64 {
        (**self).now_ns()
    }
    fn sleep_until_ns(&self, t_ns: u64) {
        (**self).sleep_until_ns(t_ns)
    }
}

impl<C: Clock + ?Sized> Clock for Arc<C> {
    fn now_ns(&self) -> u64 {
        (**self).now_ns()
    }
    fn sleep_until_ns(&self, t_ns: u64) {
        (**self).sleep_until_ns(t_ns)
    }
}

/// `CLOCK_MONOTONIC`, slept on with `clock_nanosleep(TIMER_ABSTIME)`: the wake-up is tied to the
/// absolute release time, so time spent between reading the clock and going to sleep does not
/// shift the release (a relative `sleep(period − elapsed)` would).
#[derive(Debug, Clone, Copy, Default)]
pub struct MonotonicClock;

impl Clock for MonotonicClock {
    fn now_ns(&self) -> u64 {
        match clock_gettime(ClockId::CLOCK_MONOTONIC) {
            Ok(t) => timespec_to_ns(&t),
            // CLOCK_MONOTONIC cannot fail on Linux; falling back keeps the type total.
            Err(_) => std_monotonic_ns(),
        }
    }

    fn sleep_until_ns(&self, t_ns: u64) {
        let request = TimeSpec::new((t_ns / 1_000_000_000) as i64, (t_ns % 1_000_000_000) as i64);
        loop {
            match clock_nanosleep(ClockId::CLOCK_MONOTONIC, ClockNanosleepFlags::TIMER_ABSTIME, &request) {
                // A signal (SIGTERM for the stop flag, SIGCHLD) wakes us early: with an absolute
                // deadline, sleeping again is exact.
                Err(Errno::EINTR) => continue,
                Ok(_) => return,
                Err(_) => {
                    let now = self.now_ns();
                    if now < t_ns {
                        std::thread::sleep(std::time::Duration::from_nanos(t_ns - now));
                    }
                    return;
                }
            }
        }
    }
}

fn timespec_to_ns(t: &TimeSpec) -> u64 {
    (t.tv_sec().max(0) as u64).saturating_mul(1_000_000_000).saturating_add(t.tv_nsec().max(0) as u64)
}

fn std_monotonic_ns() -> u64 {
    use std::sync::OnceLock;
    static ORIGIN: OnceLock<std::time::Instant> = OnceLock::new();
    ORIGIN.get_or_init(std::time::Instant::now).elapsed().as_nanos() as u64
}

/// Simulated time for tests: it stands still until someone moves it. A sleep jumps to its
/// target plus the configured wake-up latency (a stand-in for scheduler jitter); a task body
/// "takes time" by calling [`SimClock::advance_ns`].
#[derive(Debug, Default)]
pub struct SimClock {
    now_ns: AtomicU64,
    wake_latency_ns: AtomicU64,
}

impl SimClock {
    pub fn new(start_ns: u64) -> SimClock {
        SimClock { now_ns: AtomicU64::new(start_ns), wake_latency_ns: AtomicU64::new(0) }
    }

    pub fn advance_ns(&self, dt_ns: u64) {
        self.now_ns.fetch_add(dt_ns, Ordering::SeqCst);
    }

    /// Every following sleep returns this long after its target.
    pub fn set_wake_latency_ns(&self, latency_ns: u64) {
        self.wake_latency_ns.store(latency_ns, Ordering::SeqCst);
    }
}

impl Clock for SimClock {
    fn now_ns(&self) -> u64 {
        self.now_ns.load(Ordering::SeqCst)
    }

    fn sleep_until_ns(&self, t_ns: u64) {
        // Like the real clock, a target in the past returns at once (no wake-up latency).
        if self.now_ns() < t_ns {
            let wake = t_ns.saturating_add(self.wake_latency_ns.load(Ordering::SeqCst));
            self.now_ns.fetch_max(wake, Ordering::SeqCst);
        }
    }
}
