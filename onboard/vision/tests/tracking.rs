#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Pyramid, corner detector and KLT tracker on synthetic motion with exact ground truth and on
//! real KITTI / EuRoC frames.

use hal::emulator::SplitMix64;
use nalgebra::{Matrix3, Vector3};
use proptest::prelude::*;
use vision::ImageView;
use vision::features::{FeatureConfig, FeatureDetector, Keypoint};
use vision::klt::{KltConfig, KltTracker};
use vision::pyramid::Pyramid;

const KITTI: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/stereo_sequences/kitti_straight");
const EUROC_MH01: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/euroc/mh_01_handheld/mav0");

struct Gray {
    width: usize,
    height: usize,
    data: Vec<u8>,
}

impl Gray {
    fn view(&self) -> ImageView<'_> {
        ImageView::new(self.width, self.height, &self.data).unwrap()
    }
}

fn load_png(path: &str) -> Gray {
    let bytes = std::fs::read(path).unwrap_or_else(|e| panic!("{path}: {e}"));
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes.as_slice()));
    let mut reader = decoder.read_info().unwrap();
    let (color, depth) = reader.output_color_type();
    assert_eq!((color, depth), (png::ColorType::Grayscale, png::BitDepth::Eight), "{path}");
    let (width, height) = (reader.info().width as usize, reader.info().height as usize);
    let mut data = vec![0; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut data).unwrap();
    assert_eq!(data.len(), width * height);
    Gray { width, height, data }
}

/// A smooth random texture: a sum of plane waves with random direction, period (5–60 px) and
/// phase. Defined everywhere, so a moved copy can be rendered exactly at sub-pixel offsets.
struct Texture {
    waves: Vec<[f64; 4]>,
}

impl Texture {
    fn new(seed: u64) -> Self {
        let mut rng = SplitMix64::new(seed);
        let mut uniform = move || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        let waves = (0..40)
            .map(|_| {
                let angle = uniform() * std::f64::consts::TAU;
                let period = 5.0 + 55.0 * uniform();
                let k = std::f64::consts::TAU / period;
                [k * angle.cos(), k * angle.sin(), uniform() * std::f64::consts::TAU, 0.5 + uniform()]
            })
            .collect();
        Texture { waves }
    }

    fn value(&self, x: f64, y: f64) -> f64 {
        let sum: f64 = self.waves.iter().map(|w| w[3] * (w[0] * x + w[1] * y + w[2]).sin()).sum();
        (128.0 + 14.0 * sum).clamp(0.0, 255.0)
    }

    /// Renders `I(x) = f(source_of(x))` where `source_of` maps an image pixel back to the texture.
    fn render(&self, width: usize, height: usize, source_of: impl Fn(f64, f64) -> (f64, f64)) -> Gray {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let (sx, sy) = source_of(x as f64, y as f64);
                data.push(self.value(sx, sy).round() as u8);
            }
        }
        Gray { width, height, data }
    }
}

fn pyramid_of(image: &Gray, levels: usize) -> Pyramid {
    let mut pyramid = Pyramid::new(image.width, image.height, levels);
    pyramid.build(image.view());
    pyramid
}

fn median(values: &mut [f32]) -> f32 {
    assert!(!values.is_empty());
    values.sort_by(f32::total_cmp);
    values[values.len() / 2]
}

fn detect(image: &Gray, config: FeatureConfig) -> Vec<Keypoint> {
    let mut detector = FeatureDetector::new(config, image.width, image.height);
    let mut out = Vec::new();
    detector.detect(image.view(), &[], &mut out);
    out
}

fn points_of(keypoints: &[Keypoint]) -> Vec<[f32; 2]> {
    keypoints.iter().map(|k| [k.x, k.y]).collect()
}

/// Tracks `points` and returns the errors against `truth` of the successful tracks, plus the
/// number of lost ones.
fn tracking_errors(
    prev: &Gray,
    next: &Gray,
    points: &[[f32; 2]],
    truth: &[[f64; 2]],
    config: KltConfig,
) -> (Vec<f32>, usize) {
    let (p0, p1) = (pyramid_of(prev, 4), pyramid_of(next, 4));
    let mut tracker = KltTracker::new(config);
    let mut out = Vec::new();
    tracker.track(&p0, &p1, points, None, &mut out);
    assert_eq!(out.len(), points.len());
    let mut errors = Vec::new();
    let mut lost = 0;
    for (result, t) in out.iter().zip(truth) {
        match result {
            Some([x, y]) => errors.push(((f64::from(*x) - t[0]).hypot(f64::from(*y) - t[1])) as f32),
            None => lost += 1,
        }
    }
    (errors, lost)
}

#[test]
fn pyramid_levels_halve_and_keep_a_constant_image_constant() {
    let image = Gray { width: 101, height: 64, data: vec![77; 101 * 64] };
    let pyramid = pyramid_of(&image, 4);
    assert_eq!(pyramid.levels(), 4);
    let sizes: Vec<_> = (0..4).map(|l| (pyramid.level(l).width, pyramid.level(l).height)).collect();
    assert_eq!(sizes, [(101, 64), (51, 32), (26, 16), (13, 8)]);
    for l in 0..4 {
        assert!(pyramid.level(l).data.iter().all(|&v| (v - 77.0).abs() < 1e-4));
    }
    // Too small for another halving: levels stop instead of producing degenerate images.
    assert_eq!(Pyramid::new(20, 20, 5).levels(), 2);
}

#[test]
fn pyramid_level_samples_the_texture_at_half_coordinates() {
    // A smooth texture seen at level k at (x, y) / 2^k must match level 0 (blur of a smooth signal
    // changes it little): checks the coordinate convention (no half-pixel shift).
    let texture = Texture { waves: vec![[0.06, 0.02, 0.3, 1.0], [-0.03, 0.05, 1.1, 1.0]] };
    let image = texture.render(256, 192, |x, y| (x, y));
    let pyramid = pyramid_of(&image, 3);
    let top = pyramid.level(2);
    let mut worst = 0.0f64;
    for y in (20..170).step_by(7) {
        for x in (20..230).step_by(7) {
            let expected = texture.value(f64::from(x), f64::from(y));
            let got = f64::from(top.sample(x as f32 / 4.0, y as f32 / 4.0));
            worst = worst.max((expected - got).abs());
        }
    }
    // Binomial blur over two levels attenuates a 100 px period wave by < 5 % of its 14-level
    // amplitude; a half-pixel registration error would cost ~ 14 · 2π · 0.5 · 4 / 100 ≈ 1.8 levels.
    assert!(worst < 1.5, "worst deviation {worst}");
    // Bilinear sampling is exact at pixel centres and clamps outside.
    let base = pyramid.level(0);
    assert_eq!(base.sample(10.0, 12.0), f32::from(image.data[12 * 256 + 10]));
    assert_eq!(base.sample(-5.0, -3.0), f32::from(image.data[0]));
    assert_eq!(base.sample(1e9, 1e9), f32::from(image.data[256 * 192 - 1]));
}

#[test]
fn klt_recovers_subpixel_translation_and_drops_points_leaving_the_image() {
    let texture = Texture::new(7);
    let (w, h) = (320, 240);
    let (tx, ty) = (9.37, -4.81);
    let prev = texture.render(w, h, |x, y| (x, y));
    let next = texture.render(w, h, |x, y| (x - tx, y - ty));
    // A narrow border so that features along the right and top edges leave the image.
    let config = FeatureConfig { max_features: 1000, cell_size_px: 16, border_px: 4, ..FeatureConfig::default() };
    let keypoints = detect(&prev, config);
    assert!(keypoints.len() > 100, "only {} features on the synthetic texture", keypoints.len());
    let points = points_of(&keypoints);
    let truth: Vec<[f64; 2]> = points.iter().map(|p| [f64::from(p[0]) + tx, f64::from(p[1]) + ty]).collect();
    let (p0, p1) = (pyramid_of(&prev, 4), pyramid_of(&next, 4));
    let mut tracker = KltTracker::new(KltConfig::default());
    let mut out = Vec::new();
    tracker.track(&p0, &p1, &points, None, &mut out);
    let mut errors = Vec::new();
    let (mut inside, mut outside, mut inside_tracked) = (0, 0, 0);
    for (result, t) in out.iter().zip(&truth) {
        let margin = 7.0; // window radius: near the border the window sees clamped pixels
        let clearly_inside =
            t[0] >= margin && t[1] >= margin && t[0] <= (w - 1) as f64 - margin && t[1] <= (h - 1) as f64 - margin;
        let outside_image = t[0] < -0.5 || t[1] < -0.5 || t[0] > (w - 1) as f64 + 0.5 || t[1] > (h - 1) as f64 + 0.5;
        if outside_image {
            outside += 1;
            assert!(result.is_none(), "point moved to {t:?} (outside) tracked to {result:?}");
        }
        if clearly_inside {
            inside += 1;
            if let Some([x, y]) = result {
                inside_tracked += 1;
                errors.push(((f64::from(*x) - t[0]).hypot(f64::from(*y) - t[1])) as f32);
            }
        }
    }
    assert!(outside >= 5, "the translation moves only {outside} points out of the image");
    assert!(inside_tracked * 100 >= inside * 95, "tracked {inside_tracked} of {inside} points that stay inside");
    let med = median(&mut errors);
    let p90 = errors[errors.len() * 9 / 10];
    println!("translation: {inside_tracked}/{inside} tracked, median error {med:.4} px, 90 % {p90:.4} px");
    // u8 quantisation of the texture limits sub-pixel accuracy to a few hundredths of a pixel.
    assert!(med < 0.05, "median error {med} px");
}

#[test]
fn klt_large_translation_is_either_found_or_dropped() {
    // 23 px is beyond the convergence basin of part of this texture's points on a 4-level pyramid
    // (its coarse levels keep little low-frequency content); those must be dropped, not mislocated.
    let texture = Texture::new(7);
    let (tx, ty) = (23.37, -9.81);
    let prev = texture.render(320, 240, |x, y| (x, y));
    let next = texture.render(320, 240, |x, y| (x - tx, y - ty));
    let config = FeatureConfig { max_features: 1000, cell_size_px: 16, border_px: 40, ..FeatureConfig::default() };
    let points = points_of(&detect(&prev, config));
    let truth: Vec<[f64; 2]> = points.iter().map(|p| [f64::from(p[0]) + tx, f64::from(p[1]) + ty]).collect();
    let (errors, lost) = tracking_errors(&prev, &next, &points, &truth, KltConfig::default());
    let wrong = errors.iter().filter(|&&e| e > 0.2).count();
    println!("23 px translation: {} tracked, {lost} lost, {wrong} off by > 0.2 px", errors.len());
    assert!(errors.len() * 2 >= points.len(), "{} of {} tracked", errors.len(), points.len());
    assert!(wrong * 50 <= errors.len(), "{wrong} of {} accepted tracks are off by > 0.2 px", errors.len());
}

#[test]
fn klt_follows_small_rotation_and_scale() {
    let texture = Texture::new(11);
    let (w, h) = (320, 240);
    let centre = (160.0, 120.0);
    let (angle, scale, shift) = (2.0f64.to_radians(), 1.02, (1.7, -0.6));
    let (c, s) = (angle.cos(), angle.sin());
    // next(x) = prev(A⁻¹ (x - centre - shift) + centre) with A = scale · R(angle).
    let forward = |x: f64, y: f64| {
        let (dx, dy) = (x - centre.0, y - centre.1);
        (scale * (c * dx - s * dy) + centre.0 + shift.0, scale * (s * dx + c * dy) + centre.1 + shift.1)
    };
    let inverse = |x: f64, y: f64| {
        let (dx, dy) = ((x - centre.0 - shift.0) / scale, (y - centre.1 - shift.1) / scale);
        (c * dx + s * dy + centre.0, -s * dx + c * dy + centre.1)
    };
    let prev = texture.render(w, h, |x, y| (x, y));
    let next = texture.render(w, h, inverse);
    let keypoints =
        detect(&prev, FeatureConfig { max_features: 1000, cell_size_px: 16, border_px: 24, ..Default::default() });
    let points = points_of(&keypoints);
    let truth: Vec<[f64; 2]> = points
        .iter()
        .map(|p| {
            let (x, y) = forward(f64::from(p[0]), f64::from(p[1]));
            [x, y]
        })
        .collect();
    // Translation-only windows (default) and affine windows on the finest level.
    for (affine_levels, tolerance) in [(0, 0.05), (1, 0.02)] {
        let config = KltConfig { affine_levels, ..KltConfig::default() };
        let (mut errors, lost) = tracking_errors(&prev, &next, &points, &truth, config);
        let med = median(&mut errors);
        println!(
            "rotation+scale, affine levels {affine_levels}: {} tracked, {lost} lost, median error {med:.4} px",
            errors.len()
        );
        // Motion at the image corners is up to ~8 px; all points stay well inside the image.
        assert!(errors.len() * 100 >= points.len() * 95, "lost {lost} of {}", points.len());
        // A translation window is nearly unbiased at its centre under a 2° / 2 % deformation
        // (measured 0.042 px); the affine window models it (measured 0.009 px).
        assert!(med < tolerance, "affine levels {affine_levels}: median error {med} px");
    }
}

#[test]
fn klt_uses_the_prediction_for_large_motion() {
    // 60 px exceeds what a 4-level pyramid with a 7 px window can find from zero; the prediction
    // (e.g. from a gyro prior) brings it back in range.
    let texture = Texture::new(3);
    let (w, h) = (320, 240);
    let (tx, ty) = (-60.4, 3.3);
    let prev = texture.render(w, h, |x, y| (x, y));
    let next = texture.render(w, h, |x, y| (x - tx, y - ty));
    let points: Vec<[f32; 2]> =
        detect(&prev, FeatureConfig::default()).iter().filter(|k| k.x > 90.0).map(|k| [k.x, k.y]).collect();
    assert!(points.len() > 20);
    let predicted: Vec<[f32; 2]> = points.iter().map(|p| [p[0] - 58.0, p[1] + 2.0]).collect();
    let (p0, p1) = (pyramid_of(&prev, 4), pyramid_of(&next, 4));
    let mut tracker = KltTracker::new(KltConfig::default());
    let mut out = Vec::new();
    tracker.track(&p0, &p1, &points, Some(&predicted), &mut out);
    let mut errors: Vec<f32> = out
        .iter()
        .zip(&points)
        .filter_map(|(r, p)| r.map(|[x, y]| (x - (p[0] + tx as f32)).hypot(y - (p[1] + ty as f32))))
        .collect();
    assert!(errors.len() * 100 >= points.len() * 95, "{} of {} tracked", errors.len(), points.len());
    assert!(median(&mut errors) < 0.05);
}

#[test]
fn klt_rejects_untextured_windows_and_mismatched_pyramids() {
    let flat = Gray { width: 64, height: 64, data: vec![100; 64 * 64] };
    let p = pyramid_of(&flat, 3);
    let mut tracker = KltTracker::new(KltConfig::default());
    let mut out = Vec::new();
    tracker.track(&p, &p, &[[32.0, 32.0], [-3.0, 5.0], [f32::NAN, 1.0]], None, &mut out);
    assert_eq!(out, [None, None, None]);
    let other = pyramid_of(&Gray { width: 32, height: 64, data: vec![100; 32 * 64] }, 3);
    tracker.track(&p, &other, &[[10.0, 10.0]], None, &mut out);
    assert_eq!(out, [None]);
}

struct Kitti {
    fx: f64,
    cx: f64,
    cy: f64,
}

fn kitti_calibration() -> Kitti {
    let text = std::fs::read_to_string(format!("{KITTI}/calib.txt")).unwrap();
    let p0: Vec<f64> = text.lines().next().unwrap().split_whitespace().map(|v| v.parse().unwrap()).collect();
    Kitti { fx: p0[0], cx: p0[2], cy: p0[6] }
}

/// `T_world_cam0` of a frame as (R, t).
fn kitti_pose(frame: usize) -> (Matrix3<f64>, Vector3<f64>) {
    let text = std::fs::read_to_string(format!("{KITTI}/poses.txt")).unwrap();
    let v: Vec<f64> = text.lines().nth(frame).unwrap().split_whitespace().map(|v| v.parse().unwrap()).collect();
    (Matrix3::new(v[0], v[1], v[2], v[4], v[5], v[6], v[8], v[9], v[10]), Vector3::new(v[3], v[7], v[11]))
}

#[test]
fn kitti_consecutive_frames_track_consistently_with_the_epipolar_geometry() {
    let prev = load_png(&format!("{KITTI}/image_l/000000.png"));
    let next = load_png(&format!("{KITTI}/image_l/000001.png"));
    let keypoints = detect(&prev, FeatureConfig::default());
    assert!(keypoints.len() >= 300, "{} features", keypoints.len());
    let points = points_of(&keypoints);
    let (p0, p1) = (pyramid_of(&prev, 4), pyramid_of(&next, 4));
    let mut tracker = KltTracker::new(KltConfig::default());
    let mut out = Vec::new();
    tracker.track(&p0, &p1, &points, None, &mut out);
    let tracked: Vec<([f32; 2], [f32; 2])> = points.iter().zip(&out).filter_map(|(&a, b)| b.map(|b| (a, b))).collect();
    let fraction = tracked.len() as f64 / points.len() as f64;

    // Forward-backward error measured independently of the tracker's own gate.
    let mut plain = KltTracker::new(KltConfig { forward_backward_px: 0.0, ..KltConfig::default() });
    let ends: Vec<[f32; 2]> = tracked.iter().map(|t| t.1).collect();
    let starts: Vec<[f32; 2]> = tracked.iter().map(|t| t.0).collect();
    let mut back = Vec::new();
    plain.track(&p1, &p0, &ends, Some(&starts), &mut back);
    let mut fb: Vec<f32> =
        back.iter().zip(&starts).filter_map(|(b, s)| b.map(|b| (b[0] - s[0]).hypot(b[1] - s[1]))).collect();
    let fb_median = median(&mut fb);

    // Epipolar distance under the ground-truth motion: x1 = R x0 + t in camera-1 coordinates.
    let cal = kitti_calibration();
    let (r_w0, t_w0) = kitti_pose(0);
    let (r_w1, t_w1) = kitti_pose(1);
    let rotation = r_w1.transpose() * r_w0;
    let translation = r_w1.transpose() * (t_w0 - t_w1);
    let essential = translation.cross_matrix() * rotation;
    let k = Matrix3::new(cal.fx, 0.0, cal.cx, 0.0, cal.fx, cal.cy, 0.0, 0.0, 1.0);
    let k_inv = k.try_inverse().unwrap();
    let fundamental = k_inv.transpose() * essential * k_inv;
    let mut epipolar: Vec<f32> = tracked
        .iter()
        .map(|(a, b)| {
            let x0 = Vector3::new(f64::from(a[0]), f64::from(a[1]), 1.0);
            let x1 = Vector3::new(f64::from(b[0]), f64::from(b[1]), 1.0);
            let line = fundamental * x0;
            (x1.dot(&line).abs() / line.x.hypot(line.y)) as f32
        })
        .collect();
    let epipolar_median = median(&mut epipolar);
    let within_1px = epipolar.iter().filter(|&&d| d < 1.0).count() as f64 / epipolar.len() as f64;
    let within_2px = epipolar.iter().filter(|&&d| d < 2.0).count() as f64 / epipolar.len() as f64;
    println!(
        "KITTI 0→1: {}/{} tracked ({:.1} %), FB median {fb_median:.4} px, epipolar median {epipolar_median:.3} px, \
         {:.1} % within 1 px, {:.1} % within 2 px",
        tracked.len(),
        points.len(),
        100.0 * fraction,
        100.0 * within_1px,
        100.0 * within_2px
    );
    // 1.2 m per frame at 10 Hz: a quarter of the features move > 30 px and their windows scale by
    // > 10 % (near road, parked cars, overhanging trees). Measured 56.0 %; the forward-backward gate
    // rejects the rest rather than passing biased tracks on.
    assert!(fraction >= 0.5, "tracked only {:.1} %", 100.0 * fraction);
    assert!(fb_median < 0.1, "forward-backward median {fb_median} px");
    // The tracks themselves are good to < 0.1 px (forward-backward), so the epipolar distance mostly
    // measures KITTI's GPS/INS ground truth, whose frame-to-frame rotation is good to ~0.05° (≈ 0.6
    // px at fx 707): measured median 0.65 px. A wrong track would be off by pixels to tens of pixels.
    assert!(epipolar_median < 1.0, "epipolar median {epipolar_median} px");
    assert!(within_2px >= 0.85, "only {:.1} % within 2 px of their epipolar line", 100.0 * within_2px);
}

#[test]
fn kitti_left_right_tracks_stay_on_the_same_row() {
    let left = load_png(&format!("{KITTI}/image_l/000000.png"));
    let right = load_png(&format!("{KITTI}/image_r/000000.png"));
    let keypoints = detect(&left, FeatureConfig::default());
    let points = points_of(&keypoints);
    // Disparities reach ~100 px close to the car: one more level than for frame-to-frame motion.
    let (pl, pr) = (pyramid_of(&left, 5), pyramid_of(&right, 5));
    let mut tracker = KltTracker::new(KltConfig::default());
    let mut out = Vec::new();
    tracker.track(&pl, &pr, &points, None, &mut out);
    let pairs: Vec<([f32; 2], [f32; 2])> = points.iter().zip(&out).filter_map(|(&a, b)| b.map(|b| (a, b))).collect();
    let on_row = pairs.iter().filter(|(a, b)| (a[1] - b[1]).abs() < 0.5).count();
    let positive = pairs.iter().filter(|(a, b)| a[0] - b[0] > -0.5).count();
    let near_row = pairs.iter().filter(|(a, b)| (a[1] - b[1]).abs() < 1.5).count();
    println!(
        "KITTI left→right: {}/{} tracked, {on_row} with |Δy| < 0.5 px, {near_row} < 1.5 px, {positive} with disparity ≥ -0.5",
        pairs.len(),
        points.len()
    );
    assert!(pairs.len() * 2 >= points.len(), "tracked only {} of {}", pairs.len(), points.len());
    // Measured 69 % within 0.5 px: the misses sit in the tree canopy of the upper third (fine 3-D
    // foliage looks different from the two viewpoints), below it > 85 % are within 0.5 px.
    assert!(on_row * 100 >= pairs.len() * 60, "{on_row} of {} within 0.5 px of the same row", pairs.len());
    assert!(near_row * 100 >= pairs.len() * 90, "{near_row} of {} within 1.5 px of the same row", pairs.len());
    assert!(positive * 10 >= pairs.len() * 9, "{positive} of {} with non-negative disparity", pairs.len());
}

#[test]
fn euroc_consecutive_frames_track_with_small_forward_backward_error() {
    let csv = std::fs::read_to_string(format!("{EUROC_MH01}/cam0/data.csv")).unwrap();
    let names: Vec<&str> =
        csv.lines().filter(|l| !l.starts_with('#')).filter_map(|l| l.split(',').nth(1)).map(str::trim).collect();
    let prev = load_png(&format!("{EUROC_MH01}/cam0/data/{}", names[10]));
    let next = load_png(&format!("{EUROC_MH01}/cam0/data/{}", names[11]));
    let keypoints = detect(&prev, FeatureConfig { max_features: 300, cell_size_px: 32, ..Default::default() });
    assert!(keypoints.len() >= 150, "{} features", keypoints.len());
    let points = points_of(&keypoints);
    let (p0, p1) = (pyramid_of(&prev, 4), pyramid_of(&next, 4));
    let mut tracker = KltTracker::new(KltConfig::default());
    let mut out = Vec::new();
    tracker.track(&p0, &p1, &points, None, &mut out);
    let tracked = out.iter().flatten().count();
    println!("EuRoC MH_01 frame 10→11: {tracked}/{} tracked", points.len());
    assert!(tracked * 10 >= points.len() * 8, "tracked {tracked} of {}", points.len());
}

fn cell_of(x: f32, y: f32, cell: usize) -> (usize, usize) {
    (x as usize / cell, y as usize / cell)
}

/// Standard deviation of the grey values of a `cell`² block.
fn cell_contrast(image: &Gray, cx: usize, cy: usize, cell: usize) -> f64 {
    let mut values = Vec::new();
    for y in cy * cell..((cy + 1) * cell).min(image.height) {
        for x in cx * cell..((cx + 1) * cell).min(image.width) {
            values.push(f64::from(image.data[y * image.width + x]));
        }
    }
    let mean = values.iter().sum::<f64>() / values.len() as f64;
    (values.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / values.len() as f64).sqrt()
}

#[test]
fn detector_spreads_features_respects_border_and_existing_points_and_is_deterministic() {
    for path in [format!("{KITTI}/image_l/000000.png"), format!("{EUROC_MH01}/cam0/data/1403636593013555456.png")] {
        let image = load_png(&path);
        let config = FeatureConfig { max_features: 10_000, ..FeatureConfig::default() };
        let (cell, border) = (config.cell_size_px, config.border_px);
        let mut detector = FeatureDetector::new(config.clone(), image.width, image.height);
        let mut features = Vec::new();
        detector.detect(image.view(), &[], &mut features);

        // Border and one feature per cell.
        let mut cells = std::collections::HashSet::new();
        for k in &features {
            assert!(k.x >= border as f32 && k.y >= border as f32, "{k:?} inside the border");
            assert!(k.x < (image.width - border) as f32 && k.y < (image.height - border) as f32, "{k:?}");
            assert!(cells.insert(cell_of(k.x, k.y, cell)), "two features in the cell of {k:?}");
        }
        assert!(features.windows(2).all(|p| p[0].score >= p[1].score), "not strongest first");

        // Spread: cells entirely inside the border with clear texture (grey-level standard
        // deviation ≥ 10) nearly all get a feature.
        let (mut textured, mut hit) = (0, 0);
        for cy in 0..image.height / cell {
            for cx in 0..image.width / cell {
                let inside = cx * cell >= border
                    && cy * cell >= border
                    && (cx + 1) * cell <= image.width - border
                    && (cy + 1) * cell <= image.height - border;
                if inside && cell_contrast(&image, cx, cy, cell) >= 10.0 {
                    textured += 1;
                    hit += usize::from(cells.contains(&(cx, cy)));
                }
            }
        }
        println!("{path}: {} features, {hit}/{textured} textured cells covered", features.len());
        assert!(textured > 50, "{textured} textured cells");
        assert!(hit * 10 >= textured * 6, "{hit} of {textured} textured cells have a feature");

        // Existing points: their cells get nothing, and the budget counts them.
        let existing: Vec<[f32; 2]> = features.iter().step_by(2).map(|k| [k.x + 0.3, k.y - 0.2]).collect();
        let blocked: std::collections::HashSet<_> = existing.iter().map(|p| cell_of(p[0], p[1], cell)).collect();
        let mut refill = Vec::new();
        detector.detect(image.view(), &existing, &mut refill);
        assert!(!refill.is_empty());
        assert!(refill.iter().all(|k| !blocked.contains(&cell_of(k.x, k.y, cell))));
        let limited = FeatureConfig { max_features: existing.len() + 5, ..config.clone() };
        let mut small = FeatureDetector::new(limited, image.width, image.height);
        small.detect(image.view(), &existing, &mut refill);
        assert_eq!(refill.len(), 5);

        // Deterministic: a fresh detector and a reused one give identical output.
        let mut again = Vec::new();
        detector.detect(image.view(), &[], &mut again);
        assert_eq!(again, features);
        assert_eq!(detect(&image, config), features);
    }
}

#[test]
fn default_detector_finds_features_on_low_texture_terrain() {
    // Planetary-like: faint smooth undulations (± 6 grey levels) plus sensor noise.
    let texture = Texture::new(21);
    let mut rng = SplitMix64::new(5);
    let mut image = texture.render(512, 256, |x, y| (x * 1.5, y * 1.5));
    for v in &mut image.data {
        let faint = 128.0 + (f64::from(*v) - 128.0) * 0.4;
        let noise = ((rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 3.0;
        *v = (faint + noise).round().clamp(0.0, 255.0) as u8;
    }
    let features = detect(&image, FeatureConfig::default());
    let cells = (512 - 32) / 32 * ((256 - 32) / 32);
    println!("low texture: {} features over ~{cells} cells", features.len());
    assert!(features.len() * 10 >= cells * 6, "{} features", features.len());
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(64))]
    /// Detection and tracking are total: any image content, size and any point coordinates.
    #[test]
    fn detector_and_tracker_never_panic(
        width in 1usize..48,
        height in 1usize..48,
        seed in any::<u64>(),
        points in proptest::collection::vec((-1e3f32..1e3, -1e3f32..1e3), 0..8),
        special in proptest::sample::select(vec![f32::NAN, f32::INFINITY, -0.0, 1e30]),
    ) {
        let mut rng = SplitMix64::new(seed);
        let data: Vec<u8> = (0..width * height).map(|_| rng.next_u64() as u8).collect();
        let image = Gray { width, height, data };
        let mut detector = FeatureDetector::new(
            FeatureConfig { cell_size_px: 4, border_px: 2, ..Default::default() }, width, height);
        let mut features = Vec::new();
        let mut pts: Vec<[f32; 2]> = points.iter().map(|&(x, y)| [x, y]).collect();
        pts.push([special, 3.0]);
        detector.detect(image.view(), &pts, &mut features);
        let pyramid = pyramid_of(&image, 4);
        let mut tracker = KltTracker::new(KltConfig { window_radius_px: 3, ..Default::default() });
        let mut out = Vec::new();
        let predicted: Vec<[f32; 2]> = pts.iter().map(|p| [p[1], p[0]]).collect();
        tracker.track(&pyramid, &pyramid, &pts, Some(&predicted), &mut out);
        prop_assert_eq!(out.len(), pts.len());
        for p in out.iter().flatten() {
            prop_assert!(p[0] >= 0.0 && p[1] >= 0.0 && p[0] <= (width - 1) as f32 && p[1] <= (height - 1) as f32);
        }
    }
}
