//! `eval sync`, `eval fuse` and `eval plot`: the RAWSEEDS ground-truth tools and the figures.

use std::ffi::OsString;
use std::path::PathBuf;

use eval::fusion::{self, FusionConfig, GtStream};
use eval::timesync::{self, HeadingAxis, SyncConfig, SyncSignal};
use eval::{Trajectory, io, metrics, plot};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use serde_json::json;

use super::{CliError, PairOptions, long_name, read_trajectory, unknown_option, value};

pub const SYNC_HELP: &str = "\
eval sync --gt GT --est EST [--signal yaw|rate] [--offset-bounds A:B] [--drift-bounds A:B] [--out SYNCED] [--json]

Estimates the clock offset (s), drift (scale) and heading offset (rad) that map the estimate's
stamps onto the ground truth's clock (RAWSEEDS D2.1 §4.1.3): least squares on the heading signal,
bounded derivative-free pattern search. Defaults: offset in [-1, 1] s, drift in [0.99, 1.01].
--signal rate uses the angular-rate norm (frame-invariant, no heading offset).
--out writes the estimate in TUM with its stamps on the GT clock and rotated by the heading offset.";

fn bounds(parser: &mut lexopt::Parser, option: &str) -> Result<std::ops::RangeInclusive<f64>, CliError> {
    let text: String = value(parser, option)?;
    let parsed = text.split_once(':').and_then(|(a, b)| Some((a.parse::<f64>().ok()?, b.parse::<f64>().ok()?)));
    match parsed {
        Some((a, b)) if a.is_finite() && b.is_finite() && a < b => Ok(a..=b),
        _ => Err(CliError::Usage(format!("{option}: expected LOW:HIGH with LOW < HIGH, got `{text}`"))),
    }
}

pub fn cmd_sync(args: Vec<OsString>) -> Result<(), CliError> {
    let mut options = PairOptions::default();
    let mut config = SyncConfig::default();
    let mut out: Option<PathBuf> = None;
    let mut parser = lexopt::Parser::from_args(args);
    while let Some(arg) = parser.next()? {
        let option = long_name(arg)?;
        if options.take(&option, &mut parser)? {
            continue;
        }
        match option.as_str() {
            "signal" => {
                let name: String = value(&mut parser, "--signal")?;
                config.signal = match name.as_str() {
                    "yaw" => SyncSignal::Yaw { axis: HeadingAxis::Auto },
                    "rate" => SyncSignal::AngularRateNorm,
                    _ => return Err(CliError::Usage(format!("--signal: `yaw` or `rate`, got `{name}`"))),
                };
            }
            "offset-bounds" => config.offset_bounds_s = bounds(&mut parser, "--offset-bounds")?,
            "drift-bounds" => config.drift_bounds = bounds(&mut parser, "--drift-bounds")?,
            "out" => out = Some(parser.value()?.into()),
            "help" => {
                println!("{SYNC_HELP}");
                return Ok(());
            }
            _ => return Err(unknown_option(&option)),
        }
    }
    let (gt, est) = options.load()?;
    let result = timesync::synchronize(&est, &gt, &config).map_err(|e| CliError::Data(e.to_string()))?;
    if let Some(path) = &out {
        let synced = timesync::apply_sync(&est, &result);
        write_tum(path, &synced)?;
    }
    if options.json {
        let object = json!({
            "offset_s": result.offset_s,
            "drift": result.drift,
            "heading_offset_rad": result.heading_offset_rad,
            "anchor_s": result.anchor_s,
            "cost": result.cost,
            "overlap_samples": result.overlap_samples,
            "evaluations": result.evaluations,
            "converged": result.converged,
            "at_bound": result.at_bound,
        });
        println!("{object}");
    } else {
        println!("clock offset    {:+.4} s", result.offset_s);
        println!("drift           {:.7} ({:+.1} ppm)", result.drift, (result.drift - 1.0) * 1e6);
        println!(
            "heading offset  {:+.4} rad ({:+.3}°)",
            result.heading_offset_rad,
            result.heading_offset_rad.to_degrees()
        );
        println!("residual        {:.3e} (mean square) over {} samples", result.cost, result.overlap_samples);
        for (name, at) in ["offset", "drift", "heading offset"].iter().zip(result.at_bound) {
            if at {
                println!("warning: the {name} sits on its bound; widen the box or check the data");
            }
        }
    }
    Ok(())
}

pub const FUSE_HELP: &str = "\
eval fuse --odom ODOM --stream NAME:FILE:SIGMA_XY_M:SIGMA_THETA_DEG[:BIAS_DEG] [--stream ...]
          [--grid-step S] [--max-gap S] [--no-gate] --out FUSED [--json]

Fuses ground-truth streams with odometry as the control: planar (x, y, heading) EKF forward pass
and Rauch-Tung-Striebel backward pass (RAWSEEDS D2.1 §4.1.4 with the corrections of the spec),
on a fixed grid (default 0.01 s), no interpolation across stream gaps longer than --max-gap
(default 0.5 s), chi-square gating at 99.9 % unless --no-gate. Writes the smoothed poses as TUM.
RAWSEEDS noise levels: GT-laser 0.016 m / 1.56°, GT-vision 0.089 m / 2.16° with a -0.8° bias.";

fn parse_stream(text: &str, max_gap_s: f64, format: Option<io::Format>) -> Result<GtStream, CliError> {
    let parts: Vec<&str> = text.split(':').collect();
    let usage =
        || CliError::Usage(format!("--stream: expected NAME:FILE:SIGMA_XY_M:SIGMA_THETA_DEG[:BIAS_DEG], got `{text}`"));
    if !(4..=5).contains(&parts.len()) {
        return Err(usage());
    }
    let number = |s: &str| s.parse::<f64>().ok().filter(|v| v.is_finite());
    let sigma_xy_m = number(parts[2]).filter(|v| *v > 0.0).ok_or_else(usage)?;
    let sigma_theta_deg = number(parts[3]).filter(|v| *v > 0.0).ok_or_else(usage)?;
    let bias_deg = match parts.get(4) {
        Some(b) => number(b).ok_or_else(usage)?,
        None => 0.0,
    };
    let trajectory = read_trajectory(std::path::Path::new(parts[1]), format, None)?;
    Ok(GtStream {
        name: parts[0].to_owned(),
        trajectory,
        sigma_xy_m,
        sigma_theta_rad: sigma_theta_deg.to_radians(),
        heading_bias_rad: bias_deg.to_radians(),
        max_gap_s,
    })
}

pub fn cmd_fuse(args: Vec<OsString>) -> Result<(), CliError> {
    let mut config = FusionConfig::default();
    let (mut odom, mut out, mut json_out) = (None::<PathBuf>, None::<PathBuf>, false);
    let mut stream_texts: Vec<String> = Vec::new();
    let mut max_gap_s = 0.5;
    let mut format = None;
    let mut parser = lexopt::Parser::from_args(args);
    while let Some(arg) = parser.next()? {
        let option = long_name(arg)?;
        match option.as_str() {
            "odom" => odom = Some(parser.value()?.into()),
            "stream" => stream_texts.push(value(&mut parser, "--stream")?),
            "grid-step" => config.grid_step_s = value(&mut parser, "--grid-step")?,
            "max-gap" => max_gap_s = value(&mut parser, "--max-gap")?,
            "no-gate" => config.gate_chi2 = None,
            "format" => format = Some(value(&mut parser, "--format")?),
            "out" => out = Some(parser.value()?.into()),
            "json" => json_out = true,
            "help" => {
                println!("{FUSE_HELP}");
                return Ok(());
            }
            _ => return Err(unknown_option(&option)),
        }
    }
    let odom = odom.ok_or_else(|| CliError::Usage("--odom is required".into()))?;
    let out = out.ok_or_else(|| CliError::Usage("--out is required".into()))?;
    if stream_texts.is_empty() {
        return Err(CliError::Usage("at least one --stream is required".into()));
    }
    config.heading_axis = HeadingAxis::Auto;
    let odometry = read_trajectory(&odom, format, None)?;
    let streams =
        stream_texts.iter().map(|s| parse_stream(s, max_gap_s, format)).collect::<Result<Vec<_>, CliError>>()?;
    let fused = fusion::fuse(&odometry, &streams, &config).map_err(|e| CliError::Data(e.to_string()))?;
    let planar = Trajectory {
        stamps_s: fused.smoothed.iter().map(|s| s.stamp_s).collect(),
        poses: fused
            .smoothed
            .iter()
            .map(|s| {
                Isometry3::from_parts(
                    Translation3::new(s.mean.x, s.mean.y, 0.0),
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), s.mean.z),
                )
            })
            .collect(),
    };
    write_tum(&out, &planar)?;
    if json_out {
        let reports: Vec<_> =
            fused.streams.iter().map(|r| json!({ "name": r.name, "used": r.used, "rejected": r.rejected })).collect();
        println!("{}", json!({ "epochs": fused.smoothed.len(), "streams": reports, "out": out.display().to_string() }));
    } else {
        println!("fused {} epochs into {}", fused.smoothed.len(), out.display());
        for r in &fused.streams {
            println!("  {:<12} {} measurements used, {} rejected by the gate", r.name, r.used, r.rejected);
        }
        println!("(poses are planar: x, y and heading about z; the heading is of the body axis chosen automatically)");
    }
    Ok(())
}

pub const PLOT_HELP: &str = "\
eval plot --gt GT --est EST --out TRAJECTORY.png [--error-out ERROR.png] [--align A] [--title T]

Draws the top-down trajectory against ground truth (after the alignment, default se3) and,
with --error-out, the translation error over the distance travelled along the ground truth.
Association options as for `eval ate`. Needs DejaVu Sans (Debian: fonts-dejavu-core).";

pub fn cmd_plot(args: Vec<OsString>) -> Result<(), CliError> {
    let mut options = PairOptions { align: eval::align::Alignment::Se3, ..PairOptions::default() };
    let (mut out, mut error_out, mut title) = (None::<PathBuf>, None::<PathBuf>, None::<String>);
    let mut parser = lexopt::Parser::from_args(args);
    while let Some(arg) = parser.next()? {
        let option = long_name(arg)?;
        if options.take(&option, &mut parser)? {
            continue;
        }
        match option.as_str() {
            "out" => out = Some(parser.value()?.into()),
            "error-out" => error_out = Some(parser.value()?.into()),
            "title" => title = Some(value(&mut parser, "--title")?),
            "help" => {
                println!("{PLOT_HELP}");
                return Ok(());
            }
            _ => return Err(unknown_option(&option)),
        }
    }
    let out = out.ok_or_else(|| CliError::Usage("--out is required".into()))?;
    let (gt, est) = options.load()?;
    let association = options.associate(&gt, &est)?;
    let report = metrics::ate(&association, &options.align, metrics::PoseRelation::Translation)
        .map_err(|e| CliError::Data(e.to_string()))?;
    let aligned = Trajectory { stamps_s: est.stamps_s.clone(), poses: report.alignment.apply_all(&est.poses) };
    // Ground truth over the estimate's time span only, so both start and end together.
    let (first, last) = (association.stamps_s.first().copied(), association.stamps_s.last().copied());
    let gt_span = match (first, last) {
        (Some(first), Some(last)) => {
            let keep: Vec<usize> =
                (0..gt.len()).filter(|&i| gt.stamps_s[i] >= first - 0.01 && gt.stamps_s[i] <= last + 0.01).collect();
            Trajectory {
                stamps_s: keep.iter().map(|&i| gt.stamps_s[i]).collect(),
                poses: keep.iter().map(|&i| gt.poses[i]).collect(),
            }
        }
        _ => gt.clone(),
    };
    let title = title.unwrap_or_else(|| "estimate vs ground truth".to_owned());
    let label = format!("estimate ({}-aligned)", options.align);
    let draw = |e: plot::PlotError| CliError::Data(e.to_string());
    plot::plot_trajectories(&out, &gt_span, &[(label.as_str(), &aligned)], &format!("{title}: top view"))
        .map_err(draw)?;
    if let Some(error_out) = &error_out {
        let distances = eval::align::path_distances_m(&report.gt);
        plot::plot_error_over_distance(
            error_out,
            &distances,
            &report.errors,
            &format!("{title}: translation error over distance"),
        )
        .map_err(draw)?;
    }
    println!(
        "ATE RMSE {:.4} m over {} pairs ({:.2} m of ground truth); wrote {}{}",
        report.stats.rmse,
        report.errors.len(),
        report.final_error.gt_path_length_m,
        out.display(),
        error_out.map(|p| format!(" and {}", p.display())).unwrap_or_default()
    );
    Ok(())
}

fn write_tum(path: &std::path::Path, trajectory: &Trajectory) -> Result<(), CliError> {
    let mut text = String::new();
    io::write_tum(trajectory, &mut text).map_err(|e| CliError::Data(e.to_string()))?;
    std::fs::write(path, text).map_err(|e| CliError::Data(format!("cannot write {}: {e}", path.display())))
}
