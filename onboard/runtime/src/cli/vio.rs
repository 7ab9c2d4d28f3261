//! `onboard vio --dataset DIR [--out EST.tum] [--json] [...]`
//!
//! Replays a recorded dataset through the rover's own nodes ([`crate::vio`]), writes the robot's
//! online estimate in TUM format (the dataset's clock) and prints a summary. Scoring against
//! ground truth is the harness's (`sil vio … --gt GT`) or evo's/`eval ate`'s on the written file:
//! the firmware carries no evaluation code. Exit codes: 0 success, 1 runtime error (unreadable
//! dataset, garbled calibration, ...), 2 usage error.

use std::ffi::OsString;
use std::path::PathBuf;
use std::process::ExitCode;

use crate::config::{RoverConfig, VoUpdatesConfig};
use crate::vio::{DatasetReport, dataset_config, run_dataset};

pub const USAGE: &str = "usage: onboard vio --dataset DIR [--out EST.tum] [--json] [options]

  --dataset DIR          EuRoC/ASL (mav0/ or a folder with cam0/, cam1/, optional imu0/, wheel0/)
                         or KITTI odometry (image_l/ + image_r/ or image_0/ + image_1/, calib.txt,
                         optional times.txt)
  --config FILE          start from this rover configuration instead of the defaults (its
                         driver becomes the replay of --dataset)
  --out FILE             write the robot's online estimate (TUM: t x y z qx qy qz qw, one pose per
                         image, body frame in the robot's first local frame, dataset clock)
  --json                 print one JSON object instead of text
  --sgm                  odometry depth from the SGM disparity map instead of sparse matching
  --sgm-threads N        SGM worker threads (default 1)
  --latency-ms MS        VO result latency in sensor time (default 250)
  --no-imu               stereo odometry alone even when the dataset has IMU data
  --no-wheel             ignore wheel odometry
  --no-zupt              no zero-velocity updates
  --no-prior             do not seed the odometry with the filter's motion prediction
  --vo-keyframes         fuse only keyframe-to-keyframe deltas (default: every frame's delta)
  --switch-distance M    the mapper starts a new submap (frame switch) after M metres (default 7)
  --switch-sigma M       ... or when the position sigma exceeds M metres (default 0.2)
  --gravity MPS2         gravity at the site (default 9.80665)
  --gyro-scale-sigma S   relative gyro scale/misalignment error the filter assumes (default
                         0.005, EuRoC's ADIS16448; 0 for the simulator's ideal-scale gyro)
  --all-imu              also replay IMU data after the last image (default: stop there)";

/// `onboard vio`'s options: the dataset, how to print, and the configuration they build.
#[derive(Debug)]
pub struct Options {
    pub dataset: PathBuf,
    pub output: Option<PathBuf>,
    pub json: bool,
    pub all_imu: bool,
    pub config: RoverConfig,
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

/// A change an option makes to the configuration (applied after `--config` is read).
type ConfigEdit = Box<dyn FnOnce(&mut RoverConfig)>;

/// Parses `onboard vio`'s options (`Ok(None)`: `--help`).
pub fn parse_args(args: Vec<OsString>) -> Result<Option<Options>, String> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let (mut dataset, mut config_path, mut output, mut json, mut all_imu) = (None, None, None, false, false);
    let mut edits: Vec<ConfigEdit> = Vec::new();
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("dataset") => dataset = Some(PathBuf::from(string_value(&mut parser, "--dataset")?)),
            Long("config") => config_path = Some(PathBuf::from(string_value(&mut parser, "--config")?)),
            Long("out") => output = Some(PathBuf::from(string_value(&mut parser, "--out")?)),
            Long("json") => json = true,
            Long("sgm") => edits.push(Box::new(|c| c.vision.sgm_depth_for_vo = true)),
            Long("sgm-threads") => {
                let text = string_value(&mut parser, "--sgm-threads")?;
                let n = match text.parse::<usize>() {
                    Ok(n) if (1..=64).contains(&n) => n,
                    _ => return Err(format!("--sgm-threads: expected 1..64, got {text:?}")),
                };
                edits.push(Box::new(move |c| c.vision.sgm_threads = n));
            }
            Long("latency-ms") => {
                let text = string_value(&mut parser, "--latency-ms")?;
                let ms = match text.parse::<f64>() {
                    Ok(v) if v.is_finite() && (0.0..=10_000.0).contains(&v) => v,
                    _ => return Err(format!("--latency-ms: expected 0..10000, got {text:?}")),
                };
                edits.push(Box::new(move |c| c.filter.vo_latency_ms = ms));
            }
            Long("no-imu") => edits.push(Box::new(|c| c.filter.use_imu = false)),
            Long("no-wheel") => edits.push(Box::new(|c| c.filter.use_wheel = false)),
            Long("no-zupt") => edits.push(Box::new(|c| c.filter.zupt = false)),
            Long("no-prior") => edits.push(Box::new(|c| c.vision.vo_prior = false)),
            Long("vo-keyframes") => edits.push(Box::new(|c| c.filter.vo_updates = VoUpdatesConfig::Keyframes)),
            Long("switch-distance") => {
                let m = positive("--switch-distance", &string_value(&mut parser, "--switch-distance")?)?;
                edits.push(Box::new(move |c| c.mapper.submap_max_distance_m = m));
            }
            Long("switch-sigma") => {
                let m = positive("--switch-sigma", &string_value(&mut parser, "--switch-sigma")?)?;
                edits.push(Box::new(move |c| c.mapper.max_position_sigma_m = m));
            }
            Long("gyro-scale-sigma") => {
                let value = string_value(&mut parser, "--gyro-scale-sigma")?;
                let sigma = value
                    .parse::<f64>()
                    .ok()
                    .filter(|v| v.is_finite() && *v >= 0.0)
                    .ok_or_else(|| format!("--gyro-scale-sigma: not a non-negative number: {value}"))?;
                edits.push(Box::new(move |c| c.imu.gyro_scale_sigma = sigma));
            }
            Long("gravity") => {
                let g = positive("--gravity", &string_value(&mut parser, "--gravity")?)?;
                edits.push(Box::new(move |c| c.imu.gravity_mps2 = g));
            }
            Long("all-imu") => all_imu = true,
            Short('h') | Long("help") => return Ok(None),
            other => return Err(other.unexpected().to_string()),
        }
    }
    let dataset = dataset.ok_or("--dataset is required")?;
    let mut config = match &config_path {
        Some(path) => RoverConfig::load(path).map_err(|e| format!("--config: {e}"))?,
        None => dataset_config(&dataset),
    };
    config.driver = dataset_config(&dataset).driver;
    for edit in edits {
        edit(&mut config);
    }
    config.validate().map_err(|e| e.to_string())?;
    Ok(Some(Options { dataset, output, json, all_imu, config }))
}

/// Runs the replay and writes `--out`.
pub fn run(options: &Options) -> Result<DatasetReport, String> {
    let report = run_dataset(&options.config, options.all_imu).map_err(|e| e.to_string())?;
    if report.estimate.is_empty() {
        return Err("the robot produced no estimate (too little data to initialize?)".to_owned());
    }
    if let Some(path) = &options.output {
        crate::tum::write_tum(path, &report.estimate, report.time_offset_ns)
            .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
    }
    Ok(report)
}

fn vector(v: Option<nalgebra::Vector3<f64>>) -> serde_json::Value {
    v.map_or(serde_json::Value::Null, |v| serde_json::json!([v.x, v.y, v.z]))
}

fn mode(report: &DatasetReport) -> &'static str {
    if report.use_imu { "vio" } else { "vo" }
}

fn seconds_of(report: &DatasetReport, node: &str) -> f64 {
    report.node_seconds.iter().find(|(n, _)| *n == node).map_or(0.0, |(_, s)| *s)
}

/// The report as one JSON object (`sil vio` adds its score to it).
pub fn json(options: &Options, report: &DatasetReport) -> serde_json::Value {
    let (v, f) = (&report.vision, &report.filter);
    let health = f.filter_health.unwrap_or_default();
    let frames = v.frames.max(1) as f64;
    serde_json::json!({
        "dataset": options.dataset.display().to_string(),
        "layout": report.layout.name(),
        "mode": mode(report),
        "depth": if options.config.vision.sgm_depth_for_vo { "sgm" } else { "sparse" },
        "frames": v.frames,
        "frames_before_init": v.frames_before_init,
        "keyframes": v.keyframes,
        "vo_resets": v.vo_resets,
        "vo_deltas": v.vo_deltas,
        "mean_inliers": if v.vo_deltas > 0 { v.inliers_sum as f64 / v.vo_deltas as f64 } else { 0.0 },
        "min_inliers": v.min_inliers.unwrap_or(0),
        "poses": report.estimate.len(),
        "time_offset_ns": report.time_offset_ns,
        "imu_samples": report.driver.imu,
        "vo_updates_applied": f.vo_updates_applied,
        "vo_updates_rejected": f.vo_updates_rejected,
        "vo_updates_missing_clone": f.vo_updates_missing_clone,
        "vo_updates_skipped": f.vo_updates_skipped,
        "wheel_updates_applied": f.wheel_updates_applied,
        "wheel_updates_rejected": f.wheel_updates_rejected,
        "zupt_updates_applied": f.zupt_updates_applied,
        "zupt_updates_rejected": f.zupt_updates_rejected,
        "frame_switches": f.frame_switches,
        "filter_updates_applied": health.updates_applied,
        "filter_updates_rejected": health.updates_rejected,
        "filter_missing_clones": health.missing_clones,
        "filter_clones_evicted": health.clones_evicted,
        "filter_covariance_repairs": health.covariance_repairs,
        "initial_gyro_bias_radps": vector(report.initial_gyro_bias_radps),
        "final_gyro_bias_radps": vector(report.final_gyro_bias_radps),
        "final_accel_bias_mps2": vector(report.final_accel_bias_mps2),
        "data_duration_s": report.data_duration_s,
        "vision_ms_per_frame": seconds_of(report, "vision") * 1e3 / frames,
        "filter_ms_per_s": seconds_of(report, "filter") * 1e3 / report.data_duration_s.max(1e-9),
        "mapper_ms_per_frame": seconds_of(report, "mapper") * 1e3 / frames,
        "wall_s": report.wall_s,
        "max_displacement_m": report.max_displacement_m(),
    })
}

/// The report as a short text.
pub fn print_text(options: &Options, report: &DatasetReport) {
    let (v, f) = (&report.vision, &report.filter);
    println!(
        "{} on {} ({} layout, {} depth): {} frames, {} keyframes, {} resets, {} poses written",
        mode(report),
        options.dataset.display(),
        report.layout.name(),
        if options.config.vision.sgm_depth_for_vo { "SGM" } else { "sparse" },
        v.frames,
        v.keyframes,
        v.vo_resets,
        report.estimate.len()
    );
    let mean = if v.vo_deltas > 0 { v.inliers_sum as f64 / v.vo_deltas as f64 } else { 0.0 };
    println!("VO inliers         mean {mean:.1}, min {}", v.min_inliers.unwrap_or(0));
    if report.use_imu {
        println!(
            "filter updates     VO {} applied / {} rejected / {} without clone, wheel {} / {}, ZUPT {} / {}",
            f.vo_updates_applied,
            f.vo_updates_rejected,
            f.vo_updates_missing_clone,
            f.wheel_updates_applied,
            f.wheel_updates_rejected,
            f.zupt_updates_applied,
            f.zupt_updates_rejected
        );
        if let (Some(g0), Some(g1)) = (report.initial_gyro_bias_radps, report.final_gyro_bias_radps) {
            println!("gyro bias          {:.5?} -> {:.5?} rad/s", g0.as_slice(), g1.as_slice());
        }
        if let Some(a1) = report.final_accel_bias_mps2 {
            println!("accel bias         {:.4?} m/s²", a1.as_slice());
        }
    }
    println!("frame switches     {}", f.frame_switches);
    let frames = v.frames.max(1) as f64;
    println!(
        "cost               vision {:.1} ms/frame, mapper {:.1} ms/frame, filter {:.1} ms/s; {:.1} s wall",
        seconds_of(report, "vision") * 1e3 / frames,
        seconds_of(report, "mapper") * 1e3 / frames,
        seconds_of(report, "filter") * 1e3 / report.data_duration_s.max(1e-9),
        report.wall_s
    );
    println!("max displacement   {:.4} m over {:.2} s", report.max_displacement_m(), report.data_duration_s);
}

pub fn main(args: Vec<OsString>) -> ExitCode {
    let (options, report) = match super::parse_and_run("onboard", "vio", USAGE, args, parse_args, run) {
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
