//! The firmware on real data as separate processes: `onboard run --config` with a replay driver
//! on EuRoC MH_01 (raw stereo, no IMU samples) starts the driver, vision, filter, mapper and comms
//! processes over iceoryx2, and the estimate and map it writes are those of the lockstep runner
//! (`onboard vio`'s code) on the same data: the same nodes, so with every frame processed the
//! same numbers.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use nix::sys::signal::{Signal, kill};
use nix::unistd::Pid;
use onboard::config::{DriverKind, LinkKind, RoverConfig};

const MH01: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/euroc/mh_01_handheld");
/// The first 2 s of the 4.2 s excerpt (41 pairs, both ends included), at a tenth of the recorded pace: vision's SGM
/// and odometry on one loaded core of this 2-core machine must not drop a pair, or the two
/// runners would see different data.
const DURATION_S: f64 = 2.0;
const REPLAY_SPEED: f64 = 0.1;

fn config(dir: &Path) -> RoverConfig {
    let mut config = RoverConfig::default();
    config.robot.name = "replay".into();
    config.robot.bus_id = Some(30_000 + (std::process::id() % 5_000) as u16);
    config.robot.output_dir = Some(dir.to_owned());
    config.driver.kind = DriverKind::Replay;
    config.driver.replay_path = Some(PathBuf::from(MH01));
    config.driver.replay_speed = REPLAY_SPEED;
    config.driver.duration_s = Some(DURATION_S);
    config.link.kind = LinkKind::None;
    config.validate().unwrap();
    config
}

/// `(stamp_ns, [x, y, z])` rows of a TUM file in sensor time.
fn read_positions(path: &Path) -> Vec<(u64, [f64; 3])> {
    std::fs::read_to_string(path)
        .unwrap()
        .lines()
        .map(|line| {
            let f: Vec<&str> = line.split_whitespace().collect();
            let (s, ns) = f[0].split_once('.').unwrap();
            let stamp_ns = s.parse::<u64>().unwrap() * 1_000_000_000 + ns.parse::<u64>().unwrap();
            (stamp_ns, [f[1].parse().unwrap(), f[2].parse().unwrap(), f[3].parse().unwrap()])
        })
        .collect()
}

fn json(path: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

#[test]
fn the_process_runner_replays_a_dataset_like_the_lockstep_runner() {
    let dir = std::env::temp_dir().join(format!("onboard-replay-run-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let config = config(&dir);
    let path = dir.join("rover.toml");
    std::fs::write(&path, config.to_toml_string()).unwrap();

    let mut supervisor =
        Command::new(env!("CARGO_BIN_EXE_onboard")).args(["run", "--config"]).arg(&path).spawn().unwrap();
    let started = Instant::now();
    let ready = |kind: &str| dir.join("ready").join(kind).exists();
    while !["driver", "vision", "filter", "mapper", "comms"].iter().all(|k| ready(k)) {
        assert!(started.elapsed() < Duration::from_secs(60), "the processes did not get ready");
        assert!(supervisor.try_wait().unwrap().is_none(), "the supervisor exited during set-up");
        std::thread::sleep(Duration::from_millis(50));
    }
    // The supervisor starts sensor time 3 s after its own start; the replay then takes
    // duration / speed, and the last result a moment to cross vision, filter and mapper.
    let replay = Duration::from_secs_f64(DURATION_S / REPLAY_SPEED);
    while started.elapsed() < Duration::from_secs(3) + replay + Duration::from_secs(4) {
        std::thread::sleep(Duration::from_millis(100));
    }
    kill(Pid::from_raw(supervisor.id() as i32), Signal::SIGTERM).unwrap();
    assert!(supervisor.wait().unwrap().success());

    // Every pair was published and processed.
    let driver = json(&dir.join("tasks/driver.json"));
    let vision = json(&dir.join("tasks/vision.json"));
    let mapper = json(&dir.join("mapper_status.json"));
    let published = driver["node"]["stereo"].as_u64().unwrap();
    assert_eq!(published, 41, "{driver}");
    assert_eq!(driver["node"]["finished"], true);
    assert_eq!(driver["node"]["time_offset_ns"], 1_403_636_593_013_555_456_u64);
    assert_eq!(vision["node"]["frames"].as_u64().unwrap(), published, "vision dropped pairs: {vision}");
    assert_eq!(mapper["images_integrated"].as_u64().unwrap(), published, "{mapper}");
    for name in ["map.ply", "map.bt", "graph.g2o", "estimate.tum"] {
        assert!(dir.join(name).exists(), "{name} missing");
    }
    let process = read_positions(&dir.join("estimate.tum"));

    // The same configuration on the lockstep runner (`onboard vio`'s path).
    let lockstep = onboard::vio::run_dataset(&config, false).unwrap();
    assert_eq!(lockstep.estimate.len(), process.len());
    let mut worst_m = 0.0_f64;
    for ((s_l, pose), (s_p, p)) in lockstep.estimate.iter().zip(&process) {
        assert_eq!(s_l, s_p);
        let d = pose.translation.vector - nalgebra::Vector3::from(*p);
        worst_m = worst_m.max(d.norm());
    }
    eprintln!("{} poses; largest difference between the runners {worst_m:.2e} m", process.len());
    // The TUM text carries shortest round-trip floats: the same poses to the last bit.
    assert!(worst_m == 0.0, "{worst_m} m");
    std::fs::remove_dir_all(&dir).ok();
}
