//! The mission on the lockstep runner: every robot's driver, vision, filter, mapper and comms
//! nodes in this process on simulated time, the radios between robots as link emulators.
//!
//! Time advances in IMU periods (5 ms). Per step and robot: the driver publishes the sensor data
//! due, every message is delivered through the robot's [`LocalBus`]; the mapper's task runs at
//! 10 Hz and the comms task at 50 Hz of sensor time; then every radio moves the packets that
//! arrived. Deterministic for a seed: no thread, clock or hash order decides anything (with a
//! `--feed` ground station, what it sends back is of course its own).
//!
//! Ground link: every robot's comms has one ([`GROUND_LINK`], rate
//! [`GROUND_RATE_BYTES_PER_S`]); per step its packets go to the [`GroundEnd`] (the ground station
//! at `--feed`, or the in-process stand-in), and what the ground sends back (acks, commands) is
//! read without waiting and handed to the addressed robot's ground link. Everything is recorded
//! in `out/ground_feed.log`. No link delay is emulated here: simulated time runs at the
//! machine's pace, not the wall clock's.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use hal::emulator::{DuplexEmulator, EmulatorConfig};
use protocol::{NodeId, RobotId};
use sim::world::World;

use super::report::{MissionReport, ProcessReport, RobotReport};
use super::truth_closures::TruthLoopClosures;
use super::world::{mapper_config, mission_world, robot_id, truth_in_own_frame};
use super::{MissionError, MissionOptions, RadioPreset, write_outputs};
use crate::lockstep::OwnedMessage;
use crate::lockstep::{LocalBus, NodeTimes};
use crate::nodes::comms::{
    CommsConfig, CommsNode, GROUND_RATE_BYTES_PER_S, GroundEnd, LinkConfig, LinkId, step_duplex,
};
use crate::nodes::driver::{DriverNode, DriverOptions};
use crate::nodes::filter::{FilterNode, FilterNodeOptions};
use crate::nodes::mapper::MapperNode;
use crate::nodes::vision::{VisionNode, VisionNodeOptions};
use crate::nodes::{Node, Topic};
use crate::team_record::sim_vio_options;

const STEP_NS: u64 = 5_000_000;
const MAPPER_PERIOD_NS: u64 = 100_000_000;
const COMMS_PERIOD_NS: u64 = 20_000_000;
/// Ground link id on every robot; team links are `LinkId(1 + peer index)`.
pub const GROUND_LINK: LinkId = LinkId(0);
/// The recording of the ground link in the output folder (`hal::feedlog`).
pub const GROUND_FEED_LOG: &str = "ground_feed.log";

/// One robot's nodes.
#[derive(Debug)]
pub struct RobotStack {
    pub robot: usize,
    pub driver: DriverNode,
    pub vision: VisionNode,
    pub filter: FilterNode,
    pub mapper: MapperNode,
    pub comms: CommsNode,
    pub bus: LocalBus,
    pub times: NodeTimes,
}

const NODE_NAMES: [&str; 5] = ["driver", "vision", "filter", "mapper", "comms"];

impl RobotStack {
    fn nodes(&mut self) -> ([&mut dyn Node; 5], &mut LocalBus, &mut NodeTimes) {
        (
            [&mut self.driver, &mut self.vision, &mut self.filter, &mut self.mapper, &mut self.comms],
            &mut self.bus,
            &mut self.times,
        )
    }

    fn step(&mut self, now_ns: u64) -> Result<(), MissionError> {
        let mapper_due = now_ns.is_multiple_of(MAPPER_PERIOD_NS);
        let comms_due = now_ns.is_multiple_of(COMMS_PERIOD_NS);
        // Vision and filter are event-driven; their ticks run at the driver's rate (a no-op for
        // most) so that time-based work in them (late-prior waits) progresses.
        let due = [true, true, true, mapper_due, comms_due];
        let (mut nodes, bus, times) = self.nodes();
        bus.tick(now_ns, &mut nodes, &due, times).map_err(|e| MissionError::Node(self_robot(self.robot), e))
    }
}

fn self_robot(robot: usize) -> String {
    format!("robot {robot}")
}

fn radio_config(preset: RadioPreset) -> EmulatorConfig {
    match preset {
        RadioPreset::SerialRadio => EmulatorConfig::serial_radio_57k6(),
        RadioPreset::Wifi => EmulatorConfig::lossy_wifi(),
    }
}

/// Builds robot `robot`'s stack; its mapper keeps its state under `out/robotN/state`.
pub fn robot_stack(
    world: &Arc<World>,
    robot: usize,
    options: &MissionOptions,
    out: &Path,
) -> Result<RobotStack, MissionError> {
    let node_error = |e| MissionError::Node(self_robot(robot), e);
    let end_ns = (options.duration_s * 1e9) as u64;
    let driver =
        DriverNode::new(Arc::clone(world), robot, DriverOptions { end_stamp_ns: Some(end_ns) }).map_err(node_error)?;
    let calibration = driver
        .stereo_calibration()
        .ok_or_else(|| MissionError::World(format!("robot {robot} has no stereo camera")))?;
    let vio = sim_vio_options(world, true);
    let vision = VisionNode::new(&calibration, VisionNodeOptions::from_vio(&vio)).map_err(node_error)?;
    let filter = FilterNode::new(FilterNodeOptions::from_vio(&vio));
    let mut mapper_config = mapper_config(robot, *vision.rectified_calibration(), options.downscale);
    mapper_config.state_dir = Some(out.join(format!("robot{robot}")).join("state"));
    if let Some(distance_m) = options.submap_max_distance_m {
        mapper_config.policy.max_distance_m = distance_m;
    }
    let mapper =
        MapperNode::new(mapper_config).map_err(|e| MissionError::Setup(format!("robot {robot} mapper: {e}")))?;
    let radio = radio_config(options.radio);
    let mut links = Vec::new();
    for peer in (0..options.robots).filter(|&p| p != robot) {
        let peer_id = RobotId(robot_id(peer) as u8);
        links.push(LinkConfig::team(
            LinkId(1 + peer as u8),
            &format!("radio to robot {peer}"),
            radio.framing,
            radio.bandwidth_bytes_per_s,
            vec![peer_id],
        ));
    }
    links.push(LinkConfig::ground(GROUND_LINK, hal_datagram(), GROUND_RATE_BYTES_PER_S));
    let mut comms_config = CommsConfig::new(RobotId(robot_id(robot) as u8), links);
    comms_config.boot_id = robot_id(robot).into();
    if let Some(key) = &options.ground_key {
        comms_config =
            comms_config.with_key_file(key).map_err(|e| MissionError::Setup(format!("--ground-key: {e}")))?;
    }
    let comms = CommsNode::new(comms_config).map_err(|e| MissionError::Setup(format!("robot {robot} comms: {e}")))?;
    Ok(RobotStack { robot, driver, vision, filter, mapper, comms, bus: LocalBus::new(), times: NodeTimes::default() })
}

fn hal_datagram() -> protocol::frame::Framing {
    // One UDP datagram per packet, below the usual 1280-byte IPv6 minimum MTU.
    protocol::frame::Framing::Datagram { mtu: 1200 }
}

/// Moves one step's ground traffic: what the ground sent back first (it may free window room),
/// then what each robot may send now.
fn step_ground(ground: &mut GroundEnd, robots: &mut [RobotStack], now_ns: u64) {
    while let Some((node, packet)) = ground.poll_uplink(now_ns) {
        if let Some(stack) = robots.iter_mut().find(|s| robot_id(s.robot) == u16::from(node.0)) {
            stack.comms.handle_packet(now_ns, GROUND_LINK, packet);
        }
    }
    for stack in robots.iter_mut() {
        let node = NodeId(robot_id(stack.robot) as u8);
        while let Some(packet) = stack.comms.poll_transmit_on(now_ns, GROUND_LINK) {
            ground.downlink(now_ns, node, packet);
        }
    }
}

/// Runs the mission of `options` on the lockstep runner and writes its outputs.
pub fn run(options: &MissionOptions) -> Result<MissionReport, MissionError> {
    let wall = Instant::now();
    let out = &options.out;
    std::fs::create_dir_all(out).map_err(|e| MissionError::Io { path: out.clone(), source: e })?;
    // A fresh mission: the mappers must not restore the journal of an earlier run in this folder.
    for robot in 0..options.robots {
        let state = out.join(format!("robot{robot}")).join("state");
        if state.exists() {
            std::fs::remove_dir_all(&state).map_err(|e| MissionError::Io { path: state.clone(), source: e })?;
        }
    }
    let world = mission_world(options)?;
    let mut robots =
        (0..options.robots).map(|r| robot_stack(&world, r, options, out)).collect::<Result<Vec<_>, _>>()?;
    let radio = radio_config(options.radio);
    let mut radios: BTreeMap<(usize, usize), DuplexEmulator> = BTreeMap::new();
    for a in 0..options.robots {
        for b in a + 1..options.robots {
            let seed = options.seed.wrapping_mul(1_000_003).wrapping_add((a * 64 + b) as u64);
            radios.insert((a, b), DuplexEmulator::symmetric(radio.clone().with_seed(seed)));
        }
    }
    let nodes: Vec<NodeId> = (0..options.robots).map(|r| NodeId(robot_id(r) as u8)).collect();
    let mut ground = GroundEnd::new(options.feed, &nodes, Some(&out.join(GROUND_FEED_LOG)))
        .map_err(|e| MissionError::Setup(e.to_string()))?;
    let mut truth = options.truth_loop_closures.then(|| TruthLoopClosures::new(&world, options.robots));
    if truth.is_some() {
        for stack in &mut robots {
            stack.bus.tap(&[Topic::FrameSwitch]);
        }
    }
    let camera_period_ns = (1e9 / world.scenario.camera_rate_hz).round() as u64;
    let end_ns = (options.duration_s * 1e9) as u64;
    let mut now_ns = 0;
    while now_ns <= end_ns {
        for stack in &mut robots {
            stack.step(now_ns)?;
        }
        if let Some(truth) = &mut truth {
            for stack in &mut robots {
                for message in stack.bus.take_tapped() {
                    if let OwnedMessage::FrameSwitch(s) = message {
                        truth.on_frame_switch(stack.robot, s.stamp_ns);
                    }
                }
                if let Some(init) = stack.filter.summary().initialized_ns {
                    truth.on_initialized(stack.robot, init);
                }
                if now_ns.is_multiple_of(camera_period_ns) {
                    truth.detect(stack.robot, now_ns, &mut stack.mapper, &mut stack.bus)?;
                }
            }
            if truth.match_due(now_ns) {
                for stack in &mut robots {
                    truth.match_for(stack.robot, &mut stack.mapper, &mut stack.bus)?;
                }
                truth.matched();
            }
            for stack in &mut robots {
                let robot = stack.robot;
                let (mut nodes, bus, times) = stack.nodes();
                bus.deliver(&mut nodes, times).map_err(|e| MissionError::Node(self_robot(robot), e))?;
            }
        }
        for (&(a, b), duplex) in &mut radios {
            let (left, right) = robots.split_at_mut(b);
            let (ra, rb) = (&mut left[a], &mut right[0]);
            step_duplex(duplex, now_ns, (&mut ra.comms, LinkId(1 + b as u8)), (&mut rb.comms, LinkId(1 + a as u8)));
        }
        step_ground(&mut ground, &mut robots, now_ns);
        now_ns += STEP_NS;
    }
    let mut robot_reports = Vec::new();
    let mut processes = Vec::new();
    for stack in &mut robots {
        let node_error = |e| MissionError::Node(self_robot(stack.robot), e);
        stack.vision.flush(&mut stack.bus).map_err(node_error)?;
        stack.filter.flush();
        {
            let robot = stack.robot;
            let (mut nodes, bus, times) = stack.nodes();
            bus.deliver(&mut nodes, times).map_err(|e| MissionError::Node(self_robot(robot), e))?;
            bus.tick(end_ns, &mut nodes, &[false, false, false, true, false], times)
                .map_err(|e| MissionError::Node(self_robot(robot), e))?;
        }
        let summary = stack.filter.summary();
        let estimate = stack.mapper.online_trajectory().to_vec();
        let truth = summary
            .initialized_ns
            .and_then(|init| truth_in_own_frame(&world, stack.robot, init, stack.driver.truth_log()));
        let robot_dir = out.join(format!("robot{}", stack.robot));
        let written = write_outputs(&robot_dir, &mut stack.mapper, &estimate, truth.as_deref())?;
        let comms = stack.comms.stats();
        robot_reports.push(RobotReport {
            robot: robot_id(stack.robot),
            score: written.score,
            score_error: written.score_error,
            graph_nodes: written.graph_nodes,
            graph_factors: written.graph_factors,
            connected: written.connected,
            submaps_finished: written.submaps_finished,
            submaps_received: written.submaps_received,
            imu_received: summary.imu_received,
            imu_lost: summary.imu_lost,
            bytes_sent_by_class: comms.sent_by_class.iter().map(|(k, v)| ((*k).to_owned(), v.wire_bytes)).collect(),
        });
        for (name, seconds) in NODE_NAMES.iter().zip(&stack.times.seconds) {
            processes.push(ProcessReport {
                robot: robot_id(stack.robot),
                process: (*name).to_owned(),
                releases: 0,
                deadline_overruns: 0,
                skipped_releases: 0,
                jitter_p50_us: 0.0,
                jitter_p99_us: 0.0,
                jitter_max_us: 0.0,
                cpu_s: *seconds,
                restarts: 0,
            });
        }
    }
    ground.flush().map_err(|e| MissionError::Output(e.to_string()))?;
    let report = MissionReport {
        runner: "lockstep".to_owned(),
        scenario: options.scenario.clone(),
        seed: options.seed,
        duration_s: options.duration_s,
        wall_s: wall.elapsed().as_secs_f64(),
        truth_loop_closures: options.truth_loop_closures,
        robots: robot_reports,
        processes,
    };
    super::write_report(out, &report)?;
    Ok(report)
}
