//! Speed of the fast matcher against OpenCV's StereoSGBM at the rover's frame size, 1024×508 px
//! with 128 disparities, measured in the same run on the same pixels.
//!
//! Input: the Adirondack pair (`middlebury_2014q_adirondack`, 720×497) converted to gray and
//! resized to 1024×508 by integer bilinear interpolation, written as gray PNGs into the target
//! directory; OpenCV reads those PNGs through `scripts/opencv_sgbm.py speed`.
//!
//! `cargo bench -p fpga_model --bench vs_opencv`: the full table (median of several runs,
//! matching only, no I/O). Without `--bench` (as `cargo test --all-targets` runs it): a smoke run
//! of every step, one frame each.

use std::path::{Path, PathBuf};
use std::process::{Command, ExitCode};
use std::time::Instant;

use fpga_model::{DisparityImage, GrayImage, PathMode, SgmConfig, fast, io};

/// The rover camera's frame and the core's disparity range.
const WIDTH_PX: usize = 1024;
const HEIGHT_PX: usize = 508;
const DISPARITIES: u16 = 128;

/// Fractional bits of the resampling coordinates and weights.
const FRAC_BITS: u32 = 8;
const ONE: i64 = 1 << FRAC_BITS;

/// Source coordinate of destination index `i` in Q8, pixel centres aligned
/// (`(i + 0.5) · src / dst − 0.5`, clamped to the image), as (index, fraction).
fn source_coordinate(i: usize, src: usize, dst: usize) -> (usize, i64) {
    let q = ((2 * i as i64 + 1) * src as i64 * ONE) / (2 * dst as i64) - ONE / 2;
    let q = q.clamp(0, (src as i64 - 1) * ONE);
    ((q >> FRAC_BITS) as usize, q & (ONE - 1))
}

/// Bilinear resize in integer arithmetic: Q8 weights, one rounding at the end.
fn resize_bilinear(image: &GrayImage, width: usize, height: usize) -> Result<GrayImage, String> {
    let mut pixels = Vec::with_capacity(width * height);
    let at = |x: usize, y: usize| i64::from(image.pixels[y * image.width + x]);
    for y in 0..height {
        let (y0, fy) = source_coordinate(y, image.height, height);
        let y1 = (y0 + 1).min(image.height - 1);
        for x in 0..width {
            let (x0, fx) = source_coordinate(x, image.width, width);
            let x1 = (x0 + 1).min(image.width - 1);
            let top = at(x0, y0) * (ONE - fx) + at(x1, y0) * fx;
            let bottom = at(x0, y1) * (ONE - fx) + at(x1, y1) * fx;
            let value = (top * (ONE - fy) + bottom * fy + ONE * ONE / 2) >> (2 * FRAC_BITS);
            pixels.push(value.clamp(0, 255) as u8);
        }
    }
    GrayImage::new(width, height, pixels).map_err(|e| e.to_string())
}

/// Writes the 1024×508 gray pair into the target directory; returns the images and paths.
fn prepare_input() -> Result<(GrayImage, GrayImage, PathBuf, PathBuf), String> {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/stereo/middlebury_2014q_adirondack");
    let out_dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("vs_opencv");
    std::fs::create_dir_all(&out_dir).map_err(|e| format!("{}: {e}", out_dir.display()))?;
    let mut images = Vec::new();
    for (file, name) in [("Adirondack_left.png", "left_1024x508.png"), ("Adirondack_right.png", "right_1024x508.png")] {
        let source = io::read_gray_png(data.join(file)).map_err(|e| e.to_string())?;
        let resized = resize_bilinear(&source, WIDTH_PX, HEIGHT_PX)?;
        let path = out_dir.join(name);
        io::write_gray_png(&path, &resized).map_err(|e| e.to_string())?;
        images.push((resized, path));
    }
    let (right, right_path) = images.pop().ok_or("no right image")?;
    let (left, left_path) = images.pop().ok_or("no left image")?;
    Ok((left, right, left_path, right_path))
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    let n = values.len();
    if n % 2 == 1 { values[n / 2] } else { (values[n / 2 - 1] + values[n / 2]) / 2.0 }
}

struct OursResult {
    paths: PathMode,
    threads: usize,
    median_ms: f64,
    working_memory_bytes: usize,
    invalid_fraction: f64,
}

fn time_ours(
    left: &GrayImage,
    right: &GrayImage,
    paths: PathMode,
    threads: usize,
    runs: usize,
) -> Result<OursResult, String> {
    let config = SgmConfig { disparities: DISPARITIES, paths, ..Default::default() };
    let mut matcher = fast::Matcher::new(config, left.width, left.height, threads).map_err(|e| e.to_string())?;
    let mut out = DisparityImage { width: left.width, height: left.height, data: vec![0; left.pixels.len()] };
    // Warm-up: first-touch page faults of the working memory are not a per-frame cost.
    matcher.compute_into(left, right, &mut out).map_err(|e| e.to_string())?;
    let mut times_ms = Vec::with_capacity(runs);
    for _ in 0..runs {
        let start = Instant::now();
        matcher.compute_into(left, right, &mut out).map_err(|e| e.to_string())?;
        times_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    Ok(OursResult {
        paths,
        threads: matcher.threads(),
        median_ms: median(&mut times_ms),
        working_memory_bytes: matcher.working_memory_bytes(),
        invalid_fraction: out.invalid_fraction(),
    })
}

struct OpenCvResult {
    mode: String,
    block_size: u32,
    threads: u64,
    median_ms: f64,
}

fn time_opencv(
    left: &Path,
    right: &Path,
    mode: &str,
    block_size: u32,
    runs: usize,
) -> Result<Vec<OpenCvResult>, String> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let python = root.join("../.venv/bin/python");
    if !python.exists() {
        return Err(format!("{} is missing: run scripts/test (it creates the venv with OpenCV)", python.display()));
    }
    let output = Command::new(&python)
        .arg(root.join("scripts/opencv_sgbm.py"))
        .arg("speed")
        .arg("--left")
        .arg(left)
        .arg("--right")
        .arg(right)
        .args(["--disparities", &DISPARITIES.to_string(), "--mode", mode])
        .args(["--block-size", &block_size.to_string(), "--runs", &runs.to_string()])
        .output()
        .map_err(|e| format!("{}: {e}", python.display()))?;
    if !output.status.success() {
        return Err(format!("opencv_sgbm.py speed failed: {}", String::from_utf8_lossy(&output.stderr)));
    }
    let report: serde_json::Value = serde_json::from_slice(&output.stdout).map_err(|e| e.to_string())?;
    let results = report["results"].as_array().ok_or("no results in the script's JSON")?;
    results
        .iter()
        .map(|r| {
            Ok(OpenCvResult {
                mode: mode.to_owned(),
                block_size,
                threads: r["threads"].as_u64().ok_or("no threads")?,
                median_ms: r["median_ms"].as_f64().ok_or("no median_ms")?,
            })
        })
        .collect()
}

fn run(full: bool) -> Result<(), String> {
    let (left, right, left_path, right_path) = prepare_input()?;
    let all_threads = std::thread::available_parallelism().map_or(1, usize::from);
    let runs = if full { 9 } else { 1 };
    let thread_counts: Vec<usize> = if all_threads > 1 { vec![1, all_threads] } else { vec![1] };

    let mut ours = Vec::new();
    for paths in [PathMode::Four, PathMode::Eight] {
        for &threads in &thread_counts {
            ours.push(time_ours(&left, &right, paths, threads, runs)?);
        }
    }
    // OpenCV's StereoSGBM: its three modes (SGBM: 5 paths; HH: 8 paths, full-image buffer;
    // SGBM_3WAY: 4-ish paths, the multi-threaded one) at block sizes 3 and 5.
    let opencv_settings: &[(&str, u32)] = if full {
        &[("SGBM", 3), ("SGBM", 5), ("HH", 3), ("HH", 5), ("SGBM_3WAY", 3), ("SGBM_3WAY", 5)]
    } else {
        &[("SGBM", 5)]
    };
    let opencv_runs = if full { 7 } else { 1 };
    let mut opencv = Vec::new();
    for &(mode, block_size) in opencv_settings {
        opencv.extend(time_opencv(&left_path, &right_path, mode, block_size, opencv_runs)?);
    }

    println!(
        "\n{WIDTH_PX}x{HEIGHT_PX} px, {DISPARITIES} disparities, Adirondack resized; median of {runs} (ours) / {opencv_runs} (OpenCV) runs, matching only"
    );
    println!("| matcher | setting | threads | ms/frame | fps | working memory | invalid % |");
    println!("|---|---|---:|---:|---:|---:|---:|");
    for r in &ours {
        println!(
            "| ours (fast) | {} paths | {} | {:.1} | {:.2} | {:.1} MiB | {:.1} |",
            r.paths.count(),
            r.threads,
            r.median_ms,
            1e3 / r.median_ms,
            r.working_memory_bytes as f64 / (1024.0 * 1024.0),
            100.0 * r.invalid_fraction
        );
    }
    for r in &opencv {
        println!(
            "| OpenCV StereoSGBM | MODE_{} blockSize {} | {} | {:.1} | {:.2} | | |",
            r.mode,
            r.block_size,
            r.threads,
            r.median_ms,
            1e3 / r.median_ms
        );
    }
    println!("\nspeed ratio ours/OpenCV (fps over fps, same thread count):");
    println!("| OpenCV setting | threads | ours 4 paths / OpenCV | ours 8 paths / OpenCV |");
    println!("|---|---:|---:|---:|");
    for r in &opencv {
        let ratio = |paths: PathMode| {
            ours.iter()
                .find(|o| o.paths == paths && o.threads as u64 == r.threads)
                .map_or("-".to_owned(), |o| format!("{:.2}", r.median_ms / o.median_ms))
        };
        println!(
            "| MODE_{} blockSize {} | {} | {} | {} |",
            r.mode,
            r.block_size,
            r.threads,
            ratio(PathMode::Four),
            ratio(PathMode::Eight)
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    // `cargo bench` passes `--bench`; `cargo test --all-targets` does not: then a smoke run only.
    let full = std::env::args().any(|a| a == "--bench");
    match run(full) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("vs_opencv: {message}");
            ExitCode::FAILURE
        }
    }
}
