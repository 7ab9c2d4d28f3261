//! Matches two of a mission's submaps with the on-board matcher and prints the outcome and the
//! time of each stage, on one core: what the mapper's background thread does for one pair.
//!
//! ```text
//! cargo run --release -p mapper --example match_submaps -- TARGET.subm SOURCE.subm [6d]
//! ```
//!
//! When SOURCE is the submap after TARGET of the same robot, its recorded switch transform is the
//! prior (Δσ 0.5 m per axis, the mission's pair evaluation floor) and the result is compared with
//! it; otherwise the pair is matched without a prior.

use std::sync::Arc;

use mapper::matching::{MatchMode, MatcherParams, PreparedCloud, RelativePrior, match_clouds};
use nalgebra::Vector3;

fn load(path: &str) -> Result<mapper::submap::Submap, String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{path}: {e}"))?;
    mapper::exchange::decode_submap(&bytes).map_err(|e| format!("{path}: {e}"))
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if !(2..=3).contains(&args.len()) {
        eprintln!("usage: match_submaps TARGET.subm SOURCE.subm [4d|6d]");
        std::process::exit(2);
    }
    let mode = match args.get(2).map(String::as_str) {
        None | Some("4d") => MatchMode::FourDof,
        Some("6d") => MatchMode::SixDof,
        Some(other) => {
            eprintln!("mode {other:?}: expected 4d or 6d");
            std::process::exit(2);
        }
    };
    let (target, source) = match (load(&args[0]), load(&args[1])) {
        (Ok(t), Ok(s)) => (t, s),
        (Err(e), _) | (_, Err(e)) => {
            eprintln!("{e}");
            std::process::exit(1);
        }
    };
    let consecutive = source.robot_id == target.robot_id && source.index == target.index + 1;
    let prior =
        consecutive.then(|| RelativePrior { t_target_source: source.t_prev_this, delta_sigma_m: Vector3::repeat(0.5) });
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
            match prior {
                Some(p) => {
                    let off = p.t_target_source.inverse() * found.t_target_source;
                    println!(
                        ", {:.3} m / {:.2}° from the odometry",
                        off.translation.vector.norm(),
                        off.rotation.angle().to_degrees()
                    );
                }
                None => println!(),
            }
        }
        Err(rejection) => println!("rejected: {}", rejection.name()),
    }
}
