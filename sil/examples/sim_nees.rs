//! Filter consistency (issue 7): 20 simulated Moon runs with different seeds, the filter started at
//! the true pose; the NEES of position and of orientation (3 DoF each) from the filter covariance
//! against ground truth, averaged over the runs, compared with the two-sided 95 % chi-square
//! bounds of that average.
//!
//! `cargo run --release -p sil --example sim_nees -- [--runs N] [--duration S] [--downscale N] [--no-wheel] [--vo-keyframes] [--vo-scale F] [--no-zupt]`

#[path = "../tests/common/sim_run.rs"]
mod sim_run;

fn arg(name: &str, default: f64) -> f64 {
    let args: Vec<String> = std::env::args().collect();
    args.iter().position(|a| a == name).and_then(|i| args.get(i + 1)).and_then(|v| v.parse().ok()).unwrap_or(default)
}

/// Chi-square quantile by the Wilson–Hilferty approximation (relative error < 1e-3 for k ≥ 30).
fn chi2_quantile(k: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let runs = arg("--runs", 20.0) as usize;
    let duration_s = arg("--duration", 30.0);
    let downscale = arg("--downscale", 2.0) as u32;
    let use_wheel = !std::env::args().any(|a| a == "--no-wheel");
    let period_ns = 500_000_000;
    println!("{runs} runs of {duration_s} s, downscale {downscale}, wheel odometry {use_wheel}");
    let mut position: Vec<Vec<f64>> = Vec::new();
    let mut orientation: Vec<Vec<f64>> = Vec::new();
    for seed in 1..=runs as u64 {
        let world = sim_run::moon_world(seed, duration_s, downscale, Some(1.0));
        let mut config = sim_run::sim_config(&world, use_wheel);
        if std::env::args().any(|a| a == "--vo-keyframes") {
            config.filter.vo_updates = onboard::config::VoUpdatesConfig::Keyframes;
        }
        config.filter.zupt = !std::env::args().any(|a| a == "--no-zupt");
        config.filter.vo_covariance_scale = arg("--vo-scale", config.filter.vo_covariance_scale);
        let run = sim_run::run(&world, config, true, Some(period_ns))?;
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
        println!(
            "seed {seed:2}: {:5.1} m, final error {:.3} m, mean NEES position {:6.2}, orientation {:6.2}",
            run.distance_m,
            run.final_error_m,
            mean(&run.nees_position),
            mean(&run.nees_orientation)
        );
        position.push(run.nees_position);
        orientation.push(run.nees_orientation);
    }
    let checks = position.iter().chain(&orientation).map(Vec::len).min().unwrap_or(0);
    let n = runs as f64;
    // The run-average of n NEES values of 3 DoF is chi²(3n)/n if the filter is consistent.
    let (lower, upper) = (chi2_quantile(3.0 * n, -1.959_964) / n, chi2_quantile(3.0 * n, 1.959_964) / n);
    println!("95 % bounds of the {runs}-run average NEES (3 DoF): [{lower:.2}, {upper:.2}]");
    for (name, values) in [("position", &position), ("orientation", &orientation)] {
        let averages: Vec<f64> = (0..checks).map(|k| values.iter().map(|run| run[k]).sum::<f64>() / n).collect();
        let inside = averages.iter().filter(|a| (lower..=upper).contains(*a)).count();
        let overall = averages.iter().sum::<f64>() / averages.len().max(1) as f64;
        // Over all checks and runs: chi²(3·n·checks)/(n·checks).
        let m = n * checks as f64;
        let (lo_all, hi_all) = (chi2_quantile(3.0 * m, -1.959_964) / m, chi2_quantile(3.0 * m, 1.959_964) / m);
        println!(
            "{name:<12} average NEES {overall:.2} (bounds for all {} samples [{lo_all:.2}, {hi_all:.2}]); \
             run-average inside the bounds at {inside} of {checks} instants",
            runs * checks
        );
    }
    Ok(())
}
