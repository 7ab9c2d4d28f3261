//! Time per frame of the fast core at the rover's frame size, 1024×508 px, 128 disparities:
//! Four and Eight paths, one and two threads, dispatched SIMD kernels and portable ones.
//!
//! Input: the Adirondack pair (`middlebury_2014q_adirondack`, 720×497) in gray, resized to
//! 1024×508 by bilinear interpolation (its disparities, ≤ ~75 px, grow to ≤ ~105 px: inside 128).
//!
//! `cargo bench -p fpga_model --bench fast_core`: the table (median of several frames, after a
//! warm-up). Without `--bench` (as `cargo test --all-targets` runs it): one small frame per
//! variant as a smoke test. `FAST_CORE_ONLY=Four/1/avx512` (substring of `paths/threads/kernels`)
//! runs only the matching variants and `FAST_CORE_FRAMES=n` times `n` frames, for profiling.

use std::process::ExitCode;
use std::time::Instant;

use fpga_model::fast::Matcher;
use fpga_model::{DisparityImage, GrayImage, INVALID, PathMode, SgmConfig, io};

const WIDTH_PX: usize = 1024;
const HEIGHT_PX: usize = 508;
const DISPARITIES: u16 = 128;

/// Bilinear resize with pixel centres aligned, in Q8 fixed point.
fn resize_bilinear(image: &GrayImage, width: usize, height: usize) -> GrayImage {
    const ONE: i64 = 256;
    let coordinate = |i: usize, src: usize, dst: usize| {
        let q = ((2 * i as i64 + 1) * src as i64 * ONE) / (2 * dst as i64) - ONE / 2;
        let q = q.clamp(0, (src as i64 - 1) * ONE);
        ((q / ONE) as usize, q % ONE)
    };
    let at = |x: usize, y: usize| i64::from(image.pixels[y * image.width + x]);
    let mut pixels = Vec::with_capacity(width * height);
    for y in 0..height {
        let (y0, fy) = coordinate(y, image.height, height);
        let y1 = (y0 + 1).min(image.height - 1);
        for x in 0..width {
            let (x0, fx) = coordinate(x, image.width, width);
            let x1 = (x0 + 1).min(image.width - 1);
            let top = at(x0, y0) * (ONE - fx) + at(x1, y0) * fx;
            let bottom = at(x0, y1) * (ONE - fx) + at(x1, y1) * fx;
            pixels.push(((top * (ONE - fy) + bottom * fy + ONE * ONE / 2) / (ONE * ONE)).clamp(0, 255) as u8);
        }
    }
    GrayImage { width, height, pixels }
}

fn load_pair(width: usize, height: usize) -> Result<(GrayImage, GrayImage), String> {
    let data = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/stereo/middlebury_2014q_adirondack/");
    let read = |name: &str| io::read_gray_png(format!("{data}{name}")).map_err(|e| e.to_string());
    let (left, right) = (read("Adirondack_left.png")?, read("Adirondack_right.png")?);
    Ok((resize_bilinear(&left, width, height), resize_bilinear(&right, width, height)))
}

/// Median time of `frames` frames after one warm-up frame, in ms; and the last output.
fn time_frames(
    matcher: &mut Matcher,
    left: &GrayImage,
    right: &GrayImage,
    frames: usize,
) -> Result<(f64, DisparityImage), String> {
    let mut out = DisparityImage { width: 0, height: 0, data: Vec::new() };
    matcher.compute_into(left, right, &mut out).map_err(|e| e.to_string())?;
    let mut times_ms = Vec::with_capacity(frames);
    for _ in 0..frames {
        let start = Instant::now();
        matcher.compute_into(left, right, &mut out).map_err(|e| e.to_string())?;
        times_ms.push(start.elapsed().as_secs_f64() * 1e3);
    }
    times_ms.sort_by(f64::total_cmp);
    Ok((times_ms[times_ms.len() / 2], out))
}

fn run(full: bool) -> Result<(), String> {
    let (width, height, frames) = if full { (WIDTH_PX, HEIGHT_PX, 15usize) } else { (96, 24, 1) };
    let frames = std::env::var("FAST_CORE_FRAMES").ok().and_then(|n| n.parse().ok()).unwrap_or(frames);
    let (left, right) = load_pair(width, height)?;
    let only = std::env::var("FAST_CORE_ONLY").unwrap_or_default();
    println!(
        "fast core, {width}x{height} px, D = {DISPARITIES}, default configuration otherwise; median of {frames} frames"
    );
    println!(
        "{:<6} {:>7} {:>9} {:>10} {:>8} {:>9} {:>12}",
        "paths", "threads", "kernels", "ms/frame", "fps", "invalid", "memory MiB"
    );
    for paths in [PathMode::Four, PathMode::Eight] {
        let config = SgmConfig { disparities: DISPARITIES, paths, ..SgmConfig::default() };
        let mut reference_output: Option<DisparityImage> = None;
        for threads in [1, 2] {
            for portable in [false, true] {
                let mut matcher = Matcher::new(config, width, height, threads).map_err(|e| e.to_string())?;
                matcher.set_force_portable(portable);
                if !format!("{paths:?}/{}/{}", matcher.threads(), matcher.isa().name()).contains(only.as_str()) {
                    continue;
                }
                // Portable kernels are several times slower: fewer frames keep the run short.
                let n = if portable { frames.div_ceil(3) } else { frames };
                let (ms, out) = time_frames(&mut matcher, &left, &right, n)?;
                let invalid = out.data.iter().filter(|&&v| v == INVALID).count() as f64 / out.data.len() as f64;
                println!(
                    "{:<6} {:>7} {:>9} {:>10.2} {:>8.1} {:>8.1}% {:>12.1}",
                    format!("{paths:?}"),
                    matcher.threads(),
                    matcher.isa().name(),
                    ms,
                    1e3 / ms,
                    100.0 * invalid,
                    matcher.working_memory_bytes() as f64 / (1 << 20) as f64
                );
                match &reference_output {
                    None => reference_output = Some(out),
                    Some(first) if first.data != out.data => {
                        return Err(format!(
                            "{paths:?}: {threads} thread(s), portable {portable} differs from the first variant"
                        ));
                    }
                    Some(_) => {}
                }
            }
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let full = std::env::args().any(|arg| arg == "--bench");
    match run(full) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("fast_core: {message}");
            ExitCode::FAILURE
        }
    }
}
