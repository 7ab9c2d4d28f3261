//! `sim record` end to end: determinism of the written trees, the datasets read back through
//! `hal::asl` equal the in-memory simulation event for event, the ground truth and the world
//! files agree with the world, and the CLI's exit codes.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

use hal::asl::AslDataset;
use hal::asl::yaml::Yaml;
use hal::sensor::{SensorEvent, SensorSource, StereoFrame};
use nalgebra::Isometry3;
use sim::robot::RobotKind;
use sim::scenario::{self, ScenarioOptions};
use sim::world::World;

const SIM: &str = env!("CARGO_BIN_EXE_sim");
const SEED: u64 = 7;

fn options(seed: u64) -> ScenarioOptions {
    ScenarioOptions {
        robots: 2,
        duration_s: 3.0,
        seed,
        downscale: 4,
        world_size_m: Some(60.0),
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    }
}

fn fresh_dir(name: &str) -> PathBuf {
    static NEXT: AtomicUsize = AtomicUsize::new(0);
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join(format!(
        "sim-record-{name}-{}-{}",
        std::process::id(),
        NEXT.fetch_add(1, Ordering::Relaxed)
    ));
    let _ = fs::remove_dir_all(&dir);
    dir
}

fn run(args: &[&str]) -> Output {
    Command::new(SIM).args(args).output().unwrap()
}

/// `sim record` of the test scenario into a fresh folder.
fn record(seed: u64, extra: &[&str]) -> PathBuf {
    let out = fresh_dir("run");
    let seed = seed.to_string();
    let mut args = vec!["record", "--scenario", "moon", "--robots", "2", "--duration", "3", "--downscale", "4"];
    args.extend(["--world-size", "60", "--seed", &seed, "--json", "--out", out.to_str().unwrap()]);
    args.extend(extra);
    let output = run(&args);
    assert!(output.status.success(), "sim record failed: {}", String::from_utf8_lossy(&output.stderr));
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert_eq!(report["robots"].as_array().unwrap().len(), 2);
    assert!(report["stereo_pairs"].as_u64().unwrap() > 0);
    out
}

/// The recording every read-back test uses (made once).
fn shared_run() -> &'static Path {
    static RUN: OnceLock<PathBuf> = OnceLock::new();
    RUN.get_or_init(|| record(SEED, &[]))
}

fn shared_world() -> &'static Arc<World> {
    static WORLD: OnceLock<Arc<World>> = OnceLock::new();
    WORLD.get_or_init(|| World::build(&scenario::preset("moon", &options(SEED)).unwrap()).unwrap())
}

/// Relative path → bytes of every file under `root`.
fn tree(root: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut files = BTreeMap::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        for entry in fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.is_dir() {
                stack.push(path);
            } else {
                files.insert(path.strip_prefix(root).unwrap().to_path_buf(), fs::read(&path).unwrap());
            }
        }
    }
    files
}

#[test]
fn same_seed_gives_identical_bytes_and_another_seed_differs() {
    let a = tree(shared_run());
    // One thread instead of all cores: the bytes must not depend on scheduling.
    let b = tree(&record(SEED, &["--threads", "1"]));
    assert!(a.len() > 20, "only {} files", a.len());
    assert_eq!(a.keys().collect::<Vec<_>>(), b.keys().collect::<Vec<_>>(), "different file lists");
    for (path, bytes) in &a {
        assert!(bytes == &b[path], "{} differs between two runs with the same seed", path.display());
    }
    let c = tree(&record(SEED + 1, &[]));
    let image = a.keys().find(|p| p.extension().is_some_and(|e| e == "png")).unwrap();
    assert_ne!(a.get(image), c.get(image), "another seed renders the same first image");
    for file in ["robot0/mav0/imu0/data.csv", "world/terrain.heightgrid", "world/scenario.json"] {
        assert_ne!(a.get(Path::new(file)), c.get(Path::new(file)), "{file} is the same for another seed");
    }
}

/// Pose difference: translation (m) and rotation angle (rad).
fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
    ((a.translation.vector - b.translation.vector).norm(), a.rotation.angle_to(&b.rotation))
}

/// Replays robot `robot`'s dataset in `dir` next to the simulation's own source and checks that
/// every event, image, ground-truth row and the calibration agree; returns the counts of IMU,
/// wheel and stereo events.
fn assert_reads_back(world: &Arc<World>, robot: usize, dir: &Path) -> [usize; 3] {
    let mut dataset = AslDataset::open(dir).unwrap();
    let mut source = sim::driver::SimSensorSource::new(Arc::clone(world), robot).unwrap();
    let gt_text = fs::read_to_string(dir.join("mav0/state_groundtruth_estimate0/data.csv")).unwrap();
    let mut gt_rows = gt_text.lines().filter(|l| !l.starts_with('#'));

    let (mut expected, mut actual) = (StereoFrame::default(), StereoFrame::default());
    let mut counts = [0usize; 3];
    loop {
        let e = hal::sensor::next_event_with_frame(&mut source, &mut expected).unwrap();
        let a = hal::sensor::next_event_with_frame(&mut dataset, &mut actual).unwrap();
        assert_eq!(e, a, "robot {robot}: event {counts:?} differs");
        match e {
            None => break,
            Some(SensorEvent::Stereo(_)) => {
                counts[2] += 1;
                assert!(expected == actual, "robot {robot}: stereo frame {} differs", expected.stamp_ns);
            }
            Some(SensorEvent::Imu(sample)) => {
                counts[0] += 1;
                // The ground-truth row of this IMU stamp holds every state the simulator knows.
                let truth = source.ground_truth(sample.stamp_ns).unwrap();
                let row: Vec<f64> = gt_rows.next().unwrap().split(',').map(|v| v.parse().unwrap()).collect();
                let q = truth.state.t_world_body.rotation.quaternion();
                let p = truth.state.t_world_body.translation.vector;
                let (v, bg, ba) = (truth.state.v_world_mps, truth.gyro_bias_radps, truth.accel_bias_mps2);
                let expected_row =
                    [p.x, p.y, p.z, q.w, q.i, q.j, q.k, v.x, v.y, v.z, bg.x, bg.y, bg.z, ba.x, ba.y, ba.z];
                assert_eq!(row[0], sample.stamp_ns as f64);
                assert_eq!(&row[1..], &expected_row, "ground truth at {}", sample.stamp_ns);
            }
            Some(SensorEvent::WheelOdom(_)) => counts[1] += 1,
        }
    }
    assert!(gt_rows.next().is_none(), "more ground-truth rows than IMU samples");
    assert_eq!(dataset.unmatched_frames(), 0);

    // Calibration: the same rectified pinhole pair; the head at rest in the reader's
    // calibration (via pantilt0/sensor.yaml), the fixed tilt in the cameras' own T_BS.
    let (sim_cal, read_cal) = (source.stereo_calibration().unwrap(), dataset.stereo_calibration().unwrap());
    assert!(read_cal.rectified && sim_cal.rectified);
    assert_eq!(read_cal.left.intrinsics, sim_cal.left.intrinsics);
    assert_eq!((read_cal.left.width_px, read_cal.left.height_px), (sim_cal.left.width_px, sim_cal.left.height_px));
    assert!((read_cal.baseline_m - sim_cal.baseline_m).abs() < 1e-12);
    let model = world.robots[robot].model();
    let (dt, dr) = pose_error(&read_cal.left.t_body_cam, &model.t_body_cam(0.0, 0.0));
    assert!(dt < 1e-12 && dr < 1e-12, "t_body_cam at rest off by {dt} m, {dr} rad");
    assert_eq!(read_cal.head.is_some(), model.head.is_some());
    assert_eq!(sim_cal.head, model.head);
    // Both calibrations turn any head angles into the simulator's camera pose.
    for (pan, tilt) in [(0.0, 0.0), (0.4, 0.25), (-2.0, -0.3), (3.0, 1.2)] {
        for cal in [&sim_cal, &read_cal] {
            let (dt, dr) = pose_error(&cal.t_body_left(pan, tilt), &model.t_body_cam(pan, tilt));
            assert!(dt < 1e-12 && dr < 1e-12, "t_body_left({pan}, {tilt}) off by {dt} m, {dr} rad");
        }
    }
    let yaml_path = dir.join("mav0/cam0/sensor.yaml");
    let yaml = Yaml::parse(&fs::read(&yaml_path).unwrap(), &yaml_path).unwrap();
    let t_bs = hal::asl::read_transform(&yaml, "T_BS").unwrap().unwrap();
    let (dt, dr) = pose_error(&t_bs, &model.t_body_cam(0.0, world.robots[robot].setup.tilt_rad));
    assert!(dt < 1e-12 && dr < 1e-12, "cam0 T_BS off by {dt} m, {dr} rad");
    counts
}

#[test]
fn datasets_read_back_as_the_in_memory_simulation() {
    let world = shared_world();
    for robot in 0..2 {
        let counts =
            assert_reads_back(world, robot, &shared_run().join(format!("robot{}", world.robots[robot].setup.id)));
        assert!(counts.iter().all(|&n| n > 0), "robot {robot}: {counts:?}");
    }
}

#[test]
fn a_flyer_dataset_has_no_head_and_no_wheels() {
    let options = ScenarioOptions { robots: 1, duration_s: 1.0, flyer: true, ..options(SEED) };
    let world = World::build(&scenario::preset("mars", &options).unwrap()).unwrap();
    let flyer = world.robots.iter().position(|r| r.model().kind == RobotKind::Flyer).unwrap();
    let dir = fresh_dir("flyer");
    let mut stamps = Vec::new();
    let stats = sim::asl::record_robot(&world, flyer, &dir, |stamp| stamps.push(stamp)).unwrap();
    assert!(!dir.join("mav0/wheel0").exists() && !dir.join("mav0/pantilt0").exists());
    let counts = assert_reads_back(&world, flyer, &dir);
    assert_eq!(counts[1], 0);
    assert_eq!(
        [stats.imu_samples, stats.wheel_samples, stats.stereo_pairs, stats.ground_truth_rows],
        [counts[0] as u64, 0, counts[2] as u64, counts[0] as u64]
    );
    assert_eq!(stamps.len(), counts[2], "progress once per stereo pair");
}

#[test]
fn ground_truth_files_parse_and_follow_the_trajectory() {
    let world = shared_world();
    let dir = shared_run().join(format!("robot{}", world.robots[0].setup.id));
    let dataset = AslDataset::open(&dir).unwrap();

    let euroc =
        eval::io::parse_euroc(&fs::read_to_string(dir.join("mav0/state_groundtruth_estimate0/data.csv")).unwrap())
            .unwrap();
    assert_eq!(euroc.poses.len(), dataset.imu_samples().len());
    for (pose, sample) in euroc.poses.iter().zip(dataset.imu_samples()) {
        let state = world.robot_state(0, sample.stamp_ns).unwrap();
        // Round-trip printing: only the quaternion's renormalisation in the reader differs.
        let (dt, dr) = pose_error(pose, &state.t_world_body);
        assert!(dt < 1e-12 && dr < 1e-9, "EuRoC ground truth at {} off by {dt} m, {dr} rad", sample.stamp_ns);
    }

    let tum = eval::io::parse_tum(&fs::read_to_string(dir.join("groundtruth.tum")).unwrap()).unwrap();
    assert_eq!(tum.poses.len(), dataset.pairs().len());
    for ((pose, stamp_s), pair) in tum.poses.iter().zip(&tum.stamps_s).zip(dataset.pairs()) {
        assert!((stamp_s - pair.stamp_ns as f64 / 1e9).abs() < 1e-12, "TUM stamp {stamp_s}");
        let state = world.robot_state(0, pair.stamp_ns).unwrap();
        let (dt, dr) = pose_error(pose, &state.t_world_body);
        assert!(dt < 1e-12 && dr < 1e-9, "TUM pose at {} off by {dt} m, {dr} rad", pair.stamp_ns);
    }
}

#[test]
fn world_files_agree_with_the_terrain() {
    let world = shared_world();
    let dir = shared_run().join("world");
    let grid = eval::map::HeightGrid::parse(&fs::read_to_string(dir.join("terrain.heightgrid")).unwrap()).unwrap();
    let hf = &world.terrain.heightfield;
    assert!((grid.resolution_m - 2.0 * hf.resolution_m).abs() < 1e-12, "every 2nd cell: {}", grid.resolution_m);
    for row in 0..grid.rows {
        for col in 0..grid.cols {
            let centre = grid.cell_centre_m(col, row);
            let c = (centre.x - hf.origin_m[0]) / hf.resolution_m;
            let r = (centre.y - hf.origin_m[1]) / hf.resolution_m;
            assert!((c - c.round()).abs() < 1e-6 && (r - r.round()).abs() < 1e-6, "cell ({col}, {row}) off-grid");
            let expected = hf.height_at_cell(c.round() as isize, r.round() as isize);
            let height = grid.heights_m[row * grid.cols + col];
            // The terrain prints heights to the millimetre: half a millimetre of rounding.
            assert!((height - expected).abs() <= 0.0005 + 1e-6, "cell ({col}, {row}): {height} vs {expected}");
        }
    }
    // The grid covers the paths with the 10 m margin, as far as the site reaches.
    let (lo, hi) = sim::asl::path_bounds(world).unwrap();
    let site_max = [
        hf.origin_m[0] + (hf.cols - 1) as f64 * hf.resolution_m,
        hf.origin_m[1] + (hf.rows - 1) as f64 * hf.resolution_m,
    ];
    let last = grid.cell_centre_m(grid.cols - 1, grid.rows - 1);
    let slack = grid.resolution_m + 1e-9;
    assert!(grid.origin_m.0 <= (lo[0] - 10.0).max(hf.origin_m[0]) + slack);
    assert!(grid.origin_m.1 <= (lo[1] - 10.0).max(hf.origin_m[1]) + slack);
    assert!(last.x >= (hi[0] + 10.0).min(site_max[0]) - slack);
    assert!(last.y >= (hi[1] + 10.0).min(site_max[1]) - slack);

    let rocks = fs::read_to_string(dir.join("rocks.csv")).unwrap();
    let rows: Vec<Vec<f64>> = rocks
        .lines()
        .filter(|l| !l.starts_with('#'))
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), world.terrain.rocks.len());
    for (row, rock) in rows.iter().zip(&world.terrain.rocks) {
        assert_eq!(
            row,
            &[f64::from(rock.id), rock.base_m.x, rock.base_m.y, rock.base_m.z, rock.radius_m, rock.height_m]
        );
    }
    let markers = fs::read_to_string(dir.join("markers.csv")).unwrap();
    let marker_count: usize = world.robots.iter().map(|r| r.model().markers.len()).sum();
    assert_eq!(markers.lines().filter(|l| !l.starts_with('#')).count(), marker_count);

    let scenario: serde_json::Value =
        serde_json::from_str(&fs::read_to_string(dir.join("scenario.json")).unwrap()).unwrap();
    assert_eq!(scenario["seed"], SEED);
    assert_eq!(scenario["name"], world.scenario.name.as_str());
    assert_eq!(scenario["robots"].as_array().unwrap().len(), 2);
    assert_eq!(scenario["gravity_mps2"].as_f64().unwrap(), world.scenario.body.gravity_mps2());
}

#[test]
fn pictures_of_a_small_world() {
    let world = shared_world();
    let out = fresh_dir("pictures");
    let options = sim::pictures::PictureOptions { width: 128, stamp_s: 1.0, ..Default::default() };
    let pictures = sim::pictures::preset_pictures(world, "test", &out, &options).unwrap();
    assert_eq!(pictures.len(), 3);
    for picture in &pictures {
        let bytes = fs::read(&picture.path).unwrap();
        assert_eq!(bytes.len() as u64, picture.bytes);
        let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
        let info = decoder.read_info().unwrap().info().clone();
        assert_eq!((info.width, info.height), (picture.width, picture.height));
        assert_eq!(info.width, 128);
    }
}

#[test]
fn usage_errors_exit_2_and_runtime_errors_exit_1() {
    let out = fresh_dir("usage");
    let out = out.to_str().unwrap();
    let usage_cases: &[&[&str]] = &[
        &[],
        &["fly"],
        &["record", "--out", out],
        &["record", "--scenario", "moon"],
        &["record", "--scenario", "pluto", "--out", out],
        &["record", "--scenario", "moon", "--out", out, "--robots", "two"],
        &["record", "--scenario", "moon", "--out", out, "--robots", "0"],
        &["record", "--scenario", "moon", "--out", out, "--duration", "-1"],
        &["record", "--scenario", "moon", "--out", out, "--downscale", "0"],
        &["record", "--scenario", "moon", "--out", out, "--colour"],
        // An experiment is for two robots.
        &["record", "--scenario", "loops", "--out", out, "--robots", "3"],
        &["pictures"],
        &["pictures", "--out", out, "--width", "3"],
    ];
    for args in usage_cases {
        let output = run(args);
        assert_eq!(output.status.code(), Some(2), "sim {args:?}: {}", String::from_utf8_lossy(&output.stderr));
        assert!(!output.stderr.is_empty(), "sim {args:?} says nothing");
    }
    assert!(!Path::new(out).exists(), "a usage error wrote files");
    assert_eq!(run(&["help"]).status.code(), Some(0));
    let unknown = run(&["record", "--scenario", "pluto", "--out", out]);
    let message = String::from_utf8_lossy(&unknown.stderr);
    assert!(message.contains("moon") && message.contains("leave-reenter"), "{message}");

    // Recording over an existing recording would mix two runs' files: refused before any work.
    let existing = shared_run().to_str().unwrap();
    let output = run(&["record", "--scenario", "moon", "--duration", "1", "--out", existing]);
    assert_eq!(output.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&output.stderr).contains("already exists"));
}
