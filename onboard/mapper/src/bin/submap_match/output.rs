//! The result as one JSON object or a readable summary, both in the input frames.

use std::fmt::Write;

use nalgebra::{Isometry3, Matrix4, Matrix6};
use serde_json::{Value, json};

use mapper::matching::{MatchFound, MatchMode};

use crate::Run;
use crate::args::Args;

/// The transform and covariance of a match, in the input frames.
struct InputFrameMatch {
    t_target_source: Isometry3<f64>,
    covariance: Matrix6<f64>,
    /// About the up direction (the aligned frame's z).
    yaw_rad: f64,
}

fn input_frame_match(run: &Run, found: &MatchFound) -> InputFrameMatch {
    // The yaw is read in the aligned frame, where the up direction is z.
    let (_, _, yaw_rad) = found.t_target_source.rotation.euler_angles();
    InputFrameMatch {
        t_target_source: run.alignment.input_from_aligned(&found.t_target_source),
        covariance: run.alignment.covariance_to_input(&found.covariance),
        yaw_rad,
    }
}

fn row_major4(m: &Matrix4<f64>) -> Vec<Vec<f64>> {
    (0..4).map(|r| (0..4).map(|c| m[(r, c)]).collect()).collect()
}

fn row_major6(m: &Matrix6<f64>) -> Vec<Vec<f64>> {
    (0..6).map(|r| (0..6).map(|c| m[(r, c)]).collect()).collect()
}

fn ms(seconds: f64) -> f64 {
    seconds * 1e3
}

pub fn json(args: &Args, run: &Run) -> Value {
    let report = &run.report;
    let times = &report.times;
    let mut record = json!({
        "source": args.source.display().to_string(),
        "target": args.target.display().to_string(),
        "mode": match args.params.mode { MatchMode::FourDof => "4d", MatchMode::SixDof => "6d" },
        "found": report.outcome.is_ok(),
        "points": {"source": run.source_points, "target": run.target_points},
        "hypotheses": report.hypotheses,
        "time_ms": ms(run.total_s),
        "stages_ms": {
            "prepare": ms(run.prepare_s),
            "features": ms(times.features_s),
            "correspondences": ms(times.correspondences_s),
            "hough_ransac": ms(times.hough_ransac_s),
            "icp": ms(times.icp_s),
        },
    });
    match &report.outcome {
        Ok(found) => {
            let m = input_frame_match(run, found);
            let t = m.t_target_source.translation.vector;
            record["transform"] = json!(row_major4(&m.t_target_source.to_homogeneous()));
            record["yaw_rad"] = json!(m.yaw_rad);
            record["translation_m"] = json!([t.x, t.y, t.z]);
            record["rmse_m"] = json!(found.rmse_m);
            record["correspondences"] = json!(found.correspondences);
            record["inliers"] = json!(found.inliers);
            record["icp_pairs"] = json!(found.icp_pairs);
            record["icp_iterations"] = json!(found.icp_iterations);
            record["covariance"] = json!(row_major6(&m.covariance));
        }
        Err(rejection) => {
            // The correspondences the pair had before it was rejected.
            record["correspondences"] = json!(report.correspondences);
            record["rejection"] = json!(rejection.name());
            record["rejection_detail"] = json!(rejection.to_string());
        }
    }
    record
}

pub fn summary(args: &Args, run: &Run) -> String {
    let report = &run.report;
    let times = &report.times;
    let mut out = String::new();
    let _ = writeln!(
        out,
        "{} ({} points) -> {} ({} points), {:?}",
        args.source.display(),
        run.source_points,
        args.target.display(),
        run.target_points,
        args.params.mode
    );
    match &report.outcome {
        Ok(found) => {
            let m = input_frame_match(run, found);
            let t = m.t_target_source.translation.vector;
            let (roll, pitch, _) = m.t_target_source.rotation.euler_angles();
            let _ = writeln!(
                out,
                "match: yaw {:.3}° about up, translation [{:.4}, {:.4}, {:.4}] m",
                m.yaw_rad.to_degrees(),
                t.x,
                t.y,
                t.z
            );
            let _ = writeln!(out, "  roll {:.3}°, pitch {:.3}° (input frame)", roll.to_degrees(), pitch.to_degrees());
            let _ = writeln!(
                out,
                "  rmse {:.4} m, {} correspondences, {} inliers, {} ICP pairs in {} iterations",
                found.rmse_m, found.correspondences, found.inliers, found.icp_pairs, found.icp_iterations
            );
            let sigma = m.covariance.diagonal().map(f64::sqrt);
            let _ = writeln!(
                out,
                "  sigma translation [{:.4}, {:.4}, {:.4}] m, rotation [{:.3}, {:.3}, {:.3}]°",
                sigma[0],
                sigma[1],
                sigma[2],
                sigma[3].to_degrees(),
                sigma[4].to_degrees(),
                sigma[5].to_degrees()
            );
            let _ = writeln!(out, "  T_target_source =");
            let h = m.t_target_source.to_homogeneous();
            for r in 0..4 {
                let _ =
                    writeln!(out, "    {:10.6} {:10.6} {:10.6} {:10.6}", h[(r, 0)], h[(r, 1)], h[(r, 2)], h[(r, 3)]);
            }
        }
        Err(rejection) => {
            let _ = writeln!(
                out,
                "no match: {rejection} [{}], {} correspondences",
                rejection.name(),
                report.correspondences
            );
        }
    }
    let _ = writeln!(
        out,
        "time {:.1} ms (prepare {:.1}, features {:.1}, correspondences {:.1}, hough+ransac {:.1}, icp {:.1})",
        ms(run.total_s),
        ms(run.prepare_s),
        ms(times.features_s),
        ms(times.correspondences_s),
        ms(times.hough_ransac_s),
        ms(times.icp_s)
    );
    out
}
