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
use onboard::lockstep::{NODE_NAMES, OwnedMessage, RobotStack, STEP_NS};
use onboard::nodes::Topic;
use onboard::nodes::comms::{CommsConfig, CommsNode, GROUND_RATE_BYTES_PER_S, LinkConfig, LinkId, step_duplex};
use onboard::sensors::sensor_setup;
use protocol::{NodeId, RobotId};
use sim::driver::SimSensorSource;
use sim::world::World;

use super::events::closure_events;
use super::progress::{Progress, RobotProgress, path_length_m};
use super::replay::replay_variants;
use super::report::{LinkTraffic, MissionReport, ProcessReport, RobotReport, SubmapTraffic};
use super::screening::ClosureScreening;
use super::world::{
    inter_robot_errors, marker_model_name, mission_world, robot_config, robot_id, truth_at_captures, truth_in_own_frame,
};
use super::{MissionError, MissionOptions, RadioPreset, write_outputs};
use crate::ground_end::GroundEnd;
use crate::truth_closures::TruthLoopClosures;

/// Ground link id on every robot; team links are `LinkId(1 + peer index)`.
pub const GROUND_LINK: LinkId = LinkId(0);
/// The recording of the ground link in the output folder (`hal::feedlog`).
pub const GROUND_FEED_LOG: &str = "ground_feed.log";

/// One robot of the lockstep mission: the firmware's stack and its index.
#[derive(Debug)]
pub struct MissionRobot {
    pub robot: usize,
    pub stack: RobotStack,
}

/// A robot's own submap traffic from its comms counters, and the encoded size of the submaps it
/// persisted (`robotN/state/submaps/*.subm`).
fn submap_traffic(
    comms: &onboard::nodes::comms::CommsStats,
    submaps: u64,
    robot_dir: &Path,
) -> Result<SubmapTraffic, MissionError> {
    let traffic = |by_class: &BTreeMap<&'static str, onboard::nodes::comms::ClassTraffic>| {
        ["SubmapHeader", "SubmapChunk"].iter().filter_map(|c| by_class.get(c)).fold(LinkTraffic::default(), |t, c| {
            LinkTraffic {
                packets: t.packets + c.packets,
                wire_bytes: t.wire_bytes + c.wire_bytes,
                retransmissions: t.retransmissions + c.retransmissions,
            }
        })
    };
    let (all, ground) = (traffic(&comms.sent_by_class), traffic(&comms.ground_sent_by_class));
    let team = LinkTraffic {
        packets: all.packets - ground.packets,
        wire_bytes: all.wire_bytes - ground.wire_bytes,
        retransmissions: all.retransmissions - ground.retransmissions,
    };
    let dir = robot_dir.join("state").join("submaps");
    let io = |e| MissionError::Io { path: dir.clone(), source: e };
    let mut payload_bytes = 0;
    if dir.is_dir() {
        for entry in std::fs::read_dir(&dir).map_err(io)? {
            let entry = entry.map_err(io)?;
            if entry.path().extension().is_some_and(|e| e == "subm") {
                payload_bytes += entry.metadata().map_err(io)?.len();
            }
        }
    }
    Ok(SubmapTraffic { submaps, payload_bytes, team, ground })
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

/// Builds robot `robot`'s stack from its mission configuration (the one the process runner
/// writes to its `rover.toml`); its mapper keeps its state under `out/robotN/state`.
pub fn robot_stack(
    world: &Arc<World>,
    robot: usize,
    options: &MissionOptions,
    out: &Path,
) -> Result<MissionRobot, MissionError> {
    let node_error = |e| MissionError::Node(self_robot(robot), e);
    let config = robot_config(options, world, robot)?;
    // The configuration the robot runs with, as the process runner would hand it to `sil run`.
    let robot_dir = out.join(format!("robot{robot}"));
    std::fs::create_dir_all(&robot_dir).map_err(|e| MissionError::Io { path: robot_dir.clone(), source: e })?;
    let toml_path = robot_dir.join("rover.toml");
    std::fs::write(&toml_path, config.to_toml_string()).map_err(|e| MissionError::Io { path: toml_path, source: e })?;
    let setup = sensor_setup(&config).map_err(|e| MissionError::Setup(format!("robot {robot}: {e}")))?;
    let source = SimSensorSource::new(Arc::clone(world), robot)
        .map_err(|e| MissionError::World(format!("robot {robot} sensors: {e}")))?;
    let radio = radio_config(options.radio);
    let mut links = Vec::new();
    for peer in (0..options.robots).filter(|&p| p != robot && !options.solo) {
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
    comms_config.initial_mode = config.robot.mode.mode();
    comms_config.cpu_cores = onboard::task::usage::board_cores();
    comms_config.board_memory_kib = onboard::task::usage::board_memory_kib();
    if let Some(key) = &options.ground_key {
        comms_config =
            comms_config.with_key_file(key).map_err(|e| MissionError::Setup(format!("--ground-key: {e}")))?;
    }
    let comms = CommsNode::new(comms_config).map_err(|e| MissionError::Setup(format!("robot {robot} comms: {e}")))?;
    let state_dir = out.join(format!("robot{robot}")).join("state");
    let stack =
        RobotStack::new(&config, &setup, Box::new(source), Some(comms), Some(state_dir)).map_err(|e| match e {
            onboard::lockstep::StackError::Node(e) => node_error(e),
            onboard::lockstep::StackError::Setup(e) => MissionError::Setup(format!("robot {robot}: {e}")),
        })?;
    Ok(MissionRobot { robot, stack })
}

fn comms(stack: &mut RobotStack) -> Result<&mut CommsNode, MissionError> {
    stack.comms.as_mut().ok_or_else(|| MissionError::Setup("a mission robot without comms".into()))
}

fn hal_datagram() -> protocol::frame::Framing {
    // One UDP datagram per packet, below the usual 1280-byte IPv6 minimum MTU.
    protocol::frame::Framing::Datagram { mtu: 1200 }
}

/// Steps every robot to `now_ns`, the robots split over up to `threads` threads. Between two
/// steps the robots only meet through the radios, which the runner moves after this returns,
/// so the order in which they step decides nothing: the outputs are those of a sequential run.
fn step_robots(robots: &mut [MissionRobot], now_ns: u64, threads: usize) -> Result<(), MissionError> {
    let step_all = |robots: &mut [MissionRobot]| {
        robots.iter_mut().try_for_each(|r| r.stack.step(now_ns).map_err(|e| MissionError::Node(self_robot(r.robot), e)))
    };
    if threads <= 1 || robots.len() < 2 {
        return step_all(robots);
    }
    let per_thread = robots.len().div_ceil(threads.min(robots.len()));
    std::thread::scope(|scope| {
        let mut groups = robots.chunks_mut(per_thread);
        let first = groups.next();
        let others: Vec<_> = groups.map(|group| scope.spawn(move || step_all(group))).collect();
        // The first error in robot order, as a sequential run would report it.
        let mut result = first.map_or(Ok(()), step_all);
        for handle in others {
            let outcome = handle.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            result = result.and(outcome);
        }
        result
    })
}

/// Moves one step's ground traffic: what the ground sent back first (it may free window room),
/// then what each robot may send now.
fn step_ground(ground: &mut GroundEnd, robots: &mut [MissionRobot], now_ns: u64) -> Result<(), MissionError> {
    while let Some((node, packet)) = ground.poll_uplink(now_ns) {
        if let Some(r) = robots.iter_mut().find(|r| robot_id(r.robot) == u16::from(node.0)) {
            comms(&mut r.stack)?.handle_packet(now_ns, GROUND_LINK, packet);
        }
    }
    for r in robots.iter_mut() {
        let node = NodeId(robot_id(r.robot) as u8);
        let comms = comms(&mut r.stack)?;
        while let Some(packet) = comms.poll_transmit_on(now_ns, GROUND_LINK) {
            ground.downlink(now_ns, node, packet);
        }
    }
    Ok(())
}

/// What robot `r` has so far, for the progress line.
fn robot_progress(r: &MissionRobot) -> RobotProgress {
    let mapper = &r.stack.mapper;
    RobotProgress {
        robot: robot_id(r.robot),
        distance_m: path_length_m(mapper.online_trajectory()),
        submaps: mapper.counters().submaps_finished,
        matches: mapper.matcher().map_or(0, |m| m.stats().accepted),
        detections: mapper.counters().marker_detections,
        connected: mapper.team_estimate().connected_robots(),
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
    for a in (0..options.robots).filter(|_| !options.solo) {
        for b in a + 1..options.robots {
            let seed = options.seed.wrapping_mul(1_000_003).wrapping_add((a * 64 + b) as u64);
            radios.insert((a, b), DuplexEmulator::symmetric(radio.clone().with_seed(seed)));
        }
    }
    let nodes: Vec<NodeId> = (0..options.robots).map(|r| NodeId(robot_id(r) as u8)).collect();
    let mut ground = GroundEnd::new(options.feed, &nodes, Some(&out.join(GROUND_FEED_LOG)))
        .map_err(|e| MissionError::Setup(e.to_string()))?;
    let mut truth = options.truth_loop_closures.then(|| {
        TruthLoopClosures::new(&world, options.robots)
            .with_wrong_closures(options.wrong_closure_fraction, options.seed)
            .intra_robot_only(options.solo)
    });
    if truth.is_some() {
        for r in &mut robots {
            r.stack.bus.tap(&[Topic::FrameSwitch]);
        }
    }
    let camera_period_ns = (1e9 / world.scenario.camera_rate_hz).round() as u64;
    let end_ns = (options.duration_s * 1e9) as u64;
    if options.replay_variants {
        for r in &mut robots {
            r.stack.mapper.log_graph_inserts();
        }
    }
    let mut now_ns = 0;
    let mut progress = Progress::new(options.progress, options.duration_s);
    while now_ns <= end_ns {
        step_robots(&mut robots, now_ns, options.step_threads)?;
        if progress.due() {
            progress.draw(now_ns as f64 * 1e-9, &robots.iter().map(robot_progress).collect::<Vec<_>>());
        }
        if let Some(truth) = &mut truth {
            for r in &mut robots {
                for message in r.stack.bus.take_tapped() {
                    if let OwnedMessage::FrameSwitch(s) = message {
                        truth.on_frame_switch(r.robot, s.stamp_ns);
                    }
                }
                if let Some(init) = r.stack.filter.summary().initialized_ns {
                    truth.on_initialized(r.robot, init);
                }
                if now_ns.is_multiple_of(camera_period_ns) {
                    truth.detect(r.robot, now_ns, &mut r.stack.mapper, &mut r.stack.bus)?;
                }
            }
            if truth.match_due(now_ns) {
                for r in &mut robots {
                    truth.match_for(r.robot, &mut r.stack.mapper, &mut r.stack.bus)?;
                }
                truth.matched();
            }
            for r in &mut robots {
                r.stack.deliver().map_err(|e| MissionError::Node(self_robot(r.robot), e))?;
            }
        }
        for (&(a, b), duplex) in &mut radios {
            let (left, right) = robots.split_at_mut(b);
            let (ra, rb) = (comms(&mut left[a].stack)?, comms(&mut right[0].stack)?);
            step_duplex(duplex, now_ns, (ra, LinkId(1 + b as u8)), (rb, LinkId(1 + a as u8)));
        }
        step_ground(&mut ground, &mut robots, now_ns)?;
        now_ns += STEP_NS;
    }
    progress.finish();
    let mut robot_reports = Vec::new();
    let mut processes = Vec::new();
    for r in &mut robots {
        r.stack.finish(end_ns).map_err(|e| MissionError::Node(self_robot(r.robot), e))?;
    }
    // Each robot's filter poses, the latest that every other robot's graph can place (eq. 4.6:
    // its submap origin connected there): where the team thinks its members are.
    let filter_poses: Vec<Vec<mapper::slam::FilterPose>> = robots
        .iter()
        .map(|r| {
            let buffer = r.stack.mapper.graph().pose_buffer(robot_id(r.robot));
            buffer.map(|b| b.range(0, u64::MAX).copied().collect()).unwrap_or_default()
        })
        .collect();
    let placed: Vec<Vec<(u16, u64, nalgebra::Isometry3<f64>)>> = robots
        .iter()
        .map(|observer| {
            let graph = observer.stack.mapper.graph();
            filter_poses
                .iter()
                .filter_map(|poses| {
                    poses
                        .iter()
                        .rev()
                        .filter(|p| p.robot != robot_id(observer.robot))
                        .find_map(|p| Some((p.robot, p.stamp_ns, graph.online_pose(p)?)))
                })
                .collect()
        })
        .collect();
    // Where each finished submap starts (submap 0: the filter's initialization), for the truth
    // of the matches.
    let mut submap_starts_ns: BTreeMap<mapper::slam::SubmapId, u64> = BTreeMap::new();
    for r in &robots {
        let init_ns = r.stack.filter.summary().initialized_ns;
        for s in r.stack.mapper.own_submaps() {
            let start_ns = if s.index == 0 { init_ns } else { Some(s.start_stamp_ns) };
            if let Some(start_ns) = start_ns {
                submap_starts_ns.insert(mapper::slam::SubmapId::new(s.robot_id, s.index), start_ns);
            }
        }
    }
    let truth_origins = sim::truth_constraints::TruthConstraints::new(Arc::clone(&world), Default::default());
    let true_origin = |id: mapper::slam::SubmapId| {
        let robot = (1..=options.robots).find(|&r| robot_id(r - 1) == id.robot)? - 1;
        truth_origins.true_origin(robot, *submap_starts_ns.get(&id)?)
    };
    for (r, placed) in robots.iter_mut().zip(&placed) {
        let robot = r.robot;
        let stack = &mut r.stack;
        let summary = stack.filter.summary();
        let estimate = stack.mapper.online_trajectory().to_vec();
        let truth = summary
            .initialized_ns
            .and_then(|init| truth_in_own_frame(&world, robot, init, &truth_at_captures(&world, robot)));
        let robot_dir = out.join(format!("robot{robot}"));
        let written = write_outputs(&robot_dir, &mut stack.mapper, &estimate, truth.as_deref())?;
        let inter_robot_error_m = summary
            .initialized_ns
            .map_or_else(Default::default, |init| inter_robot_errors(&world, robot, init, placed));
        let (replays, closure_events) = if options.replay_variants {
            let graph = stack.mapper.graph();
            let inserts = stack.mapper.graph_inserts();
            (replay_variants(graph.own(), graph.config(), inserts, truth.as_deref()), closure_events(inserts))
        } else {
            (Vec::new(), Vec::new())
        };
        let comms = comms(stack)?.stats();
        robot_reports.push(RobotReport {
            replays,
            closure_events,
            step_times: Some(*stack.mapper.step_times()),
            robot: robot_id(robot),
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
            markers_published: stack.vision.summary().markers.published,
            marker_detections: stack.mapper.counters().marker_detections,
            inter_robot_error_m,
            submap_traffic: Some(submap_traffic(&comms, stack.mapper.counters().submaps_finished, &robot_dir)?),
            matching: stack.mapper.matcher().map(|m| {
                let mut report = super::matching::MatchingReport::new(m, &true_origin);
                if options.compare_match_modes {
                    let mut params = m.config().matcher.clone();
                    let (mode, name) = match params.mode {
                        mapper::matching::MatchMode::FourDof => (mapper::matching::MatchMode::SixDof, "6d"),
                        mapper::matching::MatchMode::SixDof => (mapper::matching::MatchMode::FourDof, "4d"),
                    };
                    params.mode = mode;
                    report.other_mode = Some(super::matching::OtherMode::rematch(m, &params, name, &true_origin));
                }
                report
            }),
        });
        for (name, seconds) in NODE_NAMES.iter().zip(&stack.times.seconds) {
            processes.push(ProcessReport::lockstep(robot_id(robot), name, *seconds));
        }
    }
    let pair_evaluation = if options.evaluate_match_pairs {
        let mut marginals = Vec::new();
        for r in &mut robots {
            let m: BTreeMap<_, _> = r
                .stack
                .mapper
                .submap_marginals()
                .map_err(|e| MissionError::Output(format!("marginals for the pair evaluation: {e}")))?
                .into_iter()
                .map(|(id, m)| (id, m.fixed_view::<3, 3>(0, 0).into_owned()))
                .collect();
            marginals.push(m);
        }
        let views: Vec<_> = robots
            .iter()
            .zip(marginals)
            .filter_map(|(r, marginals)| {
                let mapper = &r.stack.mapper;
                Some(super::matching::RobotView { scheduler: mapper.matcher()?, graph: mapper.graph(), marginals })
            })
            .collect();
        views.first().map(|first| {
            let min_overlap_m2 = first.scheduler.config().pairing.min_overlap_m2;
            super::matching::PairEvaluation::run(&views, min_overlap_m2, &true_origin)
        })
    } else {
        None
    };
    ground.flush().map_err(|e| MissionError::Output(e.to_string()))?;
    let closure_screening = truth.as_ref().map(|truth| ClosureScreening {
        consistency: format!("{:?}", options.consistency).to_lowercase(),
        wrong_fraction: options.wrong_closure_fraction,
        inter_robot_closures: truth.inter_robot_closures,
        injected_wrong: truth.wrong.len() as u64,
        robots: robots
            .iter()
            .map(|r| ClosureScreening::robot(robot_id(r.robot), r.stack.mapper.graph(), &truth.wrong))
            .collect(),
    });
    let report = MissionReport {
        runner: "lockstep".to_owned(),
        scenario: options.scenario.clone(),
        seed: options.seed,
        duration_s: options.duration_s,
        wall_s: wall.elapsed().as_secs_f64(),
        truth_loop_closures: options.truth_loop_closures,
        solo: options.solo,
        closure_screening,
        marker_model: marker_model_name(options),
        robots: robot_reports,
        processes,
        pair_evaluation,
    };
    super::write_report(out, &report)?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use onboard::nodes::comms::{ClassTraffic, CommsStats};

    use super::*;

    /// Team traffic is everything on the links minus the ground's, only submap classes count,
    /// and the payload is what the `.subm` files hold (other files in the folder are not).
    #[test]
    fn submap_traffic_splits_team_from_ground_and_counts_the_subm_files() {
        let dir = std::env::temp_dir().join(format!("sil-submap-traffic-{}", std::process::id()));
        let submaps = dir.join("state").join("submaps");
        std::fs::create_dir_all(&submaps).unwrap();
        std::fs::write(submaps.join("00000000.subm"), [0u8; 300]).unwrap();
        std::fs::write(submaps.join("00000001.subm"), [0u8; 200]).unwrap();
        std::fs::write(submaps.join("notes.txt"), [0u8; 1000]).unwrap();
        let class = |packets, wire_bytes, retransmissions| ClassTraffic {
            packets,
            packet_bytes: wire_bytes,
            wire_bytes,
            retransmissions,
        };
        let mut stats = CommsStats::default();
        stats.sent_by_class.insert("SubmapChunk", class(10, 11_000, 2));
        stats.sent_by_class.insert("SubmapHeader", class(2, 200, 0));
        stats.sent_by_class.insert("PoseEstimate", class(50, 5_000, 0));
        stats.ground_sent_by_class.insert("SubmapChunk", class(4, 4_400, 1));
        stats.ground_sent_by_class.insert("SubmapHeader", class(1, 100, 0));
        let t = submap_traffic(&stats, 2, &dir).unwrap();
        assert_eq!(t.submaps, 2);
        assert_eq!(t.payload_bytes, 500);
        assert_eq!(t.ground, LinkTraffic { packets: 5, wire_bytes: 4_500, retransmissions: 1 });
        assert_eq!(t.team, LinkTraffic { packets: 7, wire_bytes: 6_700, retransmissions: 1 });
        assert!((t.wire_bytes_per_s(2.0) - 5_600.0).abs() < 1e-9);
        std::fs::remove_dir_all(&dir).ok();
    }
}
