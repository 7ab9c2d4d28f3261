//! Real IMU: EuRoC V1_01 (ADIS16448, 200 Hz, 144 s) against the Vicon ground truth.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use filter::chi2::chi2_quantile;
use filter::{Filter, FilterConfig, ImuNoise, InitialSigmas, StandstillConfig, StandstillDetector, UpdateOutcome};
use hal::asl::AslDataset;
use hal::sensor::ImuSample;
use nalgebra::{Matrix6, Vector3, Vector6};

const DATASET: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/euroc/v1_01_excerpt");
const GRAVITY_ZURICH_MPS2: f64 = 9.8066;

fn load() -> (Vec<ImuSample>, ImuNoise, eval::Trajectory) {
    let ds = AslDataset::open(DATASET).unwrap();
    let imu = ds.imu_samples().to_vec();
    let noise: ImuNoise = ds.imu_noise().unwrap().into();
    let text = std::fs::read_to_string(format!("{DATASET}/groundtruth_from_evo/V101_gt_tum.txt")).unwrap();
    let gt = eval::io::parse_tum(&text).unwrap();
    (imu, noise, gt)
}

/// The densities of `imu0/sensor.yaml` are Kalibr's static values for a sensor on a bench; in
/// flight the ADIS16448 sits on a MAV frame next to four rotors. Their vibration raises the
/// accelerometer's white noise far above the bench value, and the yaml densities are known to be
/// optimistic (VIO systems run on EuRoC with them inflated). With the yaml values (factor 1) the
/// position NEES is 37 and 128 of 144 updates fail the gate; 1.6× (with the gyro scale error
/// below) puts position and orientation NEES inside their bounds.
const NOISE_INFLATION: f64 = 1.6;

/// The ADIS16448's gyro scale and misalignment error ([`FilterConfig::gyro_scale_sigma`]). Without
/// it the orientation NEES is 12.8 (4× its bound): the attitude error after the MAV's turns is
/// 0.2–0.5° while white noise alone predicts 0.1°. With it (0.5 % at 1σ; datasheet ±1 %) the
/// orientation NEES falls inside the bounds; it also explains the filter's position excess
/// that the noise inflation had to cover before (2× then, 1.6× now).
const GYRO_SCALE_SIGMA: f64 = 0.005;

#[test]
fn ground_truth_corrected_filter_is_consistent_on_real_imu() {
    let (imu, noise, gt) = load();
    assert_eq!(imu.len(), 29_120);
    let mut config = FilterConfig::from_imu_noise(noise.scaled(NOISE_INFLATION), GRAVITY_ZURICH_MPS2);
    config.gyro_scale_sigma = GYRO_SCALE_SIGMA;
    config.initial = InitialSigmas {
        position_m: 0.01,
        velocity_mps: 0.02,
        roll_pitch_rad: 0.5_f64.to_radians(),
        yaw_rad: 0.5_f64.to_radians(),
        // ADIS16448 turn-on biases: gyro up to a few °/s (EuRoC's z axis is ~0.08 rad/s), accel
        // up to ~0.2 m/s² after calibration.
        accel_bias_mps2: 0.2,
        gyro_bias_radps: 0.1,
    };
    let mut filter = Filter::new(config);
    let t0 = gt.stamps_s[0];
    let v0 = (gt.poses[1].translation.vector - gt.poses[0].translation.vector) / (gt.stamps_s[1] - t0);
    let t0_ns = (t0 * 1e9).round() as u64;
    filter.initialize_with_pose(t0_ns, &gt.poses[0], &v0).unwrap();
    let update_sigma_m: f64 = 0.01;
    let update_sigma_rad: f64 = 0.5_f64.to_radians();
    let cov = Matrix6::from_diagonal(&Vector6::new(
        update_sigma_m.powi(2),
        update_sigma_m.powi(2),
        update_sigma_m.powi(2),
        update_sigma_rad.powi(2),
        update_sigma_rad.powi(2),
        update_sigma_rad.powi(2),
    ));
    let mut next_update_s = t0 + 1.0;
    let (mut nees_p, mut nees_t) = (Vec::new(), Vec::new());
    let mut bias_log = Vec::new();
    let mut rejected = 0;
    let mut nis_log = Vec::new();
    for sample in imu.iter().filter(|s| s.stamp_ns >= t0_ns) {
        filter.propagate(sample).unwrap();
        let t = sample.stamp_ns as f64 * 1e-9;
        if t < next_update_s {
            continue;
        }
        next_update_s += 1.0;
        let Some(truth) = gt.interpolate(t, 0.1) else { continue };
        let s = filter.state().unwrap();
        let ep = truth.translation.vector - s.t_local_body.translation.vector;
        let et = (truth.rotation * s.t_local_body.rotation.inverse()).scaled_axis();
        let pp = s.covariance.fixed_view::<3, 3>(0, 0).into_owned();
        let pt = s.covariance.fixed_view::<3, 3>(6, 6).into_owned();
        nees_p.push(ep.dot(&(pp.try_inverse().unwrap() * ep)));
        nees_t.push(et.dot(&(pt.try_inverse().unwrap() * et)));
        let outcome = filter.update_pose(&truth, &cov).unwrap();
        match outcome {
            UpdateOutcome::Applied { nis } => nis_log.push(nis),
            _ => rejected += 1,
        }
        let s = filter.state().unwrap();
        let sig = |i: usize| {
            Vector3::new(s.covariance[(i, i)], s.covariance[(i + 1, i + 1)], s.covariance[(i + 2, i + 2)])
                .map(f64::sqrt)
        };
        bias_log.push((t - t0, s.gyro_bias_radps, sig(12), s.accel_bias_mps2, sig(9)));
    }
    let n = nees_p.len();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let lo = chi2_quantile(3 * n as u32, 0.025) / n as f64;
    let hi = chi2_quantile(3 * n as u32, 0.975) / n as f64;
    let median = |v: &[f64]| {
        let mut w = v.to_vec();
        w.sort_by(f64::total_cmp);
        w[w.len() / 2]
    };
    println!(
        "{n} updates; mean NEES position {:.2} (median {:.2}), orientation {:.2} (median {:.2}); 95 % bounds [{lo:.2}, {hi:.2}]",
        mean(&nees_p),
        median(&nees_p),
        mean(&nees_t),
        median(&nees_t)
    );
    for (t, bg, sg, ba, sa) in bias_log.iter().step_by(12) {
        println!(
            "t {t:5.1} s  b_g {:+.4?} ± {:.4?}  b_a {:+.3?} ± {:.3?}",
            bg.as_slice(),
            sg.as_slice(),
            ba.as_slice(),
            sa.as_slice()
        );
    }
    println!(
        "mean NIS {:.2} (6-DoF bounds [{:.2}, {:.2}])",
        mean(&nis_log),
        chi2_quantile(6 * n as u32, 0.025) / n as f64,
        chi2_quantile(6 * n as u32, 0.975) / n as f64
    );
    println!("rejected {rejected} {:?}", filter.health());

    assert_eq!(rejected, 0);
    assert!((lo..=hi).contains(&mean(&nees_p)), "position NEES {}", mean(&nees_p));
    assert!((lo..=hi).contains(&mean(&nees_t)), "orientation NEES {}", mean(&nees_t));
    // The declared 0.5° reference sigma is generous (the innovations' attitude part is smaller),
    // so the NIS lies below its expectation of 6; it must not exceed it.
    assert!(mean(&nis_log) < chi2_quantile(6 * n as u32, 0.975) / n as f64, "NIS {}", mean(&nis_log));

    // Biases settle: their sigmas shrink by an order of magnitude and the estimates stay put over
    // the last minute, within the ADIS16448's plausible range.
    let (_, bg_first, sg_first, _, sa_first) = bias_log[0];
    let (_, bg_mid, _, ba_mid, _) = bias_log[bias_log.len() - 60];
    let (_, bg_end, sg_end, ba_end, sa_end) = *bias_log.last().unwrap();
    assert!(sg_end.max() < 0.1 * sg_first.min() && sa_end.max() < 0.5 * sa_first.min(), "{sg_end} {sa_end}");
    assert!((bg_end - bg_mid).norm() < 1e-3 && (ba_end - ba_mid).norm() < 0.05);
    assert!(bg_end.amax() < 0.15 && ba_end.amax() < 0.5, "{bg_end} {ba_end}");
    assert!((bg_end - bg_first).norm() < 0.01, "the static start already sees the gyro bias");
}

#[test]
fn static_start_stays_put_with_zero_velocity_updates() {
    let (imu, noise, gt) = load();
    // The MAV stands still for the first ~5 s (the ground truth moves < 2 mm); use the first 4 s.
    let t0_ns = imu[0].stamp_ns;
    let end_ns = t0_ns + 4_000_000_000;
    let gt_start = gt.poses[0];
    let gt_end = gt.interpolate(end_ns as f64 * 1e-9, 0.1).unwrap();
    assert!((gt_end.translation.vector - gt_start.translation.vector).norm() < 0.005);

    // The MAV's rotors idle from 0.25 s on while it sits on the ground: the IMU sees vibration of
    // 0.1–1.3 m/s² and up to 0.1 rad/s (std over 0.25 s windows), far above sensor noise. The
    // detector thresholds and the zero-rate sigma are set above that idle vibration (a rover
    // standing with motors off would use `StandstillConfig::from_imu_noise`'s noise-level values).
    let mut config = FilterConfig::from_imu_noise(noise.scaled(NOISE_INFLATION), GRAVITY_ZURICH_MPS2);
    config.zupt_rate_sigma_radps = Some(0.15);
    let detector_config = StandstillConfig {
        gyro_std_max_radps: 0.15,
        accel_std_max_mps2: 2.0,
        ..StandstillConfig::from_imu_noise(&config.imu, 200.0, 3.0)
    };
    let mut detector = StandstillDetector::new(detector_config);
    let window = detector.config().window;
    let first = &imu[..window];
    let mean_accel = first.iter().fold(Vector3::zeros(), |a, s| a + s.accel_mps2) / window as f64;
    let mean_gyro = first.iter().fold(Vector3::zeros(), |a, s| a + s.gyro_radps) / window as f64;
    let mut filter = Filter::new(config);
    filter.initialize_at_rest(first[window - 1].stamp_ns, &mean_accel, &mean_gyro).unwrap();
    let start = filter.state().unwrap().t_local_body;
    let (mut standing, mut total) = (0, 0);
    for s in imu.iter().take_while(|s| s.stamp_ns <= end_ns) {
        detector.push_imu(s);
        if s.stamp_ns <= filter.stamp_ns() {
            continue;
        }
        filter.propagate(s).unwrap();
        total += 1;
        if detector.is_standing() {
            standing += 1;
            filter.update_zero_velocity().unwrap();
        }
    }
    let end = filter.state().unwrap();
    let moved = (end.t_local_body.translation.vector - start.translation.vector).norm();
    let turned = (start.rotation.inverse() * end.t_local_body.rotation).angle().to_degrees();
    let (gyro_std, accel_std) = detector.spreads().unwrap();
    println!(
        "standing {standing}/{total}; moved {:.2} mm, turned {turned:.4}°; spreads gyro {gyro_std:.4} rad/s accel \
         {accel_std:.4} m/s²; zupt {:?}",
        moved * 1e3,
        filter.health().zero_velocity
    );
    assert!(standing as f64 > 0.9 * total as f64, "detector: {standing}/{total}");
    assert!(moved < 0.01, "{moved} m");
    assert!(turned < 0.1, "{turned}°");
    // Idle vibration is not Gaussian; a few ZUPTs out of hundreds fail the 0.999 gate.
    let z = filter.health().zero_velocity;
    assert!(z.rejected as f64 <= 0.01 * z.applied as f64, "{z:?}");

    // Limitation, reported not asserted: thresholds above rotor idle vibration also fire during
    // V1_01's smooth flight (~92 % of 10–30 s), so on a vibrating platform the IMU-only detector
    // needs a second cue (wheel speed on a rover, motor state on a MAV).
    let (mut flying_standing, mut flying) = (0, 0);
    for s in imu.iter().filter(|s| s.stamp_ns > t0_ns + 10_000_000_000 && s.stamp_ns < t0_ns + 30_000_000_000) {
        detector.push_imu(s);
        flying += 1;
        flying_standing += usize::from(detector.is_standing());
    }
    println!("in flight: standing {flying_standing}/{flying}");
}
