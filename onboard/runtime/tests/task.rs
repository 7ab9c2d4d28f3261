//! Fixed-rate tasks: release grid, overrun and skip accounting on a simulated clock (no timing
//! assumptions), the jitter histogram against exact quantiles, process usage parsers, and the
//! real-time set-up never failing hard.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::convert::Infallible;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use msgs::ProcessKind;
use onboard::task::rt::{self, RtRequest};
use onboard::task::{
    Clock, FixedRateTask, LogHistogram, MonotonicClock, Release, RunEnd, SimClock, TaskSpec, parse_statm_rss_bytes,
    parse_status_rss_bytes,
};
use proptest::prelude::*;

const MS: u64 = 1_000_000;

fn spec(period_ns: u64, deadline_ns: u64) -> TaskSpec {
    TaskSpec { name: "test".into(), period_ns, deadline_ns }
}

fn ok() -> Result<(), Infallible> {
    Ok(())
}

#[test]
fn releases_follow_the_absolute_grid_whatever_the_run_time() {
    let clock = Arc::new(SimClock::new(1_000 * MS));
    clock.set_wake_latency_ns(300_000);
    let mut task = FixedRateTask::new(spec(5 * MS, 5 * MS), Arc::clone(&clock)).unwrap();
    let mut seen: Vec<Release> = Vec::new();
    let body_clock = Arc::clone(&clock);
    let end = task
        .run_for_releases(20, |r| {
            seen.push(*r);
            // Run times 0..4 ms: a drifting `sleep(period)` loop would shift every later release.
            body_clock.advance_ns((r.index % 5) * 900_000);
            ok()
        })
        .unwrap();
    assert_eq!(end, RunEnd::LimitReached);
    assert_eq!(seen.len(), 20);
    for (k, r) in seen.iter().enumerate() {
        assert_eq!(r.index, k as u64);
        assert_eq!(r.planned_ns, 1_000 * MS + k as u64 * 5 * MS, "release {k} on the grid");
        // Release 0 is "now" (no sleep); every later one wakes 300 µs late.
        let latency = if k == 0 { 0 } else { 300_000 };
        assert_eq!(r.start_ns, r.planned_ns + latency);
    }
    let c = task.counters();
    assert_eq!((c.releases, c.overruns, c.skipped), (20, 0, 0));
    assert_eq!(c.jitter_ns.max(), 300_000);
    assert_eq!(c.execution_max_ns, 4 * 900_000);
    assert_eq!(task.next_release_ns(), Some(1_000 * MS + 20 * 5 * MS));
}

#[test]
fn an_overrun_past_later_releases_skips_them_and_realigns() {
    let clock = Arc::new(SimClock::new(0));
    let mut task = FixedRateTask::new(spec(10 * MS, 5 * MS), Arc::clone(&clock)).unwrap();
    let body_clock = Arc::clone(&clock);
    let mut seen = Vec::new();
    task.run_for_releases(6, |r| {
        seen.push((r.index, r.planned_ns, r.start_ns));
        let run_ns = match r.index {
            1 => 7 * MS,  // past the deadline, inside the period: overrun, nothing skipped
            2 => 26 * MS, // finishes at 46 ms: releases at 30 and 40 ms are gone
            6 => 10 * MS, // finishes exactly at the next release (70 ms): it is not skipped
            _ => MS,
        };
        body_clock.advance_ns(run_ns);
        ok()
    })
    .unwrap();
    let indices: Vec<u64> = seen.iter().map(|s| s.0).collect();
    assert_eq!(indices, [0, 1, 2, 5, 6, 7]);
    for (index, planned, start) in &seen {
        assert_eq!(*planned, index * 10 * MS);
        assert_eq!(start, planned, "a release is run on time or not at all");
    }
    let c = task.counters();
    assert_eq!(c.releases, 6);
    assert_eq!(c.skipped, 2);
    assert_eq!(c.overruns, 3, "runs 1, 2 and 6 finish after release + 5 ms");
    assert_eq!(c.execution_max_ns, 26 * MS);
    assert_eq!(c.jitter_ns.max(), 0);
}

#[test]
fn the_stop_flag_ends_the_loop_before_the_next_release() {
    let clock = SimClock::new(0);
    let mut task = FixedRateTask::new(spec(5 * MS, 5 * MS), &clock).unwrap();
    let stop = task.stop_flag();
    let mut runs = 0;
    let end = task
        .run(|r| {
            runs += 1;
            if r.index == 3 {
                stop.store(true, Ordering::Relaxed);
            }
            ok()
        })
        .unwrap();
    assert_eq!(end, RunEnd::Stopped);
    assert_eq!(runs, 4);
    assert_eq!(task.counters().releases, 4);
}

#[test]
fn run_for_ns_runs_the_releases_inside_the_window_and_later_runs_continue_the_grid() {
    let clock = SimClock::new(7);
    let mut task = FixedRateTask::new(spec(5 * MS, 2 * MS), &clock).unwrap();
    let mut planned = Vec::new();
    task.run_for_ns(50 * MS, |r| {
        planned.push(r.planned_ns);
        ok()
    })
    .unwrap();
    assert_eq!(planned.len(), 10);
    task.run_for_releases(2, |r| {
        planned.push(r.planned_ns);
        ok()
    })
    .unwrap();
    let expected: Vec<u64> = (0..12).map(|k| 7 + k * 5 * MS).collect();
    assert_eq!(planned, expected);
}

#[test]
fn a_failing_body_ends_the_run_with_its_error_and_is_still_counted() {
    let clock = SimClock::new(0);
    let mut task = FixedRateTask::new(spec(MS, MS), &clock).unwrap();
    let result = task.run(|r| if r.index == 2 { Err(format!("failed at {}", r.index)) } else { Ok(()) });
    assert_eq!(result.unwrap_err(), "failed at 2");
    assert_eq!(task.counters().releases, 3);
}

#[test]
fn stats_carry_the_counters_and_this_process_usage() {
    let clock = Arc::new(SimClock::new(0));
    let mut task =
        FixedRateTask::new(spec(10 * MS, 4 * MS), Arc::clone(&clock)).unwrap().with_identity(ProcessKind::Filter, 2);
    let body_clock = Arc::clone(&clock);
    task.run_for_releases(3, |r| {
        body_clock.advance_ns(if r.index == 1 { 15 * MS } else { MS });
        ok()
    })
    .unwrap();
    let stats = task.stats();
    assert_eq!((stats.period_ns, stats.deadline_ns), (10 * MS, 4 * MS));
    assert_eq!((stats.releases, stats.overruns, stats.skipped), (3, 1, 1));
    assert_eq!(stats.execution_max_ns, 15 * MS);
    assert_eq!(stats.process, ProcessKind::Filter as u32);
    assert_eq!(stats.task, 2);
    assert_eq!(stats.stamp_ns, clock.now_ns());
    assert!(stats.process_cpu_ns > 0, "this test process has used CPU");
    assert!(stats.process_rss_bytes > 1 << 20, "RSS {} bytes", stats.process_rss_bytes);
}

#[test]
fn the_monotonic_clock_never_wakes_before_the_release() {
    let mut task = FixedRateTask::monotonic(spec(MS, MS)).unwrap();
    let mut seen = Vec::new();
    task.run_for_releases(5, |r| {
        seen.push(*r);
        ok()
    })
    .unwrap();
    assert_eq!(task.counters().releases, 5);
    for r in &seen {
        assert!(r.start_ns >= r.planned_ns, "{r:?}");
    }
    assert!(MonotonicClock.now_ns() >= seen[4].planned_ns);
}

#[test]
fn specs_are_validated() {
    let s = TaskSpec::from_rate("filter", 200.0, 0.5).unwrap();
    assert_eq!((s.period_ns, s.deadline_ns), (5_000_000, 2_500_000));
    assert!(TaskSpec::from_rate("x", 0.0, 0.5).is_err());
    assert!(TaskSpec::from_rate("x", f64::NAN, 0.5).is_err());
    let err = FixedRateTask::new(spec(MS, 2 * MS), SimClock::new(0)).unwrap_err();
    assert!(err.to_string().contains("deadline"), "{err}");
    assert!(FixedRateTask::new(spec(0, 0), SimClock::new(0)).is_err());
}

#[test]
fn realtime_setup_never_fails_hard_and_reports_what_it_did() {
    // In its own thread: SCHED_FIFO and the affinity apply to the calling thread only.
    let report =
        std::thread::spawn(|| rt::apply(&RtRequest { fifo_priority: Some(10), lock_memory: true, cpu: Some(0) }))
            .join()
            .unwrap();
    // Each item is either applied or skipped with a reason, never both, never neither.
    let requested = 3;
    let applied = usize::from(report.fifo_priority == Some(10))
        + usize::from(report.memory_locked)
        + usize::from(report.cpu == Some(0));
    assert_eq!(applied + report.skipped.len(), requested, "{report:?}");
    if report.memory_locked {
        // Do not leave the whole test process locked in memory.
        nix::sys::mman::munlockall().unwrap();
    }

    let impossible =
        std::thread::spawn(|| rt::apply(&RtRequest { fifo_priority: Some(0), lock_memory: false, cpu: Some(5000) }))
            .join()
            .unwrap();
    assert_eq!((impossible.fifo_priority, impossible.cpu, impossible.memory_locked), (None, None, false));
    assert_eq!(impossible.skipped.len(), 2, "{impossible:?}");
    assert!(impossible.skipped.iter().any(|l| l.contains("SCHED_FIFO") && l.contains("1..=99")));
    assert!(impossible.skipped.iter().any(|l| l.contains("CPU 5000")));

    // A CPU index a set can hold but this machine does not have: refused by the kernel.
    let absent_cpu =
        std::thread::spawn(|| rt::apply(&RtRequest { fifo_priority: None, lock_memory: false, cpu: Some(1023) }))
            .join()
            .unwrap();
    assert_eq!(absent_cpu.cpu, None);
    assert!(absent_cpu.skipped.len() == 1 && absent_cpu.skipped[0].contains("CPU 1023"), "{absent_cpu:?}");

    let nothing = rt::apply(&RtRequest::default());
    assert!(nothing.complete());
}

#[test]
fn usage_parsers() {
    let status = "Name:\tonboard\nVmPeak:\t  9000 kB\nVmRSS:\t    1676 kB\nThreads:\t1\n";
    assert_eq!(parse_status_rss_bytes(status), Some(1676 * 1024));
    assert_eq!(parse_status_rss_bytes("VmRSS: x kB"), None);
    assert_eq!(parse_status_rss_bytes("VmRSS: 12"), None);
    assert_eq!(parse_status_rss_bytes(""), None);
    assert_eq!(parse_statm_rss_bytes("2360 419 378 2 0 152 0\n", 4096), Some(419 * 4096));
    assert_eq!(parse_statm_rss_bytes("2360", 4096), None);
    assert_eq!(parse_statm_rss_bytes("1 18446744073709551615", 4096), None);
}

#[test]
fn empty_histogram_is_all_zero() {
    let h = LogHistogram::new();
    assert_eq!((h.count(), h.quantile(0.5), h.quantile(0.99), h.max()), (0, 0, 0, 0));
}

proptest! {
    #[test]
    fn histogram_quantiles_are_within_one_sixteenth_of_exact(
        values in prop::collection::vec(prop_oneof![0u64..100, 0u64..10_000_000, any::<u64>()], 1..400),
        q in 0.0f64..=1.0,
    ) {
        let mut h = LogHistogram::new();
        for &v in &values {
            h.record(v);
        }
        let mut sorted = values.clone();
        sorted.sort_unstable();
        let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
        let exact = sorted[rank - 1];
        let estimate = h.quantile(q);
        prop_assert!(estimate >= exact, "estimate {} < exact {}", estimate, exact);
        prop_assert!(estimate - exact <= exact / 16, "estimate {} vs exact {}", estimate, exact);
        prop_assert_eq!(h.max(), *sorted.last().unwrap());
        prop_assert_eq!(h.count(), values.len() as u64);
    }

    #[test]
    fn usage_parsers_never_panic(text in ".{0,200}", page in any::<u64>()) {
        let _ = parse_status_rss_bytes(&text);
        let _ = parse_statm_rss_bytes(&text, page);
    }
}
