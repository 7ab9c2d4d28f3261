//! One pair through the whole matcher (§6.1.2 a–f).

use std::time::Instant;

use nalgebra::{Isometry3, Point3};

use super::correspondences::{Correspondence, find_correspondences};
use super::covariance::match_covariance;
use super::hough::{Direction, Side, cluster};
use super::icp::{Problem, icp};
use super::keypoints::line_spread;
use super::params::{MatchMode, MatcherParams};
use super::prepared::PreparedCloud;
use super::ransac::ransac;
use super::report::{MatchFound, MatchReport, Rejection, RelativePrior, StageTimes};

/// One Hough cluster's RANSAC model, in the `t_target_source` convention.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Hypothesis {
    pub t_target_source: Isometry3<f64>,
    /// Indices into the correspondences of the supporting (RANSAC inlier) correspondences.
    pub inliers: Vec<usize>,
    pub cluster_size: usize,
}

fn roll_pitch_within(t: &Isometry3<f64>, max_rad: f64) -> bool {
    let (roll, pitch, _) = t.rotation.euler_angles();
    roll.abs() <= max_rad && pitch.abs() <= max_rad
}

/// Hough clusters in both directions (trap T3), one RANSAC model each; the target→source
/// models are inverted into `t_target_source`.
pub(crate) fn hypotheses(
    source: &PreparedCloud,
    target: &PreparedCloud,
    corrs: &[Correspondence],
    params: &MatcherParams,
) -> Vec<Hypothesis> {
    let (fs, ft) = (source.features(), target.features());
    let side_s = Side { position: &fs.position, lrf: &fs.lrf };
    let side_t = Side { position: &ft.position, lrf: &ft.lrf };
    let mut out = Vec::new();
    for (d, direction) in [Direction::SourceInTarget, Direction::TargetInSource].into_iter().enumerate() {
        for (ci, members) in cluster(side_s, side_t, corrs, direction, params).into_iter().enumerate() {
            let from: Vec<Point3<f64>> = members.iter().map(|&m| fs.position[corrs[m].source].cast::<f64>()).collect();
            let to: Vec<Point3<f64>> = members.iter().map(|&m| ft.position[corrs[m].target].cast::<f64>()).collect();
            let seed = params.seed ^ ((d as u64) << 32 | ci as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15);
            // Both directions fit the same pairs; the second fits target→source, as its
            // Hough votes were cast, and is inverted (its residuals live in the source frame).
            let model = match direction {
                Direction::SourceInTarget => ransac(&from, &to, params, seed).map(|m| (m.transform, m.inliers)),
                Direction::TargetInSource => {
                    ransac(&to, &from, params, seed).map(|m| (m.transform.inverse(), m.inliers))
                }
            };
            if let Some((t_target_source, inliers)) = model {
                let inliers = inliers.into_iter().map(|i| members[i]).collect();
                out.push(Hypothesis { t_target_source, inliers, cluster_size: members.len() });
            }
        }
    }
    out
}

/// §6.1.2 d: the prior gate, the 6D roll/pitch gate, the distribution check in both clouds;
/// then the hypothesis with most supporting correspondences (trap T4).
pub(crate) fn select(
    hyps: &[Hypothesis],
    source: &PreparedCloud,
    target: &PreparedCloud,
    corrs: &[Correspondence],
    prior: Option<&RelativePrior>,
    params: &MatcherParams,
) -> Result<usize, Rejection> {
    if hyps.is_empty() {
        return Err(Rejection::NoHypothesis);
    }
    let mut remaining: Vec<usize> = (0..hyps.len()).collect();
    if let Some(prior) = prior {
        remaining.retain(|&i| prior.contains(&hyps[i].t_target_source, params.prior_sigma_factor));
        if remaining.is_empty() {
            return Err(Rejection::OutsidePriorBounds);
        }
    }
    if params.mode == MatchMode::SixDof {
        remaining.retain(|&i| roll_pitch_within(&hyps[i].t_target_source, params.max_roll_pitch_ransac_rad));
        if remaining.is_empty() {
            return Err(Rejection::RollPitchImplausible);
        }
    }
    let (fs, ft) = (source.features(), target.features());
    let spread_params = MatcherParams { min_spread_keypoints: params.hypothesis_min_spread, ..params.clone() };
    remaining.retain(|&i| {
        let h = &hyps[i];
        if h.inliers.len() < params.hypothesis_min_spread {
            return false;
        }
        let in_source: Vec<Point3<f32>> = h.inliers.iter().map(|&c| fs.position[corrs[c].source]).collect();
        let in_target: Vec<Point3<f32>> = h.inliers.iter().map(|&c| ft.position[corrs[c].target]).collect();
        line_spread(&in_source, &spread_params) >= params.hypothesis_min_spread
            && line_spread(&in_target, &spread_params) >= params.hypothesis_min_spread
    });
    // Most inliers; ties to the larger cluster, then to the first found (deterministic).
    remaining
        .into_iter()
        .max_by(|&a, &b| {
            (hyps[a].inliers.len(), hyps[a].cluster_size)
                .cmp(&(hyps[b].inliers.len(), hyps[b].cluster_size))
                .then(b.cmp(&a))
        })
        .ok_or(Rejection::BadlyDistributed)
}

/// Matches `source` into `target`: `t_target_source` maps source coordinates into target
/// coordinates. `prior` (the SLAM estimate with its Δσ_t) gates hypotheses and the result; None
/// matches without it.
pub fn match_clouds(
    source: &PreparedCloud,
    target: &PreparedCloud,
    prior: Option<&RelativePrior>,
    params: &MatcherParams,
) -> MatchReport {
    let start = Instant::now();
    let mut report = MatchReport {
        outcome: Err(Rejection::NoHypothesis),
        times: StageTimes::default(),
        correspondences: 0,
        hypotheses: 0,
    };
    report.outcome = run(source, target, prior, params, &mut report);
    report.times.total_s = start.elapsed().as_secs_f64();
    report
}

fn run(
    source: &PreparedCloud,
    target: &PreparedCloud,
    prior: Option<&RelativePrior>,
    params: &MatcherParams,
    report: &mut MatchReport,
) -> Result<MatchFound, Rejection> {
    source.suitability().map_err(Rejection::SourceUnsuitable)?;
    target.suitability().map_err(Rejection::TargetUnsuitable)?;

    let t0 = Instant::now();
    let (fs, ft) = (source.features(), target.features());
    report.times.features_s = t0.elapsed().as_secs_f64();

    let t1 = Instant::now();
    let corrs = find_correspondences(&fs.descriptors, &ft.descriptors, params.k_neighbours, params.min_similarity);
    report.times.correspondences_s = t1.elapsed().as_secs_f64();
    report.correspondences = corrs.len();
    if corrs.len() < params.min_correspondences.max(2) {
        return Err(Rejection::TooFewCorrespondences { found: corrs.len(), min: params.min_correspondences });
    }

    let t2 = Instant::now();
    let hyps = hypotheses(source, target, &corrs, params);
    report.hypotheses = hyps.len();
    let chosen = select(&hyps, source, target, &corrs, prior, params);
    report.times.hough_ransac_s = t2.elapsed().as_secs_f64();
    let best = &hyps[chosen?];

    let t3 = Instant::now();
    let problem = Problem::between(source, target, params.icp_metric);
    let result = icp(&problem, target.index(), &best.t_target_source, params);
    let outcome = result.map_err(|_| Rejection::IcpFailed).and_then(|r| {
        let smaller = source.positions().len().min(target.positions().len()).max(1);
        if r.rmse_m > params.icp_max_rmse_m || (r.pairs.len() as f64) < params.icp_min_pair_fraction * smaller as f64 {
            return Err(Rejection::IcpFailed);
        }
        if let Some(prior) = prior
            && !prior.contains(&r.t_target_source, params.prior_sigma_factor)
        {
            return Err(Rejection::FinalOutsidePriorBounds);
        }
        if params.mode == MatchMode::SixDof && !roll_pitch_within(&r.t_target_source, params.max_roll_pitch_icp_rad) {
            return Err(Rejection::RollPitchImplausible);
        }
        let covariance =
            match_covariance(&r.t_target_source, &problem, &r.pairs, params).ok_or(Rejection::IcpFailed)?;
        Ok(MatchFound {
            t_target_source: r.t_target_source,
            covariance,
            rmse_m: r.rmse_m,
            correspondences: best.cluster_size,
            inliers: best.inliers.len(),
            icp_pairs: r.pairs.len(),
            icp_iterations: r.iterations,
        })
    });
    report.times.icp_s = t3.elapsed().as_secs_f64();
    outcome
}
