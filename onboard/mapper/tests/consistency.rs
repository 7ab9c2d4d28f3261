//! Inter-robot closure screening (PCM) on the synthetic team with injected wrong closures:
//! confidently wrong detections and matches (1–10 m, random yaw, the genuine covariance).
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "common/synthetic_team.rs"]
mod synthetic_team;

use std::collections::BTreeSet;

use mapper::slam::{
    ClosureKey, ConsistencyCheck, Measurement, NodeId, PcmParams, RobotDetection, SubmapId, SubmapMatch, SubmapPair,
    TeamGraph, TeamGraphConfig,
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use synthetic_team::{Rng, RobotRun, all_measurements, detections, matches, robot_run};

/// Two robots circling overlapping loops (they meet), 4 minutes.
fn meeting_team(seed: u64) -> Vec<RobotRun> {
    vec![robot_run(0, [0.0, 0.0], 6.0, 0.0, 2400, seed), robot_run(1, [4.0, 0.0], 6.0, 0.5, 2400, seed)]
}

/// A wrong relative pose: 1–10 m in a random horizontal direction, a random yaw.
fn wrong_offset(rng: &mut Rng) -> Isometry3<f64> {
    let distance_m = 1.0 + 9.0 * rng.uniform();
    let heading = std::f64::consts::TAU * rng.uniform();
    let yaw = std::f64::consts::PI * (2.0 * rng.uniform() - 1.0);
    Isometry3::from_parts(
        Translation3::new(distance_m * heading.cos(), distance_m * heading.sin(), 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw),
    )
}

/// The team's measurements with `fraction` of the inter-robot closures made wrong, and the
/// identities of the wrong ones.
fn corrupted(team: &[RobotRun], fraction: f64, seed: u64) -> (Vec<(u64, Measurement)>, BTreeSet<ClosureKey>) {
    let mut rng = Rng::new(seed ^ 0x0bad_c105);
    let mut wrong = BTreeSet::new();
    let mut dets: Vec<RobotDetection> = detections(team, seed);
    for d in &mut dets {
        if rng.uniform() < fraction {
            d.t_observer_observed *= wrong_offset(&mut rng);
            wrong.insert(ClosureKey::Detection {
                observer: d.observer,
                observed: d.observed,
                stamp_ns: d.stamp_ns,
                tag_id: d.tag_id,
            });
        }
    }
    let mut ms: Vec<SubmapMatch> = matches(team, 3.0, seed);
    for m in ms.iter_mut().filter(|m| m.a.robot != m.b.robot) {
        if rng.uniform() < fraction {
            m.t_a_b *= wrong_offset(&mut rng);
            wrong.insert(ClosureKey::Match(SubmapPair::new(m.a, m.b)));
        }
    }
    (all_measurements(team, &dets, &ms), wrong)
}

fn run(consistency: ConsistencyCheck, data: &[(u64, Measurement)]) -> TeamGraph {
    let mut graph = TeamGraph::new(0, TeamGraphConfig { consistency, ..TeamGraphConfig::default() });
    for (_, m) in data {
        graph.insert(m);
        graph.update().unwrap();
    }
    graph
}

/// The largest distance between robot 1's submap origins in robot 0's graph and the truth
/// (robot 0's frame is its first submap origin): the team's relative localization.
fn inter_robot_error_m(graph: &TeamGraph, team: &[RobotRun]) -> f64 {
    let t_own_world = team[0].true_origins[0].inverse();
    team[1]
        .true_origins
        .iter()
        .enumerate()
        .map(|(i, t_world_origin)| {
            let estimate = graph.node_pose(NodeId::Submap(SubmapId::new(1, i as u32))).expect("robot 1 connected");
            (estimate.translation.vector - (t_own_world * t_world_origin).translation.vector).norm()
        })
        .fold(0.0, f64::max)
}

#[test]
fn pcm_rejects_injected_wrong_closures() {
    let team = meeting_team(7);
    let (clean, none_wrong) = corrupted(&team, 0.0, 7);
    assert!(none_wrong.is_empty());
    let reference = inter_robot_error_m(&run(ConsistencyCheck::None, &clean), &team);
    for fraction in [0.3, 0.7] {
        let (dirty, wrong) = corrupted(&team, fraction, 7);
        assert!(wrong.len() >= 5, "{} wrong closures", wrong.len());
        let graph = run(ConsistencyCheck::Pcm(PcmParams::default()), &dirty);
        let pcm = inter_robot_error_m(&graph, &team);
        let closures = graph.screened_closures();
        let wrong_in = closures.iter().filter(|c| c.accepted && wrong.contains(&c.key)).count();
        let genuine_out = closures.iter().filter(|c| !c.accepted && !wrong.contains(&c.key)).count();
        let genuine = closures.len() - wrong.len();
        println!(
            "{fraction}: {wrong_in} of {} wrong accepted, {genuine_out} of {genuine} genuine rejected; \
             inter-robot error {pcm:.3} m (clean, Cauchy only: {reference:.3} m)",
            wrong.len()
        );
        assert_eq!(wrong_in, 0, "no wrong closure enters the PCM graph");
        assert!(genuine_out * 5 <= genuine, "at most 20 % of the genuine closures lost");
        assert!(pcm < 2.0 * reference + 0.05, "PCM {pcm:.3} m vs clean {reference:.3} m");
    }
}

/// Honest about the kernel: with this many genuine closures the Cauchy kernel alone copes with
/// 30–50 % wrong ones here (within a few cm of the clean graph), so the test shows where it does
/// not: 70 % wrong, where the wrong closures outvote the genuine ones in places.
#[test]
fn cauchy_alone_is_pulled_off_where_pcm_is_not() {
    let team = meeting_team(7);
    let (dirty, _) = corrupted(&team, 0.7, 7);
    let cauchy = inter_robot_error_m(&run(ConsistencyCheck::None, &dirty), &team);
    let pcm = inter_robot_error_m(&run(ConsistencyCheck::Pcm(PcmParams::default()), &dirty), &team);
    println!("70 % wrong: Cauchy alone {cauchy:.3} m, PCM {pcm:.3} m");
    assert!(cauchy > 1.0, "Cauchy alone {cauchy:.3} m");
    assert!(pcm < 0.5, "PCM {pcm:.3} m");
}

#[test]
fn pcm_keeps_a_clean_team_as_it_was() {
    let team = meeting_team(3);
    let (clean, _) = corrupted(&team, 0.0, 3);
    let cauchy = inter_robot_error_m(&run(ConsistencyCheck::None, &clean), &team);
    let pcm_graph = run(ConsistencyCheck::Pcm(PcmParams::default()), &clean);
    let pcm = inter_robot_error_m(&pcm_graph, &team);
    let stats = pcm_graph.consistency_stats().unwrap();
    println!("clean team: Cauchy {cauchy:.3} m, PCM {pcm:.3} m, {stats:?}");
    // The 0.99 test drops a few genuine closures (3 of 28 here): the price of screening.
    assert!(stats.accepted * 100 >= stats.closures * 85, "{stats:?}");
    assert!(pcm < cauchy + 0.05, "PCM {pcm:.3} m vs Cauchy {cauchy:.3} m");
}
