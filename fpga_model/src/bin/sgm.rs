//! `sgm`: the FPGA SGM core model on a stereo pair, writing the left-view disparity as a
//! Middlebury PFM (px, `inf` = invalid).
//!
//! Exit codes: 0 success, 1 runtime error (unreadable file, size mismatch, matcher error),
//! 2 usage error (unknown or missing option, bad value, configuration out of range).

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use fpga_model::image::check_pair;
use fpga_model::{DisparityImage, PathMode, SgmConfig, fast, io, reference};

const USAGE: &str = "\
usage: sgm --left L.png --right R.png --disparities N --out D.pfm
           [--paths 4|8] [--threads T] [--reference] [--runs R] [--json]

  --left, --right   rectified stereo pair (PNG, any colour type; converted to 8-bit gray)
  --disparities N   disparities searched, 0..N-1 (multiple of 16, 16..=256)
  --out D.pfm       left-view disparity, Middlebury PFM in px, inf = invalid
  --paths 4|8       aggregation paths (default 8)
  --threads T       worker threads of the fast matcher (default: all cores)
  --reference       run the slow stage-by-stage reference instead (single-threaded)
  --runs R          match R times and report the median time (default 1)
  --json            print one JSON object instead of the human summary";

/// Why the program stops: usage errors exit with 2, runtime errors with 1.
#[derive(Debug)]
enum CliError {
    Usage(String),
    Runtime(String),
}

impl From<lexopt::Error> for CliError {
    fn from(e: lexopt::Error) -> Self {
        CliError::Usage(e.to_string())
    }
}

#[derive(Debug)]
struct Args {
    left: PathBuf,
    right: PathBuf,
    out: PathBuf,
    config: SgmConfig,
    threads: usize,
    reference: bool,
    runs: usize,
    json: bool,
}

fn parse_number<T: std::str::FromStr>(option: &str, value: std::ffi::OsString) -> Result<T, CliError> {
    let text = value.to_string_lossy();
    text.parse().map_err(|_| CliError::Usage(format!("--{option}: '{text}' is not a valid number")))
}

/// `Ok(None)` means `--help` was asked for.
fn parse_args() -> Result<Option<Args>, CliError> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_env();
    let (mut left, mut right, mut out, mut disparities) = (None, None, None, None);
    let mut paths = SgmConfig::default().paths;
    let mut threads = None;
    let (mut reference, mut json, mut runs) = (false, false, 1usize);
    while let Some(arg) = parser.next()? {
        match arg {
            Long("left") => left = Some(PathBuf::from(parser.value()?)),
            Long("right") => right = Some(PathBuf::from(parser.value()?)),
            Long("out") => out = Some(PathBuf::from(parser.value()?)),
            Long("disparities") => disparities = Some(parse_number::<u16>("disparities", parser.value()?)?),
            Long("paths") => {
                paths = match parse_number::<u8>("paths", parser.value()?)? {
                    4 => PathMode::Four,
                    8 => PathMode::Eight,
                    n => return Err(CliError::Usage(format!("--paths must be 4 or 8, not {n}"))),
                }
            }
            Long("threads") => threads = Some(parse_number::<usize>("threads", parser.value()?)?),
            Long("runs") => runs = parse_number("runs", parser.value()?)?,
            Long("reference") => reference = true,
            Long("json") => json = true,
            Long("help") | Short('h') => return Ok(None),
            _ => return Err(arg.unexpected().into()),
        }
    }
    let missing = |name: &str| CliError::Usage(format!("missing --{name}"));
    let config =
        SgmConfig { disparities: disparities.ok_or_else(|| missing("disparities"))?, paths, ..Default::default() };
    // A bad N is the caller's mistake: report it as usage before touching any file.
    config.validate().map_err(|e| CliError::Usage(e.to_string()))?;
    let threads = match threads {
        Some(0) => return Err(CliError::Usage("--threads must be at least 1".to_owned())),
        Some(t) => t,
        None => std::thread::available_parallelism().map_or(1, usize::from),
    };
    if runs == 0 {
        return Err(CliError::Usage("--runs must be at least 1".to_owned()));
    }
    Ok(Some(Args {
        left: left.ok_or_else(|| missing("left"))?,
        right: right.ok_or_else(|| missing("right"))?,
        out: out.ok_or_else(|| missing("out"))?,
        config,
        threads,
        reference,
        runs,
        json,
    }))
}

/// What one invocation measured.
struct Outcome {
    disparity: DisparityImage,
    times_ms: Vec<f64>,
    working_memory_bytes: Option<usize>,
    /// Threads the matcher actually used (the fast matcher caps them per path mode).
    threads: usize,
}

fn run_matcher(args: &Args, left: &fpga_model::GrayImage, right: &fpga_model::GrayImage) -> Result<Outcome, CliError> {
    let runtime = |e: fpga_model::SgmError| CliError::Runtime(e.to_string());
    let mut times_ms = Vec::with_capacity(args.runs);
    if args.reference {
        let mut disparity = None;
        for _ in 0..args.runs {
            let start = Instant::now();
            disparity = Some(reference::compute(left, right, &args.config).map_err(runtime)?);
            times_ms.push(start.elapsed().as_secs_f64() * 1e3);
        }
        let disparity = disparity.ok_or_else(|| CliError::Runtime("no run was made".to_owned()))?;
        return Ok(Outcome { disparity, times_ms, working_memory_bytes: None, threads: 1 });
    }
    // The matcher (and its working memory) is built once, as on the rover where it serves
    // every frame; the time per frame is `compute_into` alone.
    let mut matcher = fast::Matcher::new(args.config, left.width, left.height, args.threads).map_err(runtime)?;
    let mut disparity = DisparityImage { width: left.width, height: left.height, data: vec![0; left.pixels.len()] };
    for _ in 0..args.runs {
        let start = Instant::now();
        matcher.compute_into(left, right, &mut disparity).map_err(runtime)?;
        times_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    Ok(Outcome {
        disparity,
        times_ms,
        working_memory_bytes: Some(matcher.working_memory_bytes()),
        threads: matcher.threads(),
    })
}

fn median(values: &[f64]) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let n = sorted.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => sorted[n / 2],
        _ => (sorted[n / 2 - 1] + sorted[n / 2]) / 2.0,
    }
}

fn run(args: &Args) -> Result<(), CliError> {
    let runtime = |e: io::IoError| CliError::Runtime(e.to_string());
    let left = io::read_gray_png(&args.left).map_err(runtime)?;
    let right = io::read_gray_png(&args.right).map_err(runtime)?;
    check_pair(&left, &right).map_err(|e| CliError::Runtime(e.to_string()))?;

    let outcome = run_matcher(args, &left, &right)?;
    let disparity = &outcome.disparity;
    io::write_pfm(&args.out, disparity.width, disparity.height, &io::disparity_to_pfm_values(disparity))
        .map_err(runtime)?;

    let time_ms = median(&outcome.times_ms);
    let implementation = if args.reference { "reference" } else { "fast" };
    let invalid_fraction = disparity.invalid_fraction();
    if args.json {
        let report = serde_json::json!({
            "time_ms": time_ms,
            "times_ms": outcome.times_ms,
            "fps": 1e3 / time_ms,
            "width": disparity.width,
            "height": disparity.height,
            "disparities": args.config.disparities,
            "paths": args.config.paths.count(),
            "threads": outcome.threads,
            "threads_requested": args.threads,
            "implementation": implementation,
            "invalid_fraction": invalid_fraction,
            "working_memory_bytes": outcome.working_memory_bytes,
            "left": args.left.display().to_string(),
            "right": args.right.display().to_string(),
            "out": args.out.display().to_string(),
        });
        println!("{report}");
    } else {
        println!(
            "sgm: {}x{} px, {} disparities, {} paths, {implementation} matcher, {} thread(s)",
            disparity.width,
            disparity.height,
            args.config.disparities,
            args.config.paths.count(),
            outcome.threads
        );
        println!(
            "time per frame: {time_ms:.2} ms ({:.1} fps; matching only, median of {} run(s))",
            1e3 / time_ms,
            outcome.times_ms.len()
        );
        if let Some(bytes) = outcome.working_memory_bytes {
            println!("working memory: {:.1} MiB", bytes as f64 / (1024.0 * 1024.0));
        }
        println!("invalid pixels: {:.2} %", 100.0 * invalid_fraction);
        println!("wrote {}", args.out.display());
    }
    Ok(())
}

fn main() -> ExitCode {
    let result = parse_args().and_then(|args| match args {
        Some(args) => run(&args),
        None => {
            println!("{USAGE}");
            Ok(())
        }
    });
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(CliError::Usage(message)) => {
            eprintln!("sgm: {message}\n\n{USAGE}");
            ExitCode::from(2)
        }
        Err(CliError::Runtime(message)) => {
            eprintln!("sgm: error: {message}");
            ExitCode::from(1)
        }
    }
}
