//! `onboard posegraph --in G.g2o --out O.g2o [--incremental] [--robust cauchy:C|huber:K]
//! [--information reject|repair] [--json]`
//!
//! Reads a g2o graph (3-D, or 2-D lifted to 3-D), holds the first vertex with a prior (as
//! GTSAM's examples do), optimizes, writes the result as 3-D g2o and prints initial cost, final
//! cost, iterations and time. Costs are GTSAM's `graph.error` of the same graph. An edge whose
//! information is not positive definite stops the run with its line, unless `--information
//! repair` projects it onto the nearest positive-definite matrix (`posegraph::information`).

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use posegraph::dataset::{self, RobustSelection};
use posegraph::g2o::{G2oErrorKind, InformationPolicy, RepairedEdge};
use posegraph::{Isam, IsamParams, LmParams, RobustKernel, g2o};

const USAGE: &str = "usage: onboard posegraph --in G.g2o [--out O.g2o] [--incremental] [--robust cauchy:C|huber:K]
                         [--information reject|repair] [--json]

  --in FILE        g2o graph (VERTEX_SE3:QUAT/EDGE_SE3:QUAT, VERTEX_SE2/EDGE_SE2 lifted to 3-D, EDGE3)
  --out FILE       write the optimized graph (3-D g2o, first vertex FIX)
  --incremental    feed the graph pose by pose to the incremental smoother instead of batch LM
  --robust K:P     robust kernel on loop closures (edges between non-consecutive ids):
                   cauchy:C or huber:K, C and K in Mahalanobis distance
  --information P  edges whose information matrix is not positive definite:
                   reject (default) stops with the edge's line; repair raises its eigenvalues
                   to a floor of 1e-6 of the largest (the nearest such matrix) and lists the
                   edge (--out then writes the repaired matrix)
  --json           print one JSON object (initial_cost, final_cost, iterations, time_ms,
                   repaired_edges, ...)";

/// Appended to the error of an edge whose information is not positive definite.
const REPAIR_HINT: &str = "hint: pass `--information repair` to project it to the nearest positive-definite matrix";

#[derive(Debug)]
struct Options {
    input: PathBuf,
    output: Option<PathBuf>,
    incremental: bool,
    robust: Option<RobustKernel>,
    information: InformationPolicy,
    json: bool,
}

fn parse_args(args: Vec<OsString>) -> Result<Option<Options>, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let (mut input, mut output, mut incremental, mut robust, mut json) = (None, None, false, None, false);
    let mut information = InformationPolicy::Reject;
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("in") => input = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?)),
            Long("out") => output = Some(PathBuf::from(parser.value().map_err(|e| e.to_string())?)),
            Long("incremental") => incremental = true,
            Long("robust") => {
                let value = parser.value().map_err(|e| e.to_string())?;
                robust = Some(parse_kernel(&value.to_string_lossy())?);
            }
            Long("information") => {
                let value = parser.value().map_err(|e| e.to_string())?;
                information = match value.to_string_lossy().as_ref() {
                    "reject" => InformationPolicy::Reject,
                    "repair" => InformationPolicy::repair(),
                    other => return Err(format!("--information: unknown policy {other:?} (reject or repair)")),
                };
            }
            Long("json") => json = true,
            Short('h') | Long("help") => return Ok(None),
            other => return Err(other.unexpected().to_string()),
        }
    }
    let input = input.ok_or("--in is required")?;
    Ok(Some(Options { input, output, incremental, robust, information, json }))
}

fn parse_kernel(text: &str) -> Result<RobustKernel, String> {
    let (name, value) = text.split_once(':').ok_or_else(|| format!("--robust expects NAME:VALUE, got {text:?}"))?;
    let value: f64 = value.parse().map_err(|_| format!("--robust: {value:?} is not a number"))?;
    match name {
        "cauchy" => RobustKernel::cauchy(value),
        "huber" => RobustKernel::huber(value),
        _ => return Err(format!("--robust: unknown kernel {name:?} (cauchy or huber)")),
    }
    .map_err(|e| format!("--robust: {e}"))
}

/// What a run measured.
struct Report {
    mode: &'static str,
    vertices: usize,
    factors: usize,
    initial_cost: f64,
    final_cost: f64,
    iterations: usize,
    time_ms: f64,
    update_ms: Option<(f64, f64)>,
    repaired_edges: Vec<RepairedEdge>,
}

fn run(options: &Options) -> Result<Report, String> {
    let text =
        std::fs::read_to_string(&options.input).map_err(|e| format!("cannot read {}: {e}", options.input.display()))?;
    let checked = g2o::parse_with(&text, options.information).map_err(|e| {
        let hint = if matches!(e.kind, G2oErrorKind::NotPositiveDefinite { .. }) {
            format!("\n{REPAIR_HINT}")
        } else {
            String::new()
        };
        format!("{}: {e}{hint}", options.input.display())
    })?;
    let mut graph = checked.graph;
    // Files such as CSAIL.g2o carry only edges: initialize from the odometry chain.
    graph.fill_missing_vertices().map_err(|e| format!("{}: {e}", options.input.display()))?;
    let robust = options.robust.map(|kernel| RobustSelection { kernel, loop_closures_only: true });
    let mut problem = dataset::from_g2o(&graph, robust).map_err(|e| e.to_string())?;
    let initial_cost = posegraph::total_cost(&problem.factors, &problem.values).map_err(|e| e.to_string())?;

    let (final_cost, iterations, time_ms, update_ms, values) = if options.incremental {
        let steps = dataset::incremental_steps(&problem);
        let mut isam = Isam::new(IsamParams::default());
        let mut times = Vec::with_capacity(steps.len());
        let start = Instant::now();
        for step in &steps {
            let initial = step.initial_value(&isam);
            let t = Instant::now();
            isam.update(step.factors.clone(), &[(step.key, initial)]).map_err(|e| e.to_string())?;
            times.push(t.elapsed().as_secs_f64() * 1e3);
        }
        let time_ms = start.elapsed().as_secs_f64() * 1e3;
        times.sort_by(f64::total_cmp);
        let median = times.get(times.len() / 2).copied().unwrap_or(0.0);
        let max = times.last().copied().unwrap_or(0.0);
        (isam.cost(), steps.len(), time_ms, Some((median, max)), isam.estimates())
    } else {
        let start = Instant::now();
        let summary = posegraph::optimize(&problem.factors, &mut problem.values, &LmParams::default())
            .map_err(|e| e.to_string())?;
        let time_ms = start.elapsed().as_secs_f64() * 1e3;
        (summary.final_cost, summary.iterations, time_ms, None, problem.values.clone())
    };

    if let Some(path) = &options.output {
        let mut out = String::new();
        g2o::write(&dataset::to_g2o(&problem.factors, &values), &mut out).map_err(|e| e.to_string())?;
        std::fs::write(path, out).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    }
    Ok(Report {
        mode: if options.incremental { "incremental" } else { "batch" },
        vertices: values.len(),
        factors: problem.factors.len(),
        initial_cost,
        final_cost,
        iterations,
        time_ms,
        update_ms,
        repaired_edges: checked.repaired_edges,
    })
}

pub fn main(args: Vec<OsString>) -> ExitCode {
    let (options, report) = match super::parse_and_run("onboard", "posegraph", USAGE, args, parse_args, run) {
        Ok(done) => done,
        Err(code) => return code,
    };
    if options.json {
        let mut object = serde_json::json!({
            "mode": report.mode,
            "vertices": report.vertices,
            "factors": report.factors,
            "initial_cost": report.initial_cost,
            "final_cost": report.final_cost,
            "iterations": report.iterations,
            "time_ms": report.time_ms,
        });
        if let Some((median, max)) = report.update_ms {
            object["median_update_ms"] = median.into();
            object["max_update_ms"] = max.into();
        }
        object["repaired_edges"] = report
            .repaired_edges
            .iter()
            .map(|edge| {
                serde_json::json!({
                    "line": edge.line,
                    "from": edge.from,
                    "to": edge.to,
                    "smallest_eigenvalue": edge.smallest_eigenvalue_before,
                    "eigen_floor": edge.eigen_floor,
                    "frobenius_change": edge.frobenius_change,
                })
            })
            .collect();
        println!("{object}");
    } else {
        println!(
            "{} optimization of {} ({} vertices, {} factors)",
            report.mode,
            options.input.display(),
            report.vertices,
            report.factors
        );
        println!("initial cost  {:.6}", report.initial_cost);
        println!("final cost    {:.6}", report.final_cost);
        let unit = if options.incremental { "updates" } else { "iterations" };
        println!("{unit:<13} {}", report.iterations);
        println!("time          {:.1} ms", report.time_ms);
        if let Some((median, max)) = report.update_ms {
            println!("per update    median {median:.3} ms, max {max:.3} ms");
        }
        if matches!(options.information, InformationPolicy::Repair(_)) {
            println!("repaired      {} edges (information not positive definite)", report.repaired_edges.len());
        }
    }
    ExitCode::SUCCESS
}
