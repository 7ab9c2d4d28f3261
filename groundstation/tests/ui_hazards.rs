//! The hazard layer on the ground, from packets to pixels: two robots' poses, a submap match and
//! their hazard cells go through real protocol endpoints into the team model; the map panel draws
//! the model's view headless (egui_kittest); the squares it paints sit where the robots' poses put
//! the cells, computed here independently, and the "hazards" box hides them. A recorded feed of
//! the same packets replays to the same cells.
#![allow(clippy::unwrap_used, clippy::expect_used)]

mod model_common;

use egui::{Color32, Pos2, Shape, Vec2};
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable as _;
use groundstation::model::{ModelConfig, TeamModel};
use groundstation::replay::Replay;
use groundstation::ui::{self, UiState, palette};
use groundstation::view::{TeamView, UiAction};
use hal::feedlog::FeedLogWriter;
use model_common::*;
use nalgebra::{Isometry3, Point3};
use protocol::message::HazardCells;
use protocol::{RobotId, SubmapId};

/// Robot 2's first submap in robot 1's (the reference) frame: the match the test sends.
fn t_1_2() -> Isometry3<f64> {
    planar(10.0, 5.0, std::f64::consts::FRAC_PI_2)
}

fn body(robot: u8) -> Isometry3<f64> {
    if robot == 1 { planar(2.0, 0.0, 0.0) } else { planar(1.0, 0.5, 30f64.to_radians()) }
}

fn cells(robot: u8) -> Vec<[i8; 2]> {
    if robot == 1 { vec![[5, 5]] } else { vec![[10, 0], [0, 5], [-3, -4], [12, 7]] }
}

fn hazards(robot: u8, stamp_ns: u64) -> HazardCells {
    let mut list = heapless::Vec::new();
    list.extend_from_slice(&cells(robot)).unwrap();
    HazardCells {
        robot: RobotId(robot),
        stamp_ns,
        submap: SubmapId { robot: RobotId(robot), index: 0 },
        t_submap_body: pose3(&body(robot)),
        cell_size_m: 0.1,
        omitted: if robot == 2 { 17 } else { 0 },
        cells: list,
    }
}

/// Where the cells must land in robot 1's frame: the body pose in the reference frame applied to
/// the offsets (planar bodies: the heading frame is the body frame).
fn expected_ref_m(robot: u8) -> Vec<[f64; 2]> {
    let t_ref_submap = if robot == 1 { Isometry3::identity() } else { t_1_2() };
    let t_ref_body = t_ref_submap * body(robot);
    cells(robot)
        .iter()
        .map(|&[i, j]| {
            let p = t_ref_body * Point3::new(f64::from(i) * 0.1, f64::from(j) * 0.1, 0.0);
            [p.x, p.y]
        })
        .collect()
}

/// 4 s of two robots: poses every second, the match at 1 s, hazard cells at 3 s. Returns the
/// packets as received.
fn run(model: &mut TeamModel) -> Vec<(u64, Vec<u8>)> {
    let (mut r1, mut r2) = (SimRobot::new(1, None), SimRobot::new(2, None));
    let mut log = Vec::new();
    for s in 0..=4u64 {
        let now = s * S;
        for (robot, sim) in [(1, &mut r1), (2, &mut r2)] {
            sim.send(now, telemetry(robot, now, 0));
            sim.send(now, pose(robot, now, 0, &body(robot)));
            if s == 3 {
                sim.send(now, hazards(robot, now));
            }
        }
        if s == 1 {
            r2.send(now, submap_match(2, 0, (1, 0), (2, 0), &t_1_2()));
        }
        for packet in exchange(model, &mut [&mut r1, &mut r2], now) {
            log.push((now, packet));
        }
        model.tick(now);
    }
    model.settle(4 * S);
    log
}

fn close(a: [f64; 2], b: [f64; 2], tolerance_m: f64) -> bool {
    (a[0] - b[0]).abs() < tolerance_m && (a[1] - b[1]).abs() < tolerance_m
}

fn assert_cells(view: &TeamView) {
    for robot in [1, 2] {
        let r = &view.robots[&robot];
        assert!(r.connected, "robot {robot}");
        let h = r.hazards.as_ref().expect("hazards in the view");
        assert!(h.exact && (h.cell_m - 0.1).abs() < 1e-6);
        assert_eq!((h.received_ns, h.omitted), (3 * S, if robot == 2 { 17 } else { 0 }));
        assert_eq!(h.cells_ref_m.len(), cells(robot).len());
        for (got, want) in h.cells_ref_m.iter().zip(expected_ref_m(robot)) {
            assert!(close(*got, want, 1e-6), "robot {robot}: {got:?} vs {want:?}");
        }
    }
}

#[test]
fn the_model_places_each_robots_cells_with_its_pose() {
    let mut model = TeamModel::new(ModelConfig { auth_key: None, source: "test".into() });
    run(&mut model);
    assert_cells(model.view());
}

struct State {
    view: TeamView,
    ui: UiState,
    actions: Vec<UiAction>,
}

/// The hazard squares the last frame painted: one quad (4 vertices) per cell, in `colour`.
fn painted_quads(h: &Harness<'_, State>, colour: Color32) -> Vec<[Pos2; 4]> {
    let mut quads = Vec::new();
    for clipped in &h.output().shapes {
        let Shape::Mesh(mesh) = &clipped.shape else { continue };
        if mesh.vertices.is_empty() || mesh.vertices.iter().any(|v| v.color != colour) {
            continue;
        }
        assert_eq!(mesh.vertices.len() % 4, 0);
        assert_eq!(mesh.indices.len(), mesh.vertices.len() / 4 * 6, "two triangles per cell");
        for quad in mesh.vertices.chunks_exact(4) {
            quads.push([quad[0].pos, quad[1].pos, quad[2].pos, quad[3].pos]);
        }
    }
    quads
}

#[test]
fn the_map_draws_the_models_hazard_cells_where_the_poses_put_them() {
    let mut model = TeamModel::new(ModelConfig { auth_key: None, source: "test".into() });
    run(&mut model);
    let view = model.view().clone();
    let mut h = Harness::builder().with_size(Vec2::new(1600.0, 1100.0)).build_ui_state(
        |ui, s: &mut State| {
            let actions = ui::show(ui, &s.view, &mut s.ui);
            s.actions.extend(actions);
        },
        State { view, ui: UiState::default(), actions: Vec::new() },
    );
    // 40 px per m around both robots: a 0.1 m cell is 4 px wide.
    h.state_mut().ui.map.set_view([6.0, 3.0], 40.0);
    h.run();
    let t = h.state().ui.map.last_transform().unwrap();

    let quads = painted_quads(&h, palette::HAZARD);
    let mut want: Vec<[f64; 2]> = expected_ref_m(1);
    want.extend(expected_ref_m(2));
    assert_eq!(quads.len(), want.len(), "one square per cell of both robots");
    for quad in &quads {
        let centre =
            Pos2::new(quad.iter().map(|p| p.x).sum::<f32>() / 4.0, quad.iter().map(|p| p.y).sum::<f32>() / 4.0);
        let at = t.screen_to_world(centre);
        assert!(want.iter().any(|w| close(at, *w, 0.005)), "a square at {at:?}, cells at {want:?}");
        // 0.1 m at 40 px/m, turned with the robot's heading.
        assert!(((quad[1] - quad[0]).length() - 4.0).abs() < 1e-3, "{quad:?}");
    }
    for w in &want {
        let s = t.world_to_screen(w[0], w[1]);
        assert!(quads.iter().any(|q| (q[0] - s).length() < 4.0), "no square drawn at {w:?}");
    }
    // Robot 2 heads 90° + 30° in robot 1's frame: its squares are turned by that (screen y down).
    let r2 = t.world_to_screen(expected_ref_m(2)[0][0], expected_ref_m(2)[0][1]);
    let quad = quads.iter().find(|q| (q[0] - r2).length() < 4.0).unwrap();
    let edge = quad[1] - quad[0];
    let angle = (-edge.y).atan2(edge.x).to_degrees();
    assert!((angle - 120.0).abs() < 0.1, "{angle}");

    // Old pictures fade; the "hazards" box hides the layer.
    h.state_mut().view.now_ns += 10 * S;
    h.run();
    assert!(painted_quads(&h, palette::HAZARD).is_empty());
    assert_eq!(painted_quads(&h, palette::HAZARD_OLD).len(), want.len());
    h.get_by_label("hazards").click();
    h.run();
    assert!(!h.state().ui.map.layers.hazards);
    assert!(painted_quads(&h, palette::HAZARD_OLD).is_empty() && painted_quads(&h, palette::HAZARD).is_empty());
    assert!(h.state().actions.is_empty());
}

#[test]
fn a_recorded_feed_replays_the_hazard_cells() {
    let mut live = TeamModel::new(ModelConfig { auth_key: None, source: "test".into() });
    let packets = run(&mut live);
    let dir = std::env::temp_dir().join(format!("gs-hazards-replay-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut writer = FeedLogWriter::create(dir.join("ground_feed.log")).unwrap();
    for (t, p) in &packets {
        let source = protocol::codec::decode_header(p).unwrap().0.source.0;
        writer.append(*t, source, p).unwrap();
    }
    writer.flush().unwrap();
    drop(writer);
    let mut replay = Replay::open(&dir, ModelConfig { auth_key: None, source: "replay".into() }).unwrap();
    replay.seek(replay.end_ns());
    assert_cells(replay.model().view());
    // Before the hazard message, none.
    replay.seek(2 * S);
    assert!(replay.model().view().robots.values().all(|r| r.hazards.is_none()));
    std::fs::remove_dir_all(&dir).ok();
}
