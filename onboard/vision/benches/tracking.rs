#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Front-end cost per frame on real KITTI frames 0 and 1 (kitti_straight, left camera), resized
//! (nearest neighbour) from 1226×370 to the rover's 1024×508 so the figures apply to the rover:
//! one pyramid build, detection of 400 features on an empty image, and forward + backward KLT
//! tracking of those features into the next frame. Single thread.
//! Run: `cargo bench -p vision --bench tracking`.

use std::hint::black_box;
use std::time::Instant;

use vision::ImageView;
use vision::features::{FeatureConfig, FeatureDetector};
use vision::klt::{KltConfig, KltTracker};
use vision::pyramid::Pyramid;

const KITTI_LEFT: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/stereo_sequences/kitti_straight/image_l");
const WIDTH: usize = 1024;
const HEIGHT: usize = 508;
/// Pyramid levels of `VoConfig::default()`.
const LEVELS: usize = 4;
const ROUNDS: usize = 50;

/// This thread's on-CPU time in ns. `schedstat` carries the same scheduler accounting as the
/// utime + stime fields of `/proc/thread-self/stat` but in ns instead of 10 ms clock ticks, which
/// would be coarser than the stages timed here. Load from other processes does not inflate it.
fn thread_cpu_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}

fn load_resized(name: &str) -> Vec<u8> {
    let path = format!("{KITTI_LEFT}/{name}");
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes.as_slice())).read_info().unwrap();
    assert_eq!(reader.output_color_type(), (png::ColorType::Grayscale, png::BitDepth::Eight), "{path}");
    let (w, h) = (reader.info().width as usize, reader.info().height as usize);
    let mut data = vec![0; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut data).unwrap();
    let mut out = Vec::with_capacity(WIDTH * HEIGHT);
    for y in 0..HEIGHT {
        for x in 0..WIDTH {
            out.push(data[(y * h / HEIGHT) * w + x * w / WIDTH]);
        }
    }
    out
}

/// Per-call wall and CPU milliseconds of one stage. Each sample is the mean over a block of
/// calls lasting about [`BLOCK_MS`]: this kernel accounts thread CPU time in scheduler ticks
/// (4 ms here), so single calls of a few ms would read as 0 or 4 ms.
struct Stage {
    name: &'static str,
    calls_per_block: usize,
    wall_ms: Vec<f64>,
    cpu_ms: Vec<f64>,
}

const BLOCK_MS: f64 = 60.0;

impl Stage {
    /// Sizes the blocks from one timed call.
    fn new(name: &'static str, mut f: impl FnMut()) -> Self {
        let start = Instant::now();
        f();
        let once_ms = start.elapsed().as_secs_f64() * 1e3;
        let calls_per_block = ((BLOCK_MS / once_ms.max(1e-3)).ceil() as usize).clamp(1, 10_000);
        Stage { name, calls_per_block, wall_ms: Vec::new(), cpu_ms: Vec::new() }
    }

    fn run(&mut self, rounds: usize, mut f: impl FnMut()) {
        for _ in 0..rounds {
            let (start, cpu_start) = (Instant::now(), thread_cpu_ns());
            for _ in 0..self.calls_per_block {
                f();
            }
            let n = self.calls_per_block as f64;
            self.wall_ms.push(start.elapsed().as_secs_f64() * 1e3 / n);
            if let (Some(a), Some(b)) = (cpu_start, thread_cpu_ns()) {
                self.cpu_ms.push(b.saturating_sub(a) as f64 * 1e-6 / n);
            }
        }
        let stats = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            let at = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
            (at(0.5), at(0.95))
        };
        let (wall_median, wall_p95) = stats(&mut self.wall_ms);
        print!(
            "{:<20} ({:>3} calls/block) wall median {wall_median:7.3} ms, p95 {wall_p95:7.3} ms",
            self.name, self.calls_per_block
        );
        if self.cpu_ms.is_empty() {
            println!();
        } else {
            let (cpu_median, cpu_p95) = stats(&mut self.cpu_ms);
            println!(" | thread CPU median {cpu_median:7.3} ms, p95 {cpu_p95:7.3} ms");
        }
    }
}

fn main() {
    let prev = load_resized("000000.png");
    let next = load_resized("000001.png");
    let prev_view = ImageView::new(WIDTH, HEIGHT, &prev).unwrap();
    let next_view = ImageView::new(WIDTH, HEIGHT, &next).unwrap();
    let (mut p0, mut p1) = (Pyramid::new(WIDTH, HEIGHT, LEVELS), Pyramid::new(WIDTH, HEIGHT, LEVELS));
    let mut detector = FeatureDetector::new(FeatureConfig::default(), WIDTH, HEIGHT);
    let mut tracker = KltTracker::new(KltConfig::default());
    let (mut features, mut points, mut out) = (Vec::new(), Vec::new(), Vec::new());
    // Warm-up (first-call buffer sizing, caches).
    p0.build(prev_view);
    p1.build(next_view);
    detector.detect(prev_view, &[], &mut features);
    points.extend(features.iter().map(|k| [k.x, k.y]));
    tracker.track(&p0, &p1, &points, None, &mut out);

    let tracked = out.iter().flatten().count();
    println!(
        "KITTI 0→1 resized to {WIDTH}x{HEIGHT}, {LEVELS} levels, one thread: {} features, {tracked} tracked with the \
         forward-backward check, {} Gauss-Newton iterations; per call over {ROUNDS} blocks:",
        features.len(),
        tracker.last_iterations()
    );
    let mut pyramid = Stage::new("pyramid build", || p0.build(black_box(prev_view)));
    pyramid.run(ROUNDS, || p0.build(black_box(prev_view)));
    let mut detect = Stage::new("detect 400", || detector.detect(black_box(prev_view), &[], &mut features));
    detect.run(ROUNDS, || detector.detect(black_box(prev_view), &[], &mut features));
    let mut track = Stage::new("track + back-check", || tracker.track(&p0, &p1, black_box(&points), None, &mut out));
    track.run(ROUNDS, || tracker.track(&p0, &p1, black_box(&points), None, &mut out));
    black_box((&features, &out));
}
