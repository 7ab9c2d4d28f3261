//! `onboard vio --dataset DIR [--out EST.tum] [--gt GT] [--json] [...]`
//!
//! Runs the VIO pipeline ([`onboard::vio`]) on a recorded dataset, writes the body trajectory in
//! TUM format and prints a summary; with `--gt` it also scores the estimate (ATE after SE(3)
//! alignment, final drift in % of the ground-truth path). Exit codes: 0 success, 1 runtime error
//! (unreadable dataset or ground truth, garbled calibration, ...), 2 usage error.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;

use filter::FilterConfig;
use nalgebra::Vector3;
use onboard::vio::score::{estimate_trajectory, max_displacement_m};
use onboard::vio::{
    Score, SwitchPolicy, VioOptions, VioPipeline, VioSummary, VoUpdates, load_ground_truth, open_dataset, score,
};

const USAGE: &str = "usage: onboard vio --dataset DIR [--out EST.tum] [--gt GT] [--json] [options]

  --dataset DIR          EuRoC/ASL (mav0/ or a folder with cam0/, cam1/, optional imu0/, wheel0/)
                         or KITTI odometry (image_l/ + image_r/ or image_0/ + image_1/, calib.txt,
                         optional times.txt)
  --out FILE             write the body trajectory (TUM: t x y z qx qy qz qw; IMU rate with IMU,
                         one pose per frame without)
  --gt FILE              score against ground truth (TUM, KITTI poses.txt or EuRoC CSV)
  --json                 print one JSON object instead of text
  --sgm                  depth from the SGM disparity map instead of sparse stereo matching
  --sgm-threads N        SGM worker threads (default 1)
  --latency-ms MS        VO result latency in sensor time (default 250)
  --no-imu               stereo odometry alone even when the dataset has IMU data
  --no-wheel             ignore wheel odometry
  --no-zupt              no zero-velocity updates
  --no-prior             do not seed the odometry with the filter's motion prediction
  --vo-keyframes         fuse only keyframe-to-keyframe deltas (default: every frame's delta)
  --switch-distance M    frame-of-reference switch every M metres (thesis: 7)
  --switch-sigma M       ... or when the position sigma reaches M metres (thesis: 0.2)
  --gravity MPS2         gravity at the site (default 9.80665)
  --gyro-scale-sigma S   relative gyro scale/misalignment error the filter assumes (default
                         0.005, EuRoC's ADIS16448; 0 for the simulator's ideal-scale gyro)
  --all-imu              also integrate IMU data after the last image (default: stop there)";

#[derive(Debug)]
struct Options {
    dataset: PathBuf,
    output: Option<PathBuf>,
    gt: Option<PathBuf>,
    json: bool,
    sgm: bool,
    sgm_threads: usize,
    latency_ms: f64,
    no_imu: bool,
    no_wheel: bool,
    no_zupt: bool,
    no_prior: bool,
    vo_keyframes: bool,
    switch: SwitchPolicy,
    gravity_mps2: f64,
    gyro_scale_sigma: f64,
    all_imu: bool,
}

fn positive(name: &str, value: &str) -> Result<f64, String> {
    match value.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        _ => Err(format!("{name}: expected a positive number, got {value:?}")),
    }
}

fn string_value(parser: &mut lexopt::Parser, name: &str) -> Result<String, String> {
    let value = parser.value().map_err(|e| e.to_string())?;
    value.into_string().map_err(|v| format!("{name}: not UTF-8: {v:?}"))
}

fn parse_args(args: Vec<OsString>) -> Result<Option<Options>, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let mut options = Options {
        dataset: PathBuf::new(),
        output: None,
        gt: None,
        json: false,
        sgm: false,
        sgm_threads: 1,
        latency_ms: 250.0,
        no_imu: false,
        no_wheel: false,
        no_zupt: false,
        no_prior: false,
        vo_keyframes: false,
        switch: SwitchPolicy::default(),
        gravity_mps2: onboard::vio::EARTH_GRAVITY_MPS2,
        gyro_scale_sigma: onboard::vio::EUROC_GYRO_SCALE_SIGMA,
        all_imu: false,
    };
    let mut dataset = None;
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("dataset") => dataset = Some(PathBuf::from(string_value(&mut parser, "--dataset")?)),
            Long("out") => options.output = Some(PathBuf::from(string_value(&mut parser, "--out")?)),
            Long("gt") => options.gt = Some(PathBuf::from(string_value(&mut parser, "--gt")?)),
            Long("json") => options.json = true,
            Long("sgm") => options.sgm = true,
            Long("sgm-threads") => {
                let text = string_value(&mut parser, "--sgm-threads")?;
                options.sgm_threads = match text.parse::<usize>() {
                    Ok(n) if (1..=64).contains(&n) => n,
                    _ => return Err(format!("--sgm-threads: expected 1..64, got {text:?}")),
                };
            }
            Long("latency-ms") => {
                let text = string_value(&mut parser, "--latency-ms")?;
                options.latency_ms = match text.parse::<f64>() {
                    Ok(v) if v.is_finite() && (0.0..=10_000.0).contains(&v) => v,
                    _ => return Err(format!("--latency-ms: expected 0..10000, got {text:?}")),
                };
            }
            Long("no-imu") => options.no_imu = true,
            Long("no-wheel") => options.no_wheel = true,
            Long("no-zupt") => options.no_zupt = true,
            Long("no-prior") => options.no_prior = true,
            Long("vo-keyframes") => options.vo_keyframes = true,
            Long("switch-distance") => {
                options.switch.distance_m =
                    Some(positive("--switch-distance", &string_value(&mut parser, "--switch-distance")?)?);
            }
            Long("switch-sigma") => {
                options.switch.sigma_m =
                    Some(positive("--switch-sigma", &string_value(&mut parser, "--switch-sigma")?)?)
            }
            Long("gyro-scale-sigma") => {
                let value = string_value(&mut parser, "--gyro-scale-sigma")?;
                options.gyro_scale_sigma = value
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v >= 0.0)
                    .ok_or_else(|| format!("--gyro-scale-sigma: not a non-negative number: {value}"))?;
            }
            Long("gravity") => options.gravity_mps2 = positive("--gravity", &string_value(&mut parser, "--gravity")?)?,
            Long("all-imu") => options.all_imu = true,
            Short('h') | Long("help") => return Ok(None),
            other => return Err(other.unexpected().to_string()),
        }
    }
    options.dataset = dataset.ok_or("--dataset is required")?;
    Ok(Some(options))
}

/// What a run produced.
struct Report {
    layout: &'static str,
    mode: &'static str,
    poses: usize,
    summary: VioSummary,
    max_displacement_m: f64,
    score: Option<Score>,
}

fn run(options: &Options) -> Result<Report, String> {
    let mut dataset = open_dataset(&options.dataset).map_err(|e| e.to_string())?;
    let use_imu = !options.no_imu && dataset.imu_samples > 0;
    let latency_ns = (options.latency_ms * 1e6).round() as u64;
    let last_image_ns = dataset.image_stamps_ns.last().copied().unwrap_or(0);
    let vio_options = VioOptions {
        sgm: options.sgm,
        sgm_threads: options.sgm_threads,
        use_imu,
        use_wheel: !options.no_wheel,
        zupt: !options.no_zupt,
        latency_ns,
        switch: options.switch,
        filter: FilterConfig {
            gyro_scale_sigma: options.gyro_scale_sigma,
            ..FilterConfig::from_imu_noise(
                dataset.imu_noise.unwrap_or(onboard::vio::EUROC_IMU_NOISE),
                options.gravity_mps2,
            )
        },
        // IMU data past the last image has no vision to correct it (EuRoC V1_01's excerpt has
        // 2 s of images and 144 s of IMU): stop once the last frame's result has arrived.
        end_stamp_ns: (!options.all_imu).then(|| last_image_ns.saturating_add(latency_ns)),
        vo_prior: !options.no_prior,
        vo_updates: if options.vo_keyframes { VoUpdates::Keyframes } else { VoUpdates::EveryFrame },
        ..VioOptions::default()
    };
    let mut pipeline = VioPipeline::new(&dataset.calibration, vio_options).map_err(|e| e.to_string())?;
    let summary = pipeline.run(&mut dataset.source).map_err(|e| e.to_string())?;
    let (stamps_ns, poses) = pipeline.trajectory();
    if poses.is_empty() {
        return Err("the pipeline produced no pose (too little data to initialize?)".to_owned());
    }
    let estimate = estimate_trajectory(stamps_ns, poses).map_err(|e| e.to_string())?;
    if let Some(path) = &options.output {
        let mut text = String::new();
        eval::io::write_tum(&estimate, &mut text).map_err(|e| e.to_string())?;
        std::fs::write(path, text).map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    }
    let score = match &options.gt {
        Some(path) => {
            let gt =
                load_ground_truth(path, dataset.kind, &dataset.image_stamps_ns, &dataset.calibration.left.t_body_cam)
                    .map_err(|e| e.to_string())?;
            Some(score(&estimate, &gt).map_err(|e| e.to_string())?)
        }
        None => None,
    };
    Ok(Report {
        layout: dataset.kind.name(),
        mode: if use_imu { "vio" } else { "vo" },
        poses: poses.len(),
        max_displacement_m: max_displacement_m(poses),
        summary,
        score,
    })
}

fn vector(v: Option<Vector3<f64>>) -> serde_json::Value {
    v.map_or(serde_json::Value::Null, |v| serde_json::json!([v.x, v.y, v.z]))
}

fn json(options: &Options, report: &Report) -> serde_json::Value {
    let s = &report.summary;
    let health = s.filter_health.unwrap_or_default();
    let mut object = serde_json::json!({
        "dataset": options.dataset.display().to_string(),
        "layout": report.layout,
        "mode": report.mode,
        "depth": if options.sgm { "sgm" } else { "sparse" },
        "frames": s.frames,
        "frames_before_init": s.frames_before_init,
        "keyframes": s.keyframes,
        "vo_resets": s.vo_resets,
        "vo_deltas": s.vo_deltas,
        "mean_inliers": s.mean_inliers,
        "min_inliers": s.min_inliers,
        "poses": report.poses,
        "imu_samples": s.imu_samples,
        "vo_updates_applied": s.vo_updates_applied,
        "vo_updates_rejected": s.vo_updates_rejected,
        "vo_updates_missing_clone": s.vo_updates_missing_clone,
        "vo_updates_skipped": s.vo_updates_skipped,
        "wheel_updates_applied": s.wheel_updates_applied,
        "wheel_updates_rejected": s.wheel_updates_rejected,
        "zupt_updates_applied": s.zupt_updates_applied,
        "zupt_updates_rejected": s.zupt_updates_rejected,
        "frame_switches": s.frame_switches,
        "filter_updates_applied": health.updates_applied,
        "filter_updates_rejected": health.updates_rejected,
        "filter_missing_clones": health.missing_clones,
        "filter_clones_evicted": health.clones_evicted,
        "filter_covariance_repairs": health.covariance_repairs,
        "initial_gyro_bias_radps": vector(s.initial_gyro_bias_radps),
        "initial_accel_bias_mps2": vector(s.initial_accel_bias_mps2),
        "final_gyro_bias_radps": vector(s.final_gyro_bias_radps),
        "final_accel_bias_mps2": vector(s.final_accel_bias_mps2),
        "data_duration_s": s.data_duration_s,
        "rectify_ms_per_frame": s.rectify_ms_per_frame,
        "sgm_ms_per_frame": s.sgm_ms_per_frame,
        "vo_ms_per_frame": s.vo_ms_per_frame,
        "vo_ms_max": s.vo_ms_max,
        "filter_ms_per_s": s.filter_ms_per_s,
        "max_displacement_m": report.max_displacement_m,
    });
    if let Some(score) = &report.score {
        let fields = [
            ("gt_pairs", serde_json::json!(score.pairs)),
            ("ate_rmse_m", serde_json::json!(score.ate_rmse_m)),
            ("ate_mean_m", serde_json::json!(score.ate_mean_m)),
            ("ate_max_m", serde_json::json!(score.ate_max_m)),
            ("gt_path_length_m", serde_json::json!(score.gt_path_length_m)),
            ("final_error_m", serde_json::json!(score.final_error_m)),
            ("final_drift_percent", serde_json::json!(score.final_drift_percent)),
            ("final_error_aligned_m", serde_json::json!(score.final_error_aligned_m)),
            ("final_drift_aligned_percent", serde_json::json!(score.final_drift_aligned_percent)),
            ("final_rotation_error_deg", serde_json::json!(score.final_rotation_error_deg)),
        ];
        for (key, value) in fields {
            object[key] = value;
        }
    }
    object
}

fn print_text(options: &Options, report: &Report) {
    let s = &report.summary;
    println!(
        "{} on {} ({} layout, {} depth): {} frames, {} keyframes, {} resets, {} poses written",
        report.mode,
        options.dataset.display(),
        report.layout,
        if options.sgm { "SGM" } else { "sparse" },
        s.frames,
        s.keyframes,
        s.vo_resets,
        report.poses
    );
    println!("VO inliers         mean {:.1}, min {}", s.mean_inliers, s.min_inliers);
    if report.mode == "vio" {
        println!(
            "filter updates     VO {} applied / {} rejected / {} without clone, wheel {} / {}, ZUPT {} / {}",
            s.vo_updates_applied,
            s.vo_updates_rejected,
            s.vo_updates_missing_clone,
            s.wheel_updates_applied,
            s.wheel_updates_rejected,
            s.zupt_updates_applied,
            s.zupt_updates_rejected
        );
        println!("frame switches     {}", s.frame_switches);
        if let (Some(g0), Some(g1)) = (s.initial_gyro_bias_radps, s.final_gyro_bias_radps) {
            println!("gyro bias          {:.5?} -> {:.5?} rad/s", g0.as_slice(), g1.as_slice());
        }
        if let (Some(a0), Some(a1)) = (s.initial_accel_bias_mps2, s.final_accel_bias_mps2) {
            println!("accel bias         {:.4?} -> {:.4?} m/s²", a0.as_slice(), a1.as_slice());
        }
    }
    println!(
        "cost               VO {:.1} ms/frame (max {:.1}), rectify {:.1} ms/frame, SGM {:.1} ms/frame, filter {:.1} ms/s",
        s.vo_ms_per_frame, s.vo_ms_max, s.rectify_ms_per_frame, s.sgm_ms_per_frame, s.filter_ms_per_s
    );
    println!("max displacement   {:.4} m over {:.2} s", report.max_displacement_m, s.data_duration_s);
    if let Some(score) = &report.score {
        println!(
            "ATE (SE(3))        RMSE {:.4} m, mean {:.4} m, max {:.4} m over {} poses",
            score.ate_rmse_m, score.ate_mean_m, score.ate_max_m, score.pairs
        );
        let percent = |p: Option<f64>| p.map_or("n/a".to_owned(), |p| format!("{p:.2} %"));
        println!(
            "final drift        {:.4} m = {} of {:.2} m (after SE(3) alignment {:.4} m = {}), rotation {:.2}°",
            score.final_error_m,
            percent(score.final_drift_percent),
            score.gt_path_length_m,
            score.final_error_aligned_m,
            percent(score.final_drift_aligned_percent),
            score.final_rotation_error_deg
        );
    }
}

pub fn main(args: Vec<OsString>) -> ExitCode {
    let (options, report) = match super::parse_and_run("vio", USAGE, args, parse_args, run) {
        Ok(done) => done,
        Err(code) => return code,
    };
    if options.json {
        println!("{}", json(&options, &report));
    } else {
        print_text(&options, &report);
    }
    ExitCode::SUCCESS
}
