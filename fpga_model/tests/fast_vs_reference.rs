//! `fast` must equal `reference` bit for bit: on random small pairs with random valid
//! configurations, and on the Middlebury scenes with the default configuration in both path
//! modes; for the dispatched SIMD kernels and the portable ones, on one and two threads.

#![allow(clippy::unwrap_used, reason = "test helpers: a panic is a failed test with its message")]

use fpga_model::fast::{self, Matcher};
use fpga_model::{DisparityImage, GrayImage, PathMode, SgmConfig, reference};
use proptest::prelude::*;

/// Runs every fast variant on the pair and checks each against `expected`.
fn check_all_variants(left: &GrayImage, right: &GrayImage, config: &SgmConfig, expected: &DisparityImage, what: &str) {
    for threads in [1, 2] {
        for portable in [false, true] {
            let mut matcher = Matcher::new(*config, left.width, left.height, threads).unwrap();
            matcher.set_force_portable(portable);
            let got = matcher.compute(left, right).unwrap();
            assert_same(&got, expected, &format!("{what}, {threads} thread(s), {}", matcher.isa().name()));
        }
    }
}

fn assert_same(got: &DisparityImage, expected: &DisparityImage, what: &str) {
    assert_eq!((got.width, got.height), (expected.width, expected.height), "{what}: size");
    if got.data != expected.data {
        let differing = got.data.iter().zip(&expected.data).filter(|(a, b)| a != b).count();
        let first = got.data.iter().zip(&expected.data).position(|(a, b)| a != b).unwrap();
        panic!(
            "{what}: {differing} of {} pixels differ; first at (x {}, y {}): fast {} reference {}",
            got.data.len(),
            first % got.width,
            first / got.width,
            got.data[first],
            expected.data[first]
        );
    }
}

/// A pair with structure: smooth-ish random texture, the right view shifted by a per-row
/// disparity, plus noise, so winners, ties, LR failures and subpixel offsets all occur.
fn textured_pair(width: usize, height: usize, seed: u64, shift: usize, noise: u8) -> (GrayImage, GrayImage) {
    let mut state = seed | 1;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let texture_width = width + shift + 2;
    let base: Vec<u8> = (0..texture_width * height).map(|_| (next() % 256) as u8).collect();
    let mut left = vec![0u8; width * height];
    let mut right = vec![0u8; width * height];
    for y in 0..height {
        for x in 0..width {
            let sample = |tx: usize| base[y * texture_width + tx];
            // left(x) = right(x − shift): disparity `shift`.
            left[y * width + x] = sample(x);
            let jitter = if noise == 0 { 0 } else { (next() % u64::from(noise)) as u8 };
            right[y * width + x] = sample(x + shift).wrapping_add(jitter);
        }
    }
    (GrayImage::new(width, height, left).unwrap(), GrayImage::new(width, height, right).unwrap())
}

fn config_strategy() -> impl Strategy<Value = SgmConfig> {
    let window = prop_oneof![
        Just((9u8, 7u8)),
        Just((1, 1)),
        Just((3, 3)),
        Just((5, 5)),
        Just((1, 9)),
        Just((13, 1)),
        Just((7, 9)),
        Just((65, 1)),
        Just((1, 65)),
        Just((3, 21)),
        Just((5, 13)),
    ];
    let penalties = (1u8..=255).prop_flat_map(|p1| (Just(p1), p1..=255u8));
    // Weight 0 (census only) often; truncations up to the largest allowed, 191.
    let gradient_term = (prop_oneof![Just(0u8), 1u8..=15], prop_oneof![Just(32u8), 0u8..=191]);
    (
        (window, gradient_term),
        (1u16..=16).prop_map(|k| 16 * k),
        prop_oneof![Just(PathMode::Four), Just(PathMode::Eight)],
        penalties,
        prop_oneof![Just(0u8), any::<u8>()],
        6u8..=12,
        0u8..=100,
        (any::<bool>(), prop_oneof![0u8..=3, any::<u8>()], any::<bool>()),
        any::<bool>(),
        any::<bool>(),
    )
        .prop_map(
            |(
                ((census_width, census_height), (gradient_cost_weight, gradient_cost_truncation)),
                disparities,
                paths,
                (p1, p2),
                p2_gradient_scale,
                path_cost_bits,
                uniqueness_percent,
                (lr_check, lr_max_diff, lr_lenient),
                subpixel,
                median,
            )| SgmConfig {
                census_width,
                census_height,
                gradient_cost_weight,
                gradient_cost_truncation,
                disparities,
                paths,
                p1,
                p2,
                p2_gradient_scale,
                path_cost_bits,
                uniqueness_percent,
                lr_check,
                lr_max_diff,
                lr_lenient,
                subpixel,
                median,
            },
        )
}

fn size_strategy() -> impl Strategy<Value = (usize, usize)> {
    prop_oneof![
        Just((1usize, 1usize)),
        Just((3, 40)),
        Just((40, 3)),
        Just((2, 2)),
        Just((1, 17)),
        Just((70, 1)),
        (1usize..=80, 1usize..=24),
        (60usize..=140, 2usize..=8),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1000, ..ProptestConfig::default() })]

    #[test]
    fn random_pairs_match_reference(
        (width, height) in size_strategy(),
        config in config_strategy(),
        seed in any::<u64>(),
        shift in 0usize..40,
        noise in prop_oneof![Just(0u8), 1u8..=40, Just(255u8)],
    ) {
        config.validate().unwrap();
        let (left, right) = textured_pair(width, height, seed, shift, noise);
        let expected = reference::compute(&left, &right, &config).unwrap();
        check_all_variants(&left, &right, &config, &expected, &format!("{width}x{height} {config:?}"));
    }

    #[test]
    fn flat_and_constant_images_match_reference(
        (width, height) in size_strategy(),
        config in config_strategy(),
        levels in (any::<u8>(), any::<u8>()),
    ) {
        // Ties everywhere: every cost equal, every path cost equal.
        let left = GrayImage::new(width, height, vec![levels.0; width * height]).unwrap();
        let right = GrayImage::new(width, height, vec![levels.1; width * height]).unwrap();
        let expected = reference::compute(&left, &right, &config).unwrap();
        check_all_variants(&left, &right, &config, &expected, &format!("flat {width}x{height} {config:?}"));
    }
}

#[test]
fn default_config_on_wide_random_pairs() {
    // Rows wider than a 64-pixel block and more rows than threads: exercises the wavefront hand-over.
    for (width, height, seed) in [(200, 37, 1u64), (129, 64, 2), (65, 5, 3), (64, 9, 4)] {
        for paths in [PathMode::Four, PathMode::Eight] {
            let config = SgmConfig { paths, ..SgmConfig::default() };
            let (left, right) = textured_pair(width, height, seed, 30, 8);
            let expected = reference::compute(&left, &right, &config).unwrap();
            check_all_variants(&left, &right, &config, &expected, &format!("{width}x{height} {paths:?}"));
            // More threads than the machine has cores: a deeper wavefront (Four), capped (Eight).
            for threads in [3, 4] {
                let got = Matcher::new(config, width, height, threads).unwrap().compute(&left, &right).unwrap();
                assert_same(&got, &expected, &format!("{width}x{height} {paths:?}, {threads} threads"));
            }
        }
    }
}

#[test]
fn matcher_is_reusable_and_allocation_sized() {
    let config = SgmConfig { paths: PathMode::Four, ..SgmConfig::default() };
    let mut matcher = Matcher::new(config, 90, 20, 2).unwrap();
    let mut out = DisparityImage { width: 0, height: 0, data: Vec::new() };
    for seed in 1..4u64 {
        let (left, right) = textured_pair(90, 20, seed, 20, 4);
        matcher.compute_into(&left, &right, &mut out).unwrap();
        assert_same(&out, &reference::compute(&left, &right, &config).unwrap(), "reused matcher");
        assert_same(&fast::compute(&left, &right, &config).unwrap(), &out, "one-shot");
    }
    assert!(matcher.working_memory_bytes() > 0);
    let (left, right) = textured_pair(91, 20, 1, 20, 4);
    assert!(matcher.compute_into(&left, &right, &mut out).is_err(), "wrong size must be refused");
    assert!(Matcher::new(config, 90, 20, 0).is_err());
    assert!(Matcher::new(SgmConfig { disparities: 20, ..config }, 90, 20, 1).is_err());
}

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/stereo/");

fn read_gray(relative: &str) -> GrayImage {
    fpga_model::io::read_gray_png(format!("{DATA}{relative}")).unwrap()
}

/// One scene with the default configuration in both modes: the reference once per mode, the
/// fast variants against it.
fn check_scene(left: &str, right: &str, disparities: u16) {
    let (left_image, right_image) = (read_gray(left), read_gray(right));
    for paths in [PathMode::Four, PathMode::Eight] {
        let config = SgmConfig { disparities, paths, ..SgmConfig::default() };
        let expected = reference::compute(&left_image, &right_image, &config).unwrap();
        let invalid = expected.invalid_fraction();
        assert!(invalid < 0.9, "{left} {paths:?}: reference leaves {invalid:.2} invalid");
        check_all_variants(&left_image, &right_image, &config, &expected, &format!("{left} {paths:?}"));
    }
}

#[test]
fn middlebury_tsukuba() {
    check_scene("middlebury_v2/tsukuba/imL.png", "middlebury_v2/tsukuba/imR.png", 16);
}

#[test]
fn middlebury_teddy() {
    check_scene("middlebury_v2/teddy/imL.png", "middlebury_v2/teddy/imR.png", 64);
}

#[test]
fn middlebury_cones() {
    check_scene("middlebury_v2/cones/imL.png", "middlebury_v2/cones/imR.png", 64);
}

#[test]
fn middlebury_reindeer() {
    check_scene("middlebury_2005_2006_half/Reindeer/view1.png", "middlebury_2005_2006_half/Reindeer/view5.png", 128);
}

#[test]
fn middlebury_adirondack() {
    check_scene(
        "middlebury_2014q_adirondack/Adirondack_left.png",
        "middlebury_2014q_adirondack/Adirondack_right.png",
        128,
    );
}
