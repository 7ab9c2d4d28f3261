//! g2o import/export against the benchmark files in `data/posegraph`, hand-made records
//! with known answers, and a fuzz test of the parser's totality and write/parse round trip.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::f64::consts::FRAC_PI_2;

use nalgebra::{Isometry3, Matrix6, UnitQuaternion, Vector3, Vector4};
use posegraph::g2o::{
    Dimension, G2oErrorKind, G2oGraph, InformationPolicy, InitialPoseError, parse, parse_with, write,
};
use proptest::prelude::*;
use proptest::sample::Index;
use proptest::test_runner::Config;

/// The repository's test data (`data/posegraph`).
const DATA_DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/posegraph");

/// File, dimension, vertex records, edge records (counted with `awk '{print $1}' | uniq -c`).
const FILES: [(&str, Dimension, usize, usize); 12] = [
    ("sphere2500.g2o", Dimension::Three, 2500, 4949),
    ("parking-garage.g2o", Dimension::Three, 1661, 6275),
    ("smallGrid3D.g2o", Dimension::Three, 125, 297),
    ("tinyGrid3D.g2o", Dimension::Three, 9, 11),
    ("pose3example.g2o", Dimension::Three, 5, 6),
    ("intel.g2o", Dimension::Two, 1728, 2512),
    ("MIT.g2o", Dimension::Two, 808, 827),
    ("CSAIL.g2o", Dimension::Two, 0, 1172),
    ("manhattan.g2o", Dimension::Two, 0, 5453),
    ("sphere2500_groundtruth.g2o", Dimension::Three, 0, 4949),
    ("torus3D_gen.g2o", Dimension::Three, 5000, 9058),
    ("grid3D_gen.g2o", Dimension::Three, 8000, 22204),
];

fn read_data(name: &str) -> String {
    let path = format!("{DATA_DIR}/{name}");
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{path}: {e}"))
}

fn load(name: &str) -> G2oGraph {
    parse(&read_data(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn to_text(graph: &G2oGraph) -> String {
    let mut text = String::new();
    write(graph, &mut text).unwrap();
    text
}

fn num(token: &str) -> f64 {
    token.parse().unwrap()
}

/// Translation then quaternion (i, j, k, w), as raw bits: `==` on poses would accept q = −q
/// and 0.0 = −0.0.
fn pose_bits(pose: &Isometry3<f64>) -> Vec<u64> {
    pose.translation.vector.iter().chain(pose.rotation.coords.iter()).map(|v| v.to_bits()).collect()
}

fn assert_bit_identical(a: &G2oGraph, b: &G2oGraph) {
    assert_eq!(a.vertices.len(), b.vertices.len());
    for (va, vb) in a.vertices.iter().zip(&b.vertices) {
        assert_eq!(va.id, vb.id);
        assert_eq!(pose_bits(&va.pose), pose_bits(&vb.pose), "vertex {}", va.id);
    }
    assert_eq!(a.edges.len(), b.edges.len());
    for (ea, eb) in a.edges.iter().zip(&b.edges) {
        assert_eq!((ea.from, ea.to), (eb.from, eb.to));
        assert_eq!(pose_bits(&ea.measurement), pose_bits(&eb.measurement), "edge {}-{}", ea.from, ea.to);
        let bits = |m: &Matrix6<f64>| m.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&ea.information), bits(&eb.information), "edge {}-{}", ea.from, ea.to);
    }
    assert_eq!(a.fixed, b.fixed);
}

/// `q` (given as x y z w) normalized, with the sign the parser picks.
fn expected_quaternion(x: f64, y: f64, z: f64, w: f64) -> Vector4<f64> {
    let q = Vector4::new(x, y, z, w).normalize();
    if w < 0.0 { -q } else { q }
}

#[test]
fn every_data_file_parses_with_its_record_counts() {
    let mut seen = 0;
    for entry in std::fs::read_dir(DATA_DIR).unwrap() {
        let name = entry.unwrap().file_name().into_string().unwrap();
        if !name.ends_with(".g2o") {
            continue;
        }
        let &(_, dimension, vertices, edges) =
            FILES.iter().find(|f| f.0 == name).unwrap_or_else(|| panic!("{name} is not in the table"));
        let graph = load(&name);
        assert_eq!(graph.dimension, dimension, "{name}");
        assert_eq!(graph.vertices.len(), vertices, "{name}");
        assert_eq!(graph.edges.len(), edges, "{name}");
        assert!(graph.fixed.is_empty(), "{name}");
        seen += 1;
    }
    assert_eq!(seen, FILES.len());
}

#[test]
fn sphere2500_first_records_match_the_file_text() {
    let graph = load("sphere2500.g2o");

    // VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1
    assert_eq!(graph.vertices[0].id, 0);
    assert_eq!(pose_bits(&graph.vertices[0].pose), pose_bits(&Isometry3::identity()));

    // VERTEX_SE3:QUAT 1 0.341895 -0.0416997 0.0330394 -0.00189341 0.00395691 0.0899835 0.995934
    let v1 = &graph.vertices[1];
    assert_eq!(v1.id, 1);
    assert_eq!(v1.pose.translation.vector, Vector3::new(num("0.341895"), num("-0.0416997"), num("0.0330394")));
    let q = expected_quaternion(-0.00189341, 0.00395691, 0.0899835, 0.995934);
    assert!((v1.pose.rotation.coords - q).amax() < 1e-15);

    // Stored with qw < 0: VERTEX_SE3:QUAT 25 -1.01622 5.97466 -0.608022 -0.0405851 0.05631 0.997534 -0.0103459
    let v25 = &graph.vertices[25];
    assert_eq!(v25.id, 25);
    assert_eq!(v25.pose.translation.vector, Vector3::new(-1.01622, 5.97466, -0.608022));
    let q = expected_quaternion(-0.0405851, 0.05631, 0.997534, -0.0103459);
    assert!(q[3] > 0.0);
    assert!((v25.pose.rotation.coords - q).amax() < 1e-15);

    // EDGE_SE3:QUAT 0 1 0.341895 -0.0416997 0.0330394 -0.00189341 0.00395691 0.0899835 0.995934
    //   10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 400.021 0.00193512 2.06612 399.993 0.496977 99.203
    let e0 = &graph.edges[0];
    assert_eq!((e0.from, e0.to), (0, 1));
    assert_eq!(pose_bits(&e0.measurement), pose_bits(&v1.pose));
    #[rustfmt::skip]
    let information = Matrix6::new(
        10.0, 0.0, 0.0, 0.0, 0.0, 0.0,
        0.0, 10.0, 0.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 10.0, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, 400.021, 0.00193512, 2.06612,
        0.0, 0.0, 0.0, 0.00193512, 399.993, 0.496977,
        0.0, 0.0, 0.0, 2.06612, 0.496977, 99.203,
    );
    assert_eq!(e0.information, information);
}

#[test]
fn intel_first_records_are_lifted_to_3d() {
    let graph = load("intel.g2o");

    // VERTEX_SE2 1 0.144012 -0.004462 -0.017453
    let v1 = &graph.vertices[1];
    assert_eq!(v1.id, 1);
    assert_eq!(v1.pose.translation.vector, Vector3::new(0.144012, -0.004462, 0.0));
    assert!((v1.pose.rotation.scaled_axis() - Vector3::new(0.0, 0.0, -0.017453)).amax() < 1e-15);
    // A yaw-only quaternion: exactly zero x and y, positive w.
    assert_eq!((v1.pose.rotation.i, v1.pose.rotation.j), (0.0, 0.0));
    assert!(v1.pose.rotation.w > 0.0);

    // EDGE_SE2 0 1 0.144012 -0.004462 -0.017453 115.187 -9.86523 -7.085 347.418 185.36 224.616
    let e0 = &graph.edges[0];
    assert_eq!((e0.from, e0.to), (0, 1));
    assert_eq!(pose_bits(&e0.measurement), pose_bits(&v1.pose));
    // Rows and columns [x, y, z, roll, pitch, yaw]; z gets max(Ixx, Iyy), roll and pitch Iθθ.
    #[rustfmt::skip]
    let information = Matrix6::new(
        115.187, -9.86523, 0.0, 0.0, 0.0, -7.085,
        -9.86523, 347.418, 0.0, 0.0, 0.0, 185.36,
        0.0, 0.0, 347.418, 0.0, 0.0, 0.0,
        0.0, 0.0, 0.0, 224.616, 0.0, 0.0,
        0.0, 0.0, 0.0, 0.0, 224.616, 0.0,
        -7.085, 185.36, 0.0, 0.0, 0.0, 224.616,
    );
    assert_eq!(e0.information, information);
}

#[test]
fn every_lifted_information_matrix_is_positive_definite() {
    for name in ["intel.g2o", "MIT.g2o", "CSAIL.g2o", "manhattan.g2o"] {
        for edge in load(name).edges {
            assert!(edge.information.cholesky().is_some(), "{name} edge {}-{}", edge.from, edge.to);
        }
    }
}

#[test]
fn nalgebra_euler_angles_are_yaw_pitch_roll() {
    let (x, y, z) = (Vector3::x_axis(), Vector3::y_axis(), Vector3::z_axis());
    for (roll, pitch, yaw) in [(0.3, -0.2, 1.1), (-2.5, 1.2, 3.0), (0.0, FRAC_PI_2 - 1e-3, -0.7)] {
        let composed = UnitQuaternion::from_axis_angle(&z, yaw)
            * UnitQuaternion::from_axis_angle(&y, pitch)
            * UnitQuaternion::from_axis_angle(&x, roll);
        let euler = UnitQuaternion::from_euler_angles(roll, pitch, yaw);
        assert!(euler.angle_to(&composed) < 1e-12, "{roll} {pitch} {yaw}");
    }
}

const LEGACY_INFORMATION: &str = "1 0 0 0 0 0 2 0 0 0 0 3 0 0 0 4 0 0 5 0 6";

fn legacy_edge(angles: &str) -> G2oGraph {
    parse(&format!("EDGE3 7 8 1 2 3 {angles} {LEGACY_INFORMATION}")).unwrap()
}

#[test]
fn legacy_edge3_angles_are_roll_pitch_yaw_about_x_y_z() {
    let z = Vector3::z_axis();
    let x = Vector3::x_axis();

    let yaw_only = &legacy_edge("0 0 0.5").edges[0];
    assert_eq!((yaw_only.from, yaw_only.to), (7, 8));
    assert_eq!(yaw_only.measurement.translation.vector, Vector3::new(1.0, 2.0, 3.0));
    assert!(yaw_only.measurement.rotation.angle_to(&UnitQuaternion::from_axis_angle(&z, 0.5)) < 1e-15);

    let roll_only = &legacy_edge("0.5 0 0").edges[0];
    assert!(roll_only.measurement.rotation.angle_to(&UnitQuaternion::from_axis_angle(&x, 0.5)) < 1e-15);

    let all = &legacy_edge("0.3 -0.2 1.1").edges[0];
    let expected = UnitQuaternion::from_euler_angles(0.3, -0.2, 1.1);
    assert!(all.measurement.rotation.angle_to(&expected) < 1e-15);

    // Information in [translation, rotation] order, like EDGE_SE3:QUAT.
    assert_eq!(all.information, Matrix6::from_diagonal(&nalgebra::Vector6::new(1.0, 2.0, 3.0, 4.0, 5.0, 6.0)));

    let vertex = parse("VERTEX3 4 1 2 3 0.3 -0.2 1.1").unwrap();
    assert!(vertex.vertices[0].pose.rotation.angle_to(&expected) < 1e-15);
    assert_eq!(vertex.vertex_pose(4).unwrap().translation.vector, Vector3::new(1.0, 2.0, 3.0));
    assert!(vertex.vertex_pose(5).is_none());
}

#[test]
fn sphere2500_groundtruth_first_edge_matches_the_file_text() {
    // EDGE3 0 1 0.258134 -0.0450052 -0.000686593 0.00153957 0.00500934 0.125564
    //   10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 100 0 0 100 0 25
    let graph = load("sphere2500_groundtruth.g2o");
    let e0 = &graph.edges[0];
    assert_eq!((e0.from, e0.to), (0, 1));
    assert_eq!(e0.measurement.translation.vector, Vector3::new(0.258134, -0.0450052, -0.000686593));
    let expected = UnitQuaternion::from_euler_angles(0.00153957, 0.00500934, 0.125564);
    assert!(e0.measurement.rotation.angle_to(&expected) < 1e-15);
    let diagonal = nalgebra::Vector6::new(10.0, 10.0, 10.0, 100.0, 100.0, 25.0);
    assert_eq!(e0.information, Matrix6::from_diagonal(&diagonal));
}

#[test]
fn round_trip_is_bit_exact_for_every_data_file() {
    for (name, ..) in FILES {
        let graph = load(name);
        let text = to_text(&graph);
        let again = parse(&text).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(again.dimension, Dimension::Three, "{name}");
        assert_bit_identical(&graph, &again);
        assert_eq!(to_text(&again), text, "{name}");
    }
}

#[test]
fn written_records_are_3d_with_non_negative_qw() {
    let text = to_text(&load("sphere2500.g2o"));
    let mut lines = text.lines();
    assert_eq!(lines.next(), Some("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1"));
    for line in text.lines() {
        let fields: Vec<&str> = line.split_whitespace().collect();
        let qw = match fields[0] {
            "VERTEX_SE3:QUAT" => fields[8],
            "EDGE_SE3:QUAT" => fields[9],
            other => panic!("unexpected record {other}"),
        };
        assert!(!qw.starts_with('-'), "{line}");
    }

    let intel = to_text(&load("intel.g2o"));
    assert!(intel.lines().all(|l| l.starts_with("VERTEX_SE3:QUAT ") || l.starts_with("EDGE_SE3:QUAT ")));
}

#[test]
fn extreme_values_and_fix_records_round_trip() {
    let text = "VERTEX_SE3:QUAT 18446744073709551615 1e308 -5e-324 -0 3 4 0 0\n\
                VERTEX_SE3:QUAT 0 1e-300 123456789012345680000 0.1 -1e300 1e300 0 -0\n\
                FIX 0 18446744073709551615 0\n\
                FIX 7\n";
    let graph = parse(text).unwrap();
    assert_eq!(graph.fixed, vec![0, u64::MAX, 7]);
    let v = &graph.vertices[0];
    assert_eq!(v.id, u64::MAX);
    assert_eq!(v.pose.translation.z.to_bits(), (-0.0f64).to_bits());
    assert_eq!(v.pose.rotation.coords, Vector4::new(0.6, 0.8, 0.0, 0.0));
    // (−1e300, 1e300, 0, −0): normalized without overflow, and flipped so qw's sign bit is clear.
    let q = graph.vertices[1].pose.rotation.coords;
    let half = std::f64::consts::FRAC_1_SQRT_2;
    assert!((q - Vector4::new(half, -half, 0.0, 0.0)).amax() < 1e-15);
    assert!(q[2].is_sign_negative() && q[3].is_sign_positive());
    let again = parse(&to_text(&graph)).unwrap();
    assert_bit_identical(&graph, &again);
}

#[test]
fn a_2d_file_written_as_3d_reparses_to_the_same_lifted_graph() {
    for name in ["intel.g2o", "MIT.g2o", "manhattan.g2o"] {
        let graph = load(name);
        assert_eq!(graph.dimension, Dimension::Two);
        let again = parse(&to_text(&graph)).unwrap();
        assert_eq!(again.dimension, Dimension::Three);
        assert_bit_identical(&graph, &again);
    }
}

#[test]
fn initial_poses_of_the_vertex_less_groundtruth_lie_on_a_sphere() {
    let graph = load("sphere2500_groundtruth.g2o");
    let poses = graph.initial_from_edges().unwrap();
    assert_eq!(poses.len(), 2500);
    assert_eq!(poses.keys().copied().collect::<Vec<_>>(), (0..2500).collect::<Vec<_>>());
    assert_eq!(pose_bits(&poses[&0]), pose_bits(&Isometry3::identity()));
    // The trajectory winds around a sphere; composing the true odometry must reproduce one.
    let centroid = poses.values().map(|p| p.translation.vector).sum::<Vector3<f64>>() / 2500.0;
    let radii: Vec<f64> = poses.values().map(|p| (p.translation.vector - centroid).norm()).collect();
    let mean = radii.iter().sum::<f64>() / radii.len() as f64;
    let worst = radii.iter().map(|r| (r - mean).abs()).fold(0.0, f64::max);
    assert!(mean > 10.0 && worst < 1e-3 * mean, "mean radius {mean}, worst deviation {worst}");
}

#[test]
fn initial_poses_follow_the_odometry_that_generated_the_file_vertices() {
    // These files' vertices are the composed odometry, printed to six digits. (Not intel's: its
    // vertices jump away from the odometry at vertex 270.)
    for (name, tolerance) in [("sphere2500.g2o", 1e-3), ("MIT.g2o", 1e-3), ("parking-garage.g2o", 1e-2)] {
        let graph = load(name);
        let poses = graph.initial_from_edges().unwrap();
        assert_eq!(poses.len(), graph.vertices.len());
        let worst = graph
            .vertices
            .iter()
            .map(|v| (poses[&v.id].translation.vector - v.pose.translation.vector).norm())
            .fold(0.0, f64::max);
        assert!(worst < tolerance, "{name}: worst position difference {worst}");
    }
}

const SE2_INFO: &str = "1 0 0 1 0 1";

#[test]
fn initial_poses_prefer_the_odometry_chain_over_loop_closures() {
    // 0 → 1 → 2 → 3 step 1 m along x; the loop closure 0 → 3 claims 10 m; odometry 2 → 1 stored
    // reversed must be inverted.
    let text = format!(
        "EDGE_SE2 0 3 10 0 0 {SE2_INFO}\nEDGE_SE2 0 1 1 0 0 {SE2_INFO}\n\
         EDGE_SE2 2 1 -1 0 0 {SE2_INFO}\nEDGE_SE2 2 3 1 0 0 {SE2_INFO}\n"
    );
    let graph = parse(&text).unwrap();
    let poses = graph.initial_from_edges().unwrap();
    for (id, x) in [(0, 0.0), (1, 1.0), (2, 2.0), (3, 3.0)] {
        assert_eq!(poses[&id].translation.vector, Vector3::new(x, 0.0, 0.0), "vertex {id}");
    }

    // Without the 2 → 3 odometry, vertex 3 is only reachable through the loop closure.
    let text =
        format!("EDGE_SE2 0 3 10 0 0 {SE2_INFO}\nEDGE_SE2 0 1 1 0 0 {SE2_INFO}\nEDGE_SE2 2 1 -1 0 0 {SE2_INFO}\n");
    let poses = parse(&text).unwrap().initial_from_edges().unwrap();
    assert_eq!(poses[&3].translation.vector, Vector3::new(10.0, 0.0, 0.0));
}

#[test]
fn initial_poses_start_from_the_root_vertex_pose_and_compose_rotations() {
    let text = format!("VERTEX_SE2 4 1 2 1.5707963267948966\nEDGE_SE2 4 5 1 0 1.5707963267948966 {SE2_INFO}\n");
    let poses = parse(&text).unwrap().initial_from_edges().unwrap();
    assert_eq!(poses.len(), 2);
    assert!((poses[&5].translation.vector - Vector3::new(1.0, 3.0, 0.0)).amax() < 1e-15);
    let half_turn = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), std::f64::consts::PI);
    assert!(poses[&5].rotation.angle_to(&half_turn) < 1e-15);
}

#[test]
fn initial_poses_fail_for_disconnected_vertices() {
    let text = format!("EDGE_SE2 0 1 1 0 0 {SE2_INFO}\nEDGE_SE2 1 2 1 0 0 {SE2_INFO}\nEDGE_SE2 5 6 1 0 0 {SE2_INFO}\n");
    let graph = parse(&text).unwrap();
    assert_eq!(graph.initial_from_edges(), Err(InitialPoseError::Unreachable { vertex: 5 }));

    let lonely = format!("VERTEX_SE2 9 0 0 0\nEDGE_SE2 0 1 1 0 0 {SE2_INFO}\n");
    let mut graph = parse(&lonely).unwrap();
    // The root is the smallest id, 0, so the lonely vertex is the one left out ...
    assert_eq!(graph.initial_from_edges(), Err(InitialPoseError::Unreachable { vertex: 9 }));
    // ... while filling starts from the vertex with a pose, and cannot reach the edges.
    assert_eq!(graph.fill_missing_vertices(), Err(InitialPoseError::Unreachable { vertex: 0 }));

    assert!(G2oGraph::default().initial_from_edges().unwrap().is_empty());
}

#[test]
fn fill_missing_vertices_completes_vertex_less_files() {
    let mut graph = load("CSAIL.g2o");
    assert_eq!(graph.fill_missing_vertices().unwrap(), 1045);
    assert_eq!(graph.vertices.iter().map(|v| v.id).collect::<Vec<_>>(), (0..1045).collect::<Vec<_>>());
    assert_eq!(graph.fill_missing_vertices().unwrap(), 0);
    // Composed rotations are stored canonically, so the filled graph round-trips exactly too.
    let again = parse(&to_text(&graph)).unwrap();
    assert_bit_identical(&graph, &again);

    // Known vertices keep their poses; missing ones hang off their nearest known neighbour.
    let text = format!(
        "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 2 5 5 0\nEDGE_SE2 0 1 1 0 0 {SE2_INFO}\nEDGE_SE2 2 3 1 0 0 {SE2_INFO}\n"
    );
    let mut graph = parse(&text).unwrap();
    assert_eq!(graph.fill_missing_vertices().unwrap(), 2);
    assert_eq!(graph.vertex_pose(2).unwrap().translation.vector, Vector3::new(5.0, 5.0, 0.0));
    assert_eq!(graph.vertex_pose(3).unwrap().translation.vector, Vector3::new(6.0, 5.0, 0.0));
    assert_eq!(graph.vertex_pose(1).unwrap().translation.vector, Vector3::new(1.0, 0.0, 0.0));
}

#[test]
fn comments_blank_lines_crlf_and_empty_input() {
    let graph = parse("").unwrap();
    assert_eq!(graph, G2oGraph::default());
    assert_eq!(graph.dimension, Dimension::Three);

    let text = "# header\r\n\r\n   \t\r\n  # indented comment\r\nVERTEX_SE2 0 0 0 0\r\nFIX 0\r\n";
    let graph = parse(text).unwrap();
    assert_eq!(graph.dimension, Dimension::Two);
    assert_eq!(graph.vertices.len(), 1);
    assert_eq!(graph.fixed, vec![0]);
    assert_eq!(parse("FIX 3").unwrap().dimension, Dimension::Three);
    assert_eq!("VERTEX_SE2 0 0 0 0".parse::<G2oGraph>().unwrap().vertices.len(), 1);
}

fn error_of(text: &str) -> (usize, G2oErrorKind) {
    let error = parse(text).unwrap_err();
    (error.line, error.kind)
}

const VERTEX: &str = "VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1";

#[test]
fn errors_name_the_line_and_the_problem() {
    let error = parse(&format!("{VERTEX}\n\nFOO 1 2\n")).unwrap_err();
    assert_eq!((error.line, &error.kind), (3, &G2oErrorKind::UnknownRecord("FOO".into())));
    assert_eq!(error.to_string(), "line 3: unknown record type `FOO`");

    let missing = error_of("# comment\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0");
    let kind = G2oErrorKind::MissingField { record: "VERTEX_SE3:QUAT", field: "qw", expected: 8, found: 7 };
    assert_eq!(missing, (2, kind));

    let missing_info = error_of("EDGE_SE2 0 1 1 0 0 1 0 0 1");
    let kind = G2oErrorKind::MissingField { record: "EDGE_SE2", field: "I23", expected: 11, found: 9 };
    assert_eq!(missing_info, (1, kind));

    let trailing = error_of(&format!("{VERTEX}\nEDGE_SE2 0 1 1 0 0 1 0 0 1 0 1 5"));
    assert_eq!(trailing, (2, G2oErrorKind::TrailingFields { record: "EDGE_SE2", expected: 11, found: 12 }));

    let bad = error_of("VERTEX_SE3:QUAT 0 0 abc 0 0 0 0 1");
    assert_eq!(bad, (1, G2oErrorKind::BadNumber { field: "y", token: "abc".into() }));

    for junk in ["nan", "inf", "-infinity", "1e999"] {
        let non_finite = error_of(&format!("VERTEX_SE2 3 0 0 {junk}"));
        assert_eq!(non_finite, (1, G2oErrorKind::NonFinite { field: "theta", token: junk.into() }));
    }

    for junk in ["-1", "18446744073709551616", "1.0", "1e3", "x"] {
        let bad_id = error_of(&format!("{VERTEX}\nEDGE_SE2 0 {junk} 1 0 0 1 0 0 1 0 1"));
        assert_eq!(bad_id, (2, G2oErrorKind::BadId { field: "to", token: junk.into() }));
    }

    for quaternion in ["0 0 0 0", "1e-9 0 0 -1e-9", "-0 0 0 -0"] {
        let zero = error_of(&format!("# header\n{VERTEX}\nVERTEX_SE3:QUAT 1 0 0 0 {quaternion}"));
        assert_eq!(zero, (3, G2oErrorKind::ZeroQuaternion));
    }

    assert_eq!(error_of(&format!("{VERTEX}\n{VERTEX}")), (2, G2oErrorKind::DuplicateVertex(0)));
    assert_eq!(error_of(&format!("{VERTEX}\nVERTEX_SE2 1 0 0 0")), (2, G2oErrorKind::MixedDimensions));
    assert_eq!(error_of("EDGE_SE2 0 1 1 0 0 1 0 0 1 0 1\nVERTEX3 5 0 0 0 0 0 0"), (2, G2oErrorKind::MixedDimensions));
    assert_eq!(error_of("EDGE_SE2 4 4 1 0 0 1 0 0 1 0 1"), (1, G2oErrorKind::SelfLoop(4)));
    let fix = error_of("FIX");
    assert_eq!(fix, (1, G2oErrorKind::MissingField { record: "FIX", field: "id", expected: 1, found: 0 }));
    assert_eq!(error_of("FIX 1 -2"), (1, G2oErrorKind::BadId { field: "id", token: "-2".into() }));
    // Case matters, as in g2o.
    assert_eq!(error_of("vertex_se2 0 0 0 0"), (1, G2oErrorKind::UnknownRecord("vertex_se2".into())));

    // Long junk is quoted, but cut short.
    let long = "9".repeat(500);
    let (_, kind) = error_of(&format!("VERTEX_SE2 {long} 0 0 0"));
    assert!(kind.to_string().len() < 150, "{kind}");
}

// ---------------------------------------------------------------------------------------------
// Fuzzing

/// Valid lines; `{a}` and `{b}` become ids distinct per line so that unmutated documents parse.
const LINES_3D: [&str; 5] = [
    "VERTEX3 {a} 1 2 3 0.3 -0.2 1.1",
    "VERTEX_SE3:QUAT {a} 0.341895 -0.0416997 0.0330394 -0.00189341 0.00395691 0.0899835 0.995934",
    "VERTEX_SE3:QUAT {a} -1.01622 5.97466 -0.608022 -0.0405851 0.05631 0.997534 -0.0103459",
    "EDGE_SE3:QUAT {a} {b} 0.341895 -0.0416997 0.0330394 -0.00189341 0.00395691 0.0899835 0.995934 \
     10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 400.021 0.00193512 2.06612 399.993 0.496977 99.203",
    "EDGE3 {a} {b} 0.258134 -0.0450052 -0.000686593 0.00153957 0.00500934 0.125564 \
     10 0 0 0 0 0 10 0 0 0 0 10 0 0 0 100 0 0 100 0 25",
];
const LINES_2D: [&str; 4] = [
    "VERTEX_SE2 {a} 0.144012 -0.004462 -0.017453",
    "VERTEX_SE2 {a} 2.039345 0.003006 3.5",
    "EDGE_SE2 {a} {b} 0.144012 -0.004462 -0.017453 115.187 -9.86523 -7.085 347.418 185.36 224.616",
    "EDGE_SE2 {b} {a} -0.1 0.0 0.1 17.706797 158.758870 0.000000 1584.070981 0.000000 330.578512",
];
const LINES_ANY: [&str; 3] = ["FIX {a}", "# comment {a}", ""];

const JUNK: [&str; 26] = [
    "nan",
    "NaN",
    "inf",
    "-inf",
    "infinity",
    "1e999",
    "-1e999",
    "-1",
    "18446744073709551616",
    "18446744073709551615",
    "0",
    "-0",
    "5e-324",
    "1e308",
    "-1.7976931348623157e308",
    "abc",
    "+3",
    ".5",
    "1.",
    "0x10",
    "1_0",
    "EDGE_SE2",
    "FIX",
    "#",
    "é∞",
    "\u{0}",
];

#[derive(Debug, Clone)]
enum Mutation {
    Delete(Index),
    Duplicate(Index),
    Replace(Index, String),
}

fn junk_token() -> impl Strategy<Value = String> {
    prop_oneof![
        4 => prop::sample::select(&JUNK[..]).prop_map(str::to_owned),
        2 => any::<f64>().prop_map(|v| format!("{v:e}")),
        2 => any::<f64>().prop_map(|v| format!("{v}")),
        2 => (-3i64..3000).prop_map(|v| v.to_string()),
        1 => "[ -~]{0,6}",
    ]
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        any::<Index>().prop_map(Mutation::Delete),
        any::<Index>().prop_map(Mutation::Duplicate),
        (any::<Index>(), junk_token()).prop_map(|(i, t)| Mutation::Replace(i, t)),
    ]
}

/// Picks template lines of one dimension (so that unmutated documents are valid), mutates some.
fn mutated_document() -> impl Strategy<Value = String> {
    let line = (any::<bool>(), any::<Index>(), prop::collection::vec(mutation(), 0..3));
    (any::<bool>(), prop::collection::vec(line, 1..8), prop::sample::select(&["\n", "\r\n", " \n\n"][..])).prop_map(
        |(planar, lines, separator)| {
            let family: &[&str] = if planar { &LINES_2D } else { &LINES_3D };
            let mut out = Vec::new();
            for (n, (any_family, pick, mutations)) in lines.into_iter().enumerate() {
                let template = if any_family { *pick.get(&LINES_ANY) } else { *pick.get(family) };
                let text = template.replace("{a}", &(2 * n).to_string()).replace("{b}", &(2 * n + 1).to_string());
                let mut tokens: Vec<String> = text.split(' ').map(str::to_owned).collect();
                for mutation in mutations {
                    if tokens.is_empty() {
                        break;
                    }
                    match mutation {
                        Mutation::Delete(i) => {
                            tokens.remove(i.index(tokens.len()));
                        }
                        Mutation::Duplicate(i) => {
                            let i = i.index(tokens.len());
                            tokens.insert(i, tokens[i].clone());
                        }
                        Mutation::Replace(i, junk) => {
                            let i = i.index(tokens.len());
                            tokens[i] = junk;
                        }
                    }
                }
                out.push(tokens.join(" "));
            }
            out.join(separator)
        },
    )
}

/// Every accepted input is reproduced exactly by write → parse, and writing again gives the same
/// text. The checking reader never panics either, and what it accepts unrepaired is what the
/// plain reader reads.
fn check_round_trip(text: &str) -> Result<(), TestCaseError> {
    for policy in [InformationPolicy::Reject, InformationPolicy::repair()] {
        if let Ok(checked) = parse_with(text, policy)
            && checked.repaired_edges.is_empty()
        {
            prop_assert_eq!(Ok(checked.graph), parse(text));
        }
    }
    if let Ok(graph) = parse(text) {
        let written = to_text(&graph);
        let again = parse(&written).map_err(|e| TestCaseError::fail(format!("{e} in\n{written}")))?;
        assert_bit_identical(&graph, &again);
        prop_assert_eq!(to_text(&again), written);
    }
    Ok(())
}

fn fuzz_config(cases: u32) -> Config {
    // No regression files: this test's directory belongs to the whole crate.
    Config { cases, failure_persistence: None, ..Config::default() }
}

proptest! {
    #![proptest_config(fuzz_config(20_000))]

    #[test]
    fn mutated_valid_lines_never_panic_and_round_trip(text in mutated_document()) {
        check_round_trip(&text)?;
    }
}

proptest! {
    #![proptest_config(fuzz_config(10_000))]

    #[test]
    fn arbitrary_text_never_panics_and_round_trips(
        text in prop_oneof![
            any::<String>(),
            prop::collection::vec(any::<u8>(), 0..300).prop_map(|b| String::from_utf8_lossy(&b).into_owned()),
            "((VERTEX_SE3:QUAT|EDGE_SE2|VERTEX_SE2|FIX|EDGE3|#)?[ 0-9.e+\\-]{0,40}\n?){0,4}",
        ]
    ) {
        check_round_trip(&text)?;
    }
}

#[test]
fn unmutated_fuzz_documents_parse() {
    // Guards the fuzz test against generating only errors.
    for family in [&LINES_2D[..], &LINES_3D[..]] {
        let text = family
            .iter()
            .chain(&LINES_ANY)
            .enumerate()
            .map(|(n, l)| l.replace("{a}", &(2 * n).to_string()).replace("{b}", &(2 * n + 1).to_string()))
            .collect::<Vec<_>>()
            .join("\n");
        check_round_trip(&text).unwrap();
        assert!(parse(&text).is_ok(), "{text}");
    }
}
