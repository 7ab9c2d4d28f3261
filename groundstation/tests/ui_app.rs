//! The app's frame loop without a window: snapshots in, actions out to the source, frame times
//! kept, a refused action shown to the operator.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::BTreeMap;
use std::sync::{Arc, Mutex};

use egui::Vec2;
use egui_kittest::Harness;
use egui_kittest::kittest::Queryable as _;
use groundstation::app::{GroundStationApp, TeamSource};
use groundstation::view::{LinkView, MapPoints, RobotView, Staleness, TeamView, UiAction};

struct Fixed {
    view: Arc<TeamView>,
    acted: Arc<Mutex<Vec<UiAction>>>,
    refuse: bool,
}

impl TeamSource for Fixed {
    fn view(&self) -> Arc<TeamView> {
        Arc::clone(&self.view)
    }
    fn act(&mut self, action: UiAction) -> Result<(), String> {
        self.acted.lock().unwrap().push(action);
        if self.refuse { Err("command queue full".to_owned()) } else { Ok(()) }
    }
}

fn view() -> TeamView {
    let robot = |id: u8| RobotView {
        robot: id,
        connected: true,
        mode: None,
        sensors: None,
        filter: None,
        tasks: vec![],
        queues: vec![],
        links: vec![],
        resources: None,
        auth_rejections: 0,
        last_message_ns: Some(1_000_000_000),
        staleness: Staleness::Fresh,
        trajectory_ref_m: vec![[0.0, 0.0, 0.0], [1.0, 1.0, 0.0]],
        t_ref_body: None,
        position_cov_xy_m2: None,
        submaps: vec![],
        hazards: None,
    };
    TeamView {
        now_ns: 2_000_000_000,
        reference_robot: Some(1),
        robots: BTreeMap::from([(1, robot(1)), (2, robot(2))]),
        edges: vec![],
        map: None,
        points: Arc::new(MapPoints::default()),
        link: LinkView::default(),
        commands: vec![],
        can_command: true,
        replay: None,
        notices: vec![],
        source: "test".into(),
    }
}

fn app(refuse: bool) -> (GroundStationApp, Arc<Mutex<Vec<UiAction>>>) {
    let acted = Arc::new(Mutex::new(Vec::new()));
    let source = Fixed { view: Arc::new(view()), acted: Arc::clone(&acted), refuse };
    (GroundStationApp::new(Box::new(source)), acted)
}

#[test]
fn actions_reach_the_source_and_frames_are_timed() {
    let (app, acted) = app(false);
    let mut h = Harness::builder().with_size(Vec2::new(1400.0, 900.0)).build_ui_state(
        |ui, app: &mut GroundStationApp| {
            app.draw(ui);
        },
        app,
    );
    h.get_by_label("R2").click();
    h.run();
    assert_eq!(*acted.lock().unwrap(), vec![UiAction::SetReference(2)]);
    assert!(h.state().frame_times().quantile(0.5).is_some());
    // The corner shows the frame-time summary.
    assert!(h.query_by_label_contains("ms p50").is_some());
}

#[test]
fn a_refused_action_is_shown() {
    let (app, _) = app(true);
    let mut h = Harness::builder().with_size(Vec2::new(1400.0, 900.0)).build_ui_state(
        |ui, app: &mut GroundStationApp| {
            app.draw(ui);
        },
        app,
    );
    h.get_by_label("Set mode").click();
    h.run();
    assert!(h.query_by_label_contains("action failed: command queue full").is_some());
}
