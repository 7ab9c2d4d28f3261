#![allow(clippy::unwrap_used, clippy::expect_used)]
//! The KITTI odometry reader on the straight-drive excerpt in `data/` and on synthetic layouts.

use std::fs;
use std::path::{Path, PathBuf};

use hal::kitti::{self, KittiDataset};
use hal::sensor::{SensorError, SensorEvent, SensorSource, StereoFrame, r_flu_optical};
use nalgebra::Vector3;
use proptest::prelude::*;

const KITTI: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/stereo_sequences/kitti_straight");

fn fresh_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("hal-kitti-{name}-{}", std::process::id()));
    let _ = fs::remove_dir_all(&dir);
    fs::create_dir_all(&dir).unwrap();
    dir
}

fn write_png(path: &Path, width: u32, height: u32, color: png::ColorType, data: &[u8]) {
    let file = fs::File::create(path).unwrap();
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    encoder.set_color(color);
    encoder.set_depth(png::BitDepth::Eight);
    encoder.write_header().unwrap().write_image_data(data).unwrap();
}

#[test]
fn straight_drive_calibration_stamps_and_images() {
    let mut dataset = KittiDataset::open(KITTI).unwrap();
    let calibration = dataset.stereo_calibration().unwrap();
    assert!(calibration.rectified);
    assert_eq!((calibration.left.width_px, calibration.left.height_px), (1226, 370));
    assert_eq!(calibration.left.intrinsics.fx_px, 707.0912);
    assert_eq!(calibration.left.intrinsics, calibration.right.intrinsics);
    // 379.8145 / 707.0912 from P1[0,3].
    assert!((calibration.baseline_m - 0.537_150_7).abs() < 1e-6, "{}", calibration.baseline_m);
    // Body x (forward) is the optical axis, body y (left) is −x of the image.
    let r = calibration.left.t_body_cam.rotation;
    assert!((r * Vector3::z() - Vector3::x()).norm() < 1e-12);
    assert!((r * Vector3::x() + Vector3::y()).norm() < 1e-12);
    assert!((r.to_rotation_matrix().matrix() - r_flu_optical().matrix()).norm() < 1e-12);
    let t_left_right = calibration.left.t_body_cam.inverse() * calibration.right.t_body_cam;
    assert!((t_left_right.translation.vector - Vector3::new(calibration.baseline_m, 0.0, 0.0)).norm() < 1e-12);

    assert_eq!(dataset.frames().len(), 51);
    let mut frame = StereoFrame::default();
    let mut stamps = Vec::new();
    while let Some(event) = hal::sensor::next_event_with_frame(&mut dataset, &mut frame).unwrap() {
        assert!(matches!(event, SensorEvent::Stereo(_)));
        assert_eq!(frame.left.len(), 1226 * 370);
        stamps.push(frame.stamp_ns);
    }
    // No times.txt: 10 Hz from zero.
    assert_eq!(stamps, (0..51).map(|i| i * 100_000_000).collect::<Vec<u64>>());
    // Real content: a textured street scene, and the right image differs from the left.
    let mean = frame.left.iter().map(|&v| f64::from(v)).sum::<f64>() / frame.left.len() as f64;
    assert!((30.0..220.0).contains(&mean), "{mean}");
    assert_ne!(frame.left, frame.right);
    dataset.rewind();
    assert!(matches!(
        hal::sensor::next_event_with_frame(&mut dataset, &mut frame).unwrap(),
        Some(SensorEvent::Stereo(_))
    ));
    assert_eq!(frame.stamp_ns, 0);
}

#[test]
fn labelled_calibration_times_and_rgb_images() {
    let dir = fresh_dir("labelled");
    fs::create_dir_all(dir.join("image_0")).unwrap();
    fs::create_dir_all(dir.join("image_1")).unwrap();
    let (w, h) = (4, 3);
    // Pure red, green and blue pixels repeated: luma 76, 150, 29 (Rec. 601).
    let rgb: Vec<u8> = (0..w * h)
        .flat_map(|i| match i % 3 {
            0 => [255, 0, 0],
            1 => [0, 255, 0],
            _ => [0, 0, 255],
        })
        .collect();
    let grey: Vec<u8> = (0..(w * h) as u8).collect();
    for name in ["000000.png", "000001.png"] {
        write_png(&dir.join("image_0").join(name), w, h, png::ColorType::Rgb, &rgb);
        write_png(&dir.join("image_1").join(name), w, h, png::ColorType::Grayscale, &grey);
    }
    fs::write(
        dir.join("calib.txt"),
        "P0: 500 0 2 0 0 500 1.5 0 0 0 1 0\nP1: 500 0 2 -60 0 500 1.5 0 0 0 1 0\n\
         P2: 500 0 2 44 0 500 1.5 0.2 0 0 1 0.003\nTr: 1 0 0 0 0 1 0 0 0 0 1 0\n",
    )
    .unwrap();
    fs::write(dir.join("times.txt"), "0.000000e+00\n1.036000e-01\n").unwrap();
    let mut dataset = KittiDataset::open(&dir).unwrap();
    let calibration = dataset.stereo_calibration().unwrap();
    assert!((calibration.baseline_m - 0.12).abs() < 1e-12);
    let mut frame = StereoFrame::default();
    hal::sensor::next_event_with_frame(&mut dataset, &mut frame).unwrap().unwrap();
    assert_eq!(&frame.left[..3], &[76, 150, 29]);
    assert_eq!(frame.right, grey);
    hal::sensor::next_event_with_frame(&mut dataset, &mut frame).unwrap().unwrap();
    assert_eq!(frame.stamp_ns, 103_600_000);
    assert_eq!(frame.sequence, 1);
    assert!(hal::sensor::next_event_with_frame(&mut dataset, &mut frame).unwrap().is_none());

    // A times file that does not match the images is refused.
    fs::write(dir.join("times.txt"), "0.0\n").unwrap();
    let error = KittiDataset::open(&dir).unwrap_err().to_string();
    assert!(error.contains("1 stamps for 2 images"), "{error}");
    fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn missing_and_broken_inputs_give_clear_errors() {
    let missing = KittiDataset::open("/nonexistent/kitti").unwrap_err();
    assert!(matches!(missing, SensorError::Io { .. }), "{missing}");

    let dir = fresh_dir("broken");
    let not_kitti = KittiDataset::open(&dir).unwrap_err().to_string();
    assert!(not_kitti.contains("not a KITTI sequence"), "{not_kitti}");

    fs::create_dir_all(dir.join("image_l")).unwrap();
    fs::create_dir_all(dir.join("image_r")).unwrap();
    let no_calib = KittiDataset::open(&dir).unwrap_err().to_string();
    assert!(no_calib.contains("calib.txt"), "{no_calib}");

    fs::write(dir.join("calib.txt"), "P0: 1 2 3\n").unwrap();
    let garbled = KittiDataset::open(&dir).unwrap_err().to_string();
    assert!(garbled.contains("calib.txt:1") && garbled.contains("expected 12 numbers"), "{garbled}");

    // Left and right swapped: a negative baseline.
    fs::write(dir.join("calib.txt"), "500 0 2 -60 0 500 1.5 0 0 0 1 0\n500 0 2 0 0 500 1.5 0 0 0 1 0\n").unwrap();
    let swapped = KittiDataset::open(&dir).unwrap_err().to_string();
    assert!(swapped.contains("baseline"), "{swapped}");

    fs::write(dir.join("calib.txt"), "500 0 2 0 0 500 1.5 0 0 0 1 0\n500 0 2 -60 0 500 1.5 0 0 0 1 0\n").unwrap();
    let no_images = KittiDataset::open(&dir).unwrap_err().to_string();
    assert!(no_images.contains("no PNG images"), "{no_images}");

    write_png(&dir.join("image_l/000000.png"), 2, 2, png::ColorType::Grayscale, &[0; 4]);
    let no_right = KittiDataset::open(&dir).unwrap_err().to_string();
    assert!(no_right.contains("right image"), "{no_right}");

    // A right image of another size fails when the pair is read, naming the file.
    write_png(&dir.join("image_r/000000.png"), 3, 2, png::ColorType::Grayscale, &[0; 6]);
    let mut dataset = KittiDataset::open(&dir).unwrap();
    let wrong_size =
        hal::sensor::next_event_with_frame(&mut dataset, &mut StereoFrame::default()).unwrap_err().to_string();
    assert!(wrong_size.contains("000000.png") && wrong_size.contains("3×2"), "{wrong_size}");
    fs::remove_dir_all(&dir).unwrap();
}

proptest! {
    #[test]
    fn calibration_parser_is_total(text in "[ P01:\\-.e0-9\n#x]{0,200}") {
        let path = Path::new("calib.txt");
        if let Ok(projections) = kitti::parse_calib(&text, path) {
            let _ = projections.pinhole_and_baseline();
        }
    }

    #[test]
    fn calibration_parser_survives_any_text(text in "\\PC{0,300}") {
        let _ = kitti::parse_calib(&text, Path::new("calib.txt"));
    }

    #[test]
    fn times_parser_is_total_and_accepts_only_increasing_stamps(text in "[ 0-9.e\\-+\nNaI]{0,120}") {
        if let Ok(stamps) = kitti::parse_times(&text, Path::new("times.txt")) {
            prop_assert!(stamps.windows(2).all(|w| w[1] > w[0]));
        }
    }

    #[test]
    fn times_round_trip(deltas in proptest::collection::vec(1u64..1_000_000_000, 0..20)) {
        let mut stamps = Vec::new();
        let mut t = 0u64;
        for d in deltas {
            t += d;
            stamps.push(t);
        }
        let text: String = stamps.iter().map(|s| format!("{:.9}\n", *s as f64 / 1e9)).collect();
        prop_assert_eq!(kitti::parse_times(&text, Path::new("times.txt")).unwrap(), stamps);
    }
}
