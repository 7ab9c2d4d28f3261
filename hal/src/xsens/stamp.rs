//! Host time stamps for device samples from the device's own clock (SampleTimeFine).
//!
//! A sample's arrival time on the host is its true time plus a transport delay that jitters
//! with USB polling and OS scheduling (milliseconds), while the device's sample clock ticks
//! evenly but at its own rate (tens of ppm off the host's). With the device time `t` of each
//! sample, arrival `a = offset + (1 + drift)·t + delay`, `delay ≥ delay_min`:
//!
//! - **drift**: a least-squares line through the per-block minima of `a − t` (one point per
//!   `drift_block_ns` of device time, the last `drift_blocks` blocks); the minima sit on the lower
//!   envelope, where the delay is close to its minimum, so the jitter hardly moves the slope;
//! - **offset**: the minimum of `a − (1 + drift)·t` over the last `window_ns` of samples,
//!   re-anchored at every sample, so it follows the drift-corrected lower envelope;
//! - the corrected stamp is `(1 + drift)·t + offset − latency_ns`.
//!
//! The stamp therefore carries the minimum transport delay (unobservable from one-way
//! traffic): set `latency_ns` to a measured value to remove it. A corrected stamp is never
//! later than its arrival (plus the latency removed), and stamps never go backwards.
//!
//! SampleTimeFine is unwrapped across its 2³² wrap (every 4.97 days at 10 kHz). A step back
//! of more than 2³¹ ticks is taken as a device restart and resets the estimator (counted).
//! Until a window has filled, stamps are only as good as the best arrival seen so far.

use std::collections::VecDeque;

/// Nanoseconds per SampleTimeFine tick (10 kHz).
pub const NS_PER_TICK: u64 = 100_000;
/// Bound on the samples kept for the offset window, whatever the rate (at 200 Hz the default
/// two-second window holds 400).
const MAX_WINDOW_SAMPLES: usize = 2048;
/// Blocks needed before the drift is estimated; until then it is taken as zero.
const MIN_DRIFT_BLOCKS: usize = 3;

/// Tuning of the [`StampCorrector`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampCorrectorConfig {
    /// Device time over which the offset is the minimum.
    pub window_ns: u64,
    /// Device time per point of the drift fit.
    pub drift_block_ns: u64,
    /// Points of the drift fit.
    pub drift_blocks: usize,
    /// Bound on the drift estimate (real crystals are within ±100 ppm); 0 turns drift
    /// tracking off.
    pub max_drift_ppm: f64,
    /// Known constant transport delay subtracted from every stamp.
    pub latency_ns: u64,
}

impl Default for StampCorrectorConfig {
    fn default() -> Self {
        StampCorrectorConfig {
            window_ns: 2_000_000_000,
            drift_block_ns: 1_000_000_000,
            drift_blocks: 16,
            max_drift_ppm: 500.0,
            latency_ns: 0,
        }
    }
}

/// One sample: device time since the origin, arrival since the origin (ns).
#[derive(Debug, Clone, Copy)]
struct Point {
    device_ns: f64,
    arrival_ns: f64,
}

/// Maps device sample times to host time; see the module documentation.
#[derive(Debug, Clone)]
pub struct StampCorrector {
    config: StampCorrectorConfig,
    last_ticks_raw: Option<u32>,
    /// Unwrapped ticks since the first sample.
    ticks: u64,
    /// Host arrival of the first sample: all times are kept relative to it as f64.
    origin_arrival_ns: u64,
    window: VecDeque<Point>,
    /// Minimum of `a − t` in each finished block, and the block being filled.
    block_minima: VecDeque<Point>,
    block: Option<(u64, Point)>,
    drift: f64,
    last_stamp_ns: Option<u64>,
    resets: u64,
}

impl Default for StampCorrector {
    fn default() -> Self {
        Self::new(StampCorrectorConfig::default())
    }
}

impl StampCorrector {
    pub fn new(config: StampCorrectorConfig) -> Self {
        StampCorrector {
            config,
            last_ticks_raw: None,
            ticks: 0,
            origin_arrival_ns: 0,
            window: VecDeque::new(),
            block_minima: VecDeque::new(),
            block: None,
            drift: 0.0,
            last_stamp_ns: None,
            resets: 0,
        }
    }

    pub fn config(&self) -> &StampCorrectorConfig {
        &self.config
    }

    /// Host seconds per device second, minus one: about −50e-6 for a device clock 50 ppm fast.
    pub fn drift(&self) -> f64 {
        self.drift
    }

    /// Device restarts seen (SampleTimeFine stepping back).
    pub fn resets(&self) -> u64 {
        self.resets
    }

    /// Forgets everything (a reconfigured device restarts its clock).
    pub fn reset(&mut self) {
        *self = StampCorrector::new(self.config);
    }

    /// The host stamp of the sample taken at `sample_time_fine` that arrived at `arrival_ns`.
    pub fn correct(&mut self, sample_time_fine: u32, arrival_ns: u64) -> u64 {
        if let Some(last) = self.last_ticks_raw {
            let step = sample_time_fine.wrapping_sub(last);
            if step > u32::MAX / 2 {
                let (resets, last_stamp_ns) = (self.resets.saturating_add(1), self.last_stamp_ns);
                self.reset();
                self.resets = resets;
                self.last_stamp_ns = last_stamp_ns;
            } else {
                self.ticks = self.ticks.saturating_add(u64::from(step));
            }
        }
        if self.last_ticks_raw.is_none() {
            self.origin_arrival_ns = arrival_ns;
        }
        self.last_ticks_raw = Some(sample_time_fine);
        let device_ns = self.ticks.saturating_mul(NS_PER_TICK);
        let point = Point {
            device_ns: device_ns as f64,
            arrival_ns: arrival_ns.wrapping_sub(self.origin_arrival_ns) as i64 as f64,
        };
        self.update_drift(device_ns, point);
        self.window.push_back(point);
        let horizon = point.device_ns - self.config.window_ns as f64;
        while self.window.len() > MAX_WINDOW_SAMPLES || self.window.front().is_some_and(|p| p.device_ns < horizon) {
            self.window.pop_front();
        }
        let rate = 1.0 + self.drift;
        let offset = self.window.iter().map(|p| p.arrival_ns - rate * p.device_ns).fold(f64::INFINITY, f64::min);
        let stamp = rate * point.device_ns + offset - self.config.latency_ns as f64;
        let stamp_ns = (self.origin_arrival_ns as i64).saturating_add(stamp.round() as i64).max(0) as u64;
        // A new drift estimate can move the line by a few ns; stamps must not go backwards.
        let stamp_ns = self.last_stamp_ns.map_or(stamp_ns, |last| stamp_ns.max(last));
        self.last_stamp_ns = Some(stamp_ns);
        stamp_ns
    }

    fn update_drift(&mut self, device_ns: u64, point: Point) {
        let block_ns = self.config.drift_block_ns.max(1);
        let index = device_ns / block_ns;
        let raw_offset = |p: &Point| p.arrival_ns - p.device_ns;
        match &mut self.block {
            Some((current, best)) if *current == index => {
                if raw_offset(&point) < raw_offset(best) {
                    *best = point;
                }
            }
            _ => {
                if let Some((_, best)) = self.block.take() {
                    self.block_minima.push_back(best);
                    while self.block_minima.len() > self.config.drift_blocks.max(MIN_DRIFT_BLOCKS) {
                        self.block_minima.pop_front();
                    }
                    self.drift = self.fit_drift();
                }
                self.block = Some((index, point));
            }
        }
    }

    /// Slope of the least-squares line through the block minima of `a − t`.
    fn fit_drift(&self) -> f64 {
        let n = self.block_minima.len();
        if n < MIN_DRIFT_BLOCKS {
            return 0.0;
        }
        let mean_t = self.block_minima.iter().map(|p| p.device_ns).sum::<f64>() / n as f64;
        let mean_o = self.block_minima.iter().map(|p| p.arrival_ns - p.device_ns).sum::<f64>() / n as f64;
        let (mut stt, mut sto) = (0.0, 0.0);
        for p in &self.block_minima {
            let dt = p.device_ns - mean_t;
            stt += dt * dt;
            sto += dt * (p.arrival_ns - p.device_ns - mean_o);
        }
        if stt <= 0.0 {
            return 0.0;
        }
        let limit = self.config.max_drift_ppm * 1e-6;
        (sto / stt).clamp(-limit, limit)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn without_jitter_the_stamp_is_the_arrival() {
        let mut corrector = StampCorrector::default();
        for k in 0..1000u64 {
            let arrival = 5_000_000_000 + k * 5_000_000;
            assert_eq!(corrector.correct((k * 50) as u32, arrival), arrival);
        }
    }

    #[test]
    fn tick_wrap_is_unwrapped_and_a_step_back_resets() {
        let mut corrector = StampCorrector::default();
        let start = u32::MAX - 120;
        let mut stamps = Vec::new();
        for k in 0..6u32 {
            stamps.push(corrector.correct(start.wrapping_add(k * 50), 1_000_000_000 + u64::from(k) * 5_000_000));
        }
        assert_eq!(stamps, (0..6).map(|k| 1_000_000_000 + k * 5_000_000).collect::<Vec<u64>>());
        assert_eq!(corrector.resets(), 0);
        corrector.correct(10, 2_000_000_000);
        assert_eq!(corrector.resets(), 1);
    }
}
