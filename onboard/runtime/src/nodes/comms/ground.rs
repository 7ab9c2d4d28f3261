//! The ground feed: what the robot tells the ground station once a second (thesis §7.2).
//!
//! Field mapping from the bus:
//! - filter health from the latest `FilterStateMsg`: `INITIALIZING` → `Initializing`; `RUNNING`
//!   → `Nominal`, or `Degraded` when IMU samples were lost since the previous report or the state
//!   is older than two report periods; any other status → `Degraded`. Standard deviations from
//!   the pose covariance (largest translation variance; the yaw variance). The comms node does
//!   not see visual odometry, so `vo_age_ms` is `u32::MAX` (unknown).
//! - the IMU loss counter travels as the queue `imu` (`dropped` = samples the filter saw lost);
//! - tasks from every process's `TaskStatsMsg` (label `process.task`, at most
//!   [`MAX_TASKS`] in (process, task) order); CPU load from the growth of each process's CPU
//!   time between its reports, memory as the sum of the processes' RSS;
//! - per link: bytes, and rates in bit/s over the last period, retransmissions, rejected packets, the
//!   retransmitted share of packets sent in the period as `loss_permille`, the smoothed RTT and
//!   the outages; its queue (queued + in flight + backlog) as a queue named after the link.
//!
//! - per message class (v2): cumulative wire bytes and packets the robot put on all its links
//!   (retransmissions included), from the node's `stats().sent_by_class`, in key order; the
//!   ground station differentiates them into bytes per second per class.

use std::collections::BTreeMap;

use msgs::{FilterStateMsg, ProcessKind, TaskStatsMsg};
use protocol::delivery::EndpointStats;
use protocol::message::state::{MAX_CLASSES, MAX_LINKS, MAX_QUEUES, MAX_TASKS};
use protocol::message::{
    ClassBytes, FilterHealth, FilterStatus, Label, LinkStats, Mode, PoseEstimate, QueueStats, ResourceUsage,
    SensorAvailability, TaskStats, Telemetry,
};
use protocol::{AnyMessage, Cov6, Pose3, RobotId, SubmapId};

use super::ClassTraffic;

/// A telemetry label from any text: truncated to what fits.
pub(super) fn label(text: &str) -> Label {
    let mut label = Label::new();
    for c in text.chars() {
        if label.push(c).is_err() {
            break;
        }
    }
    label
}

fn saturate_u32(value: u64) -> u32 {
    u32::try_from(value).unwrap_or(u32::MAX)
}

fn saturate_u16(value: u64) -> u16 {
    u16::try_from(value).unwrap_or(u16::MAX)
}

fn process_name(process: u32) -> &'static str {
    const KINDS: [(ProcessKind, &str); 6] = [
        (ProcessKind::Driver, "driver"),
        (ProcessKind::Vision, "vision"),
        (ProcessKind::Filter, "filter"),
        (ProcessKind::Mapper, "mapper"),
        (ProcessKind::Comms, "comms"),
        (ProcessKind::Supervisor, "super"),
    ];
    KINDS.iter().find(|(kind, _)| *kind as u32 == process).map_or("proc", |(_, name)| name)
}

/// Counters of a link at the previous report.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct LinkReport {
    sent_wire: u64,
    received_wire: u64,
    sent_packets: u64,
    retransmissions: u64,
}

/// What the feed needs of a link.
pub(super) struct LinkView<'a> {
    pub label: &'a Label,
    pub stats: &'a EndpointStats,
    pub backlog: usize,
    pub backlog_dropped: u64,
    pub outages: u32,
    pub report: &'a mut LinkReport,
}

/// The node's counters a telemetry report carries.
pub(super) struct Counters<'a> {
    pub links: Vec<LinkView<'a>>,
    pub auth_rejections: u64,
    pub sent_by_class: &'a BTreeMap<&'static str, ClassTraffic>,
}

/// CPU accounting of one process.
#[derive(Debug, Clone, Copy, Default)]
struct ProcessCpu {
    stamp_ns: u64,
    cpu_ns: u64,
    rss_bytes: u64,
    /// Load of the process over its last two reports, per mille of one core.
    permille_of_core: u64,
}

#[derive(Debug)]
pub(super) struct GroundFeed {
    cpu_cores: u16,
    board_memory_kib: Option<u64>,
    filter: Option<FilterStateMsg>,
    imu_lost_reported: u64,
    tasks: BTreeMap<(u32, u32), TaskStatsMsg>,
    processes: BTreeMap<u32, ProcessCpu>,
}

impl GroundFeed {
    pub fn new(cpu_cores: u16, board_memory_kib: Option<u64>) -> Self {
        GroundFeed {
            cpu_cores: cpu_cores.max(1),
            board_memory_kib,
            filter: None,
            imu_lost_reported: 0,
            tasks: BTreeMap::new(),
            processes: BTreeMap::new(),
        }
    }

    pub fn filter_state(&self) -> Option<&FilterStateMsg> {
        self.filter.as_ref()
    }

    pub fn task_stats(&self) -> impl Iterator<Item = &TaskStatsMsg> + '_ {
        self.tasks.values()
    }

    pub fn on_filter_state(&mut self, state: &FilterStateMsg) {
        if self.filter.is_none_or(|f| f.stamp_ns <= state.stamp_ns) {
            self.filter = Some(*state);
        }
    }

    pub fn on_task_stats(&mut self, stats: &TaskStatsMsg) {
        self.tasks.insert((stats.process, stats.task), *stats);
        let entry = self.processes.entry(stats.process).or_default();
        // Several tasks of a process report the same process counters: measure the load only
        // over a span long enough for the CPU clock's granularity.
        let span_ns = stats.stamp_ns.saturating_sub(entry.stamp_ns);
        if entry.stamp_ns == 0 || stats.stamp_ns < entry.stamp_ns {
            *entry = ProcessCpu { stamp_ns: stats.stamp_ns, cpu_ns: stats.process_cpu_ns, ..*entry };
        } else if span_ns >= 500_000_000 {
            let used_ns = stats.process_cpu_ns.saturating_sub(entry.cpu_ns);
            entry.permille_of_core = used_ns.saturating_mul(1000) / span_ns;
            entry.stamp_ns = stats.stamp_ns;
            entry.cpu_ns = stats.process_cpu_ns;
        }
        entry.rss_bytes = stats.process_rss_bytes;
    }

    fn filter_health(&mut self, now_ns: u64, period_ns: u64) -> (FilterHealth, u64) {
        let Some(state) = self.filter else {
            let health = FilterHealth {
                status: FilterStatus::Initializing,
                position_std_m: 0.0,
                yaw_std_rad: 0.0,
                vo_age_ms: u32::MAX,
            };
            return (health, 0);
        };
        let fresh = now_ns.saturating_sub(state.stamp_ns) <= period_ns.saturating_mul(2);
        let lost_since_report = state.imu_lost > self.imu_lost_reported;
        self.imu_lost_reported = state.imu_lost;
        let status = match state.status {
            FilterStateMsg::INITIALIZING => FilterStatus::Initializing,
            FilterStateMsg::RUNNING if fresh && !lost_since_report => FilterStatus::Nominal,
            _ => FilterStatus::Degraded,
        };
        let c = &state.pose_covariance;
        let position_var = c[0].max(c[7]).max(c[14]);
        let health = FilterHealth {
            status,
            position_std_m: position_var.max(0.0).sqrt() as f32,
            yaw_std_rad: c[35].max(0.0).sqrt() as f32,
            vo_age_ms: match state.last_vo_capture_ns {
                FilterStateMsg::NEVER => u32::MAX,
                capture_ns => saturate_u32(now_ns.saturating_sub(capture_ns) / 1_000_000),
            },
        };
        (health, state.imu_lost)
    }

    /// The robot's pose in its current local frame (= the submap it maps into; the submap
    /// index is the filter's frame id).
    pub fn pose_estimate(&self, robot: RobotId) -> Option<PoseEstimate> {
        let state = self.filter?;
        let mut full = [[0.0f64; 6]; 6];
        for (r, row) in full.iter_mut().enumerate() {
            row.copy_from_slice(&state.pose_covariance[r * 6..r * 6 + 6]);
        }
        Some(PoseEstimate {
            robot,
            stamp_ns: state.stamp_ns,
            submap: SubmapId { robot, index: state.frame_id },
            t_submap_body: Pose3 {
                translation_m: state.t_local_body.translation_m,
                rotation_wxyz: state.t_local_body.rotation_wxyz,
            },
            covariance: Cov6::from_full(&full),
        })
    }

    /// The driver's last report of its devices, if it reads devices.
    fn sensors(&self) -> Option<SensorAvailability> {
        let driver = ProcessKind::Driver as u32;
        let bits = self.tasks.iter().find(|((process, _), _)| *process == driver).map(|(_, s)| s.devices)?;
        (bits & TaskStatsMsg::DEVICES_REPORTED != 0).then_some(SensorAvailability {
            imu: bits & TaskStatsMsg::DEVICE_IMU != 0,
            wheels: bits & TaskStatsMsg::DEVICE_WHEELS != 0,
            head: bits & TaskStatsMsg::DEVICE_HEAD != 0,
        })
    }

    pub fn telemetry(
        &mut self,
        robot: RobotId,
        now_ns: u64,
        period_ns: u64,
        mode: Mode,
        counters: Counters<'_>,
    ) -> Telemetry {
        let Counters { links, auth_rejections, sent_by_class } = counters;
        let (filter, imu_lost) = self.filter_health(now_ns, period_ns);
        let permille_all_cores: u64 =
            self.processes.values().map(|p| p.permille_of_core).sum::<u64>() / u64::from(self.cpu_cores);
        let rss_bytes: u64 = self.processes.values().map(|p| p.rss_bytes).sum();
        let mut telemetry = Telemetry {
            robot,
            stamp_ns: now_ns,
            mode,
            filter,
            resources: ResourceUsage {
                cpu_permille: saturate_u16(permille_all_cores),
                mem_used_kib: saturate_u32(rss_bytes / 1024),
                mem_total_kib: saturate_u32(self.board_memory_kib.unwrap_or(0)),
            },
            tasks: Default::default(),
            queues: Default::default(),
            links: Default::default(),
            auth_rejections: saturate_u32(auth_rejections),
            classes: Default::default(),
            sensors: self.sensors(),
        };
        for key in AnyMessage::KEYS.iter().take(MAX_CLASSES) {
            let Some(traffic) = AnyMessage::name_of(*key).and_then(|name| sent_by_class.get(name)) else { continue };
            // Cannot fail: at most MAX_CLASSES keys are taken.
            let _ = telemetry.classes.push(ClassBytes {
                message_key: key.0,
                tx_bytes: traffic.wire_bytes,
                tx_packets: saturate_u32(traffic.packets),
            });
        }
        // Nodes without a fixed-rate task (the lockstep runner) report CPU and memory only.
        let timed = self.tasks.iter().filter(|(_, s)| s.period_ns != TaskStatsMsg::NO_TASK);
        for ((process, task), stats) in timed.take(MAX_TASKS) {
            let entry = TaskStats {
                task: label(&format!("{}.{task}", process_name(*process))),
                period_us: saturate_u32(stats.period_ns / 1000),
                releases: saturate_u32(stats.releases),
                deadline_overruns: saturate_u32(stats.overruns),
                jitter_p99_us: saturate_u32(stats.jitter_p99_ns / 1000),
                jitter_max_us: saturate_u32(stats.jitter_max_ns / 1000),
            };
            // Cannot fail: at most MAX_TASKS are taken.
            let _ = telemetry.tasks.push(entry);
        }
        // Each process's fullest receive queue since its last report; the filter's also counts
        // the IMU samples that never arrived.
        let filter_process = ProcessKind::Filter as u32;
        for ((process, _), stats) in &self.tasks {
            if stats.queue_topic == 0 || telemetry.queues.is_full() {
                continue;
            }
            let _ = telemetry.queues.push(QueueStats {
                queue: label(process_name(*process)),
                depth: saturate_u16(u64::from(stats.queue_depth_max)),
                capacity: saturate_u16(u64::from(stats.queue_capacity)),
                dropped: if *process == filter_process { saturate_u32(imu_lost) } else { 0 },
            });
        }
        if !telemetry.queues.iter().any(|q| q.queue.as_str() == "filter") {
            let _ = telemetry.queues.push(QueueStats {
                queue: label("filter"),
                depth: 0,
                capacity: 0,
                dropped: saturate_u32(imu_lost),
            });
        }
        let seconds = (period_ns as f64 / 1e9).max(1e-3);
        for view in links.into_iter().take(MAX_LINKS) {
            let s = view.stats;
            let sent = s.sent_total();
            let received = s.received_total();
            let report = LinkReport {
                sent_wire: sent.wire_bytes,
                received_wire: received.wire_bytes,
                sent_packets: sent.packets,
                retransmissions: s.retransmissions,
            };
            let previous = std::mem::replace(view.report, report);
            // `_bps` fields are bits per second (a 57.6 kbit/s radio reports about 57 600).
            let rate = |now: u64, before: u64| saturate_u32((now.saturating_sub(before) as f64 * 8.0 / seconds) as u64);
            let sent_in_period = report.sent_packets.saturating_sub(previous.sent_packets);
            let retransmitted = report.retransmissions.saturating_sub(previous.retransmissions);
            let _ = telemetry.links.push(LinkStats {
                link: view.label.clone(),
                tx_bytes: sent.wire_bytes,
                rx_bytes: received.wire_bytes,
                tx_rate_bps: rate(report.sent_wire, previous.sent_wire),
                rx_rate_bps: rate(report.received_wire, previous.received_wire),
                retransmissions: saturate_u32(s.retransmissions),
                rejected: saturate_u32(s.rejected.total()),
                loss_permille: saturate_u16(retransmitted * 1000 / sent_in_period.max(1)),
                rtt_ms: s.srtt_ms.map_or(u32::MAX, saturate_u32),
                outages: view.outages,
            });
            if telemetry.queues.len() < MAX_QUEUES {
                let depth: u64 =
                    s.queued.iter().chain(s.in_flight.iter()).map(|&n| u64::from(n)).sum::<u64>() + view.backlog as u64;
                let _ = telemetry.queues.push(QueueStats {
                    queue: view.label.clone(),
                    depth: saturate_u16(depth),
                    capacity: saturate_u16(super::WINDOW_PACKETS as u64),
                    dropped: saturate_u32(view.backlog_dropped),
                });
            }
        }
        telemetry
    }
}
