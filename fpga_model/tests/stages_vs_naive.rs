//! Each stage of `fpga_model::stages` against a deliberately naive, independent implementation
//! written from `SPEC.md` with a different loop structure, on small random stereo pairs and
//! random valid configurations. The last property chains the naive stages and compares with
//! `reference::compute`, which checks the order in which the reference wires the stages.

#![allow(clippy::unwrap_used, reason = "test data builders: a panic is a failed test")]

use std::collections::HashMap;

use fpga_model::image::{DisparityImage, GrayImage, INVALID};
use fpga_model::reference;
use fpga_model::stages::aggregate::{self, Direction};
use fpga_model::stages::select::{self, Winner};
use fpga_model::stages::{AggregatedVolume, CostVolume, census, cost, lr, median};
use fpga_model::{PathMode, SgmConfig};
use proptest::prelude::*;

// ---------------------------------------------------------------------------------------------
// Test data

/// A tiny xorshift generator: the images derive from one proptest seed, so a failing case
/// shrinks on sizes and parameters, and replays exactly.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
}

/// A left image of random blocks plus noise and a right image that is the left shifted by a
/// per-row-band disparity (so the matching has real structure and occlusions), plus noise.
fn stereo_pair(width: usize, height: usize, seed: u64) -> (GrayImage, GrayImage) {
    let mut rng = Rng(seed | 1);
    let block = 1 + rng.below(4) as usize;
    let blocks_w = (width + 32).div_ceil(block);
    let base: Vec<u8> = (0..blocks_w * height.div_ceil(block)).map(|_| rng.next() as u8).collect();
    let noise = rng.below(12) as u8;
    let mut left = vec![0u8; width * height];
    let mut right = vec![0u8; width * height];
    let band_disparity: Vec<usize> = (0..4).map(|_| rng.below(12) as usize).collect();
    for y in 0..height {
        let shift = band_disparity[(y * 4) / height];
        for x in 0..width {
            let pattern = |x: usize| base[(y / block) * blocks_w + x / block];
            let mut jitter = || if noise == 0 { 0 } else { rng.below(u64::from(noise)) as u8 };
            left[y * width + x] = pattern(x + 16).saturating_add(jitter());
            // right(x) = left(x + shift): a left pixel at x matches the right pixel at x − shift.
            right[y * width + x] = pattern(x + 16 + shift).saturating_add(jitter());
        }
    }
    (GrayImage::new(width, height, left).unwrap(), GrayImage::new(width, height, right).unwrap())
}

prop_compose! {
    fn configs()(
        window in prop::sample::select(vec![(1u8, 1u8), (3, 3), (5, 3), (5, 5), (7, 5), (9, 7), (13, 5)]),
        gradient_cost_weight in prop::sample::select(vec![0u8, 0, 1, 2, 4, 15]),
        gradient_cost_truncation in prop::sample::select(vec![0u8, 1, 16, 32, 191]),
        disparities in prop::sample::select(vec![16u16, 32]),
        eight in any::<bool>(),
        p1 in 1u8..=40,
        p2_extra in 0u8..=255,
        gradient_scale in prop::sample::select(vec![0u8, 0, 1, 4, 16, 64, 255]),
        path_cost_bits in 6u8..=12,
        uniqueness_percent in 0u8..=100,
        lr_check in any::<bool>(),
        lr_max_diff in 0u8..=3,
        lr_lenient in any::<bool>(),
        subpixel in any::<bool>(),
        median in any::<bool>(),
    ) -> SgmConfig {
        SgmConfig {
            census_width: window.0,
            census_height: window.1,
            gradient_cost_weight,
            gradient_cost_truncation,
            disparities,
            paths: if eight { PathMode::Eight } else { PathMode::Four },
            p1,
            p2: p1.saturating_add(p2_extra),
            p2_gradient_scale: gradient_scale,
            path_cost_bits,
            uniqueness_percent,
            lr_check,
            lr_max_diff,
            lr_lenient,
            subpixel,
            median,
        }
    }
}

fn sizes() -> impl Strategy<Value = (usize, usize, u64)> {
    (5usize..40, 5usize..30, any::<u64>())
}

// ---------------------------------------------------------------------------------------------
// Naive stages

/// Census by an explicit list of neighbour offsets; bit `n − 1 − i` is the i-th neighbour.
fn naive_census(image: &GrayImage, window_w: usize, window_h: usize) -> Vec<u64> {
    let offsets: Vec<(isize, isize)> = (0..window_w * window_h)
        .map(|i| ((i % window_w) as isize - (window_w / 2) as isize, (i / window_w) as isize - (window_h / 2) as isize))
        .filter(|&o| o != (0, 0))
        .collect();
    let at = |x: isize, y: isize| {
        let x = x.max(0).min(image.width as isize - 1) as usize;
        let y = y.max(0).min(image.height as isize - 1) as usize;
        image.pixels[y * image.width + x]
    };
    let n = offsets.len();
    let mut out = vec![0u64; image.width * image.height];
    for (i, word) in out.iter_mut().enumerate() {
        let (x, y) = ((i % image.width) as isize, (i / image.width) as isize);
        for (k, &(dx, dy)) in offsets.iter().enumerate() {
            if at(x + dx, y + dy) < at(x, y) {
                *word += 1u64 << (n - 1 - k);
            }
        }
    }
    out
}

/// Horizontal gradient at `(x, y)` with an explicit border case instead of clamping.
fn naive_gradient(image: &GrayImage, x: usize, y: usize) -> i64 {
    let at = |x: usize| i64::from(image.pixels[y * image.width + x]);
    let last = image.width - 1;
    let next = if x == last { at(last) } else { at(x + 1) };
    let previous = if x == 0 { at(0) } else { at(x - 1) };
    next - previous
}

/// Hamming distance bit by bit plus the gradient term in wide signed arithmetic; the cost of
/// `x − d < 0` as the largest cost any pair of gradients (−255 ..= 255) can give.
fn naive_cost(cl: &[u64], cr: &[u64], left: &GrayImage, right: &GrayImage, config: &SgmConfig) -> Vec<u8> {
    let (width, height, disparities) = (left.width, left.height, usize::from(config.disparities));
    let (weight, truncation) = (i64::from(config.gradient_cost_weight), i64::from(config.gradient_cost_truncation));
    let term = |a: i64, b: i64| ((a - b).abs() * weight).min(truncation);
    let worst = i64::from(config.census_bits()) + (-255..=255).map(|g| term(g, -255)).max().unwrap();
    let mut out = Vec::new();
    for y in 0..height {
        for x in 0..width {
            for d in 0..disparities {
                if d > x {
                    out.push(u8::try_from(worst).unwrap());
                    continue;
                }
                let (a, b) = (cl[y * width + x], cr[y * width + x - d]);
                let hamming = (0..64).filter(|k| (a >> k) & 1 != (b >> k) & 1).count() as i64;
                let gradients = term(naive_gradient(left, x, y), naive_gradient(right, x - d, y));
                out.push(u8::try_from(hamming + gradients).unwrap());
            }
        }
    }
    out
}

/// `L_r` by recursion along the path with a memo, straight from the formula.
struct NaivePath<'a> {
    cost: &'a [u8],
    left: &'a GrayImage,
    config: &'a SgmConfig,
    disparities: usize,
    r: (isize, isize),
    memo: HashMap<(isize, isize), Vec<i64>>,
}

impl NaivePath<'_> {
    fn l(&mut self, x: isize, y: isize) -> Vec<i64> {
        if let Some(v) = self.memo.get(&(x, y)) {
            return v.clone();
        }
        let (w, h) = (self.left.width as isize, self.left.height as isize);
        let l_max = (1i64 << self.config.path_cost_bits) - 1;
        let (cost, disparities) = (self.cost, self.disparities);
        let c = |d: usize| i64::from(cost[((y * w + x) as usize) * disparities + d]);
        let (px, py) = (x - self.r.0, y - self.r.1);
        let result: Vec<i64> = if px < 0 || py < 0 || px >= w || py >= h {
            (0..self.disparities).map(|d| c(d).min(l_max)).collect()
        } else {
            let prev = self.l(px, py);
            let m = *prev.iter().min().unwrap();
            let g =
                i64::from(self.left.pixels[(y * w + x) as usize]) - i64::from(self.left.pixels[(py * w + px) as usize]);
            let (p1, p2, s) =
                (i64::from(self.config.p1), i64::from(self.config.p2), i64::from(self.config.p2_gradient_scale));
            let p2_eff = if s == 0 { p2 } else { p1.max((p2 * s) / (s + g.abs())) };
            (0..self.disparities)
                .map(|d| {
                    let mut candidates = vec![prev[d], m + p2_eff];
                    if d >= 1 {
                        candidates.push(prev[d - 1] + p1);
                    }
                    if d + 1 < self.disparities {
                        candidates.push(prev[d + 1] + p1);
                    }
                    let best = *candidates.iter().min().unwrap();
                    (c(d) + best - m).min(l_max)
                })
                .collect()
        };
        self.memo.insert((x, y), result.clone());
        result
    }
}

fn naive_path(cost: &[u8], left: &GrayImage, config: &SgmConfig, r: (isize, isize)) -> Vec<u16> {
    let disparities = usize::from(config.disparities);
    let mut path = NaivePath { cost, left, config, disparities, r, memo: HashMap::new() };
    let mut out = Vec::new();
    for y in 0..left.height as isize {
        for x in 0..left.width as isize {
            out.extend(path.l(x, y).into_iter().map(|v| v as u16));
        }
    }
    out
}

fn naive_directions(mode: PathMode) -> Vec<(isize, isize)> {
    let four = vec![(1, 0), (1, 1), (0, 1), (-1, 1)];
    match mode {
        PathMode::Four => four,
        PathMode::Eight => four.iter().copied().chain(four.iter().map(|&(dx, dy)| (-dx, -dy))).collect(),
    }
}

fn naive_sum(cost: &[u8], left: &GrayImage, config: &SgmConfig) -> Vec<u16> {
    let mut total = vec![0u32; cost.len()];
    for r in naive_directions(config.paths) {
        for (t, l) in total.iter_mut().zip(naive_path(cost, left, config, r)) {
            *t += u32::from(l);
        }
    }
    total.into_iter().map(|v| u16::try_from(v).unwrap()).collect()
}

/// WTA by sorting `(S, d)` pairs: the first is the winner (ties by smaller d), the first one at
/// least two away is the runner-up; ambiguity tested as `(S2 − S1) · 100 < U · S1`.
fn naive_winner(costs: &[u16], uniqueness: u8) -> Winner {
    let mut pairs: Vec<(u16, usize)> = costs.iter().copied().zip(0..).collect();
    pairs.sort();
    let (s1, d1) = pairs[0];
    let unique = match pairs.iter().find(|&&(_, d)| d.abs_diff(d1) >= 2) {
        None => true,
        Some(&(s2, _)) => (i64::from(s2) - i64::from(s1)) * 100 >= i64::from(uniqueness) * i64::from(s1),
    };
    Winner { disparity: d1 as u16, cost: s1, unique }
}

/// The subpixel offset as the integer k in −8..=8 nearest to `8 (a − c) / den`, ties away from
/// zero, found by trying every k.
fn naive_offset(a: u16, c0: u16, c: u16) -> i32 {
    let den = i64::from(a) + i64::from(c) - 2 * i64::from(c0);
    if den == 0 {
        return 0;
    }
    let num = 8 * (i64::from(a) - i64::from(c));
    let mut best = 0i64;
    for k in -8i64..=8 {
        let (err, best_err) = ((num - k * den).abs(), (num - best * den).abs());
        if err < best_err || (err == best_err && k.abs() > best.abs()) {
            best = k;
        }
    }
    best as i32
}

fn naive_subpixel(s: &[u16], winners: &[Winner], disparities: usize, enabled: bool) -> Vec<u16> {
    winners
        .iter()
        .enumerate()
        .map(|(i, w)| {
            let d1 = usize::from(w.disparity);
            let costs = &s[i * disparities..(i + 1) * disparities];
            if !w.unique {
                INVALID
            } else if !enabled || d1 == 0 || d1 == disparities - 1 {
                (16 * d1) as u16
            } else {
                (16 * d1 as i32 + naive_offset(costs[d1 - 1], costs[d1], costs[d1 + 1])) as u16
            }
        })
        .collect()
}

/// dR by sorting the right pixel's candidates `(S(xr + d, d), d)`.
fn naive_right(s: &[u16], width: usize, height: usize, disparities: usize) -> Vec<u16> {
    let mut out = Vec::new();
    for y in 0..height {
        for xr in 0..width {
            let mut candidates: Vec<(u16, usize)> = (0..disparities)
                .filter(|d| xr + d < width)
                .map(|d| (s[(y * width + xr + d) * disparities + d], d))
                .collect();
            candidates.sort();
            out.push(candidates[0].1 as u16);
        }
    }
    out
}

/// The check with the candidates in floating point: `d1`, or with `lenient` the integers next to
/// the subpixel disparity `D16 / 16` (the same one twice when it is an integer).
fn naive_lr(image: &[u16], winners: &[Winner], right: &[u16], width: usize, max_diff: u8, lenient: bool) -> Vec<u16> {
    (0..image.len())
        .map(|i| {
            if image[i] == INVALID {
                return INVALID;
            }
            let x = (i % width) as i64;
            let px = f64::from(image[i]) / 16.0;
            let candidates: Vec<i64> =
                if lenient { vec![px.floor() as i64, px.ceil() as i64] } else { vec![i64::from(winners[i].disparity)] };
            let keep = candidates
                .iter()
                .any(|&d| x - d >= 0 && (d - i64::from(right[i - d as usize])).abs() <= i64::from(max_diff));
            if keep { image[i] } else { INVALID }
        })
        .collect()
}

/// The median as the smallest valid window value that at least half (rounded up) of the valid
/// window values do not exceed; INVALID if fewer than five are valid.
fn naive_median(image: &[u16], width: usize, height: usize) -> Vec<u16> {
    let mut out = image.to_vec();
    for y in 1..height.saturating_sub(1) {
        for x in 1..width.saturating_sub(1) {
            let window: Vec<u16> = [(-1, -1), (0, -1), (1, -1), (-1, 0), (0, 0), (1, 0), (-1, 1), (0, 1), (1, 1)]
                .iter()
                .map(|&(dx, dy): &(isize, isize)| {
                    image[(y as isize + dy) as usize * width + (x as isize + dx) as usize]
                })
                .collect();
            let valid: Vec<u16> = window.into_iter().filter(|&v| v != INVALID).collect();
            out[y * width + x] = if valid.len() < 5 {
                INVALID
            } else {
                let half = valid.len().div_ceil(2);
                *valid.iter().filter(|&&v| valid.iter().filter(|&&u| u <= v).count() >= half).min().unwrap()
            };
        }
    }
    out
}

fn naive_mark_invalid(image: &[u16], width: usize) -> Vec<u16> {
    image
        .iter()
        .enumerate()
        .map(|(i, &v)| if v != INVALID && f64::from(v) / 16.0 > (i % width) as f64 { INVALID } else { v })
        .collect()
}

/// The whole core from the naive stages, in `SPEC.md` order.
fn naive_core(left: &GrayImage, right: &GrayImage, config: &SgmConfig) -> Vec<u16> {
    let (w, h, d) = (left.width, left.height, usize::from(config.disparities));
    let (cw, ch) = (usize::from(config.census_width), usize::from(config.census_height));
    let cost = naive_cost(&naive_census(left, cw, ch), &naive_census(right, cw, ch), left, right, config);
    let s = naive_sum(&cost, left, config);
    let winners: Vec<Winner> = s.chunks(d).map(|c| naive_winner(c, config.uniqueness_percent)).collect();
    let mut image = naive_subpixel(&s, &winners, d, config.subpixel);
    if config.lr_check {
        image = naive_lr(&image, &winners, &naive_right(&s, w, h, d), w, config.lr_max_diff, config.lr_lenient);
    }
    if config.median {
        image = naive_median(&image, w, h);
    }
    naive_mark_invalid(&image, w)
}

// ---------------------------------------------------------------------------------------------
// Helpers

fn volume<T>(width: usize, height: usize, disparities: usize, data: Vec<T>) -> fpga_model::stages::Volume<T> {
    fpga_model::stages::Volume { width, height, disparities, data }
}

fn image(width: usize, height: usize, data: Vec<u16>) -> DisparityImage {
    DisparityImage { width, height, data }
}

fn cost_of(left: &GrayImage, right: &GrayImage, config: &SgmConfig) -> CostVolume {
    let (cw, ch) = (usize::from(config.census_width), usize::from(config.census_height));
    let cl = census::transform(left, cw, ch);
    let cr = census::transform(right, cw, ch);
    cost::volume(&cl, &cr, left, right, config)
}

fn sum_of(left: &GrayImage, right: &GrayImage, config: &SgmConfig) -> AggregatedVolume {
    aggregate::sum(&cost_of(left, right, config), left, config)
}

// ---------------------------------------------------------------------------------------------
// Properties

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, ..ProptestConfig::default() })]

    #[test]
    fn census_matches_neighbour_list((w, h, seed) in sizes(), config in configs()) {
        let (left, _) = stereo_pair(w, h, seed);
        let (cw, ch) = (usize::from(config.census_width), usize::from(config.census_height));
        let words = census::transform(&left, cw, ch);
        prop_assert_eq!(&words, &naive_census(&left, cw, ch));
        // Only the w·h − 1 low bits may be set.
        let bits = config.census_bits();
        prop_assert!(words.iter().all(|&c| bits == 64 || c >> bits == 0));
    }

    #[test]
    fn cost_matches_bitwise_hamming_plus_gradient_term((w, h, seed) in sizes(), config in configs()) {
        let (left, right) = stereo_pair(w, h, seed);
        let (cw, ch) = (usize::from(config.census_width), usize::from(config.census_height));
        let (cl, cr) = (census::transform(&left, cw, ch), census::transform(&right, cw, ch));
        let d = usize::from(config.disparities);
        let volume = cost::volume(&cl, &cr, &left, &right, &config);
        prop_assert_eq!((volume.width, volume.height, volume.disparities), (w, h, d));
        prop_assert!(volume.data.iter().all(|&c| u16::from(c) <= config.cost_max()));
        prop_assert_eq!(volume.data, naive_cost(&cl, &cr, &left, &right, &config));
    }

    #[test]
    fn gradient_term_matches_wide_arithmetic(a in -255i16..=255, b in -255i16..=255, w in 0u8..=15, t in 0u8..=191) {
        let wide = (i64::from(a) - i64::from(b)).abs() * i64::from(w);
        prop_assert_eq!(i64::from(cost::gradient_term(a, b, w, t)), wide.min(i64::from(t)));
    }

    #[test]
    fn each_path_matches_recursion_with_memo((w, h, seed) in sizes(), config in configs()) {
        let (left, right) = stereo_pair(w, h, seed);
        let cost = cost_of(&left, &right, &config);
        for direction in aggregate::directions(PathMode::Eight) {
            let path = aggregate::path(&cost, &left, direction, &config);
            let naive = naive_path(&cost.data, &left, &config, (direction.dx, direction.dy));
            prop_assert_eq!(&path.data, &naive, "direction {:?}", direction);
            prop_assert!(path.data.iter().all(|&l| l <= config.path_cost_max()));
        }
    }

    #[test]
    fn sum_matches_naive_sum_for_the_mode((w, h, seed) in sizes(), config in configs()) {
        let (left, right) = stereo_pair(w, h, seed);
        let cost = cost_of(&left, &right, &config);
        prop_assert_eq!(aggregate::sum(&cost, &left, &config).data, naive_sum(&cost.data, &left, &config));
    }

    #[test]
    fn winner_matches_sorting((w, h, seed) in sizes(), config in configs()) {
        let (left, right) = stereo_pair(w, h, seed);
        let s = sum_of(&left, &right, &config);
        let d = s.disparities;
        let naive: Vec<Winner> = s.data.chunks(d).map(|c| naive_winner(c, config.uniqueness_percent)).collect();
        prop_assert_eq!(select::winner(&s, config.uniqueness_percent), naive);
    }

    #[test]
    fn winner_of_handles_ties_and_flat_costs(costs in prop::collection::vec(0u16..6, 16..=32), u in 0u8..=100) {
        // Few distinct values: many ties for the winner and the runner-up.
        prop_assert_eq!(select::winner_of(&costs, u), naive_winner(&costs, u));
    }

    #[test]
    fn subpixel_offset_matches_nearest_integer_search(c0 in 0u16..5000, da in 0u16..3000, dc in 0u16..3000) {
        prop_assert_eq!(select::subpixel_offset(c0 + da, c0, c0 + dc), naive_offset(c0 + da, c0, c0 + dc));
    }

    #[test]
    fn subpixel_matches_naive((w, h, seed) in sizes(), config in configs()) {
        let (left, right) = stereo_pair(w, h, seed);
        let s = sum_of(&left, &right, &config);
        let winners = select::winner(&s, config.uniqueness_percent);
        let refined = select::subpixel(&s, &winners, config.subpixel);
        prop_assert_eq!(refined.data, naive_subpixel(&s.data, &winners, s.disparities, config.subpixel));
    }

    #[test]
    fn right_disparity_and_check_match_naive((w, h, seed) in sizes(), config in configs()) {
        let (left, right) = stereo_pair(w, h, seed);
        let s = sum_of(&left, &right, &config);
        let winners = select::winner(&s, config.uniqueness_percent);
        let refined = select::subpixel(&s, &winners, config.subpixel);
        let dr = lr::right_disparity(&s);
        prop_assert_eq!(&dr, &naive_right(&s.data, w, h, s.disparities));
        let checked = lr::check(&refined, &winners, &dr, config.lr_max_diff, config.lr_lenient);
        let naive = naive_lr(&refined.data, &winners, &dr, w, config.lr_max_diff, config.lr_lenient);
        prop_assert_eq!(checked.data, naive);
    }

    #[test]
    fn median_matches_counting_median(
        (w, h) in (1usize..20, 1usize..20),
        seed in any::<u64>(),
        invalid_share in 0u64..10,
    ) {
        let mut rng = Rng(seed | 1);
        let data: Vec<u16> = (0..w * h)
            .map(|_| if rng.below(10) < invalid_share { INVALID } else { rng.below(16 * 31) as u16 })
            .collect();
        let filtered = median::median3x3(&image(w, h, data.clone()));
        prop_assert_eq!(filtered.data, naive_median(&data, w, h));
    }

    #[test]
    fn mark_invalid_matches_float_comparison((w, h) in (1usize..40, 1usize..10), seed in any::<u64>()) {
        let mut rng = Rng(seed | 1);
        let data: Vec<u16> =
            (0..w * h).map(|_| if rng.below(8) == 0 { INVALID } else { rng.below(16 * 48) as u16 }).collect();
        prop_assert_eq!(select::mark_invalid(&image(w, h, data.clone())).data, naive_mark_invalid(&data, w));
    }

    #[test]
    fn reference_equals_the_naive_stages_chained((w, h, seed) in sizes(), config in configs()) {
        let (left, right) = stereo_pair(w, h, seed);
        let out = reference::compute(&left, &right, &config).unwrap();
        prop_assert_eq!((out.width, out.height), (w, h));
        prop_assert_eq!(out.data, naive_core(&left, &right, &config));
    }
}

// ---------------------------------------------------------------------------------------------
// Hand-checked corner cases

#[test]
fn census_of_a_3x3_window_by_hand() {
    // Centre 5; neighbours in raster order 1 9 2 / 8 _ 3 / 7 4 6: darker ones are 1 2 3 4.
    let img = GrayImage::new(3, 3, vec![1, 9, 2, 8, 5, 3, 7, 4, 6]).unwrap();
    let words = census::transform(&img, 3, 3);
    assert_eq!(words[4], 0b1010_1010, "got {:08b}", words[4]);
}

#[test]
fn out_of_image_cost_is_the_worst_cost() {
    let img = GrayImage::new(4, 1, vec![0, 50, 100, 160]).unwrap();
    let c = census::transform(&img, 5, 3);
    let census_only = SgmConfig {
        census_width: 5,
        census_height: 3,
        disparities: 16,
        gradient_cost_weight: 0,
        ..SgmConfig::default()
    };
    let cost = cost::volume(&c, &c, &img, &img, &census_only);
    assert_eq!(cost.pixel(2, 0)[0], 0, "same image, d = 0: identical census");
    assert_eq!(cost.pixel(2, 0)[3], 14, "x − d < 0: worst cost, the census width");
    // With the gradient term: 14 + min(510 · 2, 40) = 54. Gradients (borders clamped): 50, 100,
    // 110, 60; a real match of x = 2 costs its Hamming distance plus min(2 · |110 − G(x − d)|, 40).
    let combined = SgmConfig { gradient_cost_weight: 2, gradient_cost_truncation: 40, ..census_only };
    assert_eq!(combined.cost_max(), 54);
    assert_eq!(cost::horizontal_gradient(&img), vec![50, 100, 110, 60]);
    let cost = cost::volume(&c, &c, &img, &img, &combined);
    assert_eq!(cost.pixel(2, 0)[0], 0);
    assert_eq!(cost.pixel(2, 0)[1], (c[2] ^ c[1]).count_ones() as u8 + 20, "2 · 10");
    assert_eq!(cost.pixel(2, 0)[2], (c[2] ^ c[0]).count_ones() as u8 + 40, "2 · 60, truncated");
    assert_eq!(cost.pixel(2, 0)[3], 54);
}

#[test]
fn gradient_term_by_hand() {
    assert_eq!(cost::gradient_term(30, 20, 4, 32), 32, "4 · 10 = 40, truncated to 32");
    assert_eq!(cost::gradient_term(20, 25, 4, 32), 20, "symmetric, 4 · 5");
    assert_eq!(cost::gradient_term(-255, 255, 15, 191), 191, "largest difference, no overflow");
    assert_eq!(cost::gradient_term(-255, 255, 0, 191), 0, "weight 0: census only");
    assert_eq!(cost::gradient_term(-255, 255, 3, 0), 0, "truncation 0: census only");
}

#[test]
fn gradient_ignores_a_brightness_offset() {
    let img = GrayImage::new(5, 2, vec![10, 40, 20, 90, 60, 0, 0, 7, 7, 200]).unwrap();
    let brighter = GrayImage::new(5, 2, img.pixels.iter().map(|&p| p + 30).collect()).unwrap();
    assert_eq!(cost::horizontal_gradient(&img), vec![30, 10, 50, 40, -30, 0, 7, 7, 193, 193]);
    assert_eq!(cost::horizontal_gradient(&brighter), cost::horizontal_gradient(&img));
}

#[test]
fn median_by_hand() {
    const I: u16 = INVALID;
    assert_eq!(median::median_of_window([9, 1, 8, 2, 7, 3, 6, 4, 5]), 5, "nine valid: the 5th");
    assert_eq!(median::median_of_window([I, 1, 8, 2, I, 3, 6, 4, 5]), 4, "seven valid: the 4th");
    assert_eq!(median::median_of_window([I, 1, 8, 2, I, 3, 6, I, 5]), 3, "six valid: the 3rd (lower median)");
    assert_eq!(median::median_of_window([I, 1, 8, I, I, 3, 6, I, 5]), 5, "five valid: the 3rd");
    assert_eq!(median::median_of_window([I, 1, I, I, I, 3, 6, I, 5]), I, "four valid: invalid");
    assert_eq!(median::median_of_window([1, 1, 1, 1, I, 1, 1, 1, 1]), 1, "an isolated hole is filled");
}

#[test]
fn first_pixel_of_a_path_is_the_saturated_cost() {
    let config = SgmConfig { disparities: 16, path_cost_bits: 6, ..SgmConfig::default() };
    let left = GrayImage::new(2, 1, vec![10, 20]).unwrap();
    let cost = volume(2, 1, 16, (0..32).map(|i| if i < 16 { 62 } else { 0 }).collect());
    let l = aggregate::path(&cost, &left, Direction { dx: 1, dy: 0 }, &config);
    assert!(l.pixel(0, 0).iter().all(|&v| v == 62), "min(C, 63) at the path start");
    // Second pixel: C = 0, best − M = 0 at every d (flat predecessor): L = 0.
    assert!(l.pixel(1, 0).iter().all(|&v| v == 0));
}

#[test]
fn effective_p2_by_hand() {
    assert_eq!(aggregate::effective_p2(10, 120, 0, 200), 120, "adaptation off");
    assert_eq!(aggregate::effective_p2(10, 120, 16, 0), 120, "no step: full P2");
    assert_eq!(aggregate::effective_p2(10, 120, 16, 16), 60, "120·16/32");
    assert_eq!(aggregate::effective_p2(10, 120, 16, 255), 10, "floor(1920/271) = 7 < P1: P1");
}

#[test]
fn subpixel_by_hand() {
    // Parabola: 16 · (a − c) / (2 · (a + c − 2·c0)) = 8 · (a − c) / den.
    assert_eq!(select::subpixel_offset(20, 10, 20), 0, "symmetric");
    assert_eq!(select::subpixel_offset(20, 10, 10), 8, "flat right side: halfway to d1 + 1");
    assert_eq!(select::subpixel_offset(30, 10, 20), 3, "8·10/30 = 2.67 → 3");
    assert_eq!(select::subpixel_offset(13, 10, 11), 4, "8·2/4 = 4");
    assert_eq!(select::subpixel_offset(11, 10, 13), -4);
    assert_eq!(select::subpixel_offset(14, 10, 13), 1, "8/7 = 1.14 → 1");
    assert_eq!(select::subpixel_offset(29, 10, 23), 2, "8·6/32 = 1.5 → 2 (half away from zero)");
    assert_eq!(select::subpixel_offset(23, 10, 29), -2);
    assert_eq!(select::subpixel_offset(10, 10, 10), 0, "den = 0");
}
