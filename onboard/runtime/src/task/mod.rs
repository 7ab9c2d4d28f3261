//! Fixed-rate tasks with deadlines (DESIGN §3.2).
//!
//! A [`FixedRateTask`] runs its body at the absolute release times `start + k·period` of a grid
//! fixed when it first runs. The wrong way drifts:
//!
//! ```text
//! loop { body(); sleep(period) }          // every run's duration and wake-up delay add up
//! ```
//!
//! the right way sleeps *until* the next release (`clock_nanosleep(TIMER_ABSTIME)`), so a late
//! wake-up delays one run, never the grid.
//!
//! Overrun policy: a release is either run at its time (plus wake-up jitter) or skipped, never
//! run late in a burst. When a run finishes after later releases have passed, those are counted
//! as skipped and the task waits for the next release still ahead of it. A run that finishes
//! after `release + deadline` counts as a deadline overrun.
//!
//! Counters: releases run, overruns, skipped releases, release jitter (actual start − planned
//! release) in a fixed-memory [`LogHistogram`] (p50/p99/max), longest execution time. They are
//! published as [`msgs::TaskStatsMsg`] by [`FixedRateTask::stats`].
//!
//! The loop is generic over a [`Clock`]: [`MonotonicClock`] on the rover, [`SimClock`] in tests,
//! where the release, overrun and skip logic is checked without any timing assumption.

mod clock;
pub mod histogram;
pub mod rt;
pub mod usage;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};

pub use clock::{Clock, MonotonicClock, SimClock};
pub use histogram::LogHistogram;
pub use usage::{ProcessUsage, UsageError, parse_statm_rss_bytes, parse_status_rss_bytes};

use msgs::{ProcessKind, TaskStatsMsg};

/// A task's timing contract.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TaskSpec {
    pub name: String,
    pub period_ns: u64,
    /// Time after each release by which the run must have finished; `0 < deadline ≤ period`.
    pub deadline_ns: u64,
}

impl TaskSpec {
    /// A task at `rate_hz` whose deadline is `deadline_fraction` of its period.
    pub fn from_rate(name: &str, rate_hz: f64, deadline_fraction: f64) -> Result<TaskSpec, TaskError> {
        if !(rate_hz.is_finite() && rate_hz > 0.0) {
            return Err(TaskError::InvalidSpec { task: name.into(), reason: format!("rate {rate_hz} Hz") });
        }
        let period_ns = (1e9 / rate_hz).round() as u64;
        let deadline_ns = (period_ns as f64 * deadline_fraction).round() as u64;
        let spec = TaskSpec { name: name.into(), period_ns, deadline_ns };
        spec.validate()?;
        Ok(spec)
    }

    pub fn validate(&self) -> Result<(), TaskError> {
        let reason = if self.period_ns == 0 {
            "period must be positive".to_string()
        } else if self.deadline_ns == 0 || self.deadline_ns > self.period_ns {
            format!("deadline {} ns must be in 1..={} ns (the period)", self.deadline_ns, self.period_ns)
        } else {
            return Ok(());
        };
        Err(TaskError::InvalidSpec { task: self.name.clone(), reason })
    }
}

#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    #[error("task {task}: {reason}")]
    InvalidSpec { task: String, reason: String },
}

/// One release as the body sees it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Release {
    /// Index on the task's grid (skipped releases leave gaps).
    pub index: u64,
    pub planned_ns: u64,
    /// When the body actually started (clock time).
    pub start_ns: u64,
}

/// Why a `run*` call returned.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RunEnd {
    /// The stop flag was set.
    Stopped,
    /// The requested number of releases or the end time was reached.
    LimitReached,
}

/// The task's counters over its life.
#[derive(Debug, Clone, Default)]
pub struct TaskCounters {
    pub releases: u64,
    pub overruns: u64,
    pub skipped: u64,
    pub jitter_ns: LogHistogram,
    pub execution_max_ns: u64,
}

/// A body run on absolute release times; see the module docs.
#[derive(Debug)]
pub struct FixedRateTask<C: Clock = MonotonicClock> {
    spec: TaskSpec,
    clock: C,
    stop: Arc<AtomicBool>,
    /// Release 0 of the grid; set by the first run.
    start_ns: Option<u64>,
    next_index: u64,
    counters: TaskCounters,
    process: ProcessKind,
    task_index: u32,
}

enum Limit {
    Forever,
    Releases(u64),
    /// Run releases planned strictly before this clock time.
    Until(u64),
}

impl FixedRateTask<MonotonicClock> {
    pub fn monotonic(spec: TaskSpec) -> Result<Self, TaskError> {
        FixedRateTask::new(spec, MonotonicClock)
    }
}

impl<C: Clock> FixedRateTask<C> {
    pub fn new(spec: TaskSpec, clock: C) -> Result<Self, TaskError> {
        spec.validate()?;
        Ok(FixedRateTask {
            spec,
            clock,
            stop: Arc::new(AtomicBool::new(false)),
            start_ns: None,
            next_index: 0,
            counters: TaskCounters::default(),
            process: ProcessKind::Supervisor,
            task_index: 0,
        })
    }

    /// Which process and task index the telemetry names.
    pub fn with_identity(mut self, process: ProcessKind, task_index: u32) -> Self {
        self.process = process;
        self.task_index = task_index;
        self
    }

    /// Shares an existing stop flag (e.g. the one a SIGTERM handler sets).
    pub fn with_stop_flag(mut self, stop: Arc<AtomicBool>) -> Self {
        self.stop = stop;
        self
    }

    /// Places release 0 at `start_ns` instead of the time of the first run (tasks of several
    /// processes can share one grid this way).
    pub fn with_start_ns(mut self, start_ns: u64) -> Self {
        self.start_ns = Some(start_ns);
        self
    }

    /// Setting it ends the loop after the current run (checked before and after every sleep).
    pub fn stop_flag(&self) -> Arc<AtomicBool> {
        Arc::clone(&self.stop)
    }

    pub fn spec(&self) -> &TaskSpec {
        &self.spec
    }

    pub fn clock(&self) -> &C {
        &self.clock
    }

    pub fn counters(&self) -> &TaskCounters {
        &self.counters
    }

    /// The next release's planned time, if the grid is set.
    pub fn next_release_ns(&self) -> Option<u64> {
        self.start_ns.map(|s| self.release_time(s, self.next_index))
    }

    /// Runs until the stop flag is set or the body fails.
    pub fn run<E>(&mut self, body: impl FnMut(&Release) -> Result<(), E>) -> Result<RunEnd, E> {
        self.run_limited(Limit::Forever, body)
    }

    /// Runs `releases` more releases (skipped ones do not count).
    pub fn run_for_releases<E>(
        &mut self,
        releases: u64,
        body: impl FnMut(&Release) -> Result<(), E>,
    ) -> Result<RunEnd, E> {
        self.run_limited(Limit::Releases(releases), body)
    }

    /// Runs the releases planned within `duration_ns` from now.
    pub fn run_for_ns<E>(
        &mut self,
        duration_ns: u64,
        body: impl FnMut(&Release) -> Result<(), E>,
    ) -> Result<RunEnd, E> {
        let end = self.clock.now_ns().saturating_add(duration_ns);
        self.run_limited(Limit::Until(end), body)
    }

    fn release_time(&self, start_ns: u64, index: u64) -> u64 {
        start_ns.saturating_add(index.saturating_mul(self.spec.period_ns))
    }

    fn run_limited<E>(&mut self, limit: Limit, mut body: impl FnMut(&Release) -> Result<(), E>) -> Result<RunEnd, E> {
        let start_ns = *self.start_ns.get_or_insert_with(|| self.clock.now_ns());
        let mut ran = 0u64;
        loop {
            if self.stop.load(Ordering::Relaxed) {
                return Ok(RunEnd::Stopped);
            }
            let planned_ns = self.release_time(start_ns, self.next_index);
            match limit {
                Limit::Releases(n) if ran >= n => return Ok(RunEnd::LimitReached),
                Limit::Until(end) if planned_ns >= end => return Ok(RunEnd::LimitReached),
                _ => {}
            }
            self.clock.sleep_until_ns(planned_ns);
            // A stop requested during the sleep must not cost one more run.
            if self.stop.load(Ordering::Relaxed) {
                return Ok(RunEnd::Stopped);
            }
            let begin_ns = self.clock.now_ns();
            let release = Release { index: self.next_index, planned_ns, start_ns: begin_ns };
            let result = body(&release);
            let finish_ns = self.clock.now_ns();

            let c = &mut self.counters;
            c.releases += 1;
            c.jitter_ns.record(begin_ns.saturating_sub(planned_ns));
            c.execution_max_ns = c.execution_max_ns.max(finish_ns.saturating_sub(begin_ns));
            if finish_ns > planned_ns.saturating_add(self.spec.deadline_ns) {
                c.overruns += 1;
            }
            // The next release is the first one of the grid not yet passed at the finish; the
            // ones in between are skipped, never run late.
            let mut next = self.next_index + 1;
            let elapsed = finish_ns.saturating_sub(start_ns);
            let first_ahead = elapsed.div_ceil(self.spec.period_ns);
            if first_ahead > next {
                c.skipped += first_ahead - next;
                next = first_ahead;
            }
            self.next_index = next;
            ran += 1;
            result?;
        }
    }

    /// The counters as telemetry, stamped with the task's clock, with this process's CPU time
    /// and RSS (zero if they cannot be read).
    pub fn stats(&self) -> TaskStatsMsg {
        let usage = ProcessUsage::now().unwrap_or_default();
        let c = &self.counters;
        TaskStatsMsg {
            stamp_ns: self.clock.now_ns(),
            period_ns: self.spec.period_ns,
            deadline_ns: self.spec.deadline_ns,
            releases: c.releases,
            overruns: c.overruns,
            skipped: c.skipped,
            jitter_p50_ns: c.jitter_ns.quantile(0.5),
            jitter_p99_ns: c.jitter_ns.quantile(0.99),
            jitter_max_ns: c.jitter_ns.max(),
            execution_max_ns: c.execution_max_ns,
            process_cpu_ns: usage.cpu_ns,
            process_rss_bytes: usage.rss_bytes,
            process: self.process as u32,
            task: self.task_index,
            queue_topic: 0,
            queue_depth_max: 0,
            queue_capacity: 0,
            devices: 0,
        }
    }
}
