//! The submap matcher's part of the mission report: what each robot's matcher tried, what it
//! accepted and rejected (by which check), and, on the lockstep runner where the simulator's
//! truth is at hand, each accepted match's error against the true relative pose of the two
//! submap origins (thesis Fig. 8.8: 3D translation and yaw error per match).
//!
//! A match is counted a **false positive** when its translation error exceeds
//! [`FALSE_POSITIVE_TRANSLATION_M`] or its yaw error [`FALSE_POSITIVE_YAW_DEG`]: the thesis's
//! accepted matches lie mostly within 0.1–0.3 m, so twice the top of that range is wrong, not
//! imprecise. NEES is the 6-DoF normalized error `δᵀ Σ⁻¹ δ` with `δ = Log(T_true⁻¹ · T_match)`
//! in the graph's convention (perturbation on the right, `[translation, rotation]`): consistent
//! covariances give a mean of 6.

use std::collections::BTreeMap;

use std::collections::BTreeSet;
use std::sync::Arc;

use mapper::matching::diagnose::{self, PairDiagnosis};
use mapper::matching::{PreparedCloud, RelativePrior};
use mapper::pairing::{PlacedSubmap, delta_sigma_in_frame, delta_sigma_m, global_position_variance_m2, xy_bounds};
use mapper::scheduler::{AttemptRecord, MatchScheduler};
use mapper::slam::{SubmapId, SubmapPair, TeamGraph};
use nalgebra::Isometry3;
use nalgebra::Matrix3;
use serde_json::{Value, json};

pub const FALSE_POSITIVE_TRANSLATION_M: f64 = 0.6;
pub const FALSE_POSITIVE_YAW_DEG: f64 = 5.0;

/// One accepted match scored against the truth.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchScore {
    pub a: SubmapId,
    pub b: SubmapId,
    pub translation_error_m: f64,
    pub yaw_error_deg: f64,
    pub nees: f64,
    pub rmse_m: f64,
    /// The prior's error: how far the graph's estimate was before the match (m).
    pub prior_translation_error_m: f64,
}

impl MatchScore {
    pub fn inter_robot(&self) -> bool {
        self.a.robot != self.b.robot
    }

    pub fn false_positive(&self) -> bool {
        self.translation_error_m > FALSE_POSITIVE_TRANSLATION_M || self.yaw_error_deg > FALSE_POSITIVE_YAW_DEG
    }
}

/// One robot's matcher over the mission.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct MatchingReport {
    pub submaps_checked: u64,
    pub submaps_unsuitable: u64,
    pub attempts: u64,
    pub accepted: u64,
    pub rejected: BTreeMap<String, u64>,
    /// Pairs still queued at the end (thesis T16: the queue at the end bounds the count).
    pub queued: usize,
    /// Open pairs the last ranking left out, by rule (eqs. 6.1–6.3), and unsuitable submaps by check.
    pub skipped: BTreeMap<String, u64>,
    pub unsuitable_by: BTreeMap<String, u64>,
    /// Mean time per attempt by stage (s): features, correspondences, Hough + RANSAC, ICP, total.
    pub mean_stage_s: [f64; 5],
    /// Accepted matches against the truth (lockstep runner only).
    pub scores: Vec<MatchScore>,
    /// The same attempted pairs matched again in the other mode (`compare_match_modes`).
    pub other_mode: Option<OtherMode>,
}

/// The attempted pairs re-matched in the other mode with the same priors.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct OtherMode {
    pub mode: String,
    pub attempts: u64,
    pub accepted: u64,
    pub rejected: BTreeMap<String, u64>,
    pub scores: Vec<MatchScore>,
    /// Matching time of all attempts (s).
    pub total_s: f64,
    /// Per attempt: the pair and "accepted" or the rejection's name.
    pub outcomes: Vec<(SubmapPair, &'static str)>,
}

impl OtherMode {
    /// Re-matches every attempt in `scheduler`'s log with `params` (the other mode).
    pub fn rematch(
        scheduler: &MatchScheduler,
        params: &mapper::matching::MatcherParams,
        mode: &str,
        true_origin: &dyn Fn(SubmapId) -> Option<Isometry3<f64>>,
    ) -> OtherMode {
        let pairs: Vec<(SubmapPair, RelativePrior)> = scheduler
            .log()
            .iter()
            .map(|r| (r.pair, RelativePrior { t_target_source: r.prior_t_a_b, delta_sigma_m: r.delta_sigma_m }))
            .collect();
        Self::match_pairs(&|id| scheduler.prepared(id).cloned(), &pairs, params, mode, true_origin)
    }

    /// Matches `pairs` (target = first, source = second) with their priors.
    pub fn match_pairs(
        prepared: &dyn Fn(SubmapId) -> Option<Arc<PreparedCloud>>,
        pairs: &[(SubmapPair, RelativePrior)],
        params: &mapper::matching::MatcherParams,
        mode: &str,
        true_origin: &dyn Fn(SubmapId) -> Option<Isometry3<f64>>,
    ) -> OtherMode {
        let mut other = OtherMode { mode: mode.to_owned(), ..OtherMode::default() };
        for (pair, prior) in pairs {
            let (Some(target), Some(source)) = (prepared(pair.first()), prepared(pair.second())) else {
                continue;
            };
            let report = mapper::matching::match_clouds(&source, &target, Some(prior), params);
            other.attempts += 1;
            other.total_s += report.times.total_s;
            let record = AttemptRecord::new(*pair, 0, prior.t_target_source, prior.delta_sigma_m, &report);
            match record.result {
                Ok(_) => other.accepted += 1,
                Err(name) => *other.rejected.entry(name.to_owned()).or_default() += 1,
            }
            other.outcomes.push((*pair, record.result.as_ref().map_or_else(|name| *name, |_| "accepted")));
            other.scores.extend(score(&record, true_origin));
        }
        other
    }

    pub fn to_json(&self) -> Value {
        json!({
            "mode": self.mode,
            "attempts": self.attempts,
            "accepted": self.accepted,
            "rejected": self.rejected,
            "mean_attempt_s": if self.attempts > 0 { self.total_s / self.attempts as f64 } else { 0.0 },
            "false_positives": self.scores.iter().filter(|s| s.false_positive()).count(),
            "matches": self.scores.iter().map(score_json).collect::<Vec<_>>(),
            "outcomes": self
                .outcomes
                .iter()
                .map(|(p, o)| json!({"a": [p.first().robot, p.first().index], "b": [p.second().robot, p.second().index], "outcome": o}))
                .collect::<Vec<_>>(),
        })
    }
}

fn score_json(s: &MatchScore) -> Value {
    json!({
        "a": [s.a.robot, s.a.index],
        "b": [s.b.robot, s.b.index],
        "inter_robot": s.inter_robot(),
        "translation_error_m": s.translation_error_m,
        "yaw_error_deg": s.yaw_error_deg,
        "nees": s.nees,
        "rmse_m": s.rmse_m,
        "prior_translation_error_m": s.prior_translation_error_m,
        "false_positive": s.false_positive(),
    })
}

impl MatchingReport {
    /// The report of `scheduler`; `true_origin` gives a submap origin's true pose (any common
    /// frame), `None` where unknown (the process runner: no scores).
    pub fn new(scheduler: &MatchScheduler, true_origin: &dyn Fn(SubmapId) -> Option<Isometry3<f64>>) -> Self {
        let stats = scheduler.stats();
        let log = scheduler.log();
        let mut mean_stage_s = [0.0; 5];
        for record in log {
            let t = &record.times;
            for (sum, v) in
                mean_stage_s.iter_mut().zip([t.features_s, t.correspondences_s, t.hough_ransac_s, t.icp_s, t.total_s])
            {
                *sum += v;
            }
        }
        if !log.is_empty() {
            mean_stage_s.iter_mut().for_each(|v| *v /= log.len() as f64);
        }
        MatchingReport {
            submaps_checked: stats.submaps_added,
            submaps_unsuitable: stats.submaps_unsuitable,
            attempts: stats.attempts,
            accepted: stats.accepted,
            rejected: stats.rejected.iter().map(|(k, v)| ((*k).to_owned(), *v)).collect(),
            queued: stats.queued,
            skipped: [
                ("unplaced", stats.last_skips.unplaced),
                ("disjoint", stats.last_skips.disjoint),
                ("small_overlap", stats.last_skips.small_overlap),
                ("below_precision", stats.last_skips.precise),
            ]
            .into_iter()
            .filter(|(_, n)| *n > 0)
            .map(|(k, n)| (k.to_owned(), n as u64))
            .collect(),
            unsuitable_by: stats.unsuitable_by.iter().map(|(k, v)| ((*k).to_owned(), *v)).collect(),
            mean_stage_s,
            scores: log.iter().filter_map(|r| score(r, true_origin)).collect(),
            other_mode: None,
        }
    }

    pub fn false_positives(&self) -> usize {
        self.scores.iter().filter(|s| s.false_positive()).count()
    }

    pub fn to_json(&self) -> Value {
        let scores: Vec<Value> = self.scores.iter().map(score_json).collect();
        json!({
            "submaps_checked": self.submaps_checked,
            "submaps_unsuitable": self.submaps_unsuitable,
            "attempts": self.attempts,
            "accepted": self.accepted,
            "rejected": self.rejected,
            "queued": self.queued,
            "skipped": self.skipped,
            "unsuitable_by": self.unsuitable_by,
            "mean_stage_s": {
                "features": self.mean_stage_s[0],
                "correspondences": self.mean_stage_s[1],
                "hough_ransac": self.mean_stage_s[2],
                "icp": self.mean_stage_s[3],
                "total": self.mean_stage_s[4],
            },
            "false_positives": self.false_positives(),
            "matches": scores,
            "other_mode": self.other_mode.as_ref().map(OtherMode::to_json),
        })
    }

    /// One line: attempts, accepted, rejections by check, errors of the accepted.
    pub fn summary_line(&self) -> String {
        let rejected: Vec<String> = self.rejected.iter().map(|(k, v)| format!("{k} {v}")).collect();
        let list = |m: &BTreeMap<String, u64>| {
            if m.is_empty() {
                "none".to_owned()
            } else {
                m.iter().map(|(k, v)| format!("{k} {v}")).collect::<Vec<_>>().join(", ")
            }
        };
        let mut line = format!(
            "{} attempts, {} accepted, rejected: {}; {} of {} submaps unsuitable ({}); {} queued, last ranking skipped: {}; {:.2} s per attempt",
            self.attempts,
            self.accepted,
            if rejected.is_empty() { "none".to_owned() } else { rejected.join(", ") },
            self.submaps_unsuitable,
            self.submaps_checked,
            list(&self.unsuitable_by),
            self.queued,
            list(&self.skipped),
            self.mean_stage_s[4]
        );
        if !self.scores.is_empty() {
            let mut t: Vec<f64> = self.scores.iter().map(|s| s.translation_error_m).collect();
            t.sort_by(f64::total_cmp);
            let mut yaw: Vec<f64> = self.scores.iter().map(|s| s.yaw_error_deg).collect();
            yaw.sort_by(f64::total_cmp);
            let nees = self.scores.iter().map(|s| s.nees).sum::<f64>() / self.scores.len() as f64;
            line.push_str(&format!(
                "; errors median {:.3} m / {:.2}°, max {:.3} m / {:.2}°, mean NEES {:.1}, {} false positive(s)",
                t[t.len() / 2],
                yaw[yaw.len() / 2],
                t[t.len() - 1],
                yaw[yaw.len() - 1],
                nees,
                self.false_positives()
            ));
        }
        if let Some(other) = &self.other_mode {
            line.push_str(&format!(
                "; the same pairs in {}: {} accepted, {} false positive(s)",
                other.mode,
                other.accepted,
                other.scores.iter().filter(|s| s.false_positive()).count()
            ));
        }
        line
    }
}

fn score(record: &AttemptRecord, true_origin: &dyn Fn(SubmapId) -> Option<Isometry3<f64>>) -> Option<MatchScore> {
    let m = record.result.as_ref().ok()?;
    let t_a_b_true = true_origin(m.a)?.inverse() * true_origin(m.b)?;
    let error = t_a_b_true.inverse() * m.t_a_b;
    let delta = posegraph::se3::log(&error);
    let nees = m.covariance.try_inverse().map_or(f64::INFINITY, |info| (delta.transpose() * info * delta)[(0, 0)]);
    let prior_error = t_a_b_true.inverse() * record.prior_t_a_b;
    Some(MatchScore {
        a: m.a,
        b: m.b,
        translation_error_m: error.translation.vector.norm(),
        yaw_error_deg: yaw_rad(&error).abs().to_degrees(),
        nees,
        rmse_m: record.rmse_m.unwrap_or(f64::NAN),
        prior_translation_error_m: prior_error.translation.vector.norm(),
    })
}

/// The z-y-x Euler yaw of a pose's rotation.
fn yaw_rad(t: &Isometry3<f64>) -> f64 {
    let r = t.rotation.to_rotation_matrix().into_inner();
    r[(1, 0)].atan2(r[(0, 0)])
}

/// Every pair of suitable submaps the robots' matchers hold whose obstacle keypoints truly
/// overlap by more than `min_overlap_m2` in xy and that share at least
/// [`EVALUATION_MIN_SHARED_KEYPOINTS`] keypoints under the truth, matched in 4D and in 6D with the final graph
/// estimate of the first robot that places both as the prior and Δσ = sqrt(Σ_a + Σ_b) from its
/// marginals, at least [`EVALUATION_MIN_DELTA_SIGMA_M`] per axis (the pairing's precision cut,
/// ownership, the ledger and whether the clouds were exchanged left aside): per-match accuracy
/// of the matcher itself on the same pairs. The floor keeps the 2·Δσ gate to gross errors: the
/// robots' detections make the final estimates centimetre-precise, and the thesis's gate would
/// then reject every match that is merely less precise than the estimate (the pairing never
/// queues such pairs).
pub const EVALUATION_MIN_DELTA_SIGMA_M: f64 = 0.5;

/// Keypoints of one submap that must lie within `mapper::matching::diagnose::SAME_KEYPOINT_M`
/// of the other's under the true relative pose for a pair to be evaluated: overlapping boxes are
/// not enough, the two submaps must have seen the same obstacles (the thesis's descriptiveness
/// minimum, 10).
pub const EVALUATION_MIN_SHARED_KEYPOINTS: usize = 10;

/// What to bring into the pair evaluation of one robot at the end of a mission.
#[derive(Debug)]
pub struct RobotView<'a> {
    pub scheduler: &'a MatchScheduler,
    pub graph: &'a TeamGraph,
    /// Position marginals of the submap origins in the robot's global frame.
    pub marginals: BTreeMap<SubmapId, Matrix3<f64>>,
}

#[derive(Debug, Clone, PartialEq, Default)]
pub struct PairEvaluation {
    /// Pairs whose keypoint boxes truly overlap by more than the pairing's minimum.
    pub overlapping: usize,
    /// Of these, pairs sharing at least [`EVALUATION_MIN_SHARED_KEYPOINTS`] keypoints under the
    /// truth; those both placed in a robot's graph were matched.
    pub sharing: usize,
    /// The sharing pairs' matcher internals against the truth (4D parameters).
    pub diagnoses: Vec<(SubmapPair, Isometry3<f64>, PairDiagnosis)>,
    pub unplaced: usize,
    pub four_d: OtherMode,
    pub six_d: OtherMode,
}

impl PairEvaluation {
    pub fn run(
        views: &[RobotView<'_>],
        min_overlap_m2: f64,
        true_origin: &dyn Fn(SubmapId) -> Option<Isometry3<f64>>,
    ) -> PairEvaluation {
        let Some(first) = views.first() else {
            return PairEvaluation::default();
        };
        let prepared = |id: SubmapId| views.iter().find_map(|v| v.scheduler.prepared(id).cloned());
        let ids: BTreeSet<SubmapId> = views.iter().flat_map(|v| v.scheduler.prepared_ids()).collect();
        let ids: Vec<SubmapId> = ids.into_iter().collect();
        let mut evaluation = PairEvaluation::default();
        let mut pairs = Vec::new();
        for (i, &a) in ids.iter().enumerate() {
            for &b in &ids[i + 1..] {
                let pair = SubmapPair::new(a, b);
                if pair.is_consecutive() {
                    continue;
                }
                let (Some(prep_a), Some(prep_b), Some(true_a), Some(true_b)) =
                    (prepared(a), prepared(b), true_origin(a), true_origin(b))
                else {
                    continue;
                };
                let at_truth = |id, t, keypoints| PlacedSubmap {
                    id,
                    t_global_submap: t,
                    position_covariance_m2: Matrix3::zeros(),
                    keypoints,
                };
                let (Some(ba), Some(bb)) = (
                    xy_bounds(&at_truth(a, true_a, prep_a.keypoints())),
                    xy_bounds(&at_truth(b, true_b, prep_b.keypoints())),
                ) else {
                    continue;
                };
                let ox = ba[2].min(bb[2]) - ba[0].max(bb[0]);
                let oy = ba[3].min(bb[3]) - ba[1].max(bb[1]);
                if ox <= 0.0 || oy <= 0.0 || ox * oy <= min_overlap_m2 {
                    continue;
                }
                evaluation.overlapping += 1;
                let t_a_b = true_a.inverse() * true_b;
                if diagnose::shared_keypoints(prep_b.keypoints(), prep_a.keypoints(), &t_a_b)
                    < EVALUATION_MIN_SHARED_KEYPOINTS
                {
                    continue;
                }
                evaluation.sharing += 1;
                // Target = a, source = b, as matched below.
                evaluation.diagnoses.push((
                    pair,
                    t_a_b,
                    diagnose::diagnose(&prep_b, &prep_a, &t_a_b, &first.scheduler.config().matcher),
                ));
                let placed = |view: &RobotView<'_>, id| {
                    Some(PlacedSubmap {
                        id,
                        t_global_submap: view.graph.node_pose(mapper::slam::NodeId::Submap(id))?,
                        position_covariance_m2: *view.marginals.get(&id)?,
                        keypoints: &[],
                    })
                };
                let Some((pa, pb)) = views.iter().find_map(|v| Some((placed(v, a)?, placed(v, b)?))) else {
                    evaluation.unplaced += 1;
                    continue;
                };
                let sigma_global = delta_sigma_m(
                    &global_position_variance_m2(&pa),
                    &global_position_variance_m2(&pb),
                    mapper::pairing::DeltaSigma::Sum,
                );
                let prior = RelativePrior {
                    t_target_source: pa.t_global_submap.inverse() * pb.t_global_submap,
                    delta_sigma_m: delta_sigma_in_frame(&sigma_global, &pa.t_global_submap)
                        .map(|s| s.max(EVALUATION_MIN_DELTA_SIGMA_M)),
                };
                pairs.push((pair, prior));
            }
        }
        let base = first.scheduler.config().matcher.clone();
        let four = mapper::matching::MatcherParams { mode: mapper::matching::MatchMode::FourDof, ..base.clone() };
        let six = mapper::matching::MatcherParams { mode: mapper::matching::MatchMode::SixDof, ..base };
        evaluation.four_d = OtherMode::match_pairs(&prepared, &pairs, &four, "4d", true_origin);
        evaluation.six_d = OtherMode::match_pairs(&prepared, &pairs, &six, "6d", true_origin);
        evaluation
    }

    /// One line: pairs, and per mode accepted, false positives, median errors and NEES.
    pub fn summary_line(&self) -> String {
        let mode = |m: &OtherMode| {
            let mut t: Vec<f64> = m.scores.iter().map(|s| s.translation_error_m).collect();
            t.sort_by(f64::total_cmp);
            let mut yaw: Vec<f64> = m.scores.iter().map(|s| s.yaw_error_deg).collect();
            yaw.sort_by(f64::total_cmp);
            let nees = m.scores.iter().map(|s| s.nees).sum::<f64>() / m.scores.len().max(1) as f64;
            let fp = m.scores.iter().filter(|s| s.false_positive()).count();
            match (t.get(t.len() / 2), yaw.get(yaw.len() / 2)) {
                (Some(t), Some(y)) => format!(
                    "{}: {} of {} accepted, {fp} false positive(s), median error {t:.3} m / {y:.2}°, mean NEES {nees:.1}",
                    m.mode, m.accepted, m.attempts
                ),
                _ => format!("{}: {} of {} accepted", m.mode, m.accepted, m.attempts),
            }
        };
        format!(
            "pair evaluation: {} truly overlapping pairs, {} sharing ≥ {EVALUATION_MIN_SHARED_KEYPOINTS} keypoints ({} not placed in a graph); {}; {}",
            self.overlapping,
            self.sharing,
            self.unplaced,
            mode(&self.four_d),
            mode(&self.six_d)
        )
    }

    pub fn to_json(&self) -> Value {
        json!({
            "overlapping_pairs": self.overlapping,
            "sharing_pairs": self.sharing,
            "diagnoses": self.diagnoses.iter().map(|(p, t, d)| json!({
                "a": [p.first().robot, p.first().index],
                "b": [p.second().robot, p.second().index],
                "t_a_b_true": {
                    "translation_m": t.translation.vector.as_slice(),
                    "quaternion_xyzw": t.rotation.coords.as_slice(),
                },
                "shared_keypoints": d.shared_keypoints,
                "described": [d.described.0, d.described.1],
                "correspondences": d.correspondences,
                "true_correspondences": d.true_correspondences,
                "hypotheses": d.hypotheses,
                "true_hypotheses": d.true_hypotheses,
                "best_inliers": d.best_inliers,
                "best_true_inliers": d.best_true_inliers,
                "icp_from_truth": d.icp_from_truth.map(|(m, deg, rmse)| json!({"moved_m": m, "moved_deg": deg, "rmse_m": rmse})),
            })).collect::<Vec<_>>(),
            "unplaced_pairs": self.unplaced,
            "4d": self.four_d.to_json(),
            "6d": self.six_d.to_json(),
        })
    }
}
