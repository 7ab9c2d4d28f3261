//! The seeded generators of `posegraph::synthetic`: the same seed gives the same bytes, the
//! committed `data/posegraph/*_gen.g2o` files are exactly the generator's output, and the graphs
//! have the structure and noise the module documents.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use posegraph::synthetic::{self, GridSpec, Noise, TorusSpec};
use posegraph::{g2o, se3};

fn text(graph: &g2o::G2oGraph) -> String {
    let mut out = String::new();
    g2o::write(graph, &mut out).unwrap();
    out
}

#[test]
fn same_seed_same_bytes_other_seed_other_bytes() {
    let spec = TorusSpec { rings: 6, poses_per_ring: 8, ..TorusSpec::default() };
    let a = text(&synthetic::torus(&spec, 7));
    assert_eq!(a, text(&synthetic::torus(&spec, 7)));
    assert_ne!(a, text(&synthetic::torus(&spec, 8)));
    let spec = GridSpec { side: 4, ..GridSpec::default() };
    let b = text(&synthetic::grid(&spec, 7));
    assert_eq!(b, text(&synthetic::grid(&spec, 7)));
    assert_ne!(b, text(&synthetic::grid(&spec, 8)));
}

/// The files' provenance (`data/posegraph/SOURCE.md`): `make_graph torus|grid --seed 1`. On a
/// platform whose libm rounds `sin`/`cos`/`ln` differently the last digits could differ; then
/// this test, not the benchmark, is what breaks.
#[test]
fn committed_files_are_the_generators_output() {
    let torus = std::fs::read_to_string(common::data_path("torus3D_gen.g2o")).unwrap();
    assert!(torus == text(&synthetic::torus(&TorusSpec::default(), 1)), "torus3D_gen.g2o differs from seed 1");
    let grid = std::fs::read_to_string(common::data_path("grid3D_gen.g2o")).unwrap();
    assert!(grid == text(&synthetic::grid(&GridSpec::default(), 1)), "grid3D_gen.g2o differs from seed 1");
}

#[test]
fn edges_are_odometry_plus_neighbour_closures() {
    let torus = synthetic::torus(&TorusSpec::default(), 1);
    assert_eq!(torus.vertices.len(), 5000);
    // 4,999 odometry edges plus 80 % of 5,000 candidates, within 4σ of the binomial.
    let closures = torus.edges.len() - 4999;
    assert!(closures.abs_diff(4000) < 4 * 29, "{closures}");
    for e in &torus.edges {
        let gap = e.to - e.from;
        // Same tube angle on the previous ring, or the last ring closing onto the first.
        assert!(gap == 1 || gap == 100 || gap == 4900, "{} -> {}", e.from, e.to);
    }
    let grid = synthetic::grid(&GridSpec::default(), 1);
    assert_eq!(grid.vertices.len(), 8000);
    // Lattice neighbours are 1 m apart in the ground truth; the measured distance is within
    // 5σ_t·√3 of it.
    for e in &grid.edges {
        let distance_m = e.measurement.translation.vector.norm();
        assert!((distance_m - 1.0).abs() < 0.5, "{} -> {}: {distance_m}", e.from, e.to);
    }
    let closures = grid.edges.len() - 7999;
    assert!(closures.abs_diff(14_209) < 4 * 24, "{closures}");
}

/// Vertex 0 is the identity and the initial values are the odometry composed from it.
#[test]
fn initial_values_compose_the_odometry() {
    let graph = synthetic::torus(&TorusSpec { rings: 5, poses_per_ring: 10, ..TorusSpec::default() }, 3);
    assert_eq!(graph.vertices[0].pose, nalgebra::Isometry3::identity());
    for e in graph.edges.iter().filter(|e| e.to == e.from + 1) {
        let composed = graph.vertices[e.from as usize].pose * e.measurement;
        let error = se3::local(&composed, &graph.vertices[e.to as usize].pose).norm();
        assert!(error < 1e-12, "{} -> {}: {error}", e.from, e.to);
    }
}

/// The information written is the inverse covariance of the drawn noise. The ground truth is
/// not returned, so the check is the optimum's cost: with consistent information it is about
/// ½χ² with 6(m − n + 1) degrees of freedom (m edges, n poses, the first anchored).
#[test]
fn optimum_cost_matches_the_noise_model() {
    let spec = GridSpec { side: 8, ..GridSpec::default() };
    let graph = synthetic::grid(&spec, 5);
    let mut problem = posegraph::dataset::from_g2o(&graph, None).unwrap();
    let summary = posegraph::optimize(&problem.factors, &mut problem.values, &Default::default()).unwrap();
    // Degrees of freedom: 6 per edge minus 6 per pose except the anchored first.
    let dof = 6.0 * (graph.edges.len() as f64 - graph.vertices.len() as f64 + 1.0);
    let expected = 0.5 * dof;
    let sd = (0.5 * dof).sqrt(); // sd of ½χ²(dof) is √(dof/2)
    assert!((summary.final_cost - expected).abs() < 4.0 * sd, "cost {} vs {expected} ± {sd}", summary.final_cost);
    let noise: Noise = spec.noise;
    assert_eq!(noise.information()[(0, 0)], 400.0);
    assert_eq!(noise.information()[(5, 5)], 10_000.0);
}
