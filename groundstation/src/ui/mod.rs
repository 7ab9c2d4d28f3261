//! The operator's panels. Every panel reads one [`TeamView`] snapshot and pushes the operator's
//! requests as [`UiAction`]s; the only state kept here is the UI's own (camera, form fields,
//! the map texture), in [`UiState`].
//!
//! Layout: top bar (source, replay timeline, frame time), robots on the left, commands on the
//! right, link plots at the bottom, and the map or the 3D point view in the middle.

pub mod commands;
pub mod link;
pub mod map;
pub mod palette;
pub mod points3d;
pub mod replay;
pub mod robots;
pub mod transform;

use egui::{CentralPanel, Panel, ScrollArea, Ui};

use crate::view::{TeamView, UiAction};

/// What the central area shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CentralTab {
    #[default]
    Map,
    Points3d,
}

/// The UI's own state between frames.
#[derive(Debug, Default)]
pub struct UiState {
    pub tab: CentralTab,
    pub map: map::MapState,
    pub points: points3d::PointsState,
    pub commands: commands::CommandForm,
    /// The robot the commands panel (and a waypoint click) addresses.
    pub target_robot: Option<u8>,
    /// The next click on the map sends a waypoint to `target_robot`.
    pub waypoint_armed: bool,
    /// Shown in the top bar's corner (the app's frame-time summary).
    pub status_text: String,
}

/// Draws the whole window and returns what the operator asked for this frame.
pub fn show(ui: &mut Ui, view: &TeamView, state: &mut UiState) -> Vec<UiAction> {
    let mut actions = Vec::new();
    resolve_target(view, state);

    Panel::top("gs_top_bar").show(ui, |ui| {
        top_bar(ui, view, state, &mut actions);
    });
    Panel::left("gs_robots").resizable(true).default_size(300.0).show(ui, |ui| {
        ScrollArea::vertical().id_salt("gs_robots_scroll").show(ui, |ui| {
            robots::show(ui, view, &mut actions);
        });
    });
    Panel::right("gs_commands").resizable(true).default_size(330.0).show(ui, |ui| {
        ScrollArea::vertical().id_salt("gs_commands_scroll").show(ui, |ui| {
            commands::show(ui, view, state, &mut actions);
        });
    });
    Panel::bottom("gs_link").resizable(true).default_size(260.0).show(ui, |ui| {
        link::show(ui, view);
    });
    CentralPanel::default().show(ui, |ui| {
        ui.horizontal(|ui| {
            ui.selectable_value(&mut state.tab, CentralTab::Map, "Map");
            ui.selectable_value(&mut state.tab, CentralTab::Points3d, "3D points");
        });
        match state.tab {
            CentralTab::Map => map::show(ui, view, state, &mut actions),
            CentralTab::Points3d => points3d::show(ui, view, &mut state.points),
        }
    });
    actions
}

/// Keeps the command target valid: the first robot heard until the operator picks one.
fn resolve_target(view: &TeamView, state: &mut UiState) {
    let valid = state.target_robot.is_some_and(|r| view.robots.contains_key(&r));
    if !valid {
        state.target_robot = view.robots.keys().next().copied();
        state.waypoint_armed = false;
    }
}

fn top_bar(ui: &mut Ui, view: &TeamView, state: &UiState, actions: &mut Vec<UiAction>) {
    ui.horizontal(|ui| {
        ui.strong("Ground station");
        ui.label(format!("source: {}", view.source));
        ui.separator();
        ui.label(match view.reference_robot {
            Some(r) => format!("frame of robot {r}"),
            None => "no reference robot yet".to_owned(),
        });
        ui.separator();
        // Live, the model runs on the ground's own clock (since start); a replay on mission time.
        let clock = if view.replay.is_some() { "mission time" } else { "ground time" };
        ui.label(format!("{clock} {:.1} s", view.now_ns as f64 * 1e-9));
        if let Some(replay) = &view.replay {
            ui.separator();
            replay::show(ui, replay, actions);
        }
        ui.with_layout(egui::Layout::right_to_left(egui::Align::Center), |ui| {
            ui.monospace(&state.status_text);
        });
    });
}
