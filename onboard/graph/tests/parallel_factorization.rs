//! The two-thread factorization against the sequential one: same arithmetic per clique, so the
//! optimized values must agree bit for bit.
#![allow(clippy::unwrap_used)]

mod common;

use common::load;
use posegraph::{LmParams, optimize};

fn optimized_bits(name: &str, threads: usize) -> (Vec<u64>, usize, usize) {
    let mut problem = load(name);
    let params = LmParams { threads, ..LmParams::default() };
    let summary = optimize(&problem.factors, &mut problem.values, &params).unwrap();
    let bits = problem
        .values
        .poses()
        .iter()
        .flat_map(|p| {
            p.translation.vector.iter().chain(p.rotation.coords.iter()).map(|x| x.to_bits()).collect::<Vec<_>>()
        })
        .chain([summary.final_cost.to_bits()])
        .collect();
    (bits, summary.factorizations, summary.threaded_factorizations)
}

#[test]
fn two_threads_give_bit_identical_results() {
    for name in ["sphere2500.g2o", "parking-garage.g2o"] {
        let (sequential, factorizations, threaded) = optimized_bits(name, 1);
        assert_eq!(threaded, 0, "{name}: one thread must stay sequential");
        let (parallel, parallel_factorizations, threaded) = optimized_bits(name, 2);
        assert_eq!(threaded, parallel_factorizations, "{name}: every factorization should be threaded");
        assert_eq!(factorizations, parallel_factorizations, "{name}");
        assert!(sequential == parallel, "{name}: results differ between 1 and 2 threads");
    }
}

#[test]
fn small_graphs_stay_on_one_thread() {
    let mut problem = load("smallGrid3D.g2o");
    let params = LmParams { threads: 2, ..LmParams::default() };
    let summary = optimize(&problem.factors, &mut problem.values, &params).unwrap();
    assert_eq!(summary.threaded_factorizations, 0);
}
