//! Matches two of a mission's submaps with the on-board matcher and prints the outcome and the
//! time of each stage, on one core: what the mapper's background thread does for one pair.
//!
//! ```text
//! cargo run --release -p mapper --example match_submaps -- TARGET.subm SOURCE.subm \
//!     [--mode 4d|6d] [--known X,Y,Z,QX,QY,QZ,QW]
//! ```
//!
//! `--known` is the true `t_target_source` (a mission report's pair diagnosis has it): it
//! becomes the prior (Δσ 0.5 m per axis, the mission's pair evaluation floor) and the result and
//! the matcher's internals are measured against it (`mapper::matching::diagnose`). Without it,
//! when SOURCE is the submap after TARGET of the same robot, the recorded switch transform is the
//! prior; otherwise the pair is matched without one.

use std::sync::Arc;

use mapper::matching::diagnose::diagnose;
use mapper::matching::{MatchMode, MatcherParams, PreparedCloud, RelativePrior, match_clouds};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion, Vector3};

fn load(path: &str) -> Result<mapper::submap::Submap, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    mapper::exchange::decode_submap(&bytes).map_err(|e| format!("{path}: {e}"))
}

fn parse_pose(text: &str) -> Result<Isometry3<f64>, String> {
    let v: Vec<f64> =
        text.split(',').map(|x| x.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    if v.len() != 7 || v.iter().any(|x| !x.is_finite()) {
        return Err(format!("--known {text:?}: expected X,Y,Z,QX,QY,QZ,QW"));
    }
    let q = Quaternion::new(v[6], v[3], v[4], v[5]);
    if q.norm() < 1e-6 {
        return Err("--known: zero quaternion".to_owned());
    }
    Ok(Isometry3::from_parts(Translation3::new(v[0], v[1], v[2]), UnitQuaternion::from_quaternion(q)))
}

fn fail(message: &str) -> ! {
    eprintln!("{message}");
    std::process::exit(2);
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut files, mut mode, mut known) = (Vec::new(), MatchMode::FourDof, None);
    let mut it = args.iter();
    while let Some(arg) = it.next() {
        match arg.as_str() {
            "--mode" => {
                mode = match it.next().map(String::as_str) {
                    Some("4d") => MatchMode::FourDof,
                    Some("6d") => MatchMode::SixDof,
                    other => fail(&format!("--mode {other:?}: expected 4d or 6d")),
                }
            }
            "--known" => {
                known = Some(parse_pose(it.next().map_or("", String::as_str)).unwrap_or_else(|e| fail(&e)));
            }
            _ => files.push(arg.clone()),
        }
    }
    if files.len() != 2 {
        fail("usage: match_submaps TARGET.subm SOURCE.subm [--mode 4d|6d] [--known X,Y,Z,QX,QY,QZ,QW]");
    }
    let (target, source) = match (load(&files[0]), load(&files[1])) {
        (Ok(t), Ok(s)) => (t, s),
        (Err(e), _) | (_, Err(e)) => fail(&e),
    };
    let consecutive = source.robot_id == target.robot_id && source.index == target.index + 1;
    let prior_pose = known.or_else(|| consecutive.then_some(source.t_prev_this));
    let prior = prior_pose.map(|t| RelativePrior { t_target_source: t, delta_sigma_m: Vector3::repeat(0.5) });
    let params = MatcherParams { mode, ..MatcherParams::default() };
    let (target_points, source_points) = (target.cloud.len(), source.cloud.len());
    let target = PreparedCloud::new(Arc::new(target.cloud), &params);
    let source = PreparedCloud::new(Arc::new(source.cloud), &params);
    let report = match_clouds(&source, &target, prior.as_ref(), &params);
    let t = report.times;
    println!(
        "points {target_points} / {source_points}, keypoints {} / {}, correspondences {}, hypotheses {}",
        target.keypoints().len(),
        source.keypoints().len(),
        report.correspondences,
        report.hypotheses
    );
    println!(
        "time: features {:.3} s, correspondences {:.3} s, hough + ransac {:.3} s, icp {:.3} s, total {:.3} s",
        t.features_s, t.correspondences_s, t.hough_ransac_s, t.icp_s, t.total_s
    );
    match report.outcome {
        Ok(found) => {
            let translation = found.t_target_source.translation.vector;
            print!(
                "matched: t = [{:.3}, {:.3}, {:.3}] m, rmse {:.3} m, {} icp pairs in {} iterations",
                translation.x, translation.y, translation.z, found.rmse_m, found.icp_pairs, found.icp_iterations
            );
            match prior_pose {
                Some(p) => {
                    let off = p.inverse() * found.t_target_source;
                    let from = if known.is_some() { "the known pose" } else { "the odometry" };
                    println!(
                        ", {:.3} m / {:.2}° from {from}",
                        off.translation.vector.norm(),
                        off.rotation.angle().to_degrees()
                    );
                }
                None => println!(),
            }
        }
        Err(rejection) => println!("rejected: {}", rejection.name()),
    }
    if let Some(known) = known {
        println!("against the known pose: {:?}", diagnose(&source, &target, &known, &params));
    }
}
