//! Round-trip time estimation and the retransmission timeout (Jacobson/Karels, RFC 6298).
//!
//! Integer arithmetic in microseconds, so a 1 ms link keeps its precision and a 4 s link does
//! not overflow:
//! - first sample `R`: `SRTT = R`, `RTTVAR = R/2`;
//! - then `RTTVAR = 3/4·RTTVAR + 1/4·|SRTT − R|`, `SRTT = 7/8·SRTT + 1/8·R`;
//! - `RTO = SRTT + max(G, 4·RTTVAR)` with clock granularity `G` = 1 ms, rounded up to whole
//!   milliseconds and clamped to `[min_ms, max_ms]`; `initial_ms` until the first sample.
//!
//! Samples come only from packets transmitted once (Karn's algorithm), so an acknowledgement
//! is never matched to the wrong copy. Exponential backoff as in RFC 6298 §5.5 and Karn: a
//! retransmission timeout doubles the timeout of every packet sent from then on
//! ([`RttEstimator::timeout_ms`] = `RTO·2^backoff`, capped at `max_ms`), until a packet sent
//! once is acknowledged and gives a fresh sample. The backoff state is kept per peer; it grows
//! at most once per round (only when a packet (re)sent after the last backoff times out too), so
//! a window of packets timing out together doubles it once, not once per packet. This is what
//! makes a 4 s link converge from a 1 s initial RTO: the timeout doubles until packets get
//! through unretransmitted and the first sample sets it right.

/// Bounds of the retransmission timeout.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RtoConfig {
    /// RTO before the first RTT sample. Set it near the expected RTT when known (a 4 s link
    /// with the default spends its first seconds retransmitting what is still in flight).
    pub initial_ms: u64,
    /// Lower bound. RFC 6298 says 1 s for the Internet; these links are dedicated and their
    /// RTT is measured, so the default lets a 1 ms link recover in a few milliseconds.
    pub min_ms: u64,
    /// Upper bound, also of the backed-off timeout: after an outage, retransmission resumes
    /// at most this long after the link is back.
    pub max_ms: u64,
}

impl Default for RtoConfig {
    fn default() -> Self {
        RtoConfig { initial_ms: 1_000, min_ms: 5, max_ms: 30_000 }
    }
}

/// Clock granularity `G` of RFC 6298, µs.
const GRANULARITY_US: u64 = 1_000;

/// Smoothed RTT and RTT variation of one peer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RttEstimator {
    config: RtoConfig,
    srtt_us: u64,
    rttvar_us: u64,
    samples: u64,
    rto_ms: u64,
    /// Doublings of the RTO since the last sample.
    backoff: u32,
    /// When the backoff last grew.
    last_backoff_ms: Option<u64>,
}

impl RttEstimator {
    pub fn new(config: RtoConfig) -> Self {
        RttEstimator {
            config,
            srtt_us: 0,
            rttvar_us: 0,
            samples: 0,
            rto_ms: config.initial_ms,
            backoff: 0,
            last_backoff_ms: None,
        }
    }

    /// Feeds one RTT measurement (ms) of a packet transmitted once.
    pub fn on_sample(&mut self, rtt_ms: u64) {
        let r = rtt_ms.saturating_mul(1_000);
        if self.samples == 0 {
            self.srtt_us = r;
            self.rttvar_us = r / 2;
        } else {
            let err = self.srtt_us.abs_diff(r);
            self.rttvar_us = self.rttvar_us - self.rttvar_us / 4 + err / 4;
            self.srtt_us = self.srtt_us - self.srtt_us / 8 + r / 8;
        }
        self.samples = self.samples.saturating_add(1);
        self.backoff = 0;
        self.last_backoff_ms = None;
        let rto_us = self.srtt_us.saturating_add(GRANULARITY_US.max(self.rttvar_us.saturating_mul(4)));
        self.rto_ms = rto_us.div_ceil(1_000).clamp(self.config.min_ms, self.config.max_ms);
    }

    /// The retransmission timeout from the estimate alone (no backoff), ms.
    pub fn rto_ms(&self) -> u64 {
        self.rto_ms
    }

    /// The timeout a packet sent now waits before it is retransmitted: the RTO doubled once per
    /// backoff, capped at `max_ms`.
    pub fn timeout_ms(&self) -> u64 {
        self.rto_ms.saturating_mul(1u64 << self.backoff.min(32)).min(self.config.max_ms.max(self.rto_ms))
    }

    /// Doublings applied since the last sample.
    pub fn backoff(&self) -> u32 {
        self.backoff
    }

    /// A packet last sent at `sent_ms` timed out at `now_ms`: back off, unless the packet
    /// belongs to a round that already backed off (it was sent before the last backoff).
    pub fn on_timeout(&mut self, now_ms: u64, sent_ms: u64) {
        if self.last_backoff_ms.is_none_or(|last| sent_ms >= last) && self.timeout_ms() < self.config.max_ms {
            self.backoff += 1;
            self.last_backoff_ms = Some(now_ms);
        }
    }

    /// Smoothed RTT, ms (`None` before the first sample).
    pub fn srtt_ms(&self) -> Option<u64> {
        (self.samples > 0).then(|| self.srtt_us.div_ceil(1_000))
    }

    /// RTT variation, ms (`None` before the first sample).
    pub fn rttvar_ms(&self) -> Option<u64> {
        (self.samples > 0).then(|| self.rttvar_us.div_ceil(1_000))
    }

    pub fn samples(&self) -> u64 {
        self.samples
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn converges_on_a_one_millisecond_link() {
        let mut rtt = RttEstimator::new(RtoConfig { initial_ms: 1_000, min_ms: 1, max_ms: 60_000 });
        for _ in 0..50 {
            rtt.on_sample(1);
        }
        assert_eq!(rtt.srtt_ms(), Some(1));
        assert_eq!(rtt.rto_ms(), 2);
    }

    #[test]
    fn converges_on_a_four_second_link() {
        let mut rtt = RttEstimator::new(RtoConfig::default());
        for i in 0..50 {
            rtt.on_sample(4_000 + (i % 3) * 10);
        }
        let srtt = rtt.srtt_ms().unwrap_or(0);
        assert!((4_000..=4_020).contains(&srtt), "{srtt}");
        assert!((4_000..=4_100).contains(&rtt.rto_ms()), "{}", rtt.rto_ms());
        assert_eq!(rtt.timeout_ms(), rtt.rto_ms());
    }

    #[test]
    fn backs_off_once_per_round_until_a_sample() {
        let mut rtt = RttEstimator::new(RtoConfig::default());
        // A window sent at 0..10 times out at 1000..1010: one doubling.
        for sent in 0..10 {
            rtt.on_timeout(1_000 + sent, sent);
        }
        assert_eq!(rtt.timeout_ms(), 2_000);
        // Their retransmissions (sent after the backoff) time out too: another doubling.
        rtt.on_timeout(3_000, 1_000);
        assert_eq!(rtt.timeout_ms(), 4_000);
        for _ in 0..10 {
            rtt.on_timeout(100_000, 100_000);
        }
        assert_eq!(rtt.timeout_ms(), 30_000);
        rtt.on_sample(4_000);
        assert_eq!(rtt.backoff(), 0);
        assert_eq!(rtt.timeout_ms(), 12_000); // first sample: SRTT + 4·SRTT/2
    }
}
