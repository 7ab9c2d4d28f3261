//! Token bucket: the bytes it lets through never exceed `rate·T/1000 + burst` over any interval
//! of `T` ms, whatever the sequence of requests, and `time_until` is exact.

// Test helpers too may unwrap and panic: a panic is a failed test with a backtrace.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use proptest::prelude::*;
use protocol::delivery::TokenBucket;

/// Checks every interval `[t_i, t_j]` spanned by granted requests (exact integer arithmetic).
fn assert_within_cap(granted: &[(u64, u64)], rate: u64, burst: u64) {
    for i in 0..granted.len() {
        let mut bytes = 0u64;
        for j in i..granted.len() {
            bytes += granted[j].1;
            let span_ms = granted[j].0 - granted[i].0;
            assert!(
                1000 * bytes <= rate * span_ms + 1000 * burst,
                "{bytes} bytes in {span_ms} ms exceed rate {rate} B/s + burst {burst} B"
            );
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, ..ProptestConfig::default() })]

    #[test]
    fn never_exceeds_rate_times_interval_plus_burst(
        rate in 1u64..200_000,
        burst in 1u64..5_000,
        requests in proptest::collection::vec((0u64..50, 0u64..3_000), 1..300),
    ) {
        let mut bucket = TokenBucket::new(rate, burst, 0);
        let mut now = 0u64;
        let mut granted = Vec::new();
        for (dt, bytes) in requests {
            now += dt;
            let wait = bucket.time_until(now, bytes);
            let ok = bucket.try_consume(now, bytes);
            // time_until is exact: 0 exactly when the request succeeds now.
            prop_assert_eq!(ok, wait == 0);
            if ok {
                granted.push((now, bytes));
            }
        }
        assert_within_cap(&granted, rate, burst);
    }

    #[test]
    fn time_until_is_the_first_moment_it_succeeds(
        rate in 1u64..100_000,
        burst in 1u64..5_000,
        taken in 0u64..5_000,
        bytes in 0u64..5_000,
    ) {
        let mut bucket = TokenBucket::new(rate, burst, 0);
        let _ = bucket.try_consume(0, taken.min(burst));
        let wait = bucket.time_until(0, bytes);
        if bytes > burst {
            prop_assert_eq!(wait, u64::MAX);
        } else {
            if wait > 0 {
                prop_assert!(!bucket.clone().try_consume(wait - 1, bytes));
            }
            prop_assert!(bucket.clone().try_consume(wait, bytes));
        }
    }

    /// A greedy sender that always asks for the next packet uses the whole rate in the long run
    /// (time is in whole milliseconds, so the burst must hold a millisecond's worth of rate).
    #[test]
    fn greedy_sender_reaches_the_rate(rate in 1_000u64..200_000, packet in 1u64..1_500) {
        let burst = packet * 2 + rate / 1000;
        let mut bucket = TokenBucket::new(rate, burst, 0);
        let mut now = 0;
        let mut sent = 0u64;
        let horizon = 60_000;
        while now <= horizon {
            if bucket.try_consume(now, packet) {
                sent += packet;
            } else {
                now += bucket.time_until(now, packet);
            }
        }
        // At least rate·T minus one packet of rounding, at most rate·T + burst.
        let cap = rate * horizon / 1000;
        prop_assert!(sent + packet >= cap, "{} < {}", sent, cap);
        prop_assert!(sent <= cap + burst + packet);
    }
}

#[test]
fn time_going_back_is_ignored() {
    let mut bucket = TokenBucket::new(1_000, 1_000, 100);
    assert!(bucket.try_consume(100, 1_000));
    assert!(!bucket.try_consume(50, 1));
    assert_eq!(bucket.time_until(50, 10), 60);
    assert!(bucket.try_consume(110, 10));
}
