//! Rover configuration: the example file loads, defaults fill what is left out, every invalid
//! case is rejected with a message naming the key, and no input makes the loader panic.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};

use msgs::ProcessKind;
use onboard::config::{ConfigError, DriverKind, LinkKind, RoverConfig};
use onboard::task::rt::RtRequest;
use proptest::prelude::*;

fn example_path() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("config/rover.toml")
}

fn example_text() -> String {
    std::fs::read_to_string(example_path()).unwrap()
}

#[test]
fn the_example_file_loads() {
    let c = RoverConfig::load(&example_path()).unwrap();
    assert_eq!((c.robot.id, c.robot.name.as_str()), (0, "lru1"));
    assert_eq!(c.driver.kind, DriverKind::Replay);
    assert_eq!(c.driver.replay_path.as_deref(), Some(Path::new("data/euroc/mh_01_handheld")));
    assert_eq!((c.driver.replay_speed, c.driver.duration_s), (0.25, None));
    // The dataset brings the calibration.
    assert!(c.camera.calibration.is_none());
    assert_eq!(c.vision.sgm_disparities, 128);
    let filter = c.rates.filter.spec("filter");
    assert_eq!((filter.period_ns, filter.deadline_ns), (5_000_000, 2_500_000));
    let mapper = c.rates.mapper.spec("mapper");
    assert_eq!((mapper.period_ns, mapper.deadline_ns), (100_000_000, 100_000_000));
    let comms = c.rates.comms.spec("comms");
    assert_eq!(comms.deadline_ns, comms.period_ns, "no deadline given: the whole period");
    assert_eq!(c.link.kind, LinkKind::Udp);
    assert_eq!(c.link.bind_addr(), Some("0.0.0.0:47000".parse().unwrap()));
    assert_eq!(c.link.peer_addrs(), vec![(1, "127.0.0.1:47001".parse().unwrap())]);
    assert_eq!(c.link.ground_feed_addr(), Some("127.0.0.1:47100".parse().unwrap()));
    assert_eq!(
        c.realtime.request(ProcessKind::Filter),
        RtRequest { fifo_priority: Some(80), lock_memory: true, cpu: Some(1) }
    );
    assert_eq!(
        c.realtime.request(ProcessKind::Mapper),
        RtRequest { fifo_priority: None, lock_memory: true, cpu: None }
    );
    assert!(!c.recording.enabled);
}

#[test]
fn only_the_robot_id_and_the_sensor_source_are_required() {
    let c = RoverConfig::from_toml_str("[robot]\nid = 0\n[driver]\nreplay_path = \"data/x\"\n").unwrap();
    let mut expected = RoverConfig::default();
    expected.driver.replay_path = Some("data/x".into());
    assert_eq!(c, expected);
    let err = RoverConfig::from_toml_str("").unwrap_err();
    assert!(err.to_string().contains("missing field `robot`"), "{err}");
    let err = RoverConfig::from_toml_str("[robot]\nid = 0\n").unwrap_err();
    assert!(err.to_string().contains("driver.replay_path"), "{err}");
}

#[test]
fn the_serialized_form_loads_back_identically() {
    let c = RoverConfig::load(&example_path()).unwrap();
    let text = c.to_toml_string();
    assert_eq!(RoverConfig::from_toml_str(&text).unwrap(), c, "{text}");
}

#[test]
fn marker_detection_needs_the_teams_tag_mountings() {
    let c = RoverConfig::load(&example_path()).unwrap();
    assert_eq!(
        (c.markers.detect, c.markers.size_m, c.markers.tags_per_robot, c.markers.mounting.len()),
        (false, 0.16, 3, 3)
    );
    let on = RoverConfig::from_toml_str("[robot]\nid = 0\n[driver]\nreplay_path = \"d\"\n[markers]\ndetect = true\n");
    let err = on.unwrap_err().to_string();
    assert!(err.contains("markers.mounting") && err.contains("required"), "{err}");
    // With the mountings, the table models need the camera's table.
    let mounted = "[robot]\nid = 0\n[driver]\nreplay_path = \"d\"\n[markers]\ndetect = true\n[[markers.mounting]]\ntranslation_m = [0.0, 0.0, 0.8]\nrotation_wxyz = [1.0, 0.0, 0.0, 0.0]\n";
    let err = RoverConfig::from_toml_str(mounted).unwrap_err().to_string();
    assert!(err.contains("markers.lut") && err.contains("required"), "{err}");
    let online = mounted.replace("detect = true", "detect = true\nmodel = \"online\"");
    assert!(RoverConfig::from_toml_str(&online).is_ok());
    let bad = "[robot]\nid = 0\n[driver]\nreplay_path = \"d\"\n[[markers.mounting]]\ntranslation_m = [0.0, 0.0, 0.8]\nrotation_wxyz = [2.0, 0.0, 0.0, 0.0]\n";
    let err = RoverConfig::from_toml_str(bad).unwrap_err().to_string();
    assert!(err.contains("markers.mounting[0]") && err.contains("unit quaternion"), "{err}");
}

#[test]
fn a_missing_file_names_the_path() {
    let err = RoverConfig::load(Path::new("/nonexistent/rover.toml")).unwrap_err();
    assert!(matches!(err, ConfigError::Read { .. }));
    assert!(err.to_string().contains("/nonexistent/rover.toml"), "{err}");
}

/// The example with `key = value` lines of `section` replaced or added.
fn example_with(section: &str, key: &str, value: &str) -> String {
    let mut out = String::new();
    let mut in_section = false;
    let mut done = false;
    for line in example_text().lines() {
        let trimmed = line.split('#').next().unwrap_or("").trim();
        if trimmed.starts_with('[') {
            if in_section && !done {
                out.push_str(&format!("{key} = {value}\n"));
                done = true;
            }
            in_section = trimmed == format!("[{section}]") || trimmed == format!("[[{section}]]");
        }
        if in_section && trimmed.split('=').next().map(str::trim) == Some(key) {
            if !done {
                out.push_str(&format!("{key} = {value}\n"));
                done = true;
            }
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    if !done {
        if !in_section {
            out.push_str(&format!("[{section}]\n"));
        }
        out.push_str(&format!("{key} = {value}\n"));
    }
    out
}

#[test]
fn each_invalid_value_is_rejected_naming_its_key() {
    let cases: &[(&str, &str, &str, &[&str])] = &[
        ("camera", "fps", "3", &["camera.fps", "unknown field `fps`"]),
        ("robot", "id", "-1", &["robot.id", "u16"]),
        ("robot", "id", "\"one\"", &["robot.id"]),
        ("camera", "rate_hz", "20.0", &["camera.rate_hz", "14.6"]),
        ("camera", "rate_hz", "0.0", &["camera.rate_hz", "positive"]),
        ("camera", "rate_hz", "nan", &["camera.rate_hz"]),
        ("camera", "downscale", "3", &["camera.downscale", "unknown field"]),
        ("rates", "imu_hz", "-200.0", &["rates.imu_hz"]),
        ("rates.filter", "deadline_fraction", "1.5", &["rates.filter.deadline_fraction", "at most 1"]),
        ("rates.filter", "deadline_ns", "1000", &["rates.filter", "not both"]),
        ("rates.mapper", "deadline_ns", "200000000", &["rates.mapper.deadline_ns", "the period"]),
        ("rates.vision", "hz", "5.0", &["rates.vision.hz", "below camera.rate_hz"]),
        ("rates.comms", "period", "5", &["rates.comms.period", "unknown field"]),
        ("driver", "kind", "\"sim\"", &["driver.sim", "required"]),
        ("driver", "kind", "\"hardware\"", &["driver.kind", "unknown variant `hardware`"]),
        ("driver", "scenario", "\"venus\"", &["driver.scenario", "unknown field"]),
        ("driver", "replay_speed", "0.0", &["driver.replay_speed"]),
        ("driver", "duration_s", "-1.0", &["driver.duration_s"]),
        ("imu", "gravity_mps2", "0.0", &["imu.gravity_mps2"]),
        ("imu", "gyro_scale_sigma", "-0.1", &["imu.gyro_scale_sigma"]),
        (
            "imu",
            "noise",
            "{ gyro_noise_density = 0.0, gyro_random_walk = 1.0, accel_noise_density = 1.0, accel_random_walk = 1.0 }",
            &["imu.noise.gyro_noise_density", "positive"],
        ),
        ("vision", "sgm_disparities", "100", &["vision.sgm_disparities", "multiple of 16"]),
        ("markers", "size_m", "0.0", &["markers.size_m"]),
        ("markers", "tags_per_robot", "0", &["markers.tags_per_robot"]),
        ("markers", "tags_per_robot", "2", &["markers.mounting", "3 mountings for 2 tags"]),
        ("markers", "model", "\"gaussian\"", &["markers.model", "unknown variant `gaussian`"]),
        ("vision", "sgm_threads", "0", &["vision.sgm_threads"]),
        ("filter", "vo_updates", "\"sometimes\"", &["filter.vo_updates", "unknown variant"]),
        ("filter", "vo_covariance_scale", "0.0", &["filter.vo_covariance_scale"]),
        ("mapper", "max_position_sigma_m", "5.0", &["mapper.max_position_sigma_m"]),
        ("mapper", "submap_max_distance_m", "0.0", &["mapper.submap_max_distance_m"]),
        ("mapper", "octree_voxel_m", "0.0", &["mapper.octree_voxel_m"]),
        ("mapper", "max_depth_error_m", "0.0", &["mapper.max_depth_error_m"]),
        ("link", "bind", "\"nonsense\"", &["link.bind", "`nonsense`"]),
        ("link", "ground_feed", "\"localhost\"", &["link.ground_feed"]),
        ("link", "kind", "\"pigeon\"", &["link.kind", "unknown variant `pigeon`"]),
        ("link", "kind", "\"serial\"", &["link.serial_device", "required"]),
        ("link", "bandwidth_bytes_per_s", "0", &["link.bandwidth_bytes_per_s"]),
        ("link.peers", "address", "\"rover2\"", &["link.peers[0].address", "`rover2`"]),
        ("link.peers", "robot_id", "0", &["link.peers[0].robot_id", "own id"]),
        ("realtime.filter", "fifo_priority", "0", &["realtime.filter.fifo_priority", "1..=99"]),
        ("realtime.filter", "fifo_priority", "300", &["realtime.filter.fifo_priority", "u8"]),
        ("realtime.vision", "cpu", "4096", &["realtime.vision.cpu"]),
        ("recording", "directory", "\"\"", &[]), // recording disabled: an empty directory is fine
        ("surprise", "x", "1", &["surprise", "unknown field `surprise`"]),
    ];
    for (section, key, value, expected) in cases {
        let text = example_with(section, key, value);
        let result = RoverConfig::from_toml_str(&text);
        if expected.is_empty() {
            assert!(result.is_ok(), "{section}.{key} = {value}: {result:?}");
            continue;
        }
        let message = match result {
            Ok(_) => panic!("{section}.{key} = {value} was accepted"),
            Err(e) => e.to_string(),
        };
        for part in *expected {
            assert!(message.contains(part), "{section}.{key} = {value}: message {message:?} lacks {part:?}");
        }
    }
}

/// A simulated robot: the `[driver.sim]` table is the harness's (passed through untouched), the
/// head's calibration must be given, and a calibration is checked.
#[test]
fn a_simulated_driver_needs_its_world_and_a_calibration() {
    let sim = example_text()
        .replace("kind = \"replay\"", "kind = \"sim\"")
        .replace("replay_path = \"data/euroc/mh_01_handheld\"", "")
        + "\n[driver.sim]\nscenario = \"moon\"\nseed = 7\nrobots = 2\ndownscale = 4\n";
    let err = RoverConfig::from_toml_str(&sim).unwrap_err().to_string();
    assert!(err.contains("camera.calibration") && err.contains("required"), "{err}");
    let calibration_toml = "
[camera.calibration]
rectified = true
baseline_m = 0.09
[camera.calibration.left]
width_px = 256
height_px = 127
intrinsics = { fx_px = 186.3, fy_px = 186.3, cx_px = 127.5, cy_px = 63.0 }
t_body_cam = { translation_m = [0.36, 0.045, 1.05], rotation_wxyz = [0.5, -0.5, 0.5, -0.5] }
[camera.calibration.right]
width_px = 256
height_px = 127
intrinsics = { fx_px = 186.3, fy_px = 186.3, cx_px = 127.5, cy_px = 63.0 }
t_body_cam = { translation_m = [0.36, -0.045, 1.05], rotation_wxyz = [0.5, -0.5, 0.5, -0.5] }
";
    let with_calibration = format!("{sim}{calibration_toml}");
    let c = RoverConfig::from_toml_str(&with_calibration).unwrap();
    assert_eq!(c.driver.kind, DriverKind::Sim);
    let table = c.driver.sim.as_ref().unwrap();
    assert_eq!(table.get("scenario").and_then(|v| v.as_str()), Some("moon"));
    let calibration = c.camera.calibration.unwrap().to_calibration().unwrap();
    assert_eq!((calibration.left.width_px, calibration.baseline_m), (256, 0.09));
    // The serialized form carries the calibration and the simulator's table back unchanged.
    assert_eq!(RoverConfig::from_toml_str(&c.to_toml_string()).unwrap(), c);

    let with = |from: &str, to: &str| format!("{sim}{}", calibration_toml.replacen(from, to, 1));
    let err = RoverConfig::from_toml_str(&with("baseline_m = 0.09", "baseline_m = -0.09")).unwrap_err().to_string();
    assert!(err.contains("camera.calibration") && err.contains("baseline_m"), "{err}");
    let err = RoverConfig::from_toml_str(&with("width_px = 256", "width_px = 300")).unwrap_err().to_string();
    assert!(err.contains("one size"), "{err}");
    let tilted = with("rotation_wxyz = [0.5, -0.5, 0.5, -0.5]", "rotation_wxyz = [1.0, 1.0, 0.0, 0.0]");
    let err = RoverConfig::from_toml_str(&tilted).unwrap_err().to_string();
    assert!(err.contains("unit quaternion"), "{err}");
    // A replay does not take a simulated world.
    let both = with_calibration.replacen("kind = \"sim\"", "kind = \"replay\"\nreplay_path = \"data/x\"", 1);
    let err = RoverConfig::from_toml_str(&both).unwrap_err().to_string();
    assert!(err.contains("driver.sim"), "{err}");
}

#[test]
fn a_syntax_error_gives_a_line() {
    let err = RoverConfig::from_toml_str("[robot]\nid = 0\n[camera\nrate_hz = 1\n").unwrap_err();
    match err {
        ConfigError::Syntax { line, .. } => assert_eq!(line, 3),
        other => panic!("{other}"),
    }
}

proptest! {
    #[test]
    fn arbitrary_text_never_panics(text in "\\PC{0,300}") {
        let _ = RoverConfig::from_toml_str(&text);
    }

    #[test]
    fn tomlish_text_never_panics(text in "(\\[[a-z.]{0,12}\\]\n|[a-z_]{1,12} = (-?[0-9.]{1,6}|\"[a-z:0-9.]{0,12}\"|true)\n){0,30}") {
        let _ = RoverConfig::from_toml_str(&text);
    }

    #[test]
    fn damaged_example_never_panics(position in any::<prop::sample::Index>(), byte in any::<u8>()) {
        let mut bytes = example_text().into_bytes();
        let i = position.index(bytes.len());
        bytes[i] = byte;
        if let Ok(text) = String::from_utf8(bytes) {
            let _ = RoverConfig::from_toml_str(&text);
        }
    }
}
