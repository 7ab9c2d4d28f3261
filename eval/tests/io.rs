//! Trajectory readers and writers: the real files, round trips, format detection, errors with
//! line numbers, the command line's exit codes, and totality (no input makes a reader panic).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::process::Command;

use eval::Trajectory;
use eval::io::{self, Format, ParseErrorKind};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data");

fn read(relative: &str) -> String {
    std::fs::read_to_string(format!("{DATA}/{relative}")).unwrap()
}

#[test]
fn reads_evo_v102_estimate() {
    let text = read("trajectories/V102.txt");
    assert_eq!(io::detect_format(&text).unwrap(), Format::Tum);
    let trajectory = io::parse_tum(&text).unwrap();
    assert_eq!(trajectory.len(), 807);
    // The file repeats four stamps; they are kept, as evo keeps them.
    assert_eq!(io::repeated_stamps(&trajectory), 4);
    assert_eq!(trajectory.stamps_s[0], "1.403715529112143517e+09".parse::<f64>().unwrap());
    let p = trajectory.poses[0].translation.vector;
    assert_eq!((p.x, p.y, p.z), (-6.151e-2, 4.838e-2, 1.7712e-1));
    // qx qy qz qw = 0.81321 -0.0273 0.58066 0.02779 (norm 0.99999…, hence normalized).
    let q = trajectory.poses[0].rotation;
    let expected = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(0.02779, 0.81321, -0.0273, 0.58066));
    assert!(q.angle_to(&expected) < 1e-12);
}

#[test]
fn reads_euroc_ground_truth_csv() {
    let text = read("trajectories/V102_groundtruth.csv");
    assert_eq!(io::detect_format(&text).unwrap(), Format::Euroc);
    let trajectory = io::parse_euroc(&text).unwrap();
    assert_eq!(trajectory.len(), 16_702);
    assert_eq!(io::repeated_stamps(&trajectory), 0);
    // 1403715524907143168 ns, converted as evo does.
    assert_eq!(trajectory.stamps_s[0], 1403715524907143168.0 / 1e9);
    assert!((trajectory.stamps_s[1] - trajectory.stamps_s[0] - 0.005).abs() < 1e-6, "200 Hz");
    let p = trajectory.poses[0].translation.vector;
    assert_eq!((p.x, p.y, p.z), (0.515356, 1.996773, 0.971104));
    // q_RS_w, x, y, z = 0.161996, 0.789985, -0.205376, 0.554528: w comes first in EuRoC.
    let q = trajectory.poses[0].rotation.quaternion();
    assert!((q.w - 0.161996).abs() < 1e-5 && (q.i - 0.789985).abs() < 1e-5);
}

#[test]
fn reads_evo_v101_tum_files() {
    let gt_text = read("euroc/v1_01_excerpt/groundtruth_from_evo/V101_gt_tum.txt");
    let est_text = read("euroc/v1_01_excerpt/groundtruth_from_evo/V101_openvins_estimate_tum.txt");
    // The ground truth starts with a `# timestamp(s) tx ty …` header line.
    assert_eq!(io::detect_format(&gt_text).unwrap(), Format::Tum);
    assert_eq!(io::detect_format(&est_text).unwrap(), Format::Tum);
    let gt = io::parse_tum(&gt_text).unwrap();
    let est = io::parse_tum(&est_text).unwrap();
    assert_eq!(gt.len(), 2895);
    assert_eq!(est.len(), 2776);
    assert_eq!(gt.stamps_s[0], 1403715273.26214);
    assert!(gt.length_m() > 50.0);
}

fn synthetic_trajectory(count: usize) -> Trajectory {
    let stamps_s = (0..count).map(|i| 1_700_000_000.0 + 0.1 * i as f64 + 1e-4 * (i * i) as f64).collect();
    let poses = (0..count)
        .map(|i| {
            let a = i as f64;
            Isometry3::from_parts(
                Translation3::new(0.3 * a, -2.0 + 0.01 * a * a, (0.7 * a).sin()),
                // Rotation angles up to ~π and near identity.
                UnitQuaternion::from_scaled_axis(Vector3::new(0.1 * a, (0.37 * a).cos(), 3.0 * (a / 7.0).sin())),
            )
        })
        .collect();
    Trajectory::new(stamps_s, poses).unwrap()
}

#[test]
fn kitti_round_trip_with_times() {
    let trajectory = synthetic_trajectory(50);
    let (mut poses_text, mut times_text) = (String::new(), String::new());
    io::write_kitti(&trajectory, &mut poses_text).unwrap();
    io::write_times(&trajectory, &mut times_text).unwrap();
    assert_eq!(io::detect_format(&poses_text).unwrap(), Format::Kitti);
    let back = io::parse_kitti(&poses_text, Some(&times_text)).unwrap();
    assert_eq!(back.stamps_s, trajectory.stamps_s, "stamps are written with round-trip formatting");
    for (a, b) in back.poses.iter().zip(&trajectory.poses) {
        assert_eq!(a.translation, b.translation);
        assert!(a.rotation.angle_to(&b.rotation) < 1e-14);
    }
    // Without a times file, the row index is the stamp.
    let untimed = io::parse_kitti(&poses_text, None).unwrap();
    assert_eq!(untimed.stamps_s, (0..50).map(|i| i as f64).collect::<Vec<_>>());
}

#[test]
fn tum_round_trip_is_bit_exact() {
    let trajectory = synthetic_trajectory(200);
    let mut text = String::new();
    io::write_tum(&trajectory, &mut text).unwrap();
    let back = io::parse_tum(&text).unwrap();
    assert_eq!(back, trajectory);
}

#[test]
fn kitti_accepts_printed_rotations_and_rejects_non_rotations() {
    // A rotation printed with 6 digits is orthonormal only to ~1e-6: accepted.
    let printed = "0.866025 -0.5 0 1 0.5 0.866025 0 2 0 0 1 3\n";
    let t = io::parse_kitti(printed, None).unwrap();
    assert!((t.poses[0].rotation.angle() - 30f64.to_radians()).abs() < 1e-5);
    // A reflection and a scaled matrix are not.
    for bad in ["1 0 0 0 0 1 0 0 0 0 -1 0", "2 0 0 0 0 2 0 0 0 0 2 0"] {
        let error = io::parse_kitti(bad, None).unwrap_err();
        assert_eq!(error.line, 1);
        assert!(matches!(error.kind, ParseErrorKind::NotRotation { .. }), "{error}");
    }
}

#[test]
fn detects_formats() {
    assert_eq!(io::detect_format("# header\n\n1 2 3 4 0 0 0 1\n").unwrap(), Format::Tum);
    assert_eq!(io::detect_format("1 0 0 0 0 1 0 0 0 0 1 0").unwrap(), Format::Kitti);
    assert_eq!(io::detect_format("#timestamp,x\n1,2,3,4,1,0,0,0").unwrap(), Format::Euroc);
    assert_eq!(io::detect_format("\u{feff}1 2 3 4 0 0 0 1").unwrap(), Format::Tum, "byte-order mark");
    let error = io::detect_format("# only a header\n1 2 3\n").unwrap_err();
    assert_eq!(error.line, 2);
    assert!(matches!(error.kind, ParseErrorKind::UnknownFormat { fields: 3 }));
    assert!(matches!(io::detect_format("").unwrap_err().kind, ParseErrorKind::Empty));
    assert_eq!("EuRoC".parse::<Format>().unwrap(), Format::Euroc);
    assert!("csv".parse::<Format>().is_err());
}

#[test]
fn errors_name_the_line() {
    let tum = "# header\n0 0 0 0 0 0 0 1\n1 0 0 x 0 0 0 1\n";
    let error = io::parse_tum(tum).unwrap_err();
    assert_eq!(error.line, 3);
    assert_eq!(error.to_string(), "line 3: field `z`: `x` is not a number");

    let error = io::parse_tum("1 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n").unwrap_err();
    assert_eq!(error.line, 2);
    assert!(matches!(error.kind, ParseErrorKind::Decreasing { .. }));

    let error = io::parse_tum("0 0 0 0 0 0 0 0\n").unwrap_err();
    assert_eq!((error.line, error.kind), (1, ParseErrorKind::BadQuaternion));

    let error = io::parse_tum("0 0 0 0 0 0 0 1 9\n").unwrap_err();
    assert!(matches!(error.kind, ParseErrorKind::FieldCount { found: 9, .. }));

    let error = io::parse_euroc("#h\n1,2,3,4,1,0,0\n").unwrap_err();
    assert_eq!(error.line, 2);
    assert!(matches!(error.kind, ParseErrorKind::FieldCount { found: 7, .. }));

    let error = io::parse_euroc("1,2,3,inf,1,0,0,0\n").unwrap_err();
    assert!(matches!(error.kind, ParseErrorKind::NonFinite { field: "p_z", .. }));

    let error = io::parse_tum("# nothing\n").unwrap_err();
    assert_eq!((error.line, error.kind.clone()), (0, ParseErrorKind::Empty));
    assert_eq!(error.to_string(), "no poses");

    let kitti = "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0 0 1 0 0 0 0 1 0\n";
    let error = io::parse_kitti(kitti, Some("0\n")).unwrap_err();
    assert!(matches!(error.kind, ParseErrorKind::TimesCount { expected: 2, found: 1 }));
}

#[test]
fn euroc_ignores_extra_columns_and_converts_nanoseconds() {
    let text =
        "#timestamp [ns],x,y,z,qw,qx,qy,qz,vx\n1500000000, 1, 2, 3, 1, 0, 0, 0, 9\n2500000000,1,2,3,0,0,0,1,9,9\n";
    let t = io::parse_euroc(text).unwrap();
    assert_eq!(t.stamps_s, vec![1.5, 2.5]);
    assert!((t.poses[1].rotation.angle() - core::f64::consts::PI).abs() < 1e-12);
}

fn run_cli(args: &[&str]) -> (Option<i32>, String) {
    let output = Command::new(env!("CARGO_BIN_EXE_eval")).args(args).output().unwrap();
    (output.status.code(), String::from_utf8_lossy(&output.stderr).into_owned())
}

#[test]
fn cli_exit_codes() {
    let dir = std::env::temp_dir().join(format!("eval-io-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let good = dir.join("good.txt");
    let bad = dir.join("bad.txt");
    let mut text = String::new();
    io::write_tum(&synthetic_trajectory(20), &mut text).unwrap();
    std::fs::write(&good, &text).unwrap();
    std::fs::write(&bad, "0 0 0 0 0 0 0 1\n1 0 0 0 0 0 0 1\n2 0 0 0 zero 0 0 1\n").unwrap();
    let (good, bad) = (good.to_str().unwrap(), bad.to_str().unwrap());

    let (code, _) = run_cli(&["ate", "--gt", good, "--est", good, "--align", "se3"]);
    assert_eq!(code, Some(0));
    let (code, stderr) = run_cli(&["ate", "--gt", good, "--est", bad]);
    assert_eq!(code, Some(1));
    assert!(stderr.contains("bad.txt: line 3: field `qx`"), "{stderr}");
    let (code, _) = run_cli(&["ate", "--gt", good, "--est", "/nonexistent/file"]);
    assert_eq!(code, Some(1));
    let (code, _) = run_cli(&["ate", "--gt", good, "--est", good, "--align", "sideways"]);
    assert_eq!(code, Some(2));
    let (code, _) = run_cli(&["ate", "--gt", good]);
    assert_eq!(code, Some(2));
    let (code, _) = run_cli(&["ate", "--gt", good, "--est", good, "--online", "--align", "se3"]);
    assert_eq!(code, Some(2));
    let (code, _) = run_cli(&["rpe", "--gt", good, "--est", good, "--delta", "1.5"]);
    assert_eq!(code, Some(2), "frames must be whole");
    let (code, _) = run_cli(&["launch"]);
    assert_eq!(code, Some(2));
    let (code, _) = run_cli(&[]);
    assert_eq!(code, Some(2));
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Every reader on `text`: none may panic.
fn all_readers(text: &str) {
    let _ = io::detect_format(text);
    let _ = io::parse(text, None);
    let _ = io::parse_tum(text);
    let _ = io::parse_euroc(text);
    let _ = io::parse_kitti(text, None);
    let _ = io::parse_kitti(text, Some(text));
    let _ = io::parse_times(text, 3);
    let _ = text.parse::<Format>();
    let _ = text.parse::<eval::align::Alignment>();
    let _ = text.parse::<eval::metrics::PoseRelation>();
}

/// A token that is sometimes a number (including extremes), sometimes not.
fn token() -> impl Strategy<Value = String> {
    prop_oneof![
        any::<f64>().prop_map(|v| v.to_string()),
        (-2.0..2.0f64).prop_map(|v| format!("{v}")),
        Just("0".to_string()),
        Just("1".to_string()),
        Just("-0".to_string()),
        Just("1e308".to_string()),
        Just("-1e308".to_string()),
        Just("1e-320".to_string()),
        Just("nan".to_string()),
        Just("inf".to_string()),
        "[-+.e0-9a-z#,]{0,6}",
    ]
}

/// Rows of 1, 8, 12 or 17 tokens joined by spaces or commas, so every reader gets past field
/// counting into number, quaternion and rotation checks.
fn rows() -> impl Strategy<Value = String> {
    let row = (prop_oneof![Just(1usize), Just(8), Just(12), Just(17), 0usize..20], any::<bool>()).prop_flat_map(
        |(n, commas)| {
            proptest::collection::vec(token(), n).prop_map(move |tokens| tokens.join(if commas { "," } else { " " }))
        },
    );
    proptest::collection::vec(row, 0..8).prop_map(|rows| rows.join("\n"))
}

/// A real file's first lines with random edits.
fn mutated_real_text() -> impl Strategy<Value = String> {
    // No real KITTI file is at hand: a synthetic one, so mutations reach the rotation check.
    let mut kitti = String::new();
    io::write_kitti(&synthetic_trajectory(6), &mut kitti).unwrap();
    let sources = [
        kitti,
        read("trajectories/V102.txt").lines().take(6).collect::<Vec<_>>().join("\n"),
        read("trajectories/V102_groundtruth.csv").lines().take(6).collect::<Vec<_>>().join("\n"),
        read("euroc/v1_01_excerpt/groundtruth_from_evo/V101_gt_tum.txt").lines().take(6).collect::<Vec<_>>().join("\n"),
    ];
    let edits = proptest::collection::vec((any::<prop::sample::Index>(), 0u8..4, "[-+ ,.e0-9#\n\r\u{feff}é]"), 1..12);
    (prop::sample::select(sources.to_vec()), edits).prop_map(|(source, edits)| {
        let mut chars: Vec<char> = source.chars().collect();
        for (index, kind, replacement) in edits {
            if chars.is_empty() {
                break;
            }
            let at = index.index(chars.len());
            match kind {
                0 => {
                    chars.remove(at);
                }
                1 => chars.insert(at, replacement.chars().next().unwrap_or(' ')),
                2 => chars[at] = replacement.chars().next().unwrap_or(' '),
                _ => chars.truncate(at),
            }
        }
        chars.into_iter().collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn readers_never_panic_on_arbitrary_text(text in any::<String>()) {
        all_readers(&text);
    }

    #[test]
    fn readers_never_panic_on_numeric_rows(text in rows()) {
        all_readers(&text);
    }

    #[test]
    fn readers_never_panic_on_mutated_real_files(text in mutated_real_text()) {
        all_readers(&text);
    }

    #[test]
    fn tum_round_trip_of_arbitrary_poses(
        rows in proptest::collection::vec(
            (-1e6..1e6f64, -1e3..1e3f64, -1e3..1e3f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64, -1.0..1.0f64),
            1..20,
        )
    ) {
        let mut stamps_s = Vec::new();
        let mut poses = Vec::new();
        let mut t = 0.0;
        for (dt, x, y, qx, qy, qz, qw) in rows {
            t += dt.abs() + 1e-3;
            let q = nalgebra::Quaternion::new(qw, qx, qy, qz);
            prop_assume!(q.norm() > 1e-3);
            stamps_s.push(t);
            poses.push(Isometry3::from_parts(Translation3::new(x, y, x * y), UnitQuaternion::from_quaternion(q)));
        }
        let trajectory = Trajectory::new(stamps_s, poses).unwrap();
        let mut text = String::new();
        io::write_tum(&trajectory, &mut text).unwrap();
        prop_assert_eq!(io::parse_tum(&text).unwrap(), trajectory);
    }
}
