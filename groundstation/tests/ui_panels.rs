//! Headless UI tests (egui_kittest, no display): the panels show the view fed to them, and the
//! operator's clicks become the right `UiAction`s.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;

use egui::{Pos2, Vec2};
use egui_kittest::Harness;
use egui_kittest::kittest::{NodeT as _, Queryable as _};
use groundstation::ui::{self, UiState, map::MAP_LABEL};
use groundstation::view::{
    CommandState, CommandView, EdgeKind, EdgeView, HeightGrid, LinkSample, LinkView, MapPoints, ReplayView, RobotView,
    Staleness, SubmapOutline, TeamView, UiAction,
};
use nalgebra::{Isometry3, Matrix2, Vector3};
use protocol::message::{CommandOutcome, FilterHealth, FilterStatus, Mode, ResourceUsage, TaskStats};

const S: u64 = 1_000_000_000;
const CELL_M: f64 = 0.5;

fn robot(id: u8, staleness: Staleness, last_message_ns: u64, mode: Mode) -> RobotView {
    let trajectory_ref_m: Vec<[f64; 3]> =
        (0..500).map(|i| [f64::from(id) * 5.0 + i as f64 * 0.05, (i as f64 * 0.02).sin() * 4.0, 0.0]).collect();
    let last = *trajectory_ref_m.last().unwrap();
    RobotView {
        robot: id,
        connected: id != 4,
        mode: Some(mode),
        // Robot 2 reads devices and has lost its wheels; the others report none.
        sensors: (id == 2).then_some(protocol::message::SensorAvailability { imu: true, wheels: false, head: true }),
        filter: Some(FilterHealth {
            status: FilterStatus::Nominal,
            position_std_m: 0.12,
            yaw_std_rad: 0.02,
            vo_age_ms: 40,
        }),
        tasks: vec![TaskStats {
            task: "filter".into(),
            period_us: 5_000,
            releases: 1000,
            deadline_overruns: 3,
            jitter_p99_us: 120,
            jitter_max_us: 800,
        }],
        queues: vec![],
        links: vec![],
        resources: Some(ResourceUsage { cpu_permille: 455, mem_used_kib: 1 << 20, mem_total_kib: 4 << 20 }),
        auth_rejections: 0,
        last_message_ns: Some(last_message_ns),
        staleness,
        trajectory_ref_m: if id == 4 { vec![] } else { trajectory_ref_m },
        t_ref_body: (id != 4).then(|| Isometry3::new(Vector3::new(last[0], last[1], 0.0), Vector3::new(0.0, 0.0, 0.5))),
        position_cov_xy_m2: Some(Matrix2::new(0.09, 0.01, 0.01, 0.04)),
        submaps: vec![SubmapOutline {
            index: 0,
            t_ref_submap: Isometry3::new(Vector3::new(f64::from(id) * 5.0, 0.0, 0.0), Vector3::new(0.0, 0.0, 0.3)),
            bounds_submap_m: Some([-5.0, -5.0, 15.0, 5.0]),
        }],
        hazards: None,
    }
}

fn grid(revision: u64) -> HeightGrid {
    let (width, height) = (120, 80);
    let n = width * height;
    HeightGrid {
        origin_xy_m: [-10.0, -20.0],
        cell_m: CELL_M,
        width,
        height,
        height_m: (0..n).map(|i| if i.is_multiple_of(17) { f32::NAN } else { (i % width) as f32 * 0.01 }).collect(),
        obstacle: (0..n).map(|i| i.is_multiple_of(97)).collect(),
        revision,
    }
}

fn team_view() -> TeamView {
    let now_ns = 100 * S;
    let mut robots = BTreeMap::new();
    robots.insert(1, robot(1, Staleness::Fresh, now_ns - S / 2, Mode::Autonomous));
    robots.insert(2, robot(2, Staleness::Stale, now_ns - 7 * S, Mode::Waypoint));
    robots.insert(3, robot(3, Staleness::Lost, now_ns - 45 * S, Mode::Safe));
    robots.insert(4, robot(4, Staleness::Fresh, now_ns - S, Mode::Idle));
    let samples: VecDeque<LinkSample> = (0..60)
        .map(|i| LinkSample {
            t_s: f64::from(i),
            rx_bytes_per_s_by_class: [
                ("Telemetry".to_owned(), 300.0),
                ("SubmapChunk".to_owned(), 2000.0 + f64::from(i)),
            ]
            .into_iter()
            .collect(),
            tx_bytes_per_s_by_class: [("Telemetry".to_owned(), 310.0)].into_iter().collect(),
            rtt_ms: Some(4000.0),
            loss_permille: Some(5.0),
            robot_queue_depth: 3,
            ground_queue_depth: 1,
            outage: (20..25).contains(&i) || i == 59,
        })
        .collect();
    TeamView {
        now_ns,
        reference_robot: Some(1),
        robots,
        edges: vec![
            EdgeView { kind: EdgeKind::RobotDetection, from_ref_m: [5.0, 0.0, 0.0], to_ref_m: [10.0, 0.0, 0.0] },
            EdgeView { kind: EdgeKind::SubmapMatch, from_ref_m: [10.0, 0.0, 0.0], to_ref_m: [15.0, 1.0, 0.0] },
        ],
        map: Some(Arc::new(grid(1))),
        points: Arc::new(MapPoints {
            points_ref_m: (0..2000).map(|i| [i as f32 * 0.01, (i % 50) as f32 * 0.1, 0.2]).collect(),
            obstacle: (0..2000u32).map(|i| i.is_multiple_of(10)).collect(),
            revision: 1,
        }),
        link: LinkView { samples, outages: 2, packets_received: 1234, packets_rejected: 5 },
        commands: vec![
            CommandView {
                id: 7,
                target: 1,
                summary: "set mode Safe".into(),
                state: CommandState::Queued,
                queued_ns: now_ns - 3 * S,
            },
            CommandView {
                id: 8,
                target: 2,
                summary: "waypoint (12.0, -3.5) m".into(),
                state: CommandState::Acknowledged { outcome: CommandOutcome::Executed, rtt_ms: 3900 },
                queued_ns: now_ns - 10 * S,
            },
            CommandView {
                id: 9,
                target: 2,
                summary: "resend submap 3".into(),
                state: CommandState::TimedOut,
                queued_ns: now_ns - 60 * S,
            },
        ],
        can_command: true,
        replay: None,
        notices: vec!["waypoint refused: robot 4 is not connected to robot 1's frame".into()],
        source: "udp://127.0.0.1:47800".into(),
    }
}

struct State {
    view: TeamView,
    ui: UiState,
    actions: Vec<UiAction>,
}

fn harness(view: TeamView) -> Harness<'static, State> {
    Harness::builder().with_size(Vec2::new(1600.0, 1100.0)).build_ui_state(
        |ui, s: &mut State| {
            let actions = ui::show(ui, &s.view, &mut s.ui);
            s.actions.extend(actions);
        },
        State { view, ui: UiState::default(), actions: Vec::new() },
    )
}

fn click_at(h: &mut Harness<'_, State>, pos: Pos2) {
    h.event(egui::Event::PointerMoved(pos));
    for pressed in [true, false] {
        h.event(egui::Event::PointerButton {
            pos,
            button: egui::PointerButton::Primary,
            pressed,
            modifiers: egui::Modifiers::default(),
        });
    }
    h.run();
}

#[test]
fn robots_panel_shows_ids_modes_and_staleness() {
    let h = harness(team_view());
    for id in 1..=4 {
        h.get_by_label(&format!("Robot {id}"));
    }
    h.get_by_label("mode: Autonomous");
    h.get_by_label("mode: Waypoint");
    h.get_by_label("mode: Safe");
    // Stale shows its age, lost says so.
    h.get_by_label("STALE 7 s");
    h.get_by_label("LOST");
    assert_eq!(h.query_all_by_label("OK").count(), 2);
    h.get_by_label("not connected to robot 1's frame");
    // The devices of the robot that reads devices, from its telemetry, each with its state.
    assert_eq!(h.query_all_by_label("IMU ok").count(), 1);
    h.get_by_label("wheels unavailable");
    h.get_by_label("head ok");
    assert_eq!(h.get_all_by_label("CPU 45.5 %, memory 1.00 / 4.00 GiB").count(), 4);
    h.get_by_label("source: udp://127.0.0.1:47800");
    // Task timing in the table.
    assert_eq!(h.get_all_by_label("filter").count(), 4);
    assert_eq!(h.get_all_by_label("800 µs").count(), 4);
}

#[test]
fn link_and_command_panels_show_their_data() {
    let h = harness(team_view());
    h.get_by_label("1234 packets received, 5 rejected, 2 outages (shaded red)");
    h.get_by_label("OUTAGE NOW");
    h.get_by_label("queued 3 s");
    h.get_by_label("Executed, RTT 3900 ms");
    h.get_by_label("timed out");
    h.get_by_label("waypoint (12.0, -3.5) m");
    h.get_by_label("waypoint refused: robot 4 is not connected to robot 1's frame");
}

#[test]
fn clicked_waypoint_is_emitted_in_reference_metres() {
    let mut h = harness(team_view());
    h.state_mut().ui.target_robot = Some(2);
    // A known camera: (10, 5) m in the middle, 8 px per m.
    h.state_mut().ui.map.set_view([10.0, 5.0], 8.0);
    h.run();
    h.get_by_label("Arm waypoint (click the map)").click();
    h.run();
    assert!(h.state().ui.waypoint_armed);

    let rect = h.get_by_label(MAP_LABEL).rect();
    let click = rect.center() + Vec2::new(40.0, -24.0);
    click_at(&mut h, click);
    // Computed here independently: right is +x, up is +y.
    let (want_x, want_y) = (10.0 + 40.0 / 8.0, 5.0 + 24.0 / 8.0);
    let waypoints: Vec<&UiAction> =
        h.state().actions.iter().filter(|a| matches!(a, UiAction::Waypoint { .. })).collect();
    assert_eq!(waypoints.len(), 1, "{:?}", h.state().actions);
    let UiAction::Waypoint { robot, x_ref_m, y_ref_m } = waypoints[0] else { unreachable!() };
    assert_eq!(*robot, 2);
    assert!((x_ref_m - want_x).abs() < CELL_M && (y_ref_m - want_y).abs() < CELL_M, "({x_ref_m}, {y_ref_m})");
    // Single shot: the next click sends nothing.
    assert!(!h.state().ui.waypoint_armed);
    click_at(&mut h, click + Vec2::new(10.0, 10.0));
    assert_eq!(h.state().actions.iter().filter(|a| matches!(a, UiAction::Waypoint { .. })).count(), 1);
}

#[test]
fn waypoint_lands_where_the_map_is_drawn_after_zoom_and_pan() {
    let mut h = harness(team_view());
    h.state_mut().ui.map.set_view([0.0, 0.0], 4.0);
    h.run();
    let rect = h.get_by_label(MAP_LABEL).rect();
    // Zoom in about a point off-centre, then drag the map.
    let anchor = rect.center() + Vec2::new(-100.0, 50.0);
    h.event(egui::Event::PointerMoved(anchor));
    h.event(egui::Event::MouseWheel {
        unit: egui::MouseWheelUnit::Point,
        delta: Vec2::new(0.0, 200.0),
        phase: egui::TouchPhase::Move,
        modifiers: egui::Modifiers::default(),
        source: egui::MouseWheelSource::Wheel,
    });
    h.run();
    let t = h.state().ui.map.last_transform().unwrap();
    assert!(t.px_per_m > 4.0, "zoomed in: {}", t.px_per_m);
    // The world point under the anchor did not move.
    let w = t.screen_to_world(anchor);
    let before = [(anchor.x - rect.center().x) as f64 / 4.0, -(anchor.y - rect.center().y) as f64 / 4.0];
    assert!((w[0] - before[0]).abs() < 0.05 && (w[1] - before[1]).abs() < 0.05, "{w:?} vs {before:?}");

    h.get_by_label("Arm waypoint (click the map)").click();
    h.run();
    let target = h.state().ui.target_robot.unwrap();
    // Click where the transform draws robot 1's pose: the waypoint is that pose.
    let pose = h.state().view.robots[&1].t_ref_body.unwrap().translation;
    let p = t.world_to_screen(pose.x, pose.y);
    assert!(rect.contains(p));
    click_at(&mut h, p);
    let Some(UiAction::Waypoint { robot, x_ref_m, y_ref_m }) = h.state().actions.last().cloned() else {
        panic!("{:?}", h.state().actions)
    };
    assert_eq!(robot, target);
    assert!((x_ref_m - pose.x).abs() < CELL_M && (y_ref_m - pose.y).abs() < CELL_M);
}

#[test]
fn reference_selector_emits_set_reference() {
    let mut h = harness(team_view());
    h.get_by_label("R3").click();
    h.run();
    assert_eq!(h.state().actions, vec![UiAction::SetReference(3)]);
    // The current reference is no action.
    h.get_by_label("R1").click();
    h.run();
    assert_eq!(h.state().actions.len(), 1);
}

#[test]
fn command_buttons_emit_actions_for_the_target() {
    let mut h = harness(team_view());
    h.get_by_label("Set mode").click();
    h.get_by_label("Request resend").click();
    h.get_by_label("Stop recording").click();
    h.run();
    assert_eq!(
        h.state().actions,
        vec![
            UiAction::SetMode { robot: 1, mode: Mode::Idle },
            UiAction::RequestResend { robot: 1, submap_index: 0 },
            UiAction::StopRecording { robot: 1 },
        ]
    );
    // An empty parameter name is refused in the form, not sent.
    h.get_by_label("Set parameter").click();
    h.run();
    assert_eq!(h.state().actions.len(), 3);
    h.get_by_label("parameter name is empty");
}

#[test]
fn typed_parameter_is_parsed_and_sent() {
    let mut h = harness(team_view());
    let name = h.get_by(|n| n.placeholder() == Some("parameter name"));
    name.focus();
    name.type_text("max_speed_mps");
    h.run();
    let value = h.get_by(|n| n.placeholder() == Some("value: true, 3, 0.5"));
    value.focus();
    value.type_text("0.8");
    h.run();
    h.get_by_label("Set parameter").click();
    h.run();
    assert_eq!(
        h.state().actions,
        vec![UiAction::SetParameter {
            robot: 1,
            name: "max_speed_mps".into(),
            value: protocol::message::ParamValue::Float(0.8)
        }]
    );
}

#[test]
fn controls_are_disabled_without_a_key() {
    let mut view = team_view();
    view.can_command = false;
    let mut h = harness(view);
    h.get_by_label("Commands disabled: no command key loaded (start with --key FILE)");
    for label in ["Set mode", "Set parameter", "Request resend", "Start recording", "Stop recording"] {
        assert!(h.get_by_label(label).accesskit_node().is_disabled(), "{label} enabled");
    }
    assert!(h.get_by_label("Arm waypoint (click the map)").accesskit_node().is_disabled());
    h.get_by_label("Set mode").click();
    h.state_mut().ui.waypoint_armed = true; // even if armed somehow, a click sends nothing
    h.run();
    let rect = h.get_by_label(MAP_LABEL).rect();
    click_at(&mut h, rect.center());
    assert!(h.state().actions.is_empty(), "{:?}", h.state().actions);
}

#[test]
fn replay_timeline_plays_pauses_and_seeks() {
    let mut view = team_view();
    view.can_command = false;
    view.replay =
        Some(ReplayView { start_ns: 10 * S, end_ns: 110 * S, position_ns: 60 * S, playing: true, speed: 1.0 });
    let mut h = harness(view);
    h.get_by_label("Commands disabled: replaying a recording: commands go to live robots only");
    h.get_by_label("Pause").click();
    h.run();
    assert_eq!(h.state().actions, vec![UiAction::ReplayPlay(false)]);
    h.state_mut().actions.clear();
    h.get_by_role_and_label(egui::Role::Slider, "replay position").set_value_accesskit(25.0);
    h.run();
    assert_eq!(h.state().actions, vec![UiAction::ReplaySeek(35 * S)]);
}

#[test]
fn map_texture_is_uploaded_once_per_revision() {
    let mut h = harness(team_view());
    h.run_steps(5);
    assert_eq!(h.state().ui.map.texture_uploads, 1);
    h.state_mut().view.map = Some(Arc::new(grid(2)));
    h.run_steps(3);
    assert_eq!(h.state().ui.map.texture_uploads, 2);
}

#[test]
fn three_d_tab_draws_the_points() {
    let mut h = harness(team_view());
    h.get_by_label("3D points").click();
    h.run();
    h.get_by_label("2000 points (revision 1); drag to orbit, scroll to zoom, double-click to re-frame");
    h.get_by_label(groundstation::ui::points3d::POINTS_LABEL);
    assert!(h.query_by_label(MAP_LABEL).is_none());
}
