#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Map readers, height error and obstacle precision/recall against hand-computed answers.

use eval::map::{
    ErrorStats, HeightGrid, HeightGridError, ObstacleEvalError, ObstacleMatching, PlyError, PlyFormat, TrueObstacle,
    cloud_height_error, evaluate_obstacles, grid_height_error, obstacles_in_mapped_area, parse_ply, ply_bytes,
    points_away_from_obstacles,
};
use nalgebra::{Point2, Point3};
use proptest::prelude::*;

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

// ------------------------------------------------------------------------------------------------
// PLY
// ------------------------------------------------------------------------------------------------

#[test]
fn ply_ascii_skips_other_properties_and_elements() {
    let text = "ply\r\nformat ascii 1.0\r\ncomment made by hand\r\nelement camera 1\r\nproperty float fov\r\n\
                element vertex 2\r\nproperty uchar red\r\nproperty float x\r\nproperty list uchar int idx\r\n\
                property float y\r\nproperty double z\r\nelement face 1\r\nproperty list uchar int vertex_indices\r\n\
                end_header\r\n\
                60.0\n\
                255 1.5 2 7 8 -2.25 3e-1\n\
                0 -1 0 0.0 4.0\n\
                3 0 1 1\n";
    let points = parse_ply(text.as_bytes()).unwrap();
    assert_eq!(points, vec![Point3::new(1.5, -2.25, 0.3), Point3::new(-1.0, 0.0, 4.0)]);
}

#[test]
fn ply_binary_little_endian_with_lists_before_vertices() {
    let mut bytes = b"ply\nformat binary_little_endian 1.0\nelement meta 2\nproperty list uchar ushort ids\n\
                      element vertex 2\nproperty float x\nproperty float y\nproperty float z\nproperty uchar intensity\n\
                      end_header\n"
        .to_vec();
    // meta 0: two ushorts; meta 1: empty list.
    bytes.extend_from_slice(&[2, 1, 0, 2, 0, 0]);
    for (p, intensity) in [([1.0f32, 2.0, 3.0], 9u8), ([-0.5, 0.25, 8.0], 200)] {
        p.iter().for_each(|v| bytes.extend_from_slice(&v.to_le_bytes()));
        bytes.push(intensity);
    }
    let points = parse_ply(&bytes).unwrap();
    assert_eq!(points, vec![Point3::new(1.0, 2.0, 3.0), Point3::new(-0.5, 0.25, 8.0)]);
}

#[test]
fn ply_errors_name_the_problem() {
    let header = |format: &str, props: &str, count: usize| {
        format!("ply\nformat {format} 1.0\nelement vertex {count}\n{props}end_header\n").into_bytes()
    };
    let xyz = "property float x\nproperty float y\nproperty float z\n";
    assert_eq!(parse_ply(b""), Err(PlyError::NotPly));
    assert_eq!(parse_ply(b"PLY\n"), Err(PlyError::NotPly));
    assert_eq!(parse_ply(b"ply\nformat ascii 1.0\n"), Err(PlyError::UnterminatedHeader));
    assert_eq!(
        parse_ply(&header("binary_big_endian", xyz, 0)),
        Err(PlyError::UnsupportedFormat("binary_big_endian".into()))
    );
    assert_eq!(parse_ply(b"ply\nelement vertex 0\nend_header\n"), Err(PlyError::MissingFormat));
    assert_eq!(parse_ply(b"ply\nformat ascii 1.0\nend_header\n"), Err(PlyError::NoVertexElement));
    assert_eq!(
        parse_ply(&header("ascii", "property float x\nproperty float y\n", 0)),
        Err(PlyError::MissingCoordinate("z"))
    );
    assert!(matches!(
        parse_ply(b"ply\nformat ascii 1.0\nproperty float x\nend_header\n"),
        Err(PlyError::Header { line: 3, .. })
    ));
    assert!(matches!(
        parse_ply(b"ply\nformat ascii 1.0\nelement vertex 1\nproperty half x\nend_header\n"),
        Err(PlyError::Header { line: 4, .. })
    ));
    let mut truncated = header("binary_little_endian", xyz, 2);
    truncated.extend_from_slice(&[0; 12 + 5]);
    assert_eq!(parse_ply(&truncated), Err(PlyError::Truncated { element: "vertex".into(), index: 1 }));
    let mut bad = header("ascii", xyz, 1);
    bad.extend_from_slice(b"1 two 3\n");
    assert!(matches!(parse_ply(&bad), Err(PlyError::BadValue { index: 0, ref token, .. }) if token == "two"));
    let mut nan = header("ascii", xyz, 1);
    nan.extend_from_slice(b"1 nan 3\n");
    assert_eq!(parse_ply(&nan), Err(PlyError::NonFinite { index: 0 }));
}

#[test]
fn ply_huge_claimed_counts_fail_fast() {
    // A header may claim more than the data holds; that must be an error, not an allocation.
    let text = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\nproperty double x\nproperty double y\nproperty double z\nend_header\n",
        usize::MAX
    );
    assert!(matches!(parse_ply(text.as_bytes()), Err(PlyError::Truncated { index: 0, .. })));
    let text = "ply\nformat ascii 1.0\nelement empty 18446744073709551615\nelement vertex 0\nproperty float x\n\
                property float y\nproperty float z\nend_header\n";
    assert_eq!(parse_ply(text.as_bytes()), Ok(vec![]));
}

fn point() -> impl Strategy<Value = Point3<f64>> {
    (-1e6..1e6f64, -1e6..1e6f64, -1e3..1e3f64).prop_map(|(x, y, z)| Point3::new(x, y, z))
}

proptest! {
    #[test]
    fn ply_never_panics_on_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let _ = parse_ply(&bytes);
    }

    #[test]
    fn ply_never_panics_on_arbitrary_data_after_a_valid_header(
        binary in any::<bool>(),
        count in 0usize..1000,
        data in proptest::collection::vec(any::<u8>(), 0..512),
    ) {
        let format = if binary { "binary_little_endian" } else { "ascii" };
        let mut bytes = format!(
            "ply\nformat {format} 1.0\nelement pre 3\nproperty list uchar int l\nelement vertex {count}\n\
             property float x\nproperty double y\nproperty short z\nend_header\n"
        ).into_bytes();
        bytes.extend_from_slice(&data);
        let _ = parse_ply(&bytes);
    }

    #[test]
    fn ply_never_panics_on_header_like_text(
        text in "ply\n((format (ascii|binary_little_endian|binary_big_endian) 1\\.0|element (vertex|face) [0-9]{1,3}|\
                 property (float|double|uchar|int|list uchar int|list float int|half) [xyzw]|comment x|bogus)\n){0,8}\
                 end_header\n[ -~\n]{0,64}",
    ) {
        let _ = parse_ply(text.as_bytes());
    }

    #[test]
    fn ply_round_trips(points in proptest::collection::vec(point(), 0..50), binary in any::<bool>()) {
        let format = if binary { PlyFormat::BinaryLittleEndian } else { PlyFormat::Ascii };
        prop_assert_eq!(parse_ply(&ply_bytes(&points, format)).unwrap(), points);
    }
}

// ------------------------------------------------------------------------------------------------
// Height grids
// ------------------------------------------------------------------------------------------------

/// z = 0.5 x − 0.25 y + 1 on a `cols` × `rows` grid at 0.1 m, origin (−1, 2).
fn plane_grid(cols: usize, rows: usize) -> HeightGrid {
    let mut heights = Vec::new();
    for row in 0..rows {
        for col in 0..cols {
            let (x, y) = (-1.0 + col as f64 * 0.1, 2.0 + row as f64 * 0.1);
            heights.push((0.5 * x - 0.25 * y + 1.0) as f32);
        }
    }
    HeightGrid::new(0.1, (-1.0, 2.0), cols, rows, heights).unwrap()
}

fn plane(x: f64, y: f64) -> f64 {
    0.5 * x - 0.25 * y + 1.0
}

#[test]
fn height_grid_text_format() {
    let text = "HEIGHTGRID v1 3 2 0.05 10.0 -4.5\n0.1 nan 0.3\n1 2 NaN\n\n";
    let grid = HeightGrid::parse(text).unwrap();
    assert_eq!((grid.cols, grid.rows, grid.resolution_m, grid.origin_m), (3, 2, 0.05, (10.0, -4.5)));
    assert_eq!(grid.height_at_cell_m(0, 1), Some(1.0));
    assert_eq!(grid.height_at_cell_m(1, 0), None);
    assert_eq!(grid.height_at_cell_m(3, 0), None);
    assert_eq!(grid.known_cells(), 4);
    assert!((grid.cell_centre_m(2, 1) - Point2::new(10.1, -4.45)).norm() < 1e-12);
    assert_eq!(HeightGrid::parse(&grid.to_text()).unwrap().to_text(), grid.to_text());
}

#[test]
fn height_grid_errors() {
    use HeightGridError::*;
    assert_eq!(HeightGrid::parse(""), Err(BadMagic));
    assert_eq!(HeightGrid::parse("HEIGHTGRID v2 1 1 1 0 0\n0\n"), Err(BadMagic));
    assert_eq!(HeightGrid::parse("HEIGHTGRID v1 1 1 1 0\n0\n"), Err(BadMagic));
    assert_eq!(HeightGrid::parse("HEIGHTGRID v12 1 1 0 0\n0\n"), Err(BadMagic));
    assert!(matches!(HeightGrid::parse("HEIGHTGRID v1 -1 1 1 0 0\n"), Err(BadHeader { field: "cols", .. })));
    assert!(matches!(HeightGrid::parse("HEIGHTGRID v1 1 1 0 0 0\n0\n"), Err(BadHeader { field: "resolution_m", .. })));
    assert!(matches!(HeightGrid::parse("HEIGHTGRID v1 0 0 1 0 0\n"), Err(BadHeader { field: "cols/rows", .. })));
    assert_eq!(
        HeightGrid::parse("HEIGHTGRID v1 2 2 1 0 0\n1 2\n3\n"),
        Err(RowLength { line: 3, found: 1, expected: 2 })
    );
    assert_eq!(HeightGrid::parse("HEIGHTGRID v1 2 2 1 0 0\n1 2\n"), Err(RowCount { found: 1, expected: 2 }));
    assert_eq!(HeightGrid::parse("HEIGHTGRID v1 1 1 1 0 0\n1\n2\n"), Err(RowCount { found: 2, expected: 1 }));
    assert_eq!(
        HeightGrid::parse("HEIGHTGRID v1 2 1 1 0 0\n1 inf\n"),
        Err(BadHeight { line: 2, value: 2, token: "inf".into() })
    );
    assert_eq!(
        HeightGrid::parse(&format!("HEIGHTGRID v1 {} 2 1 0 0\n", usize::MAX)),
        Err(SizeMismatch { len: 0, cols: usize::MAX, rows: 2 })
    );
    assert_eq!(HeightGrid::new(1.0, (0.0, 0.0), 2, 2, vec![0.0; 3]), Err(SizeMismatch { len: 3, cols: 2, rows: 2 }));
}

#[test]
fn bilinear_sampling_reproduces_a_plane_and_respects_unknown_cells() {
    let mut grid = plane_grid(5, 4);
    for (x, y) in [(-1.0, 2.0), (-0.93, 2.11), (-0.6, 2.3), (-0.77, 2.25)] {
        assert!((grid.sample_bilinear_m(x, y).unwrap() - plane(x, y)).abs() < 1e-6, "({x}, {y})");
    }
    // Past the outermost centre, inside the last half cell: held at the edge value.
    let edge = grid.sample_bilinear_m(-1.04, 2.0).unwrap();
    assert!((edge - plane(-1.0, 2.0)).abs() < 1e-6);
    assert_eq!(grid.sample_bilinear_m(-1.06, 2.0), None);
    assert_eq!(grid.sample_bilinear_m(f64::NAN, 2.0), None);
    // An unknown neighbour drops out; an unknown containing cell makes the sample unknown.
    grid.heights_m[1] = f32::NAN; // cell (1, 0) at x = −0.9
    assert_eq!(grid.sample_bilinear_m(-0.9, 2.0), None);
    let h = grid.sample_bilinear_m(-0.96, 2.0).unwrap();
    assert!((h - plane(-1.0, 2.0)).abs() < 1e-6, "only cell (0, 0) is known on that edge: {h}");
}

proptest! {
    #[test]
    fn height_grid_never_panics_on_arbitrary_text(text in "(HEIGHTGRID v1 )?[0-9 .naNe\\-\n]{0,80}") {
        let _ = HeightGrid::parse(&text);
    }

    #[test]
    fn height_grid_never_panics_on_arbitrary_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..256)) {
        let _ = HeightGrid::parse(&String::from_utf8_lossy(&bytes));
    }

    #[test]
    fn height_grid_round_trips(
        cols in 1usize..6,
        rows in 1usize..6,
        resolution_m in 0.01..2.0f64,
        origin_m in (-1e4..1e4f64, -1e4..1e4f64),
        seed in proptest::collection::vec(prop_oneof![Just(f32::NAN), -1e3f32..1e3], 36),
    ) {
        let grid = HeightGrid::new(resolution_m, origin_m, cols, rows, seed[..cols * rows].to_vec()).unwrap();
        let back = HeightGrid::parse(&grid.to_text()).unwrap();
        prop_assert_eq!(back.to_text(), grid.to_text());
        prop_assert_eq!((back.cols, back.rows, back.resolution_m, back.origin_m), (cols, rows, resolution_m, origin_m));
        for (a, b) in back.heights_m.iter().zip(&grid.heights_m) {
            prop_assert!(a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan()));
        }
    }
}

// ------------------------------------------------------------------------------------------------
// Height error
// ------------------------------------------------------------------------------------------------

#[test]
fn error_stats_known_answers() {
    let s = ErrorStats::from_errors(&[1.0, -1.0, 2.0, -2.0, f64::NAN]).unwrap();
    assert_eq!(s.count, 4);
    assert!(close(s.rmse_m, 2.5f64.sqrt()));
    assert!(close(s.mean_m, 0.0));
    assert!(close(s.std_m, 2.5f64.sqrt()));
    assert!(close(s.median_abs_m, 1.5));
    assert!(close(s.p95_abs_m, 2.0));
    assert!(close(s.max_abs_m, 2.0));
    let one = ErrorStats::from_errors(&[-0.3]).unwrap();
    assert!(close(one.mean_m, -0.3) && close(one.median_abs_m, 0.3) && close(one.std_m, 0.0));
    assert_eq!(ErrorStats::from_errors(&[]), None);
}

#[test]
fn cloud_height_error_counts_outside_and_unknown_apart() {
    let mut gt = plane_grid(10, 10); // x ∈ [−1.05, −0.05), y ∈ [1.95, 2.95)
    gt.heights_m[99] = f32::NAN; // cell (9, 9)
    let on = |x: f64, y: f64, dz: f64| Point3::new(x, y, plane(x, y) + dz);
    let points = [
        on(-1.0, 2.0, 0.1),
        on(-0.52, 2.33, -0.1),
        on(-0.52, 2.34, 0.3), // same cell as the one before
        on(-0.1, 2.9, 0.0),   // in the unknown cell (9, 9)
        on(0.5, 2.5, 0.0),    // east of the grid
        Point3::new(f64::NAN, 2.5, 0.0),
    ];
    let report = cloud_height_error(&points, &gt);
    let stats = report.stats.unwrap();
    assert_eq!((stats.count, report.unknown_gt, report.outside_gt), (3, 1, 2));
    assert!((stats.mean_m - 0.1).abs() < 1e-6);
    assert!((stats.rmse_m - (0.11f64 / 3.0).sqrt()).abs() < 1e-6);
    assert!((stats.max_abs_m - 0.3).abs() < 1e-6);
    assert!(close(report.coverage_fraction, 2.0 / 99.0));

    let empty = cloud_height_error(&[], &gt);
    assert_eq!((empty.stats, empty.outside_gt, empty.unknown_gt, empty.coverage_fraction), (None, 0, 0, 0.0));
}

#[test]
fn grid_height_error_compares_known_cells_across_resolutions() {
    let gt = plane_grid(20, 20); // 0.1 m cells
    // The map: 0.2 m cells over the western half of the ground truth, 5 cm too high, with one
    // unknown cell and one column hanging off the ground truth's western edge.
    let (cols, rows) = (6, 10);
    // Offsets of 2 and 1 cm keep every ground-truth centre off the map's cell edges.
    let origin = (-1.18, 2.01);
    let mut heights = Vec::new();
    for row in 0..rows {
        for col in 0..cols {
            let (x, y) = (origin.0 + col as f64 * 0.2, origin.1 + row as f64 * 0.2);
            heights.push((plane(x, y) + 0.05) as f32);
        }
    }
    heights[cols + 2] = f32::NAN;
    let map = HeightGrid::new(0.2, origin, cols, rows, heights).unwrap();
    let report = grid_height_error(&map, &gt);
    let stats = report.stats.unwrap();
    assert_eq!(report.outside_gt, rows); // column 0 at x = −1.18
    assert_eq!(report.unknown_gt, 0);
    assert_eq!(stats.count, cols * rows - rows - 1);
    assert!((stats.mean_m - 0.05).abs() < 1e-6 && stats.std_m < 1e-6);
    // The map's known cells at x ∈ [−1.08, −0.08) hold the ground-truth centres of columns
    // 0..=9 (x = −1.0 … −0.1), all rows; minus the 4 centres in the unknown map cell (2, 1).
    assert!(close(report.coverage_fraction, (10.0 * 20.0 - 4.0) / 400.0), "{}", report.coverage_fraction);
}

// ------------------------------------------------------------------------------------------------
// Obstacles
// ------------------------------------------------------------------------------------------------

fn rock(x: f64, y: f64, radius_m: f64) -> TrueObstacle {
    TrueObstacle { centre_m: Point2::new(x, y), radius_m }
}

const MATCHING: ObstacleMatching = ObstacleMatching { tolerance_m: 0.1, link_distance_m: 0.075 };

/// Cell centres at 5 cm spacing of a `w` × `h` block whose lower-left cell is at (x, y).
fn block(x: f64, y: f64, w: usize, h: usize) -> Vec<Point2<f64>> {
    (0..h).flat_map(|j| (0..w).map(move |i| Point2::new(x + i as f64 * 0.05, y + j as f64 * 0.05))).collect()
}

#[test]
fn obstacle_precision_and_recall_per_cluster() {
    let truth = [rock(0.0, 0.0, 0.3), rock(0.8, 0.0, 0.3), rock(5.0, 5.0, 0.2)];
    let mut detections = block(-0.1, -0.1, 3, 3); // on rock 0: true positive cluster of 9
    detections.extend(block(3.0, 0.0, 2, 1)); // far from everything: a false positive cluster of 2
    detections.push(Point2::new(0.65, 0.0)); // on rock 1, within the tolerance band
    let report = evaluate_obstacles(&detections, &truth, &MATCHING).unwrap();
    assert_eq!(
        (report.detections, report.detections_matched, report.clusters, report.clusters_matched),
        (12, 10, 3, 2)
    );
    assert_eq!((report.obstacles, report.obstacles_found), (3, 2));
    assert!(close(report.precision().unwrap(), 2.0 / 3.0));
    assert!(close(report.point_precision().unwrap(), 10.0 / 12.0));
    assert!(close(report.recall().unwrap(), 2.0 / 3.0));
    assert!(close(report.f1().unwrap(), 2.0 / 3.0));
}

#[test]
fn obstacle_clusters_need_a_matched_majority() {
    let truth = [rock(0.0, 0.0, 0.2), rock(0.45, 0.0, 0.2)];
    // A strip from x = −0.1 to 0.55 bridges both rocks: one cluster, all matched.
    let bridge = block(-0.1, 0.0, 14, 1);
    let report = evaluate_obstacles(&bridge, &truth, &MATCHING).unwrap();
    assert_eq!((report.clusters, report.clusters_matched, report.obstacles_found), (1, 1, 2));
    // A strip from x = 0.0 to 1.95 touches rock 0 only with its first 6 of 40 cells.
    let smear = block(0.0, 0.0, 40, 1);
    let report = evaluate_obstacles(&smear, &[rock(0.0, 0.0, 0.2)], &MATCHING).unwrap();
    assert_eq!((report.clusters, report.clusters_matched, report.detections_matched), (1, 0, 7));
    assert_eq!(report.recall(), Some(1.0));
    assert_eq!(report.precision(), Some(0.0));
}

#[test]
fn obstacle_edge_cases() {
    let truth = [rock(0.0, 0.0, 0.3)];
    let none = evaluate_obstacles(&[], &truth, &MATCHING).unwrap();
    assert_eq!((none.precision(), none.point_precision(), none.recall(), none.f1()), (None, None, Some(0.0), None));

    let false_alarm = evaluate_obstacles(&[Point2::new(2.0, 0.0)], &[], &MATCHING).unwrap();
    assert_eq!((false_alarm.precision(), false_alarm.recall()), (Some(0.0), None));

    let nothing = evaluate_obstacles(&[], &[], &MATCHING).unwrap();
    assert_eq!(nothing, Default::default());

    let miss = evaluate_obstacles(&[Point2::new(2.0, 0.0)], &truth, &MATCHING).unwrap();
    assert_eq!(miss.f1(), Some(0.0));

    let bad = |tolerance_m, link_distance_m| ObstacleMatching { tolerance_m, link_distance_m };
    assert_eq!(evaluate_obstacles(&[], &truth, &bad(-0.1, 0.1)), Err(ObstacleEvalError::Tolerance(-0.1)));
    assert_eq!(evaluate_obstacles(&[], &truth, &bad(0.1, 0.0)), Err(ObstacleEvalError::LinkDistance(0.0)));
    assert_eq!(
        evaluate_obstacles(&[Point2::new(0.0, f64::INFINITY)], &truth, &MATCHING),
        Err(ObstacleEvalError::NonFiniteDetection { index: 0 })
    );
    assert_eq!(
        evaluate_obstacles(&[], &[rock(0.0, 0.0, -1.0)], &MATCHING),
        Err(ObstacleEvalError::BadObstacle { index: 0 })
    );
}

#[test]
fn obstacle_flags_from_a_grid_and_the_mapped_area() {
    // A flag grid in the height-grid format: 1 = obstacle, 0 = free, nan = unseen.
    let flags = HeightGrid::parse("HEIGHTGRID v1 4 3 0.5 0 0\n0 1 1 0\n0 1 nan nan\nnan nan nan nan\n").unwrap();
    let detections = flags.cell_centres_where(|v| v > 0.5);
    assert_eq!(detections, vec![Point2::new(0.5, 0.0), Point2::new(1.0, 0.0), Point2::new(0.5, 0.5)]);

    let truth = [
        rock(0.6, 0.2, 0.3),   // centre on a known cell, detected
        rock(1.5, 0.0, 0.1),   // centre on a known free cell: seen but missed
        rock(1.5, 0.9, 0.4),   // every cell its footprint reaches is unseen
        rock(1.3, 0.25, 0.35), // centre cell unseen, but the known cell centre (1.5, 0) is 0.32 m away
    ];
    let mapped = obstacles_in_mapped_area(&truth, &flags);
    assert_eq!(mapped, vec![truth[0], truth[1], truth[3]]);
    let matching = ObstacleMatching { tolerance_m: 0.05, link_distance_m: 0.75 };
    let report = evaluate_obstacles(&detections, &mapped, &matching).unwrap();
    assert_eq!((report.clusters, report.clusters_matched, report.obstacles_found), (1, 1, 2));
}

#[test]
fn terrain_points_exclude_rock_footprints() {
    let points = [Point3::new(0.0, 0.0, 1.0), Point3::new(0.35, 0.0, 0.1), Point3::new(0.45, 0.0, 0.0)];
    let kept = points_away_from_obstacles(&points, &[rock(0.0, 0.0, 0.3)], 0.1);
    assert_eq!(kept, vec![points[2]]);
}
