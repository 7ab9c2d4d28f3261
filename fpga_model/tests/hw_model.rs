//! The hardware model: block RAM packing and cycle arithmetic checked by hand on small
//! configurations; the LX75 configuration of the README fits and reaches the thesis's 14.6 Hz;
//! b = 8 and an on-chip Eight-path design do not fit.

#![allow(clippy::unwrap_used, reason = "test data builders: a panic is a failed test")]

use fpga_model::hw::{
    BRAM_ASPECTS, DEVICES, HwConfig, ROVER_FRAME_RATE_HZ, SPARTAN6_LX45, SPARTAN6_LX75, SPARTAN6_LX100, SPARTAN6_LX150,
    Storage, budget, pack,
};
use fpga_model::{PathMode, SgmConfig};

/// A configuration small enough to count by hand.
fn small() -> HwConfig {
    HwConfig {
        clock_hz: 1180.0,
        disparity_units: 4,
        pipeline_depth_cycles: 10,
        horizontal_blanking_cycles: 2,
        vertical_blanking_lines: 1,
        width: 32,
        height: 8,
        disparities: 16,
        census_width: 3,
        census_height: 3,
        gradient_cost_max: 0,
        path_cost_bits: 6,
        paths: PathMode::Four,
        subpixel: true,
        lr_check: true,
        median: true,
        eight_path_buffers_external: true,
    }
}

fn blocks_of(budget: &fpga_model::hw::Budget, name_part: &str) -> Vec<u64> {
    budget.buffers.iter().filter(|b| b.name.contains(name_part)).map(|b| b.bram_blocks()).collect()
}

#[test]
fn packing_by_hand() {
    let case = |depth, width| {
        let p = pack(depth, width);
        (p.aspect.depth_words, p.aspect.width_bits, p.blocks_deep, p.blocks_wide, p.blocks())
    };
    // Six census rows of 8 bits, 1024 columns: 1K×18 three wide (2K×9 would need six).
    assert_eq!(case(1024, 48), (1024, 18, 1, 3, 3));
    // A row of path costs, 16 disparities of 7 bits per clock: 2K×9, 4 deep × 13 wide = 52
    // (1K×18 needs 8 × 7 = 56, 4K×4 needs 2 × 28 = 56).
    assert_eq!(case(8192, 112), (2048, 9, 4, 13, 52));
    // The same with 8 bits: 4 × 15 = 60 (every other aspect needs 64).
    assert_eq!(case(8192, 128), (2048, 9, 4, 15, 60));
    // 8 disparities of 7 bits: no aspect beats the bit count, 56 blocks.
    assert_eq!(case(16384, 56).4, 56);
    assert_eq!(case(16384, 1), (16384, 1, 1, 1, 1));
    assert_eq!(case(16385, 1), (16384, 1, 2, 1, 2));
    assert_eq!(case(512, 36), (512, 36, 1, 1, 1));
    // A tie (512×36: 2 × 1, 1K×18: 1 × 2) goes to the deeper aspect.
    assert_eq!(case(513, 36), (1024, 18, 1, 2, 2));
    assert_eq!(case(100, 37), (512, 36, 1, 2, 2));
    assert_eq!(case(1, 1).4, 1);
    assert_eq!(case(1000, 0).4, 0);
    // Every aspect holds 18 Kb or 16 Kb.
    for a in BRAM_ASPECTS {
        assert!(matches!(a.depth_words * u64::from(a.width_bits), 16384 | 18432));
    }
}

#[test]
fn cycles_of_a_small_configuration_by_hand() {
    let b = budget(&small()).unwrap();
    assert_eq!(b.cycles_per_pixel, 4, "16 disparities, 4 per clock");
    assert_eq!(b.cycles_per_line, 32 * 4 + 2);
    assert_eq!(b.cycles_per_frame, (8 + 1) * 130 + 10);
    assert_eq!(b.cycles_per_frame, 1180);
    assert!((b.frames_per_second - 1.0).abs() < 1e-12, "1180 Hz clock, 1180 cycles");
    assert!((b.min_clock_hz_for(2.0) - 2360.0).abs() < 1e-9);

    let eight = budget(&HwConfig { paths: PathMode::Eight, ..small() }).unwrap();
    assert_eq!(eight.passes, 2);
    assert_eq!(eight.cycles_per_frame, 2 * 9 * 130 + 10);

    // 5 disparities per clock: ceil(16 / 5) = 4 clocks, the last one only partly busy.
    let uneven = budget(&HwConfig { disparity_units: 5, ..small() }).unwrap();
    assert_eq!(uneven.cycles_per_pixel, 4);
}

#[test]
fn memory_of_a_small_configuration_by_hand() {
    let b = budget(&small()).unwrap();
    // Census 3×3: 2 rows × 8 bits, 32 deep → one block (1K×18) per image.
    assert_eq!(blocks_of(&b, "census line buffers"), vec![1, 1]);
    // Path rows: 32 px × 4 clocks deep, 4 × 6 bits wide = 128 × 24 → one 512×36 block each.
    assert_eq!(blocks_of(&b, "previous row's costs"), vec![1, 1, 1]);
    let row = b.buffers.iter().find(|b| b.name.contains("(0,1): previous row's costs")).unwrap();
    assert_eq!((row.depth_words, row.width_bits, row.bits()), (128, 24, 32 * 16 * 6));
    assert_eq!(blocks_of(&b, "previous row's minima"), vec![1, 1, 1]);
    // Median: 2 rows of (8 bits for 0..=248 + 1 invalid flag) = 18 bits → one block.
    let median = b.buffers.iter().find(|b| b.name.contains("median")).unwrap();
    assert_eq!((median.depth_words, median.width_bits, median.bram_blocks()), (32, 18, 1));
    assert_eq!(b.bram_blocks(), 9);
    // Fabric: right census window 16 × 8 bits, path (1,0) 16 × 6, P2 table 256 × 8,
    // LR minima 16 × (8 + 4), finished dR 16 × 4, delay line 16 × (9 + 4).
    assert_eq!(b.fabric_bits(), 16 * 8 + 16 * 6 + 256 * 8 + 16 * 12 + 16 * 4 + 16 * 13);
    // DSPs: two uniqueness multipliers, one subpixel divider (4 steps in 4 clocks).
    assert_eq!(b.dsp_count(), 3);
    let one_clock = budget(&HwConfig { disparity_units: 16, ..small() }).unwrap();
    assert_eq!(one_clock.dsp_count(), 2 + 4, "one pixel per clock unrolls the 4 division steps");
    let bare = budget(&HwConfig { subpixel: false, lr_check: false, median: false, ..small() }).unwrap();
    assert_eq!(bare.bram_blocks(), 8);
    assert_eq!(bare.dsp_count(), 2);
    assert_eq!(b.external_bytes_per_frame(), 0);
    assert_eq!(b.cost_bits, 4, "census 3×3: 0 ..= 8");
}

#[test]
fn gradient_term_widens_the_cost_and_adds_fabric_only() {
    let census_only = budget(&small()).unwrap();
    let with_gradient = budget(&HwConfig { gradient_cost_max: 32, ..small() }).unwrap();
    // C ≤ 8 + 32 = 40: 6 bits instead of 4.
    assert_eq!(with_gradient.cost_bits, 6);
    // The right gradients of the last D = 16 pixels, 9 bits each, beside the census window.
    assert_eq!(with_gradient.fabric_bits(), census_only.fabric_bits() + 16 * 9);
    let gradients = with_gradient.buffers.iter().find(|b| b.name.contains("right gradients")).unwrap();
    assert_eq!((gradients.depth_words, gradients.width_bits, gradients.storage), (4, 4 * 9, Storage::Fabric));
    // No block RAM, no DSP, no clock.
    assert_eq!(with_gradient.bram_blocks(), census_only.bram_blocks());
    assert_eq!(with_gradient.dsp_count(), census_only.dsp_count());
    assert_eq!(with_gradient.cycles_per_frame, census_only.cycles_per_frame);
    assert!(budget(&HwConfig { gradient_cost_max: 256, ..small() }).is_err());
}

#[test]
fn eight_paths_external_traffic_by_hand() {
    let b = budget(&HwConfig { paths: PathMode::Eight, ..small() }).unwrap();
    // Forward sums: 32 × 8 px × 16 d × (6 + 2) bits = 4096 B; images 32 × 8 × 2 B = 512 B;
    // each written once and read once.
    assert_eq!(b.external_bytes_per_frame(), 2 * (4096 + 512));
    assert_eq!(b.bram_blocks(), 9, "the DRAM buffers take no block RAM");
    let on_chip = budget(&HwConfig { paths: PathMode::Eight, eight_path_buffers_external: false, ..small() }).unwrap();
    let sums = on_chip.buffers.iter().find(|b| b.name.contains("forward-pass sums")).unwrap();
    assert!(matches!(sums.storage, Storage::BlockRam(_)));
    // 32·8·4 = 1024 words of 4 × 8 = 32 bits: 1K×18 two wide.
    assert_eq!(sums.bram_blocks(), 2);
}

#[test]
fn lx75_configuration_fits_and_reaches_the_rover_frame_rate() {
    let config = HwConfig::lx75_rover();
    assert_eq!((config.width, config.height, config.disparities, config.paths), (1024, 508, 128, PathMode::Four));
    let b = budget(&config).unwrap();
    println!("{}", b.report(&DEVICES));
    assert_eq!(b.cycles_per_frame, (508 + 4) * (1024 * 8 + 64) + 64);
    assert!(b.frames_per_second >= ROVER_FRAME_RATE_HZ, "{} Hz", b.frames_per_second);
    assert_eq!(blocks_of(&b, "previous row's costs"), vec![52, 52, 52]);
    assert_eq!(b.bram_blocks(), 6 + 3 * 52 + 3 + 2);
    assert_eq!(b.dsp_count(), 3);
    // C = Hamming (≤ 62) + gradient term (≤ 32) ≤ 94: 7 bits, within Lmax = 127 of b = 7.
    assert_eq!(b.cost_bits, 7);
    // Right census window 128 × 62, right gradients 128 × 9, path (1,0) 128 × 7, P2 table
    // 256 × 8, LR minima 128 × (9 + 7), finished dR 128 × 7, delay line 128 × (12 + 7).
    assert_eq!(b.fabric_bits(), 128 * 62 + 128 * 9 + 128 * 7 + 256 * 8 + 128 * 16 + 128 * 7 + 128 * 19);
    assert!(b.fits(&SPARTAN6_LX75));
    assert!(!b.fits(&SPARTAN6_LX45));
    assert!(b.fits(&SPARTAN6_LX100) && b.fits(&SPARTAN6_LX150));
    // The same budget from the flight configuration's parameters, with Four paths.
    let from_sgm = HwConfig::from_sgm(&SgmConfig { paths: PathMode::Four, ..SgmConfig::default() }, 1024, 508);
    assert_eq!(from_sgm, config);
}

#[test]
fn path_costs_of_8_bits_do_not_fit_the_lx75_at_any_parallelism() {
    for units in [1, 2, 4, 8, 16, 32, 64, 128] {
        let b = budget(&HwConfig { path_cost_bits: 8, disparity_units: units, ..HwConfig::lx75_rover() }).unwrap();
        assert!(!b.fits(&SPARTAN6_LX75), "{units} per clock: {} blocks", b.bram_blocks());
        // The three row buffers alone hold 3 · 1024 · 128 · 8 bits = 3,072 Kb ≈ the whole device.
        assert!(b.bram_data_bits() >= 3 * 1024 * 128 * 8);
    }
    let seven = budget(&HwConfig::lx75_rover()).unwrap();
    assert!(seven.fits(&SPARTAN6_LX75));
}

#[test]
fn eight_paths_at_full_resolution_do_not_fit_on_chip() {
    let on_chip = HwConfig { paths: PathMode::Eight, eight_path_buffers_external: false, ..HwConfig::lx75_rover() };
    let b = budget(&on_chip).unwrap();
    for device in DEVICES {
        assert!(!b.fits(&device), "{}", device.name);
    }
    // The forward sums alone: 1024 · 508 · 128 · 9 bits ≈ 75 MB, 190× the LX75's block RAM.
    assert!(b.bram_data_bits() > 190 * u64::from(SPARTAN6_LX75.bram_18kb) * 18 * 1024);

    // In DRAM the block RAM fits, but the second pass doubles the cycles and the sums cross
    // the memory interface twice: more than 2 GB/s at 14.6 Hz.
    let external = HwConfig { paths: PathMode::Eight, disparity_units: 32, ..HwConfig::lx75_rover() };
    let b = budget(&external).unwrap();
    println!("{}", b.report(&[SPARTAN6_LX75]));
    assert!(b.fits(&SPARTAN6_LX75));
    assert_eq!(b.external_bytes_per_frame(), 2 * (1024 * 508 * 128 * 9 / 8 + 1024 * 508 * 2));
    assert!(b.external_bytes_per_frame() as f64 * ROVER_FRAME_RATE_HZ > 2.0e9);
    let sixteen = budget(&HwConfig { paths: PathMode::Eight, ..HwConfig::lx75_rover() }).unwrap();
    assert!(sixteen.frames_per_second < ROVER_FRAME_RATE_HZ, "two passes at 16 per clock are too slow");
}

#[test]
fn invalid_parameters_are_errors() {
    let cases = [
        HwConfig { disparity_units: 0, ..small() },
        HwConfig { disparity_units: 17, ..small() },
        HwConfig { census_width: 4, ..small() },
        HwConfig { clock_hz: 0.0, ..small() },
        HwConfig { clock_hz: f64::NAN, ..small() },
        HwConfig { width: 0, ..small() },
        HwConfig { path_cost_bits: 0, ..small() },
        HwConfig { census_width: 11, census_height: 7, ..small() },
    ];
    for config in cases {
        assert!(budget(&config).is_err(), "{config:?}");
    }
}
