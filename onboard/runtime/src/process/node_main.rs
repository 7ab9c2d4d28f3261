//! One on-board process: `onboard node <driver|vision|filter|mapper|comms> --config rover.toml`.
//!
//! Builds its node from the configuration ([`crate::stack`], as the lockstep runners do),
//! attaches it to the robot's bus, and runs a [`FixedRateTask`] at the process's configured
//! rate: per release it drains the inbox into [`Node::on_message`], then calls [`Node::on_tick`]
//! with the sensor time of the release (the comms process also pumps its links). About once a
//! second it publishes its task's [`msgs::TaskStatsMsg`]. On SIGTERM it finishes the current
//! release, writes its files (module docs of [`crate::process`]) and exits 0.
//!
//! Only the driver opens the sensor source (through the [`SourceProvider`] of the binary it runs
//! in: the firmware's replays, or the `sil` harness's simulator); vision, filter and mapper need
//! the [`crate::sensors::SensorSetup`] alone, so they are back within a fraction of a second
//! after a restart. The filter checkpoints into `state/filter.ckpt` and resumes from it once it
//! knows the epoch ([`FilterNode::resume`]). The mapper's submap policy comes from `[mapper]`.
//!
//! A replay runs at `driver.replay_speed` of its recorded pace: sensor time is the wall clock
//! since the epoch times that factor, for every process of the robot alike.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use hal::can::CanLink;
use hal::link::Link;
use hal::serial::SerialLink;
use hal::udp::UdpLink;
use protocol::RobotId;
use serde_json::{Value, json};

use super::{NodeKind, ProcessError, READY_DIR, io_error, monotonic_ns, termination_flag, wait_for_epoch, write_json};
use crate::bus::{Bus, BusInbox, BusOutbox, ImageGeometry};
use crate::config::{DriverKind, LinkKind, RoverConfig};
use crate::nodes::comms::{CommsConfig, CommsNode, LinkConfig, LinkDriver, LinkId};
use crate::nodes::driver::{DriverNode, DriverOptions};
use crate::nodes::filter::FilterNode;
use crate::nodes::mapper::MapperNode;
use crate::nodes::vision::VisionNode;
use crate::nodes::{Message, Node, Outbox};
use crate::sensors::{SensorSetup, SourceProvider, sensor_setup};
use crate::stack::{self, protocol_robot_id};
use crate::task::histogram::LogHistogram;
use crate::task::rt::{self, RtReport};
use crate::task::{FixedRateTask, RunEnd};

/// Task telemetry period.
const STATS_PERIOD_NS: u64 = 1_000_000_000;
/// Ground link id (team links start at 1), as in the lockstep mission.
const GROUND_LINK: LinkId = LinkId(0);
const TEAM_LINK: LinkId = LinkId(1);

/// A built node with what its process needs besides the bus.
enum Hosted {
    Driver(Box<DriverNode>),
    Vision(Box<VisionNode>),
    Filter(Box<FilterNode>),
    Mapper(Box<MapperNode>),
    Comms(Box<CommsNode>, LinkDriver),
}

impl Hosted {
    fn node(&mut self) -> &mut dyn Node {
        match self {
            Hosted::Driver(n) => n.as_mut(),
            Hosted::Vision(n) => n.as_mut(),
            Hosted::Filter(n) => n.as_mut(),
            Hosted::Mapper(n) => n.as_mut(),
            Hosted::Comms(n, _) => n.as_mut(),
        }
    }

    fn release(
        &mut self,
        now_ns: u64,
        inbox: &mut BusInbox,
        outbox: &mut BusOutbox,
        latency: &mut SensorLatency,
    ) -> Result<(), ProcessError> {
        let node = self.node();
        inbox.drain(&mut |message| {
            latency.record(&message);
            node.on_message(message, outbox)
        })?;
        node.on_tick(now_ns, outbox)?;
        if let Hosted::Comms(comms, links) = self {
            links.pump(comms, now_ns)?;
        }
        Ok(())
    }
}

/// How old the sensor samples are when the process takes them from the bus: sensor time at the
/// drain minus the sample's stamp (the device's capture time), the whole path device → driver →
/// bus → this process. Measured where the clock is the wall clock at the recorded pace (not for a
/// replay at another speed).
struct SensorLatency {
    epoch_ns: Option<u64>,
    imu: LogHistogram,
    wheel: LogHistogram,
}

impl SensorLatency {
    fn record(&mut self, message: &Message<'_>) {
        let Some(epoch_ns) = self.epoch_ns else { return };
        let (histogram, stamp_ns) = match message {
            Message::Imu(m) => (&mut self.imu, m.stamp_ns),
            Message::WheelOdom(m) => (&mut self.wheel, m.stamp_ns),
            _ => return,
        };
        histogram.record(monotonic_ns().saturating_sub(epoch_ns).saturating_sub(stamp_ns));
    }

    fn json(&self) -> Value {
        let quantiles = |h: &LogHistogram| json!({"samples": h.count(), "p50_ns": h.quantile(0.5), "p99_ns": h.quantile(0.99), "max_ns": h.max()});
        json!({"imu": quantiles(&self.imu), "wheel_odom": quantiles(&self.wheel)})
    }
}

fn driver_node(config: &RoverConfig, sources: &dyn SourceProvider) -> Result<DriverNode, ProcessError> {
    let source = sources.open(config)?;
    Ok(DriverNode::new(source, DriverOptions { end_stamp_ns: config.driver.end_stamp_ns() }))
}

fn comms_node(config: &RoverConfig) -> Result<(CommsNode, LinkDriver), ProcessError> {
    let link = &config.link;
    let mut links = Vec::new();
    let mut driver = LinkDriver::new();
    match link.kind {
        LinkKind::Udp => {
            let peers = link.peer_addrs();
            if !peers.is_empty() {
                let bind = link.bind_addr().ok_or_else(|| ProcessError::Setup(format!("link.bind {:?}", link.bind)))?;
                let udp = UdpLink::bind(bind)?.with_peers(peers.iter().map(|(_, a)| *a));
                let peer_ids = peers.iter().map(|(id, _)| RobotId(protocol_robot_id(*id) as u8)).collect();
                links.push(LinkConfig::team(
                    TEAM_LINK,
                    "team radio",
                    udp.framing(),
                    link.bandwidth_bytes_per_s,
                    peer_ids,
                ));
                driver.add(TEAM_LINK, Box::new(udp));
            }
        }
        LinkKind::None => {}
        LinkKind::Can => {
            let text = link.can_interface.as_deref().unwrap_or_default();
            let interface: hal::can::interface::CanInterface =
                text.parse().map_err(|e| ProcessError::Setup(format!("link.can_interface {text:?}: {e}")))?;
            let bus = interface.open()?;
            let can = CanLink::new(bus, protocol::NodeId(protocol_robot_id(config.robot.id) as u8));
            // A CAN bus is a broadcast medium too.
            let peer_ids = link.peers.iter().map(|p| RobotId(protocol_robot_id(p.robot_id) as u8)).collect();
            links.push(LinkConfig::team(TEAM_LINK, "team CAN", can.framing(), link.bandwidth_bytes_per_s, peer_ids));
            driver.add(TEAM_LINK, Box::new(can));
        }
        LinkKind::Serial => {
            let device = link.serial_device.as_deref().unwrap_or_default();
            let serial = SerialLink::open(device, link.serial_baud)?;
            // A serial radio is a broadcast medium: every peer hears every packet.
            let peer_ids = link.peers.iter().map(|p| RobotId(protocol_robot_id(p.robot_id) as u8)).collect();
            links.push(LinkConfig::team(
                TEAM_LINK,
                "team radio",
                serial.framing(),
                link.bandwidth_bytes_per_s,
                peer_ids,
            ));
            driver.add(TEAM_LINK, Box::new(serial));
        }
    }
    if let Some(feed) = link.ground_feed_addr() {
        let udp = UdpLink::bind("0.0.0.0:0")?.with_peers([feed]);
        links.push(LinkConfig::ground(GROUND_LINK, udp.framing(), link.ground_bandwidth_bytes_per_s));
        driver.add(GROUND_LINK, Box::new(udp));
    }
    let mut comms_config = CommsConfig::new(RobotId(protocol_robot_id(config.robot.id) as u8), links);
    comms_config.initial_mode = config.robot.mode.mode();
    comms_config.cpu_cores = crate::task::usage::board_cores();
    comms_config.board_memory_kib = crate::task::usage::board_memory_kib();
    // A new boot id per start: peers reset their channels to a restarted process.
    comms_config.boot_id = (monotonic_ns() / 1_000) as u32 ^ std::process::id();
    if let Some(key) = &link.ground_key_file {
        comms_config = comms_config.with_key_file(key).map_err(|e| ProcessError::Setup(format!("comms: {e}")))?;
    }
    let comms = CommsNode::new(comms_config).map_err(|e| ProcessError::Setup(format!("comms: {e}")))?;
    Ok((comms, driver))
}

fn build(
    kind: NodeKind,
    config: &RoverConfig,
    setup: &SensorSetup,
    dir: &Path,
    sources: &dyn SourceProvider,
) -> Result<Hosted, ProcessError> {
    Ok(match kind {
        NodeKind::Driver => Hosted::Driver(Box::new(driver_node(config, sources)?)),
        NodeKind::Vision => Hosted::Vision(Box::new(stack::vision_node(config, setup)?)),
        NodeKind::Filter => {
            let state = dir.join("state");
            std::fs::create_dir_all(&state).map_err(io_error(&state))?;
            let mut filter = stack::filter_node(config, setup);
            filter.set_checkpoint_path(state.join("filter.ckpt"));
            Hosted::Filter(Box::new(filter))
        }
        NodeKind::Mapper => {
            let rectified =
                stack::rectified_calibration(setup).map_err(|e| ProcessError::Setup(format!("rectification: {e}")))?;
            let mut mapper_config = stack::mapper_config(config, rectified);
            mapper_config.state_dir = Some(dir.join("state"));
            // On the wall clock the matcher takes the CPU the real-time tasks leave.
            if let Some(matching) = &mut mapper_config.matching {
                matching.executor =
                    mapper::scheduler::Executor::Background { setup: crate::task::rt::idle_background_thread };
            }
            Hosted::Mapper(Box::new(
                MapperNode::new(mapper_config).map_err(|e| ProcessError::Setup(format!("mapper: {e}")))?,
            ))
        }
        NodeKind::Comms => {
            let (comms, links) = comms_node(config)?;
            Hosted::Comms(Box::new(comms), links)
        }
    })
}

/// The first point of the grid `epoch + k·period` at or after `now`: every process of the robot
/// releases on the same grid, and a late starter does not count the releases it missed.
fn grid_start_ns(epoch_ns: u64, period_ns: u64, now_ns: u64) -> u64 {
    if now_ns <= epoch_ns || period_ns == 0 {
        return epoch_ns;
    }
    epoch_ns + (now_ns - epoch_ns).div_ceil(period_ns) * period_ns
}

/// Runs process `kind` of the robot configured in `config_path` until SIGTERM or SIGINT; the
/// driver takes its sensors from `sources`.
pub fn node_main(kind: NodeKind, config_path: &Path, sources: &dyn SourceProvider) -> Result<(), ProcessError> {
    let stop = termination_flag()?;
    let setup_start = Instant::now();
    let config = RoverConfig::load(config_path)?;
    let dir = config.robot.output_dir();
    let tasks_dir = dir.join("tasks");
    std::fs::create_dir_all(&tasks_dir).map_err(io_error(&tasks_dir))?;

    let setup = sensor_setup(&config)?;
    let mut hosted = build(kind, &config, &setup, &dir, sources)?;
    if let Hosted::Driver(driver) = &hosted
        && let Some(from_source) = driver.stereo_calibration()
        && from_source != setup.calibration
    {
        return Err(ProcessError::Setup(
            "the sensor source's stereo calibration differs from the configuration's (camera.calibration)".into(),
        ));
    }
    let geometry =
        ImageGeometry { width_px: setup.calibration.left.width_px, height_px: setup.calibration.left.height_px };
    let bus = Bus::open(config.robot.bus_id(), kind.name(), geometry)?;
    let mut outbox = bus.outbox(&kind.publishes())?;
    let mut inbox = bus.inbox(hosted.node().subscriptions())?;
    let ready = dir.join(READY_DIR);
    std::fs::create_dir_all(&ready).map_err(io_error(&ready))?;
    std::fs::write(ready.join(kind.name()), b"").map_err(io_error(&ready))?;
    let setup_s = setup_start.elapsed().as_secs_f64();
    let Some(epoch_ns) = wait_for_epoch(&stop)? else { return Ok(()) };
    if let Hosted::Driver(driver) = &mut hosted {
        driver.set_live_epoch(epoch_ns);
    }
    let speed = if config.driver.kind == DriverKind::Replay { config.driver.replay_speed } else { 1.0 };
    let mut latency = SensorLatency {
        epoch_ns: (speed == 1.0).then_some(epoch_ns),
        imu: LogHistogram::new(),
        wheel: LogHistogram::new(),
    };
    let sensor_ns = move |monotonic: u64| (monotonic.saturating_sub(epoch_ns) as f64 * speed) as u64;
    if let Hosted::Filter(filter) = &mut hosted {
        match filter.resume(epoch_ns) {
            Ok(Some(stamp_ns)) => eprintln!("filter: resumed from the checkpoint at {:.3} s", stamp_ns as f64 * 1e-9),
            Ok(None) => {}
            Err(e) => eprintln!("filter: {e}; starting uninitialized"),
        }
    }

    // After the set-up: locking memory earlier would lock the world's build garbage too.
    let rt_report = rt::apply(&config.realtime.request(kind.process_kind()));
    let spec = kind.task_rate(&config.rates).spec(kind.name());
    let start_ns = grid_start_ns(epoch_ns, spec.period_ns, monotonic_ns());
    let mut task = FixedRateTask::monotonic(spec)?
        .with_identity(kind.process_kind(), 0)
        .with_stop_flag(Arc::clone(&stop))
        .with_start_ns(start_ns);
    eprintln!(
        "{}: bus {}, {} Hz, set up in {setup_s:.2} s, release 0 at sensor time {:.3} s",
        bus.node_name(),
        bus.robot_id(),
        kind.task_rate(&config.rates).hz,
        start_ns.saturating_sub(epoch_ns) as f64 * 1e-9
    );
    let mut stats_failed = 0u64;
    loop {
        let end = task.run_for_ns(STATS_PERIOD_NS, |release| {
            hosted.release(sensor_ns(release.start_ns), &mut inbox, &mut outbox, &mut latency)
        })?;
        // Telemetry is best effort: a full buffer never stops the task.
        let mut stats = task.stats();
        if let Hosted::Driver(driver) = &hosted
            && let Some(health) = driver.device_health()
        {
            stats.devices = device_bits(&health);
        }
        if let Some(peak) = inbox.take_queue_peak() {
            stats.queue_topic = u32::from(peak.topic.code());
            stats.queue_depth_max = peak.depth;
            stats.queue_capacity = peak.capacity;
        }
        if outbox.publish(Message::TaskStats(&stats)).is_err() {
            stats_failed += 1;
        }
        if end == RunEnd::Stopped {
            break;
        }
    }
    let now_ns = sensor_ns(monotonic_ns());
    let extra = finish(&mut hosted, &dir, now_ns, &mut inbox, &mut outbox, &mut latency)?;
    let stats = task.stats();
    let mut topics = serde_json::Map::new();
    for topic in inbox.topics() {
        let c = inbox.counters(topic);
        topics.insert(
            format!("in:{}", topic.path()),
            json!({"received": c.received, "rejected": c.rejected, "sequence_gaps": c.sequence_gaps}),
        );
    }
    for topic in outbox.topics() {
        let c = outbox.counters(topic);
        topics.insert(
            format!("out:{}", topic.path()),
            json!({"sent": c.sent, "deliveries": c.deliveries, "discarded": c.discarded, "failed": c.failed}),
        );
    }
    let path = tasks_dir.join(format!("{}.json", kind.name()));
    write_json(
        &path,
        &json!({
            "process": kind.name(),
            "pid": std::process::id(),
            "period_ns": stats.period_ns,
            "deadline_ns": stats.deadline_ns,
            "releases": stats.releases,
            "overruns": stats.overruns,
            "skipped": stats.skipped,
            "jitter_p50_ns": stats.jitter_p50_ns,
            "jitter_p99_ns": stats.jitter_p99_ns,
            "jitter_max_ns": stats.jitter_max_ns,
            "execution_max_ns": stats.execution_max_ns,
            "cpu_ns": stats.process_cpu_ns,
            "rss_bytes": stats.process_rss_bytes,
            "stats_publish_failed": stats_failed,
            "realtime": rt_json(&rt_report),
            "topics": Value::Object(topics),
            "sensor_latency": latency.json(),
            "node": extra,
        }),
    )?;
    Ok(())
}

/// The driver's devices as `TaskStatsMsg::devices` bits.
fn device_bits(health: &hal::sensor::DeviceHealth) -> u32 {
    let mut bits = msgs::TaskStatsMsg::DEVICES_REPORTED;
    for (status, bit) in [
        (&health.imu, msgs::TaskStatsMsg::DEVICE_IMU),
        (&health.wheels, msgs::TaskStatsMsg::DEVICE_WHEELS),
        (&health.head, msgs::TaskStatsMsg::DEVICE_HEAD),
    ] {
        if status.available {
            bits |= bit;
        }
    }
    bits
}

fn device_health_json(health: &hal::sensor::DeviceHealth) -> Value {
    let device = |d: &hal::sensor::DeviceStatus| json!({"available": d.available, "samples": d.samples, "dropouts": d.dropouts, "errors": d.errors});
    json!({"imu": device(&health.imu), "wheels": device(&health.wheels), "head": device(&health.head)})
}

fn rt_json(report: &RtReport) -> Value {
    json!({
        "fifo_priority": report.fifo_priority,
        "memory_locked": report.memory_locked,
        "cpu": report.cpu,
        "skipped": report.skipped,
    })
}

/// The last release's work and the node's files; returns node counters for the task file.
fn finish(
    hosted: &mut Hosted,
    dir: &Path,
    now_ns: u64,
    inbox: &mut BusInbox,
    outbox: &mut BusOutbox,
    latency: &mut SensorLatency,
) -> Result<Value, ProcessError> {
    match hosted {
        Hosted::Driver(driver) => {
            let c = driver.counts();
            Ok(json!({"imu": c.imu, "wheel": c.wheel, "stereo": c.stereo, "out_of_order": c.out_of_order,
                      "before_epoch": c.before_epoch, "devices": driver.device_health().map(|h| device_health_json(&h)),
                      "device_log": driver.device_log().iter()
                          .map(|(t_s, line)| json!({"t_s": t_s, "event": line})).collect::<Vec<_>>(),
                      "finished": driver.finished(), "time_offset_ns": driver.time_offset_ns()}))
        }
        Hosted::Vision(vision) => {
            let s = vision.summary();
            Ok(json!({"frames": s.frames, "vo_deltas": s.vo_deltas, "keyframes": s.keyframes,
                      "disparity_published": s.disparity_published, "bad_stereo": s.bad_stereo,
                      "markers_detected": s.markers.tags_detected, "markers_published": s.markers.published,
                      "markers_gated": s.markers.gated, "priors_used": s.priors_used,
                      "prior_state_missing": s.prior_state_missing}))
        }
        Hosted::Filter(filter) => {
            let s = filter.summary();
            let summary = json!({
                "imu_received": s.imu_received,
                "imu_lost": s.imu_lost,
                "imu_stream_gaps": s.imu_stream_gaps,
                "clones_without_imu": s.clones_without_imu,
                "imu_gap_max_ns": s.imu_gap_max_ns,
                "imu_rejected": s.imu_rejected,
                "initialized_ns": s.initialized_ns,
                "vo_received": s.vo_received,
                "vo_late": s.vo_late,
                "vo_updates_applied": s.vo_updates_applied,
                "vo_updates_rejected": s.vo_updates_rejected,
                "vo_dropped": s.vo_dropped,
                "wheel_updates_applied": s.wheel_updates_applied,
                "frame_switches": s.frame_switches,
                "bad_messages": s.bad_messages,
                "filter_errors": s.filter_errors,
                "resumes": s.resumes,
                "resumed_from_ns": s.resumed_from_ns,
                "restart_gap_ns": s.restart_gap_ns,
                "restart_imu_lost": s.restart_imu_lost,
                "imu_replayed": s.imu_replayed,
                "checkpoints_written": s.checkpoints_written,
                "checkpoint_errors": s.checkpoint_errors,
                "frame_id": filter.frame_id(),
            });
            write_json(&dir.join("filter_summary.json"), &summary)?;
            Ok(summary)
        }
        Hosted::Mapper(_) => {
            // What arrived since the last release still belongs to the map.
            hosted.release(now_ns, inbox, outbox, latency)?;
            let Hosted::Mapper(mapper) = hosted else { return Ok(Value::Null) };
            let estimate = mapper.online_trajectory().to_vec();
            let written = mapper.write_outputs(dir).map_err(|e| ProcessError::Output(e.to_string()))?;
            super::write_tum(&dir.join("estimate.tum"), &estimate)?;
            let c = mapper.counters();
            let status = json!({
                "first_estimate_ns": estimate.first().map(|r| r.0),
                "estimate_poses": estimate.len(),
                "graph_nodes": written.graph.nodes,
                "graph_factors": written.graph.factors,
                "connected": mapper.team_estimate().connected_robots(),
                "markers_received": c.markers_received,
                "marker_detections": c.marker_detections,
                "markers_refused": c.markers_refused,
                "markers_skipped": c.markers_skipped,
                "submaps_finished": c.submaps_finished,
                "submaps_sent": c.submaps_sent,
                "submaps_received": c.submaps_received,
                "images_integrated": c.images_integrated,
                "switch_requests": c.switch_requests,
                "messages_rejected": c.messages_rejected,
                "submaps_restored": c.submaps_restored,
                "own_submaps": mapper.own_submaps().map(|s| s.index).collect::<Vec<_>>(),
                "current_submap": mapper.current_submap().index,
                "matching": mapper.matcher().map(|m| {
                    let s = m.stats();
                    json!({
                        "submaps_checked": s.submaps_added,
                        "submaps_unsuitable": s.submaps_unsuitable,
                        "attempts": s.attempts,
                        "accepted": s.accepted,
                        "rejected": s.rejected,
                        "queued": s.queued,
                    })
                }),
            });
            write_json(&dir.join("mapper_status.json"), &status)?;
            Ok(status)
        }
        Hosted::Comms(comms, links) => {
            links.pump(comms, now_ns)?;
            let s = comms.stats();
            let by_class: serde_json::Map<String, Value> =
                s.sent_by_class.iter().map(|(k, v)| ((*k).to_owned(), json!(v.wire_bytes))).collect();
            let d = links.stats();
            let stats = json!({
                "sent_wire_bytes_by_class": by_class,
                "packets_sent": s.packets_sent,
                "packets_received": s.packets_received,
                "retransmissions": s.retransmissions,
                "delivered_to_mapper": s.delivered_to_mapper,
                "packet_rejections": s.packet_rejections,
                "peer_restarts": s.peer_restarts,
                "link_send_errors": d.send_errors,
                "link_packets_sent": d.packets_sent,
                "link_packets_received": d.packets_received,
            });
            write_json(&dir.join("comms_stats.json"), &stats)?;
            Ok(stats)
        }
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn late_starter_joins_the_shared_grid() {
        assert_eq!(grid_start_ns(1_000, 5, 900), 1_000);
        assert_eq!(grid_start_ns(1_000, 5, 1_000), 1_000);
        assert_eq!(grid_start_ns(1_000, 5, 1_001), 1_005);
        assert_eq!(grid_start_ns(1_000, 5, 1_005), 1_005);
        assert_eq!(grid_start_ns(1_000, 0, 2_000), 1_000);
    }
}
