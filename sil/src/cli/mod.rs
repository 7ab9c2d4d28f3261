//! Command-line front ends of the `sil` subcommands.

pub mod campaign;
pub mod mission;
pub mod vio;

/// The value of option `name` as UTF-8.
fn text(parser: &mut lexopt::Parser, name: &str) -> Result<String, String> {
    let value = parser.value().map_err(|e| e.to_string())?;
    value.into_string().map_err(|v| format!("{name}: not UTF-8: {v:?}"))
}

/// `--downscale K`: 1, 2 or 4.
fn downscale(v: &str) -> Result<u32, String> {
    match v {
        "1" => Ok(1),
        "2" => Ok(2),
        "4" => Ok(4),
        _ => Err(format!("--downscale: expected 1, 2 or 4, got {v:?}")),
    }
}

/// `--duration S`: at least 5 simulated seconds.
fn duration_s(v: &str) -> Result<f64, String> {
    match v.parse::<f64>() {
        Ok(s) if s.is_finite() && s >= 5.0 => Ok(s),
        _ => Err(format!("--duration: expected at least 5 seconds, got {v:?}")),
    }
}

/// `--threads N`: 1 to 64 threads stepping a mission's robots.
fn step_threads(v: &str) -> Result<usize, String> {
    match v.parse::<usize>() {
        Ok(n) if (1..=64).contains(&n) => Ok(n),
        _ => Err(format!("--threads: expected 1 to 64, got {v:?}")),
    }
}
