#![allow(clippy::unwrap_used, clippy::expect_used)]
//! A two-rover Moon run recorded for the multi-robot SLAM evaluation through the firmware's
//! nodes: poses on the camera stamps, frame switches by the mapper's submap rule, accuracy
//! against ground truth, and the on-disk cache.

use std::path::PathBuf;
use std::time::Instant;

use mapper::submap::SubmapPolicy;
use nalgebra::Isometry3;
use sil::team_record::{self, RobotRecord, TeamRecordError, TeamRecordOptions};

const CAMERA_PERIOD_NS: u64 = 100_000_000;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("team_record_{name}_{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

/// The record's own consistency.
fn check_record(record: &RobotRecord, end_ns: u64) {
    let r = record.robot;
    let poses = &record.poses;
    // 10 Hz on the camera grid, from the filter start to the last capture.
    assert!(poses[0].stamp_ns >= record.initialized_ns, "robot {r}");
    assert!(poses[0].stamp_ns < record.initialized_ns + CAMERA_PERIOD_NS, "robot {r}");
    assert!(poses.iter().all(|p| p.stamp_ns % CAMERA_PERIOD_NS == 0), "robot {r}: off the camera grid");
    assert!(poses.windows(2).all(|w| w[1].stamp_ns - w[0].stamp_ns == CAMERA_PERIOD_NS), "robot {r}: gap");
    assert_eq!(poses[poses.len() - 1].stamp_ns, (end_ns - 1) / CAMERA_PERIOD_NS * CAMERA_PERIOD_NS);
    assert_eq!(record.truth.len(), poses.len());
    assert!(record.truth.iter().zip(poses).all(|(t, p)| t.0 == p.stamp_ns));

    // Frame ids: +1 per switch. The filter switches when the mapper's request arrives, right after
    // the state that triggered it, so a pose at the switch's stamp is still in the old frame.
    assert!(!record.switches.is_empty(), "robot {r}: no switch over {:.1} m", record.distance_m);
    assert_eq!(record.summary.frame_switches as usize, record.switches.len());
    for (i, s) in record.switches.iter().enumerate() {
        assert_eq!((s.old_frame_id, s.new_frame_id), (i as u32, i as u32 + 1), "robot {r}");
        // The new frame is levelled at the body: roll and pitch of the transform stay zero.
        let (roll, pitch, _) = s.t_old_new.rotation.euler_angles();
        assert!(roll.abs() < 0.05 && pitch.abs() < 0.05, "robot {r}: switch {i} tilts the frame");
    }
    assert!(record.switches.windows(2).all(|w| w[0].stamp_ns < w[1].stamp_ns));
    for p in poses {
        let frame = record.switches.iter().filter(|s| s.stamp_ns < p.stamp_ns).count();
        assert_eq!(p.frame_id as usize, frame, "robot {r} at {}", p.stamp_ns);
    }

    for p in poses {
        let c = &p.covariance;
        let scale = c.abs().max();
        assert!((c - c.transpose()).abs().max() <= 1e-12 * scale, "robot {r}: asymmetric at {}", p.stamp_ns);
        // Rounding of a ~1e-3 m² matrix: eigenvalues are exact to ~1e-16 × its scale.
        let min_eigenvalue = c.symmetric_eigenvalues().min();
        assert!(min_eigenvalue >= -1e-12 * scale, "robot {r}: eigenvalue {min_eigenvalue} at {}", p.stamp_ns);
    }
}

/// `t_first_body` at every pose: the chained switches up to the pose's stamp, then its local pose.
fn chained(record: &RobotRecord) -> Vec<Isometry3<f64>> {
    record
        .poses
        .iter()
        .map(|p| {
            let t_first_local = record
                .switches
                .iter()
                .filter(|s| s.stamp_ns <= p.stamp_ns)
                .fold(Isometry3::identity(), |acc, s| acc * s.t_old_new);
            t_first_local * p.t_local_body
        })
        .collect()
}

#[test]
fn a_two_rover_moon_team_records_local_poses_switches_and_truth() {
    // 60 s with 1 s stands at downscale 4: the rovers drive 9.0 and 10.7 m (printed), so the
    // early experiments' 3.5 m submaps give 2 and 3 switches.
    let options = TeamRecordOptions {
        robots: 2,
        duration_s: 60.0,
        seed: 3,
        downscale: 4,
        policy: SubmapPolicy::early(),
        use_wheel: true,
        pause_s: Some(1.0),
    };
    let world = team_record::moon_team_world(&options).unwrap();
    let start = Instant::now();
    let records = team_record::record_team(&world, &options).unwrap();
    eprintln!("recorded 2 × {} s in {:.1} s", options.duration_s, start.elapsed().as_secs_f64());
    assert_eq!(records.len(), 2);
    for record in &records {
        let s = &record.summary;
        eprintln!(
            "robot {}: {:.2} m driven, {} poses, {} switches, VO {} applied / {} rejected of {} frames, {} resets",
            record.robot,
            record.distance_m,
            record.poses.len(),
            record.switches.len(),
            s.vo_updates_applied,
            s.vo_updates_rejected,
            s.frames,
            s.vo_resets,
        );
        // The rover really drives and the odometry really tracks at this resolution.
        assert!(record.distance_m > 8.0, "{}", record.distance_m);
        assert!(s.vo_updates_applied as f64 > 0.8 * s.vo_frames as f64, "{s:?}");
        assert!(s.images_integrated as f64 > 0.9 * s.vo_frames as f64, "{s:?}");
        check_record(record, world.end_ns());
    }

    for record in &records {
        let t_first_body = chained(record);

        // Against truth, anchored at the filter start (position and yaw there are the filter's
        // zero by construction). vio_sim's bound: drift within 2 % of the path (issue 7's target
        // is 1 % over 150 m; a short run weighs the levelling at the start more), plus 0.1 m (the
        // early policy's position sigma, what the mapper tolerates within a submap) for the
        // online estimate's transients: it runs 250 ms ahead of its VO updates, and in the first
        // turns the unlevelled heading shows. Measured: at most 0.155 m after 5 m, 0.13 m at the
        // end of 9 m.
        let t_world_first = record.truth[0].1 * t_first_body[0].inverse();
        let mut path_m = 0.0;
        let mut worst = (0.0_f64, 0.0_f64);
        for (k, (truth, est)) in record.truth.iter().zip(&t_first_body).enumerate() {
            if k > 0 {
                path_m += (truth.1.translation.vector - record.truth[k - 1].1.translation.vector).norm();
            }
            let error_m = (truth.1.translation.vector - (t_world_first * est).translation.vector).norm();
            if error_m > worst.0 {
                worst = (error_m, path_m);
            }
            assert!(error_m <= 0.10 + 0.02 * path_m, "robot {}: {error_m:.3} m after {path_m:.2} m", record.robot);
        }
        eprintln!("robot {}: worst error {:.3} m after {:.2} m", record.robot, worst.0, worst.1);
    }

    // The cache gives back the same record, bit for bit.
    let dir = temp_dir("roundtrip");
    team_record::write_team(&dir, &records).unwrap();
    assert_eq!(team_record::read_team(&dir).unwrap(), records);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn malformed_cache_files_are_errors() {
    let record = RobotRecord {
        robot: 1,
        initialized_ns: 500_000_000,
        poses: Vec::new(),
        switches: Vec::new(),
        truth: vec![(500_000_000, Isometry3::translation(1.0, 2.0, 3.0))],
        summary: Default::default(),
        distance_m: 0.0,
    };
    let dir = temp_dir("malformed");
    record.write(&dir).unwrap();
    assert_eq!(RobotRecord::read(&dir).unwrap(), record);
    let truth = dir.join("truth.txt");
    for bad in [
        "500000000 1 2 3 0 0 0\n",                // a field short
        "500000000 1 2 3 0 0 0 2\n",              // not a unit quaternion
        "500000000 1 2 NaN 0 0 0 1\n",            // not finite
        "-5 1 2 3 0 0 0 1\n",                     // negative stamp
        "500000000 1 2 3 0 0 0 1 extra\n",        // a field too many
        "5000000000000000000000 1 2 3 0 0 0 1\n", // stamp out of range
    ] {
        std::fs::write(&truth, bad).unwrap();
        let error = RobotRecord::read(&dir).unwrap_err();
        assert!(matches!(error, TeamRecordError::Parse { line: 1, .. }), "{bad}: {error}");
    }
    std::fs::write(&truth, "500000000 1 2 3 0 0 0 1\n").unwrap();
    let meta = dir.join("meta.txt");
    let text = std::fs::read_to_string(&meta).unwrap();
    std::fs::write(&meta, text.replace("frames 0\n", "")).unwrap();
    assert!(matches!(RobotRecord::read(&dir), Err(TeamRecordError::Parse { .. })));
    std::fs::remove_file(&meta).unwrap();
    assert!(matches!(RobotRecord::read(&dir), Err(TeamRecordError::Io { .. })));
    std::fs::remove_dir_all(&dir).unwrap();
}
