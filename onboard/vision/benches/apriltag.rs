#![allow(clippy::unwrap_used, clippy::expect_used)]
//! `vision::apriltag` against the upstream C library (AprilTag 3.4.5, its Python wheel, timed
//! inside Python around `detect` only), one thread each, on the 20 real photographs of
//! `data/apriltag/` and on a full-resolution 1024×508 simulated frame with a rover in view; at
//! decimation 1 and 2. Both see the same grey pixels (PNG copies of what our decoder read).
//!
//! Per image: the best of several runs, in thread CPU time (immune to other load on the shared
//! machine; wall-clock in brackets), and the ratio ours / C.
//!
//! `cargo bench -p vision --bench apriltag`: the table. Without `--bench` (as `cargo test
//! --all-targets` runs it): a smoke run, two photos and the simulated frame, one run each.

#[path = "../tests/apriltag_common/mod.rs"]
mod apriltag_common;

use std::time::Instant;

use apriltag_common::{grey_copies, photo_sets, run_reference, sim_frames};
use vision::apriltag::{TagDetector, TagDetectorConfig};
use vision::image_file::GreyImage;

/// This thread's CPU time in ns (`CLOCK_THREAD_CPUTIME_ID`, the clock Python's
/// `time.thread_time` reads; `/proc/thread-self/schedstat` ticks in 4 ms steps on some kernels).
fn thread_cpu_ns() -> Option<u64> {
    let t = nix::time::clock_gettime(nix::time::ClockId::CLOCK_THREAD_CPUTIME_ID).ok()?;
    Some(t.tv_sec() as u64 * 1_000_000_000 + t.tv_nsec() as u64)
}

/// Best CPU and wall time of `runs` detections (after one warm-up) and the number of tags.
fn time_ours(detector: &mut TagDetector, image: &GreyImage, runs: usize) -> (f64, f64, usize) {
    let tags = detector.detect(image.view()).len();
    let (mut cpu_best, mut wall_best) = (f64::INFINITY, f64::INFINITY);
    for _ in 0..runs {
        let (start, cpu_start) = (Instant::now(), thread_cpu_ns());
        std::hint::black_box(detector.detect(std::hint::black_box(image.view())));
        wall_best = wall_best.min(start.elapsed().as_secs_f64() * 1e3);
        if let (Some(a), Some(b)) = (cpu_start, thread_cpu_ns()) {
            cpu_best = cpu_best.min(b.saturating_sub(a) as f64 * 1e-6);
        }
    }
    if !cpu_best.is_finite() {
        cpu_best = wall_best;
    }
    (cpu_best, wall_best, tags)
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let runs = if full { 15 } else { 1 };
    let mut images: Vec<(String, GreyImage)> = Vec::new();
    for set in photo_sets() {
        images.extend(set.images);
    }
    if !full {
        images = vec![images[0].clone(), images[6].clone()];
    }
    // A 1024×508 frame with a rover and its markers in view.
    let frame = sim_frames(5, 1, 0).remove(0);
    assert!(!frame.markers.is_empty(), "the simulated frame should show a rover's markers");
    images.push((format!("sim 1024x508 ({} markers in view)", frame.markers.len()), frame.image));

    let dir = std::path::PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("apriltag_bench");
    let files = grey_copies(&images, &dir);
    println!(
        "apriltag ({}): ours vs upstream C 3.4.5, one thread, best of {runs} run(s), thread CPU ms (wall ms)",
        if full { "full" } else { "smoke" }
    );
    for decimate in [1u32, 2] {
        let config = TagDetectorConfig { quad_decimate: decimate, ..TagDetectorConfig::default() };
        let reference = run_reference(&files, decimate, config.max_hamming, runs);
        let mut detector = TagDetector::new(config).unwrap();
        println!("\ndecimate {decimate}:");
        println!("| image | size | tags ours / C | ours ms | C ms | ours / C |");
        println!("|---|---|---|---|---|---|");
        let (mut sum_ours, mut sum_c, mut photos_ours, mut photos_c) = (0.0, 0.0, 0.0, 0.0);
        let (mut tags_ours, mut tags_c) = (0, 0);
        for ((name, image), r) in images.iter().zip(&reference) {
            let (cpu, wall, tags) = time_ours(&mut detector, image, runs);
            println!(
                "| {name} | {}x{} | {tags} / {} | {cpu:.2} ({wall:.2}) | {:.2} ({:.2}) | {:.2} |",
                image.width,
                image.height,
                r.detections.len(),
                r.cpu_ms,
                r.time_ms,
                cpu / r.cpu_ms
            );
            sum_ours += cpu;
            sum_c += r.cpu_ms;
            if !name.starts_with("sim") {
                photos_ours += cpu;
                photos_c += r.cpu_ms;
                tags_ours += tags;
                tags_c += r.detections.len();
            }
        }
        println!(
            "| **photos** | | {tags_ours} / {tags_c} | {photos_ours:.1} | {photos_c:.1} | {:.2} |",
            photos_ours / photos_c
        );
        println!("| **all** | | | {sum_ours:.1} | {sum_c:.1} | {:.2} |", sum_ours / sum_c);
    }
}
