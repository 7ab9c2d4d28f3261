//! Health counters.

/// Counters for telemetry.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FilterHealth {
    pub imu_samples: u64,
    pub updates_applied: u64,
    pub updates_rejected: u64,
}
