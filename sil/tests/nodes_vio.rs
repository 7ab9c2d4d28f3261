#![allow(clippy::unwrap_used, clippy::expect_used)]
//! The driver, vision and filter nodes wired by a tiny in-test router (not the lockstep runner's
//! bus: another legitimate delivery order) on a simulated Moon rover, with a fake mapper that asks
//! for frame switches: accuracy against the simulator's truth, dense disparity and labels; plus
//! the nodes' handling of late and bad messages.

use std::collections::VecDeque;
use std::sync::{Arc, OnceLock};

use hal::sensor::{SensorSource, StereoCalibration};
use msgs::{
    DisparityPixel, FilterStateMsg, FrameSwitchRequestMsg, ImuMsg, Pose, StereoHeader, VoDeltaMsg, WheelOdomMsg,
};
use nalgebra::Isometry3;
use onboard::nodes::driver::{DriverNode, DriverOptions};
use onboard::nodes::filter::{FilterNode, FilterNodeOptions};
use onboard::nodes::vision::{VisionNode, VisionNodeOptions};
use onboard::nodes::{Message, Node, NodeError, Outbox, Topic};
use onboard::record::OwnedMessage;
use onboard::sensors::sensor_setup;
use onboard::stack;
use onboard::vio::VioOptions;
use sil::team_record::{TeamRecordOptions, moon_team_world};
use sim::driver::SimSensorSource;
use sim::world::World;
use vision::obstacles::PixelLabels;

/// The fake mapper's rule: a new frame this far from the current origin (the mapper's 7 m would not
/// be reached: the rover drives about 8 m in the 40 s, with turns).
const SWITCH_DISTANCE_M: f64 = 2.5;
const TICK_NS: u64 = 5_000_000;

fn team() -> TeamRecordOptions {
    TeamRecordOptions { robots: 2, duration_s: 40.0, downscale: 4, pause_s: Some(1.0), ..Default::default() }
}

fn world() -> &'static Arc<World> {
    static WORLD: OnceLock<Arc<World>> = OnceLock::new();
    WORLD.get_or_init(|| moon_team_world(&team()).unwrap())
}

/// Robot 0's node options, from its firmware configuration as a mission builds it.
fn options(world: &World) -> (VioOptions, VisionNodeOptions) {
    let config = team().robot_config(world, 0).unwrap();
    let setup = sensor_setup(&config).unwrap();
    let mut vision = stack::vision_options(&config, &setup);
    // A quarter-resolution camera sees a quarter of the full-resolution disparity range.
    vision.sgm.disparities = 32;
    (stack::vio_options(&config, &setup), vision)
}

/// The router's queue: every message in publish order.
#[derive(Debug, Default)]
struct Queue(VecDeque<OwnedMessage>);

impl Outbox for Queue {
    fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError> {
        self.0.push_back(OwnedMessage::from_message(&message));
        Ok(())
    }
}

/// Collects everything published (unit tests).
#[derive(Debug, Default)]
struct Sink(Vec<OwnedMessage>);

impl Outbox for Sink {
    fn publish(&mut self, message: Message<'_>) -> Result<(), NodeError> {
        self.0.push(OwnedMessage::from_message(&message));
        Ok(())
    }
}

/// What the test observes on the bus, and the fake mapper.
#[derive(Debug, Default)]
struct Observer {
    /// Chained filter poses (first frame) per running state.
    stamps_ns: Vec<u64>,
    poses: Vec<Isometry3<f64>>,
    frame_id: u32,
    t_first_local: Isometry3<f64>,
    requested_frame: Option<u32>,
    switches: u64,
    last_state: Option<FilterStateMsg>,
    disparity_maps: u64,
    /// Lower half of the image (the ground in front of the rover): valid pixels and all pixels.
    ground_valid: u64,
    ground_pixels: u64,
    obstacle_pixels: u64,
    labelled_maps: u64,
    vo_deltas: u64,
    switch_distance_m: Option<f64>,
}

impl Observer {
    fn observe(&mut self, message: &OwnedMessage, out: &mut Queue) {
        match message {
            OwnedMessage::FilterState(state) => {
                self.last_state = Some(*state);
                if state.status != FilterStateMsg::RUNNING {
                    return;
                }
                assert_eq!(state.frame_id, self.frame_id, "a state in another frame than the chain's");
                let t_local_body = state.t_local_body.to_isometry().unwrap();
                let pose = self.t_first_local * t_local_body;
                if self.stamps_ns.last() == Some(&state.stamp_ns) {
                    *self.poses.last_mut().unwrap() = pose;
                } else {
                    self.stamps_ns.push(state.stamp_ns);
                    self.poses.push(pose);
                }
                if self.switch_distance_m.is_some_and(|d| t_local_body.translation.vector.norm() >= d)
                    && self.requested_frame != Some(state.frame_id)
                {
                    self.requested_frame = Some(state.frame_id);
                    let request =
                        FrameSwitchRequestMsg { stamp_ns: state.stamp_ns, frame_id: state.frame_id, reserved: 0 };
                    out.publish(Message::FrameSwitchRequest(&request)).unwrap();
                }
            }
            OwnedMessage::FrameSwitch(switch) => {
                assert_eq!(switch.old_frame_id, self.frame_id);
                self.t_first_local *= switch.t_old_new.to_isometry().unwrap();
                self.frame_id = switch.new_frame_id;
                self.switches += 1;
            }
            OwnedMessage::Disparity(header, pixels) => {
                let (w, h) = (header.width_px as usize, header.height_px as usize);
                assert_eq!(pixels.len(), w * h);
                self.disparity_maps += 1;
                for pixel in &pixels[w * (h / 2)..] {
                    self.ground_pixels += 1;
                    self.ground_valid += u64::from(pixel.disparity_q4 != DisparityPixel::INVALID);
                }
                let obstacles = pixels.iter().filter(|p| p.labels & PixelLabels::OBSTACLE != 0).count() as u64;
                self.obstacle_pixels += obstacles;
                self.labelled_maps += u64::from(pixels.iter().any(|p| p.labels != 0));
            }
            OwnedMessage::VoDelta(_) => self.vo_deltas += 1,
            _ => {}
        }
    }
}

fn subscribed(node: &dyn Node, topic: Topic) -> bool {
    node.subscriptions().contains(&topic)
}

/// Delivers the queue until it is empty: each message to the nodes subscribed to its topic (vision,
/// then the filter) and to the observer.
fn drain(queue: &mut Queue, vision: &mut VisionNode, filter: &mut FilterNode, observer: &mut Observer) {
    while let Some(message) = queue.0.pop_front() {
        let topic = message.as_message().topic();
        if subscribed(vision, topic) {
            vision.on_message(message.as_message(), queue).unwrap();
        }
        if subscribed(filter, topic) {
            filter.on_message(message.as_message(), queue).unwrap();
        }
        observer.observe(&message, queue);
    }
}

struct NodesRun {
    driver: DriverNode,
    vision: VisionNode,
    filter: FilterNode,
    observer: Observer,
}

fn run_nodes(world: &Arc<World>, robot: usize, vio: &VioOptions, vision_options: VisionNodeOptions) -> NodesRun {
    let driver_options = DriverOptions { end_stamp_ns: vio.end_stamp_ns };
    let source = SimSensorSource::new(Arc::clone(world), robot).unwrap();
    let mut driver = DriverNode::new(Box::new(source), driver_options);
    let calibration = driver.stereo_calibration().unwrap();
    let mut vision = VisionNode::new(&calibration, vision_options).unwrap();
    let mut filter = FilterNode::new(FilterNodeOptions::from_vio(vio));
    // The driver hears only head commands, and nothing here sends any (no gaze policy).
    assert_eq!(driver.subscriptions(), &[Topic::HeadCommand]);
    let mut observer = Observer { switch_distance_m: Some(SWITCH_DISTANCE_M), ..Observer::default() };
    let mut queue = Queue::default();
    let mut now_ns = 0;
    while !driver.finished() {
        driver.on_tick(now_ns, &mut queue).unwrap();
        drain(&mut queue, &mut vision, &mut filter, &mut observer);
        vision.on_tick(now_ns, &mut queue).unwrap();
        filter.on_tick(now_ns, &mut queue).unwrap();
        drain(&mut queue, &mut vision, &mut filter, &mut observer);
        now_ns += TICK_NS;
    }
    vision.flush(&mut queue).unwrap();
    drain(&mut queue, &mut vision, &mut filter, &mut observer);
    assert!(filter.flush().is_some());
    NodesRun { driver, vision, filter, observer }
}

/// `t_world_body` of robot 0 at `stamp_ns`.
fn truth(stamp_ns: u64) -> Isometry3<f64> {
    world().robot_state(0, stamp_ns).unwrap().t_world_body
}

/// Final position error (m) with the estimate anchored at the true pose of its first stamp.
fn final_error_m(stamps_ns: &[u64], poses: &[Isometry3<f64>]) -> f64 {
    let t_world_first = truth(stamps_ns[0]) * poses[0].inverse();
    let last = stamps_ns.len() - 1;
    ((t_world_first * poses[last]).translation.vector - truth(stamps_ns[last]).translation.vector).norm()
}

#[test]
fn the_nodes_track_a_simulated_rover_and_map_its_ground() {
    let world = world();
    let (vio, vision_options) = options(world);
    let nodes = run_nodes(world, 0, &vio, vision_options);
    let NodesRun { driver, vision, filter, observer } = &nodes;
    let filter_summary = filter.summary();
    let vision_summary = vision.summary();
    eprintln!("driver {:?}", driver.counts());
    eprintln!("filter {filter_summary:?}");
    eprintln!("vision {vision_summary:?}");

    // Initialization and no lost IMU sample.
    assert!(filter_summary.initialized_ns.is_some());
    let last = observer.last_state.unwrap();
    assert_eq!(last.imu_lost, 0);
    assert_eq!(last.imu_received, driver.counts().imu);
    assert_eq!(filter_summary.imu_received, driver.counts().imu);
    assert_eq!(vision_summary.vo_frames, vision_summary.frames - vision_summary.frames_before_init);
    assert!(filter_summary.vo_updates_applied as f64 > 0.8 * vision_summary.vo_frames as f64, "{filter_summary:?}");
    assert!(filter_summary.wheel_updates_applied > 0);
    // In this router the capture's filter state always arrives (right after the image).
    assert_eq!(vision_summary.prior_state_missing, 0);
    assert_eq!(vision_summary.prior_keyframe_missing, 0);
    assert_eq!(observer.vo_deltas, vision_summary.vo_frames);

    let captures: Vec<u64> = (0..driver.counts().stereo).map(|k| k * 100_000_000).collect();
    let distance_m: f64 =
        captures.windows(2).map(|w| (truth(w[1]).translation.vector - truth(w[0]).translation.vector).norm()).sum();
    let error_m = final_error_m(&observer.stamps_ns, &observer.poses);
    eprintln!(
        "{distance_m:.2} m driven, {} switches; final error {error_m:.3} m ({:.2} %)",
        observer.switches,
        100.0 * error_m / distance_m
    );
    assert!(observer.switches >= 2, "the run must switch frames");
    assert_eq!(filter_summary.frame_switches, observer.switches);
    // vio_sim's class: issue 7's 1 % over 150 m, 2 % over a short run.
    assert!(error_m < 0.02 * distance_m, "{error_m} m after {distance_m} m");

    // Dense disparity over the ground, and obstacle labels.
    assert_eq!(observer.disparity_maps, driver.counts().stereo);
    let ground_valid = observer.ground_valid as f64 / observer.ground_pixels as f64;
    eprintln!(
        "disparity: {:.1} % of the lower half valid; {} of {} maps with labels, {} obstacle pixels",
        100.0 * ground_valid,
        observer.labelled_maps,
        observer.disparity_maps,
        observer.obstacle_pixels
    );
    assert!(ground_valid > 0.7, "{ground_valid}");
    assert!(observer.labelled_maps as f64 > 0.8 * observer.disparity_maps as f64);
}

/// IMU samples at rest (`+g` up) from `from_ns` while `< to_ns`, with consecutive sequence numbers.
fn feed_rest(filter: &mut FilterNode, sequence: &mut u64, from_ns: u64, to_ns: u64, out: &mut Sink) {
    let gravity = filter.filter().config().gravity_mps2;
    let mut stamp = from_ns;
    while stamp < to_ns {
        let imu =
            ImuMsg { stamp_ns: stamp, sequence: *sequence, gyro_radps: [0.0; 3], accel_mps2: [0.0, 0.0, gravity] };
        filter.on_message(Message::Imu(&imu), out).unwrap();
        *sequence += 1;
        stamp += TICK_NS;
    }
}

fn stereo_header(stamp_ns: u64, sequence: u64, width_px: u32, height_px: u32) -> StereoHeader {
    StereoHeader { stamp_ns, sequence, pan_rad: 0.0, tilt_rad: 0.0, width_px, height_px }
}

#[test]
fn a_late_vo_delta_is_applied_on_arrival() {
    let mut filter = FilterNode::new(FilterNodeOptions::from_vio(&VioOptions::default()));
    let mut out = Sink::default();
    let mut sequence = 0;
    feed_rest(&mut filter, &mut sequence, 0, 600_000_000, &mut out);
    assert!(filter.summary().initialized_ns.is_some());
    let (first_ns, second_ns) = (600_000_000, 700_000_000);
    for capture in [first_ns, second_ns] {
        feed_rest(&mut filter, &mut sequence, capture, capture + TICK_NS, &mut out);
        filter.on_message(Message::Stereo(&stereo_header(capture, 0, 1, 1), &[0, 0]), &mut out).unwrap();
    }
    // The IMU stream runs past both due times (capture + 250 ms) before the results arrive.
    feed_rest(&mut filter, &mut sequence, second_ns + TICK_NS, 1_000_000_000, &mut out);
    let keyframe = VoDeltaMsg {
        capture_stamp_ns: first_ns,
        keyframe_stamp_ns: 0,
        t_keyframe_current_body: Pose::IDENTITY,
        covariance_body: [0.0; 36],
        t_odom_body: Pose::IDENTITY,
        inliers: 0,
        flags: VoDeltaMsg::NEW_KEYFRAME,
    };
    filter.on_message(Message::VoDelta(&keyframe), &mut out).unwrap();
    let mut covariance = [0.0; 36];
    for i in 0..6 {
        covariance[i * 7] = 1e-6;
    }
    // The robot stood still: a zero delta with a tight covariance passes the gate.
    let delta = VoDeltaMsg {
        capture_stamp_ns: second_ns,
        keyframe_stamp_ns: first_ns,
        t_keyframe_current_body: Pose::IDENTITY,
        covariance_body: covariance,
        t_odom_body: Pose::IDENTITY,
        inliers: 80,
        flags: VoDeltaMsg::HAS_DELTA,
    };
    filter.on_message(Message::VoDelta(&delta), &mut out).unwrap();
    let summary = filter.summary();
    assert_eq!(summary.vo_late, 2, "{summary:?}");
    assert_eq!(summary.vo_updates_applied, 1, "{summary:?}");
    assert_eq!(summary.vo_updates_missing_clone + summary.vo_updates_rejected, 0, "{summary:?}");
    assert_eq!(summary.clones, 2);
    // One state per IMU sample, none lost.
    let states: Vec<_> =
        out.0.iter().filter_map(|m| if let OwnedMessage::FilterState(s) = m { Some(*s) } else { None }).collect();
    assert_eq!(states.len() as u64, sequence);
    assert_eq!(states.last().unwrap().imu_lost, 0);
}

#[test]
fn bad_payloads_are_counted_and_skipped() {
    let calibration: StereoCalibration =
        SimSensorSource::new(Arc::clone(world()), 0).unwrap().stereo_calibration().unwrap();
    let (w, h) = (calibration.left.width_px, calibration.left.height_px);
    let mut vision = VisionNode::new(&calibration, VisionNodeOptions::from_vio(&VioOptions::default())).unwrap();
    let mut out = Sink::default();
    let n = (w * h) as usize;
    let truncated = vec![0u8; 2 * n - 1];
    vision.on_message(Message::Stereo(&stereo_header(0, 0, w, h), &truncated), &mut out).unwrap();
    let full = vec![0u8; 2 * n];
    vision.on_message(Message::Stereo(&stereo_header(0, 0, w + 1, h), &full), &mut out).unwrap();
    let mut nan_state = FilterStateMsg {
        stamp_ns: 0,
        t_local_body: Pose::IDENTITY,
        v_local_mps: [0.0; 3],
        accel_bias_mps2: [0.0; 3],
        gyro_bias_radps: [0.0; 3],
        pose_covariance: [0.0; 36],
        imu_received: 0,
        imu_lost: 0,
        frame_id: 0,
        status: FilterStateMsg::RUNNING,
        last_vo_capture_ns: FilterStateMsg::NEVER,
    };
    nan_state.t_local_body.translation_m[0] = f64::NAN;
    vision.on_message(Message::FilterState(&nan_state), &mut out).unwrap();
    let summary = vision.summary();
    assert_eq!(summary.bad_stereo, 2);
    assert_eq!(summary.bad_filter_states, 1);
    assert_eq!(summary.frames, 0);
    assert!(out.0.is_empty());
    // A good pair still goes through afterwards (a disparity map; no odometry without a filter).
    vision.on_message(Message::Stereo(&stereo_header(0, 0, w, h), &full), &mut out).unwrap();
    vision.flush(&mut out).unwrap();
    assert!(matches!(out.0.as_slice(), [OwnedMessage::Disparity(..)]));
    assert_eq!(vision.summary().frames_before_init, 1);

    let mut filter = FilterNode::new(FilterNodeOptions::from_vio(&VioOptions::default()));
    let imu = ImuMsg { stamp_ns: 0, sequence: 0, gyro_radps: [f64::NAN, 0.0, 0.0], accel_mps2: [0.0; 3] };
    filter.on_message(Message::Imu(&imu), &mut out).unwrap();
    let wheel = WheelOdomMsg {
        stamp_ns: 0,
        sequence: 0,
        linear_mps: [f64::INFINITY; 3],
        angular_radps: [0.0; 3],
        sigma: [0.1; 6],
    };
    filter.on_message(Message::WheelOdom(&wheel), &mut out).unwrap();
    let summary = filter.summary();
    assert_eq!((summary.imu_received, summary.imu_rejected, summary.bad_messages), (1, 1, 1));
    // A repeated request for a frame that is not the current one is ignored.
    filter
        .on_message(
            Message::FrameSwitchRequest(&FrameSwitchRequestMsg { stamp_ns: 0, frame_id: 3, reserved: 0 }),
            &mut out,
        )
        .unwrap();
    assert_eq!(filter.summary().switch_requests_ignored, 1);
}
