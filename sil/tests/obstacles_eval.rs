#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Obstacle classification (thesis §5.1.1) on SGM depth of a simulated Moon world, scored
//! against the simulator's true obstacles with [`sil::obstacles`]: deliberate viewpoints facing
//! each rock, and approach runs towards each rock.

use vision::obstacles::ObstacleConfig;

/// Measured on seed 1 (deterministic: seeded render noise, deterministic SGM); not widened.
const ROCK_VIEWS: usize = 11;
const ROCKS_SEEN: usize = 11;
/// With the on-board stereo (SGM uniqueness 15 %, speckle filter) and the two-cell step support:
/// 8 of 11; the three misses are rocks less than 0.1 m above h_max. (Before the stereo filters
/// 9 of 11, at 28 of 43 clusters on listed obstacles.)
const ROCKS_FOUND: usize = 8;
/// All 12 clusters from the rock viewpoints lie on a rock > h_max or a negative edge.
const LISTED_PERCENT: usize = 100;
const OPEN_CLUSTERS: usize = 1;

#[test]
fn sgm_depth_finds_moon_rocks_from_deliberate_viewpoints() {
    // One viewpoint per rock taller than h_max (camera 2.5 m away, facing it) and two on open
    // ground of a 60 m Moon world; full-resolution render, SGM, ground-truth poses.
    use sil::obstacles::{Aim, Evaluator, Tally, Truth, moon_world, viewpoints};
    let config = ObstacleConfig::default();
    let world = moon_world(1, 60.0).unwrap();
    let mut truth = Truth::of(&world, config.max_step_m);
    truth.edge_targets.clear();
    let views = viewpoints(&world, &truth, 1, 2, 1);
    let mut evaluator = Evaluator::new(&world, &truth, config).unwrap();
    let (mut rocks, mut open) = (Tally::default(), Tally::default());
    for (i, view) in views.iter().enumerate() {
        let tally = if view.aim == Aim::Rock { &mut rocks } else { &mut open };
        evaluator.evaluate(view, 1_000_003 + i as u64, tally).unwrap();
    }
    assert_eq!((rocks.frames, open.frames), (ROCK_VIEWS, 2));
    // Measured (README table): rocks found, and clusters explained by the listed obstacles.
    assert!(rocks.rocks_found >= ROCKS_FOUND && rocks.rocks == ROCKS_SEEN, "{rocks:?}");
    assert!(rocks.clusters_listed * 100 >= LISTED_PERCENT * rocks.clusters, "{rocks:?}");
    assert!(open.clusters <= OPEN_CLUSTERS, "{open:?}");
}

/// Measured on seed 1 (deterministic): 10 of the 18 rocks taller than h_max have a straight
/// approach path on free ground; every one is detected during its run, 9 of them already from
/// 4.5 m; 85 of the 88 clusters in the run frames lie on listed obstacles.
const APPROACHED_ROCKS: usize = 10;
const FOUND_FROM_4_5_M: usize = 9;

#[test]
fn every_rock_is_detected_while_the_rover_drives_towards_it() {
    // The navigation claim behind the rolling local map: a rock the step rule cannot confirm from
    // far (its threshold h_max + Δd grows with range) is confirmed as the rover comes nearer,
    // before its foot leaves the image. Camera from 5 m to 2.5 m, a frame every 0.5 m.
    use sil::obstacles::{APPROACH_M, Evaluator, Tally, Truth, approaches, moon_world};
    let config = ObstacleConfig::default();
    let world = moon_world(1, 60.0).unwrap();
    let mut truth = Truth::of(&world, config.max_step_m);
    truth.edge_targets.clear();
    let robot = &world.robots[0];
    let runs = approaches(&world, &truth, config.max_step_m, APPROACH_M, robot.setup.tilt_rad, 1);
    assert_eq!(runs.len(), APPROACHED_ROCKS);
    let mut evaluator = Evaluator::new(&world, &truth, config).unwrap();
    let mut tally = Tally::default();
    let found_from_m: Vec<Option<f64>> = runs
        .iter()
        .enumerate()
        .map(|(r, run)| evaluator.drive(run, 1_000_003 + (r * 64) as u64, &mut tally).unwrap().found_at_m)
        .collect();
    assert!(found_from_m.iter().all(Option::is_some), "{found_from_m:?}");
    let early = found_from_m.iter().flatten().filter(|&&d| d >= 4.5).count();
    assert!(early >= FOUND_FROM_4_5_M, "{found_from_m:?}");
    assert!(
        tally.clusters_listed + 3 >= tally.clusters,
        "clusters {} listed {}",
        tally.clusters,
        tally.clusters_listed
    );
}
