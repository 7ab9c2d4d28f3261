//! A token bucket in exact integer arithmetic.
//!
//! Tokens are kept in milli-bytes: one millisecond at `rate` bytes/s adds exactly `rate`
//! milli-bytes, so refilling never rounds and never drifts however it is called. The bucket
//! starts full and holds at most `burst` bytes, which gives the guarantee the sender relies on:
//! over any interval of `T` ms the bytes consumed are at most `rate·T/1000 + burst`.

/// A byte-rate limiter on caller-supplied (simulated or real) time in milliseconds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TokenBucket {
    rate_bytes_per_s: u64,
    burst_bytes: u64,
    /// Current tokens, milli-bytes; at most `burst_bytes * 1000`.
    tokens_milli: u64,
    /// Time of the last refill. Time never goes back for the bucket: an earlier `now_ms` is
    /// treated as this one.
    last_ms: u64,
}

impl TokenBucket {
    /// A full bucket at time `now_ms`.
    pub fn new(rate_bytes_per_s: u64, burst_bytes: u64, now_ms: u64) -> Self {
        TokenBucket { rate_bytes_per_s, burst_bytes, tokens_milli: burst_bytes.saturating_mul(1000), last_ms: now_ms }
    }

    pub fn rate_bytes_per_s(&self) -> u64 {
        self.rate_bytes_per_s
    }

    pub fn burst_bytes(&self) -> u64 {
        self.burst_bytes
    }

    fn capacity_milli(&self) -> u64 {
        self.burst_bytes.saturating_mul(1000)
    }

    /// Tokens (milli-bytes) the bucket holds at `now_ms`, without changing it.
    fn tokens_at(&self, now_ms: u64) -> u64 {
        let elapsed = now_ms.saturating_sub(self.last_ms);
        let added = elapsed.saturating_mul(self.rate_bytes_per_s);
        self.tokens_milli.saturating_add(added).min(self.capacity_milli())
    }

    fn refill(&mut self, now_ms: u64) {
        if now_ms > self.last_ms {
            self.tokens_milli = self.tokens_at(now_ms);
            self.last_ms = now_ms;
        }
    }

    /// Whole bytes available at `now_ms`.
    pub fn available(&self, now_ms: u64) -> u64 {
        self.tokens_at(now_ms) / 1000
    }

    /// Takes `bytes` tokens if the bucket holds them at `now_ms`; otherwise takes nothing.
    pub fn try_consume(&mut self, now_ms: u64, bytes: u64) -> bool {
        self.refill(now_ms);
        let Some(needed) = bytes.checked_mul(1000) else {
            return false;
        };
        if needed <= self.tokens_milli {
            self.tokens_milli -= needed;
            true
        } else {
            false
        }
    }

    /// Milliseconds from `now_ms` until `try_consume(.., bytes)` would succeed (0: now);
    /// `u64::MAX` if it never can (more than `burst` bytes, or a zero rate).
    pub fn time_until(&self, now_ms: u64, bytes: u64) -> u64 {
        let Some(needed) = bytes.checked_mul(1000) else {
            return u64::MAX;
        };
        if needed > self.capacity_milli() {
            return u64::MAX;
        }
        // Measured from the later of `now_ms` and the last refill (time never goes back).
        let from = now_ms.max(self.last_ms);
        let tokens = self.tokens_at(from);
        if needed <= tokens {
            return from - now_ms;
        }
        if self.rate_bytes_per_s == 0 {
            return u64::MAX;
        }
        let deficit = needed - tokens;
        (from - now_ms).saturating_add(deficit.div_ceil(self.rate_bytes_per_s))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn refills_exactly_without_drift() {
        // 7 bytes/s: 1000 calls one millisecond apart add exactly 7 bytes.
        let mut bucket = TokenBucket::new(7, 100, 0);
        assert!(bucket.try_consume(0, 100));
        for t in 1..=1000 {
            bucket.refill(t);
        }
        assert_eq!(bucket.available(1000), 7);
        assert!(bucket.try_consume(1000, 7));
        assert!(!bucket.try_consume(1000, 1));
    }

    #[test]
    fn time_until_is_exact() {
        let mut bucket = TokenBucket::new(1000, 500, 0);
        assert!(bucket.try_consume(0, 500));
        assert_eq!(bucket.time_until(0, 300), 300);
        assert!(!bucket.try_consume(299, 300));
        assert!(bucket.try_consume(300, 300));
        assert_eq!(bucket.time_until(300, 501), u64::MAX);
        assert_eq!(TokenBucket::new(0, 10, 0).time_until(0, 11), u64::MAX);
    }
}
