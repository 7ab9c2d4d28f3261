//! The multi-robot SLAM front-end on a synthetic team (true paths, drifting filter estimates,
//! detections and matches from the truth with the thesis's noise models).
#![allow(clippy::unwrap_used, clippy::expect_used)]

#[path = "common/synthetic_team.rs"]
mod synthetic_team;

use mapper::slam::covariance;
use mapper::slam::{
    AttemptOutcome, FilterPose, InsertOutcome, MatchAttempt, MatchLedger, Measurement, NodeId, SubmapId, SubmapPair,
    TeamGraph, TeamGraphConfig, Topology,
};
use nalgebra::{Isometry3, Matrix6, Translation3, UnitQuaternion, Vector3, Vector6};
use posegraph::LmParams;
use synthetic_team::{Rng, RobotRun, all_measurements, detections, matches, robot_run};

/// Two robots circling overlapping loops (they meet), 4 minutes.
fn meeting_team(seed: u64) -> Vec<RobotRun> {
    vec![robot_run(0, [0.0, 0.0], 6.0, 0.0, 2400, seed), robot_run(1, [4.0, 0.0], 6.0, 0.5, 2400, seed)]
}

fn feed(graph: &mut TeamGraph, measurements: &[(u64, Measurement)]) {
    for (_, m) in measurements {
        let outcome = graph.insert(m);
        assert!(!matches!(outcome, InsertOutcome::Rejected(_)), "{outcome:?} for {m:?}");
        graph.update().unwrap();
    }
}

fn tight() -> LmParams {
    LmParams { relative_tolerance: 1e-12, absolute_tolerance: 1e-14, ..LmParams::default() }
}

#[test]
fn graph_size_follows_the_thesis_formula_for_every_graph() {
    let team = meeting_team(3);
    let dets = detections(&team, 3);
    let ms = matches(&team, 3.0, 3);
    assert!(dets.len() >= 4 && ms.len() >= 4, "{} detections, {} matches", dets.len(), ms.len());
    type Variant<'a> = (&'a str, Topology, Vec<(u64, Measurement)>);
    let variants: Vec<Variant<'_>> = vec![
        ("own only", Topology::LocalReference, all_measurements(&team[..1], &[], &[])),
        ("own + intra matches", Topology::LocalReference, {
            let own: Vec<_> = ms.iter().filter(|m| m.a.robot == 0 && m.b.robot == 0).copied().collect();
            all_measurements(&team[..1], &[], &own)
        }),
        ("team, detections", Topology::LocalReference, all_measurements(&team, &dets, &[])),
        ("team, detections + matches", Topology::LocalReference, all_measurements(&team, &dets, &ms)),
        ("team, sequential", Topology::SequentialOdometry, all_measurements(&team, &dets, &ms)),
    ];
    for (name, topology, data) in variants {
        let mut graph = TeamGraph::new(0, TeamGraphConfig { topology, ..TeamGraphConfig::default() });
        feed(&mut graph, &data);
        let size = graph.size();
        assert_eq!(size.thesis_formula(), (size.nodes, size.factors), "{name}: {size:?}");
        assert_eq!(size.priors, 1, "{name}");
        // Robot-pose nodes only where a measurement needs one: one per robot and detection stamp.
        let stamps: std::collections::BTreeSet<u64> =
            dets.iter().filter(|_| size.detections > 0).map(|d| d.stamp_ns).collect();
        for x in size.robot_poses.values() {
            assert_eq!(*x, stamps.len(), "{name}");
        }
        if topology == Topology::LocalReference {
            assert_eq!(size.sequential_factors, 0);
            let s: usize = size.submaps.values().sum();
            assert_eq!(size.switch_factors, s - size.submaps.len(), "{name}");
        } else {
            assert_eq!(size.switch_factors + size.filter_pose_factors, 0);
        }
    }
}

#[test]
fn delayed_shuffled_delivery_gives_the_in_order_estimate() {
    let team = meeting_team(5);
    let dets = detections(&team, 5);
    let ms = matches(&team, 3.0, 5);
    let in_order = all_measurements(&team, &dets, &ms);
    // Robot 0's view: its own data live; robot 1's data (chain, poses, detections it made,
    // matches) delayed by up to 5 minutes and shuffled.
    let mut rng = Rng::new(99);
    let (mut own, mut remote): (Vec<_>, Vec<_>) = in_order.iter().cloned().partition(|(_, m)| match m {
        Measurement::FilterPose(p) => p.robot == 0,
        Measurement::SubmapSwitch(s) => s.robot == 0,
        Measurement::Detection(d) => d.observer == 0,
        Measurement::Match(m) => m.a.robot == 0 && m.b.robot == 0,
        _ => true,
    });
    for (t, _) in &mut remote {
        *t = t.saturating_add((rng.uniform() * 300e9) as u64);
    }
    own.extend(remote);
    // Stable sort by the delayed arrival time, then a shuffle of everything that arrives in the
    // same 30 s window (an outage flushing its queue in arbitrary order).
    own.sort_by_key(|(t, _)| *t);
    let mut shuffled: Vec<(u64, Measurement)> = Vec::with_capacity(own.len());
    for chunk in own.chunk_by(|a, b| a.0 / 30_000_000_000 == b.0 / 30_000_000_000) {
        let mut chunk = chunk.to_vec();
        for i in (1..chunk.len()).rev() {
            let j = (rng.next_u64() % (i as u64 + 1)) as usize;
            chunk.swap(i, j);
        }
        shuffled.extend(chunk);
    }

    let mut a = TeamGraph::new(0, TeamGraphConfig::default());
    feed(&mut a, &in_order);
    let mut b = TeamGraph::new(0, TeamGraphConfig::default());
    feed(&mut b, &shuffled);
    assert_eq!(b.pending(), 0);
    assert_eq!(a.size(), b.size());

    let (ea, eb) = (a.batch_estimate(&tight()).unwrap(), b.batch_estimate(&tight()).unwrap());
    assert_eq!(ea.len(), eb.len());
    let mut worst = (0.0f64, 0.0f64);
    for (node, pa) in &ea {
        let pb = eb[node];
        worst.0 = worst.0.max((pa.translation.vector - pb.translation.vector).norm());
        worst.1 = worst.1.max((pa.rotation.inverse() * pb.rotation).angle());
    }
    // Same factors, same optimum: only the solver's convergence tolerance separates them.
    assert!(worst.0 < 1e-6 && worst.1 < 1e-7, "batch: {worst:?}");

    // The incremental estimates (one Gauss-Newton step per update, relinearized at 0.1) differ
    // by what that leaves unconverged, far below the filter's drift (1 % of distance).
    let mut worst_inc = 0.0f64;
    for (node, pa) in a.estimates() {
        let pb = b.node_pose(node).unwrap();
        worst_inc = worst_inc.max((pa.translation.vector - pb.translation.vector).norm());
    }
    let mut off_a = 0.0f64;
    for (node, pa) in a.estimates() {
        off_a = off_a.max((pa.translation.vector - ea[&node].translation.vector).norm());
    }
    println!("incremental: orders differ by {worst_inc} m; in-order incremental vs optimum {off_a} m");
    // Measured: 2.5 mm between the orders, 2.1 mm from the optimum (relinearization at 1 cm).
    assert!(worst_inc < 0.01, "incremental: {worst_inc} m");
}

#[test]
fn robots_that_never_meet_stay_unconnected() {
    // Robot 1 drives 200 m away: no detection, no match across robots.
    let team = vec![robot_run(0, [0.0, 0.0], 6.0, 0.0, 1200, 7), robot_run(1, [200.0, 0.0], 6.0, 0.0, 1200, 7)];
    let dets = detections(&team, 7);
    let ms = matches(&team, 3.0, 7);
    assert!(dets.is_empty());
    assert!(ms.iter().all(|m| m.a.robot == m.b.robot));
    let mut graph = TeamGraph::new(0, TeamGraphConfig::default());
    feed(&mut graph, &all_measurements(&team, &dets, &ms));
    let estimate = graph.estimate();
    assert_eq!(estimate.connected_robots(), vec![0]);
    let other = estimate.robots.iter().find(|r| r.robot == 1).unwrap();
    assert!(!other.connected && other.latest.is_none() && other.submaps_connected == 0);
    assert_eq!(other.submaps_known, team[1].true_origins.len());
    assert!(estimate.submaps.iter().all(|(id, _)| id.robot == 0));
    // The held-back chain is complete and enters at the first connection.
    let stamp = team[1].stamps_ns[600];
    let link = mapper::slam::RobotDetection {
        observer: 0,
        observed: 1,
        tag_id: 3,
        stamp_ns: stamp,
        t_observer_observed: team[0].truth[600].inverse() * team[1].truth[600],
        covariance: Matrix6::identity() * 1e-4,
    };
    assert_eq!(graph.insert_detection(&link), InsertOutcome::Added);
    graph.update().unwrap();
    let estimate = graph.estimate();
    assert_eq!(estimate.connected_robots(), vec![0, 1]);
    let size = graph.size();
    assert_eq!(size.submaps[&1], team[1].true_origins.len());
    assert_eq!(size.thesis_formula(), (size.nodes, size.factors));
}

#[test]
fn the_team_estimate_is_better_than_the_filter_and_places_the_other_robot() {
    let team = meeting_team(11);
    let dets = detections(&team, 11);
    let ms = matches(&team, 3.0, 11);
    let mut graph = TeamGraph::new(0, TeamGraphConfig::default());
    feed(&mut graph, &all_measurements(&team, &dets, &ms));
    // Own frame = robot 0's first submap origin.
    let t_own_world = team[0].true_origins[0].inverse();
    let final_error = |graph: &TeamGraph, run: &RobotRun| {
        let last = run.poses.last().unwrap();
        let est = graph.online_pose(last).unwrap();
        (est.translation.vector - (t_own_world * run.truth.last().unwrap()).translation.vector).norm()
    };
    // Filter only: chain the switches (what the robot would have without the graph).
    let filter_only = |run: &RobotRun| {
        let mut t = team[0].true_origins[0].inverse() * run.true_origins[0];
        for s in &run.switches {
            t *= s.t_old_new;
        }
        let est = t * run.poses.last().unwrap().t_submap_body;
        (est.translation.vector - (t_own_world * run.truth.last().unwrap()).translation.vector).norm()
    };
    let (slam0, filter0) = (final_error(&graph, &team[0]), filter_only(&team[0]));
    let slam1 = final_error(&graph, &team[1]);
    assert!(slam0 < 0.5 * filter0, "robot 0: SLAM {slam0} m vs filter {filter0} m");
    // Robot 1 is placed in robot 0's frame to the accuracy of the constraints.
    assert!(slam1 < 0.5, "robot 1 in robot 0's frame: {slam1} m");
    // Every submap origin of both robots, against the truth.
    for run in &team {
        for (i, truth) in run.true_origins.iter().enumerate() {
            let est = graph.node_pose(NodeId::Submap(SubmapId::new(run.robot, i as u32))).unwrap();
            let err = (est.translation.vector - (t_own_world * truth).translation.vector).norm();
            assert!(err < 0.6, "submap {}/{i}: {err} m", run.robot);
        }
    }
    // Marginals: the own first origin is pinned, later ones are uncertain but bounded.
    let marginals = graph.submap_marginals().unwrap();
    let first = marginals.iter().find(|(id, _)| *id == SubmapId::new(0, 0)).unwrap().1;
    assert!(first[(0, 0)].sqrt() < 2e-3);
    for (id, m) in &marginals {
        assert!(covariance::is_valid(m), "{id:?}");
        assert!(m[(0, 0)].sqrt() < 1.0, "{id:?}: {}", m[(0, 0)].sqrt());
    }
}

#[test]
fn an_outlier_match_is_tamed_by_the_cauchy_kernel() {
    let team = meeting_team(13);
    let dets = detections(&team, 13);
    let mut ms = matches(&team, 3.0, 13);
    let clean = all_measurements(&team, &dets, &ms);
    // A wrong match (a look-alike place): 5 m and 60° off, claimed at 8 cm.
    let k = ms.len() / 2;
    let wrong = ms[k];
    let bad =
        Isometry3::from_parts(Translation3::new(4.0, -3.0, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, 1.05));
    ms[k] = mapper::slam::SubmapMatch { t_a_b: wrong.t_a_b * bad, ..wrong };
    let dirty = all_measurements(&team, &dets, &ms);
    let run = |data: &[(u64, Measurement)], c: f64| {
        let mut g = TeamGraph::new(0, TeamGraphConfig { cauchy_c: c, ..TeamGraphConfig::default() });
        feed(&mut g, data);
        let est = g.batch_estimate(&LmParams::default()).unwrap();
        let t_own_world = team[0].true_origins[0].inverse();
        let mut worst = 0.0f64;
        for run in &team {
            for (i, truth) in run.true_origins.iter().enumerate() {
                let e = est[&NodeId::Submap(SubmapId::new(run.robot, i as u32))];
                worst = worst.max((e.translation.vector - (t_own_world * truth).translation.vector).norm());
            }
        }
        worst
    };
    let clean_err = run(&clean, 4.0);
    let robust_err = run(&dirty, 4.0);
    let plain_err = run(&dirty, 1e6);
    println!("worst submap error: clean {clean_err} m, outlier with Cauchy {robust_err} m, without {plain_err} m");
    // With the kernel the outlier keeps a weight of c²/(c² + d²) ≈ 0.1 % at d ≈ 60 whitened units.
    assert!(robust_err < clean_err + 0.01, "robust {robust_err} vs clean {clean_err}");
    assert!(plain_err > clean_err + 0.1, "without the kernel {plain_err} vs {clean_err}");
}

#[test]
fn repeated_messages_change_nothing_and_detections_wait_for_poses() {
    let team = meeting_team(17);
    let dets = detections(&team, 17);
    let mut graph = TeamGraph::new(0, TeamGraphConfig::default());
    // The detection first: both poses are unknown.
    let d = dets[0];
    assert_eq!(graph.insert_detection(&d), InsertOutcome::Pending);
    assert_eq!(graph.insert_detection(&d), InsertOutcome::Duplicate);
    for run in &team {
        for s in &run.switches {
            graph.insert_switch(s);
            assert_eq!(graph.insert_switch(s), InsertOutcome::Duplicate);
        }
    }
    for p in &team[0].poses {
        graph.insert_filter_pose(p);
    }
    assert_eq!(graph.pending(), 1);
    for p in &team[1].poses {
        assert_eq!(graph.insert_filter_pose(p), InsertOutcome::Added);
    }
    assert_eq!(graph.pending(), 0);
    graph.update().unwrap();
    let before = graph.size();
    graph.insert_filter_pose(&team[1].poses[5]);
    graph.insert_detection(&d);
    assert!(graph.update().unwrap().is_none());
    assert_eq!(graph.size(), before);
    assert_eq!(before.detections, 1);
}

#[test]
fn the_sequential_baseline_drops_what_it_cannot_chain() {
    let team = meeting_team(19);
    let dets = detections(&team, 19);
    let mut graph =
        TeamGraph::new(0, TeamGraphConfig { topology: Topology::SequentialOdometry, ..TeamGraphConfig::default() });
    feed(&mut graph, &all_measurements(&team, &dets, &[]));
    assert_eq!(graph.dropped_out_of_order(), 0);
    let before = graph.size();
    // A detection older than both chains' ends arrives late.
    let old = dets[0];
    let late = mapper::slam::RobotDetection { stamp_ns: old.stamp_ns + 100_000_000, ..old };
    graph.insert_detection(&late);
    graph.update().unwrap();
    assert_eq!(graph.dropped_out_of_order(), 1);
    assert_eq!(graph.size(), before);
    // The local-reference topology takes the same detection at any time.
    let mut local = TeamGraph::new(0, TeamGraphConfig::default());
    feed(&mut local, &all_measurements(&team, &dets, &[]));
    assert_eq!(local.insert_detection(&late), InsertOutcome::Added);
    local.update().unwrap();
    assert_eq!(local.dropped_out_of_order(), 0);
}

#[test]
fn the_online_pose_is_the_submap_origin_chained_with_the_filter_pose() {
    let team = meeting_team(23);
    let mut graph = TeamGraph::new(0, TeamGraphConfig::default());
    feed(&mut graph, &all_measurements(&team[..1], &[], &[]));
    let log = graph.online_log();
    assert_eq!(log.len(), team[0].poses.len());
    // Without loop closures the graph is the filter: the online log equals the chained switches.
    let mut t_own_origin = Isometry3::identity();
    let mut next = 0;
    for (p, (stamp, online)) in team[0].poses.iter().zip(log) {
        while next < team[0].switches.len() && team[0].switches[next].stamp_ns <= p.stamp_ns {
            t_own_origin *= team[0].switches[next].t_old_new;
            next += 1;
        }
        assert_eq!(*stamp, p.stamp_ns);
        let expected = t_own_origin * p.t_submap_body;
        assert!((online.translation.vector - expected.translation.vector).norm() < 1e-6);
    }
}

#[test]
fn match_pairs_are_owned_by_exactly_one_robot() {
    let finished: Vec<SubmapId> = (0..3u16).flat_map(|r| (0..6u32).map(move |i| SubmapId::new(r, i))).collect();
    let mut ledgers = [MatchLedger::new(), MatchLedger::new(), MatchLedger::new()];
    let open: Vec<Vec<SubmapPair>> = (0..3u16).map(|r| ledgers[r as usize].open_pairs(r, &finished)).collect();
    let total: usize = open.iter().map(Vec::len).sum();
    // All unordered pairs minus the consecutive ones, each exactly once.
    let n = finished.len();
    assert_eq!(total, n * (n - 1) / 2 - 3 * 5);
    let mut all: Vec<SubmapPair> = open.concat();
    all.sort();
    all.dedup();
    assert_eq!(all.len(), total);
    // Inter-robot work is shared, not all on one robot.
    let inter = |r: usize| open[r].iter().filter(|p| p.first().robot != p.second().robot).count();
    assert!((0..3).all(|r| inter(r) > 20), "{:?}", (0..3).map(inter).collect::<Vec<_>>());
    // Once robot 1 records an attempt and the record reaches robot 0, nobody tries it again.
    let pair = open[1][0];
    let attempt = MatchAttempt { pair, by: 1, outcome: AttemptOutcome::Failed };
    assert!(ledgers[0].record(attempt));
    assert!(!ledgers[0].record(attempt));
    ledgers[1].record(attempt);
    assert!(!ledgers[1].open_pairs(1, &finished).contains(&pair));
}

#[test]
fn filter_covariances_are_converted_to_the_graph_convention() {
    // Monte Carlo: perturb a pose the filter's way (δt in the local frame, δθ on the right),
    // read the perturbation the graph's way (Log(T⁻¹·T')), compare covariances.
    let t = Isometry3::from_parts(Translation3::new(1.0, 2.0, 0.5), UnitQuaternion::from_euler_angles(0.1, -0.2, 1.2));
    let filter_cov: Matrix6<f64> = Matrix6::from_diagonal(&Vector6::new(0.04, 0.01, 0.0025, 1e-4, 4e-4, 9e-4));
    let mut rng = Rng::new(1);
    let mut sum = Matrix6::zeros();
    let n = 20000;
    for _ in 0..n {
        let e = Vector6::from_iterator((0..6).map(|i| filter_cov[(i, i)].sqrt() * rng.gaussian()));
        let dp = Vector3::new(e[0], e[1], e[2]);
        let perturbed = Isometry3::from_parts(
            Translation3::from(t.translation.vector + dp),
            t.rotation * UnitQuaternion::from_scaled_axis(Vector3::new(e[3], e[4], e[5])),
        );
        let xi = posegraph::se3::log(&(t.inverse() * perturbed));
        sum += xi * xi.transpose();
    }
    let sampled = sum / n as f64;
    let converted = covariance::from_filter(&t, &filter_cov);
    for i in 0..6 {
        for j in 0..6 {
            let scale = (converted[(i, i)] * converted[(j, j)]).sqrt();
            // 20000 samples: relative standard error of a covariance entry ≈ √(2/n) = 1 %.
            assert!((sampled[(i, j)] - converted[(i, j)]).abs() < 0.05 * scale, "({i},{j})");
        }
    }
    let back = covariance::to_filter(&t, &converted);
    assert!((back - filter_cov).amax() < 1e-15);
}

#[test]
fn bad_covariances_are_rejected_not_inserted() {
    let mut graph = TeamGraph::new(0, TeamGraphConfig::default());
    let mut p = FilterPose {
        robot: 0,
        stamp_ns: 1,
        submap_index: 0,
        t_submap_body: Isometry3::identity(),
        covariance: Matrix6::identity() * f64::NAN,
    };
    assert!(matches!(graph.insert_filter_pose(&p), InsertOutcome::Rejected(_)));
    p.covariance = -Matrix6::identity();
    assert!(matches!(graph.insert_filter_pose(&p), InsertOutcome::Rejected(_)));
    let m = mapper::slam::SubmapMatch {
        a: SubmapId::new(0, 0),
        b: SubmapId::new(0, 3),
        t_a_b: Isometry3::identity(),
        covariance: Matrix6::zeros(),
    };
    assert!(matches!(graph.insert_match(&m), InsertOutcome::Rejected(_)));
    assert!(graph.update().unwrap().is_some()); // the prior alone
    assert_eq!(graph.size().factors, 1);
}
