//! `apriltag`: tag36h11 detection in PNG and JPEG images with `vision::apriltag`.
//!
//! Exit codes: 0 success, 1 runtime error (unreadable image), 2 usage error.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use vision::apriltag::{TagDetection, TagDetector, TagDetectorConfig};
use vision::image_file;

const USAGE: &str = "\
usage: apriltag [--family tag36h11] [--json] [--decimate N] [--max-hamming N] [--min-margin M]
                [--runs R] [--fx F --fy F --cx C --cy C --tag-size-m S] IMAGE...

  --family F        tag family (only tag36h11)
  --json            one JSON object per image and line: {\"image\", \"width\", \"height\", \"time_ms\",
                    \"detections\": [{\"id\", \"hamming\", \"decision_margin\", \"center\", \"corners\"}]}
  --decimate N      search quads on the image decimated by N (default 1)
  --max-hamming N   bit errors corrected, 0..=3 (default 2)
  --min-margin M    drop detections with a smaller decision margin (default 0)
  --runs R          detect R times per image, report the fastest (default 1)
  --fx --fy --cx --cy --tag-size-m
                    camera intrinsics (px) and tag size (m, black square) for the tags' poses
                    (both PnP solutions with their reprojection errors)

Pixel coordinates: (0, 0) is the centre of the top-left pixel. Corners: the tag's bottom-left,
bottom-right, top-right, top-left (counter-clockwise in the image; the upstream library's order).
Colour images become grey with the BT.601 luma weights (0.299, 0.587, 0.114).";

/// Why the program stops: usage errors exit with 2, runtime errors with 1.
#[derive(Debug)]
enum CliError {
    Usage(String),
    Runtime(String),
}

impl From<lexopt::Error> for CliError {
    fn from(e: lexopt::Error) -> Self {
        CliError::Usage(e.to_string())
    }
}

/// Pinhole intrinsics and tag size for the poses.
#[derive(Debug, Clone, Copy, Default)]
struct PoseOptions {
    fx: Option<f64>,
    fy: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    tag_size_m: Option<f64>,
}

impl PoseOptions {
    fn any(&self) -> bool {
        self.fx.is_some() || self.fy.is_some() || self.cx.is_some() || self.cy.is_some() || self.tag_size_m.is_some()
    }
}

#[derive(Debug)]
struct Args {
    images: Vec<PathBuf>,
    config: TagDetectorConfig,
    runs: usize,
    json: bool,
    pose: PoseOptions,
}

fn parse_number<T: std::str::FromStr>(option: &str, value: std::ffi::OsString) -> Result<T, CliError> {
    let text = value.to_string_lossy();
    text.parse().map_err(|_| CliError::Usage(format!("--{option}: '{text}' is not a valid number")))
}

/// `Ok(None)` means `--help` was asked for.
fn parse_args() -> Result<Option<Args>, CliError> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_env();
    let mut config = TagDetectorConfig::default();
    let (mut images, mut runs, mut json) = (Vec::new(), 1usize, false);
    let mut pose = PoseOptions::default();
    while let Some(arg) = parser.next()? {
        match arg {
            Long("family") => {
                let family = parser.value()?.to_string_lossy().into_owned();
                if family != "tag36h11" {
                    return Err(CliError::Usage(format!("--family: only tag36h11 is supported, not '{family}'")));
                }
            }
            Long("json") => json = true,
            Long("decimate") => config.quad_decimate = parse_number("decimate", parser.value()?)?,
            Long("max-hamming") => config.max_hamming = parse_number("max-hamming", parser.value()?)?,
            Long("min-margin") => config.min_decision_margin = parse_number("min-margin", parser.value()?)?,
            Long("runs") => runs = parse_number("runs", parser.value()?)?,
            Long("fx") => pose.fx = Some(parse_number("fx", parser.value()?)?),
            Long("fy") => pose.fy = Some(parse_number("fy", parser.value()?)?),
            Long("cx") => pose.cx = Some(parse_number("cx", parser.value()?)?),
            Long("cy") => pose.cy = Some(parse_number("cy", parser.value()?)?),
            Long("tag-size-m") => pose.tag_size_m = Some(parse_number("tag-size-m", parser.value()?)?),
            Long("help") | Short('h') => return Ok(None),
            Value(path) => images.push(PathBuf::from(path)),
            _ => return Err(arg.unexpected().into()),
        }
    }
    if images.is_empty() {
        return Err(CliError::Usage("no image given".to_owned()));
    }
    if runs == 0 {
        return Err(CliError::Usage("--runs must be at least 1".to_owned()));
    }
    if pose.any() {
        check_pose_options(&pose)?;
    }
    Ok(Some(Args { images, config, runs, json, pose }))
}

/// Poses: both IPPE solutions of a detection (`vision::marker_pose`), best first, each as the
/// tag in the camera frame (x right, y down, z forward; translation in m, quaternion w x y z) with
/// its reprojection RMS, and the ratio second / best (near 1: the planar ambiguity).
fn pinhole(pose: &PoseOptions) -> Option<(hal::sensor::Pinhole, f64)> {
    let k = hal::sensor::Pinhole { fx_px: pose.fx?, fy_px: pose.fy?, cx_px: pose.cx?, cy_px: pose.cy? };
    Some((k, pose.tag_size_m?))
}

fn check_pose_options(pose: &PoseOptions) -> Result<(), CliError> {
    let (k, size) = pinhole(pose)
        .ok_or_else(|| CliError::Usage("poses need all of --fx --fy --cx --cy --tag-size-m".to_owned()))?;
    let finite = [k.fx_px, k.fy_px, k.cx_px, k.cy_px, size].iter().all(|v| v.is_finite());
    if !finite || k.fx_px <= 0.0 || k.fy_px <= 0.0 || size <= 0.0 {
        return Err(CliError::Usage("focal lengths and tag size must be positive and finite".to_owned()));
    }
    Ok(())
}

fn solution_json(s: &vision::marker_pose::PnpSolution) -> serde_json::Value {
    let t = s.t_cam_marker.translation.vector;
    let q = s.t_cam_marker.rotation.quaternion();
    serde_json::json!({"t_cam_marker_m": [t.x, t.y, t.z], "q_cam_marker_wxyz": [q.w, q.i, q.j, q.k], "rms_px": s.rms_px})
}

fn pose_solutions(pose: &PoseOptions, detection: &TagDetection) -> Result<serde_json::Value, CliError> {
    let (k, size) = pinhole(pose).ok_or_else(|| CliError::Usage("poses need the intrinsics".to_owned()))?;
    let options = vision::marker_pose::PnpOptions::default();
    Ok(match vision::marker_pose::solve_square(&detection.corners_px, &k, size, &options) {
        Ok(pnp) => serde_json::json!({
            "best": solution_json(&pnp.best),
            "second": pnp.second.as_ref().map(solution_json),
            "ratio": if pnp.ratio.is_finite() { serde_json::json!(pnp.ratio) } else { serde_json::Value::Null },
        }),
        Err(e) => serde_json::json!({"error": e.to_string()}),
    })
}

fn detection_json(t: &TagDetection) -> serde_json::Value {
    serde_json::json!({
        "id": t.id,
        "hamming": t.hamming,
        "decision_margin": t.decision_margin,
        "center": t.center_px,
        "corners": t.corners_px,
    })
}

fn run(args: &Args) -> Result<(), CliError> {
    let mut detector = TagDetector::new(args.config).map_err(|e| CliError::Usage(e.to_string()))?;
    for path in &args.images {
        let image = image_file::read_grey(path).map_err(|e| CliError::Runtime(e.to_string()))?;
        let mut best_ms = f64::INFINITY;
        for _ in 0..args.runs {
            let start = Instant::now();
            detector.detect(image.view());
            best_ms = best_ms.min(start.elapsed().as_secs_f64() * 1e3);
        }
        let detections = detector.detect(image.view());
        let poses: Vec<serde_json::Value> = if args.pose.any() {
            detections.iter().map(|t| pose_solutions(&args.pose, t)).collect::<Result<_, _>>()?
        } else {
            Vec::new()
        };
        if args.json {
            let mut record = serde_json::json!({
                "image": path.display().to_string(),
                "width": image.width,
                "height": image.height,
                "time_ms": best_ms,
                "detections": detections.iter().map(detection_json).collect::<Vec<_>>(),
            });
            if args.pose.any() {
                record["poses"] = serde_json::Value::Array(poses);
            }
            println!("{record}");
        } else {
            println!(
                "{}: {}x{} px, {} tag(s) in {best_ms:.2} ms",
                path.display(),
                image.width,
                image.height,
                detections.len()
            );
            for (k, t) in detections.iter().enumerate() {
                println!(
                    "  id {:3}  hamming {}  margin {:6.1}  centre ({:7.2}, {:7.2})  corners {}",
                    t.id,
                    t.hamming,
                    t.decision_margin,
                    t.center_px[0],
                    t.center_px[1],
                    t.corners_px.iter().map(|c| format!("({:.2}, {:.2})", c[0], c[1])).collect::<Vec<_>>().join(" ")
                );
                if let Some(p) = poses.get(k) {
                    println!("    poses: {p}");
                }
            }
        }
    }
    Ok(())
}

fn main() -> ExitCode {
    let outcome = parse_args().and_then(|args| match args {
        Some(args) => run(&args),
        None => {
            println!("{USAGE}");
            Ok(())
        }
    });
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(CliError::Usage(message)) => {
            eprintln!("apriltag: {message}\n\n{USAGE}");
            ExitCode::from(2)
        }
        Err(CliError::Runtime(message)) => {
            eprintln!("apriltag: {message}");
            ExitCode::from(1)
        }
    }
}
