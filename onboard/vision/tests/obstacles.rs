#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Obstacle classification (thesis §5.1.1) on ray-cast scenes with known steps and cliffs, and
//! the rolling local map. The evaluation on SGM depth of simulated Moon worlds is in
//! `sil/tests/obstacles_eval.rs`.

use nalgebra::{Isometry3, Rotation3, Translation3, UnitQuaternion};
use vision::obstacles::{LocalObstacleMap, ObstacleClassifier, ObstacleConfig, PixelLabels};
use vision::{DepthImage, StereoGeometry};

/// The sim's narrow camera at half resolution (f ≈ 1083 px at 1024 wide).
const GEOMETRY: StereoGeometry =
    StereoGeometry { fx_px: 541.5, fy_px: 541.5, cx_px: 255.5, cy_px: 126.5, baseline_m: 0.09 };
const W: usize = 512;
const H: usize = 254;

/// Camera 1.24 m above the origin looking along +x, tilted down 0.25 rad (the sim rover's head).
fn camera() -> Isometry3<f64> {
    // Optical (x right, y down, z forward) into x forward, y left, z up, then pitched down.
    let r_flu_optical =
        Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(0.0, 0.0, 1.0, -1.0, 0.0, 0.0, 0.0, -1.0, 0.0));
    let pitch = Rotation3::from_axis_angle(&nalgebra::Vector3::y_axis(), 0.25);
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, 1.24),
        UnitQuaternion::from_rotation_matrix(&(pitch * r_flu_optical)),
    )
}

/// Depth image of the height field `ground` by marching each ray in 5 mm steps to 12 m
/// (infinite beyond: nothing hit).
fn render(ground: impl Fn(f64, f64) -> f64) -> DepthImage {
    let t = camera();
    let mut depth = DepthImage::new(W, H);
    for v in 0..H {
        for u in 0..W {
            let ray = nalgebra::Vector3::new(
                (u as f64 - GEOMETRY.cx_px) / GEOMETRY.fx_px,
                (v as f64 - GEOMETRY.cy_px) / GEOMETRY.fy_px,
                1.0,
            );
            let mut z = 0.5;
            depth.depth_m[v * W + u] = loop {
                if z > 12.0 {
                    break f32::INFINITY;
                }
                let p = t * nalgebra::Point3::from(ray * z);
                if p.z <= ground(p.x, p.y) {
                    break z as f32;
                }
                z += 0.005;
            };
        }
    }
    depth
}

fn classify(depth: &DepthImage) -> (ObstacleClassifier, PixelLabels) {
    let mut classifier = ObstacleClassifier::new(ObstacleConfig::default()).unwrap();
    let mut labels = PixelLabels::default();
    classifier.classify(depth, &GEOMETRY, &camera(), &mut labels);
    (classifier, labels)
}

/// Local points of the labelled pixels.
fn labelled_points(depth: &DepthImage, labels: &PixelLabels, flag: u8) -> Vec<nalgebra::Point3<f64>> {
    let t = camera();
    (0..W * H)
        .filter(|&i| labels.flags[i] & flag != 0)
        .map(|i| {
            let p = GEOMETRY.point_at((i % W) as f64, (i / W) as f64, f64::from(depth.depth_m[i]));
            t * nalgebra::Point3::from(p)
        })
        .collect()
}

#[test]
fn a_step_taller_than_h_max_is_an_obstacle_and_its_foot_is_not() {
    // A 0.3 m high block from x = 3.0 to 3.4 m, |y| < 0.5 m, on flat ground.
    let block = |x: f64, y: f64| if (3.0..3.4).contains(&x) && y.abs() < 0.5 { 0.3 } else { 0.0 };
    let depth = render(block);
    let (classifier, labels) = classify(&depth);
    let points = labelled_points(&depth, &labels, PixelLabels::OBSTACLE);
    assert!(points.len() > 100, "{} obstacle pixels", points.len());
    // Upper-part rule: every obstacle point is above h_max / 2 and on or at the block.
    for p in &points {
        assert!(p.z > 0.075 && (2.9..3.5).contains(&p.x) && p.y.abs() < 0.6, "{p:?}");
    }
    let mut centres = Vec::new();
    classifier.height_map().obstacle_centres(&mut centres);
    assert!(centres.iter().all(|c| (2.85..3.55).contains(&c.x) && c.y.abs() < 0.65), "{centres:?}");
    assert!(centres.iter().any(|c| c.y.abs() < 0.2 && (2.9..3.1).contains(&c.x)));
}

#[test]
fn a_single_cell_spike_needs_the_support_rule_to_be_ignored() {
    // A 0.5 m pillar filling one 5 cm cell: the shape of an SGM blunder patch in the height map.
    // The thesis's max − min window makes it a step; with two supporting cells per side it is not.
    let pillar = |x: f64, y: f64| if (3.0..3.05).contains(&x) && (0.0..0.05).contains(&y) { 0.5 } else { 0.0 };
    let depth = render(pillar);
    let steps = |support: usize| {
        let config = ObstacleConfig { step_support_cells: support, ..ObstacleConfig::default() };
        let mut classifier = ObstacleClassifier::new(config).unwrap();
        let mut labels = PixelLabels::default();
        classifier.classify(&depth, &GEOMETRY, &camera(), &mut labels).step_cells
    };
    assert!(steps(1) > 0);
    assert_eq!(steps(ObstacleConfig::default().step_support_cells), 0);
}

#[test]
fn a_step_lower_than_h_max_is_not_an_obstacle() {
    let block = |x: f64, y: f64| if (3.0..3.4).contains(&x) && y.abs() < 0.5 { 0.1 } else { 0.0 };
    let depth = render(block);
    let (classifier, labels) = classify(&depth);
    assert_eq!(labels.flags.iter().filter(|&&f| f & PixelLabels::OBSTACLE != 0).count(), 0);
    assert!(classifier.height_map().cells().iter().all(|c| !c.is_obstacle()));
}

#[test]
fn a_cliff_edge_is_a_negative_obstacle_at_its_top() {
    // The minimal slope of a cliff is bounded by the depression of the ray grazing its rim, so
    // with the camera 1.24 m high and the view starting at 2.38 m only rims nearer than
    // 1.24 / tan 25° = 2.66 m can exceed the 25° limit. A 1 m drop at 3.5 m cannot:
    let far = render(|x, _| if x < 3.5 { 0.0 } else { -1.0 });
    let (_, labels) = classify(&far);
    assert_eq!(labels.flags.iter().filter(|&&f| f & PixelLabels::NEGATIVE_EDGE != 0).count(), 0);
    // A 1 m drop at 2.5 m (rays at 26.4°) is a cliff.
    let depth = render(|x, _| if x < 2.5 { 0.0 } else { -1.0 });
    let (_, labels) = classify(&depth);
    let edges = labelled_points(&depth, &labels, PixelLabels::NEGATIVE_EDGE);
    assert!(edges.len() > W / 2, "{} edge pixels", edges.len());
    for p in &edges {
        assert!((p.x - 2.5).abs() < 0.05 && p.z.abs() < 0.01, "{p:?}");
    }
    // A gentle 10° descent instead of the drop is no cliff.
    let depth = render(|x, _| if x < 2.5 { 0.0 } else { -(x - 2.5) * 10f64.to_radians().tan() });
    let (_, labels) = classify(&depth);
    assert_eq!(labels.flags.iter().filter(|&&f| f & PixelLabels::NEGATIVE_EDGE != 0).count(), 0);
}

#[test]
fn a_drop_hidden_behind_a_far_rim_is_an_edge_with_hidden_drops() {
    let config = ObstacleConfig { hidden_drop_m: 0.15, ..ObstacleConfig::default() };
    let classify_with = |depth: &DepthImage, config: ObstacleConfig| {
        let mut classifier = ObstacleClassifier::new(config).unwrap();
        let mut labels = PixelLabels::default();
        classifier.classify(depth, &GEOMETRY, &camera(), &mut labels);
        labels
    };
    // A 1 m drop at 2.8 m, beyond the 2.66 m the slope rule can see (and within this half-size
    // camera's 3.2 m range cutoff): the floor seen over the rim is 1 m lower, the ground
    // between out of view.
    let far = render(|x, _| if x < 2.8 { 0.0 } else { -1.0 });
    assert_eq!(classify(&far).1.flags.iter().filter(|&&f| f & PixelLabels::NEGATIVE_EDGE != 0).count(), 0);
    let labels = classify_with(&far, config);
    let edges = labelled_points(&far, &labels, PixelLabels::NEGATIVE_EDGE);
    assert!(edges.len() > W / 2, "{} edge pixels", edges.len());
    assert!(edges.iter().all(|p| (p.x - 2.8).abs() < 0.05 && p.z.abs() < 0.01));
    // A shallow ditch (0.1 m, less than h_max) and a gentle descent the camera sees: none.
    for ground in [
        &(|x: f64, _: f64| if (2.8..3.2).contains(&x) { -0.1 } else { 0.0 }) as &dyn Fn(f64, f64) -> f64,
        &|x: f64, _: f64| if x < 2.4 { 0.0 } else { -(x - 2.4) * 10f64.to_radians().tan() },
    ] {
        let depth = render(ground);
        let labels = classify_with(&depth, config);
        assert_eq!(labels.flags.iter().filter(|&&f| f & PixelLabels::NEGATIVE_EDGE != 0).count(), 0);
    }
    // A 0.3 m ditch from 2.6 to 3.6 m whose dark interior stereo leaves unmatched, its far lip
    // level with the rim: no slope and no drop is seen; bridged across the unmatched pixels, the
    // 1 m of ground out of view is a gap the wheel would cross blind.
    let mut depth = render(|x, _| if (2.6..3.6).contains(&x) { -0.3 } else { 0.0 });
    let t = camera();
    for v in 0..H {
        for u in 0..W {
            let z = depth.depth_m[v * W + u];
            let ray = nalgebra::Vector3::new(
                (u as f64 - GEOMETRY.cx_px) / GEOMETRY.fx_px,
                (v as f64 - GEOMETRY.cy_px) / GEOMETRY.fy_px,
                1.0,
            );
            if z.is_finite() && (t * nalgebra::Point3::from(ray * f64::from(z))).z < -0.02 {
                depth.depth_m[v * W + u] = f32::NAN;
            }
        }
    }
    let count = |labels: &PixelLabels| labels.flags.iter().filter(|&&f| f & PixelLabels::NEGATIVE_EDGE != 0).count();
    assert_eq!(count(&classify_with(&depth, config)), 0, "an unmatched run is not bridged by default");
    let bridged = classify_with(&depth, ObstacleConfig { bridge_invalid_px: 64, ..config });
    let edges = labelled_points(&depth, &bridged, PixelLabels::NEGATIVE_EDGE);
    assert!(edges.len() > W / 2, "{}", edges.len());
    assert!(edges.iter().all(|p| (p.x - 2.6).abs() < 0.05), "{:?}", edges.first());
}

#[test]
fn zero_disparity_beyond_an_edge_counts_as_a_cliff_and_nan_does_not() {
    // Ground ending at 3.5 m with nothing behind (infinite depth): rays just past the rim
    // descend at atan(1.24 / 3.5) ≈ 19.5°, below the 25° limit: no obstacle.
    let far = render(|x, _| if x < 3.5 { 0.0 } else { -100.0 });
    let (_, labels) = classify(&far);
    assert_eq!(labels.flags.iter().filter(|&&f| f & PixelLabels::NEGATIVE_EDGE != 0).count(), 0);
    // At 2.5 m they descend at ≈ 26.4°: steeper than the limit, an obstacle.
    let near = render(|x, _| if x < 2.5 { 0.0 } else { -100.0 });
    let (_, labels) = classify(&near);
    let edges = labelled_points(&near, &labels, PixelLabels::NEGATIVE_EDGE);
    assert!(edges.len() > W / 2 && edges.iter().all(|p| (p.x - 2.5).abs() < 0.05), "{}", edges.len());
    // The same image with the void marked invalid (NaN) instead: no pair, no edge.
    let mut invalid = near.clone();
    invalid.depth_m.iter_mut().filter(|z| z.is_infinite()).for_each(|z| *z = f32::NAN);
    let (_, labels) = classify(&invalid);
    assert_eq!(labels.flags.iter().filter(|&&f| f & PixelLabels::NEGATIVE_EDGE != 0).count(), 0);
}

#[test]
fn local_map_scrolls_and_low_passes() {
    let depth = render(|x: f64, y: f64| if (3.0..3.4).contains(&x) && y.abs() < 0.5 { 0.3 } else { 0.0 });
    let (classifier, _) = classify(&depth);
    let mut map = LocalObstacleMap::new(0.05, 200, 0.5);
    map.recentre(0.0, 0.0);
    map.integrate(classifier.height_map(), 0);
    assert!(map.is_obstacle_at(3.02, 0.0));
    let first = map.traversability_at(3.02, 0.0).unwrap();
    // A flat image 0.1 s later pulls the cell towards free by α = 1 − e^(−0.2).
    let (flat, _) = classify(&render(|_, _| 0.0));
    map.integrate(flat.height_map(), 100_000_000);
    let blended = map.traversability_at(3.02, 0.0).unwrap();
    let now = flat.height_map().cells()[flat.height_map().index_of(3.02, 0.0).unwrap()].traversability;
    let alpha = 1.0 - (-0.2f32).exp();
    assert!((blended - (first + alpha * (now - first))).abs() < 1e-5, "{first} {now} {blended}");
    // Scrolling 4 m forward keeps cells still inside, forgets those that left.
    map.recentre(4.0, 0.0);
    assert_eq!(map.traversability_at(3.02, 0.0), Some(blended));
    assert_eq!(map.traversability_at(1.0, 0.0), None);
    map.recentre(0.0, 0.0);
    assert_eq!(map.traversability_at(3.02, 0.0), Some(blended));
    assert_eq!(map.traversability_at(0.5, 0.0), None, "scrolled-in cells start unknown");
}

#[test]
fn local_map_holds_measured_edges_and_releases_unseen_ones_on_request() {
    let classify_with = |depth: &DepthImage, config: ObstacleConfig| {
        let mut classifier = ObstacleClassifier::new(config).unwrap();
        let mut labels = PixelLabels::default();
        classifier.classify(depth, &GEOMETRY, &camera(), &mut labels);
        (classifier, labels)
    };
    let edge_point = |depth: &DepthImage, labels: &PixelLabels| {
        let points = labelled_points(depth, labels, PixelLabels::NEGATIVE_EDGE);
        assert!(!points.is_empty());
        (points[points.len() / 2].x, points[points.len() / 2].y)
    };
    // A cliff whose slope the camera measures (2.5 m), and a rim at 2.8 m whose drop only the
    // hidden-drop rule infers from the floor seen beyond it.
    let cliff = render(|x, _| if x < 2.5 { 0.0 } else { -100.0 });
    let (measured, labels) = classify(&cliff);
    let measured_at = edge_point(&cliff, &labels);
    let rim = render(|x, _| if x < 2.8 { 0.0 } else { -1.0 });
    let (unseen, labels) = classify_with(&rim, ObstacleConfig { hidden_drop_m: 0.15, ..ObstacleConfig::default() });
    let unseen_at = edge_point(&rim, &labels);
    assert!(measured.height_map().cells().iter().any(|c| c.negative_edge && c.edge_measured));
    assert!(unseen.height_map().cells().iter().all(|c| !c.edge_measured));
    // Then the flat ground seen over both cells, ten times at 10 Hz.
    let (flat, _) = classify(&render(|_, _| 0.0));
    for release in [false, true] {
        let mut map = LocalObstacleMap::new(0.05, 200, 0.5).releasing_unseen_edges(release);
        map.recentre(0.0, 0.0);
        map.integrate(measured.height_map(), 0);
        map.integrate(unseen.height_map(), 0);
        assert!(map.is_obstacle_at(measured_at.0, measured_at.1) && map.is_obstacle_at(unseen_at.0, unseen_at.1));
        for k in 1..=10 {
            map.integrate(flat.height_map(), k * 100_000_000);
        }
        assert!(map.is_obstacle_at(measured_at.0, measured_at.1), "a measured edge is held");
        assert_eq!(map.is_obstacle_at(unseen_at.0, unseen_at.1), !release, "release {release}");
    }
}
