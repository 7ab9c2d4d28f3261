//! Rectification cost on the real EuRoC MH_01 raw pairs (752×480): map construction once, then
//! the per-pair remap. Run: `cargo bench -p vision --bench rectify`.

use std::hint::black_box;
use std::time::Instant;

use hal::asl::AslDataset;
use hal::sensor::{SensorSource, StereoFrame};
use vision::Rectifier;

const MH01: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/euroc/mh_01_handheld");
const PAIRS: usize = 8;

/// This thread's on-CPU time in ns (Linux `schedstat`), so that a busy machine does not inflate the
/// figure the way wall-clock time does; `None` elsewhere.
fn cpu_time_ns() -> Option<u64> {
    std::fs::read_to_string("/proc/thread-self/schedstat").ok()?.split_whitespace().next()?.parse().ok()
}
const ROUNDS: usize = 50;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut dataset = AslDataset::open(MH01)?;
    let raw = dataset.stereo_calibration().ok_or("MH_01 has no cameras")?;
    let mut frames = Vec::with_capacity(PAIRS);
    for index in 0..PAIRS {
        let mut frame = StereoFrame::default();
        dataset.load_pair(index * 10, &mut frame)?;
        frames.push(frame);
    }

    let start = Instant::now();
    let rectifier = Rectifier::new(&raw)?;
    let build_ms = start.elapsed().as_secs_f64() * 1e3;

    let mut out = StereoFrame::default();
    // Warm-up: the first call sizes the output buffers.
    rectifier.rectify(&frames[0], &mut out)?;
    let mut per_pair_ms = Vec::with_capacity(ROUNDS);
    let mut cpu_per_pair_ms = Vec::with_capacity(ROUNDS);
    for _ in 0..ROUNDS {
        let (start, cpu_start) = (Instant::now(), cpu_time_ns());
        for frame in &frames {
            rectifier.rectify(black_box(frame), &mut out)?;
            black_box(&out);
        }
        per_pair_ms.push(start.elapsed().as_secs_f64() * 1e3 / PAIRS as f64);
        if let (Some(a), Some(b)) = (cpu_start, cpu_time_ns()) {
            cpu_per_pair_ms.push(b.saturating_sub(a) as f64 * 1e-6 / PAIRS as f64);
        }
    }
    per_pair_ms.sort_by(f64::total_cmp);
    cpu_per_pair_ms.sort_by(f64::total_cmp);
    let (w, h) = (raw.left.width_px, raw.left.height_px);
    println!("rectify {w}x{h} pair (MH_01, one core): maps built in {build_ms:.1} ms");
    println!(
        "rectify {w}x{h} pair: median {:.3} ms, min {:.3} ms, max {:.3} ms over {ROUNDS} rounds of {PAIRS} pairs",
        per_pair_ms[ROUNDS / 2],
        per_pair_ms[0],
        per_pair_ms[ROUNDS - 1]
    );
    if let Some(median) = cpu_per_pair_ms.get(cpu_per_pair_ms.len() / 2) {
        println!("rectify {w}x{h} pair: median on-CPU time {median:.3} ms");
    }
    Ok(())
}
