//! The borrowed-image entry point (`Matcher::compute_views_into`) gives the owned one's bits on
//! a real Middlebury pair, including when both views borrow halves of one buffer, the layout of a
//! stereo sample in shared memory.

#![allow(clippy::unwrap_used, reason = "test helpers: a panic is a failed test with its message")]

use fpga_model::fast::Matcher;
use fpga_model::{DisparityImage, GrayImage, GrayView, PathMode, SgmConfig, SgmError, reference};

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/stereo/");

fn read_gray(relative: &str) -> GrayImage {
    fpga_model::io::read_gray_png(format!("{DATA}{relative}")).unwrap()
}

#[test]
fn views_match_owned_images_on_middlebury_teddy() {
    let left = read_gray("middlebury_v2/teddy/imL.png");
    let right = read_gray("middlebury_v2/teddy/imR.png");
    let (w, h) = (left.width, left.height);
    let mut one_buffer = left.pixels.clone();
    one_buffer.extend_from_slice(&right.pixels);
    let (left_half, right_half) = one_buffer.split_at(w * h);
    for paths in [PathMode::Four, PathMode::Eight] {
        let config = SgmConfig { disparities: 64, paths, ..SgmConfig::default() };
        let expected = reference::compute(&left, &right, &config).unwrap();
        for threads in [1, 2] {
            let mut matcher = Matcher::new(config, w, h, threads).unwrap();
            let owned = matcher.compute(&left, &right).unwrap();
            let mut viewed = DisparityImage { width: 0, height: 0, data: Vec::new() };
            matcher.compute_views_into(left.view(), right.view(), &mut viewed).unwrap();
            let mut halves = DisparityImage { width: 0, height: 0, data: Vec::new() };
            let (left_view, right_view) =
                (GrayView::new(w, h, left_half).unwrap(), GrayView::new(w, h, right_half).unwrap());
            matcher.compute_views_into(left_view, right_view, &mut halves).unwrap();
            let what = format!("{paths:?}, {threads} thread(s)");
            assert!(owned == expected, "{what}: owned images differ from the reference");
            assert!(viewed == expected, "{what}: views differ from the reference");
            assert!(halves == expected, "{what}: views of one buffer differ from the reference");
        }
    }
}

#[test]
fn malformed_views_are_refused() {
    let pixels = vec![0u8; 64 * 32];
    assert!(matches!(GrayView::new(64, 31, &pixels), Err(SgmError::BadImage { .. })));
    assert!(matches!(GrayView::new(0, 32, &[]), Err(SgmError::BadImage { .. })));
    let good = GrayView::new(64, 32, &pixels).unwrap();
    let mut matcher = Matcher::new(SgmConfig { disparities: 16, ..SgmConfig::default() }, 64, 32, 1).unwrap();
    let mut out = DisparityImage { width: 0, height: 0, data: Vec::new() };
    // Public fields can be set past the checked constructor: the matcher checks again.
    let short = GrayView { pixels: &pixels[1..], ..good };
    assert!(matches!(matcher.compute_views_into(good, short, &mut out), Err(SgmError::BadImage { .. })));
    let other_size = GrayView::new(32, 64, &pixels).unwrap();
    assert!(matches!(matcher.compute_views_into(good, other_size, &mut out), Err(SgmError::SizeMismatch { .. })));
    assert!(matches!(matcher.compute_views_into(other_size, other_size, &mut out), Err(SgmError::InvalidConfig(_))));
    matcher.compute_views_into(good, good, &mut out).unwrap();
    assert_eq!((out.width, out.height, out.data.len()), (64, 32, 64 * 32));
}
