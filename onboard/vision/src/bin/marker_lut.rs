//! `marker-lut`: generates the offline look-up table of the marker uncertainty model
//! (`vision::marker_pose::lut`, thesis §6.2.3) with the on-board AprilTag detector.
//!
//! Exit codes: 0 success, 1 runtime error (generation or writing failed), 2 usage error.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use vision::apriltag::{TagDetector, TagDetectorConfig};
use vision::marker_pose::lut::{
    LutParams, apriltag_corners, apriltag_description, default_command_params, generate_lut,
    sim_rover_camera_downscaled,
};
use vision::marker_pose::render::{TAG36H11_ID0_PATTERN, cells_from_pattern};

const USAGE: &str = "\
usage: marker-lut --out FILE [--size-m S] [--downscale K] [--width W --height H --fx F --fy F --cx C --cy C]
                  [--grid N] [--threads T]

  --out FILE     where to write the table (vision::marker_pose::lut file format)
  --size-m S     tag size, the edge of the black square (default 0.16)
  --downscale K  start from the simulator's rover camera as rendered at downscale K (default 1:
                 1024 x 508, f = 1083.14, c = (511.5, 253.5); 4: 256 x 127, f = 270.79)
  --width, --height, --fx, --fy, --cx, --cy
                 the rectified camera (pixels); each overrides its own default
  --grid N       N x N cells over d in [0.2, 7.0] m and tilt in [-89, 89] deg (default 200)
  --threads T    generator threads (default: the machine's cores)

Renders tag36h11 id 0 in every cell, detects it with vision::apriltag::TagDetector (default
configuration), runs PnP on the detected corners and their 256 perturbed sets and stores the
per-DOF maximum error (raw and after the median filter and fill rules).";

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
    out: PathBuf,
    params: LutParams,
    threads: usize,
}

fn number<T: std::str::FromStr>(name: &str, value: std::ffi::OsString) -> Result<T, CliError> {
    value
        .to_str()
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| CliError::Usage(format!("--{name}: not a valid number: {}", value.to_string_lossy())))
}

fn parse_args() -> Result<Option<Args>, CliError> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_env();
    let defaults = default_command_params();
    let (mut camera, mut size_m, mut grid) = (defaults.camera, defaults.tag_size_m, defaults.grid.distances);
    let mut out = None;
    let mut threads = std::thread::available_parallelism().map_or(1, |n| n.get());
    while let Some(arg) = parser.next()? {
        match arg {
            Long("out") => out = Some(PathBuf::from(parser.value()?)),
            Long("size-m") => size_m = number("size-m", parser.value()?)?,
            Long("downscale") => {
                let k: u32 = number("downscale", parser.value()?)?;
                if !(1..=16).contains(&k) {
                    return Err(CliError::Usage("--downscale: 1..=16".to_owned()));
                }
                camera = sim_rover_camera_downscaled(k);
            }
            Long("width") => camera.width_px = number("width", parser.value()?)?,
            Long("height") => camera.height_px = number("height", parser.value()?)?,
            Long("fx") => camera.intrinsics.fx_px = number("fx", parser.value()?)?,
            Long("fy") => camera.intrinsics.fy_px = number("fy", parser.value()?)?,
            Long("cx") => camera.intrinsics.cx_px = number("cx", parser.value()?)?,
            Long("cy") => camera.intrinsics.cy_px = number("cy", parser.value()?)?,
            Long("grid") => grid = number("grid", parser.value()?)?,
            Long("threads") => threads = number("threads", parser.value()?)?,
            Short('h') | Long("help") => return Ok(None),
            _ => return Err(arg.unexpected().into()),
        }
    }
    let out = out.ok_or_else(|| CliError::Usage("--out FILE is required".to_owned()))?;
    let k = &camera.intrinsics;
    let valid = camera.width_px > 0
        && camera.height_px > 0
        && k.fx_px.is_finite()
        && k.fy_px.is_finite()
        && k.fx_px > 0.0
        && k.fy_px > 0.0
        && k.cx_px.is_finite()
        && k.cy_px.is_finite()
        && size_m.is_finite()
        && size_m > 0.0
        && (2..=1000).contains(&grid)
        && threads > 0;
    if !valid {
        return Err(CliError::Usage(
            "camera sizes, focal lengths and tag size must be positive, the grid 2..=1000, threads > 0".to_owned(),
        ));
    }
    let params = LutParams::command_defaults(camera, size_m, grid, apriltag_description(&TagDetectorConfig::default()));
    Ok(Some(Args { out, params, threads }))
}

fn run(args: &Args) -> Result<(), CliError> {
    let config = TagDetectorConfig::default();
    TagDetector::new(config).map_err(|e| CliError::Runtime(format!("detector: {e}")))?;
    let cells = cells_from_pattern(&TAG36H11_ID0_PATTERN);
    let p = &args.params;
    eprintln!(
        "marker-lut: {} x {} cells, {} x {} px, f = ({:.3}, {:.3}), c = ({:.2}, {:.2}), tag {} m, {} threads",
        p.grid.distances,
        p.grid.tilts,
        p.camera.width_px,
        p.camera.height_px,
        p.camera.intrinsics.fx_px,
        p.camera.intrinsics.fy_px,
        p.camera.intrinsics.cx_px,
        p.camera.intrinsics.cy_px,
        p.tag_size_m,
        args.threads
    );
    let start = Instant::now();
    let make_detector = || {
        let mut detector = TagDetector::new(config).ok();
        move |image: vision::ImageView<'_>| detector.as_mut().and_then(|d| apriltag_corners(d, image, 0))
    };
    let progress = |done: usize, total: usize| {
        let elapsed = start.elapsed().as_secs_f64();
        let eta = elapsed / done as f64 * (total - done) as f64;
        eprint!("\rrow {done}/{total}, {elapsed:.0} s elapsed, ~{eta:.0} s to go   ");
    };
    let lut = generate_lut(p, &cells, make_detector, args.threads, progress)
        .map_err(|e| CliError::Runtime(format!("generation failed: {e}")))?;
    let seconds = start.elapsed().as_secs_f64();
    let bytes = lut.encode();
    std::fs::write(&args.out, &bytes)
        .map_err(|e| CliError::Runtime(format!("cannot write {}: {e}", args.out.display())))?;
    eprintln!();
    println!(
        "wrote {} ({} bytes): {:.1} % of cells detected, generated in {seconds:.0} s",
        args.out.display(),
        bytes.len(),
        100.0 * lut.detected_share()
    );
    Ok(())
}

fn main() -> ExitCode {
    match parse_args().and_then(|args| match args {
        Some(args) => run(&args),
        None => {
            println!("{USAGE}");
            Ok(())
        }
    }) {
        Ok(()) => ExitCode::SUCCESS,
        Err(CliError::Usage(message)) => {
            eprintln!("marker-lut: {message}\n{USAGE}");
            ExitCode::from(2)
        }
        Err(CliError::Runtime(message)) => {
            eprintln!("marker-lut: {message}");
            ExitCode::from(1)
        }
    }
}
