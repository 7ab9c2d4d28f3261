//! A fixed-memory histogram of nanosecond durations with log-linear buckets (HDR-style): exact
//! below 16 ns, then 16 linear buckets per power of two, so a quantile is off by at most 1/16
//! (6.25 %) of its value. Recording is a few integer operations and never allocates.

const SUB_BITS: u32 = 4;
const SUB_BUCKETS: usize = 1 << SUB_BITS;
/// 16 exact buckets, then 16 per octave for exponents 4..=63.
const BUCKETS: usize = SUB_BUCKETS + (64 - SUB_BITS as usize) * SUB_BUCKETS;

#[derive(Clone)]
pub struct LogHistogram {
    counts: Box<[u64; BUCKETS]>,
    total: u64,
    max: u64,
}

impl std::fmt::Debug for LogHistogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LogHistogram")
            .field("total", &self.total)
            .field("p50", &self.quantile(0.5))
            .field("p99", &self.quantile(0.99))
            .field("max", &self.max)
            .finish()
    }
}

impl Default for LogHistogram {
    fn default() -> Self {
        LogHistogram::new()
    }
}

impl LogHistogram {
    pub fn new() -> LogHistogram {
        LogHistogram { counts: Box::new([0; BUCKETS]), total: 0, max: 0 }
    }

    pub fn record(&mut self, value: u64) {
        let bucket = bucket_of(value);
        self.counts[bucket] = self.counts[bucket].saturating_add(1);
        self.total = self.total.saturating_add(1);
        self.max = self.max.max(value);
    }

    pub fn count(&self) -> u64 {
        self.total
    }

    /// Largest recorded value (exact); 0 when empty.
    pub fn max(&self) -> u64 {
        self.max
    }

    /// The value below or at which a fraction `q` (clamped to 0..=1) of the records lie: the upper
    /// bound of the bucket holding that rank, capped by the exact maximum. 0 when empty.
    pub fn quantile(&self, q: f64) -> u64 {
        if self.total == 0 {
            return 0;
        }
        let q = if q.is_nan() { 1.0 } else { q.clamp(0.0, 1.0) };
        // Nearest-rank: the smallest value with at least ceil(q·n) records at or below it.
        let rank = ((q * self.total as f64).ceil() as u64).clamp(1, self.total);
        let mut seen = 0u64;
        for (bucket, &count) in self.counts.iter().enumerate() {
            seen += count;
            if seen >= rank {
                return bucket_upper(bucket).min(self.max);
            }
        }
        self.max
    }

    pub fn clear(&mut self) {
        self.counts.fill(0);
        self.total = 0;
        self.max = 0;
    }
}

fn bucket_of(value: u64) -> usize {
    if value < SUB_BUCKETS as u64 {
        return value as usize;
    }
    let exponent = 63 - value.leading_zeros();
    let sub = (value >> (exponent - SUB_BITS)) as usize & (SUB_BUCKETS - 1);
    SUB_BUCKETS + (exponent - SUB_BITS) as usize * SUB_BUCKETS + sub
}

/// Largest value that falls in `bucket`.
fn bucket_upper(bucket: usize) -> u64 {
    if bucket < SUB_BUCKETS {
        return bucket as u64;
    }
    let octave = (bucket - SUB_BUCKETS) / SUB_BUCKETS;
    let sub = ((bucket - SUB_BUCKETS) % SUB_BUCKETS) as u64;
    let exponent = octave as u32 + SUB_BITS;
    let width_log2 = exponent - SUB_BITS;
    let lower = (1u64 << exponent) | (sub << width_log2);
    lower | ((1u64 << width_log2) - 1)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn buckets_tile_the_u64_range() {
        let mut previous_upper = None::<u64>;
        for bucket in 0..BUCKETS {
            let upper = bucket_upper(bucket);
            if let Some(p) = previous_upper {
                assert_eq!(bucket_of(p + 1), bucket, "first value of bucket {bucket}");
            }
            assert_eq!(bucket_of(upper), bucket);
            previous_upper = Some(upper);
        }
        assert_eq!(previous_upper, Some(u64::MAX));
    }
}
