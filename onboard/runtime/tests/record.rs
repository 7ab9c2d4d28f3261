//! Bus recordings: every message kind round-trips exactly, damaged logs end in an error or a
//! clean end (never a panic), replay publishes recorded outputs unchanged, and a deterministic
//! node re-run on its recorded inputs publishes what it published live.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use msgs::{
    DisparityHeader, DisparityPixel, FilterStateMsg, FrameSwitchMsg, FrameSwitchRequestMsg, HAZARD_CELLS_MAX,
    HazardCellsMsg, HeadCommandMsg, ImuMsg, MarkerMsg, Pose, StereoHeader, TaskStatsMsg, TeamHeader, VoDeltaMsg,
    WheelOdomMsg,
};
use onboard::nodes::{Message, Node, NodeError, Outbox, Topic};
use onboard::record::{
    CollectingOutbox, FILE_HEADER_BYTES, OwnedMessage, RecordError, RecordReader, RecordedMessage, Recorder,
    replay_into, rerun,
};
use proptest::prelude::*;

fn pose(seed: f64) -> Pose {
    Pose { translation_m: [seed, -seed, 0.5 * seed], rotation_wxyz: [0.5, 0.5, -0.5, 0.5] }
}

fn cov(seed: f64) -> [f64; 36] {
    std::array::from_fn(|i| seed + i as f64 * 1e-3)
}

/// One message of every topic, with distinctive values in every field.
fn one_of_each() -> Vec<OwnedMessage> {
    let (w, h) = (7u32, 3u32);
    vec![
        OwnedMessage::Imu(ImuMsg {
            stamp_ns: 1,
            sequence: 2,
            gyro_radps: [0.1, 0.2, 0.3],
            accel_mps2: [0.0, 0.1, 9.81],
        }),
        OwnedMessage::WheelOdom(WheelOdomMsg {
            stamp_ns: 3,
            sequence: 4,
            linear_mps: [0.2, 0.0, 0.0],
            angular_radps: [0.0, 0.0, 0.1],
            sigma: [0.01, 0.02, 0.03, 0.04, 0.05, 0.06],
        }),
        OwnedMessage::Stereo(
            StereoHeader { stamp_ns: 5, sequence: 6, pan_rad: 0.1, tilt_rad: -0.3, width_px: w, height_px: h },
            (0..2 * w * h).map(|i| (i * 7) as u8).collect(),
        ),
        OwnedMessage::Disparity(
            DisparityHeader { stamp_ns: 5, sequence: 6, pan_rad: 0.1, tilt_rad: -0.3, width_px: w, height_px: h },
            (0..w * h)
                .map(|i| DisparityPixel {
                    disparity_q4: if i % 5 == 0 { DisparityPixel::INVALID } else { i as u16 * 16 },
                    labels: i as u8 % 4,
                    reserved: 0,
                })
                .collect(),
        ),
        OwnedMessage::VoDelta(VoDeltaMsg {
            capture_stamp_ns: 7,
            keyframe_stamp_ns: 2,
            t_keyframe_current_body: pose(1.5),
            covariance_body: cov(0.1),
            t_odom_body: Pose::IDENTITY,
            inliers: 123,
            flags: VoDeltaMsg::HAS_DELTA | VoDeltaMsg::NEW_KEYFRAME,
        }),
        OwnedMessage::Marker(MarkerMsg {
            capture_stamp_ns: 8,
            t_body_cam: pose(0.5),
            t_cam_marker: pose(2.5),
            covariance_cam: cov(0.2),
            corners_px: [[1.5, 2.5], [30.0, 2.0], [31.0, 29.5], [2.0, 30.0]],
            tag_id: 3,
            hamming: 1,
            decision_margin: 55.5,
            ambiguity_ratio: 2.5,
            distance_m: 4.25,
            tilt_rad: -0.5,
            camera: MarkerMsg::RIGHT,
            model: 2,
        }),
        OwnedMessage::FilterState(FilterStateMsg {
            stamp_ns: 9,
            t_local_body: pose(3.5),
            v_local_mps: [0.1, 0.2, 0.3],
            accel_bias_mps2: [1e-3, 2e-3, 3e-3],
            gyro_bias_radps: [1e-5, 2e-5, 3e-5],
            pose_covariance: cov(0.3),
            imu_received: 1000,
            imu_lost: 1,
            frame_id: 4,
            status: FilterStateMsg::RUNNING,
            last_vo_capture_ns: FilterStateMsg::NEVER,
        }),
        OwnedMessage::FrameSwitchRequest(FrameSwitchRequestMsg { stamp_ns: 10, frame_id: 4, reserved: 0 }),
        OwnedMessage::FrameSwitch(FrameSwitchMsg {
            stamp_ns: 11,
            t_old_new: pose(4.5),
            covariance: cov(0.4),
            old_frame_id: 4,
            new_frame_id: 5,
        }),
        OwnedMessage::ToComms(
            TeamHeader { stamp_ns: 12, robot_id: TeamHeader::BROADCAST, message_key: 9 },
            b"submap bytes".to_vec(),
        ),
        OwnedMessage::ToMapper(TeamHeader { stamp_ns: 13, robot_id: 2, message_key: 10 }, Vec::new()),
        OwnedMessage::TaskStats(TaskStatsMsg {
            stamp_ns: 14,
            period_ns: 5_000_000,
            deadline_ns: 2_500_000,
            releases: 100,
            overruns: 1,
            skipped: 2,
            jitter_p50_ns: 30_000,
            jitter_p99_ns: 90_000,
            jitter_max_ns: 200_000,
            execution_max_ns: 1_000_000,
            process_cpu_ns: 123_456_789,
            process_rss_bytes: 10 << 20,
            process: msgs::ProcessKind::Filter as u32,
            task: 0,
            queue_topic: 0,
            queue_depth_max: 0,
            queue_capacity: 0,
            devices: 0,
        }),
        OwnedMessage::HeadCommand(HeadCommandMsg {
            stamp_ns: 15,
            sequence: 4,
            pan_rad: -0.5,
            tilt_rad: 0.55,
            max_rate_radps: 0.8,
            mode: HeadCommandMsg::SWEEP,
            reserved: 0,
        }),
        OwnedMessage::Hazards(Box::new(HazardCellsMsg {
            stamp_ns: 16,
            t_local_body: Pose { translation_m: [1.0, 2.0, 0.3], rotation_wxyz: [1.0, 0.0, 0.0, 0.0] },
            frame_id: 2,
            cell_size_m: 0.05,
            origin_cell: [20, -40],
            count: 2,
            omitted: 7,
            cells: {
                let mut cells = [[0i16; 2]; HAZARD_CELLS_MAX];
                cells[0] = [3, 4];
                cells[1] = [-5, 6];
                cells
            },
        })),
    ]
}

fn log_of(records: &[RecordedMessage]) -> Vec<u8> {
    let mut recorder = Recorder::new(Vec::new()).unwrap();
    for r in records {
        recorder.append_recorded(r).unwrap();
    }
    assert_eq!(recorder.records(), records.len() as u64);
    let bytes = recorder.bytes();
    let log = recorder.into_inner().unwrap();
    assert_eq!(bytes, log.len() as u64);
    log
}

fn read_all(bytes: &[u8]) -> (Vec<RecordedMessage>, Option<RecordError>) {
    let mut records = Vec::new();
    let mut reader = match RecordReader::new(bytes) {
        Ok(r) => r,
        Err(e) => return (records, Some(e)),
    };
    loop {
        match reader.next_record() {
            Ok(Some(r)) => records.push(r),
            Ok(None) => return (records, None),
            Err(e) => {
                // An error ends the log for good.
                assert!(matches!(reader.next_record(), Ok(None)));
                return (records, Some(e));
            }
        }
    }
}

fn sample_log() -> (Vec<RecordedMessage>, Vec<u8>) {
    let records: Vec<RecordedMessage> = one_of_each()
        .into_iter()
        .enumerate()
        .map(|(i, owned)| RecordedMessage { recv_stamp_ns: 1_000 + i as u64, owned })
        .collect();
    let log = log_of(&records);
    (records, log)
}

#[test]
fn every_message_kind_round_trips_exactly() {
    let (records, log) = sample_log();
    let topics: Vec<Topic> = records.iter().map(RecordedMessage::topic).collect();
    assert_eq!(topics, Topic::ALL, "the sample covers every topic");
    let (read, error) = read_all(&log);
    assert!(error.is_none(), "{error:?}");
    assert_eq!(read, records);
    // Borrowed views see the same bytes, from aligned owned storage.
    for (a, b) in read.iter().zip(&records) {
        assert_eq!(a.message().topic(), b.message().topic());
        assert_eq!(a.message().stamp_ns(), b.message().stamp_ns());
        assert_eq!(OwnedMessage::from_message(&a.message()), b.owned);
    }
}

#[test]
fn a_file_recording_reads_back() {
    let (records, _) = sample_log();
    let dir = std::env::temp_dir().join(format!("onboard-record-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bus.log");
    let mut recorder = Recorder::create(&path).unwrap();
    for r in &records {
        recorder.append(r.recv_stamp_ns, &r.message()).unwrap();
    }
    recorder.flush().unwrap();
    drop(recorder);
    let read: Vec<RecordedMessage> = RecordReader::open(&path).unwrap().map(Result::unwrap).collect();
    assert_eq!(read, records);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn inconsistent_messages_are_refused_at_recording_time() {
    let header = StereoHeader { stamp_ns: 0, sequence: 0, pan_rad: 0.0, tilt_rad: 0.0, width_px: 4, height_px: 4 };
    let pixels = [0u8; 31];
    let mut recorder = Recorder::new(Vec::new()).unwrap();
    let err = recorder.append(0, &Message::Stereo(&header, &pixels)).unwrap_err();
    assert!(matches!(err, RecordError::Unrecordable { topic: Topic::Stereo, .. }), "{err}");
    assert_eq!(recorder.records(), 0);
}

#[test]
fn damage_is_reported_where_it_is() {
    let (records, log) = sample_log();
    // A flipped payload bit: the records before it survive, then a CRC error.
    let mut flipped = log.clone();
    let first_len = log_of(&records[..1]).len();
    flipped[first_len + 30] ^= 0x10;
    let (read, error) = read_all(&flipped);
    assert_eq!(read, records[..1]);
    assert!(matches!(error, Some(RecordError::Crc { offset }) if offset == (first_len) as u64), "{error:?}");

    // Cut in the middle of the last record.
    let (read, error) = read_all(&log[..log.len() - 3]);
    assert_eq!(read.len(), records.len() - 1);
    assert!(matches!(error, Some(RecordError::Truncated { .. })), "{error:?}");

    // Cut on a record boundary: a clean, shorter log.
    let (read, error) = read_all(&log[..first_len]);
    assert_eq!((read.len(), error.is_none()), (1, true));

    let (_, error) = read_all(b"NOTALOG!........");
    assert!(matches!(error, Some(RecordError::BadMagic)));
    let mut future = log.clone();
    future[8] = 2;
    assert!(matches!(read_all(&future).1, Some(RecordError::UnsupportedVersion(2))));
    assert!(matches!(read_all(&log[..10]).1, Some(RecordError::Truncated { offset: 0 })));
    assert_eq!(read_all(&log[..FILE_HEADER_BYTES]).0.len(), 0);
}

#[test]
fn replay_publishes_the_chosen_topics_unchanged() {
    let (records, log) = sample_log();
    let mut out = CollectingOutbox::default();
    let counts =
        replay_into(RecordReader::new(&log[..]).unwrap(), &mut out, &[Topic::FilterState, Topic::Stereo]).unwrap();
    assert_eq!((counts.delivered, counts.skipped), (2, records.len() as u64 - 2));
    let owned: Vec<&OwnedMessage> = out.messages.iter().map(|m| &m.owned).collect();
    let expected: Vec<&OwnedMessage> =
        records.iter().map(|m| &m.owned).filter(|m| matches!(m.topic(), Topic::FilterState | Topic::Stereo)).collect();
    assert_eq!(owned, expected);

    let mut all = CollectingOutbox::default();
    let counts = replay_into(RecordReader::new(&log[..]).unwrap(), &mut all, &[]).unwrap();
    assert_eq!(counts.delivered, records.len() as u64);
}

/// Integrates gyro z and counts samples; on each tick publishes a state whose fields depend on
/// every input and on the tick time, so any change in inputs, order or tick placement shows.
#[derive(Default)]
struct YawCounter {
    yaw_rad: f64,
    samples: u64,
    last_stamp_ns: Option<u64>,
}

impl Node for YawCounter {
    fn name(&self) -> &'static str {
        "yaw_counter"
    }

    fn subscriptions(&self) -> &'static [Topic] {
        &[Topic::Imu]
    }

    fn on_message(&mut self, message: Message<'_>, _out: &mut dyn Outbox) -> Result<(), NodeError> {
        let Message::Imu(imu) = message else {
            return Err(NodeError::Failed { node: "yaw_counter", reason: format!("{:?}", message.topic()) });
        };
        if let Some(last) = self.last_stamp_ns {
            self.yaw_rad += imu.gyro_radps[2] * (imu.stamp_ns - last) as f64 * 1e-9;
        }
        self.last_stamp_ns = Some(imu.stamp_ns);
        self.samples += 1;
        Ok(())
    }

    fn on_tick(&mut self, now_ns: u64, out: &mut dyn Outbox) -> Result<(), NodeError> {
        let (s, c) = (0.5 * self.yaw_rad).sin_cos();
        let state = FilterStateMsg {
            stamp_ns: now_ns,
            t_local_body: Pose { translation_m: [0.0; 3], rotation_wxyz: [c, 0.0, 0.0, s] },
            v_local_mps: [0.0; 3],
            accel_bias_mps2: [0.0; 3],
            gyro_bias_radps: [0.0; 3],
            pose_covariance: [0.0; 36],
            imu_received: self.samples,
            imu_lost: 0,
            frame_id: 0,
            status: FilterStateMsg::RUNNING,
            last_vo_capture_ns: FilterStateMsg::NEVER,
        };
        out.publish(Message::FilterState(&state))
    }
}

#[test]
fn rerunning_a_node_on_its_recorded_inputs_reproduces_its_outputs() {
    const IMU_PERIOD_NS: u64 = 5_000_000;
    const TICK_NS: u64 = 20_000_000;
    // A live run: IMU at 200 Hz from 3 ms, ticks at 50 Hz on the k·20 ms grid; messages received
    // at or before a tick are handled before it. The bus also carries traffic the node ignores.
    let mut recorder = Recorder::new(Vec::new()).unwrap();
    let mut live_node = YawCounter::default();
    let mut live = CollectingOutbox::default();
    let mut next_tick = TICK_NS; // first grid time at or after the first stamp (3 ms)
    for k in 0..100u64 {
        let t = 3_000_000 + k * IMU_PERIOD_NS;
        while next_tick < t {
            live.now_ns = next_tick;
            live_node.on_tick(next_tick, &mut live).unwrap();
            next_tick += TICK_NS;
        }
        let imu =
            ImuMsg { stamp_ns: t, sequence: k, gyro_radps: [0.0, 0.0, 0.1 * (k as f64).sin()], accel_mps2: [0.0; 3] };
        recorder.append(t, &Message::Imu(&imu)).unwrap();
        live.now_ns = t;
        live_node.on_message(Message::Imu(&imu), &mut live).unwrap();
        let other = FrameSwitchRequestMsg { stamp_ns: t, frame_id: 0, reserved: 0 };
        recorder.append(t, &Message::FrameSwitchRequest(&other)).unwrap();
    }
    live.now_ns = next_tick;
    live_node.on_tick(next_tick, &mut live).unwrap();
    let log = recorder.into_inner().unwrap();

    let mut node = YawCounter::default();
    let (outputs, counts) = rerun(&mut node, RecordReader::new(&log[..]).unwrap(), TICK_NS).unwrap();
    assert_eq!((counts.delivered, counts.skipped), (100, 100));
    assert_eq!(counts.ticks, live.messages.len() as u64);
    assert!(outputs.len() > 20);
    assert_eq!(outputs, live.messages);
    // The last tick saw every sample.
    let Message::FilterState(last) = outputs.last().unwrap().message() else { panic!() };
    assert_eq!(last.imu_received, 100);
}

proptest! {
    #[test]
    fn arbitrary_bytes_never_panic(bytes in prop::collection::vec(any::<u8>(), 0..600), with_header in any::<bool>()) {
        let mut input = Vec::new();
        if with_header {
            input.extend_from_slice(&log_of(&[])[..FILE_HEADER_BYTES]);
        }
        input.extend_from_slice(&bytes);
        let _ = read_all(&input);
    }

    #[test]
    fn truncations_and_bit_flips_of_a_valid_log_never_panic(
        cut in any::<prop::sample::Index>(),
        flips in prop::collection::vec((any::<prop::sample::Index>(), 0u8..8), 0..4),
    ) {
        let (records, log) = sample_log();
        let mut damaged = log[..cut.index(log.len() + 1)].to_vec();
        for (at, bit) in &flips {
            if !damaged.is_empty() {
                let i = at.index(damaged.len());
                damaged[i] ^= 1 << bit;
            }
        }
        let (read, error) = read_all(&damaged);
        // Whatever was read is a prefix of the original (a CRC catches the damage), unless the
        // damage sits in the stamp/CRC pair so that both still match, which 1–3 bit flips cannot.
        prop_assert!(read.len() <= records.len());
        prop_assert_eq!(&read[..], &records[..read.len()]);
        if flips.is_empty() && cut.index(log.len() + 1) == log.len() {
            prop_assert!(error.is_none());
        }
    }
}
