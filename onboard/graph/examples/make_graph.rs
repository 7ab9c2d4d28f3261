//! Writes a seeded synthetic pose graph (`posegraph::synthetic`) as a g2o file.
//!
//! ```sh
//! cargo run --release -p posegraph --example make_graph -- torus --seed 1 --out data/posegraph/torus3D_gen.g2o
//! cargo run --release -p posegraph --example make_graph -- grid --seed 1 --out data/posegraph/grid3D_gen.g2o
//! ```
//!
//! Default sizes: torus 50 rings × 100 poses (torus3D's 5,000 poses), grid 20³ (grid3D's 8,000).

use std::process::ExitCode;

use posegraph::g2o;
use posegraph::synthetic::{self, GridSpec, TorusSpec};

const USAGE: &str = "usage: make_graph (torus|grid) --seed N --out FILE.g2o";

fn run(args: &[String]) -> Result<(), String> {
    let family = args.first().ok_or(USAGE)?;
    let (mut seed, mut out) = (None, None);
    let mut rest = args[1..].iter();
    while let Some(flag) = rest.next() {
        let value = rest.next().ok_or_else(|| format!("{flag} needs a value; {USAGE}"))?;
        match flag.as_str() {
            "--seed" => seed = Some(value.parse::<u64>().map_err(|e| format!("--seed {value}: {e}"))?),
            "--out" => out = Some(value.clone()),
            _ => return Err(format!("unknown argument {flag}; {USAGE}")),
        }
    }
    // The seed is part of the dataset's identity: no silent default.
    let seed = seed.ok_or_else(|| format!("--seed is required; {USAGE}"))?;
    let out = out.ok_or_else(|| format!("--out is required; {USAGE}"))?;
    let graph = match family.as_str() {
        "torus" => synthetic::torus(&TorusSpec::default(), seed),
        "grid" => synthetic::grid(&GridSpec::default(), seed),
        other => return Err(format!("unknown family {other}; {USAGE}")),
    };
    let mut text = String::new();
    g2o::write(&graph, &mut text).map_err(|e| format!("formatting: {e}"))?;
    std::fs::write(&out, text).map_err(|e| format!("{out}: {e}"))?;
    eprintln!("{out}: {family}, seed {seed}, {} poses, {} edges", graph.vertices.len(), graph.edges.len());
    Ok(())
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("make_graph: {message}");
            ExitCode::FAILURE
        }
    }
}
