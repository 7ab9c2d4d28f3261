//! Command line of `submap-match`.

use std::ffi::OsString;
use std::path::PathBuf;

use mapper::matching::{MatchMode, MatcherParams};
use nalgebra::Vector3;

pub const USAGE: &str = "\
usage: submap-match --source A --target B [--up X,Y,Z] [--prior TX,TY,TZ,YAW --prior-sigma S]
                    [--mode 4d|6d] [--scale F] [--voxel-m V] [--spread-m D] [--min-points N]
                    [--icp-min-pairs N] [--intensity-weight W] [--json]

Finds the transform that maps the source cloud's coordinates into the target cloud's
(p_target = T · p_source) with the submap matcher (mapper::matching, thesis §6.1).

  --source A, --target B
                 point clouds: PLY (ASCII or binary; the project's export keeps its obstacle
                 flags, any other PLY and all XYZ text and PCD points count as obstacles),
                 PCD (ascii or binary) or XYZ text. Coordinates in metres.
  --up X,Y,Z     the clouds' up direction (default 0,0,1). Both clouds are rotated so that it
                 becomes +z before matching (the matcher's 4D mode estimates a yaw about z);
                 the transform and covariance are reported back in the input frames.
  --prior TX,TY,TZ,YAW
                 the SLAM estimate of the relative pose (source → target) in the input frames:
                 translation in m, yaw in rad about the up direction. Needs --prior-sigma.
  --prior-sigma S
                 the prior's translation sigma per axis (Δσ_t, m); hypotheses farther than
                 2·S on any axis are rejected.
  --mode 4d|6d   4d (default): yaw + translation, the thesis's proposed matcher; 6d: full
                 rotation with roll/pitch plausibility gates (10° after RANSAC, 1° after ICP).
  --scale F      multiplies every length parameter of the matcher (keypoint voxel, radii,
                 Hough bin, inlier and ICP distances, RMSE limit; default 1, the thesis's
                 values for 5 cm voxel submaps of ~10 m). Objects of other sizes: e.g. 0.1 for
                 the Stanford bunny (~15 cm, points ~6 mm apart).
  --voxel-m V    voxel filter applied to both inputs (default 0.05·F, the submaps' leaf); 0
                 keeps every point.
  --spread-m D   the descriptiveness and distribution checks' distance (default 0.5·F): keypoints
                 farther than D from their line (in xy) count as spread. It relates to the size
                 of the scene, not to the resolution as the other lengths do: an object much
                 smaller than a submap needs a smaller value than --scale gives.
  --min-points N smallest cloud (default 1000) and, a tenth of it, smallest obstacle count
  --icp-min-pairs N
                 fewest ICP pairs of a match (default 300)
  --intensity-weight W
                 weight of the descriptor's greyscale part (default 1; 0 for clouds without
                 grey values, such as PCD/XYZ files or lidar intensities)
  --json         one JSON object: found, transform (4×4 row-major, source → target), yaw_rad
                 (about the up direction), translation_m, rmse_m, correspondences, inliers,
                 covariance (6×6 row-major, [translation, rotation], the right-perturbation
                 tangent in the source frame), time_ms, stages_ms {prepare, features,
                 correspondences, hough_ransac, icp}, points {source, target}, and on failure
                 rejection (its snake_case name) and rejection_detail.

time_ms covers the voxel filter, the preparation (keypoints, checks) and the matching of both
clouds, not the file reading.
Exit codes: 0 match found, 1 no match (the rejection is printed), 2 usage or input error.";

/// Why the program stops before matching: exit code 2.
#[derive(Debug)]
pub struct UsageError(pub String);

impl From<lexopt::Error> for UsageError {
    fn from(e: lexopt::Error) -> Self {
        UsageError(e.to_string())
    }
}

/// The SLAM prior in the input frames.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PriorArg {
    pub translation_m: Vector3<f64>,
    /// About the up direction.
    pub yaw_rad: f64,
    pub sigma_m: f64,
}

#[derive(Debug, Clone)]
pub struct Args {
    pub source: PathBuf,
    pub target: PathBuf,
    pub up: Vector3<f64>,
    pub prior: Option<PriorArg>,
    pub voxel_m: f64,
    pub params: MatcherParams,
    pub json: bool,
}

fn numbers(option: &str, value: OsString, n: usize) -> Result<Vec<f64>, UsageError> {
    let text = value.to_string_lossy();
    let parsed: Option<Vec<f64>> =
        text.split(',').map(|t| t.trim().parse::<f64>().ok().filter(|v| v.is_finite())).collect();
    match parsed {
        Some(v) if v.len() == n => Ok(v),
        _ => Err(UsageError(format!("--{option}: '{text}' is not {n} comma-separated finite numbers"))),
    }
}

fn number<T: std::str::FromStr>(option: &str, value: OsString) -> Result<T, UsageError> {
    let text = value.to_string_lossy();
    text.trim().parse().map_err(|_| UsageError(format!("--{option}: '{text}' is not a valid number")))
}

fn positive(option: &str, value: f64) -> Result<f64, UsageError> {
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err(UsageError(format!("--{option} must be positive and finite, not {value}")))
    }
}

/// Multiplies every length parameter by `scale` (the counts and angles stay).
pub fn scale_lengths(params: &mut MatcherParams, scale: f64) {
    // Destructured without `..`: a parameter added to the matcher fails to compile here until it
    // is sorted into lengths (scaled) or the rest.
    let MatcherParams {
        keypoint_voxel_m,
        line_spread_distance_m,
        line_inlier_m,
        normal_radius_m,
        descriptor_radius_m,
        hough_bin_m,
        ransac_inlier_m,
        icp_max_distance_start_m,
        icp_max_distance_final_m,
        icp_translation_epsilon_m,
        icp_max_rmse_m,
        covariance_correlation_m,
        covariance_floor_translation_m,
        mode: _,
        min_points: _,
        min_obstacle_points: _,
        min_spread_keypoints: _,
        line_iterations: _,
        min_support_points: _,
        intensity_bins: _,
        intensity_weight: _,
        k_neighbours: _,
        min_similarity: _,
        min_correspondences: _,
        hough_min_votes: _,
        hough_relative_threshold: _,
        hough_max_clusters: _,
        ransac_iterations: _,
        seed: _,
        max_roll_pitch_ransac_rad: _,
        prior_sigma_factor: _,
        hypothesis_min_spread: _,
        icp_metric: _,
        icp_coarse_stride: _,
        icp_distance_shrink: _,
        icp_max_iterations: _,
        icp_rotation_epsilon_rad: _,
        icp_min_pairs: _,
        icp_min_pair_fraction: _,
        max_roll_pitch_icp_rad: _,
        covariance_inflation: _,
        covariance_floor_rotation_rad: _,
        roll_pitch_sigma_rad: _,
    } = params;
    for length in [
        keypoint_voxel_m,
        line_spread_distance_m,
        line_inlier_m,
        normal_radius_m,
        descriptor_radius_m,
        hough_bin_m,
        ransac_inlier_m,
        icp_max_distance_start_m,
        icp_max_distance_final_m,
        icp_translation_epsilon_m,
        icp_max_rmse_m,
        covariance_correlation_m,
        covariance_floor_translation_m,
    ] {
        *length *= scale;
    }
}

/// `Ok(None)` means `--help` was asked for.
pub fn parse(args: impl IntoIterator<Item = OsString>) -> Result<Option<Args>, UsageError> {
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let (mut source, mut target, mut json) = (None, None, false);
    let mut up = Vector3::z();
    let (mut prior, mut prior_sigma) = (None, None);
    let mut spread_m = None;
    let (mut scale, mut voxel_m, mut min_points, mut icp_min_pairs, mut intensity_weight) =
        (1.0, None, None, None, None);
    let mut mode = MatchMode::FourDof;
    while let Some(arg) = parser.next()? {
        match arg {
            Long("source") => source = Some(PathBuf::from(parser.value()?)),
            Long("target") => target = Some(PathBuf::from(parser.value()?)),
            Long("up") => up = Vector3::from_iterator(numbers("up", parser.value()?, 3)?),
            Long("prior") => prior = Some(numbers("prior", parser.value()?, 4)?),
            Long("prior-sigma") => {
                prior_sigma = Some(positive("prior-sigma", number("prior-sigma", parser.value()?)?)?)
            }
            Long("mode") => {
                mode = match parser.value()?.to_string_lossy().as_ref() {
                    "4d" | "4D" => MatchMode::FourDof,
                    "6d" | "6D" => MatchMode::SixDof,
                    other => return Err(UsageError(format!("--mode: '{other}' is neither 4d nor 6d"))),
                }
            }
            Long("scale") => scale = positive("scale", number("scale", parser.value()?)?)?,
            Long("voxel-m") => voxel_m = Some(number::<f64>("voxel-m", parser.value()?)?),
            Long("spread-m") => spread_m = Some(positive("spread-m", number("spread-m", parser.value()?)?)?),
            Long("min-points") => min_points = Some(number::<usize>("min-points", parser.value()?)?),
            Long("icp-min-pairs") => icp_min_pairs = Some(number::<usize>("icp-min-pairs", parser.value()?)?),
            Long("intensity-weight") => intensity_weight = Some(number::<f32>("intensity-weight", parser.value()?)?),
            Long("json") => json = true,
            Long("help") | Short('h') => return Ok(None),
            _ => return Err(arg.unexpected().into()),
        }
    }
    let source = source.ok_or_else(|| UsageError("--source is missing".to_owned()))?;
    let target = target.ok_or_else(|| UsageError("--target is missing".to_owned()))?;
    if up.norm() < 1e-9 {
        return Err(UsageError("--up must not be the zero vector".to_owned()));
    }
    let prior = match (prior, prior_sigma) {
        (Some(p), Some(sigma_m)) => {
            Some(PriorArg { translation_m: Vector3::new(p[0], p[1], p[2]), yaw_rad: p[3], sigma_m })
        }
        (None, None) => None,
        _ => return Err(UsageError("--prior and --prior-sigma go together".to_owned())),
    };
    let voxel_m = voxel_m.unwrap_or(mapper::cloud::CLOUD_LEAF_M * scale);
    if !(voxel_m.is_finite() && voxel_m >= 0.0) {
        return Err(UsageError(format!("--voxel-m must be 0 or positive, not {voxel_m}")));
    }
    let mut params = MatcherParams::with_mode(mode);
    scale_lengths(&mut params, scale);
    if let Some(d) = spread_m {
        params.line_spread_distance_m = d;
    }
    if let Some(n) = min_points {
        params.min_points = n;
        params.min_obstacle_points = n / 10;
    }
    if let Some(n) = icp_min_pairs {
        params.icp_min_pairs = n;
    }
    if let Some(w) = intensity_weight {
        if !(w.is_finite() && w >= 0.0) {
            return Err(UsageError(format!("--intensity-weight must be 0 or positive, not {w}")));
        }
        params.intensity_weight = w;
    }
    Ok(Some(Args { source, target, up: up.normalize(), prior, voxel_m, params, json }))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(list: &[&str]) -> Result<Option<Args>, UsageError> {
        parse(list.iter().map(OsString::from))
    }

    #[test]
    fn parses_the_full_contract() {
        let a = args(&[
            "--source",
            "a.ply",
            "--target",
            "b.pcd",
            "--up",
            "0,1,0",
            "--prior",
            "1,2,3,0.5",
            "--prior-sigma",
            "0.4",
            "--mode",
            "6d",
            "--scale",
            "0.1",
            "--json",
        ])
        .unwrap()
        .unwrap();
        assert_eq!(a.up, Vector3::y());
        assert_eq!(a.prior, Some(PriorArg { translation_m: Vector3::new(1.0, 2.0, 3.0), yaw_rad: 0.5, sigma_m: 0.4 }));
        assert_eq!(a.params.mode, MatchMode::SixDof);
        assert!((a.voxel_m - 0.005).abs() < 1e-12);
        assert!((a.params.keypoint_voxel_m - MatcherParams::default().keypoint_voxel_m * 0.1).abs() < 1e-12);
        assert!(a.json);
    }

    #[test]
    fn usage_errors_say_what_is_wrong() {
        let message = |list: &[&str]| args(list).unwrap_err().0;
        assert!(message(&["--target", "b"]).contains("--source"));
        assert!(message(&["--source", "a", "--target", "b", "--prior", "1,2,3"]).contains("4 comma-separated"));
        assert!(message(&["--source", "a", "--target", "b", "--prior", "1,2,3,4"]).contains("go together"));
        assert!(message(&["--source", "a", "--target", "b", "--up", "0,0,0"]).contains("zero"));
        assert!(message(&["--source", "a", "--target", "b", "--mode", "5d"]).contains("5d"));
        assert!(args(&["--help"]).unwrap().is_none());
    }
}
