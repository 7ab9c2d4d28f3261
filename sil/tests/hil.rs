//! Hardware in the loop (issue 29): a 2-robot mission in which each robot's unmodified firmware
//! (`driver.kind = "devices"`) reads its IMU from an emulated Xsens MTi-10 on a pseudo-terminal
//! and its wheels and head over CANopen behind an emulated SLCAN adapter on a second one. Robot
//! index 1 goes through every bus fault in turn; robot index 0 runs undisturbed as the control.
//! One mission for all faults keeps the test within the machine's budget; each fault is asserted
//! on its own evidence (the driver's log and device counters, the filter's gap counters).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::Path;

use onboard::process::{NodeKind, read_json};
use serde_json::Value;
use sil::mission::hil::{DeviceFault, DeviceFaultEvent};
use sil::mission::process::{read_tum, robot_dir, run_mission_with_exe};
use sil::mission::{MissionOptions, Runner};

const DURATION_S: f64 = 40.0;

fn fault(fault: DeviceFault, at_s: f64, for_s: f64) -> DeviceFaultEvent {
    DeviceFaultEvent { robot: 1, fault, at_s, for_s }
}

fn count(log: &str, needle: &str) -> usize {
    log.lines().filter(|l| l.contains(needle)).count()
}

/// Seconds within `[0, end_s)` that any device was logged unavailable, from a driver's device log.
fn unavailable_time(driver: &Value, end_s: f64) -> f64 {
    let mut down_since: std::collections::BTreeMap<String, f64> = std::collections::BTreeMap::new();
    let mut total = 0.0;
    for entry in driver["device_log"].as_array().unwrap() {
        let (t_s, event) = (entry["t_s"].as_f64().unwrap(), entry["event"].as_str().unwrap());
        let device = event.split_whitespace().next().unwrap_or_default().to_owned();
        if event.contains(" unavailable") && t_s < end_s {
            down_since.entry(device).or_insert(t_s);
        } else if event.ends_with(" available")
            && let Some(since) = down_since.remove(&device)
        {
            total += t_s.min(end_s) - since;
        }
    }
    total + down_since.values().map(|since| (end_s - since).max(0.0)).sum::<f64>()
}

#[test]
fn the_firmware_runs_on_emulated_devices_and_survives_every_bus_fault() {
    let out = std::env::temp_dir().join(format!("onboard-hil-{}", std::process::id()));
    let options = MissionOptions {
        robots: 2,
        duration_s: DURATION_S,
        seed: 3,
        downscale: 4,
        out: out.clone(),
        runner: Runner::Process,
        hil: true,
        device_faults: vec![
            fault(DeviceFault::ImuUnplugged, 10.0, 2.0),
            fault(DeviceFault::ImuNoise, 16.0, 3.0),
            fault(DeviceFault::DriveSilent(1), 21.0, 2.0),
            fault(DeviceFault::SyncLost, 26.0, 2.0),
            fault(DeviceFault::Babbling, 31.0, 2.0),
        ],
        ..MissionOptions::default()
    };
    let report = run_mission_with_exe(&options, Path::new(env!("CARGO_BIN_EXE_sil"))).unwrap();
    assert_eq!(report.runner, "hil");

    // Both robots ran on their devices and were scored; nothing restarted.
    for (index, r) in report.robots.iter().enumerate() {
        let score = r.score.as_ref().unwrap_or_else(|| panic!("robot {} not scored: {:?}", r.robot, r.score_error));
        println!(
            "robot {index}: mean error {:.3} m, max {:.3} m over {:.1} m",
            score.mean_error_m, score.max_error_m, score.distance_m
        );
        assert!(score.mean_error_m < 0.5, "robot {index}: {score:?}");
        let supervisor = read_json(&robot_dir(&out, index).join("supervisor.json")).unwrap();
        for kind in NodeKind::ALL {
            let record =
                supervisor["processes"].as_array().unwrap().iter().find(|p| p["process"] == kind.name()).unwrap();
            assert_eq!(record["restarts"], 0, "robot {index}: {record}");
            assert_eq!(record["exits"], serde_json::json!(["exit 0"]), "robot {index}: {record}");
        }
    }
    let rover: Value =
        toml::from_str::<toml::Value>(&std::fs::read_to_string(robot_dir(&out, 1).join("rover.toml")).unwrap())
            .map(|v| serde_json::to_value(v).unwrap())
            .unwrap();
    assert_eq!(rover["driver"]["kind"], "devices");
    assert!(rover["driver"]["devices"]["can_interface"].as_str().unwrap().starts_with("slcan:"));

    let driver =
        |index: usize| read_json(&robot_dir(&out, index).join("tasks").join("driver.json")).unwrap()["node"].clone();
    let filter = |index: usize| read_json(&robot_dir(&out, index).join("filter_summary.json")).unwrap();
    let log = |index: usize| std::fs::read_to_string(robot_dir(&out, index).join("logs").join("driver.log")).unwrap();

    // The control robot: every sample of its devices, none lost, no outage.
    let control = driver(0);
    println!("control driver: {control}");
    let imu = control["imu"].as_u64().unwrap() as f64;
    assert!((imu - 200.0 * DURATION_S).abs() < 40.0, "{control}");
    let wheel = control["wheel"].as_u64().unwrap() as f64;
    assert!((wheel - 50.0 * DURATION_S).abs() < 25.0, "{control}");
    assert_eq!(control["devices"]["imu"]["errors"], 0);
    // No outage of the control robot's devices beyond a starved moment: a loaded 2-core machine
    // (the test suite, the other robot, the emulators) can hold a SYNC cycle past the 300 ms
    // limit, but nothing stays unavailable.
    let unavailable_s = unavailable_time(&control, 40.0);
    println!("control robot: devices unavailable for {unavailable_s:.3} s in total");
    assert!(unavailable_s < 1.0, "{control}");
    assert_eq!(filter(0)["imu_stream_gaps"], 0);

    // The faulty robot, fault by fault.
    let faulty = driver(1);
    let text = log(1);
    println!(
        "faulty driver: {faulty}\nfiltered log:\n{}",
        text.lines().filter(|l| l.starts_with("driver:")).collect::<Vec<_>>().join("\n")
    );
    let records = read_json(&out.join("device_faults.json")).unwrap();
    assert_eq!(records.as_array().unwrap().len(), 10, "{records}");

    // Every device change in sensor time, as the driver recorded it.
    let device_log: Vec<(f64, String)> = faulty["device_log"]
        .as_array()
        .unwrap()
        .iter()
        .map(|e| (e["t_s"].as_f64().unwrap(), e["event"].as_str().unwrap().to_owned()))
        .collect();
    for (t_s, event) in &device_log {
        println!("  {t_s:8.3} s  {event}");
    }
    // The first time `needle` was logged in [from_s, to_s).
    let logged = |needle: &str, from_s: f64, to_s: f64| {
        device_log.iter().find(|(t, e)| *t >= from_s && *t < to_s && e.contains(needle)).map(|(t, _)| *t)
    };

    // Unplugged IMU (10–12 s): lost within 0.3 s, back within 1 s of the replug (reopen period
    // 0.2 s plus the configuration handshake).
    let lost_s = logged("IMU unavailable", 10.0, 12.0).expect("the unplugged IMU was not reported");
    assert!(lost_s - 10.0 < 0.3, "IMU reported lost {:.3} s after the unplug", lost_s - 10.0);
    let back_s = logged("IMU available", 12.0, 16.0).expect("the IMU did not come back");
    println!("IMU: lost after {:.3} s, back {:.3} s after the replug", lost_s - 10.0, back_s - 12.0);
    assert!(back_s - 12.0 < 1.0);
    // The silent drive (21–23 s): the SYNC cycles stop completing and its heartbeat times out
    // (both after 300 ms: the wheels are unavailable, the node is lost), it boots again and the
    // wheels are back.
    let lost_s = logged("wheels unavailable", 21.0, 23.0).expect("the silent drive was not reported");
    let node_lost_s = logged("NodeLost", 21.0, 23.0).expect("the drive's heartbeat did not time out");
    let back_s = logged("wheels available", 23.0, 26.0).expect("the wheels did not come back");
    println!(
        "wheels: lost after {:.3} s (heartbeat timeout after {:.3} s), back {:.3} s after the drive resumed",
        lost_s - 21.0,
        node_lost_s - 21.0,
        back_s - 23.0
    );
    // 300 ms after the drive's last heartbeat, which came 0–100 ms (its period) before it fell
    // silent.
    assert!((0.19..0.45).contains(&(lost_s - 21.0)));
    assert!((0.19..0.45).contains(&(node_lost_s - 21.0)));
    assert!(back_s - 23.0 < 0.5);
    // Lost SYNC (26–28 s): the wheels report no cycle after 0.3 s and are back after it.
    let lost_s = logged("wheels unavailable", 26.0, 28.0).expect("the lost SYNC was not reported");
    let back_s = logged("wheels available", 28.0, 31.0).expect("the wheels did not come back after SYNC");
    println!("SYNC: wheels lost after {:.3} s, back {:.3} s after SYNC returned", lost_s - 26.0, back_s - 28.0);
    assert!((0.25..0.6).contains(&(lost_s - 26.0)) && back_s - 28.0 < 0.2);
    // The babbling node (31–33 s) costs no device.
    assert!(logged("unavailable", 31.0, 33.0).is_none(), "a device was lost to the babbling node");

    // What the ground saw: the faulty robot's telemetry (decoded from the recorded ground link)
    // says its IMU was unavailable during the unplug and its wheels during the silent drive, and
    // both were back afterwards.
    let feed = hal::feedlog::read_feed_log(out.join("ground_feed.log")).unwrap();
    let sensors: Vec<(f64, protocol::message::SensorAvailability)> = feed
        .records
        .iter()
        .filter_map(|r| match protocol::decode(&r.packet).ok()?.message {
            protocol::AnyMessage::Telemetry(t) if t.robot == protocol::RobotId(2) => {
                Some((t.stamp_ns as f64 * 1e-9, t.sensors?))
            }
            _ => None,
        })
        .collect();
    println!(
        "robot 2's telemetry, devices: {:?}",
        sensors.iter().map(|(t, s)| (format!("{t:.1}"), s.imu, s.wheels, s.head)).collect::<Vec<_>>()
    );
    let reported = |from: f64, to: f64, f: &dyn Fn(&protocol::message::SensorAvailability) -> bool| {
        sensors.iter().any(|(t, s)| *t >= from && *t < to && f(s))
    };
    assert!(reported(10.0, 13.5, &|s| !s.imu), "no telemetry showed the unplugged IMU");
    assert!(reported(13.5, 21.0, &|s| s.imu), "no telemetry showed the IMU back");
    assert!(reported(21.0, 24.5, &|s| !s.wheels), "no telemetry showed the silent drive");
    assert!(reported(24.5, 26.0, &|s| s.wheels), "no telemetry showed the wheels back");

    // Unplugged IMU: logged, counted, the filter bridged the outage and the IMU came back.
    assert!(count(&text, "IMU unavailable") >= 1);
    assert!(count(&text, "IMU available") >= 1);
    let summary = filter(1);
    println!("faulty filter: {summary}");
    assert!(summary["imu_stream_gaps"].as_u64().unwrap() >= 1, "{summary}");
    let gap_s = summary["imu_gap_max_ns"].as_u64().unwrap() as f64 * 1e-9;
    assert!((2.0..3.5).contains(&gap_s), "longest IMU gap {gap_s} s for a 2 s unplug");
    // Noise on the line: checksum errors counted, samples still delivered.
    assert!(faulty["devices"]["imu"]["errors"].as_u64().unwrap() > 50, "{faulty}");
    let imu = faulty["imu"].as_u64().unwrap() as f64;
    assert!(imu > 200.0 * (DURATION_S - 2.0 - 3.0), "{faulty}");
    // The silent drive: its heartbeat timed out, the wheels came back; SYNC lost and babbling
    // cost cycles but never the process.
    assert!(count(&text, "NodeLost") >= 1, "no drive was reported lost");
    assert!(count(&text, "wheels unavailable") >= 1);
    assert!(faulty["devices"]["wheels"]["dropouts"].as_u64().unwrap() >= 1);
    let wheel = faulty["wheel"].as_u64().unwrap() as f64;
    assert!(wheel > 50.0 * (DURATION_S - 2.0 - 2.0 - 2.0) - 50.0, "{faulty}");
    assert_eq!(faulty["devices"]["wheels"]["available"], true, "the wheels did not come back: {faulty}");

    // The estimate's error through each fault: before, during, after (3 s), robot 1 against the
    // control robot 0 over the same windows.
    let errors = |index: usize| {
        let dir = robot_dir(&out, index);
        let estimate = read_tum(&dir.join("estimate.tum")).unwrap();
        let truth: std::collections::BTreeMap<u64, nalgebra::Isometry3<f64>> =
            read_tum(&dir.join("truth.tum")).unwrap().into_iter().collect();
        estimate
            .iter()
            .filter_map(|(stamp, pose)| {
                let (_, t) = truth.range(stamp.saturating_sub(1_000)..=stamp + 1_000).next()?;
                Some((*stamp as f64 * 1e-9, (pose.translation.vector - t.translation.vector).norm()))
            })
            .collect::<Vec<_>>()
    };
    let (faulty_errors, control_errors) = (errors(1), errors(0));
    let max_in = |e: &[(f64, f64)], from: f64, to: f64| {
        e.iter().filter(|(t, _)| *t >= from && *t < to).map(|(_, e)| *e).fold(0.0, f64::max)
    };
    for f in &options.device_faults {
        let (start, end) = (f.at_s, f.at_s + f.for_s);
        let windows = [(start - 2.0, start), (start, end), (end, end + 3.0)];
        let faulty: Vec<f64> = windows.iter().map(|(a, b)| max_in(&faulty_errors, *a, *b)).collect();
        let control: Vec<f64> = windows.iter().map(|(a, b)| max_in(&control_errors, *a, *b)).collect();
        println!(
            "{:<14} max error before / during / after: {:.3} / {:.3} / {:.3} m (control {:.3} / {:.3} / {:.3} m)",
            f.fault.name(),
            faulty[0],
            faulty[1],
            faulty[2],
            control[0],
            control[1],
            control[2]
        );
        // Through every fault the estimate stays usable: no jump beyond 0.3 m over its error before.
        assert!(faulty[1].max(faulty[2]) < faulty[0] + 0.3, "{}: {faulty:?}", f.fault.name());
    }
}
