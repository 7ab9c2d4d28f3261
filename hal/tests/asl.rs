//! The EuRoC/ASL reader on real EuRoC data, on small synthetic datasets that exercise pairing,
//! merging and the extensions, and fuzzed: no bytes make a parser panic.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]
// Expected values are copied digit for digit from the dataset's files.
#![allow(clippy::excessive_precision)]

use std::fs;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use hal::asl::csv::{parse_camera_csv, parse_imu_csv, parse_pantilt_csv, parse_wheel_csv};
use hal::asl::yaml::Yaml;
use hal::asl::{AslDataset, camera_calibration, transform_rows};
use hal::sensor::{Distortion, SensorError, SensorEvent, SensorSource, StereoFrame};
use nalgebra::{Isometry3, Matrix3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

const V101: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/euroc/v1_01_excerpt");
const MH01: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/euroc/mh_01_handheld");

/// A fresh empty folder under the target's temp dir.
fn temp_dir(name: &str) -> PathBuf {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!(
        "hal-asl-{name}-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    dir
}

fn decode_png(path: &Path) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::BufReader::new(fs::File::open(path).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buffer = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buffer).unwrap();
    assert_eq!(info.color_type, png::ColorType::Grayscale);
    (info.width, info.height, buffer)
}

fn write_png(path: &Path, width: u32, height: u32, pixels: &[u8]) {
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(fs::File::create(path).unwrap()), width, height);
    encoder.set_color(png::ColorType::Grayscale);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header().unwrap().write_image_data(pixels).unwrap();
}

/// All events of a source: (kind, stamp) plus the frames' sequence numbers.
fn drain(source: &mut AslDataset) -> (Vec<(char, u64)>, Vec<u64>) {
    let mut frame = StereoFrame::default();
    let (mut events, mut sequences) = (Vec::new(), Vec::new());
    while let Some(event) = hal::sensor::next_event_with_frame(source, &mut frame).unwrap() {
        events.push(match event {
            SensorEvent::Imu(s) => ('i', s.stamp_ns),
            SensorEvent::WheelOdom(s) => ('w', s.stamp_ns),
            SensorEvent::Stereo(_) => {
                sequences.push(frame.sequence);
                ('s', frame.stamp_ns)
            }
        });
    }
    (events, sequences)
}

#[test]
fn v1_01_counts_stamps_and_order() {
    let mut dataset = AslDataset::open(V101).unwrap();
    // The folder holds 20 pairs (SOURCE.md's "40" predates a trim; data.csv and data/ agree on 20).
    assert_eq!(dataset.pairs().len(), 20);
    assert_eq!(dataset.unmatched_frames(), 0);
    assert_eq!(dataset.imu_samples().len(), 29_120);
    assert!(dataset.wheel_samples().is_empty());
    assert_eq!(dataset.camera_rate_hz(), Some(20.0));
    assert_eq!(dataset.pairs()[0].stamp_ns, 1_403_715_273_262_142_976);
    assert_eq!(dataset.pairs()[19].stamp_ns, 1_403_715_274_212_143_104);

    // First and last IMU rows of imu0/data.csv, digit for digit.
    let first = dataset.imu_samples()[0];
    assert_eq!(first.stamp_ns, 1_403_715_273_262_142_976);
    assert_eq!(first.gyro_radps, Vector3::new(-0.0020943951023931952, 0.017453292519943295, 0.07749261878854824));
    assert_eq!(first.accel_mps2, Vector3::new(9.0874956666666655, 0.13075533333333333, -3.6938381666666662));
    let last = dataset.imu_samples()[29_119];
    assert_eq!(last.stamp_ns, 1_403_715_418_857_143_040);
    assert_eq!(last.accel_mps2.z, -3.2035056666666666);

    let noise = dataset.imu_noise().unwrap();
    assert_eq!(noise.gyroscope_noise_density, 1.6968e-04);
    assert_eq!(noise.gyroscope_random_walk, 1.9393e-05);
    assert_eq!(noise.accelerometer_noise_density, 2.0e-3);
    assert_eq!(noise.accelerometer_random_walk, 3.0e-3);
    assert_eq!(noise.rate_hz, Some(200.0));

    let (events, sequences) = drain(&mut dataset);
    assert_eq!(events.len(), 29_120 + 20);
    assert!(events.windows(2).all(|w| w[0].1 <= w[1].1), "events out of order");
    // The first camera stamp equals the first IMU stamp: IMU first.
    assert_eq!(events[0], ('i', 1_403_715_273_262_142_976));
    assert_eq!(events[1], ('s', 1_403_715_273_262_142_976));
    assert_eq!(sequences, (0..20).collect::<Vec<u64>>());
    assert_eq!(events.iter().filter(|e| e.0 == 'i').count(), 29_120);

    // Rewinding replays the same sequence.
    dataset.rewind();
    assert_eq!(drain(&mut dataset).0, events);
}

#[test]
fn v1_01_calibration_matches_sensor_yaml() {
    let dataset = AslDataset::open(V101).unwrap();
    let calibration = dataset.stereo_calibration().unwrap();
    let (left, right) = (calibration.left, calibration.right);
    assert_eq!((left.width_px, left.height_px), (752, 480));
    assert_eq!((right.width_px, right.height_px), (752, 480));
    assert_eq!(
        [left.intrinsics.fx_px, left.intrinsics.fy_px, left.intrinsics.cx_px, left.intrinsics.cy_px],
        [458.654, 457.296, 367.215, 248.375]
    );
    assert_eq!(
        [right.intrinsics.fx_px, right.intrinsics.fy_px, right.intrinsics.cx_px, right.intrinsics.cy_px],
        [457.587, 456.134, 379.999, 255.238]
    );
    assert_eq!(left.distortion, Distortion::RadTan([-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]));
    assert_eq!(right.distortion, Distortion::RadTan([-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05]));
    assert!(!calibration.rectified);

    // T_BS of cam0, row-major as in sensor.yaml. The stored rotation is orthonormal only to about
    // 1e-9, so the reader's exact rotation may differ from it by that much.
    let t_bs0 = [
        0.0148655429818,
        -0.999880929698,
        0.00414029679422,
        -0.0216401454975,
        0.999557249008,
        0.0149672133247,
        0.025715529948,
        -0.064676986768,
        -0.0257744366974,
        0.00375618835797,
        0.999660727178,
        0.00981073058949,
    ];
    let rows = transform_rows(&left.t_body_cam);
    for (i, expected) in t_bs0.iter().enumerate() {
        assert!((rows[i] - expected).abs() < 1e-8, "T_BS[{i}] = {} vs {expected}", rows[i]);
    }
    // Baseline: distance between the two T_BS translations (cam1: -0.0198435579556,
    // 0.0453689425024, 0.00786212447038), ≈ 0.110 m as the EuRoC paper states.
    let expected: f64 = (Vector3::new(-0.0198435579556, 0.0453689425024, 0.00786212447038)
        - Vector3::new(-0.0216401454975, -0.064676986768, 0.00981073058949))
    .norm();
    assert!((calibration.baseline_m - expected).abs() < 1e-12, "{} vs {expected}", calibration.baseline_m);
    assert!((calibration.baseline_m - 0.110).abs() < 0.001);
}

#[test]
fn v1_01_images_are_the_png_pixels() {
    let mut dataset = AslDataset::open(Path::new(V101).join("mav0")).unwrap();
    let mut frame = StereoFrame::default();
    for index in [0, 19] {
        dataset.load_pair(index, &mut frame).unwrap();
        let pair = &dataset.pairs()[index];
        let (w, h, left) = decode_png(&pair.left);
        let (_, _, right) = decode_png(&pair.right);
        assert_eq!((frame.width_px, frame.height_px), (w, h));
        assert!(frame.left == left && frame.right == right, "pair {index} differs from its PNGs");
        assert_eq!(frame.stamp_ns, pair.stamp_ns);
        assert!(pair.left.ends_with(format!("cam0/data/{}.png", pair.stamp_ns)));
    }
    assert!(dataset.load_pair(20, &mut frame).is_err());
}

#[test]
fn mh_01_cameras_without_imu() {
    let mut dataset = AslDataset::open(MH01).unwrap();
    assert_eq!(dataset.pairs().len(), 85);
    assert!(dataset.imu_samples().is_empty());
    // imu0/ has only its sensor.yaml: the noise is known, the samples are not.
    assert_eq!(dataset.imu_noise().unwrap().gyroscope_noise_density, 1.6968e-04);
    let calibration = dataset.stereo_calibration().unwrap();
    assert_eq!(calibration.left.intrinsics.fx_px, 458.654);
    let (events, sequences) = drain(&mut dataset);
    assert_eq!(events.len(), 85);
    assert!(events.iter().all(|e| e.0 == 's'));
    assert_eq!(events[0].1, 1_403_636_593_013_555_456);
    assert_eq!(events[84].1, 1_403_636_597_213_555_456);
    assert_eq!(sequences.last(), Some(&84));
}

/// A small rectified dataset: 4×2 images, cameras with gaps, IMU, wheel and pan-tilt rows.
fn synthetic_dataset(dir: &Path, cam0_stamps: &[u64], cam1_stamps: &[u64]) -> PathBuf {
    let mav0 = dir.join("mav0");
    let t_body_left =
        Isometry3::from_parts(Translation3::new(0.3, 0.045, 1.1), UnitQuaternion::from_euler_angles(-1.9, 0.1, -1.4));
    let t_body_right = t_body_left * Isometry3::translation(0.09, 0.0, 0.0);
    for (cam, stamps, t) in [("cam0", cam0_stamps, t_body_left), ("cam1", cam1_stamps, t_body_right)] {
        fs::create_dir_all(mav0.join(cam).join("data")).unwrap();
        let mut csv = String::from("#timestamp [ns],filename\n");
        for &stamp in stamps {
            csv.push_str(&format!("{stamp},{stamp}.png\n"));
            let value = (stamp % 251) as u8;
            write_png(&mav0.join(cam).join("data").join(format!("{stamp}.png")), 4, 2, &[value; 8]);
        }
        fs::write(mav0.join(cam).join("data.csv"), csv).unwrap();
        let rows: Vec<String> = transform_rows(&t).iter().map(|v| format!("{v:?}")).collect();
        let yaml = format!(
            "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: [{}]\nrate_hz: 10\n\
             resolution: [4, 2]\ncamera_model: pinhole\nintrinsics: [3.5, 3.5, 1.5, 0.5]\n\
             distortion_model: radial-tangential\ndistortion_coefficients: [0.0, 0.0, 0.0, 0.0]\n",
            rows.join(", ")
        );
        fs::write(mav0.join(cam).join("sensor.yaml"), yaml).unwrap();
    }
    fs::create_dir_all(mav0.join("imu0")).unwrap();
    fs::write(
        mav0.join("imu0/data.csv"),
        "#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n1,0,0,0,0,0,1.62\n3,0.5,0,0,0,0,1.62\n",
    )
    .unwrap();
    fs::create_dir_all(mav0.join("wheel0")).unwrap();
    fs::write(
        mav0.join("wheel0/data.csv"),
        "#timestamp [ns],v_x,...\n3,0.3,0,0,0,0,0.1,0.01,0.01,0.01,0.02,0.02,0.02\n",
    )
    .unwrap();
    fs::create_dir_all(mav0.join("pantilt0")).unwrap();
    fs::write(mav0.join("pantilt0/data.csv"), "#timestamp [ns],pan [rad],tilt [rad]\n3,0.25,0.5\n").unwrap();
    mav0
}

#[test]
fn pairs_by_equal_stamps_and_merges_ties_imu_wheel_stereo() {
    let dir = temp_dir("pairs");
    synthetic_dataset(&dir, &[1, 2, 3, 5], &[1, 3, 4, 5]);
    let mut dataset = AslDataset::open(&dir).unwrap();
    assert_eq!(dataset.pairs().iter().map(|p| p.stamp_ns).collect::<Vec<_>>(), vec![1, 3, 5]);
    assert_eq!(dataset.unmatched_frames(), 2);
    let calibration = dataset.stereo_calibration().unwrap();
    assert!(calibration.rectified, "zero radtan, equal intrinsics, pure-x baseline");
    assert_eq!(calibration.left.distortion, Distortion::None);
    assert!((calibration.baseline_m - 0.09).abs() < 1e-12);

    let mut frame = StereoFrame::default();
    let mut seen = Vec::new();
    while let Some(event) = hal::sensor::next_event_with_frame(&mut dataset, &mut frame).unwrap() {
        match event {
            SensorEvent::Imu(s) => seen.push(format!("imu{}", s.stamp_ns)),
            SensorEvent::WheelOdom(s) => {
                assert_eq!(s.sigma, [0.01, 0.01, 0.01, 0.02, 0.02, 0.02]);
                seen.push(format!("wheel{}", s.stamp_ns));
            }
            SensorEvent::Stereo(_) => {
                assert_eq!(frame.left, vec![(frame.stamp_ns % 251) as u8; 8]);
                let angles = if frame.stamp_ns == 3 { (0.25, 0.5) } else { (0.0, 0.0) };
                assert_eq!((frame.pan_rad, frame.tilt_rad), angles);
                seen.push(format!("stereo{}#{}", frame.stamp_ns, frame.sequence));
            }
        }
    }
    assert_eq!(seen, ["imu1", "stereo1#0", "imu3", "wheel3", "stereo3#2", "stereo5#3"]);
}

#[test]
fn head_reference_pose_replaces_the_tilted_t_bs() {
    let dir = temp_dir("head");
    let mav0 = synthetic_dataset(&dir, &[1], &[1]);
    let t_zero =
        Isometry3::from_parts(Translation3::new(0.36, 0.045, 1.05), UnitQuaternion::from_euler_angles(-1.5, 0.0, -1.6));
    let rows: Vec<String> = transform_rows(&t_zero).iter().map(|v| format!("{v:?}")).collect();
    let yaml = format!(
        "reference_pan_rad: 0.0\nreference_tilt_rad: 0.3\nT_BS_cam0_pan0_tilt0:\n  data: [{}]\n",
        rows.join(", ")
    );
    fs::write(mav0.join("pantilt0/sensor.yaml"), yaml).unwrap();
    let calibration = AslDataset::open(&mav0).unwrap().stereo_calibration().unwrap();
    assert!((calibration.left.t_body_cam.translation.vector - t_zero.translation.vector).norm() < 1e-12);
    assert!(calibration.left.t_body_cam.rotation.angle_to(&t_zero.rotation) < 1e-12);
    // The pair stays rigid and rectified.
    assert!(calibration.rectified);
    let t_left_right = calibration.left.t_body_cam.inverse() * calibration.right.t_body_cam;
    assert!((t_left_right.translation.vector - Vector3::new(0.09, 0.0, 0.0)).norm() < 1e-12);
    // Without the head's kinematics there is no head to turn angles into poses.
    assert!(calibration.head.is_none());

    // With them, the calibration carries the head (the LRU head written by the simulator).
    let head = hal::sensor::PanTiltHead::lru();
    let rows: Vec<String> = transform_rows(&head.t_body_cam(0.0, 0.0)).iter().map(|v| format!("{v:?}")).collect();
    let yaml = format!(
        "T_BS_cam0_pan0_tilt0:\n  data: [{}]\npan_axis_body_m: [0.3, 0.0, 1.05]\nstereo_centre_head_m: [0.06, 0.0, 0.0]\n",
        rows.join(", ")
    );
    fs::write(mav0.join("pantilt0/sensor.yaml"), yaml).unwrap();
    let calibration = AslDataset::open(&mav0).unwrap().stereo_calibration().unwrap();
    let read_head = calibration.head.unwrap();
    for (pan, tilt) in [(0.0, 0.0), (0.7, 0.3), (-2.5, -0.4)] {
        let (a, b) = (calibration.t_body_left(pan, tilt), head.t_body_cam(pan, tilt));
        assert!((a.translation.vector - b.translation.vector).norm() < 1e-12);
        assert!(a.rotation.angle_to(&b.rotation) < 1e-12);
    }
    assert!((read_head.baseline_m - 0.09).abs() < 1e-12);
}

#[test]
fn errors_name_the_file_and_line() {
    let dir = temp_dir("errors");
    let mav0 = synthetic_dataset(&dir, &[1, 2], &[1, 2]);
    fs::write(mav0.join("imu0/data.csv"), "#h\n1,0,0,0,0,0,1\n2,0,0,0,zero,0,1\n").unwrap();
    let err = AslDataset::open(&dir).unwrap_err();
    let text = err.to_string();
    assert!(matches!(err, SensorError::Format { .. }));
    assert!(text.contains("imu0/data.csv:3") && text.contains("a_x"), "{text}");

    let mav0 = synthetic_dataset(&temp_dir("errors"), &[1, 2], &[1, 2]);
    fs::write(
        mav0.join("cam1/sensor.yaml"),
        "T_BS:\n  data: [1, 0, 0, 0]\nresolution: [4, 2]\nintrinsics: [3.5, 3.5, 1.5, 0.5]\n",
    )
    .unwrap();
    let text = AslDataset::open(&mav0).unwrap_err().to_string();
    assert!(text.contains("cam1/sensor.yaml:2") && text.contains("4 numbers, expected 16"), "{text}");

    let mav0 = synthetic_dataset(&temp_dir("errors"), &[1, 2], &[1, 2]);
    fs::remove_file(mav0.join("cam0/sensor.yaml")).unwrap();
    assert!(matches!(AslDataset::open(&mav0).unwrap_err(), SensorError::Io { .. }));

    // A wrong-sized or truncated image fails when its pair is replayed, naming the PNG.
    let mav0 = synthetic_dataset(&temp_dir("errors"), &[1, 2], &[1, 2]);
    write_png(&mav0.join("cam1/data/1.png"), 3, 2, &[0; 6]);
    let bytes = fs::read(mav0.join("cam0/data/2.png")).unwrap();
    fs::write(mav0.join("cam0/data/2.png"), &bytes[..bytes.len() / 2]).unwrap();
    let mut dataset = AslDataset::open(&mav0).unwrap();
    let mut frame = StereoFrame::default();
    let text = dataset.load_pair(0, &mut frame).unwrap_err().to_string();
    assert!(text.contains("cam1/data/1.png") && text.contains("3×2"), "{text}");
    let text = dataset.load_pair(1, &mut frame).unwrap_err().to_string();
    assert!(text.contains("cam0/data/2.png"), "{text}");

    assert!(AslDataset::open(temp_dir("empty")).is_err());
}

/// Real files to mutate: a camera yaml, a camera CSV and the head of the IMU CSV.
fn real_files() -> Vec<(&'static str, Vec<u8>)> {
    let mav0 = Path::new(V101).join("mav0");
    let imu = fs::read(mav0.join("imu0/data.csv")).unwrap();
    let imu_head: Vec<u8> = imu.split_inclusive(|&b| b == b'\n').take(60).flatten().copied().collect();
    vec![
        ("yaml", fs::read(mav0.join("cam0/sensor.yaml")).unwrap()),
        ("yaml", fs::read(mav0.join("imu0/sensor.yaml")).unwrap()),
        ("camera", fs::read(mav0.join("cam0/data.csv")).unwrap()),
        ("imu", imu_head),
    ]
}

/// Runs the parser for `kind` (and, for YAML, the calibration built from it); must not panic.
fn parse_any(kind: &str, bytes: &[u8]) -> bool {
    let file = Path::new("fuzz");
    match kind {
        "yaml" => Yaml::parse(bytes, file).is_ok_and(|yaml| camera_calibration(&yaml).is_ok()),
        "camera" => parse_camera_csv(bytes, file).is_ok(),
        "imu" => parse_imu_csv(bytes, file).is_ok(),
        "wheel" => parse_wheel_csv(bytes, file).is_ok(),
        _ => parse_pantilt_csv(bytes, file).is_ok(),
    }
}

#[test]
fn unmutated_real_files_parse() {
    let files = real_files();
    assert!(parse_any("yaml", &files[0].1));
    assert!(Yaml::parse(&files[1].1, Path::new("imu.yaml")).is_ok());
    assert!(parse_any("camera", &files[2].1) && parse_any("imu", &files[3].1));
}

#[derive(Debug, Clone)]
enum Mutation {
    Set(usize, u8),
    Insert(usize, u8),
    Remove(usize),
    Truncate(usize),
}

fn mutation() -> impl Strategy<Value = Mutation> {
    // Bytes the formats care about are more likely to break a parser than random ones.
    let byte = prop_oneof![any::<u8>(), prop::sample::select(b"0123456789,.-+e[]:# \n\r\t\"'!%".to_vec())];
    prop_oneof![
        (any::<usize>(), byte.clone()).prop_map(|(i, b)| Mutation::Set(i, b)),
        (any::<usize>(), byte).prop_map(|(i, b)| Mutation::Insert(i, b)),
        any::<usize>().prop_map(Mutation::Remove),
        any::<usize>().prop_map(Mutation::Truncate),
    ]
}

fn apply(bytes: &mut Vec<u8>, mutation: &Mutation) {
    let n = bytes.len().max(1);
    match *mutation {
        Mutation::Set(i, b) if !bytes.is_empty() => bytes[i % n] = b,
        Mutation::Insert(i, b) => bytes.insert(i % (bytes.len() + 1), b),
        Mutation::Remove(i) if !bytes.is_empty() => {
            bytes.remove(i % n);
        }
        Mutation::Truncate(i) => bytes.truncate(i % n),
        _ => {}
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn parsers_never_panic_on_arbitrary_bytes(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        for kind in ["yaml", "camera", "imu", "wheel", "pantilt"] {
            parse_any(kind, &bytes);
        }
    }

    #[test]
    fn parsers_never_panic_on_mutated_real_files(
        file in 0usize..4,
        mutations in prop::collection::vec(mutation(), 1..8),
    ) {
        let (kind, mut bytes) = real_files().swap_remove(file);
        for m in &mutations {
            apply(&mut bytes, m);
        }
        parse_any(kind, &bytes);
    }
}

#[test]
fn rotation_check_rejects_non_rotations() {
    let yaml = |data: &str| Yaml::parse(format!("T_BS:\n  data: [{data}]\n").as_bytes(), Path::new("t.yaml")).unwrap();
    let reflection = "1, 0, 0, 0, 0, 1, 0, 0, 0, 0, -1, 0, 0, 0, 0, 1";
    assert!(hal::asl::read_transform(&yaml(reflection), "T_BS").is_err());
    let scaled = "2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 1";
    assert!(hal::asl::read_transform(&yaml(scaled), "T_BS").is_err());
    let t =
        hal::asl::read_transform(&yaml("0, -1, 0, 1, 1, 0, 0, 2, 0, 0, 1, 3, 0, 0, 0, 1"), "T_BS").unwrap().unwrap();
    assert_eq!(t.translation.vector, Vector3::new(1.0, 2.0, 3.0));
    assert!(
        (t.rotation.to_rotation_matrix().matrix() - Matrix3::new(0.0, -1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0)).norm()
            < 1e-15
    );
}
