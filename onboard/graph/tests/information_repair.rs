#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Edges whose information is not positive definite, as in SE-Sync's cubicle (not on this
//! machine): a real dataset with a few edges' information made indefinite or singular in a
//! rotational direction, written as g2o text, then rejected with its line or repaired and solved.

mod common;

use nalgebra::{Matrix3, Matrix6};
use proptest::prelude::*;
use proptest::test_runner::Config;

use posegraph::dataset;
use posegraph::g2o::{self, G2oErrorKind, G2oGraph, InformationPolicy};
use posegraph::information::{self, ABSOLUTE_EIGEN_FLOOR, EigenFloor, RepairError};
use posegraph::{GraphError, LmParams};

/// How an edge's information is broken, in the file's `[translation, rotation]` order.
#[derive(Debug, Clone, Copy)]
enum Break {
    /// A negative pitch information: eigenvalue −0.5 along pitch.
    NegativePitch,
    /// No yaw information at all (row and column zero): a zero eigenvalue.
    NoYaw,
    /// Roll–pitch cross term larger than the diagonal (≈ 4): eigenvalue ≈ −2 along a mixed
    /// direction, the kind a wrong covariance-to-information conversion produces.
    CoupledRollPitch,
}

/// Token index of the information entry `(row, col)`, `row ≤ col`, in an `EDGE_SE3:QUAT` line.
fn se3_information_token(row: usize, col: usize) -> usize {
    10 + 6 * row - row * row.saturating_sub(1) / 2 + (col - row)
}

/// The edge as broken: (1-based line, from, to).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Broken {
    line: usize,
    from: u64,
    to: u64,
}

/// Breaks the information of the `EDGE_SE3:QUAT` records at the given edge ordinals, keeping
/// every line where it was.
fn break_edges(text: &str, breaks: &[(usize, Break)]) -> (String, Vec<Broken>) {
    let mut broken = Vec::new();
    let mut edge_ordinal = 0;
    let lines: Vec<String> = text
        .lines()
        .enumerate()
        .map(|(index, line)| {
            if !line.starts_with("EDGE_SE3:QUAT") {
                return line.to_owned();
            }
            let ordinal = edge_ordinal;
            edge_ordinal += 1;
            let Some(&(_, kind)) = breaks.iter().find(|(at, _)| *at == ordinal) else { return line.to_owned() };
            let mut tokens: Vec<String> = line.split_whitespace().map(str::to_owned).collect();
            let mut set = |row: usize, col: usize, value: &str| tokens[se3_information_token(row, col)] = value.into();
            match kind {
                Break::NegativePitch => set(4, 4, "-0.5"),
                Break::NoYaw => {
                    for row in 0..6 {
                        set(row, 5, "0");
                    }
                }
                Break::CoupledRollPitch => set(3, 4, "6"),
            }
            broken.push(Broken { line: index + 1, from: tokens[1].parse().unwrap(), to: tokens[2].parse().unwrap() });
            tokens.join(" ")
        })
        .collect();
    (lines.join("\n") + "\n", broken)
}

/// Loop closures of parking-garage (ordinals among its edges), one per kind of break.
const PARKING_GARAGE_BREAKS: [(usize, Break); 3] =
    [(789, Break::NegativePitch), (1051, Break::NoYaw), (3000, Break::CoupledRollPitch)];

fn parking_garage() -> String {
    std::fs::read_to_string(common::data_path("parking-garage.g2o")).unwrap()
}

fn bits(matrix: &Matrix6<f64>) -> Vec<u64> {
    matrix.iter().map(|v| v.to_bits()).collect()
}

/// Same vertices, and every edge's information bit for bit, except at the `skip` edge indices.
fn assert_identical_except(a: &G2oGraph, b: &G2oGraph, skip: &[usize]) {
    assert_eq!(a.vertices, b.vertices);
    assert_eq!(a.edges.len(), b.edges.len());
    for (index, (ea, eb)) in a.edges.iter().zip(&b.edges).enumerate() {
        assert_eq!((ea.from, ea.to, ea.measurement), (eb.from, eb.to, eb.measurement));
        if !skip.contains(&index) {
            assert_eq!(bits(&ea.information), bits(&eb.information), "edge {index}: {}-{}", ea.from, ea.to);
        }
    }
}

#[test]
fn the_token_map_follows_the_row_major_upper_triangle() {
    assert_eq!(se3_information_token(0, 0), 10);
    assert_eq!(se3_information_token(0, 5), 15);
    assert_eq!(se3_information_token(1, 1), 16);
    assert_eq!(se3_information_token(3, 3), 25);
    assert_eq!(se3_information_token(3, 4), 26);
    assert_eq!(se3_information_token(4, 4), 28);
    assert_eq!(se3_information_token(5, 5), 30);
}

#[test]
fn indefinite_information_is_rejected_with_its_line_and_edge() {
    let (text, broken) = break_edges(&parking_garage(), &PARKING_GARAGE_BREAKS);
    assert_eq!(broken.len(), 3);
    let error = g2o::parse_with(&text, InformationPolicy::Reject).unwrap_err();
    assert_eq!(error.line, broken[0].line);
    let G2oErrorKind::NotPositiveDefinite { from, to, smallest_eigenvalue } = error.kind else { panic!("{error}") };
    assert_eq!((from, to), (broken[0].from, broken[0].to));
    // −0.5 on the pitch diagonal, shifted slightly by the file's small rotational cross terms.
    assert!((smallest_eigenvalue + 0.5).abs() < 1e-3, "{smallest_eigenvalue}");
    let message = error.to_string();
    let expected =
        format!("line {}: edge {} → {}: information matrix is not positive definite", broken[0].line, from, to);
    assert!(message.starts_with(&expected), "{message}");

    // Each kind of break on its own is caught at its own line.
    for (ordinal, kind) in PARKING_GARAGE_BREAKS {
        let (text, broken) = break_edges(&parking_garage(), &[(ordinal, kind)]);
        let error = g2o::parse_with(&text, InformationPolicy::default()).unwrap_err();
        assert_eq!(error.line, broken[0].line, "{kind:?}");
        let G2oErrorKind::NotPositiveDefinite { smallest_eigenvalue, .. } = error.kind else { panic!("{error}") };
        assert!(smallest_eigenvalue <= 0.0, "{kind:?}: {smallest_eigenvalue}");
    }

    // The unchecked reader still takes the file; building the problem then names the edge.
    let unchecked = g2o::parse(&text).unwrap();
    let error = dataset::from_g2o(&unchecked, None).unwrap_err();
    assert_eq!(
        error,
        GraphError::InvalidEdgeNoise {
            from: broken[0].from,
            to: broken[0].to,
            reason: "information is not positive definite"
        }
    );
}

#[test]
fn repaired_parking_garage_optimizes_to_the_clean_optimum() {
    let clean_text = parking_garage();
    let (text, broken) = break_edges(&clean_text, &PARKING_GARAGE_BREAKS);
    let clean = g2o::parse(&clean_text).unwrap();
    let checked = g2o::parse_with(&text, InformationPolicy::repair()).unwrap();

    let listed: Vec<Broken> =
        checked.repaired_edges.iter().map(|edge| Broken { line: edge.line, from: edge.from, to: edge.to }).collect();
    assert_eq!(listed, broken);
    let indices: Vec<usize> = PARKING_GARAGE_BREAKS.iter().map(|(ordinal, _)| *ordinal).collect();
    assert_identical_except(&clean, &checked.graph, &indices);
    for (repaired, &index) in checked.repaired_edges.iter().zip(&indices) {
        let information = checked.graph.edges[index].information;
        let eigenvalues = information.symmetric_eigenvalues();
        assert!(information.cholesky().is_some(), "{information}");
        assert!(eigenvalues.min() >= repaired.eigen_floor * (1.0 - 1e-6), "{eigenvalues}");
        // The floor is 10⁻⁶ of the largest eigenvalue (≈ 4 for the rotation, 10 for coupling).
        assert!(repaired.eigen_floor > 1e-6 && repaired.eigen_floor < 2e-5, "{repaired:?}");
        assert!(repaired.smallest_eigenvalue_before <= 0.0, "{repaired:?}");
        assert!(repaired.frobenius_change > 0.0 && repaired.frobenius_change < 5.0, "{repaired:?}");
    }
    assert!((checked.repaired_edges[0].smallest_eigenvalue_before + 0.5).abs() < 1e-3);
    assert!((checked.repaired_edges[2].smallest_eigenvalue_before + 2.0).abs() < 0.1);

    let params = LmParams::default();
    let mut clean_problem = dataset::from_g2o(&clean, None).unwrap();
    let clean_summary = posegraph::optimize(&clean_problem.factors, &mut clean_problem.values, &params).unwrap();
    let mut problem = dataset::from_g2o(&checked.graph, None).unwrap();
    let summary = posegraph::optimize(&problem.factors, &mut problem.values, &params).unwrap();
    let relative = (summary.final_cost - clean_summary.final_cost) / clean_summary.final_cost;
    let mut max_shift_m: f64 = 0.0;
    for ((_, a), (_, b)) in clean_problem.values.iter().zip(problem.values.iter()) {
        max_shift_m = max_shift_m.max((a.translation.vector - b.translation.vector).norm());
    }
    println!(
        "parking-garage, 3 edges repaired: final cost {:.9} against {:.9} clean ({relative:+.2e}), {} against {} iterations, largest pose shift {max_shift_m:.2e} m",
        summary.final_cost, clean_summary.final_cost, summary.iterations, clean_summary.iterations
    );
    // Measured: −3.9e-6 and 0.4 mm.
    assert!(relative.abs() < 1e-4, "{relative}");
    assert!(max_shift_m < 0.005, "{max_shift_m}");
}

#[test]
fn positive_definite_files_come_back_bit_identical() {
    for name in ["parking-garage.g2o", "sphere2500.g2o", "smallGrid3D.g2o", "intel.g2o", "sphere2500_groundtruth.g2o"] {
        let text = std::fs::read_to_string(common::data_path(name)).unwrap();
        let plain = g2o::parse(&text).unwrap();
        for policy in [InformationPolicy::Reject, InformationPolicy::repair()] {
            let checked = g2o::parse_with(&text, policy).unwrap();
            assert!(checked.repaired_edges.is_empty(), "{name}");
            assert_identical_except(&plain, &checked.graph, &[]);
            assert_eq!(plain, checked.graph);
        }
    }
}

#[test]
fn planar_information_is_repaired_before_lifting() {
    let text = std::fs::read_to_string(common::data_path("intel.g2o")).unwrap();
    // EDGE_SE2 i j dx dy dθ I11 I12 I13 I22 I23 I33: make I33 (yaw) negative on the 100th edge.
    let mut line_number = 0;
    let mut ordinal = 0;
    let broken_text: Vec<String> = text
        .lines()
        .enumerate()
        .map(|(index, line)| {
            if !line.starts_with("EDGE_SE2") {
                return line.to_owned();
            }
            ordinal += 1;
            if ordinal != 100 {
                return line.to_owned();
            }
            line_number = index + 1;
            let mut tokens: Vec<&str> = line.split_whitespace().collect();
            tokens[11] = "-3";
            tokens.join(" ")
        })
        .collect();
    let broken_text = broken_text.join("\n");
    let error = g2o::parse_with(&broken_text, InformationPolicy::Reject).unwrap_err();
    assert_eq!(error.line, line_number);
    let G2oErrorKind::NotPositiveDefinite { smallest_eigenvalue, .. } = error.kind else { panic!("{error}") };
    assert!(smallest_eigenvalue < 0.0);

    let clean = g2o::parse(&text).unwrap();
    let checked = g2o::parse_with(&broken_text, InformationPolicy::repair()).unwrap();
    assert_eq!(checked.repaired_edges.len(), 1);
    assert_eq!(checked.repaired_edges[0].line, line_number);
    assert_identical_except(&clean, &checked.graph, &[99]);
    let lifted = checked.graph.edges[99].information;
    assert!(lifted.cholesky().is_some());
    // Roll and pitch take the repaired yaw information, as the lifting of a clean edge does.
    assert_eq!(lifted[(3, 3)], lifted[(5, 5)]);
    assert_eq!(lifted[(4, 4)], lifted[(5, 5)]);
    let planar = Matrix3::from_fn(|row, col| lifted[([0, 1, 5][row], [0, 1, 5][col])]);
    let floor = checked.repaired_edges[0].eigen_floor;
    assert!(planar.symmetric_eigenvalues().min() >= floor * (1.0 - 1e-6), "{planar}");
    let mut problem = dataset::from_g2o(&checked.graph, None).unwrap();
    let initial = posegraph::total_cost(&problem.factors, &problem.values).unwrap();
    let summary = posegraph::optimize(&problem.factors, &mut problem.values, &LmParams::default()).unwrap();
    assert!(summary.final_cost < initial);
}

#[test]
fn a_floor_outside_its_range_is_refused() {
    assert_eq!(EigenFloor::new(0.0), Err(GraphError::InvalidEigenFloor(0.0)));
    assert_eq!(EigenFloor::default().relative(), information::DEFAULT_RELATIVE_EIGEN_FLOOR);
}

/// Symmetric matrices with entries over many magnitudes, as `(mantissa, exponent)` pairs.
fn symmetric<const N: usize>(max_exponent: i32) -> impl Strategy<Value = nalgebra::SMatrix<f64, N, N>> {
    prop::collection::vec((-1.0f64..1.0, -max_exponent..=max_exponent), N * (N + 1) / 2).prop_map(|entries| {
        let mut matrix = nalgebra::SMatrix::<f64, N, N>::zeros();
        let mut entries = entries.into_iter();
        for row in 0..N {
            for col in row..N {
                let (mantissa, exponent) = entries.next().unwrap();
                let value = mantissa * 10f64.powi(exponent);
                matrix[(row, col)] = value;
                matrix[(col, row)] = value;
            }
        }
        matrix
    })
}

/// A repaired matrix is exactly symmetric, passes Cholesky, and no eigenvalue is below the floor
/// (up to the rebuild's rounding).
fn check_repaired<const N: usize>(
    input: &nalgebra::SMatrix<f64, N, N>,
    repaired: &information::Repaired<nalgebra::SMatrix<f64, N, N>>,
) -> Result<(), TestCaseError> {
    let matrix = repaired.matrix;
    prop_assert_eq!(matrix, matrix.transpose());
    prop_assert!(matrix.cholesky().is_some(), "{} from {}", matrix, input);
    // Scaled to unit magnitude, so that the check's own eigen-solver does not overflow.
    let scale = matrix.amax();
    let smallest =
        nalgebra::DMatrix::from_iterator(N, N, matrix.iter().map(|v| v / scale)).symmetric_eigenvalues().min() * scale;
    prop_assert!(smallest >= repaired.eigen_floor * (1.0 - 1e-6), "{} < floor {}", smallest, repaired.eigen_floor);
    prop_assert!(repaired.eigen_floor >= ABSOLUTE_EIGEN_FLOOR);
    prop_assert!(repaired.frobenius_change.is_finite());
    Ok(())
}

fn property_config() -> Config {
    Config { cases: 5_000, failure_persistence: None, ..Config::default() }
}

proptest! {
    #![proptest_config(property_config())]

    #[test]
    fn any_finite_symmetric_6x6_is_repaired_to_positive_definite(input in symmetric::<6>(12)) {
        let repaired = information::repair6(&input, EigenFloor::default()).unwrap();
        check_repaired(&input, &repaired)?;
    }

    #[test]
    fn any_finite_symmetric_3x3_is_repaired_to_positive_definite(input in symmetric::<3>(12)) {
        let repaired = information::repair3(&input, EigenFloor::default()).unwrap();
        check_repaired(&input, &repaired)?;
    }

    /// Near the ends of f64's range a repair may not be representable; it then fails with an
    /// error, never a panic or a matrix that is not positive definite.
    #[test]
    fn extreme_magnitudes_are_repaired_or_refused(input in symmetric::<6>(307)) {
        match information::repair6(&input, EigenFloor::default()) {
            Ok(repaired) => check_repaired(&input, &repaired)?,
            Err(error) => prop_assert_eq!(error, RepairError::Overflow),
        }
    }

    #[test]
    fn non_finite_entries_are_an_error(
        input in symmetric::<6>(6),
        row in 0usize..6,
        col in 0usize..6,
        bad in prop::sample::select(&[f64::NAN, f64::INFINITY, f64::NEG_INFINITY][..]),
    ) {
        let mut input = input;
        input[(row, col)] = bad;
        prop_assert_eq!(information::repair6(&input, EigenFloor::default()), Err(RepairError::NonFinite));
        let mut planar = Matrix3::identity();
        planar[(row % 3, col % 3)] = bad;
        prop_assert_eq!(information::repair3(&planar, EigenFloor::default()), Err(RepairError::NonFinite));
    }
}
