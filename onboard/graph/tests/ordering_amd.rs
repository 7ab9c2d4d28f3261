//! Approximate minimum degree against exact minimum degree on the benchmark datasets, and AMD
//! with the batch solver on a generated 3-D pose graph too large for the exact ordering's bit
//! rows.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use posegraph::ordering::{self, approximate_min_degree, factor_nonzeros, min_degree};
use posegraph::{Factor, Key, LmParams, NoiseModel, Values, optimize};
use proptest::prelude::*;

fn variable_edges(factors: &[Factor], values: &Values) -> Vec<Vec<usize>> {
    factors.iter().map(|f| f.keys().iter().map(|&k| values.index_of(k).unwrap()).collect()).collect()
}

/// The variable graph of a g2o file from its edges alone (some files have no vertex records).
fn dataset_edges(name: &str) -> (usize, Vec<Vec<usize>>) {
    let text = std::fs::read_to_string(common::data_path(name)).unwrap();
    let graph = posegraph::g2o::parse(&text).unwrap();
    let mut ids: Vec<u64> = graph.edges.iter().flat_map(|e| [e.from, e.to]).collect();
    ids.sort_unstable();
    ids.dedup();
    let index = |id: u64| ids.binary_search(&id).unwrap();
    let edges = graph.edges.iter().map(|e| vec![index(e.from), index(e.to)]).collect();
    (ids.len(), edges)
}

fn is_permutation(order: &[usize], n: usize) -> bool {
    let mut seen = vec![false; n];
    order.len() == n && order.iter().all(|&v| v < n && !std::mem::replace(&mut seen[v], true))
}

#[test]
fn amd_fill_is_close_to_exact_minimum_degree_on_the_datasets() {
    for name in [
        "sphere2500.g2o",
        "parking-garage.g2o",
        "intel.g2o",
        "manhattan.g2o",
        "CSAIL.g2o",
        "MIT.g2o",
        "smallGrid3D.g2o",
    ] {
        let (n, edges) = dataset_edges(name);
        let exact = min_degree(n, edges.iter().map(Vec::as_slice), &[]);
        let amd = approximate_min_degree(n, edges.iter().map(Vec::as_slice), &[]);
        assert!(is_permutation(&amd.order, n), "{name}");
        let fill_exact = factor_nonzeros(n, edges.iter().map(Vec::as_slice), &exact);
        let fill_amd = factor_nonzeros(n, edges.iter().map(Vec::as_slice), &amd.order);
        let ratio = fill_amd as f64 / fill_exact as f64;
        println!("{name}: n {n}, factor blocks exact MD {fill_exact}, AMD {fill_amd}, ratio {ratio:.3}");
        assert!(ratio < 1.3, "{name}: AMD fill {fill_amd} vs exact {fill_exact}");
        // Small graphs keep the exact ordering bit for bit.
        assert_eq!(ordering::order(n, edges.iter().map(Vec::as_slice), &[]), exact, "{name}");
    }
}

#[test]
fn amd_puts_the_constrained_group_last() {
    let (n, edges) = dataset_edges("intel.g2o");
    let last: Vec<bool> = (0..n).map(|i| i % 7 == 3 || i >= n - 20).collect();
    let amd = approximate_min_degree(n, edges.iter().map(Vec::as_slice), &last);
    assert!(is_permutation(&amd.order, n));
    let constrained = last.iter().filter(|&&l| l).count();
    assert!(amd.order[n - constrained..].iter().all(|&v| last[v]));
}

/// A walk through an `nx × ny × nz` lattice (rows back and forth, layers stacked), one pose per
/// cell: odometry between consecutive poses, loop closures to the cell below in the previous
/// row and, where `x` is a multiple of `layer_stride`, to the cell in the previous layer.
pub fn lattice_problem(nx: usize, ny: usize, nz: usize, layer_stride: usize) -> (Vec<Factor>, Values) {
    let cell = |x: usize, y: usize, z: usize| (z * ny + y) * nx + x;
    let mut positions = vec![Vector3::zeros(); nx * ny * nz];
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                positions[cell(x, y, z)] = Vector3::new(x as f64, y as f64, z as f64);
            }
        }
    }
    // Walk order: the serpentine through the lattice.
    let mut walk = Vec::with_capacity(positions.len());
    for z in 0..nz {
        for yy in 0..ny {
            let y = if z.is_multiple_of(2) { yy } else { ny - 1 - yy };
            for xx in 0..nx {
                let x = if (z * ny + yy).is_multiple_of(2) { xx } else { nx - 1 - xx };
                walk.push(cell(x, y, z));
            }
        }
    }
    let mut index_of_cell = vec![0usize; positions.len()];
    for (i, &c) in walk.iter().enumerate() {
        index_of_cell[c] = i;
    }
    let pose = |c: usize| Isometry3::from_parts(Translation3::from(positions[c]), UnitQuaternion::identity());
    let noise = NoiseModel::from_sigmas([0.05, 0.05, 0.05, 0.01, 0.01, 0.01]).unwrap();
    let mut values = Values::new();
    let mut factors = vec![Factor::prior(
        Key(0),
        pose(walk[0]),
        NoiseModel::from_sigmas([0.01, 0.01, 0.01, 0.001, 0.001, 0.001]).unwrap(),
    )];
    for (i, &c) in walk.iter().enumerate() {
        // A drifting initial guess, so the optimizer has work to do.
        let drift = Isometry3::new(
            Vector3::new(0.001 * i as f64, 0.0, 0.0005 * i as f64),
            Vector3::new(0.0, 0.0, 1e-5 * i as f64),
        );
        values.insert(Key(i as u64), drift * pose(c)).unwrap();
        if i > 0 {
            let a = walk[i - 1];
            factors.push(Factor::between(Key(i as u64 - 1), Key(i as u64), pose(a).inverse() * pose(c), noise.clone()));
        }
    }
    let mut closures = 0;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let c = cell(x, y, z);
                let mut link = |other: usize| {
                    let (a, b) = (index_of_cell[other], index_of_cell[c]);
                    if a + 1 != b && b + 1 != a {
                        factors.push(Factor::between(
                            Key(a as u64),
                            Key(b as u64),
                            pose(other).inverse() * pose(c),
                            noise.clone(),
                        ));
                        closures += 1;
                    }
                };
                if y > 0 {
                    link(cell(x, y - 1, z));
                }
                if z > 0 && x.is_multiple_of(layer_stride) {
                    link(cell(x, y, z - 1));
                }
            }
        }
    }
    assert!(closures > 0);
    (factors, values)
}

#[test]
fn amd_orders_and_the_batch_solver_optimizes_a_50k_pose_lattice() {
    let (factors, mut values) = lattice_problem(50, 50, 20, 25);
    let n = values.len();
    assert!(n > ordering::EXACT_MAX_VARIABLES);
    let edges = variable_edges(&factors, &values);
    let amd = approximate_min_degree(n, edges.iter().map(Vec::as_slice), &[]);
    assert!(is_permutation(&amd.order, n));
    // O(nnz): the quotient graph never holds more than a small multiple of the input's entries,
    // where the exact ordering's bit rows would take n²/8 bytes.
    println!("n {n}, input entries {}, peak entries {}", amd.initial_entries, amd.peak_entries);
    assert!(amd.peak_entries <= 2 * amd.initial_entries + n, "{amd:?}");
    let summary = optimize(&factors, &mut values, &LmParams::default()).unwrap();
    println!("{summary:?}");
    assert!(summary.final_cost < 1e-6 * summary.initial_cost.max(1.0) + 1e-3, "{summary:?}");
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, ..ProptestConfig::default() })]
    #[test]
    fn amd_of_random_graphs_is_a_permutation_with_the_constrained_last(
        n in 1usize..60,
        raw_edges in proptest::collection::vec(proptest::collection::vec(0usize..60, 1..5), 0..150),
        raw_last in proptest::collection::vec(any::<bool>(), 0..60),
    ) {
        let edges: Vec<Vec<usize>> = raw_edges.iter().map(|e| e.iter().map(|&v| v % n).collect()).collect();
        let last: Vec<bool> = raw_last.iter().copied().take(n).collect();
        let amd = approximate_min_degree(n, edges.iter().map(Vec::as_slice), &last);
        prop_assert!(is_permutation(&amd.order, n), "{:?}", amd.order);
        let constrained = last.iter().filter(|&&l| l).count();
        prop_assert!(amd.order[n - constrained..].iter().all(|&v| last[v]));
        let exact = min_degree(n, edges.iter().map(Vec::as_slice), &last);
        let fill_exact = factor_nonzeros(n, edges.iter().map(Vec::as_slice), &exact);
        let fill_amd = factor_nonzeros(n, edges.iter().map(Vec::as_slice), &amd.order);
        prop_assert!(fill_amd >= n && fill_exact >= n);
    }
}
