//! Sanity of `reference::compute` on real data (Middlebury tsukuba, D = 16): a synthetic pair
//! made by shifting one real image gives the shift almost everywhere, the result is
//! deterministic, both path modes run and agree with the ground truth, and the invariants of
//! `SPEC.md` hold for every intermediate.

#![allow(clippy::unwrap_used, reason = "test data builders: a panic is a failed test")]

use fpga_model::image::{GrayImage, INVALID};
use fpga_model::io::{read_gray_png, read_png_values};
use fpga_model::reference::{self, compute, compute_with_intermediates};
use fpga_model::{PathMode, SgmConfig, SgmError};

const TSUKUBA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/stereo/middlebury_v2/tsukuba");

fn tsukuba() -> (GrayImage, GrayImage) {
    let left = read_gray_png(format!("{TSUKUBA}/imL.png")).unwrap();
    let right = read_gray_png(format!("{TSUKUBA}/imR.png")).unwrap();
    (left, right)
}

fn config(paths: PathMode) -> SgmConfig {
    SgmConfig { disparities: 16, paths, ..SgmConfig::default() }
}

/// `right(x) = left(x + shift)` (edge replicated): every left pixel at `x ≥ shift` matches the
/// right pixel at `x − shift`, with identical census words.
fn shifted(left: &GrayImage, shift: usize) -> GrayImage {
    let mut pixels = Vec::with_capacity(left.pixels.len());
    for y in 0..left.height {
        for x in 0..left.width {
            pixels.push(left.pixels[y * left.width + (x + shift).min(left.width - 1)]);
        }
    }
    GrayImage::new(left.width, left.height, pixels).unwrap()
}

#[test]
fn shifted_real_image_gives_the_shift_almost_everywhere() {
    let (left, _) = tsukuba();
    for paths in [PathMode::Four, PathMode::Eight] {
        for shift in [3usize, 7, 12] {
            let right = shifted(&left, shift);
            let all = compute_with_intermediates(&left, &right, &config(paths)).unwrap();
            // Pixels that can see every disparity, away from the image border.
            let (mut inside, mut integer_hits, mut exact, mut valid) = (0usize, 0usize, 0usize, 0usize);
            for y in 4..left.height - 4 {
                for x in 16..left.width - 4 {
                    let i = y * left.width + x;
                    inside += 1;
                    integer_hits += usize::from(usize::from(all.winners[i].disparity) == shift);
                    let v = all.disparity.data[i];
                    valid += usize::from(v != INVALID);
                    exact += usize::from(v != INVALID && v.abs_diff(16 * shift as u16) <= 2);
                }
            }
            let share = |n: usize| n as f64 / inside as f64;
            eprintln!(
                "{paths:?} shift {shift}: winner = shift {:.4}, valid {:.4}, within 1/8 px {:.4}",
                share(integer_hits),
                share(valid),
                share(exact)
            );
            // Census costs are exactly 0 at the true shift, so the integer winner is the shift
            // except where the texture is too flat to tell.
            assert!(share(integer_hits) > 0.98, "{paths:?} shift {shift}");
            assert!(share(exact) > 0.95, "{paths:?} shift {shift}");
        }
    }
}

#[test]
fn result_is_deterministic_and_compute_equals_the_intermediates() {
    let (left, right) = tsukuba();
    let config = config(PathMode::Eight);
    let first = compute(&left, &right, &config).unwrap();
    let second = compute(&left, &right, &config).unwrap();
    assert_eq!(first, second);
    assert_eq!(first, compute_with_intermediates(&left, &right, &config).unwrap().disparity);
}

/// Share of valid pixels within 1 px of the ground truth, over the non-occluded mask.
fn accuracy(disparity: &fpga_model::DisparityImage) -> (f64, f64) {
    let truth = read_png_values(format!("{TSUKUBA}/groundtruth.png")).unwrap();
    let mask = read_png_values(format!("{TSUKUBA}/nonocc.png")).unwrap();
    let (mut evaluated, mut valid, mut good) = (0usize, 0usize, 0usize);
    for i in 0..disparity.data.len() {
        if mask.values[i] != 255 || truth.values[i] == 0 {
            continue;
        }
        evaluated += 1;
        let v = disparity.data[i];
        if v != INVALID {
            valid += 1;
            // Ground truth in 1/16 px (tsukuba's scale is 16), output in 1/16 px: 1 px = 16.
            good += usize::from(v.abs_diff(truth.values[i]) <= 16);
        }
    }
    (valid as f64 / evaluated as f64, good as f64 / valid.max(1) as f64)
}

#[test]
fn four_and_eight_paths_both_run_and_match_the_ground_truth() {
    let (left, right) = tsukuba();
    let four = compute(&left, &right, &config(PathMode::Four)).unwrap();
    let eight = compute(&left, &right, &config(PathMode::Eight)).unwrap();
    assert_ne!(four, eight, "the reverse paths must change something");
    for (name, out) in [("Four", &four), ("Eight", &eight)] {
        let (density, good) = accuracy(out);
        eprintln!("tsukuba {name}: {:.1}% valid, {:.1}% of them within 1 px", 100.0 * density, 100.0 * good);
        assert!(density > 0.7, "{name}: density {density}");
        assert!(good > 0.9, "{name}: accuracy {good}");
    }
}

#[test]
fn invariants_of_every_stage_on_real_data() {
    let (left, right) = tsukuba();
    for paths in [PathMode::Four, PathMode::Eight] {
        let config = config(paths);
        let all = compute_with_intermediates(&left, &right, &config).unwrap();
        let d = usize::from(config.disparities);
        let l_max = u32::from(config.path_cost_max());
        assert!(all.cost.data.iter().all(|&c| u16::from(c) <= config.cost_max()));
        let paths_count = paths.count() as u32;
        assert!(all.aggregated.data.iter().all(|&s| u32::from(s) <= paths_count * l_max));
        assert!(all.winners.iter().all(|w| usize::from(w.disparity) < d));
        assert!(all.right_disparity.iter().enumerate().all(|(i, &r)| (i % left.width) + usize::from(r) < left.width));
        for (i, &v) in all.disparity.data.iter().enumerate() {
            if v != INVALID {
                assert!(usize::from(v) <= 16 * (d - 1), "pixel {i}: {v}");
                assert!(usize::from(v) <= 16 * (i % left.width), "pixel {i}: match left of the right image");
            }
        }
        // Each stage only invalidates or (the median) replaces values; later stages never
        // produce a value the previous stage could not.
        for (before, after) in all.subpixel.data.iter().zip(&all.lr_checked.data) {
            assert!(*after == *before || *after == INVALID);
        }
    }
}

#[test]
fn switching_stages_off_passes_their_input_through() {
    let (left, right) = tsukuba();
    let config = SgmConfig { subpixel: false, lr_check: false, median: false, ..config(PathMode::Four) };
    let all = compute_with_intermediates(&left, &right, &config).unwrap();
    assert_eq!(all.lr_checked, all.subpixel);
    assert_eq!(all.median, all.lr_checked);
    for (i, w) in all.winners.iter().enumerate() {
        let expected =
            if !w.unique || 16 * usize::from(w.disparity) > 16 * (i % left.width) { INVALID } else { 16 * w.disparity };
        assert_eq!(all.disparity.data[i], expected);
    }
}

#[test]
fn bad_inputs_are_errors() {
    let (left, right) = tsukuba();
    let small = GrayImage::new(10, 10, vec![0; 100]).unwrap();
    assert!(matches!(compute(&left, &small, &config(PathMode::Four)), Err(SgmError::SizeMismatch { .. })));
    let bad = SgmConfig { disparities: 20, ..config(PathMode::Four) };
    assert!(matches!(compute(&left, &right, &bad), Err(SgmError::InvalidConfig(_))));
    let broken = GrayImage { width: 10, height: 10, pixels: vec![0; 99] };
    assert!(matches!(reference::compute(&broken, &broken, &config(PathMode::Four)), Err(SgmError::BadImage { .. })));
}

#[test]
fn path_cost_width_7_changes_few_pixels_and_8_none() {
    // L_r ≤ C + P2eff. Census only: C ≤ 62, so with P2 = 120 L_r ≤ 182: 8 bits never saturate,
    // 7 bits (Lmax = 127) rarely. With the default gradient term C ≤ 62 + 32 = 94 and
    // L_r ≤ 214: 8 bits still never saturate, 7 bits more often. (With the tuned defaults,
    // P2 = 160, both widths saturate; PARITY.md gives the measured accuracy of b = 7, 8 and 12.)
    let (left, right) = tsukuba();
    let run = |bits: u8, gradient_cost_weight: u8| {
        let config =
            SgmConfig { path_cost_bits: bits, p1: 10, p2: 120, gradient_cost_weight, ..config(PathMode::Four) };
        compute(&left, &right, &config).unwrap()
    };
    for (weight, max_changed_share) in [(0, 0.01), (SgmConfig::default().gradient_cost_weight, 0.05)] {
        let (seven, eight, twelve) = (run(7, weight), run(8, weight), run(12, weight));
        assert_eq!(eight, twelve, "gradient_cost_weight {weight}");
        let changed = seven.data.iter().zip(&twelve.data).filter(|(a, b)| a != b).count();
        eprintln!("gradient_cost_weight {weight}: b = 7 changes {changed} of {} pixels", seven.data.len());
        assert!(changed > 0 && (changed as f64) < max_changed_share * seven.data.len() as f64, "{changed}");
    }
}
