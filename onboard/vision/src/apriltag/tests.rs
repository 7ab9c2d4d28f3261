use nalgebra::{Matrix3, Vector3};
use proptest::prelude::*;

use super::*;
use crate::image::ImageView;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/apriltag/");

/// Whether cell `(col, row)` of the 10 × 10 rendering of `code` is white (the data folder's
/// convention; out-of-range cells are white).
fn cell_is_white(code: u64, col: i64, row: i64) -> bool {
    if !(1..=8).contains(&col) || !(1..=8).contains(&row) {
        return true;
    }
    for i in 0..36 {
        if i64::from(BIT_X[i]) + 1 == col && i64::from(BIT_Y[i]) + 1 == row {
            return (code >> (35 - i)) & 1 == 1;
        }
    }
    false
}

use super::tag36h11::{BIT_X, BIT_Y, CODES};

/// An upright tag, `cell` px per cell, the 10 × 10 grid's top-left at `(margin, margin)` px
/// (pixel edges), turned by `quarter_turns` (counter-clockwise on screen), on a white image of
/// `(20 + 2·margin / cell)` cells.
fn render_aligned(code: u64, cell: usize, margin: usize, quarter_turns: u32) -> (Vec<u8>, usize) {
    let size = 10 * cell + 2 * margin;
    let mut image = vec![230u8; size * size];
    for y in 0..size {
        for x in 0..size {
            if x < margin || y < margin || x >= margin + 10 * cell || y >= margin + 10 * cell {
                continue;
            }
            let (c, r) = (((x - margin) / cell) as i64, ((y - margin) / cell) as i64);
            // The cell shown at (c, r) after turning the tag counter-clockwise on screen.
            let (c, r) = match quarter_turns % 4 {
                0 => (c, r),
                1 => (9 - r, c),
                2 => (9 - c, 9 - r),
                _ => (r, 9 - c),
            };
            image[y * size + x] = if cell_is_white(code, c, r) { 230 } else { 25 };
        }
    }
    (image, size)
}

/// Area-sampled (`ss × ss` per pixel) rendering of `code` whose black square's corners are
/// `corners` (bottom-left, bottom-right, top-right, top-left of the tag; pixel centres at
/// integers), on a grey background.
fn render_warped(code: u64, corners: &[[f64; 2]; 4], width: usize, height: usize, ss: usize) -> Vec<u8> {
    let h = Homography::from_square(corners).unwrap();
    let hm = Matrix3::from_row_slice(&h.0);
    let inv = hm.try_inverse().unwrap();
    let mut image = vec![0u8; width * height];
    for y in 0..height {
        for x in 0..width {
            let mut acc = 0.0;
            for sy in 0..ss {
                for sx in 0..ss {
                    let px = x as f64 - 0.5 + (sx as f64 + 0.5) / ss as f64;
                    let py = y as f64 - 0.5 + (sy as f64 + 0.5) / ss as f64;
                    let t = inv * Vector3::new(px, py, 1.0);
                    let (u, v) = (t.x / t.z, t.y / t.z);
                    // Tag coordinates (y up) to cells: column 1 + 4(u + 1), row 1 + 4(1 − v).
                    let col = (4.0 * (u + 1.0)).floor() as i64 + 1;
                    let row = (4.0 * (1.0 - v)).floor() as i64 + 1;
                    let inside_tag = (0..10).contains(&col) && (0..10).contains(&row);
                    acc += if !inside_tag {
                        140.0
                    } else if cell_is_white(code, col, row) {
                        220.0
                    } else {
                        30.0
                    };
                }
            }
            image[y * width + x] = (acc / (ss * ss) as f64).round() as u8;
        }
    }
    image
}

fn detector(max_hamming: u32) -> TagDetector {
    TagDetector::new(TagDetectorConfig { max_hamming, ..TagDetectorConfig::default() }).unwrap()
}

#[test]
fn code_table_equals_the_data_files_byte_for_byte() {
    let codes = std::fs::read_to_string(format!("{DATA}tag36h11/tag36h11_codes.txt")).unwrap();
    let ours: String = CODES.iter().map(|c| format!("0x{c:016x}\n")).collect();
    assert_eq!(ours, codes);

    let layout = std::fs::read_to_string(format!("{DATA}tag36h11/tag36h11_bit_layout.txt")).unwrap();
    let f = TAG36H11;
    let mut ours = String::from(
        "# tag36h11 bit layout (data from AprilRobotics/apriltag tag36h11.c, commit \
         1c21707aa7304121a2529a71f8e512f6542f35d0)\n",
    );
    ours += &format!(
        "# nbits={} h={} ncodes={} width_at_border={} total_width={} reversed_border={}\n",
        f.nbits,
        f.min_hamming,
        f.codes.len(),
        f.width_at_border,
        f.total_width,
        f.reversed_border
    );
    ours += "# columns: bit_index bit_x bit_y   (bit_index 0 = most-significant bit of the 36-bit code, i.e. \
             (code >> 35) & 1)\n";
    for i in 0..36 {
        ours += &format!("{i} {} {}\n", f.bit_x[i], f.bit_y[i]);
    }
    assert_eq!(ours, layout);
}

#[test]
fn upright_tag_corners_start_bottom_left_and_go_counter_clockwise() {
    // Black square from pixel edge 40 to 120 (cells of 10 px, 30 px margin): in our convention
    // its corners are at 39.5 and 119.5.
    let (image, size) = render_aligned(CODES[0], 10, 30, 0);
    let mut d = detector(0);
    let found = d.detect(ImageView::new(size, size, &image).unwrap());
    assert_eq!(found.len(), 1);
    let t = &found[0];
    assert_eq!((t.id, t.hamming), (0, 0));
    let truth = [[39.5, 119.5], [119.5, 119.5], [119.5, 39.5], [39.5, 39.5]];
    for (c, e) in t.corners_px.iter().zip(&truth) {
        assert!((c[0] - e[0]).abs() < 0.1 && (c[1] - e[1]).abs() < 0.1, "{:?} vs {truth:?}", t.corners_px);
    }
    assert!((t.center_px[0] - 79.5).abs() < 0.1 && (t.center_px[1] - 79.5).abs() < 0.1);
    // The homography maps the tag square (y up) onto the corners, and its centre onto the centre.
    for (k, s) in [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0], [0.0, 0.0]].iter().enumerate() {
        let p = t.homography * Vector3::new(s[0], s[1], 1.0);
        let expected = if k < 4 { t.corners_px[k] } else { t.center_px };
        assert!((p.x / p.z - expected[0]).abs() < 1e-9 && (p.y / p.z - expected[1]).abs() < 1e-9);
    }
}

#[test]
fn decodes_all_587_codes_in_all_rotations_with_up_to_max_hamming_flipped_bits() {
    const MAX_HAMMING: u32 = 2;
    let mut d = detector(MAX_HAMMING);
    let mut state = 0x853c_49e6_748f_ea9bu64;
    let mut failures = Vec::new();
    for (id, &code) in CODES.iter().enumerate() {
        for turns in 0..4 {
            for errors in 0..=MAX_HAMMING {
                let mut flipped = 0u64;
                while flipped.count_ones() < errors {
                    state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                    flipped |= 1 << ((state >> 33) % 36);
                }
                let (image, size) = render_aligned(code ^ flipped, 6, 12, turns);
                let found = d.detect(ImageView::new(size, size, &image).unwrap());
                let ok = found.len() == 1 && found[0].id == id as u32 && found[0].hamming == errors;
                if !ok {
                    failures.push((id, turns, errors, found.iter().map(|t| (t.id, t.hamming)).collect::<Vec<_>>()));
                    continue;
                }
                // The tag's bottom-left corner: turning the tag counter-clockwise on screen moves
                // it from the image's bottom-left to its bottom-right, top-right, top-left.
                let (lo, hi) = (17.5, 65.5);
                let expected = [[lo, hi], [hi, hi], [hi, lo], [lo, lo]];
                let c0 = found[0].corners_px[0];
                let e = expected[turns as usize];
                assert!((c0[0] - e[0]).abs() < 0.2 && (c0[1] - e[1]).abs() < 0.2, "id {id} turns {turns}: {c0:?}");
            }
        }
    }
    assert!(failures.is_empty(), "{} failures, first {:?}", failures.len(), &failures[..failures.len().min(10)]);
}

#[test]
fn corners_of_a_tag_under_a_known_homography() {
    // Perspective views with sub-pixel corners, area-sampled; the bound is what the detector
    // achieves on them (worst corner of all views), with margin.
    let views: [[[f64; 2]; 4]; 4] = [
        [[30.3, 150.7], [140.2, 160.1], [150.9, 40.4], [40.6, 30.2]],
        [[60.25, 140.5], [150.75, 120.25], [130.1, 20.6], [35.4, 45.3]],
        [[20.7, 100.2], [110.4, 165.8], [170.3, 80.9], [80.1, 20.5]],
        [[45.5, 130.5], [128.5, 130.5], [128.5, 47.5], [45.5, 47.5]],
    ];
    let mut d = detector(0);
    let mut worst: f64 = 0.0;
    for (v, corners) in views.iter().enumerate() {
        let id = 7 * v + 3;
        let image = render_warped(CODES[id], corners, 200, 190, 8);
        let found = d.detect(ImageView::new(200, 190, &image).unwrap());
        assert_eq!(found.len(), 1, "view {v}");
        assert_eq!(found[0].id, id as u32);
        for (c, e) in found[0].corners_px.iter().zip(corners) {
            worst = worst.max(((c[0] - e[0]).powi(2) + (c[1] - e[1]).powi(2)).sqrt());
        }
    }
    println!("worst corner error over the rendered views: {worst:.3} px");
    assert!(worst < 0.15, "worst corner error {worst} px");
}

#[test]
fn second_detection_on_the_same_image_allocates_nothing() {
    let file = std::fs::File::open(format!("{DATA}duckietown/test_image_multiple_01.png")).unwrap();
    let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    let (w, h) = (info.width as usize, info.height as usize);
    let channels = info.color_type.samples();
    let grey: Vec<u8> = buf[..w * h * channels].chunks_exact(channels).map(|p| p[0]).collect();
    for decimate in [1, 2] {
        let mut d =
            TagDetector::new(TagDetectorConfig { quad_decimate: decimate, ..TagDetectorConfig::default() }).unwrap();
        let first = d.detect(ImageView::new(w, h, &grey).unwrap()).to_vec();
        assert!(!first.is_empty());
        let capacities = d.capacities();
        let second = d.detect(ImageView::new(w, h, &grey).unwrap()).to_vec();
        assert_eq!(first, second);
        assert_eq!(d.capacities(), capacities, "decimate {decimate}");
    }
}

#[test]
fn configuration_is_checked() {
    let bad = [
        TagDetectorConfig { quad_decimate: 0, ..TagDetectorConfig::default() },
        TagDetectorConfig { max_hamming: 4, ..TagDetectorConfig::default() },
        TagDetectorConfig { decode_sharpening: f64::NAN, ..TagDetectorConfig::default() },
        TagDetectorConfig { critical_angle_rad: 0.0, ..TagDetectorConfig::default() },
        TagDetectorConfig { max_nmaxima: 3, ..TagDetectorConfig::default() },
        TagDetectorConfig { max_line_fit_mse: -1.0, ..TagDetectorConfig::default() },
        TagDetectorConfig { min_decision_margin: f32::INFINITY, ..TagDetectorConfig::default() },
    ];
    for config in bad {
        assert!(TagDetector::new(config).is_err(), "{config:?}");
    }
    assert!(TagDetector::new(TagDetectorConfig::default()).is_ok());
}

#[test]
fn overlap_test_sees_crossing_nested_and_apart_quads() {
    let a = [[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]];
    let inner = [[2.0, 2.0], [4.0, 2.0], [4.0, 4.0], [2.0, 4.0]];
    let crossing = [[5.0, 5.0], [15.0, 5.0], [15.0, 15.0], [5.0, 15.0]];
    let apart = [[20.0, 0.0], [30.0, 0.0], [30.0, 10.0], [20.0, 10.0]];
    assert!(polygons_overlap(&a, &inner) && polygons_overlap(&inner, &a));
    assert!(polygons_overlap(&a, &crossing));
    assert!(!polygons_overlap(&a, &apart));
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    /// The detector is total: any image of any small size, noise or constant, any decimation.
    #[test]
    fn any_image_is_handled(
        width in 1usize..48,
        height in 1usize..48,
        seed in any::<u64>(),
        constant in proptest::option::of(any::<u8>()),
        decimate in 1u32..4,
        deglitch in any::<bool>(),
    ) {
        let mut state = seed | 1;
        let data: Vec<u8> = (0..width * height)
            .map(|_| {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                constant.unwrap_or((state >> 56) as u8)
            })
            .collect();
        let mut d = TagDetector::new(TagDetectorConfig {
            quad_decimate: decimate,
            deglitch,
            max_hamming: 3,
            ..TagDetectorConfig::default()
        })
        .unwrap();
        let found = d.detect(ImageView { width, height, data: &data });
        for t in found {
            prop_assert!((t.id as usize) < CODES.len());
        }
        // A view whose data does not match its size has no detections.
        let short = &data[..data.len() - 1];
        let short_view = ImageView { width, height, data: short };
        prop_assert!(d.detect(short_view).is_empty());
    }

    /// Blocky images (tag-like structure at every scale) are handled too.
    #[test]
    fn blocky_images_are_handled(width in 8usize..96, height in 8usize..96, block in 1usize..9, seed in any::<u64>()) {
        let mut state = seed | 1;
        let cells: Vec<u8> = (0..(width / block + 1) * (height / block + 1))
            .map(|_| {
                state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
                if state >> 63 == 1 { 220 } else { 30 }
            })
            .collect();
        let data: Vec<u8> = (0..width * height)
            .map(|i| cells[(i / width / block) * (width / block + 1) + (i % width) / block])
            .collect();
        let mut d = detector(3);
        let _ = d.detect(ImageView { width, height, data: &data });
    }
}

/// Random perspective views (edge 40–140 px, any rotation), area-sampled: every tag is found
/// at decimation 1 and 2, and the corners are close to the truth.
#[test]
fn corners_of_random_views_at_decimation_1_and_2() {
    let mut state = 0x1234_5678_9abc_def1u64;
    let mut rnd = move || {
        state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let views: Vec<(usize, [[f64; 2]; 4], Vec<u8>)> = (0..60)
        .map(|k| {
            let (cx, cy) = (100.0 + 40.0 * rnd(), 100.0 + 40.0 * rnd());
            let (s, a, persp) = (20.0 + 50.0 * rnd(), std::f64::consts::TAU * rnd(), 0.25 * (rnd() - 0.5));
            let mut corners = [[0.0; 2]; 4];
            for (i, (u, v)) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)].iter().enumerate() {
                let (x, y) = (u * s, -v * s * (1.0 + persp * u));
                corners[i] = [cx + a.cos() * x - a.sin() * y, cy + a.sin() * x + a.cos() * y];
            }
            let id = (k * 97) % CODES.len();
            (id, corners, render_warped(CODES[id], &corners, 240, 240, 4))
        })
        .collect();
    for decimate in [1, 2] {
        let mut d =
            TagDetector::new(TagDetectorConfig { quad_decimate: decimate, ..TagDetectorConfig::default() }).unwrap();
        let mut errors = Vec::new();
        for (id, corners, image) in &views {
            let found = d.detect(ImageView::new(240, 240, image).unwrap());
            assert_eq!(found.len(), 1, "decimate {decimate}, id {id}");
            assert_eq!(found[0].id, *id as u32);
            for (c, e) in found[0].corners_px.iter().zip(corners) {
                errors.push(((c[0] - e[0]).powi(2) + (c[1] - e[1]).powi(2)).sqrt());
            }
        }
        errors.sort_by(f64::total_cmp);
        let (median, p95, max) = (errors[errors.len() / 2], errors[errors.len() * 95 / 100], errors[errors.len() - 1]);
        println!("decimate {decimate}: corner error median {median:.3} px, p95 {p95:.3} px, max {max:.3} px");
        assert!(median < 0.05 && p95 < 0.12 && max < 0.25, "decimate {decimate}: {median} {p95} {max}");
    }
}
