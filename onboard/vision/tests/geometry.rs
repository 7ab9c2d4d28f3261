#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Stereo triangulation, P3P, RANSAC + refinement, covariance consistency, the camera-to-body
//! mapping and sparse stereo matching on a real KITTI pair.

use hal::emulator::Xoshiro256StarStar;
use hal::sensor::Pinhole;
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};
use vision::ImageView;
use vision::geometry::{
    Correspondence, PoseEstimationConfig, PoseEstimator, camera_delta_to_body, camera_to_body_jacobian, p3p, refine,
    triangulate,
};
use vision::stereo_match::{SparseStereo, StereoMatchConfig, disparity_from_map};

/// The rovers' narrow stereo set-up (spec §2.5.2, sim `CameraModel::narrow`).
const WIDTH: f64 = 1024.0;
const HEIGHT: f64 = 508.0;
const BASELINE_M: f64 = 0.09;
const PIXEL_SIGMA_PX: f64 = 0.5;

fn rover_intrinsics() -> Pinhole {
    Pinhole { fx_px: 1083.0, fy_px: 1083.0, cx_px: 511.5, cy_px: 253.5 }
}

fn gaussian(rng: &mut Xoshiro256StarStar) -> f64 {
    // Box-Muller; 1 − u keeps the logarithm finite.
    let u = 1.0 - rng.next_f64();
    let v = rng.next_f64();
    (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
}

fn uniform(rng: &mut Xoshiro256StarStar, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.next_f64()
}

fn random_pose(rng: &mut Xoshiro256StarStar, angle_rad: f64, translation_m: f64) -> Isometry3<f64> {
    let axis = Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)).normalize();
    let t = Vector3::new(gaussian(rng), gaussian(rng), gaussian(rng)) * translation_m;
    Isometry3::from_parts(Translation3::from(t), UnitQuaternion::from_scaled_axis(axis * angle_rad * rng.next_f64()))
}

/// `[δt; δθ]` with `truth = estimate ⊕ ξ` in the crate convention.
fn pose_error(estimate: &Isometry3<f64>, truth: &Isometry3<f64>) -> Vector6<f64> {
    let dt = truth.translation.vector - estimate.translation.vector;
    let dtheta = (estimate.rotation.inverse() * truth.rotation).scaled_axis();
    Vector6::new(dt.x, dt.y, dt.z, dtheta.x, dtheta.y, dtheta.z)
}

#[test]
fn triangulation_matches_the_stereo_error_model_and_monte_carlo() {
    let k = rover_intrinsics();
    let disparity_sigma = std::f64::consts::SQRT_2 * PIXEL_SIGMA_PX;
    // Depth part: Δp_z = Δp·√2·Z²/(f·b) (spec §2.5.2, eq. 5.2c); 4 m gives the thesis's 0.116 m.
    let z = 4.0;
    let d = k.fx_px * BASELINE_M / z;
    let (point, cov) = triangulate(&k, BASELINE_M, 700.0, 300.0, d, PIXEL_SIGMA_PX, disparity_sigma).unwrap();
    assert!((point.z - z).abs() < 1e-12);
    let expected_sigma_z = PIXEL_SIGMA_PX * std::f64::consts::SQRT_2 * z * z / (k.fx_px * BASELINE_M);
    assert!((cov[(2, 2)].sqrt() - expected_sigma_z).abs() < 1e-12, "{} vs {expected_sigma_z}", cov[(2, 2)].sqrt());
    assert!((expected_sigma_z - 0.116).abs() < 0.002);
    // Reprojection of the point is the input pixel.
    assert!((k.fx_px * point.x / point.z + k.cx_px - 700.0).abs() < 1e-9);
    assert!((k.fy_px * point.y / point.z + k.cy_px - 300.0).abs() < 1e-9);

    // Monte Carlo at a disparity large enough for first order to hold (Z = 2 m, d ≈ 49 px):
    // the sample covariance agrees with the propagated one within sampling error (~2 % at N = 20000).
    let d = k.fx_px * BASELINE_M / 2.0;
    let (mean_point, cov) = triangulate(&k, BASELINE_M, 800.0, 100.0, d, PIXEL_SIGMA_PX, disparity_sigma).unwrap();
    let mut rng = Xoshiro256StarStar::seed_from_u64(11);
    let n = 20_000;
    let mut sample = nalgebra::Matrix3::zeros();
    for _ in 0..n {
        let (p, _) = triangulate(
            &k,
            BASELINE_M,
            800.0 + PIXEL_SIGMA_PX * gaussian(&mut rng),
            100.0 + PIXEL_SIGMA_PX * gaussian(&mut rng),
            d + disparity_sigma * gaussian(&mut rng),
            PIXEL_SIGMA_PX,
            disparity_sigma,
        )
        .unwrap();
        let e = p - mean_point;
        sample += e * e.transpose();
    }
    sample /= n as f64;
    for i in 0..3 {
        let ratio = sample[(i, i)] / cov[(i, i)];
        assert!((ratio - 1.0).abs() < 0.05, "axis {i}: sample/propagated variance {ratio}");
    }
    assert!(triangulate(&k, BASELINE_M, 1.0, 1.0, 0.0, 0.5, 0.7).is_none());
    assert!(triangulate(&k, BASELINE_M, 1.0, 1.0, -2.0, 0.5, 0.7).is_none());
    assert!(triangulate(&k, BASELINE_M, f64::NAN, 1.0, 2.0, 0.5, 0.7).is_none());
}

#[test]
fn p3p_returns_the_true_pose_among_its_solutions() {
    let k = rover_intrinsics();
    let mut rng = Xoshiro256StarStar::seed_from_u64(3);
    let trials = 2000;
    let mut worst = 0.0f64;
    let mut solutions = [Isometry3::identity(); 4];
    for _ in 0..trials {
        let t_camera_world = random_pose(&mut rng, std::f64::consts::PI, 5.0);
        let mut points_world = [Vector3::zeros(); 3];
        let mut bearings = [Vector3::zeros(); 3];
        for i in 0..3 {
            let pixel = [uniform(&mut rng, 0.0, WIDTH), uniform(&mut rng, 0.0, HEIGHT)];
            let ray = Vector3::new((pixel[0] - k.cx_px) / k.fx_px, (pixel[1] - k.cy_px) / k.fy_px, 1.0);
            let point_camera = ray * uniform(&mut rng, 1.0, 30.0);
            bearings[i] = point_camera.normalize();
            points_world[i] = t_camera_world.inverse_transform_point(&point_camera.into()).coords;
        }
        let count = p3p::solve(&points_world, &bearings, &mut solutions);
        assert!(count <= 4);
        let best = solutions[..count]
            .iter()
            .map(|s| {
                let e = pose_error(s, &t_camera_world);
                e.fixed_rows::<3>(0).norm().max(e.fixed_rows::<3>(3).norm())
            })
            .fold(f64::INFINITY, f64::min);
        worst = worst.max(best);
    }
    eprintln!("P3P over {trials} random configurations: worst error of the best solution {worst:.2e}");
    assert!(worst < 1e-6, "worst {worst}");
}

/// A keyframe scene on the rover set-up: landmarks 2–30 m in front of the keyframe camera, seen
/// in the keyframe through stereo (noisy pixel + disparity, triangulated) and in the current image
/// (noisy pixel). `outlier_fraction` of the current pixels are replaced by random pixels.
struct Scene {
    truth: Isometry3<f64>,
    correspondences: Vec<Correspondence>,
    outlier: Vec<bool>,
}

fn make_scene(rng: &mut Xoshiro256StarStar, truth: &Isometry3<f64>, points: usize, outlier_fraction: f64) -> Scene {
    let k = rover_intrinsics();
    let disparity_sigma = std::f64::consts::SQRT_2 * PIXEL_SIGMA_PX;
    let mut correspondences = Vec::with_capacity(points);
    let mut outlier = Vec::with_capacity(points);
    while correspondences.len() < points {
        let (x, y) = (uniform(rng, 0.0, WIDTH - 1.0), uniform(rng, 0.0, HEIGHT - 1.0));
        let z = uniform(rng, 2.0, 30.0);
        let point = Vector3::new((x - k.cx_px) / k.fx_px * z, (y - k.cy_px) / k.fy_px * z, z);
        let pc = truth.inverse_transform_point(&point.into());
        if pc.z < 0.5 {
            continue;
        }
        let pixel = [k.fx_px * pc.x / pc.z + k.cx_px, k.fy_px * pc.y / pc.z + k.cy_px];
        if !(0.0..WIDTH).contains(&pixel[0]) || !(0.0..HEIGHT).contains(&pixel[1]) {
            continue;
        }
        let d = k.fx_px * BASELINE_M / z + disparity_sigma * gaussian(rng);
        let Some((point_keyframe_m, point_covariance_m2)) = triangulate(
            &k,
            BASELINE_M,
            x + PIXEL_SIGMA_PX * gaussian(rng),
            y + PIXEL_SIGMA_PX * gaussian(rng),
            d,
            PIXEL_SIGMA_PX,
            disparity_sigma,
        ) else {
            continue;
        };
        let is_outlier = rng.next_f64() < outlier_fraction;
        let pixel_current = if is_outlier {
            [uniform(rng, 0.0, WIDTH), uniform(rng, 0.0, HEIGHT)]
        } else {
            [pixel[0] + PIXEL_SIGMA_PX * gaussian(rng), pixel[1] + PIXEL_SIGMA_PX * gaussian(rng)]
        };
        correspondences.push(Correspondence { point_keyframe_m, point_covariance_m2, pixel_current });
        outlier.push(is_outlier);
    }
    Scene { truth: *truth, correspondences, outlier }
}

/// A typical keyframe-to-frame motion of a rover: 0.5 m mostly forward, a few degrees of turn.
fn rover_motion() -> Isometry3<f64> {
    Isometry3::from_parts(Translation3::new(0.08, -0.03, 0.5), UnitQuaternion::from_euler_angles(0.01, 0.05, -0.02))
}

#[test]
fn ransac_and_refinement_recover_the_pose_with_outliers() {
    let k = rover_intrinsics();
    let mut rng = Xoshiro256StarStar::seed_from_u64(21);
    let mut estimator = PoseEstimator::new(PoseEstimationConfig::default());
    let mut mask = Vec::new();
    let mut worst_t = 0.0f64;
    let mut worst_r = 0.0f64;
    let mut slowest = 0.0f64;
    let mut total_s = 0.0f64;
    for _ in 0..20 {
        let scene = make_scene(&mut rng, &rover_motion(), 300, 0.3);
        let start = std::time::Instant::now();
        let estimate = estimator.estimate(&k, &scene.correspondences, None, &mut mask).unwrap();
        slowest = slowest.max(start.elapsed().as_secs_f64());
        total_s += start.elapsed().as_secs_f64();
        let e = pose_error(&estimate.t_keyframe_current_cam, &scene.truth);
        worst_t = worst_t.max(e.fixed_rows::<3>(0).norm());
        worst_r = worst_r.max(e.fixed_rows::<3>(3).norm().to_degrees());
        // Every accepted outlier must be consistent with the pose by chance; none may be in
        // numbers, and nearly every inlier must be kept.
        let false_inliers = mask.iter().zip(&scene.outlier).filter(|(m, o)| **m && **o).count();
        let kept = mask.iter().zip(&scene.outlier).filter(|(m, o)| **m && !**o).count();
        let inliers_total = scene.outlier.iter().filter(|o| !**o).count();
        assert!(false_inliers <= 3, "{false_inliers} outliers accepted");
        assert!(kept as f64 >= 0.97 * inliers_total as f64, "kept {kept} of {inliers_total}");

        // Same input and seed, same output; the prior does not spoil it.
        let again = estimator.estimate(&k, &scene.correspondences, None, &mut mask).unwrap();
        assert_eq!(again, estimate);
        let with_prior =
            estimator.estimate(&k, &scene.correspondences, Some(&Isometry3::identity()), &mut mask).unwrap();
        let e_prior = pose_error(&with_prior.t_keyframe_current_cam, &scene.truth);
        assert!(e_prior.fixed_rows::<3>(0).norm() < 0.01);
    }
    eprintln!(
        "RANSAC + refinement, 20 scenes, 30 % outliers: worst {worst_t:.4} m, {worst_r:.4} deg; \
         estimate mean {:.2} ms, slowest {:.2} ms",
        total_s * 1e3 / 20.0,
        slowest * 1e3
    );
    assert!(worst_t < 0.01, "translation error {worst_t} m");
    assert!(worst_r < 0.1, "rotation error {worst_r} deg");
}

#[test]
fn estimator_rejects_too_little_data() {
    let k = rover_intrinsics();
    let mut rng = Xoshiro256StarStar::seed_from_u64(5);
    let mut estimator = PoseEstimator::new(PoseEstimationConfig::default());
    let mut mask = Vec::new();
    let scene = make_scene(&mut rng, &rover_motion(), 8, 0.0);
    assert!(estimator.estimate(&k, &scene.correspondences, None, &mut mask).is_err());
    assert_eq!(mask.len(), 8);
    // Pure noise: no consensus of 12.
    let scene = make_scene(&mut rng, &rover_motion(), 100, 1.0);
    assert!(estimator.estimate(&k, &scene.correspondences, None, &mut mask).is_err());
}

#[test]
fn estimator_survives_non_finite_and_behind_camera_inputs() {
    let k = rover_intrinsics();
    let mut rng = Xoshiro256StarStar::seed_from_u64(31);
    let mut scene = make_scene(&mut rng, &rover_motion(), 200, 0.1);
    let corrupt = [0usize, 7, 19, 33, 50, 81];
    scene.correspondences[0].pixel_current[0] = f64::NAN;
    scene.correspondences[7].point_keyframe_m.z = f64::INFINITY;
    scene.correspondences[19].point_covariance_m2[(2, 2)] = f64::NAN;
    scene.correspondences[33].point_keyframe_m.z = -5.0;
    scene.correspondences[50].point_covariance_m2 = nalgebra::Matrix3::zeros();
    scene.correspondences[81].pixel_current[1] = f64::NEG_INFINITY;
    let mut estimator = PoseEstimator::new(PoseEstimationConfig::default());
    let mut mask = Vec::new();
    let estimate = estimator.estimate(&k, &scene.correspondences, None, &mut mask).unwrap();
    let e = pose_error(&estimate.t_keyframe_current_cam, &scene.truth);
    assert!(e.fixed_rows::<3>(0).norm() < 0.01 && e.fixed_rows::<3>(3).norm().to_degrees() < 0.1, "{e:?}");
    // A landmark without covariance is a valid (exact) landmark; the broken ones are outliers.
    for i in corrupt.iter().filter(|&&i| i != 50) {
        assert!(!mask[*i], "corrupted correspondence {i} accepted");
    }
    assert!(estimate.covariance.iter().all(|v| v.is_finite()));
}

/// Bounds of the mean of `n` draws of chi²(dof) at 95 % (Wilson-Hilferty).
fn chi2_mean_bounds(dof: usize, n: usize) -> (f64, f64) {
    let k = (dof * n) as f64;
    let quantile = |z: f64| k * (1.0 - 2.0 / (9.0 * k) + z * (2.0 / (9.0 * k)).sqrt()).powi(3) / n as f64;
    (quantile(-1.959_964), quantile(1.959_964))
}

#[test]
fn pose_covariance_is_consistent() {
    let k = rover_intrinsics();
    let mut rng = Xoshiro256StarStar::seed_from_u64(99);
    let mut estimator = PoseEstimator::new(PoseEstimationConfig::default());
    let mut mask = Vec::new();
    let draws = 500;
    let truth = rover_motion();
    let mut nees_sum = 0.0;
    for _ in 0..draws {
        let scene = make_scene(&mut rng, &truth, 300, 0.0);
        let estimate = estimator.estimate(&k, &scene.correspondences, None, &mut mask).unwrap();
        let e = pose_error(&estimate.t_keyframe_current_cam, &truth);
        let information = estimate.covariance.try_inverse().unwrap();
        nees_sum += e.dot(&(information * e));
    }
    let mean = nees_sum / draws as f64;
    let (lo, hi) = chi2_mean_bounds(6, draws);
    eprintln!("pose NEES over {draws} draws: {mean:.3} (95 % bounds {lo:.3} .. {hi:.3})");
    assert!(mean > lo && mean < hi, "NEES {mean} outside [{lo}, {hi}]");
}

#[test]
fn reprojection_jacobian_matches_numeric() {
    let k = rover_intrinsics();
    let mut rng = Xoshiro256StarStar::seed_from_u64(8);
    let scene = make_scene(&mut rng, &rover_motion(), 50, 0.0);
    let pose = scene.truth;
    let h = 1e-6;
    for c in &scene.correspondences {
        let lin = refine::linearize(&k, &pose, c, PIXEL_SIGMA_PX).unwrap();
        for i in 0..6 {
            let mut delta = Vector6::zeros();
            delta[i] = h;
            let plus = refine::linearize(&k, &refine::retract(&pose, &delta), c, PIXEL_SIGMA_PX).unwrap();
            let minus = refine::linearize(&k, &refine::retract(&pose, &(-delta)), c, PIXEL_SIGMA_PX).unwrap();
            // residual = observed − predicted, so ∂predicted = −∂residual.
            let numeric = -(plus.residual - minus.residual) / (2.0 * h);
            let analytic = lin.jacobian.column(i);
            let scale = analytic.norm().max(1.0);
            assert!((numeric - analytic).norm() / scale < 1e-6, "column {i}: {numeric:?} vs {analytic:?}");
        }
    }
}

#[test]
fn joint_observation_jacobians_match_numeric() {
    // The joint refinement's observation in inverse-depth landmark coordinates λ = (X/Z, Y/Z, 1/Z).
    let k = rover_intrinsics();
    let mut rng = Xoshiro256StarStar::seed_from_u64(9);
    let pose = rover_motion();
    let h = 1e-7;
    for _ in 0..50 {
        let z = uniform(&mut rng, 2.0, 30.0);
        let landmark = Vector3::new(uniform(&mut rng, -0.4, 0.4), uniform(&mut rng, -0.2, 0.2), 1.0 / z);
        let pixel = [uniform(&mut rng, 0.0, WIDTH), uniform(&mut rng, 0.0, HEIGHT)];
        let eval = |pose: &Isometry3<f64>, landmark: &Vector3<f64>| {
            let rotation_t = pose.rotation.to_rotation_matrix().into_inner().transpose();
            refine::observe(&k, &rotation_t, &pose.translation.vector, landmark, pixel).unwrap()
        };
        let (_, j_pose, j_landmark) = eval(&pose, &landmark);
        for i in 0..6 {
            let mut delta = Vector6::zeros();
            delta[i] = h;
            let numeric = -(eval(&refine::retract(&pose, &delta), &landmark).0
                - eval(&refine::retract(&pose, &(-delta)), &landmark).0)
                / (2.0 * h);
            let scale = j_pose.column(i).norm().max(1.0);
            assert!((numeric - j_pose.column(i)).norm() / scale < 1e-6, "pose column {i}");
        }
        for i in 0..3 {
            let mut delta = Vector3::zeros();
            delta[i] = h * 1e-2;
            let numeric = -(eval(&pose, &(landmark + delta)).0 - eval(&pose, &(landmark - delta)).0) / (2.0 * h * 1e-2);
            let scale = j_landmark.column(i).norm().max(1.0);
            assert!((numeric - j_landmark.column(i)).norm() / scale < 1e-5, "landmark column {i}");
        }
    }
}

#[test]
fn camera_delta_to_body_maps_pose_and_covariance() {
    let mut rng = Xoshiro256StarStar::seed_from_u64(17);
    for _ in 0..50 {
        let t_kc_cc = random_pose(&mut rng, 0.5, 1.0);
        // Different head angles at the two capture times.
        let t_body_cam_k = random_pose(&mut rng, std::f64::consts::PI, 0.8);
        let t_body_cam_c = random_pose(&mut rng, std::f64::consts::PI, 0.8);

        // Pose identity through a world frame: both bodies and cameras placed in the world.
        let t_world_kb = random_pose(&mut rng, 1.0, 10.0);
        let t_world_cb = random_pose(&mut rng, 1.0, 10.0);
        let t_world_kc = t_world_kb * t_body_cam_k;
        let t_world_cc = t_world_cb * t_body_cam_c;
        let t_kc_cc_world = t_world_kc.inverse() * t_world_cc;
        let (body, _) = camera_delta_to_body(&t_kc_cc_world, &Matrix6::identity(), &t_body_cam_k, &t_body_cam_c);
        let e = pose_error(&body, &(t_world_kb.inverse() * t_world_cb));
        assert!(e.norm() < 1e-12, "pose identity off by {}", e.norm());

        // Jacobian against central differences of the body pose under camera perturbations.
        let jacobian = camera_to_body_jacobian(&t_kc_cc, &t_body_cam_k, &t_body_cam_c);
        let (body, _) = camera_delta_to_body(&t_kc_cc, &Matrix6::identity(), &t_body_cam_k, &t_body_cam_c);
        let h = 1e-6;
        for i in 0..6 {
            let mut delta = Vector6::zeros();
            delta[i] = h;
            let (plus, _) = camera_delta_to_body(
                &refine::retract(&t_kc_cc, &delta),
                &Matrix6::identity(),
                &t_body_cam_k,
                &t_body_cam_c,
            );
            let (minus, _) = camera_delta_to_body(
                &refine::retract(&t_kc_cc, &(-delta)),
                &Matrix6::identity(),
                &t_body_cam_k,
                &t_body_cam_c,
            );
            let numeric = (pose_error(&body, &plus) - pose_error(&body, &minus)) / (2.0 * h);
            let analytic = jacobian.column(i);
            let relative = (numeric - analytic).norm() / analytic.norm();
            assert!(relative < 1e-6, "column {i}: relative error {relative}");
        }

        // The covariance is the Jacobian sandwich; identity mounts leave everything unchanged.
        let a = Matrix6::from_fn(|r, c| ((r * 7 + c * 3) % 5) as f64 * 0.01);
        let cov = a * a.transpose() + Matrix6::identity() * 1e-4;
        let (_, cov_body) = camera_delta_to_body(&t_kc_cc, &cov, &t_body_cam_k, &t_body_cam_c);
        assert!((cov_body - jacobian * cov * jacobian.transpose()).norm() < 1e-12);
        let (same, cov_same) = camera_delta_to_body(&t_kc_cc, &cov, &Isometry3::identity(), &Isometry3::identity());
        assert!(pose_error(&same, &t_kc_cc).norm() < 1e-12);
        assert!((cov_same - cov).norm() < 1e-15);
    }
}

fn kitti_path(file: &str) -> String {
    format!("{}/../../data/stereo_sequences/kitti_straight/{file}", env!("CARGO_MANIFEST_DIR"))
}

fn load_gray(path: &str) -> (usize, usize, Vec<u8>) {
    let bytes = std::fs::read(path).unwrap();
    let mut decoder = png::Decoder::new(std::io::Cursor::new(bytes.as_slice()));
    decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
    let mut reader = decoder.read_info().unwrap();
    let (color, depth) = reader.output_color_type();
    assert_eq!((color, depth), (png::ColorType::Grayscale, png::BitDepth::Eight));
    let mut data = vec![0u8; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut data).unwrap();
    (info.width as usize, info.height as usize, data)
}

/// Smaller eigenvalue of the 7×7 structure tensor (Shi-Tomasi), grey levels² per pixel.
fn min_eigenvalue(image: ImageView<'_>, x: usize, y: usize) -> f64 {
    let (mut gxx, mut gyy, mut gxy) = (0.0, 0.0, 0.0);
    for yy in y - 3..=y + 3 {
        for xx in x - 3..=x + 3 {
            let gx = (f64::from(image.get(xx + 1, yy)) - f64::from(image.get(xx - 1, yy))) * 0.5;
            let gy = (f64::from(image.get(xx, yy + 1)) - f64::from(image.get(xx, yy - 1))) * 0.5;
            gxx += gx * gx;
            gyy += gy * gy;
            gxy += gx * gy;
        }
    }
    let (gxx, gyy, gxy) = (gxx / 49.0, gyy / 49.0, gxy / 49.0);
    0.5 * (gxx + gyy - ((gxx - gyy).powi(2) + 4.0 * gxy * gxy).sqrt())
}

#[test]
fn sparse_stereo_agrees_with_sgm_on_kitti() {
    let (width, height, left_data) = load_gray(&kitti_path("image_l/000000.png"));
    let (w2, h2, right_data) = load_gray(&kitti_path("image_r/000000.png"));
    assert_eq!((width, height), (w2, h2));
    let left = ImageView::new(width, height, &left_data).unwrap();
    let right = ImageView::new(width, height, &right_data).unwrap();

    let mut matcher = fpga_model::fast::Matcher::new(fpga_model::SgmConfig::default(), width, height, 2).unwrap();
    let gray_l = fpga_model::GrayImage::new(width, height, left_data.clone()).unwrap();
    let gray_r = fpga_model::GrayImage::new(width, height, right_data.clone()).unwrap();
    let mut sgm = fpga_model::DisparityImage { width, height, data: vec![0; width * height] };
    matcher.compute_into(&gray_l, &gray_r, &mut sgm).unwrap();

    // Textured points: the strongest Shi-Tomasi corner of each 24 px cell, if strong enough,
    // offset to a sub-pixel position so both the matcher and the map lookup interpolate.
    let cell = 24;
    let mut points = Vec::new();
    for cy in (16..height - 16 - cell).step_by(cell) {
        for cx in (16..width - 16 - cell).step_by(cell) {
            let (mut best, mut best_xy) = (0.0, (0, 0));
            for y in cy..cy + cell {
                for x in cx..cx + cell {
                    let s = min_eigenvalue(left, x, y);
                    if s > best {
                        best = s;
                        best_xy = (x, y);
                    }
                }
            }
            if best > 20.0 {
                points.push([best_xy.0 as f32 + 0.25, best_xy.1 as f32 + 0.5]);
            }
        }
    }
    assert!(points.len() > 200, "{} textured points", points.len());

    let mut stereo = SparseStereo::new(StereoMatchConfig::default());
    let start = std::time::Instant::now();
    let sparse: Vec<Option<f32>> = points.iter().map(|p| stereo.match_point(left, right, p[0], p[1])).collect();
    let elapsed = start.elapsed();
    let matched = sparse.iter().filter(|d| d.is_some()).count();
    let mut differences: Vec<f32> = points
        .iter()
        .zip(&sparse)
        .filter_map(|(p, d)| Some((d.as_ref()? - disparity_from_map(&sgm, p[0], p[1])?).abs()))
        .collect();
    differences.sort_by(f32::total_cmp);
    let median = differences[differences.len() / 2];
    let gross = differences.iter().filter(|d| **d > 3.0).count();
    eprintln!(
        "KITTI 000000: {} textured points, {matched} matched ({:.1} %), {} also in SGM, median |Δd| {median:.3} px, \
         {gross} differ > 3 px; {:.2} ms ({:.1} µs/point)",
        points.len(),
        100.0 * matched as f64 / points.len() as f64,
        differences.len(),
        elapsed.as_secs_f64() * 1e3,
        elapsed.as_secs_f64() * 1e6 / points.len() as f64
    );
    assert!(matched as f64 >= 0.7 * points.len() as f64, "{matched} of {}", points.len());
    assert!(differences.len() as f64 >= 0.5 * points.len() as f64);
    assert!(median < 0.5, "median {median}");
    assert!((gross as f64) < 0.05 * differences.len() as f64, "{gross} gross disagreements");
}

#[test]
fn sparse_stereo_finds_a_synthetic_shift() {
    // A random texture shifted by a known sub-pixel disparity (linear interpolation): the matcher
    // recovers it within the interpolation's bias.
    let (width, height) = (200usize, 60usize);
    let mut rng = Xoshiro256StarStar::seed_from_u64(4);
    let coarse: Vec<f64> = (0..(width / 4 + 2) * (height / 4 + 2)).map(|_| rng.next_f64() * 255.0).collect();
    let texture = |x: f64, y: f64| -> f64 {
        // Bilinear upsampling of a coarse random field: smooth enough for sub-pixel matching.
        let (gx, gy) = (x / 4.0, y / 4.0);
        let (x0, y0) = (gx.floor() as usize, gy.floor() as usize);
        let (fx, fy) = (gx - x0 as f64, gy - y0 as f64);
        let stride = width / 4 + 2;
        let at = |i: usize, j: usize| coarse[j * stride + i];
        (1.0 - fx) * (1.0 - fy) * at(x0, y0)
            + fx * (1.0 - fy) * at(x0 + 1, y0)
            + (1.0 - fx) * fy * at(x0, y0 + 1)
            + fx * fy * at(x0 + 1, y0 + 1)
    };
    let true_disparity = 17.3;
    let left: Vec<u8> =
        (0..width * height).map(|i| texture((i % width) as f64 + 20.0, (i / width) as f64) as u8).collect();
    let right: Vec<u8> = (0..width * height)
        .map(|i| texture((i % width) as f64 + 20.0 + true_disparity, (i / width) as f64) as u8)
        .collect();
    let l = ImageView::new(width, height, &left).unwrap();
    let r = ImageView::new(width, height, &right).unwrap();
    let mut stereo = SparseStereo::new(StereoMatchConfig { max_disparity_px: 40.0, ..StereoMatchConfig::default() });
    let mut errors = Vec::new();
    for y in (10..50).step_by(5) {
        for x in (60..190).step_by(7) {
            if let Some(d) = stereo.match_point(l, r, x as f32 + 0.4, y as f32) {
                errors.push((f64::from(d) - true_disparity).abs());
            }
        }
    }
    assert!(errors.len() > 100, "{} matches", errors.len());
    let max = errors.iter().copied().fold(0.0, f64::max);
    assert!(max < 0.35, "max error {max}");
}

#[test]
fn disparity_from_map_interpolates_only_consistent_neighbours() {
    let invalid = fpga_model::INVALID;
    // 16 = 1 px. Row 0: 10 px, 10.5 px, 30 px (depth edge); row 1: 10 px, invalid, 30 px.
    let map = fpga_model::DisparityImage { width: 3, height: 2, data: vec![160, 168, 480, 160, invalid, 480] };
    assert_eq!(disparity_from_map(&map, 0.0, 0.0), Some(10.0));
    // Weights 0.4 (10 px), 0.4 (10.5 px), 0.1 (10 px), 0.1 (invalid): (4 + 4.2 + 1) / 0.9.
    let d = disparity_from_map(&map, 0.5, 0.2).unwrap();
    assert!((d - 9.2 / 0.9).abs() < 1e-5, "{d}");
    // Nearest is 10.5 px; the 30 px neighbour across the edge is ignored.
    assert_eq!(disparity_from_map(&map, 1.4, 0.0), Some(10.5));
    // Nearest pixel invalid.
    assert_eq!(disparity_from_map(&map, 1.0, 1.0), None);
    assert_eq!(disparity_from_map(&map, -0.1, 0.0), None);
    assert_eq!(disparity_from_map(&map, 2.1, 0.0), None);
    assert_eq!(disparity_from_map(&map, f32::NAN, 0.0), None);
}

mod totality {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig { cases: 200, failure_persistence: None, ..ProptestConfig::default() })]
        #[test]
        fn matching_and_lookup_never_panic(
            width in 1usize..40, height in 1usize..20, seed in any::<u64>(),
            x in prop_oneof![-50.0f32..90.0, Just(f32::NAN), Just(f32::INFINITY), Just(-0.0f32)],
            y in prop_oneof![-50.0f32..90.0, Just(f32::NAN), Just(f32::NEG_INFINITY)],
            radius in 0usize..6, max_d in prop_oneof![-5.0f32..200.0, Just(f32::NAN)],
        ) {
            let mut rng = Xoshiro256StarStar::seed_from_u64(seed);
            let left: Vec<u8> = (0..width * height).map(|_| rng.next_u64() as u8).collect();
            let right: Vec<u8> = (0..width * height).map(|_| rng.next_u64() as u8).collect();
            let config = StereoMatchConfig { window_radius_px: radius, max_disparity_px: max_d, ..StereoMatchConfig::default() };
            let mut stereo = SparseStereo::new(config);
            let l = ImageView::new(width, height, &left).unwrap();
            let r = ImageView::new(width, height, &right).unwrap();
            if let Some(d) = stereo.match_point(l, r, x, y) {
                prop_assert!(d.is_finite());
            }
            let map = fpga_model::DisparityImage {
                width, height, data: (0..width * height).map(|_| rng.next_u64() as u16).collect(),
            };
            if let Some(d) = disparity_from_map(&map, x, y) {
                prop_assert!(d.is_finite() && d >= 0.0);
            }
        }
    }

    fn any_f64() -> impl Strategy<Value = f64> {
        prop_oneof![8 => -50.0f64..50.0, 1 => Just(f64::NAN), 1 => Just(f64::INFINITY), 1 => Just(0.0)]
    }

    proptest! {
        #![proptest_config(ProptestConfig { cases: 64, failure_persistence: None, ..ProptestConfig::default() })]
        #[test]
        fn estimator_never_panics(values in proptest::collection::vec(any_f64(), 0..(14 * 40)), prior in any::<bool>()) {
            let k = rover_intrinsics();
            let correspondences: Vec<Correspondence> = values
                .chunks_exact(14)
                .map(|v| Correspondence {
                    point_keyframe_m: Vector3::new(v[0], v[1], v[2]),
                    point_covariance_m2: nalgebra::Matrix3::from_fn(|r, c| v[3 + (r * 3 + c).min(8)] * 1e-3),
                    pixel_current: [v[12] * 20.0 + 500.0, v[13] * 10.0 + 250.0],
                })
                .collect();
            let mut estimator = PoseEstimator::new(PoseEstimationConfig::default());
            let mut mask = Vec::new();
            let prior = prior.then(Isometry3::identity);
            if let Ok(estimate) = estimator.estimate(&k, &correspondences, prior.as_ref(), &mut mask) {
                prop_assert!(estimate.covariance.iter().all(|v| v.is_finite()));
                prop_assert!(estimate.inliers as usize >= 12);
            }
            prop_assert_eq!(mask.len(), correspondences.len());
        }
    }
}
