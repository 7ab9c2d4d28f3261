//! The ground link over time: bytes per second per message class (received and sent), round
//! trip, loss, queue depths, with outages shaded in every plot.

use std::collections::BTreeMap;

use egui::{Color32, Id, Ui};
use egui_plot::{Corner, Legend, Line, Plot, PlotPoints, PlotUi, Span};

use super::palette;
use crate::view::{LinkSample, TeamView};

pub fn show(ui: &mut Ui, view: &TeamView) {
    let link = &view.link;
    ui.horizontal(|ui| {
        ui.strong("Link");
        ui.label(format!(
            "{} packets received, {} rejected, {} outages (shaded red)",
            link.packets_received, link.packets_rejected, link.outages
        ));
        if link.samples.back().is_some_and(|s| s.outage) {
            ui.colored_label(palette::LOST, "OUTAGE NOW");
        }
    });
    if link.samples.is_empty() {
        ui.label("no link samples yet");
        return;
    }
    let samples: Vec<&LinkSample> = link.samples.iter().collect();
    let outages = outage_spans_s(&samples);
    let rx = per_class(&samples, |s| &s.rx_bytes_per_s_by_class);
    let tx = per_class(&samples, |s| &s.tx_bytes_per_s_by_class);
    let rtt: Vec<[f64; 2]> = samples.iter().filter_map(|s| s.rtt_ms.map(|v| [s.t_s, v])).collect();
    let loss: Vec<[f64; 2]> = samples.iter().filter_map(|s| s.loss_permille.map(|v| [s.t_s, v])).collect();
    let robot_q: Vec<[f64; 2]> = samples.iter().map(|s| [s.t_s, f64::from(s.robot_queue_depth)]).collect();
    let ground_q: Vec<[f64; 2]> = samples.iter().map(|s| [s.t_s, f64::from(s.ground_queue_depth)]).collect();

    // Scrolling one plot in time scrolls them all.
    let group = Id::unique("gs_link_time_axis");
    let width = ((ui.available_width() - 3.0 * ui.spacing().item_spacing.x) / 4.0).max(120.0);
    let height = ui.available_height().max(80.0);
    let plot = |id: &str, y_label: &str| {
        Plot::new(id.to_owned())
            .width(width)
            .height(height)
            .legend(
                Legend::default().position(Corner::LeftTop).background_alpha(0.4).text_style(egui::TextStyle::Small),
            )
            .link_axis(group, [true, false])
            .x_axis_label("time (s)")
            .y_axis_label(y_label.to_owned())
            .allow_scroll(false)
    };
    ui.horizontal(|ui| {
        plot("gs_link_rx", "received B/s").show(ui, |p| {
            shade(p, &outages);
            for (class, pts) in rx {
                p.line(Line::new(class, PlotPoints::new(pts)));
            }
        });
        plot("gs_link_tx", "sent by robots B/s").show(ui, |p| {
            shade(p, &outages);
            for (class, pts) in tx {
                p.line(Line::new(class, PlotPoints::new(pts)));
            }
        });
        plot("gs_link_rtt", "RTT ms / loss ‰").show(ui, |p| {
            shade(p, &outages);
            p.line(Line::new("RTT (ms)", PlotPoints::new(rtt)));
            p.line(Line::new("loss (‰)", PlotPoints::new(loss)));
        });
        plot("gs_link_queues", "queue depth").show(ui, |p| {
            shade(p, &outages);
            p.line(Line::new("deepest robot queue", PlotPoints::new(robot_q)));
            p.line(Line::new("ground command queue", PlotPoints::new(ground_q)));
        });
    });
}

fn shade(p: &mut PlotUi<'_>, outages: &[(f64, f64)]) {
    for &(t0, t1) in outages {
        // Unnamed: kept out of the legends (the header says what red means).
        p.span(Span::new("", t0..=t1).fill(Color32::from_rgba_unmultiplied(220, 40, 40, 50)).border_width(0.0));
    }
}

/// One series per message class; a class missing from a sample counts as 0 B/s there.
fn per_class<'a>(
    samples: &[&'a LinkSample],
    field: impl Fn(&'a LinkSample) -> &'a BTreeMap<String, f64>,
) -> BTreeMap<String, Vec<[f64; 2]>> {
    let mut series: BTreeMap<String, Vec<[f64; 2]>> = BTreeMap::new();
    for s in samples {
        for class in field(s).keys() {
            series.entry(class.clone()).or_default();
        }
    }
    for (class, pts) in &mut series {
        pts.extend(samples.iter().map(|s| [s.t_s, field(s).get(class).copied().unwrap_or(0.0)]));
    }
    series
}

/// Time ranges of consecutive outage samples, each sample covering ±0.5 s.
pub fn outage_spans_s(samples: &[&LinkSample]) -> Vec<(f64, f64)> {
    let mut spans: Vec<(f64, f64)> = Vec::new();
    let mut open: Option<(f64, f64)> = None;
    for s in samples {
        match (&mut open, s.outage) {
            (Some(span), true) => span.1 = s.t_s + 0.5,
            (None, true) => open = Some((s.t_s - 0.5, s.t_s + 0.5)),
            (Some(_), false) => spans.extend(open.take()),
            (None, false) => {}
        }
    }
    spans.extend(open);
    spans
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(t_s: f64, outage: bool) -> LinkSample {
        LinkSample {
            t_s,
            rx_bytes_per_s_by_class: BTreeMap::new(),
            tx_bytes_per_s_by_class: BTreeMap::new(),
            rtt_ms: None,
            loss_permille: None,
            robot_queue_depth: 0,
            ground_queue_depth: 0,
            outage,
        }
    }

    #[test]
    fn outages_merge_into_spans() {
        let s: Vec<LinkSample> =
            [false, true, true, false, true].iter().enumerate().map(|(i, &o)| sample(i as f64, o)).collect();
        let refs: Vec<&LinkSample> = s.iter().collect();
        assert_eq!(outage_spans_s(&refs), vec![(0.5, 2.5), (3.5, 4.5)]);
    }

    #[test]
    fn missing_class_is_zero() {
        let mut a = sample(0.0, false);
        a.rx_bytes_per_s_by_class.insert("Telemetry".into(), 100.0);
        let mut b = sample(1.0, false);
        b.rx_bytes_per_s_by_class.insert("SubmapChunk".into(), 900.0);
        let s = [&a, &b];
        let series = per_class(&s, |s| &s.rx_bytes_per_s_by_class);
        assert_eq!(series["Telemetry"], vec![[0.0, 100.0], [1.0, 0.0]]);
        assert_eq!(series["SubmapChunk"], vec![[0.0, 0.0], [1.0, 900.0]]);
    }
}
