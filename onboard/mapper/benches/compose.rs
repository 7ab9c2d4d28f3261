//! Global map composition time on the KITTI straight drive's submaps, against the thesis's
//! composition figure (mean 0.26 s, max 3.27 s).
//!
//! The submaps are built as `examples/map_kitti.rs` builds them (SGM depth along the
//! ground-truth poses, 7 m submaps: 8 finished plus the current one), then composed: "first" is
//! a new `GlobalMap` composing everything (every submap resampled), "cached" is the same map
//! composed again with nothing moved (the current submap merged fresh, as on every call). Each
//! is repeated and reported as median with min–max. The result is checked bit for bit against
//! the plain reference composition of `tests/common/reference_compose.rs`, and a digest of it
//! (cloud points and occupancy leaves) is printed to compare runs.
//!
//! Run: `cargo bench -p mapper --bench compose` (`REPS=n` repetitions, default 5). Without
//! `--bench` (as `cargo test --all-targets` runs it) it is a smoke run on the first 8 frames.
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "../examples/common/mod.rs"]
mod common;
#[path = "../tests/common/reference_compose.rs"]
mod reference_compose;

use std::sync::Arc;
use std::time::Instant;

use common::{StereoDepth, SubmapRun};
use hal::kitti::KittiDataset;
use hal::sensor::StereoFrame;
use mapper::global::{Composition, GlobalMap, GlobalMapConfig};
use mapper::integrate::IntegratorConfig;
use mapper::submap::Submap;
use nalgebra::{Isometry3, Translation3};

const KITTI: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/stereo_sequences/kitti_straight");
/// Thesis composition time over its runs (s).
const THESIS_MEAN_S: f64 = 0.26;
const THESIS_MAX_S: f64 = 3.27;

/// The finished submaps at their poses and the current one at its pose.
type Submaps = (Vec<(Arc<Submap>, Isometry3<f64>)>, (Submap, Isometry3<f64>));

fn build_submaps(max_frames: usize) -> Submaps {
    let mut dataset = KittiDataset::open(KITTI).expect("KITTI excerpt");
    let calibration = *dataset.calibration();
    let geometry = common::geometry_of(&calibration);
    let poses = common::read_kitti_poses(&std::fs::read_to_string(format!("{KITTI}/poses.txt")).expect("poses"))
        .expect("poses");
    let t_world_first = Isometry3::from_parts(Translation3::identity(), calibration.left.t_body_cam.rotation);
    let (w, h) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
    let mut stereo = StereoDepth::new(128, w, h, geometry).expect("SGM");
    let mut run = SubmapRun::new(geometry, IntegratorConfig::default(), 7.0);
    let mut frame = StereoFrame::default();
    let frames = dataset.frames().len().min(poses.len()).min(max_frames);
    for (i, pose) in poses.iter().enumerate().take(frames) {
        dataset.load_frame(i, &mut frame).expect("frame");
        let depth = stereo.compute(&frame).expect("depth");
        run.add(frame.stamp_ns, depth, &frame.left, &(t_world_first * pose));
    }
    let finished = run.global.submaps().map(|(s, t)| (Arc::clone(s), *t)).collect();
    (finished, (run.current, run.t_world_current))
}

/// FNV-1a over the cloud points in order and the occupancy leaves sorted by key.
fn digest(c: &Composition) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    let mut eat = |bytes: &[u8]| {
        for b in bytes {
            h = (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3);
        }
    };
    for p in &c.cloud.points {
        for v in p.position_m.coords.iter() {
            eat(&v.to_bits().to_le_bytes());
        }
        eat(&[p.intensity, u8::from(p.obstacle)]);
    }
    let mut leaves: Vec<_> = c.occupancy.iter().collect();
    leaves.sort_unstable_by_key(|(k, _)| *k);
    for (k, l) in leaves {
        for v in k {
            eat(&v.to_le_bytes());
        }
        eat(&l.to_bits().to_le_bytes());
    }
    h
}

/// CPU time of this process so far (user + system, all threads; s), from `/proc/self/stat`
/// (Linux, 100 ticks per second), or NaN where that is not available.
fn process_cpu_s() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else { return f64::NAN };
    // Fields after the command name (which may hold spaces) start at field 3 (state).
    let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else { return f64::NAN };
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let ticks = |i: usize| fields.get(i).and_then(|f| f.parse::<f64>().ok()).unwrap_or(f64::NAN);
    // utime and stime are fields 14 and 15, i.e. 11 and 12 after the state.
    (ticks(11) + ticks(12)) / 100.0
}

/// Median, min, max of `samples` (s).
fn spread(samples: &mut [f64]) -> (f64, f64, f64) {
    samples.sort_by(f64::total_cmp);
    (samples[samples.len() / 2], samples[0], samples[samples.len() - 1])
}

fn main() {
    let full = std::env::args().any(|arg| arg == "--bench");
    let reps: usize = std::env::var("REPS").ok().and_then(|s| s.parse().ok()).unwrap_or(if full { 5 } else { 1 });
    let started = Instant::now();
    let (finished, (current, t_current)) = build_submaps(if full { usize::MAX } else { 8 });
    let source_leaves: usize = finished.iter().map(|(s, _)| s.occupancy.len()).sum::<usize>() + current.occupancy.len();
    let source_points: usize = finished.iter().map(|(s, _)| s.cloud.len()).sum::<usize>() + current.cloud.len();
    let source_bricks: usize =
        finished.iter().map(|(s, _)| s.occupancy.brick_count()).sum::<usize>() + current.occupancy.brick_count();
    println!(
        "compose: KITTI straight, {} finished submaps + current, {source_leaves} source leaves in {source_bricks} \
         bricks of 8³ ({:.0} % full), {source_points} source points (built in {:.1} s)",
        finished.len(),
        100.0 * source_leaves as f64 / (source_bricks * 512) as f64,
        started.elapsed().as_secs_f64()
    );

    let (mut first_s, mut cached_s) = (Vec::new(), Vec::new());
    let (mut first_cpu_s, mut cached_cpu_s) = (Vec::new(), Vec::new());
    let mut digests = Vec::new();
    let mut last = None;
    for _ in 0..reps {
        let mut map = GlobalMap::new(GlobalMapConfig::default());
        for (s, t) in &finished {
            map.insert(Arc::clone(s), *t);
        }
        let (t0, cpu0) = (Instant::now(), process_cpu_s());
        let first = map.compose(Some((&current, &t_current)));
        first_s.push(t0.elapsed().as_secs_f64());
        let (t1, cpu1) = (Instant::now(), process_cpu_s());
        first_cpu_s.push(cpu1 - cpu0);
        let cached = map.compose(Some((&current, &t_current)));
        cached_s.push(t1.elapsed().as_secs_f64());
        cached_cpu_s.push(process_cpu_s() - cpu1);
        assert_eq!(cached.stats.recomposed_submaps, 0);
        digests.push((digest(&first), digest(&cached)));
        last = Some(first);
    }
    let c = last.expect("at least one repetition");
    assert!(digests.iter().all(|d| *d == digests[0]), "compositions differ: {digests:x?}");
    assert_eq!(digests[0].0, digests[0].1, "cached composition differs from the first");
    println!(
        "composed: {} cloud points, {} occupancy leaves ({} bricks, {} occupied), digest {:016x}",
        c.cloud.len(),
        c.occupancy.len(),
        c.occupancy.brick_count(),
        c.occupancy.occupied_count(),
        digests[0].0
    );
    let reference_started = Instant::now();
    let mut in_order: Vec<(&Submap, Isometry3<f64>)> = finished.iter().map(|(s, t)| (s.as_ref(), *t)).collect();
    in_order.push((&current, t_current));
    let (cloud, occupancy) = reference_compose::reference_compose(&in_order, &GlobalMapConfig::default());
    let same_cloud = cloud.points.len() == c.cloud.points.len()
        && cloud.points.iter().zip(&c.cloud.points).all(|(a, b)| {
            a.position_m.coords.map(f32::to_bits) == b.position_m.coords.map(f32::to_bits)
                && (a.intensity, a.obstacle) == (b.intensity, b.obstacle)
        });
    let same_occupancy = occupancy.len() == c.occupancy.len()
        && c.occupancy.iter().all(|(k, l)| occupancy.get(&k).map(|r| r.to_bits()) == Some(l.to_bits()));
    assert!(
        same_cloud && same_occupancy,
        "differs from the reference (cloud {same_cloud}, occupancy {same_occupancy})"
    );
    println!(
        "equal bit for bit to the plain reference composition ({:.1} s for it)",
        reference_started.elapsed().as_secs_f64()
    );
    println!("wall time; CPU: both threads, 10 ms ticks; ratios: median wall time over the thesis's");
    println!(
        "{:>8} {:>5} {:>9} {:>9} {:>9} {:>12} {:>12} {:>11}",
        "compose", "reps", "median s", "min s", "max s", "CPU median s", "/thesis mean", "/thesis max"
    );
    for (name, samples, cpu) in
        [("first", &mut first_s, &mut first_cpu_s), ("cached", &mut cached_s, &mut cached_cpu_s)]
    {
        let (median, min, max) = spread(samples);
        let (cpu_median, _, _) = spread(cpu);
        println!(
            "{name:>8} {reps:>5} {median:>9.3} {min:>9.3} {max:>9.3} {cpu_median:>12.2} {:>12.2} {:>11.2}",
            median / THESIS_MEAN_S,
            median / THESIS_MAX_S
        );
    }
}
