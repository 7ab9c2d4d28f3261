//! The replay timeline: play/pause, speed, and a slider to scrub through the recording.

use egui::{ComboBox, Slider, Ui};

use crate::view::{ReplayView, UiAction};

pub const SPEEDS: [f64; 8] = [0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0];

pub fn show(ui: &mut Ui, replay: &ReplayView, actions: &mut Vec<UiAction>) {
    let label = if replay.playing { "Pause" } else { "Play" };
    if ui.button(label).clicked() {
        actions.push(UiAction::ReplayPlay(!replay.playing));
    }
    let mut speed = replay.speed;
    ComboBox::from_label("Speed").selected_text(format!("{speed}×")).show_ui(ui, |ui| {
        for s in SPEEDS {
            ui.selectable_value(&mut speed, s, format!("{s}×"));
        }
    });
    if speed != replay.speed {
        actions.push(UiAction::ReplaySpeed(speed));
    }
    let duration_s = replay.end_ns.saturating_sub(replay.start_ns) as f64 * 1e-9;
    let mut position_s = replay.position_ns.saturating_sub(replay.start_ns) as f64 * 1e-9;
    let slider = Slider::new(&mut position_s, 0.0..=duration_s.max(1e-3)).text("replay position").suffix(" s");
    if ui.add(slider).changed() {
        actions.push(UiAction::ReplaySeek(seek_target_ns(replay, position_s)));
    }
}

/// The recording time `position_s` after the start, clamped to the recording.
pub fn seek_target_ns(replay: &ReplayView, position_s: f64) -> u64 {
    let offset_ns = (position_s.max(0.0) * 1e9).round() as u64;
    replay.start_ns.saturating_add(offset_ns).min(replay.end_ns)
}
