//! The bus after crashes (SIGKILL of a process that publishes or is creating its services) and
//! under a filter stall: stale resources are removed and reported, the same topics work again,
//! and no IMU sample is lost within the documented stall.
//!
//! The test binary re-executes itself as the crashing process (env var `ONBOARD_BR_ROLE`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::Duration;

use msgs::{
    DisparityHeader, DisparityPixel, FilterStateMsg, FrameSwitchMsg, FrameSwitchRequestMsg, HAZARD_CELLS_MAX,
    HazardCellsMsg, HeadCommandMsg, ImuMsg, MarkerMsg, Pose, StereoHeader, TaskStatsMsg, TeamHeader, VoDeltaMsg,
    WheelOdomMsg,
};
use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use onboard::bus::{Bus, ImageGeometry, purge_robot, qos};
use onboard::nodes::{Message, Outbox, Topic};

const ROLE: &str = "ONBOARD_BR_ROLE";
const ROBOT: &str = "ONBOARD_BR_ROBOT";
const GEOMETRY: ImageGeometry = ImageGeometry { width_px: 64, height_px: 32 };
const READY: &str = "BUS_RECOVERY_READY";
/// The creator is about to create its services (the parent times its kill from this line).
const CREATING: &str = "BUS_RECOVERY_CREATING";

/// A robot id of its own per test and test run (tests run in parallel, robots are isolated).
fn robot(offset: u16) -> u16 {
    40_000 + (std::process::id() % 3_000) as u16 * 8 + offset
}

/// Removes the robot's iceoryx2 files when the test ends (declared first, so dropped last).
struct Purge(u16);

impl Drop for Purge {
    fn drop(&mut self) {
        let _ = purge_robot(self.0);
    }
}

fn imu(sequence: u64) -> ImuMsg {
    ImuMsg {
        stamp_ns: 1_000_000 + sequence * 5_000_000,
        sequence,
        gyro_radps: [0.01, -0.02, 0.03],
        accel_mps2: [0.1, 0.0, 9.81],
    }
}

/// The crashing process. `publisher`: open everything, then publish IMU forever. `creator`:
/// create and drop every service's ports forever, so a kill lands inside service creation.
#[test]
fn crash_child() {
    let Ok(robot) = std::env::var(ROBOT) else { return };
    let robot: u16 = robot.parse().unwrap();
    let role = std::env::var(ROLE).unwrap();
    let say = |line: &str| {
        println!("{line}");
        std::io::stdout().flush().unwrap();
    };
    match role.as_str() {
        "publisher" => {
            let bus = Bus::open(robot, "driver", GEOMETRY).unwrap();
            let mut outbox = bus.outbox(&Topic::ALL).unwrap();
            say(READY);
            for sequence in 0.. {
                outbox.publish(Message::Imu(&imu(sequence))).unwrap();
                std::thread::sleep(Duration::from_millis(1));
            }
        }
        "creator" => {
            say(READY);
            loop {
                let bus = Bus::open(robot, "driver", GEOMETRY).unwrap();
                say(CREATING);
                let outbox = bus.outbox(&Topic::ALL).unwrap();
                let inbox = bus.inbox(&Topic::ALL).unwrap();
                drop((inbox, outbox, bus));
            }
        }
        other => panic!("unknown role {other}"),
    }
}

struct KillOnDrop(Child);

impl Drop for KillOnDrop {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn spawn_child(role: &str, robot: u16) -> KillOnDrop {
    spawn_child_with_markers(role, robot).0
}

/// A child and, after its READY line, the arrivals of its later [`CREATING`] lines.
fn spawn_child_with_markers(role: &str, robot: u16) -> (KillOnDrop, mpsc::Receiver<()>) {
    let mut child = Command::new(std::env::current_exe().unwrap())
        .args(["--exact", "crash_child", "--nocapture", "--test-threads=1"])
        .env(ROLE, role)
        .env(ROBOT, robot.to_string())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let stdout = child.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel();
    let (marker_tx, markers) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if line.contains(READY) {
                let _ = tx.send(());
            } else if line.contains(CREATING) {
                let _ = marker_tx.send(());
            }
        }
    });
    let child = KillOnDrop(child);
    rx.recv_timeout(Duration::from_secs(30)).expect("child did not start");
    (child, markers)
}

fn sigkill(child: &mut KillOnDrop) {
    kill(Pid::from_raw(child.0.id() as i32), Signal::SIGKILL).unwrap();
    let status = child.0.wait().unwrap();
    assert!(!status.success());
}

fn pose() -> Pose {
    Pose { translation_m: [1.0, 2.0, 3.0], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] }
}

/// Publishes one message on every topic and checks the inbox receives exactly those.
fn every_topic_round_trip(outbox: &mut impl Outbox, inbox: &mut onboard::bus::BusInbox, stamp_ns: u64) {
    let pixels = (GEOMETRY.width_px * GEOMETRY.height_px) as usize;
    let stereo_bytes: Vec<u8> = (0..2 * pixels).map(|i| (i % 253) as u8).collect();
    let disparity = vec![DisparityPixel { disparity_q4: 17, labels: 1, reserved: 0 }; pixels];
    let stereo = StereoHeader {
        stamp_ns,
        sequence: 1,
        pan_rad: 0.0,
        tilt_rad: 0.0,
        width_px: GEOMETRY.width_px,
        height_px: GEOMETRY.height_px,
    };
    let disparity_header = DisparityHeader {
        stamp_ns,
        sequence: 1,
        pan_rad: 0.0,
        tilt_rad: 0.0,
        width_px: GEOMETRY.width_px,
        height_px: GEOMETRY.height_px,
    };
    let wheel = WheelOdomMsg { stamp_ns, sequence: 1, linear_mps: [0.1; 3], angular_radps: [0.0; 3], sigma: [0.01; 6] };
    let vo = VoDeltaMsg {
        capture_stamp_ns: stamp_ns,
        keyframe_stamp_ns: 0,
        t_keyframe_current_body: pose(),
        covariance_body: [0.0; 36],
        t_odom_body: Pose::IDENTITY,
        inliers: 40,
        flags: VoDeltaMsg::HAS_DELTA,
    };
    let marker = MarkerMsg {
        capture_stamp_ns: stamp_ns,
        t_body_cam: Pose::IDENTITY,
        t_cam_marker: pose(),
        covariance_cam: [0.0; 36],
        corners_px: [[10.0, 10.0], [20.0, 10.0], [20.0, 20.0], [10.0, 20.0]],
        tag_id: 3,
        hamming: 0,
        decision_margin: 80.0,
        ambiguity_ratio: 4.0,
        distance_m: 3.0,
        tilt_rad: 0.2,
        camera: MarkerMsg::LEFT,
        model: 0,
    };
    let state = FilterStateMsg {
        stamp_ns,
        t_local_body: pose(),
        v_local_mps: [0.0; 3],
        accel_bias_mps2: [0.0; 3],
        gyro_bias_radps: [0.0; 3],
        pose_covariance: [0.0; 36],
        imu_received: 1,
        imu_lost: 0,
        frame_id: 0,
        status: FilterStateMsg::RUNNING,
        last_vo_capture_ns: FilterStateMsg::NEVER,
    };
    let request = FrameSwitchRequestMsg { stamp_ns, frame_id: 0, reserved: 0 };
    let switch =
        FrameSwitchMsg { stamp_ns, t_old_new: pose(), covariance: [0.0; 36], old_frame_id: 0, new_frame_id: 1 };
    let team = TeamHeader { stamp_ns, robot_id: 2, message_key: 9 };
    let stats = TaskStatsMsg {
        stamp_ns,
        period_ns: 5_000_000,
        deadline_ns: 5_000_000,
        releases: 1,
        overruns: 0,
        skipped: 0,
        jitter_p50_ns: 0,
        jitter_p99_ns: 0,
        jitter_max_ns: 0,
        execution_max_ns: 0,
        process_cpu_ns: 0,
        process_rss_bytes: 0,
        process: 2,
        task: 0,
        queue_topic: 0,
        queue_depth_max: 0,
        queue_capacity: 0,
        devices: 0,
    };
    let imu = ImuMsg { stamp_ns, ..imu(0) };
    let head = HeadCommandMsg {
        stamp_ns,
        sequence: 3,
        pan_rad: 0.1,
        tilt_rad: 0.55,
        max_rate_radps: 0.8,
        mode: 1,
        reserved: 0,
    };
    let mut cells = [[0i16; 2]; HAZARD_CELLS_MAX];
    cells[0] = [12, -3];
    let hazards = HazardCellsMsg {
        stamp_ns,
        t_local_body: pose(),
        frame_id: 0,
        cell_size_m: 0.05,
        origin_cell: [4, 5],
        count: 1,
        omitted: 0,
        cells,
    };
    let messages = [
        Message::Imu(&imu),
        Message::WheelOdom(&wheel),
        Message::Stereo(&stereo, &stereo_bytes),
        Message::Disparity(&disparity_header, &disparity),
        Message::VoDelta(&vo),
        Message::Marker(&marker),
        Message::FilterState(&state),
        Message::FrameSwitchRequest(&request),
        Message::FrameSwitch(&switch),
        Message::ToComms(&team, b"to comms"),
        Message::ToMapper(&team, b"to mapper"),
        Message::TaskStats(&stats),
        Message::HeadCommand(&head),
        Message::Hazards(&hazards),
    ];
    for message in messages {
        outbox.publish(message).unwrap();
    }
    assert!(inbox.wait(Duration::from_secs(5)).unwrap());
    let mut seen = Vec::new();
    inbox
        .drain(&mut |message| {
            // A new subscriber first gets the IMU topic's history (earlier rounds' samples).
            if matches!(message, Message::Imu(m) if m.stamp_ns < stamp_ns) {
                return Ok(());
            }
            assert_eq!(message.stamp_ns(), stamp_ns);
            match message {
                Message::Stereo(_, bytes) => assert_eq!(bytes, &stereo_bytes[..]),
                Message::Disparity(_, pixels) => assert_eq!(pixels, &disparity[..]),
                Message::ToComms(h, bytes) => assert_eq!((*h, bytes), (team, &b"to comms"[..])),
                Message::ToMapper(h, bytes) => assert_eq!((*h, bytes), (team, &b"to mapper"[..])),
                Message::FilterState(m) => assert_eq!(*m, state),
                Message::HeadCommand(m) => assert_eq!(*m, head),
                Message::Hazards(m) => assert_eq!(*m, hazards),
                _ => {}
            }
            seen.push(message.topic());
            Ok(())
        })
        .unwrap();
    seen.sort();
    assert_eq!(seen, Topic::ALL.to_vec());
}

#[test]
fn killed_publisher_is_cleaned_up_and_the_same_topics_work_again() {
    let robot = robot(0);
    let _purge = Purge(robot);
    let filter_bus = Bus::open(robot, "filter", GEOMETRY).unwrap();
    let mut inbox = filter_bus.inbox(&Topic::ALL).unwrap();

    let mut child = spawn_child("publisher", robot);
    let child_pid = child.0.id() as i32;
    // The child's samples reach us before it dies.
    assert!(inbox.wait(Duration::from_secs(10)).unwrap());
    let mut before = 0;
    inbox
        .drain(&mut |m| {
            assert_eq!(m.topic(), Topic::Imu);
            before += 1;
            Ok(())
        })
        .unwrap();
    assert!(before > 0);
    sigkill(&mut child);

    let driver_bus = Bus::open(robot, "driver", GEOMETRY).unwrap();
    let cleanup = driver_bus.stale_cleanup();
    eprintln!("after SIGKILL of pid {child_pid}: {cleanup}");
    assert_eq!(cleanup.removed.len(), 1, "{cleanup:?}");
    assert_eq!(cleanup.removed[0].name, format!("rover{robot}-driver"));
    assert_eq!(cleanup.removed[0].pid, child_pid);
    assert!(cleanup.failed.is_empty(), "{cleanup:?}");
    assert!(cleanup.shm_files_removed > 0, "the dead publishers' data segments stay: {cleanup:?}");

    // A fresh publisher set on every topic reaches both the surviving and a new subscriber.
    let mut outbox = driver_bus.outbox(&Topic::ALL).unwrap();
    inbox.drain(&mut |_| Ok(())).unwrap();
    every_topic_round_trip(&mut outbox, &mut inbox, 77);
    let mapper_bus = Bus::open(robot, "mapper", GEOMETRY).unwrap();
    assert!(mapper_bus.stale_cleanup().is_empty());
    let mut fresh_inbox = mapper_bus.inbox(&Topic::ALL).unwrap();
    every_topic_round_trip(&mut outbox, &mut fresh_inbox, 78);
    assert_eq!(inbox.drain(&mut |_| Ok(())).unwrap(), Topic::ALL.len(), "the surviving subscriber got round 78 too");
    for topic in Topic::ALL {
        assert_eq!(outbox.counters(topic).discarded, 0);
        assert_eq!(outbox.counters(topic).failed, 0);
    }
}

#[test]
fn kill_during_service_creation_leaves_a_working_bus() {
    let robot = robot(1);
    let _purge = Purge(robot);
    // Kill points spread over the child's service creation: timed from the line it prints
    // just before creating its ports (a fixed delay from start-up missed the creation window
    // on a loaded machine). Rounds go on until the kills have hit both a live node and a
    // half-created service (each costs iceoryx2's 1 s creation timeout), within a bound.
    let delays_us = [0u64, 150, 400, 800, 1_300, 2_000, 3_000, 4_500];
    let (mut rounds, mut removed_total, mut hung_repaired) = (0, 0, 0);
    while rounds < 8 || (rounds < 32 && (removed_total < 4 || hung_repaired == 0)) {
        let delay_us = delays_us[rounds % delays_us.len()] + rounds as u64 * 53;
        let (mut child, markers) = spawn_child_with_markers("creator", robot);
        // Some rounds let a few create/drop cycles pass first (services then exist or not).
        for _ in 0..=rounds % 3 {
            markers.recv_timeout(Duration::from_secs(30)).expect("the creator never started creating");
        }
        std::thread::sleep(Duration::from_micros(delay_us));
        sigkill(&mut child);

        let bus = Bus::open(robot, "driver", GEOMETRY).unwrap();
        let cleanup = bus.stale_cleanup().clone();
        assert!(cleanup.failed.is_empty(), "{cleanup:?}");
        assert!(cleanup.removed.len() <= 1, "{cleanup:?}");
        removed_total += cleanup.removed.len();
        let mut outbox = bus.outbox(&Topic::ALL).unwrap();
        let mut inbox = bus.inbox(&Topic::ALL).unwrap();
        hung_repaired += bus.hung_services_repaired() + cleanup.hung_services_removed;
        eprintln!(
            "kill after {delay_us} µs: {cleanup}; {} hung service(s) repaired on open",
            bus.hung_services_repaired()
        );
        every_topic_round_trip(&mut outbox, &mut inbox, 1_000 + rounds as u64);
        rounds += 1;
    }
    eprintln!("{rounds} kills: {removed_total} dead nodes cleaned, {hung_repaired} hung services repaired");
    assert!(removed_total >= 4, "only {removed_total} dead nodes in {rounds} kills");
    assert!(hung_repaired >= 1, "no kill landed inside service creation in {rounds} kills");
}

#[test]
fn imu_burst_during_a_one_second_filter_stall_loses_nothing() {
    let robot = robot(2);
    let _purge = Purge(robot);
    let driver = Bus::open(robot, "driver", GEOMETRY).unwrap();
    let filter = Bus::open(robot, "filter", GEOMETRY).unwrap();
    let mut inbox = filter.inbox(&[Topic::Imu, Topic::VoDelta]).unwrap();
    let mut imu_out = driver.outbox(&[Topic::Imu]).unwrap();
    let vision = Bus::open(robot, "vision", GEOMETRY).unwrap();
    let mut vo_out = vision.outbox(&[Topic::VoDelta]).unwrap();

    // 1 s at 200 Hz, and the VO deltas of the same second (published late, as vision is).
    for sequence in 0..200 {
        imu_out.publish(Message::Imu(&imu(sequence))).unwrap();
    }
    for frame in 0..10u64 {
        let vo = VoDeltaMsg {
            capture_stamp_ns: imu(frame * 20 + 3).stamp_ns + 1,
            keyframe_stamp_ns: 0,
            t_keyframe_current_body: pose(),
            covariance_body: [0.0; 36],
            t_odom_body: Pose::IDENTITY,
            inliers: 10,
            flags: VoDeltaMsg::HAS_DELTA,
        };
        vo_out.publish(Message::VoDelta(&vo)).unwrap();
    }

    let mut imu_sequences = Vec::new();
    let mut stamps = Vec::new();
    let handed = inbox
        .drain(&mut |message| {
            stamps.push(message.stamp_ns());
            if let Message::Imu(m) = message {
                imu_sequences.push(m.sequence);
            }
            Ok(())
        })
        .unwrap();
    assert_eq!(handed, 210);
    assert_eq!(imu_sequences, (0..200).collect::<Vec<_>>());
    assert!(stamps.windows(2).all(|w| w[0] <= w[1]), "not merged by stamp");
    assert_eq!(inbox.counters(Topic::Imu).received, 200);
    assert_eq!(inbox.counters(Topic::Imu).sequence_gaps, 0);
    assert_eq!(imu_out.counters(Topic::Imu).discarded, 0);
    assert_eq!(imu_out.counters(Topic::Imu).deliveries, 200);
}

#[test]
fn imu_beyond_the_buffer_is_discarded_newest_first_and_counted() {
    let robot = robot(3);
    let _purge = Purge(robot);
    let driver = Bus::open(robot, "driver", GEOMETRY).unwrap();
    let filter = Bus::open(robot, "filter", GEOMETRY).unwrap();
    let mut inbox = filter.inbox(&[Topic::Imu]).unwrap();
    let mut outbox = driver.outbox(&[Topic::Imu]).unwrap();
    // The filter has drained before its stall: only a subscriber that has attached to the
    // connection makes the publisher see (and count) a full buffer.
    assert_eq!(inbox.drain(&mut |_| Ok(())).unwrap(), 0);
    let buffer = qos(Topic::Imu).subscriber_buffer as u64;

    for sequence in 0..buffer + 44 {
        outbox.publish(Message::Imu(&imu(sequence))).unwrap();
    }
    assert_eq!(outbox.counters(Topic::Imu).discarded, 44);
    let mut sequences = Vec::new();
    inbox
        .drain(&mut |message| {
            if let Message::Imu(m) = message {
                sequences.push(m.sequence);
            }
            Ok(())
        })
        .unwrap();
    assert_eq!(sequences, (0..buffer).collect::<Vec<_>>());
    // The next sample after the stall shows the loss to the filter as a gap.
    outbox.publish(Message::Imu(&imu(buffer + 44))).unwrap();
    inbox.drain(&mut |_| Ok(())).unwrap();
    assert_eq!(inbox.counters(Topic::Imu).sequence_gaps, 44);
}

#[test]
fn publishing_a_topic_without_publisher_is_an_error() {
    let _purge = Purge(robot(4));
    let bus = Bus::open(robot(4), "vision", GEOMETRY).unwrap();
    let mut outbox = bus.outbox(&[Topic::Disparity]).unwrap();
    let err = outbox.publish(Message::Imu(&imu(0))).unwrap_err();
    assert!(matches!(err, onboard::nodes::NodeError::Publish { topic: Topic::Imu, .. }), "{err}");
    // A slice that does not fit its header is refused before anything is loaned.
    let header = DisparityHeader { width_px: 64, height_px: 32, ..Default::default() };
    let short = vec![DisparityPixel { disparity_q4: 0, labels: 0, reserved: 0 }; 10];
    assert!(outbox.publish(Message::Disparity(&header, &short)).is_err());
    assert_eq!(outbox.counters(Topic::Disparity).failed, 1);
}
