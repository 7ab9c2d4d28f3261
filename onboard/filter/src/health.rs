//! Health counters.

/// Applied and rejected counts of one measurement type.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GateCounters {
    pub applied: u64,
    pub rejected: u64,
    /// Normalized innovation squared of the latest update (applied or not).
    pub last_nis: f64,
}

/// Counters for telemetry.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FilterHealth {
    pub imu_samples: u64,
    pub updates_applied: u64,
    pub updates_rejected: u64,
    pub relative_pose: GateCounters,
    pub wheel: GateCounters,
    pub zero_velocity: GateCounters,
    pub pose: GateCounters,
    /// Relative-pose measurements whose clone was not (or no longer) held.
    pub missing_clones: u64,
    /// Clones marginalized to respect `max_clones` / `max_keyframe_clones` (not the normal
    /// release after an update).
    pub clones_evicted: u64,
    /// IMU samples out of order or older than the state (ignored).
    pub imu_out_of_order: u64,
    /// Gaps between IMU samples above 50 ms (integrated anyway).
    pub imu_gaps: u64,
    /// Covariance repairs: a negative or non-finite diagonal, or non-finite entries.
    pub covariance_repairs: u64,
    pub frame_switches: u64,
}

impl FilterHealth {
    /// No covariance repair and no IMU trouble, and at most `max_rejected_fraction` of the
    /// updates rejected (a 0.999 gate rejects one in a thousand good updates).
    pub fn is_clean(&self, max_rejected_fraction: f64) -> bool {
        let total = self.updates_applied + self.updates_rejected;
        let rejected_ok = total == 0 || (self.updates_rejected as f64) <= max_rejected_fraction * total as f64;
        self.covariance_repairs == 0 && self.imu_out_of_order == 0 && rejected_ok
    }
}
