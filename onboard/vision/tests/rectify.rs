#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Rectification on the real EuRoC MH_01 raw pairs (752×480, pinhole + radial-tangential).

use std::sync::LazyLock;

use hal::asl::{AslDataset, pair_calibration};
use hal::sensor::{CameraCalibration, Distortion, Pinhole, SensorSource, StereoCalibration, StereoFrame};
use nalgebra::{Isometry3, Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use proptest::prelude::*;
use vision::StereoView;
use vision::rectify::{Rectifier, RectifyError, StereoSide, distort_normalized, undistort_normalized};

const MH01: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/euroc/mh_01_handheld");

fn raw_calibration() -> StereoCalibration {
    AslDataset::open(MH01).unwrap().stereo_calibration().unwrap()
}

/// Built once: the maps take a few tens of milliseconds.
static MH01_RECTIFIER: LazyLock<Rectifier> = LazyLock::new(|| Rectifier::new(&raw_calibration()).unwrap());

fn load_pairs(indices: &[usize]) -> Vec<StereoFrame> {
    let mut dataset = AslDataset::open(MH01).unwrap();
    indices
        .iter()
        .map(|&i| {
            let mut frame = StereoFrame::default();
            dataset.load_pair(i, &mut frame).unwrap();
            frame
        })
        .collect()
}

/// The Kalibr/EuRoC radial-tangential projection, written out independently of the crate.
fn project_radtan(camera: &CameraCalibration, p: &Vector3<f64>) -> [f64; 2] {
    let Distortion::RadTan([k1, k2, p1, p2]) = camera.distortion else { panic!("raw EuRoC camera") };
    let (x, y) = (p.x / p.z, p.y / p.z);
    let r2 = x * x + y * y;
    let radial = 1.0 + k1 * r2 + k2 * r2 * r2;
    let xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x);
    let yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y;
    let k = &camera.intrinsics;
    [k.fx_px * xd + k.cx_px, k.fy_px * yd + k.cy_px]
}

fn project_pinhole(k: &Pinhole, p: &Vector3<f64>) -> [f64; 2] {
    [k.fx_px * p.x / p.z + k.cx_px, k.fy_px * p.y / p.z + k.cy_px]
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[test]
fn rectified_calibration_is_canonical() {
    let raw = raw_calibration();
    assert!(!raw.rectified);
    let rectifier = &*MH01_RECTIFIER;
    let rect = rectifier.rectified_calibration();
    assert!(rect.rectified && !rectifier.is_identity());
    assert_eq!(rect.left.intrinsics, rect.right.intrinsics);
    assert_eq!((rect.left.width_px, rect.left.height_px), (752, 480));
    let k = rect.left.intrinsics;
    println!("MH_01 rectified pinhole: {k:?}, baseline {:.6} m", rect.baseline_m);
    assert_eq!(k.fx_px, k.fy_px);
    // Barrel distortion widens the undistorted field, so the fitted focal length sits below the raw ~458 px.
    assert!((400.0..458.0).contains(&k.fx_px), "{k:?}");
    let t_raw = raw.left.t_body_cam.inverse() * raw.right.t_body_cam;
    assert!((rect.baseline_m - t_raw.translation.vector.norm()).abs() < 1e-12);
    assert!((rect.baseline_m - 0.110).abs() < 0.002, "EuRoC's documented baseline is about 0.110 m");
    // The camera centres do not move, only turn.
    assert!((rect.left.t_body_cam.translation.vector - raw.left.t_body_cam.translation.vector).norm() < 1e-15);
    assert!((rect.right.t_body_cam.translation.vector - raw.right.t_body_cam.translation.vector).norm() < 1e-15);
    // Right at exactly +baseline along x, no relative rotation: hal's own test for a rectified pair agrees.
    let t_rect = rect.left.t_body_cam.inverse() * rect.right.t_body_cam;
    assert!((t_rect.translation.vector - Vector3::new(rect.baseline_m, 0.0, 0.0)).norm() < 1e-12);
    assert!(t_rect.rotation.angle() < 1e-12);
    assert!(pair_calibration(rect.left, rect.right).rectified);
    // Each camera turns by at most half the 0.82° relative rotation plus the baseline alignment.
    for (raw_cam, rect_cam) in [(raw.left, rect.left), (raw.right, rect.right)] {
        let turn = raw_cam.t_body_cam.rotation.angle_to(&rect_cam.t_body_cam.rotation).to_degrees();
        assert!(turn < 3.0, "rectifying rotation {turn}°");
    }
    // The fit asks for an image of real pixels only.
    assert_eq!(rectifier.invalid_pixels(), [0, 0]);
}

#[test]
fn undistortion_inverts_radtan_over_the_image() {
    let raw = raw_calibration();
    for camera in [raw.left, raw.right] {
        let k = camera.intrinsics;
        let mut worst_px: f64 = 0.0;
        for v in (0..480).step_by(3) {
            for u in (0..752).step_by(3) {
                let distorted = [(u as f64 - k.cx_px) / k.fx_px, (v as f64 - k.cy_px) / k.fy_px];
                let ideal = undistort_normalized(&camera.distortion, distorted).unwrap();
                let [xd, yd] = distort_normalized(&camera.distortion, ideal);
                let back = [k.fx_px * xd + k.cx_px, k.fy_px * yd + k.cy_px];
                worst_px = worst_px.max(distance(back, [u as f64, v as f64]));
                // The crate's model is the Kalibr one.
                let independent = project_radtan(&camera, &Vector3::new(ideal[0], ideal[1], 1.0));
                assert!(distance(independent, back) < 1e-9);
            }
        }
        println!("undistortion round trip: worst {worst_px:.2e} px");
        assert!(worst_px < 1e-3, "worst round trip {worst_px} px");
    }
    // The corners are where the distortion is strongest: about 80 px at the raw corners.
    let camera = raw.left;
    let corner =
        [(0.0 - camera.intrinsics.cx_px) / camera.intrinsics.fx_px, -camera.intrinsics.cy_px / camera.intrinsics.fy_px];
    let ideal = undistort_normalized(&camera.distortion, corner).unwrap();
    assert!((ideal[0] - corner[0]).abs() * camera.intrinsics.fx_px > 50.0, "{ideal:?} vs {corner:?}");
}

/// 3-D points seen by both cameras, in the rectified left frame.
fn scene_points() -> Vec<Vector3<f64>> {
    let mut points = Vec::new();
    for depth_m in [0.6, 1.5, 4.0, 20.0, 200.0] {
        for iy in -4..=4 {
            for ix in -6..=6 {
                points.push(Vector3::new(0.13 * ix as f64, 0.12 * iy as f64, 1.0) * depth_m);
            }
        }
    }
    points
}

#[test]
fn raw_and_rectified_models_agree() {
    let raw = raw_calibration();
    let rectifier = &*MH01_RECTIFIER;
    let rect = rectifier.rectified_calibration();
    let k = rect.left.intrinsics;
    let (mut worst_px, mut worst_row_px, mut inverse_px): (f64, f64, f64) = (0.0, 0.0, 0.0);
    for p_rect_left in scene_points() {
        let p_body = rect.left.t_body_cam * Point3::from(p_rect_left);
        let mut rows = [0.0; 2];
        for (side, raw_cam, rect_cam) in
            [(StereoSide::Left, raw.left, rect.left), (StereoSide::Right, raw.right, rect.right)]
        {
            let raw_px = project_radtan(&raw_cam, &(raw_cam.t_body_cam.inverse() * p_body).coords);
            let expected = project_pinhole(&k, &(rect_cam.t_body_cam.inverse() * p_body).coords);
            let got = rectifier.raw_to_rectified_px(side, raw_px).unwrap();
            worst_px = worst_px.max(distance(got, expected));
            rows[side as usize] = got[1];
            let inside = (0.0..=751.0).contains(&expected[0]) && (0.0..=479.0).contains(&expected[1]);
            if inside {
                let back = rectifier.rectified_to_raw_px(side, expected).unwrap();
                inverse_px = inverse_px.max(distance(back, raw_px));
            }
        }
        worst_row_px = worst_row_px.max((rows[0] - rows[1]).abs());
    }
    println!(
        "raw→rectified: worst {worst_px:.1e} px, row difference {worst_row_px:.1e} px, inverse {inverse_px:.1e} px"
    );
    assert!(worst_px < 0.05);
    assert!(worst_row_px < 0.05);
    assert!(inverse_px < 1e-3);
}

/// A raw image of Gaussian spots (σ = 1.5 px) at the given raw pixels.
fn render_spots(spots: &[[f64; 2]]) -> Vec<u8> {
    let mut image = vec![0.0f64; 752 * 480];
    for &[su, sv] in spots {
        for v in (sv as i64 - 6).max(0)..(sv as i64 + 7).min(480) {
            for u in (su as i64 - 6).max(0)..(su as i64 + 7).min(752) {
                let d2 = (u as f64 - su).powi(2) + (v as f64 - sv).powi(2);
                image[v as usize * 752 + u as usize] += 220.0 * (-d2 / (2.0 * 1.5 * 1.5)).exp();
            }
        }
    }
    image.iter().map(|&g| (g + 10.0).round().min(255.0) as u8).collect()
}

/// Intensity centroid above the background in a 13×13 window around `near`.
fn centroid(image: &[u8], near: [f64; 2]) -> [f64; 2] {
    let (cu, cv) = (near[0].round() as i64, near[1].round() as i64);
    let (mut sum, mut su, mut sv) = (0.0, 0.0, 0.0);
    for v in cv - 6..=cv + 6 {
        for u in cu - 6..=cu + 6 {
            let weight = (f64::from(image[v as usize * 752 + u as usize]) - 10.0).max(0.0);
            sum += weight;
            su += weight * u as f64;
            sv += weight * v as f64;
        }
    }
    [su / sum, sv / sum]
}

/// The maps themselves (fixed-point bilinear resampling), not only the formulas, put a 3-D point at its
/// rectified projection and on equal rows in both images.
#[test]
fn remapped_spots_land_at_their_rectified_projection() {
    let raw = raw_calibration();
    let rectifier = &*MH01_RECTIFIER;
    let rect = rectifier.rectified_calibration();
    let k = rect.left.intrinsics;
    // Spots 40 px apart over the whole image, on a wall 3 m away.
    let mut spots: [Vec<[f64; 2]>; 2] = Default::default();
    let mut expected: [Vec<[f64; 2]>; 2] = Default::default();
    for v in (30..460).step_by(40) {
        for u in (30..650).step_by(40) {
            let p_rect_left =
                Vector3::new((u as f64 + 0.37 - k.cx_px) / k.fx_px, (v as f64 + 0.61 - k.cy_px) / k.fy_px, 1.0) * 3.0;
            let p_body = rect.left.t_body_cam * Point3::from(p_rect_left);
            for (side, raw_cam, rect_cam) in [(0, raw.left, rect.left), (1, raw.right, rect.right)] {
                spots[side].push(project_radtan(&raw_cam, &(raw_cam.t_body_cam.inverse() * p_body).coords));
                expected[side].push(project_pinhole(&k, &(rect_cam.t_body_cam.inverse() * p_body).coords));
            }
        }
    }
    let raw_frame = StereoFrame {
        width_px: 752,
        height_px: 480,
        left: render_spots(&spots[0]),
        right: render_spots(&spots[1]),
        ..StereoFrame::default()
    };
    let mut out = StereoFrame::default();
    rectifier.rectify(&raw_frame, &mut out).unwrap();
    let mut errors = Vec::new();
    for (&want_left, &want_right) in expected[0].iter().zip(&expected[1]) {
        let left = centroid(&out.left, want_left);
        let right = centroid(&out.right, want_right);
        errors.push(distance(left, want_left).max(distance(right, want_right)));
        assert!((left[1] - right[1]).abs() < 0.1, "rows {left:?} {right:?}");
    }
    errors.sort_by(f64::total_cmp);
    let (median, worst) = (errors[errors.len() / 2], errors[errors.len() - 1]);
    println!("{} spots: centroid error median {median:.3} px, worst {worst:.3} px", errors.len());
    // The centroid of a resampled, 8-bit spot is itself only good to a few hundredths of a pixel.
    assert!(median < 0.05 && worst < 0.1, "median {median}, worst {worst}");
}

/// Shi-Tomasi corners (smaller structure-tensor eigenvalue, 7×7 window), the best per 16-px cell.
fn corners(image: &[u8], w: usize, h: usize, margin: usize) -> Vec<(usize, usize)> {
    let at = |x: usize, y: usize| f64::from(image[y * w + x]);
    let mut best = std::collections::HashMap::<(usize, usize), (f64, usize, usize)>::new();
    for y in margin..h - margin {
        for x in margin..w - margin {
            let (mut a, mut b, mut c) = (0.0, 0.0, 0.0);
            for yy in y - 3..=y + 3 {
                for xx in x - 3..=x + 3 {
                    let gx = at(xx + 1, yy) - at(xx - 1, yy);
                    let gy = at(xx, yy + 1) - at(xx, yy - 1);
                    (a, b, c) = (a + gx * gx, b + gx * gy, c + gy * gy);
                }
            }
            let score = 0.5 * (a + c) - (0.25 * (a - c) * (a - c) + b * b).sqrt();
            let cell = best.entry((x / 16, y / 16)).or_insert((0.0, 0, 0));
            if score > cell.0 {
                *cell = (score, x, y);
            }
        }
    }
    // Plain-wall cells have tiny scores: keep clear corners only (49 px × 10² grey-level² gradient).
    best.into_values().filter(|&(score, _, _)| score > 3000.0).map(|(_, x, y)| (x, y)).collect()
}

const PATCH_RADIUS: usize = 5;
const MAX_DISPARITY: usize = 80;

/// Vertical offset (right row − left row, sub-pixel) of each unambiguous ZNCC match of an 11×11 patch
/// searched over disparities 0..=80 and rows ±`row_range`.
fn vertical_offsets(left: &[u8], right: &[u8], w: usize, h: usize, row_range: usize) -> Vec<f64> {
    let r = PATCH_RADIUS as i64;
    let n = ((2 * r + 1) * (2 * r + 1)) as f64;
    let margin = PATCH_RADIUS + row_range + 2;
    let mut offsets = Vec::new();
    for (x, y) in corners(left, w, h, margin.max(8)) {
        let patch: Vec<f64> = (-r..=r)
            .flat_map(|dy| (-r..=r).map(move |dx| (dx, dy)))
            .map(|(dx, dy)| f64::from(left[(y as i64 + dy) as usize * w + (x as i64 + dx) as usize]))
            .collect();
        let mean = patch.iter().sum::<f64>() / n;
        let centred: Vec<f64> = patch.iter().map(|g| g - mean).collect();
        let norm = centred.iter().map(|g| g * g).sum::<f64>().sqrt();
        let rows = 2 * row_range + 1;
        let mut scores = vec![f64::NEG_INFINITY; rows * (MAX_DISPARITY + 1)];
        for d in 0..=MAX_DISPARITY.min(x - PATCH_RADIUS) {
            for (row, dy) in (-(row_range as i64)..=row_range as i64).enumerate() {
                let (cx, cy) = (x as i64 - d as i64, y as i64 + dy);
                let (mut sum, mut sum2, mut cross) = (0.0, 0.0, 0.0);
                let mut i = 0;
                for py in cy - r..=cy + r {
                    for px in cx - r..=cx + r {
                        let g = f64::from(right[py as usize * w + px as usize]);
                        (sum, sum2, cross) = (sum + g, sum2 + g * g, cross + g * centred[i]);
                        i += 1;
                    }
                }
                let spread = (sum2 - sum * sum / n).max(0.0).sqrt();
                if spread > 0.0 {
                    scores[row * (MAX_DISPARITY + 1) + d] = cross / (norm * spread);
                }
            }
        }
        let score = |row: usize, d: usize| scores[row * (MAX_DISPARITY + 1) + d];
        let (mut best, mut best_row, mut best_d) = (f64::NEG_INFINITY, 0, 0);
        for row in 0..rows {
            for d in 0..=MAX_DISPARITY {
                if score(row, d) > best {
                    (best, best_row, best_d) = (score(row, d), row, d);
                }
            }
        }
        // Unambiguous: strong, no rival peak outside the best one's neighbourhood, and an interior
        // maximum so the parabola through the rows is defined.
        let rival = (0..rows)
            .flat_map(|row| (0..=MAX_DISPARITY).map(move |d| (row, d)))
            .filter(|&(row, d)| row.abs_diff(best_row) > 2 || d.abs_diff(best_d) > 2)
            .map(|(row, d)| score(row, d))
            .fold(f64::NEG_INFINITY, f64::max);
        let interior = best_row > 0 && best_row + 1 < rows && best_d > 0 && best_d < MAX_DISPARITY;
        if best < 0.9 || rival > best - 0.1 || !interior {
            continue;
        }
        // Sub-pixel peak of a quadratic through the 3×3 scores (d along x, row along y): the row
        // alone would be biased wherever the texture is slanted and the disparity is fractional.
        let s = |dr: i64, dd: i64| score((best_row as i64 + dr) as usize, (best_d as i64 + dd) as usize);
        let (gx, gy) = (0.5 * (s(0, 1) - s(0, -1)), 0.5 * (s(1, 0) - s(-1, 0)));
        let (hxx, hyy) = (s(0, 1) - 2.0 * best + s(0, -1), s(1, 0) - 2.0 * best + s(-1, 0));
        let hxy = 0.25 * (s(1, 1) - s(1, -1) - s(-1, 1) + s(-1, -1));
        let determinant = hxx * hyy - hxy * hxy;
        if !(hxx < 0.0 && determinant > 0.0) {
            continue;
        }
        let sub_row = -(hxx * gy - hxy * gx) / determinant;
        if sub_row.abs() > 1.0 {
            continue;
        }
        offsets.push(best_row as f64 - row_range as f64 + sub_row);
    }
    offsets
}

fn percentile(values: &mut [f64], q: f64) -> f64 {
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q).round() as usize]
}

#[test]
fn rectified_matches_share_rows_and_raw_ones_do_not() {
    let rectifier = &*MH01_RECTIFIER;
    let mut rectified = StereoFrame::default();
    let (mut rect_abs, mut raw_abs) = (Vec::new(), Vec::new());
    for raw in load_pairs(&[0, 21, 42, 63, 84]) {
        rectifier.rectify(&raw, &mut rectified).unwrap();
        let (w, h) = (752, 480);
        rect_abs.extend(vertical_offsets(&rectified.left, &rectified.right, w, h, 4).iter().map(|d| d.abs()));
        // The raw pair is about 11-13 px apart vertically: search wider, else it could not match at all.
        raw_abs.extend(vertical_offsets(&raw.left, &raw.right, w, h, 16).iter().map(|d| d.abs()));
    }
    let (rect_median, rect_p90) = (percentile(&mut rect_abs, 0.5), percentile(&mut rect_abs, 0.9));
    let raw_median = percentile(&mut raw_abs, 0.5);
    println!(
        "rectified: {} matches, |Δy| median {rect_median:.3} px, p90 {rect_p90:.3} px; raw: {} matches, median {raw_median:.2} px",
        rect_abs.len(),
        raw_abs.len()
    );
    assert!(rect_abs.len() >= 200, "only {} rectified matches", rect_abs.len());
    assert!(raw_abs.len() >= 100, "only {} raw matches", raw_abs.len());
    assert!(rect_median < 0.3 && rect_p90 < 1.0);
    // The same measurement on the raw pair fails the thresholds by an order of magnitude.
    assert!(raw_median > 3.0, "raw median {raw_median}");
}

#[test]
fn rectified_output_keeps_the_frame_metadata_and_reuses_its_buffers() {
    let rectifier = &*MH01_RECTIFIER;
    let pairs = load_pairs(&[0, 1]);
    let mut out = StereoFrame::default();
    rectifier.rectify(&pairs[0], &mut out).unwrap();
    let pointers = (out.left.as_ptr(), out.right.as_ptr());
    let mut second = pairs[1].clone();
    second.pan_rad = 0.25;
    second.tilt_rad = -0.5;
    rectifier.rectify(&second, &mut out).unwrap();
    assert_eq!(pointers, (out.left.as_ptr(), out.right.as_ptr()));
    assert_eq!((out.stamp_ns, out.sequence, out.pan_rad, out.tilt_rad), (second.stamp_ns, second.sequence, 0.25, -0.5));
    assert_eq!((out.width_px, out.height_px, out.left.len()), (752, 480, 752 * 480));
    // Rectification turns and rescales the image: it is not a copy, yet it keeps the scene's brightness.
    assert_ne!(out.left, second.left);
    let mean = |image: &[u8]| image.iter().map(|&g| f64::from(g)).sum::<f64>() / image.len() as f64;
    assert!((mean(&out.left) - mean(&second.left)).abs() < 10.0);
}

/// A raw pair read in place (both images halves of one buffer, as a shared-memory sample)
/// rectifies to the owned frame's result; wrong lengths are refused as for a frame.
#[test]
fn a_view_of_one_shared_buffer_rectifies_like_the_frame() {
    let rectifier = &*MH01_RECTIFIER;
    let raw = &load_pairs(&[2])[0];
    let mut sample = raw.left.clone();
    sample.extend_from_slice(&raw.right);
    let (left, right) = sample.split_at(raw.left.len());
    let (mut expected, mut got) = (StereoFrame::default(), StereoFrame::default());
    rectifier.rectify(raw, &mut expected).unwrap();
    rectifier.rectify_view(StereoView { left, right, ..StereoView::of(raw) }, &mut got).unwrap();
    assert_eq!(got, expected);
    let short = StereoView { right: &right[1..], ..StereoView::of(raw) };
    assert!(matches!(rectifier.rectify_view(short, &mut got), Err(RectifyError::BufferLength { .. })));
}

#[test]
fn already_rectified_pair_is_copied() {
    let rect = MH01_RECTIFIER.rectified_calibration();
    let identity = Rectifier::new(&rect).unwrap();
    assert!(identity.is_identity());
    assert_eq!(identity.rectified_calibration(), rect);
    let raw = &load_pairs(&[3])[0];
    let mut out = StereoFrame::default();
    identity.rectify(raw, &mut out).unwrap();
    assert_eq!(&out, raw);
    assert_eq!(identity.raw_to_rectified_px(StereoSide::Right, [3.5, 7.25]), Some([3.5, 7.25]));
}

fn expect_calibration_error(calibration: &StereoCalibration, why: &str) {
    match Rectifier::new(calibration) {
        Err(RectifyError::Calibration(message)) => println!("{why}: {message}"),
        other => panic!("{why}: expected a calibration error, got {other:?}"),
    }
}

#[test]
fn nonsense_calibrations_are_rejected() {
    let raw = raw_calibration();
    let mut c = raw;
    c.left.intrinsics.fx_px = 0.0;
    expect_calibration_error(&c, "zero focal length");
    let mut c = raw;
    c.right.intrinsics.cy_px = f64::NAN;
    expect_calibration_error(&c, "NaN principal point");
    let mut c = raw;
    c.left.distortion = Distortion::RadTan([f64::INFINITY, 0.0, 0.0, 0.0]);
    expect_calibration_error(&c, "infinite distortion");
    let mut c = raw;
    c.right.width_px = 640;
    expect_calibration_error(&c, "different image sizes");
    let mut c = raw;
    c.right.t_body_cam = c.left.t_body_cam;
    expect_calibration_error(&c, "zero baseline (poses)");
    let mut c = raw;
    c.baseline_m = 0.0;
    expect_calibration_error(&c, "zero baseline (field)");
    let mut c = raw;
    // Left and right swapped: the "right" camera sits on the left.
    (c.left.t_body_cam, c.right.t_body_cam) = (raw.right.t_body_cam, raw.left.t_body_cam);
    expect_calibration_error(&c, "swapped cameras");
    let mut c = raw;
    // A fold inside the image: the polynomial cannot be inverted near the corners.
    c.left.distortion = Distortion::RadTan([-1.5, 0.0, 0.0, 0.0]);
    expect_calibration_error(&c, "non-invertible distortion");
    let mut c = raw;
    c.right.t_body_cam.rotation = UnitQuaternion::new_unchecked(Quaternion::new(2.0, 0.0, 0.0, 0.0));
    expect_calibration_error(&c, "non-unit rotation");
    let mut c = raw;
    let turn = UnitQuaternion::from_axis_angle(&Vector3::y_axis(), 2.0);
    c.right.t_body_cam.rotation = c.left.t_body_cam.rotation * turn;
    expect_calibration_error(&c, "cameras looking apart");
    let mut c = raw;
    (c.left.width_px, c.right.width_px) = (1, 1);
    expect_calibration_error(&c, "one-pixel-wide image");
}

/// Any number, finite or not.
fn any_value() -> impl Strategy<Value = f64> + Clone {
    prop_oneof![
        4 => -2.0..2.0f64,
        2 => any::<f64>(),
        1 => Just(0.0),
        1 => Just(f64::NAN),
        1 => Just(f64::INFINITY),
        1 => Just(-1e300),
    ]
}

/// A number that keeps the calibration plausible, so the search gets past validation.
fn tame_value() -> impl Strategy<Value = f64> + Clone {
    -1.0..1.0f64
}

fn any_pose(value: impl Strategy<Value = f64> + Clone) -> impl Strategy<Value = Isometry3<f64>> {
    (prop::array::uniform3(value.clone()), prop::array::uniform4(value)).prop_map(|(t, q)| {
        let quaternion = Quaternion::new(q[0], q[1], q[2], q[3]);
        // Mostly proper rotations, sometimes whatever the numbers are.
        let rotation = if q[0] > -0.5 {
            UnitQuaternion::new_normalize(quaternion)
        } else {
            UnitQuaternion::new_unchecked(quaternion)
        };
        Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), rotation)
    })
}

/// Small cameras (so the maps build fast) with numbers drawn from `value`.
fn camera_from(value: impl Strategy<Value = f64> + Clone) -> impl Strategy<Value = CameraCalibration> {
    (
        prop_oneof![8 => 0u32..24, 1 => Just(u32::MAX)],
        prop_oneof![8 => 0u32..24, 1 => Just(u32::MAX)],
        prop::array::uniform4(value.clone()),
        prop::array::uniform4(value.clone()),
        any::<bool>(),
        any_pose(value),
    )
        .prop_map(|(w, h, k, d, distorted, pose)| CameraCalibration {
            width_px: w,
            height_px: h,
            intrinsics: Pinhole {
                fx_px: 12.0 + 10.0 * k[0],
                fy_px: 12.0 + 10.0 * k[1],
                cx_px: 12.0 + 5.0 * k[2],
                cy_px: 12.0 + 5.0 * k[3],
            },
            distortion: if distorted {
                Distortion::RadTan([0.3 * d[0], 0.1 * d[1], 0.01 * d[2], 0.01 * d[3]])
            } else {
                Distortion::None
            },
            t_body_cam: pose,
        })
}

fn any_camera() -> impl Strategy<Value = CameraCalibration> {
    prop_oneof![camera_from(any_value()), camera_from(tame_value())]
}

/// When `new` succeeds, the result is usable: a finite rectified camera and frames that rectify.
fn check_if_built(calibration: &StereoCalibration) -> Result<(), TestCaseError> {
    if let Ok(rectifier) = Rectifier::new(calibration) {
        let rect = rectifier.rectified_calibration();
        prop_assert!(rect.rectified);
        let k = rect.left.intrinsics;
        prop_assert!([k.fx_px, k.fy_px, k.cx_px, k.cy_px].iter().all(|v| v.is_finite()));
        let (w, h) = (rect.left.width_px, rect.left.height_px);
        let len = (w * h) as usize;
        let frame = StereoFrame {
            width_px: w,
            height_px: h,
            left: vec![7; len],
            right: vec![9; len],
            ..StereoFrame::default()
        };
        let mut out = StereoFrame::default();
        prop_assert!(rectifier.rectify(&frame, &mut out).is_ok());
        let _ = rectifier.raw_to_rectified_px(StereoSide::Left, [k.cx_px, -3.0]);
        let _ = rectifier.rectified_to_raw_px(StereoSide::Right, [1e30, f64::NAN]);
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    #[test]
    fn new_never_panics(left in any_camera(), right in any_camera(), rectified in any::<bool>(), baseline in prop_oneof![any_value(), 0.01..1.0f64],
                        offset in prop::array::uniform3(-0.2..0.2f64)) {
        for same_size in [false, true] {
            let mut right = right;
            if same_size {
                // Often a plausible pair: same size, right camera near +x of the left one.
                (right.width_px, right.height_px) = (left.width_px, left.height_px);
                right.t_body_cam = left.t_body_cam * Isometry3::translation(0.1 + offset[0], offset[1], offset[2])
                    * UnitQuaternion::from_scaled_axis(Vector3::new(offset[1], offset[2], offset[0]));
            }
            let calibration = StereoCalibration { left, right, rectified, baseline_m: baseline, head: None };
            check_if_built(&calibration)?;
        }
    }

    #[test]
    fn new_never_panics_on_perturbed_euroc(scale in 4.0..40.0f64, k in prop::array::uniform4(-1.0..1.0f64),
                                           d in prop::array::uniform4(-1.0..1.0f64),
                                           pose in prop::array::uniform6(-1.0..1.0f64), big in 0usize..8) {
        // The MH_01 pair shrunk by `scale` (so the maps build fast) with every number disturbed, by a
        // lot for one of the groups: strong or folding distortion, offset principal points, turned
        // cameras. This reaches the fit and the maps, which arbitrary numbers rarely get past validation to.
        let raw = raw_calibration();
        let amount = |group: usize| if big == group { 1.0 } else { 0.05 };
        let mut c = raw;
        for (i, camera) in [&mut c.left, &mut c.right].into_iter().enumerate() {
            camera.width_px = (752.0 / scale) as u32;
            camera.height_px = (480.0 / scale) as u32;
            let p = camera.intrinsics;
            camera.intrinsics = Pinhole {
                fx_px: p.fx_px / scale * (1.0 + amount(0) * k[0]),
                fy_px: p.fy_px / scale * (1.0 + amount(0) * k[1]),
                cx_px: p.cx_px / scale + amount(1) * 20.0 * k[2],
                cy_px: p.cy_px / scale + amount(1) * 20.0 * k[3],
            };
            if i == 1 {
                camera.distortion = Distortion::RadTan([d[0], 0.5 * d[1], 0.05 * d[2], 0.05 * d[3]].map(|v| v * amount(2) * 6.0));
                let turn = Vector3::new(pose[0], pose[1], pose[2]) * amount(3);
                let shift = Vector3::new(pose[3], pose[4], pose[5]) * 0.1 * amount(4);
                camera.t_body_cam *= Isometry3::new(shift, turn);
            }
        }
        c.baseline_m = (c.left.t_body_cam.inverse() * c.right.t_body_cam).translation.vector.norm();
        check_if_built(&c)?;
    }

    #[test]
    fn frames_of_the_wrong_size_are_rejected(w in 0u32..2000, h in 0u32..1000, short in 0usize..2, which in 0usize..2) {
        let rectifier = &*MH01_RECTIFIER;
        let mut out = StereoFrame::default();
        let len = w as usize * h as usize;
        let mut frame = StereoFrame { width_px: w, height_px: h, left: vec![0; len], right: vec![0; len], ..StereoFrame::default() };
        let result = rectifier.rectify(&frame, &mut out);
        if (w, h) == (752, 480) {
            prop_assert!(result.is_ok());
            // Right header, wrong buffer.
            let buffer = if which == 0 { &mut frame.left } else { &mut frame.right };
            buffer.truncate(len - 1 - short);
            let is_buffer_error = matches!(rectifier.rectify(&frame, &mut out), Err(RectifyError::BufferLength { .. }));
            prop_assert!(is_buffer_error);
        } else {
            let is_size_error = matches!(result, Err(RectifyError::FrameSize { got_w, got_h, want_w: 752, want_h: 480 })
                if (got_w, got_h) == (w, h));
            prop_assert!(is_size_error);
        }
    }
}

#[test]
fn frame_of_the_calibrated_size_is_accepted_by_the_proptest_branch() {
    // The proptest above rarely draws exactly 752×480; check that branch explicitly.
    let rectifier = &*MH01_RECTIFIER;
    let frame = StereoFrame {
        width_px: 752,
        height_px: 480,
        left: vec![1; 752 * 480],
        right: vec![2; 752 * 480],
        ..StereoFrame::default()
    };
    let mut out = StereoFrame::default();
    rectifier.rectify(&frame, &mut out).unwrap();
    let mut short = frame.clone();
    short.right.pop();
    assert!(
        matches!(rectifier.rectify(&short, &mut out), Err(RectifyError::BufferLength { got, want: 360_960 }) if got == 360_959)
    );
}
