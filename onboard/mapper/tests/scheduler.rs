//! The matcher as the mapper's background work: a robot's loop over a rocky terrain patch is
//! closed by matching its first and third submaps, inline and on the background thread alike.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod common {
    pub use mapper::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
    pub mod terrain;
}

use std::sync::Arc;

use common::terrain::{crop, frame, terrain};
use mapper::matching::MatcherParams;
use mapper::pairing::PairingParams;
use mapper::scheduler::{Executor, MatchScheduler, SchedulerConfig};
use mapper::slam::{
    AttemptOutcome, Measurement, NodeId, SubmapId, SubmapPair, SubmapSwitch, TeamGraph, TeamGraphConfig,
};
use nalgebra::{Isometry3, Matrix6, Translation3, Vector6};

const ROBOT: u16 = 1;

/// Submap origins in the terrain frame: 0 and 2 overlap (the robot came back), 1 is elsewhere.
fn origins() -> [Isometry3<f64>; 3] {
    [frame(1.0, 1.0, 0.05, 0.3), frame(9.0, 1.0, 0.0, 1.2), frame(3.4, 2.3, -0.12, -0.45)]
}

/// A graph of the robot's three submaps whose switch odometry drifted by 0.25 m and 2°.
fn drifted_graph() -> TeamGraph {
    let o = origins();
    let mut graph = TeamGraph::new(ROBOT, TeamGraphConfig::default());
    let sigma = Vector6::new(0.15, 0.15, 0.05, 0.005, 0.005, 0.03);
    let covariance = Matrix6::from_diagonal(&sigma.component_mul(&sigma));
    let drift = Isometry3::from_parts(
        Translation3::new(0.2, -0.15, 0.0),
        nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, 2f64.to_radians()),
    );
    for (i, pair) in o.windows(2).enumerate() {
        let t_old_new = pair[0].inverse() * pair[1] * drift;
        let switch = SubmapSwitch {
            robot: ROBOT,
            stamp_ns: (i as u64 + 1) * 10_000_000_000,
            from_index: i as u32,
            t_old_new,
            covariance,
        };
        graph.insert(&Measurement::SubmapSwitch(switch));
    }
    graph.update().unwrap();
    graph
}

fn clouds() -> [Arc<mapper::VoxelCloud>; 3] {
    let raw = terrain(14.0, 70, 42);
    let o = origins();
    [
        Arc::new(crop(&raw, (0.0, 0.0), (8.0, 8.0), &o[0], 0.01, 1)),
        Arc::new(crop(&raw, (6.0, 0.0), (14.0, 8.0), &o[1], 0.01, 2)),
        Arc::new(crop(&raw, (2.5, 1.5), (10.5, 9.5), &o[2], 0.01, 3)),
    ]
}

fn config(executor: Executor) -> SchedulerConfig {
    SchedulerConfig::new(MatcherParams::default(), PairingParams::default(), executor)
}

/// Polls until the scheduler has emitted something (the thread needs wall time).
fn run_until_output(scheduler: &mut MatchScheduler, graph: &mut TeamGraph) -> Vec<Measurement> {
    for tick in 0..600u64 {
        let out = scheduler.poll(tick * 100_000_000, graph);
        if !out.is_empty() {
            return out;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    panic!("no attempt finished");
}

fn check_loop_closure(executor: Executor) {
    let mut graph = drifted_graph();
    let mut scheduler = MatchScheduler::new(ROBOT, config(executor));
    for (i, cloud) in clouds().into_iter().enumerate() {
        scheduler.add_submap(SubmapId::new(ROBOT, i as u32), cloud);
    }
    assert_eq!(scheduler.stats().submaps_unsuitable, 0, "{:?}", scheduler.stats());
    let out = run_until_output(&mut scheduler, &mut graph);
    let pair = SubmapPair::new(SubmapId::new(ROBOT, 0), SubmapId::new(ROBOT, 2));
    let Measurement::Attempt(attempt) = out[0] else { panic!("{out:?}") };
    assert_eq!(
        (attempt.pair, attempt.by, attempt.outcome),
        (pair, ROBOT, AttemptOutcome::Matched),
        "{:?}",
        scheduler.log()
    );
    let Measurement::Match(m) = out[1] else { panic!("{out:?}") };
    let o = origins();
    let truth = o[0].inverse() * o[2];
    let error = truth.inverse() * m.t_a_b;
    assert!(error.translation.vector.norm() < 0.05, "{error:?}");
    assert!(error.rotation.angle() < 0.5f64.to_radians(), "{error:?}");
    // The drifted prior was off by more than the match.
    let record = &scheduler.log()[0];
    assert!((truth.inverse() * record.prior_t_a_b).translation.vector.norm() > 0.2);
    // The match into the graph pulls submap 2 back toward the truth.
    for m in &out {
        graph.insert(m);
    }
    graph.update().unwrap();
    let estimate = graph.node_pose(NodeId::Submap(SubmapId::new(ROBOT, 0))).unwrap().inverse()
        * graph.node_pose(NodeId::Submap(SubmapId::new(ROBOT, 2))).unwrap();
    assert!((truth.inverse() * estimate).translation.vector.norm() < 0.1);
    // Attempted once: the ledger closes the pair and nothing else is open.
    for tick in 700..720u64 {
        assert!(scheduler.poll(tick * 100_000_000, &mut graph).is_empty());
    }
    assert_eq!(scheduler.stats().attempts, 1);
}

#[test]
fn a_loop_is_closed_inline() {
    check_loop_closure(Executor::Inline);
}

#[test]
fn a_loop_is_closed_on_the_background_thread() {
    check_loop_closure(Executor::Background { setup: || {} });
}

#[test]
fn consecutive_and_unsuitable_submaps_are_never_attempted() {
    let mut graph = drifted_graph();
    let mut scheduler = MatchScheduler::new(ROBOT, config(Executor::Inline));
    let [c0, c1, _] = clouds();
    scheduler.add_submap(SubmapId::new(ROBOT, 0), c0);
    scheduler.add_submap(SubmapId::new(ROBOT, 1), c1);
    // A flat patch: no obstacle points.
    let flat: Vec<mapper::MapPoint> = (0..60)
        .flat_map(|i| (0..60).map(move |j| (i, j)))
        .map(|(i, j)| mapper::MapPoint {
            position_m: nalgebra::Point3::new(i as f32 * 0.05, j as f32 * 0.05, 0.0),
            intensity: 100,
            obstacle: false,
        })
        .collect();
    scheduler.add_submap(SubmapId::new(ROBOT, 2), Arc::new(mapper::VoxelCloud::filtered(0.05, &flat)));
    assert_eq!(scheduler.stats().submaps_unsuitable, 1);
    assert_eq!(scheduler.stats().unsuitable_by.get("too_few_obstacle_points"), Some(&1));
    for tick in 0..50u64 {
        assert!(scheduler.poll(tick * 100_000_000, &mut graph).is_empty());
    }
    assert_eq!(scheduler.stats().attempts, 0);
}
