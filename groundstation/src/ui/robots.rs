//! Per-robot health: mode, filter, uncertainty, frame connection, CPU and memory, task timing,
//! message age; stale and lost robots in colour and words. Also the reference-robot selector.

use egui::{Color32, RichText, Ui};

use super::palette::{self, robot_colour};
use crate::view::{RobotView, Staleness, TeamView, UiAction};

pub fn show(ui: &mut Ui, view: &TeamView, actions: &mut Vec<UiAction>) {
    ui.heading("Robots");
    if view.robots.is_empty() {
        ui.label("no robot heard yet");
        return;
    }
    ui.horizontal_wrapped(|ui| {
        ui.label("Reference frame:");
        for &id in view.robots.keys() {
            let selected = view.reference_robot == Some(id);
            if ui
                .selectable_label(selected, format!("R{id}"))
                .on_hover_text(format!("draw the team in robot {id}'s frame"))
                .clicked()
                && !selected
            {
                actions.push(UiAction::SetReference(id));
            }
        }
    });
    for robot in view.robots.values() {
        ui.separator();
        robot_card(ui, view, robot);
    }
}

/// The staleness badge text: `OK`, `STALE 7 s` or `LOST`.
pub fn staleness_text(robot: &RobotView, now_ns: u64) -> (String, Color32) {
    let age_s = robot.last_message_ns.map(|t| now_ns.saturating_sub(t) / 1_000_000_000);
    match robot.staleness {
        Staleness::Fresh => ("OK".to_owned(), palette::GOOD),
        Staleness::Stale => (format!("STALE {} s", age_s.unwrap_or(0)), palette::STALE),
        Staleness::Lost => ("LOST".to_owned(), palette::LOST),
    }
}

fn robot_card(ui: &mut Ui, view: &TeamView, robot: &RobotView) {
    let (badge, badge_colour) = staleness_text(robot, view.now_ns);
    ui.horizontal(|ui| {
        ui.label(RichText::new(format!("Robot {}", robot.robot)).strong().color(robot_colour(robot.robot)));
        ui.label(RichText::new(badge).strong().color(Color32::BLACK).background_color(badge_colour));
        if view.reference_robot == Some(robot.robot) {
            ui.label("(reference)");
        }
    });
    let dim = robot.staleness != Staleness::Fresh;
    let text = |s: String| if dim { RichText::new(s).weak() } else { RichText::new(s) };

    ui.label(text(match robot.last_message_ns {
        Some(t) => format!("last message {:.1} s ago", view.now_ns.saturating_sub(t) as f64 * 1e-9),
        None => "no message yet".to_owned(),
    }));
    ui.label(text(format!("mode: {}", robot.mode.map_or_else(|| "unknown".to_owned(), |m| format!("{m:?}")))));
    match &robot.filter {
        Some(f) => {
            let vo = if f.vo_age_ms == u32::MAX { "never".to_owned() } else { format!("{} ms", f.vo_age_ms) };
            let colour = match f.status {
                protocol::message::FilterStatus::Nominal => palette::GOOD,
                protocol::message::FilterStatus::Initializing | protocol::message::FilterStatus::Degraded => {
                    palette::STALE
                }
                protocol::message::FilterStatus::Diverged => palette::LOST,
            };
            ui.horizontal(|ui| {
                ui.label("filter:");
                ui.colored_label(colour, format!("{:?}", f.status));
            });
            ui.label(text(format!(
                "local σ {:.2} m, yaw σ {:.1}°, VO age {vo}",
                f.position_std_m,
                f.yaw_std_rad.to_degrees()
            )));
        }
        None => {
            ui.label(text("filter: unknown".to_owned()));
        }
    }
    if let Some(sensors) = &robot.sensors {
        ui.horizontal(|ui| {
            ui.label("devices:");
            for (name, up) in [("IMU", sensors.imu), ("wheels", sensors.wheels), ("head", sensors.head)] {
                let (colour, state) = if up { (palette::GOOD, "ok") } else { (palette::LOST, "unavailable") };
                ui.colored_label(colour, format!("{name} {state}"));
            }
        });
    }
    let reference = view.reference_robot.map_or_else(|| "?".to_owned(), |r| r.to_string());
    if robot.connected {
        let sigma = robot.position_cov_xy_m2.map(|c| {
            let eig = c.symmetric_eigenvalues();
            eig.max().max(0.0).sqrt()
        });
        let sigma = sigma.map_or_else(String::new, |s| format!(", position σ {s:.2} m"));
        ui.label(text(format!("in robot {reference}'s frame{sigma}")));
    } else {
        ui.colored_label(palette::STALE, format!("not connected to robot {reference}'s frame"));
    }
    if let Some(r) = &robot.resources {
        let gib = |kib: u32| f64::from(kib) / (1024.0 * 1024.0);
        ui.label(text(format!(
            "CPU {:.1} %, memory {:.2} / {:.2} GiB",
            f64::from(r.cpu_permille) / 10.0,
            gib(r.mem_used_kib),
            gib(r.mem_total_kib)
        )));
    }
    if robot.auth_rejections > 0 {
        ui.colored_label(palette::LOST, format!("{} rejected commands (authentication)", robot.auth_rejections));
    }
    if !robot.tasks.is_empty() {
        egui::Grid::new(("tasks", robot.robot)).striped(true).show(ui, |ui| {
            for h in ["task", "overruns", "jitter p99", "max"] {
                ui.label(RichText::new(h).small());
            }
            ui.end_row();
            for task in &robot.tasks {
                ui.label(task.task.as_str());
                let overruns = RichText::new(task.deadline_overruns.to_string());
                ui.label(if task.deadline_overruns > 0 { overruns.color(palette::STALE) } else { overruns });
                ui.label(format!("{} µs", task.jitter_p99_us));
                ui.label(format!("{} µs", task.jitter_max_us));
                ui.end_row();
            }
        });
    }
    if !robot.queues.is_empty() {
        let queues: Vec<String> =
            robot.queues.iter().map(|q| format!("{} {}/{}", q.queue.as_str(), q.depth, q.capacity)).collect();
        ui.label(text(format!("queues: {}", queues.join(", "))));
    }
}
