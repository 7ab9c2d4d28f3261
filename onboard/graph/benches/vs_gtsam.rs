//! Speed of our batch LM, incremental smoother and marginal covariances against GTSAM 4.3 on the
//! 3-D g2o benchmarks of the repository's `data/posegraph`, measured in the same run on the same
//! files. GTSAM runs through `scripts/gtsam_reference.py` in the project venv; its times are
//! taken inside the script around the GTSAM call alone, so ours are timed the same way (no
//! process start-up, no file parsing, no problem set-up).
//!
//! `cargo bench -p posegraph --bench vs_gtsam [-- NAME...]`: the full tables; NAME arguments
//! keep only the datasets whose name contains one of them (e.g. `-- sphere2500`), and the
//! words `batch`, `incremental` and `marginals` keep only those sections. Without
//! `--bench` (as `cargo test --all-targets` runs it): a smoke run of every step on the small
//! graphs, one repetition each.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::Instant;

use nalgebra::Matrix6;
use posegraph::dataset::{self, Problem};
use posegraph::ordering::{self, approximate_min_degree, factor_nonzeros, min_degree};
use posegraph::{Isam, IsamParams, Key, LmParams, LmSummary, g2o, marginal_covariances, optimize};

/// The 3-D datasets, largest first. `grid3D_gen` and `torus3D_gen` are generated in the style of
/// Carlone et al.'s grid3D and torus3D (`examples/make_graph.rs`, `data/posegraph/SOURCE.md`).
const BATCH_DATASETS: [&str; 7] =
    ["grid3D_gen", "torus3D_gen", "sphere2500", "parking-garage", "smallGrid3D", "tinyGrid3D", "pose3example"];
const INCREMENTAL_DATASETS: [&str; 2] = ["sphere2500", "parking-garage"];
const MARGINAL_DATASETS: [&str; 2] = ["smallGrid3D", "parking-garage"];

/// The smoke run's stand-ins: the same steps on graphs that take milliseconds.
const SMOKE_BATCH_DATASETS: [&str; 2] = ["tinyGrid3D", "pose3example"];
const SMOKE_INCREMENTAL_DATASETS: [&str; 1] = ["smallGrid3D"];
const SMOKE_MARGINAL_DATASETS: [&str; 1] = ["tinyGrid3D"];

/// Repetitions of the batch optimization and of the all-pose marginals, each side. GTSAM's
/// batch repetitions are separate processes (each a cold start, as a single call would be).
const RUNS: usize = 5;

/// Fewer batch repetitions for graphs where one of our optimizations takes longer than
/// `SLOW_OPTIMIZE_MS` (grid3D_gen: ~30 s each side), so that the batch section stays within
/// a few minutes; a median of 3 is still robust to one disturbed run.
const SLOW_OPTIMIZE_MS: f64 = 5_000.0;
const SLOW_RUNS: usize = 3;

/// The thesis' marginals budget (spec §3.6): all submap origins after every update, GTSAM 3.2.1,
/// graphs of fewer than 180 nodes.
const THESIS_MARGINALS_MEAN_MS: f64 = 106.0;
const THESIS_MARGINALS_MAX_MS: f64 = 341.0;

fn data_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../data/posegraph")
}

fn dataset_path(name: &str) -> PathBuf {
    data_dir().join(format!("{name}.g2o"))
}

fn load(name: &str) -> Result<Problem, String> {
    let path = dataset_path(name);
    let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
    let graph = g2o::parse(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    dataset::from_g2o(&graph, None).map_err(|e| format!("{name}: {e}"))
}

fn median(values: &[f64]) -> f64 {
    percentile(values, 50.0)
}

/// numpy's default percentile (linear interpolation between order statistics), so that our
/// median and p95 are computed exactly as the script computes GTSAM's.
fn percentile(values: &[f64], p: f64) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    if sorted.is_empty() {
        return f64::NAN;
    }
    let rank = p / 100.0 * (sorted.len() - 1) as f64;
    let (lo, hi) = (rank.floor() as usize, rank.ceil() as usize);
    sorted[lo] + (sorted[hi] - sorted[lo]) * (rank - lo as f64)
}

fn relative(ours: f64, reference: f64) -> f64 {
    (ours - reference) / reference.abs()
}

/// The reference script in the project venv.
struct Gtsam {
    python: PathBuf,
    script: PathBuf,
}

impl Gtsam {
    fn find() -> Result<Self, String> {
        let root = Path::new(env!("CARGO_MANIFEST_DIR"));
        let python = root.join("../../.venv/bin/python");
        if !python.exists() {
            return Err(format!(
                "{} is missing: run scripts/test first (it creates the project venv with gtsam 4.3.0)",
                python.display()
            ));
        }
        Ok(Self { python, script: root.join("scripts/gtsam_reference.py") })
    }

    fn run(&self, args: &[&str]) -> Result<serde_json::Value, String> {
        let output = Command::new(&self.python)
            .arg(&self.script)
            .args(args)
            .output()
            .map_err(|e| format!("{}: {e}", self.python.display()))?;
        if !output.status.success() {
            return Err(format!(
                "gtsam_reference.py {} failed (if gtsam is not importable, run scripts/test first): {}",
                args.join(" "),
                String::from_utf8_lossy(&output.stderr).trim()
            ));
        }
        serde_json::from_slice(&output.stdout).map_err(|e| format!("gtsam_reference.py {}: {e}", args.join(" ")))
    }
}

fn field(json: &serde_json::Value, name: &str) -> Result<f64, String> {
    json[name].as_f64().ok_or_else(|| format!("no number `{name}` in the script's JSON"))
}

// ------------------------------------------------------------------------------------------------
// Batch
// ------------------------------------------------------------------------------------------------

struct BatchRow {
    name: &'static str,
    vertices: usize,
    factors: usize,
    ours: LmSummary,
    /// One thread.
    ours_ms: f64,
    /// Two threads; their summary, to show how many factorizations were threaded.
    ours2: LmSummary,
    ours2_ms: f64,
    gtsam_initial: f64,
    gtsam_final: f64,
    gtsam_iterations: u64,
    gtsam_ms: f64,
    /// Repetitions per cell (each side): `RUNS`, or `SLOW_RUNS` for slow graphs.
    runs: usize,
}

fn batch(name: &'static str, gtsam: &Gtsam, runs: usize) -> Result<BatchRow, String> {
    let problem = load(name)?;
    let mut times = [Vec::with_capacity(runs), Vec::with_capacity(runs)];
    let mut summaries = [None, None];
    // Alternate 1 and 2 threads so that a change of load affects both alike.
    let mut runs = runs;
    let mut repetition = 0;
    while repetition < runs {
        for (k, threads) in [1, 2].into_iter().enumerate() {
            let params = LmParams { threads, ..LmParams::default() };
            let mut values = problem.values.clone();
            let start = Instant::now();
            let result = optimize(&problem.factors, &mut values, &params).map_err(|e| format!("{name}: {e}"))?;
            times[k].push(start.elapsed().as_secs_f64() * 1e3);
            summaries[k] = Some(result);
        }
        if times[0][0] > SLOW_OPTIMIZE_MS {
            runs = runs.min(SLOW_RUNS);
        }
        repetition += 1;
    }
    let [ours, ours2] = summaries;
    let (ours, ours2) = (ours.ok_or("no batch run")?, ours2.ok_or("no batch run")?);

    let path = dataset_path(name);
    let path = path.to_string_lossy();
    let mut gtsam_times = Vec::with_capacity(runs);
    let mut last = serde_json::Value::Null;
    for _ in 0..runs {
        last = gtsam.run(&["batch", "--in", &path])?;
        gtsam_times.push(field(&last, "time_ms")?);
    }
    Ok(BatchRow {
        name,
        vertices: problem.values.len(),
        factors: problem.factors.len(),
        ours,
        ours_ms: median(&times[0]),
        ours2,
        ours2_ms: median(&times[1]),
        gtsam_initial: field(&last, "initial_cost")?,
        gtsam_final: field(&last, "final_cost")?,
        gtsam_iterations: last["iterations"].as_u64().ok_or("no iterations in the script's JSON")?,
        gtsam_ms: median(&gtsam_times),
        runs,
    })
}

fn print_batch(rows: &[BatchRow], runs: usize) {
    println!("\nBatch Levenberg-Marquardt (defaults; GTSAM: LevenbergMarquardtParams, maxIterations 100)");
    println!(
        "time: optimize() only, median of {runs} runs each (GTSAM: {runs} script invocations); {SLOW_RUNS} where one of ours takes > {SLOW_OPTIMIZE_MS} ms"
    );
    println!(
        "ours with 1 and with 2 threads (LmParams::threads), alternating; 'threaded': factorizations on 2 threads\n"
    );
    println!(
        "| dataset | poses | factors | initial cost ours / GTSAM | final cost ours | final cost GTSAM | rel. diff | iterations ours / GTSAM | ms ours 1 thr | ms ours 2 thr | threaded | ms GTSAM | GTSAM / ours 1 thr | GTSAM / ours 2 thr |"
    );
    println!("|---|---:|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        println!(
            "| {} | {} | {} | {:.6} / {:.6} | {:.10} | {:.10} | {:+.1e} | {} / {} | {:.2} | {:.2} | {}/{} | {:.2} | {:.2} | {:.2} |",
            r.name,
            r.vertices,
            r.factors,
            r.ours.initial_cost,
            r.gtsam_initial,
            r.ours.final_cost,
            r.gtsam_final,
            relative(r.ours.final_cost, r.gtsam_final),
            r.ours.iterations,
            r.gtsam_iterations,
            r.ours_ms,
            r.ours2_ms,
            r.ours2.threaded_factorizations,
            r.ours2.factorizations,
            r.gtsam_ms,
            r.gtsam_ms / r.ours_ms,
            r.gtsam_ms / r.ours2_ms
        );
    }
    println!();
    for r in rows {
        println!(
            "batch {}: time GTSAM/ours {:.2}x 1 thread, {:.2}x 2 threads ({:.2} ms vs {:.2} / {:.2} ms, median of {}), final cost ours vs GTSAM {:+.2e} relative",
            r.name,
            r.gtsam_ms / r.ours_ms,
            r.gtsam_ms / r.ours2_ms,
            r.gtsam_ms,
            r.ours_ms,
            r.ours2_ms,
            r.runs,
            relative(r.ours.final_cost, r.gtsam_final)
        );
    }
    for r in rows {
        println!(
            "batch {}: ordering (ours, inside optimize()) {:.2} ms of {:.2} ms; GTSAM's COLAMD is outside its time",
            r.name, r.ours.ordering_ms, r.ours_ms
        );
    }
}

// ------------------------------------------------------------------------------------------------
// Incremental
// ------------------------------------------------------------------------------------------------

struct IncrementalRun {
    mean_ms: f64,
    median_ms: f64,
    p95_ms: f64,
    max_ms: f64,
    total_ms: f64,
    final_cost: f64,
    /// Summed over the updates; GTSAM reports no count of relinearized variables.
    relinearized: Option<u64>,
    reeliminated: u64,
}

struct IncrementalRow {
    name: &'static str,
    /// Both sides with the partial relinearization check (GTSAM's
    /// `enablePartialRelinearizationCheck`) instead of checking every variable.
    partial_check: bool,
    updates: usize,
    ours: IncrementalRun,
    gtsam: IncrementalRun,
}

fn incremental(name: &'static str, gtsam: &Gtsam, partial_check: bool) -> Result<IncrementalRow, String> {
    let problem = load(name)?;
    let params = IsamParams { partial_relinearization_check: partial_check, ..IsamParams::default() };
    // Fed as the script feeds ISAM2: pose by pose in id order, with every factor whose latest
    // pose it is, initialised at estimate(k-1) ∘ odometry(k-1 → k).
    let steps = dataset::incremental_steps(&problem);
    let mut isam = Isam::new(params.clone());
    let mut times = Vec::with_capacity(steps.len());
    let (mut relinearized, mut reeliminated) = (0, 0);
    for step in &steps {
        let initial = step.initial_value(&isam);
        let factors = step.factors.clone();
        let start = Instant::now();
        let stats = isam.update(factors, &[(step.key, initial)]).map_err(|e| format!("{name} {:?}: {e}", step.key))?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
        relinearized += stats.relinearized_variables as u64;
        reeliminated += stats.reeliminated_variables as u64;
    }
    let ours = IncrementalRun {
        mean_ms: times.iter().sum::<f64>() / times.len().max(1) as f64,
        median_ms: median(&times),
        p95_ms: percentile(&times, 95.0),
        max_ms: times.iter().copied().fold(0.0, f64::max),
        total_ms: times.iter().sum(),
        final_cost: isam.cost(),
        relinearized: Some(relinearized),
        reeliminated,
    };

    let path = dataset_path(name);
    let threshold = params.relinearize_threshold.to_string();
    let skip = params.relinearize_skip.to_string();
    let path = path.to_string_lossy();
    let mut args = vec!["isam2", "--in", &path, "--relinearize-threshold", &threshold, "--relinearize-skip", &skip];
    if partial_check {
        args.push("--partial-relinearization-check");
    }
    let json = gtsam.run(&args)?;
    let count = |name: &str| json[name].as_u64().ok_or_else(|| format!("no count `{name}` in the script's JSON"));
    let updates = json["updates"].as_u64().ok_or("no count `updates` in the script's JSON")?;
    let gtsam_run = IncrementalRun {
        mean_ms: field(&json, "total_ms")? / updates.max(1) as f64,
        median_ms: field(&json, "median_update_ms")?,
        p95_ms: field(&json, "p95_update_ms")?,
        max_ms: field(&json, "max_update_ms")?,
        total_ms: field(&json, "total_ms")?,
        final_cost: field(&json, "final_cost")?,
        relinearized: None,
        reeliminated: count("reeliminated_variables")?,
    };
    Ok(IncrementalRow { name, partial_check, updates: steps.len(), ours, gtsam: gtsam_run })
}

fn check_name(partial_check: bool) -> &'static str {
    if partial_check { "partial" } else { "full" }
}

fn print_incremental(rows: &[IncrementalRow]) {
    let params = IsamParams::default();
    println!(
        "\nIncremental, one pose per update (ours: IsamParams {{ relinearize_threshold {}, relinearize_skip {}, wildfire {} }}; GTSAM: ISAM2 Gauss-Newton, CHOLESKY, same threshold and skip, wildfire 1e-3); relinearization check: full (every variable) or partial (descending the tree; GTSAM's enablePartialRelinearizationCheck), the same on both sides; one run each; relinearized and re-eliminated: variables, summed over the updates (GTSAM does not count relinearized ones)\n",
        params.relinearize_threshold, params.relinearize_skip, params.wildfire_threshold
    );
    println!(
        "| dataset | check | updates | solver | mean ms | median ms | p95 ms | max ms | total ms | final cost | relinearized | re-eliminated |"
    );
    println!("|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        for (solver, t) in [("ours", &r.ours), ("GTSAM iSAM2", &r.gtsam)] {
            println!(
                "| {} | {} | {} | {solver} | {:.3} | {:.3} | {:.3} | {:.3} | {:.1} | {:.10} | {} | {} |",
                r.name,
                check_name(r.partial_check),
                r.updates,
                t.mean_ms,
                t.median_ms,
                t.p95_ms,
                t.max_ms,
                t.total_ms,
                t.final_cost,
                t.relinearized.map_or("-".to_owned(), |n| n.to_string()),
                t.reeliminated
            );
        }
    }
    println!();
    for r in rows {
        println!(
            "incremental {} ({} check): ours mean {:.3} ms, max {:.3} ms; GTSAM/ours median {:.2}x, p95 {:.2}x, max {:.2}x, total {:.2}x; final cost ours vs GTSAM {:+.2e} relative",
            r.name,
            check_name(r.partial_check),
            r.ours.mean_ms,
            r.ours.max_ms,
            r.gtsam.median_ms / r.ours.median_ms,
            r.gtsam.p95_ms / r.ours.p95_ms,
            r.gtsam.max_ms / r.ours.max_ms,
            r.gtsam.total_ms / r.ours.total_ms,
            relative(r.ours.final_cost, r.gtsam.final_cost)
        );
    }
}

// ------------------------------------------------------------------------------------------------
// Marginals
// ------------------------------------------------------------------------------------------------

struct MarginalRow {
    name: &'static str,
    poses: usize,
    ours_ms: f64,
    gtsam_ms: f64,
    /// max over poses of ‖Σ_ours − Σ_GTSAM‖_F / ‖Σ_GTSAM‖_F (each at its own LM optimum).
    max_relative_difference: f64,
}

fn marginals(name: &'static str, gtsam: &Gtsam, runs: usize) -> Result<MarginalRow, String> {
    let problem = load(name)?;
    let mut values = problem.values.clone();
    optimize(&problem.factors, &mut values, &LmParams::default()).map_err(|e| format!("{name}: {e}"))?;
    let keys: Vec<Key> = values.keys().to_vec();
    let mut times = Vec::with_capacity(runs);
    let mut covariances = Vec::new();
    for _ in 0..runs {
        let start = Instant::now();
        covariances = marginal_covariances(&problem.factors, &values, &keys).map_err(|e| format!("{name}: {e}"))?;
        times.push(start.elapsed().as_secs_f64() * 1e3);
    }

    let path = dataset_path(name);
    let runs_arg = runs.to_string();
    let json = gtsam.run(&["marginals", "--in", &path.to_string_lossy(), "--all", "--runs", &runs_arg])?;
    let mut max_relative_difference: f64 = 0.0;
    for (key, ours) in keys.iter().zip(&covariances) {
        let rows =
            json["covariances"][key.0.to_string()].as_array().ok_or_else(|| format!("no covariance of {key:?}"))?;
        let mut reference = Matrix6::<f64>::zeros();
        for (r, row) in rows.iter().enumerate().take(6) {
            for c in 0..6 {
                reference[(r, c)] = row[c].as_f64().ok_or("covariance entry is not a number")?;
            }
        }
        max_relative_difference = max_relative_difference.max((ours - reference).norm() / reference.norm());
    }
    Ok(MarginalRow {
        name,
        poses: keys.len(),
        ours_ms: median(&times),
        gtsam_ms: field(&json, "marginals_median_ms")?,
        max_relative_difference,
    })
}

fn print_marginals(rows: &[MarginalRow], runs: usize) {
    println!(
        "\nMarginal covariances of ALL poses at the batch LM optimum (ours: marginal_covariances; GTSAM: Marginals(graph, result) + marginalCovariance per key, CHOLESKY); median of {runs} runs each, linearization and factorization included\n"
    );
    println!(
        "| dataset | poses | ms ours | ms GTSAM | µs/pose ours | µs/pose GTSAM | GTSAM / ours | max rel. diff (Frobenius) |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    for r in rows {
        println!(
            "| {} | {} | {:.2} | {:.2} | {:.1} | {:.1} | {:.2} | {:.1e} |",
            r.name,
            r.poses,
            r.ours_ms,
            r.gtsam_ms,
            1e3 * r.ours_ms / r.poses as f64,
            1e3 * r.gtsam_ms / r.poses as f64,
            r.gtsam_ms / r.ours_ms,
            r.max_relative_difference
        );
    }
    println!();
    for r in rows {
        println!(
            "marginals {} (all {} poses): GTSAM/ours {:.2}x ({:.2} ms vs {:.2} ms); thesis (GTSAM 3.2.1, < 180 nodes): mean {THESIS_MARGINALS_MEAN_MS} ms / max {THESIS_MARGINALS_MAX_MS} ms = {:.0}x / {:.0}x ours",
            r.name,
            r.poses,
            r.gtsam_ms / r.ours_ms,
            r.gtsam_ms,
            r.ours_ms,
            THESIS_MARGINALS_MEAN_MS / r.ours_ms,
            THESIS_MARGINALS_MAX_MS / r.ours_ms
        );
    }
}

// ------------------------------------------------------------------------------------------------

/// The benchmark's sections, selectable by name on the command line.
const SECTIONS: [&str; 4] = ["batch", "incremental", "marginals", "ordering"];

/// Datasets of `all` whose name contains one of `filters` (all of them without dataset filters),
/// or none if sections are named and `section` is not among them.
fn selected(section: &str, all: &[&'static str], filters: &[String]) -> Vec<&'static str> {
    let (sections, datasets): (Vec<&String>, Vec<&String>) =
        filters.iter().partition(|f| SECTIONS.contains(&f.as_str()));
    if !sections.is_empty() && !sections.iter().any(|s| s.as_str() == section) {
        return Vec::new();
    }
    all.iter()
        .copied()
        .filter(|name| datasets.is_empty() || datasets.iter().any(|f| name.contains(f.as_str())))
        .collect()
}

/// The variable graph of a walk through an `nx × ny × nz` lattice (rows back and forth, layers
/// stacked): odometry between consecutive poses, a loop closure to the cell in the previous row,
/// and at `x = 0` and `x = nx / 2` one to the cell in the previous layer. The same graph as
/// `tests/ordering_amd.rs` optimizes.
fn lattice_edges(nx: usize, ny: usize, nz: usize) -> Vec<[usize; 2]> {
    let cell = |x: usize, y: usize, z: usize| (z * ny + y) * nx + x;
    let mut index_of_cell = vec![0usize; nx * ny * nz];
    let mut i = 0;
    for z in 0..nz {
        for yy in 0..ny {
            let y = if z.is_multiple_of(2) { yy } else { ny - 1 - yy };
            for xx in 0..nx {
                let x = if (z * ny + yy).is_multiple_of(2) { xx } else { nx - 1 - xx };
                index_of_cell[cell(x, y, z)] = i;
                i += 1;
            }
        }
    }
    let mut edges: Vec<[usize; 2]> = (1..i).map(|k| [k - 1, k]).collect();
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let b = index_of_cell[cell(x, y, z)];
                let mut others = Vec::new();
                if y > 0 {
                    others.push(index_of_cell[cell(x, y - 1, z)]);
                }
                if z > 0 && x.is_multiple_of(nx / 2) {
                    others.push(index_of_cell[cell(x, y, z - 1)]);
                }
                edges.extend(others.into_iter().filter(|&a| a + 1 != b && b + 1 != a).map(|a| [a, b]));
            }
        }
    }
    edges
}

/// AMD against exact minimum degree: time and factor size, on the 3-D datasets and on a
/// 50,000-pose lattice beyond the exact ordering's threshold.
fn ordering_section(datasets: &[&'static str]) -> Result<(), String> {
    println!("\nOrdering: AMD (quotient graph) vs exact minimum degree (bit rows); single runs, ordering only");
    println!("factor blocks = nonzero 6x6 blocks of the Cholesky factor (symbolic elimination)\n");
    println!(
        "| graph | poses | ordering used | exact MD ms | exact MD bit rows MB | AMD ms | AMD peak entries / input | factor blocks MD | factor blocks AMD | AMD / MD |"
    );
    println!("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut graphs: Vec<(String, usize, Vec<[usize; 2]>)> = Vec::new();
    for &name in datasets {
        let problem = load(name)?;
        let edges = problem
            .factors
            .iter()
            .map(|f| {
                let keys = f.keys();
                let a = problem.values.index_of(keys[0]).ok_or("unknown key")?;
                let b = problem.values.index_of(keys[keys.len() - 1]).ok_or("unknown key")?;
                Ok([a, b])
            })
            .collect::<Result<Vec<_>, String>>()?;
        graphs.push((name.to_string(), problem.values.len(), edges));
    }
    graphs.push(("lattice 50x50x20".to_string(), 50_000, lattice_edges(50, 50, 20)));
    for (name, n, edges) in &graphs {
        let n = *n;
        let start = Instant::now();
        let exact = min_degree(n, edges.iter().map(|e| &e[..]), &[]);
        let exact_ms = start.elapsed().as_secs_f64() * 1e3;
        let start = Instant::now();
        let amd = approximate_min_degree(n, edges.iter().map(|e| &e[..]), &[]);
        let amd_ms = start.elapsed().as_secs_f64() * 1e3;
        let fill_exact = factor_nonzeros(n, edges.iter().map(|e| &e[..]), &exact);
        let fill_amd = factor_nonzeros(n, edges.iter().map(|e| &e[..]), &amd.order);
        let used = if n <= ordering::EXACT_MAX_VARIABLES { "exact MD" } else { "AMD" };
        println!(
            "| {name} | {n} | {used} | {exact_ms:.2} | {:.1} | {amd_ms:.2} | {:.2} | {fill_exact} | {fill_amd} | {:.3} |",
            (n * n.div_ceil(64) * 8) as f64 / 1e6,
            amd.peak_entries as f64 / amd.initial_entries.max(1) as f64,
            fill_amd as f64 / fill_exact as f64
        );
    }
    Ok(())
}

fn run(full: bool, filters: &[String]) -> Result<(), String> {
    let started = Instant::now();
    let ordering_sets = selected("ordering", if full { &BATCH_DATASETS } else { &SMOKE_BATCH_DATASETS }, filters);
    if full && !ordering_sets.is_empty() {
        ordering_section(&ordering_sets)?;
    }
    // The ordering section needs no GTSAM: asked for alone, it runs without the venv.
    let sections: Vec<&str> = filters.iter().map(String::as_str).filter(|f| SECTIONS.contains(f)).collect();
    if sections == ["ordering"] {
        println!("\nvs_gtsam: {:.1} s in total", started.elapsed().as_secs_f64());
        return Ok(());
    }
    let gtsam = Gtsam::find()?;
    let (batch_sets, incremental_sets, marginal_sets): (&[&'static str], &[&'static str], &[&'static str]) = if full {
        (&BATCH_DATASETS, &INCREMENTAL_DATASETS, &MARGINAL_DATASETS)
    } else {
        (&SMOKE_BATCH_DATASETS, &SMOKE_INCREMENTAL_DATASETS, &SMOKE_MARGINAL_DATASETS)
    };
    let (batch_sets, incremental_sets, marginal_sets) = (
        selected("batch", batch_sets, filters),
        selected("incremental", incremental_sets, filters),
        selected("marginals", marginal_sets, filters),
    );
    if batch_sets.is_empty() && incremental_sets.is_empty() && marginal_sets.is_empty() {
        if full {
            return Err(format!(
                "no dataset matches {filters:?}; the datasets are {BATCH_DATASETS:?}, the sections {SECTIONS:?}"
            ));
        }
        // `cargo test -- some_test_name` reaches this binary too: nothing of ours was asked for.
        return Ok(());
    }
    let runs = if full { RUNS } else { 1 };

    let batch_rows = batch_sets.iter().map(|&name| batch(name, &gtsam, runs)).collect::<Result<Vec<_>, _>>()?;
    if !batch_rows.is_empty() {
        print_batch(&batch_rows, runs);
    }
    let incremental_rows = incremental_sets
        .iter()
        .flat_map(|&name| [false, true].map(|partial_check| (name, partial_check)))
        .map(|(name, partial_check)| incremental(name, &gtsam, partial_check))
        .collect::<Result<Vec<_>, _>>()?;
    if !incremental_rows.is_empty() {
        print_incremental(&incremental_rows);
    }
    let marginal_rows =
        marginal_sets.iter().map(|&name| marginals(name, &gtsam, runs)).collect::<Result<Vec<_>, _>>()?;
    if !marginal_rows.is_empty() {
        print_marginals(&marginal_rows, runs);
    }
    println!("\nvs_gtsam: {:.1} s in total", started.elapsed().as_secs_f64());
    Ok(())
}

fn main() -> ExitCode {
    // `cargo bench` passes `--bench`; `cargo test --all-targets` does not: then a smoke run only.
    let args: Vec<String> = std::env::args().skip(1).collect();
    let full = args.iter().any(|a| a == "--bench");
    let filters: Vec<String> = args.into_iter().filter(|a| !a.starts_with('-')).collect();
    match run(full, &filters) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("vs_gtsam: {message}");
            ExitCode::FAILURE
        }
    }
}
