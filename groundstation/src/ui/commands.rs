//! Commands: target robot, mode, waypoint arming, parameters, submap resend, recording; the
//! command list with each command's state; the model's notices.

use egui::{Color32, ComboBox, DragValue, RichText, TextEdit, Ui};
use protocol::message::{Mode, ParamValue};

use super::{UiState, palette};
use crate::view::{CommandState, CommandView, TeamView, UiAction};

/// The wire limits of `ParamName` and the recording label (`heapless::String<32>`).
pub const MAX_NAME_BYTES: usize = 32;

const MODES: [Mode; 5] = [Mode::Idle, Mode::Waypoint, Mode::Autonomous, Mode::Teleoperated, Mode::Safe];

/// The command form's fields between frames.
#[derive(Debug, Clone)]
pub struct CommandForm {
    pub mode: Mode,
    pub param_name: String,
    pub param_value: String,
    pub resend_index: u32,
    pub record_label: String,
    /// Why the last button press was not turned into an action.
    pub error: Option<String>,
}

impl Default for CommandForm {
    fn default() -> Self {
        Self {
            mode: Mode::Idle,
            param_name: String::new(),
            param_value: String::new(),
            resend_index: 0,
            record_label: String::new(),
            error: None,
        }
    }
}

/// Why commands cannot be sent now, `None` when they can.
pub fn disabled_reason(view: &TeamView, target: Option<u8>) -> Option<String> {
    if !view.can_command {
        return Some(if view.replay.is_some() {
            "replaying a recording: commands go to live robots only".to_owned()
        } else {
            "no command key loaded (start with --key FILE)".to_owned()
        });
    }
    target.is_none().then(|| "no robot heard yet".to_owned())
}

/// `true`/`false`, an integer, or a decimal number.
pub fn parse_param_value(text: &str) -> Result<ParamValue, String> {
    let t = text.trim();
    match t {
        "true" => return Ok(ParamValue::Bool(true)),
        "false" => return Ok(ParamValue::Bool(false)),
        _ => {}
    }
    if let Ok(i) = t.parse::<i64>() {
        return Ok(ParamValue::Int(i));
    }
    match t.parse::<f64>() {
        Ok(f) if f.is_finite() => Ok(ParamValue::Float(f)),
        _ => Err(format!("value {t:?} is not true/false, an integer or a finite number")),
    }
}

fn check_name(what: &str, name: &str) -> Result<(), String> {
    if name.trim().is_empty() {
        Err(format!("{what} is empty"))
    } else if name.len() > MAX_NAME_BYTES {
        Err(format!("{what} is {} bytes, at most {MAX_NAME_BYTES}", name.len()))
    } else {
        Ok(())
    }
}

pub fn show(ui: &mut Ui, view: &TeamView, state: &mut UiState, actions: &mut Vec<UiAction>) {
    ui.heading("Commands");
    let reason = disabled_reason(view, state.target_robot);
    if let Some(reason) = &reason {
        ui.colored_label(palette::STALE, format!("Commands disabled: {reason}"));
        state.waypoint_armed = false;
    }
    ui.add_enabled_ui(reason.is_none(), |ui| controls(ui, view, state, actions));
    if let Some(err) = &state.commands.error {
        ui.colored_label(palette::LOST, err);
    }

    if !view.notices.is_empty() {
        ui.separator();
        ui.strong("Notices");
        for notice in view.notices.iter().rev().take(5) {
            ui.colored_label(palette::STALE, notice);
        }
    }

    ui.separator();
    ui.strong("Sent commands");
    if view.commands.is_empty() {
        ui.label("none yet");
        return;
    }
    egui::Grid::new("gs_command_list").striped(true).show(ui, |ui| {
        for h in ["id", "robot", "command", "state"] {
            ui.label(RichText::new(h).small());
        }
        ui.end_row();
        for cmd in view.commands.iter().rev().take(50) {
            ui.label(format!("#{}", cmd.id));
            ui.label(format!("to {}", cmd.target));
            ui.label(&cmd.summary);
            let (text, colour) = command_state_text(cmd, view.now_ns);
            ui.colored_label(colour, text);
            ui.end_row();
        }
    });
}

/// A command's state in words: `queued 3 s`, `sent 2× (4 s)`, `Executed, RTT 3900 ms`,
/// `timed out`.
pub fn command_state_text(cmd: &CommandView, now_ns: u64) -> (String, Color32) {
    let age_s = |t: u64| now_ns.saturating_sub(t) / 1_000_000_000;
    match cmd.state {
        CommandState::Queued => (format!("queued {} s", age_s(cmd.queued_ns)), palette::STALE),
        CommandState::Sent { first_sent_ns, attempts } => {
            (format!("sent {attempts}× ({} s)", age_s(first_sent_ns)), Color32::LIGHT_BLUE)
        }
        CommandState::Acknowledged { outcome, rtt_ms } => {
            let colour = match outcome {
                protocol::message::CommandOutcome::Accepted | protocol::message::CommandOutcome::Executed => {
                    palette::GOOD
                }
                protocol::message::CommandOutcome::Invalid | protocol::message::CommandOutcome::Refused => {
                    palette::LOST
                }
            };
            (format!("{outcome:?}, RTT {rtt_ms} ms"), colour)
        }
        CommandState::TimedOut => ("timed out".to_owned(), palette::LOST),
    }
}

fn controls(ui: &mut Ui, view: &TeamView, state: &mut UiState, actions: &mut Vec<UiAction>) {
    let target_text = state.target_robot.map_or_else(|| "none".to_owned(), |r| format!("robot {r}"));
    ComboBox::from_label("Target").selected_text(target_text).show_ui(ui, |ui| {
        for &id in view.robots.keys() {
            ui.selectable_value(&mut state.target_robot, Some(id), format!("robot {id}"));
        }
    });
    let Some(robot) = state.target_robot else { return };
    let form = &mut state.commands;

    ui.horizontal(|ui| {
        ComboBox::from_label("Mode").selected_text(format!("{:?}", form.mode)).show_ui(ui, |ui| {
            for m in MODES {
                ui.selectable_value(&mut form.mode, m, format!("{m:?}"));
            }
        });
        if ui.button("Set mode").clicked() {
            actions.push(UiAction::SetMode { robot, mode: form.mode });
        }
    });

    ui.toggle_value(&mut state.waypoint_armed, "Arm waypoint (click the map)");

    ui.separator();
    ui.add(TextEdit::singleline(&mut form.param_name).hint_text("parameter name").desired_width(150.0));
    ui.horizontal(|ui| {
        ui.add(TextEdit::singleline(&mut form.param_value).hint_text("value: true, 3, 0.5").desired_width(110.0));
        if ui.button("Set parameter").clicked() {
            let checked =
                check_name("parameter name", &form.param_name).and_then(|()| parse_param_value(&form.param_value));
            match checked {
                Ok(value) => {
                    actions.push(UiAction::SetParameter { robot, name: form.param_name.trim().to_owned(), value });
                    form.error = None;
                }
                Err(e) => form.error = Some(e),
            }
        }
    });

    ui.horizontal(|ui| {
        ui.add(DragValue::new(&mut form.resend_index).prefix("submap ")).on_hover_text("submap index to resend");
        if ui.button("Request resend").clicked() {
            actions.push(UiAction::RequestResend { robot, submap_index: form.resend_index });
        }
    });

    ui.add(TextEdit::singleline(&mut form.record_label).hint_text("recording label").desired_width(150.0));
    ui.horizontal(|ui| {
        if ui.button("Start recording").clicked() {
            match check_name("recording label", &form.record_label) {
                Ok(()) => {
                    actions.push(UiAction::StartRecording { robot, label: form.record_label.trim().to_owned() });
                    form.error = None;
                }
                Err(e) => form.error = Some(e),
            }
        }
        if ui.button("Stop recording").clicked() {
            actions.push(UiAction::StopRecording { robot });
        }
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parameter_values() {
        assert_eq!(parse_param_value(" true "), Ok(ParamValue::Bool(true)));
        assert_eq!(parse_param_value("-3"), Ok(ParamValue::Int(-3)));
        assert_eq!(parse_param_value("0.25"), Ok(ParamValue::Float(0.25)));
        assert!(parse_param_value("NaN").is_err());
        assert!(parse_param_value("fast").is_err());
        assert!(check_name("x", &"a".repeat(33)).is_err());
        assert!(check_name("x", " ").is_err());
    }
}
