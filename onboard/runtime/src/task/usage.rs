//! CPU time and resident memory of this process, for task telemetry.

use nix::sys::resource::{UsageWho, getrusage};
use nix::sys::time::TimeValLike;

/// What the whole process has used so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ProcessUsage {
    /// User + system CPU time of every thread.
    pub cpu_ns: u64,
    /// Resident set size now (not the peak).
    pub rss_bytes: u64,
}

#[derive(Debug, thiserror::Error)]
pub enum UsageError {
    #[error("getrusage: {0}")]
    Rusage(nix::Error),
    #[error("reading /proc/self/status: {0}")]
    Status(std::io::Error),
    #[error("/proc/self/status has no parsable VmRSS line")]
    NoRss,
}

impl ProcessUsage {
    pub fn now() -> Result<ProcessUsage, UsageError> {
        let usage = getrusage(UsageWho::RUSAGE_SELF).map_err(UsageError::Rusage)?;
        let cpu_us =
            usage.user_time().num_microseconds().max(0) as u64 + usage.system_time().num_microseconds().max(0) as u64;
        // getrusage only has the peak RSS; the current one is in /proc.
        let status = std::fs::read_to_string("/proc/self/status").map_err(UsageError::Status)?;
        let rss_bytes = parse_status_rss_bytes(&status).ok_or(UsageError::NoRss)?;
        Ok(ProcessUsage { cpu_ns: cpu_us.saturating_mul(1000), rss_bytes })
    }
}

/// The board's memory (`MemTotal` of `/proc/meminfo`), KiB; `None` where it cannot be read.
pub fn board_memory_kib() -> Option<u64> {
    parse_meminfo_total_kib(&std::fs::read_to_string("/proc/meminfo").ok()?)
}

/// The `MemTotal:  1234 kB` line of `/proc/meminfo`, KiB.
pub fn parse_meminfo_total_kib(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find_map(|l| l.strip_prefix("MemTotal:"))?;
    let mut fields = line.split_whitespace();
    let value: u64 = fields.next()?.parse().ok()?;
    (fields.next()? == "kB").then_some(value)
}

/// The cores this process may run on (at least one).
pub fn board_cores() -> u16 {
    std::thread::available_parallelism().map_or(1, |n| u16::try_from(n.get()).unwrap_or(u16::MAX))
}

/// The `VmRSS:  1234 kB` line of `/proc/<pid>/status`, in bytes. `None` if absent or malformed.
pub fn parse_status_rss_bytes(status: &str) -> Option<u64> {
    let line = status.lines().find_map(|l| l.strip_prefix("VmRSS:"))?;
    let mut fields = line.split_whitespace();
    let value: u64 = fields.next()?.parse().ok()?;
    let multiplier = match fields.next()? {
        "kB" => 1024,
        "mB" | "MB" => 1024 * 1024,
        "B" => 1,
        _ => return None,
    };
    value.checked_mul(multiplier)
}

/// The resident pages (second field) of `/proc/<pid>/statm`, in bytes for `page_bytes`-sized
/// pages. `None` if malformed.
pub fn parse_statm_rss_bytes(statm: &str, page_bytes: u64) -> Option<u64> {
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    pages.checked_mul(page_bytes)
}
