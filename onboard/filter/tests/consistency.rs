//! Simulated consistency (issue "must show"): 20 seeds of a ~60 s rover drive on the Moon with the
//! Xsens MTi-10 IMU model and delayed keyframe VO deltas; the average NEES over the runs must lie
//! inside the two-sided 95 % chi-square bounds, and the drift must stay below 1 % of the distance.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common;

use common::{START_NS, SimRun, nees};
use filter::chi2::chi2_quantile;

const RUNS: u64 = 20;
const DURATION_S: f64 = 60.0;

#[test]
fn average_nees_inside_chi2_bounds_over_20_runs() {
    // Checkpoints every 2 s from 4 s on (the first seconds start from exact position and yaw).
    let checkpoints: Vec<u64> = (2..30).map(|k| START_NS + k * 2_000_000_000).collect();
    let mut sum_p = vec![0.0; checkpoints.len()];
    let mut sum_t = vec![0.0; checkpoints.len()];
    let mut worst_drift = 0.0_f64;
    for seed in 0..RUNS {
        let mut run = SimRun::new(seed, DURATION_S);
        let mut distance = 0.0;
        let mut last = run.truth(START_NS).translation.vector;
        for (k, &t) in checkpoints.iter().enumerate() {
            run.run_until(t);
            let truth = run.truth(run.filter.stamp_ns());
            let (np, nt) = nees(&run.filter, &truth);
            sum_p[k] += np;
            sum_t[k] += nt;
            let now = run.truth(t).translation.vector;
            distance += (now - last).norm();
            last = now;
        }
        let truth = run.truth(run.filter.stamp_ns());
        let err = (truth.translation.vector - run.filter.state().unwrap().t_local_body.translation.vector).norm();
        worst_drift = worst_drift.max(err / distance);
        let h = run.filter.health();
        assert!(h.is_clean(0.01), "seed {seed}: {h:?}");
        assert_eq!(h.missing_clones, 0, "seed {seed}");
        assert!(run.applied > 500, "seed {seed}: {} VO deltas", run.applied);
    }
    let n = RUNS as f64;
    let lo = chi2_quantile(3 * RUNS as u32, 0.025) / n;
    let hi = chi2_quantile(3 * RUNS as u32, 0.975) / n;
    let anees_p: Vec<f64> = sum_p.iter().map(|s| s / n).collect();
    let anees_t: Vec<f64> = sum_t.iter().map(|s| s / n).collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let inside = |v: &[f64]| v.iter().filter(|&&x| (lo..=hi).contains(&x)).count() as f64 / v.len() as f64;
    println!("bounds [{lo:.3}, {hi:.3}]");
    println!("ANEES position per checkpoint: {anees_p:.2?}");
    println!("ANEES orientation per checkpoint: {anees_t:.2?}");
    println!(
        "mean ANEES position {:.3} ({:.0} % inside), orientation {:.3} ({:.0} % inside); worst drift {:.3} %",
        mean(&anees_p),
        100.0 * inside(&anees_p),
        mean(&anees_t),
        100.0 * inside(&anees_t),
        100.0 * worst_drift
    );
    assert!((lo..=hi).contains(&mean(&anees_p)), "position ANEES {}", mean(&anees_p));
    assert!((lo..=hi).contains(&mean(&anees_t)), "orientation ANEES {}", mean(&anees_t));
    // Checkpoints are correlated in time, so a few may fall outside by chance; most must not.
    assert!(inside(&anees_p) >= 0.8 && inside(&anees_t) >= 0.8);
    assert!(worst_drift <= 0.01, "drift {:.3} %", 100.0 * worst_drift);
}
