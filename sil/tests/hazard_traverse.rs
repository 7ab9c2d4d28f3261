#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Navigation's metric ([`sil::obstacles::traverse`]) on a simulated Moon world: the drives head
//! into the hazards they are about, and a tall rock and a cliff edge are in the rover's rolling
//! local map when it reaches stopping distance (full-resolution render, on-board SGM, the
//! firmware's gaze policy and hidden-drop rule, ground-truth poses).

use sil::obstacles::traverse::{Traverse, TraverseOptions, TraversePath, traverse_paths};
use sil::obstacles::{Aim, Truth, moon_world};
use vision::obstacles::ObstacleConfig;

fn config() -> ObstacleConfig {
    ObstacleConfig { hidden_drop_m: 0.3, ..ObstacleConfig::default() }
}

fn paths(world: &sim::world::World, options: &TraverseOptions) -> Vec<TraversePath> {
    let mut targets = Truth::of(world, config().max_step_m);
    targets.keep_drops(world, options.edge_drop_m);
    traverse_paths(world, &targets, &config(), options, 1)
}

#[test]
fn every_edge_drive_heads_into_a_drop_and_cliffs_are_told_from_slopes() {
    let world = moon_world(1, 60.0).unwrap();
    let options = TraverseOptions::default();
    let paths = paths(&world, &options);
    let edges: Vec<_> = paths.iter().filter(|p| p.aim == Aim::Edge).collect();
    assert!(edges.len() >= 20, "{} edge drives", edges.len());
    let slope = config().max_slope_rad;
    for path in &edges {
        let profile = path.profile_m(&world, slope);
        // Not along the rim nor up from below: the ground falls 0.3 m within 1 m ahead.
        assert!(profile.drop_m >= options.edge_drop_m, "{:?}: {profile:?}", path.target_m);
        assert_eq!(path.steep, profile.steep_drop_m >= options.edge_drop_m);
        assert!(profile.steep_drop_m <= profile.drop_m);
    }
    // Moon craters have both: rims steeper than the 25° slope limit and gentler ones.
    let steep = edges.iter().filter(|p| p.steep).count();
    assert!(steep > 0 && steep < edges.len(), "{steep} of {} steep", edges.len());
}

#[test]
fn a_tall_rock_and_a_cliff_are_in_the_local_map_at_the_stopping_distance() {
    let world = moon_world(1, 60.0).unwrap();
    let options = TraverseOptions::default();
    let paths = paths(&world, &options);
    let rock = paths
        .iter()
        .filter(|p| p.aim == Aim::Rock)
        .max_by(|a, b| a.excess_height_m.total_cmp(&b.excess_height_m))
        .expect("a rock drive");
    let cliff = paths.iter().find(|p| p.steep).expect("a steep edge drive");
    let truth = Truth::of(&world, config().max_step_m);
    let mut traverse = Traverse::new(&world, &truth, config(), options).unwrap();
    let stop_m = options.drive.stopping_distance_m();
    for (path, seed) in [(rock, 11), (cliff, 12)] {
        let outcome = traverse.drive(path, seed).unwrap();
        assert!(outcome.found_at_stop, "{:?} at {:?}: {outcome:?}", path.aim, path.target_m);
        // Marked from farther than the stop, and held since.
        assert!(outcome.first_found_m.is_some_and(|d| d > stop_m + 1.0), "{outcome:?}");
        let open = outcome.hazard_cells - outcome.cells_true - outcome.cells_beside - outcome.cells_falling;
        assert!(outcome.cells_listed > 0 && outcome.cells_true <= outcome.hazard_cells, "{outcome:?}");
        // Measured: no false cell on open ground in these two drives.
        assert_eq!(open, 0, "{outcome:?}");
    }
}
