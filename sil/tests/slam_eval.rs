//! The multi-robot SLAM front-end on short simulated 2-robot runs: real VIO on rendered stereo,
//! loop closures from the test-only ground-truth source (`sim::truth_constraints`).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use mapper::slam::Topology;
use sil::slam_eval::{self, ExchangeLog, ExchangeOptions, RobotResult, Variant};
use sil::team_record::{self, RobotRecord, TeamRecordOptions};
use sim::scenario::{self, ScenarioOptions};
use sim::world::World;

fn options() -> TeamRecordOptions {
    TeamRecordOptions {
        robots: 2,
        duration_s: 60.0,
        seed: 2,
        downscale: 4,
        pause_s: Some(1.0),
        policy: mapper::submap::SubmapPolicy::early(),
        ..TeamRecordOptions::default()
    }
}

/// One robot's received data replayed into `variant`.
fn scored(
    world: &Arc<World>,
    record: &RobotRecord,
    log: &ExchangeLog,
    exchange: &ExchangeOptions,
    variant: Variant,
) -> RobotResult {
    slam_eval::evaluate(world, record, &log.received[record.robot], variant, exchange.truth).unwrap().unwrap()
}

#[test]
fn robots_on_the_start_ring_see_each_other_and_share_one_frame() {
    let options = options();
    let world = team_record::moon_team_world(&options).unwrap();
    let records = team_record::record_team(&world, &options).unwrap();
    let exchange = ExchangeOptions::default();
    let log = slam_eval::exchange(&world, &records, &exchange).unwrap();
    // They start 3–4 m apart facing out of the ring and drive petals back through it.
    assert!(log.detections >= 1, "{log:?}");
    for record in &records {
        let multi = scored(&world, record, &log, &exchange, Variant::Multi(Topology::LocalReference));
        assert_eq!(multi.connected, vec![0, 1], "robot {}", record.robot);
        assert_eq!(multi.size.thesis_formula(), (multi.size.nodes, multi.size.factors));
        assert_eq!(multi.size.submaps.len(), 2);
        assert!(multi.size.detections >= 1);
        let filter = scored(&world, record, &log, &exchange, Variant::FilterOnly);
        assert_eq!(filter.connected, vec![record.robot as u16]);
        // In 60 s the filter drifts by centimetres; the graph must not make that worse by more
        // than the constraints' own noise (detections: 1 cm × (1 + d) per axis).
        assert!(
            multi.position.mean < filter.position.mean + 0.05,
            "robot {}: {} vs {}",
            record.robot,
            multi.position.mean,
            filter.position.mean
        );
        let sequential = scored(&world, record, &log, &exchange, Variant::Multi(Topology::SequentialOdometry));
        assert_eq!(sequential.size.thesis_formula(), (sequential.size.nodes, sequential.size.factors));
        assert_eq!(sequential.dropped_out_of_order, 0);
    }
}

#[test]
fn robots_that_never_meet_stay_unconnected() {
    let options = options();
    let scenario_options = ScenarioOptions {
        robots: 2,
        duration_s: 4.0 * options.duration_s,
        seed: options.seed,
        downscale: options.downscale,
        world_size_m: None,
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    let mut scenario = scenario::preset("moon", &scenario_options).unwrap();
    scenario.duration_s = options.duration_s;
    // Robot 1 explores 40 m east: beyond marker range and with no shared ground.
    for robot in &mut scenario.robots {
        robot.drive.pause_s = 1.0;
    }
    for w in &mut scenario.robots[1].waypoints_m {
        w[0] += 40.0;
    }
    // Its start area cleared of rocks, as the preset clears the start ring.
    let start = scenario.robots[1].waypoints_m[0];
    scenario.terrain = scenario.terrain.clone().with_clear_area([start[0], start[1]], 8.0);
    let world: Arc<World> = World::build(&scenario).unwrap();
    let records = team_record::record_team(&world, &options).unwrap();
    let exchange = ExchangeOptions::default();
    let log = slam_eval::exchange(&world, &records, &exchange).unwrap();
    assert_eq!(log.detections, 0);
    assert_eq!(log.inter_robot_matches, 0);
    for record in &records {
        let result = scored(&world, record, &log, &exchange, Variant::Multi(Topology::LocalReference));
        // Each robot knows the other's submaps but places none of them.
        assert_eq!(result.connected, vec![record.robot as u16]);
        assert_eq!(result.size.submaps.len(), 1);
        assert_eq!(result.size.thesis_formula(), (result.size.nodes, result.size.factors));
    }
}
