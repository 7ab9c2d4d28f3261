//! The campaign's pictures as SVG (a browser and the Markdown viewers of code hosts show them;
//! no plotting dependency): per run the robots' trajectories against the truth, per experiment
//! the error over time of each variant with the team's loop closures marked.
//!
//! Every panel keeps its legend below the axes, outside the data, and names its units.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Isometry3;

use crate::mission::MissionError;
use crate::mission::events::{ClosureEvent, ClosureKind};
use crate::mission::process::read_tum;

const PANEL_W: f64 = 460.0;
const PANEL_H: f64 = 360.0;
/// Plot area inside a panel: left, top, right, bottom margins (axis labels, title, legend).
const MARGIN: [f64; 4] = [62.0, 34.0, 16.0, 86.0];
/// Colours of robots 0, 1, … (then repeated), and of the closure kinds.
const ROBOT_COLOURS: [&str; 4] = ["#1f77b4", "#d62728", "#2ca02c", "#9467bd"];

fn kind_colour(kind: ClosureKind) -> &'static str {
    match kind {
        ClosureKind::Detection => "#ff7f0e",
        ClosureKind::IntraMatch => "#17becf",
        ClosureKind::InterMatch => "#8c564b",
    }
}

/// One line of a panel.
#[derive(Debug, Clone)]
pub struct Series {
    pub label: String,
    pub colour: String,
    pub dashed: bool,
    pub points: Vec<[f64; 2]>,
}

/// A vertical marker line at `x` (a loop closure in time).
#[derive(Debug, Clone)]
pub struct Marker {
    pub x: f64,
    pub label: &'static str,
    pub colour: &'static str,
}

/// One plot.
#[derive(Debug, Clone)]
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    /// Same scale on both axes (maps).
    pub equal_aspect: bool,
    /// Start the y axis at zero (errors).
    pub y_from_zero: bool,
    pub series: Vec<Series>,
    pub markers: Vec<Marker>,
}

/// "Nice" tick spacing (1, 2 or 5 × 10^k) giving about `count` ticks over `span`.
fn tick_step(span: f64, count: f64) -> f64 {
    let raw = (span / count).max(1e-9);
    let magnitude = 10f64.powf(raw.log10().floor());
    let fraction = raw / magnitude;
    let nice = if fraction < 1.5 {
        1.0
    } else if fraction < 3.5 {
        2.0
    } else if fraction < 7.5 {
        5.0
    } else {
        10.0
    };
    nice * magnitude
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

impl Panel {
    /// Data bounds `[x_min, x_max, y_min, y_max]` over series and markers, padded; None when
    /// the panel has no finite point.
    fn bounds(&self) -> Option<[f64; 4]> {
        let mut b: Option<[f64; 4]> = None;
        for p in self.series.iter().flat_map(|s| s.points.iter()).filter(|p| p[0].is_finite() && p[1].is_finite()) {
            let r = b.get_or_insert([p[0], p[0], p[1], p[1]]);
            *r = [r[0].min(p[0]), r[1].max(p[0]), r[2].min(p[1]), r[3].max(p[1])];
        }
        let mut b = b?;
        if self.y_from_zero {
            b[2] = b[2].min(0.0);
        }
        for axis in [0, 2] {
            let span = (b[axis + 1] - b[axis]).max(1e-3);
            b[axis] -= 0.04 * span;
            b[axis + 1] += 0.04 * span;
            if self.y_from_zero && axis == 2 {
                b[2] = 0.0;
            }
        }
        Some(b)
    }

    /// The panel's SVG elements, drawn at offset `(ox, oy)`.
    fn draw(&self, svg: &mut String, ox: f64, oy: f64) {
        let (w, h) = (PANEL_W - MARGIN[0] - MARGIN[2], PANEL_H - MARGIN[1] - MARGIN[3]);
        let (ax, ay) = (ox + MARGIN[0], oy + MARGIN[1]);
        let _ = writeln!(
            svg,
            r#"<text x="{:.1}" y="{:.1}" font-size="14" text-anchor="middle">{}</text>"#,
            ax + w / 2.0,
            oy + 20.0,
            escape(&self.title)
        );
        let _ = writeln!(
            svg,
            r##"<rect x="{ax:.1}" y="{ay:.1}" width="{w:.1}" height="{h:.1}" fill="#fafafa" stroke="#444"/>"##
        );
        let Some(mut b) = self.bounds() else {
            let _ = writeln!(
                svg,
                r#"<text x="{:.1}" y="{:.1}" font-size="12" text-anchor="middle">no data</text>"#,
                ax + w / 2.0,
                ay + h / 2.0
            );
            return;
        };
        if self.equal_aspect {
            // Widen the narrower axis so that a metre is as long in x as in y.
            let scale = ((b[1] - b[0]) / w).max((b[3] - b[2]) / h);
            let (cx, cy) = ((b[0] + b[1]) / 2.0, (b[2] + b[3]) / 2.0);
            b = [cx - scale * w / 2.0, cx + scale * w / 2.0, cy - scale * h / 2.0, cy + scale * h / 2.0];
        }
        let px = |x: f64| ax + (x - b[0]) / (b[1] - b[0]) * w;
        let py = |y: f64| ay + h - (y - b[2]) / (b[3] - b[2]) * h;
        // Ticks and grid.
        for (axis, along_x) in [(0usize, true), (2usize, false)] {
            let step = tick_step(b[axis + 1] - b[axis], if along_x { 6.0 } else { 5.0 });
            let mut v = (b[axis] / step).ceil() * step;
            while v <= b[axis + 1] + 1e-9 {
                let label =
                    if step >= 1.0 { format!("{v:.0}") } else { format!("{v:.*}", (-step.log10().floor()) as usize) };
                if along_x {
                    let x = px(v);
                    let _ = writeln!(
                        svg,
                        r##"<line x1="{x:.1}" y1="{ay:.1}" x2="{x:.1}" y2="{:.1}" stroke="#ddd"/>"##,
                        ay + h
                    );
                    let _ = writeln!(
                        svg,
                        r#"<text x="{x:.1}" y="{:.1}" font-size="11" text-anchor="middle">{label}</text>"#,
                        ay + h + 14.0
                    );
                } else {
                    let y = py(v);
                    let _ = writeln!(
                        svg,
                        r##"<line x1="{ax:.1}" y1="{y:.1}" x2="{:.1}" y2="{y:.1}" stroke="#ddd"/>"##,
                        ax + w
                    );
                    let _ = writeln!(
                        svg,
                        r#"<text x="{:.1}" y="{:.1}" font-size="11" text-anchor="end">{label}</text>"#,
                        ax - 4.0,
                        y + 4.0
                    );
                }
                v += step;
            }
        }
        let _ = writeln!(
            svg,
            r#"<text x="{:.1}" y="{:.1}" font-size="12" text-anchor="middle">{}</text>"#,
            ax + w / 2.0,
            ay + h + 30.0,
            escape(&self.x_label)
        );
        let _ = writeln!(
            svg,
            r#"<text x="{:.1}" y="{:.1}" font-size="12" text-anchor="middle" transform="rotate(-90 {:.1} {:.1})">{}</text>"#,
            ox + 16.0,
            ay + h / 2.0,
            ox + 16.0,
            ay + h / 2.0,
            escape(&self.y_label)
        );
        for m in &self.markers {
            let x = px(m.x);
            if (ax..=ax + w).contains(&x) {
                let _ = writeln!(
                    svg,
                    r#"<line x1="{x:.1}" y1="{ay:.1}" x2="{x:.1}" y2="{:.1}" stroke="{}" stroke-width="1" opacity="0.6"/>"#,
                    ay + h,
                    m.colour
                );
            }
        }
        for s in &self.series {
            let mut d = String::new();
            for p in s.points.iter().filter(|p| p[0].is_finite() && p[1].is_finite()) {
                let _ = write!(d, "{}{:.1},{:.1}", if d.is_empty() { "M" } else { " L" }, px(p[0]), py(p[1]));
            }
            let dash = if s.dashed { r#" stroke-dasharray="5,4""# } else { "" };
            let _ = writeln!(svg, r#"<path d="{d}" fill="none" stroke="{}" stroke-width="1.5"{dash}/>"#, s.colour);
        }
        // The legend: below the axis label, outside the plot area.
        let mut entries: Vec<(String, String, bool)> =
            self.series.iter().map(|s| (s.label.clone(), s.colour.clone(), s.dashed)).collect();
        for m in &self.markers {
            if !entries.iter().any(|e| e.0 == m.label) {
                entries.push((m.label.to_owned(), m.colour.to_owned(), false));
            }
        }
        for (i, (label, colour, dashed)) in entries.iter().enumerate() {
            let (col, row) = (i % 2, i / 2);
            let x = ox + MARGIN[0] + col as f64 * (w / 2.0);
            let y = ay + h + 48.0 + row as f64 * 16.0;
            let dash = if *dashed { r#" stroke-dasharray="5,4""# } else { "" };
            let _ = writeln!(
                svg,
                r#"<line x1="{x:.1}" y1="{:.1}" x2="{:.1}" y2="{:.1}" stroke="{colour}" stroke-width="2"{dash}/>"#,
                y - 4.0,
                x + 22.0,
                y - 4.0
            );
            let _ = writeln!(svg, r#"<text x="{:.1}" y="{y:.1}" font-size="11">{}</text>"#, x + 28.0, escape(label));
        }
    }
}

/// `panels` side by side in one SVG document.
pub fn render(panels: &[Panel]) -> String {
    let width = PANEL_W * panels.len().max(1) as f64;
    let mut svg = format!(
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0}" height="{PANEL_H:.0}" viewBox="0 0 {width:.0} {PANEL_H:.0}" font-family="sans-serif">"#
    );
    svg.push('\n');
    let _ = writeln!(svg, r#"<rect width="{width:.0}" height="{PANEL_H:.0}" fill="white"/>"#);
    for (i, panel) in panels.iter().enumerate() {
        panel.draw(&mut svg, i as f64 * PANEL_W, 0.0);
    }
    svg.push_str("</svg>\n");
    svg
}

/// One robot's outputs of one run, as read back from its directory.
#[derive(Debug, Clone)]
pub struct RobotTrack {
    pub robot: u16,
    pub estimate: Vec<(u64, Isometry3<f64>)>,
    pub truth: Vec<(u64, Isometry3<f64>)>,
}

impl RobotTrack {
    /// `estimate.tum` and `truth.tum` of `dir` (a run's `robot<i>/`).
    pub fn read(robot: u16, dir: &Path) -> Result<RobotTrack, MissionError> {
        Ok(RobotTrack {
            robot,
            estimate: read_tum(&dir.join("estimate.tum"))?,
            truth: read_tum(&dir.join("truth.tum"))?,
        })
    }

    /// 3-D position error (m) over time (s) at the stamps both trajectories have.
    pub fn error_over_time(&self) -> Vec<[f64; 2]> {
        let truth: BTreeMap<u64, &Isometry3<f64>> = self.truth.iter().map(|(s, p)| (*s, p)).collect();
        self.estimate
            .iter()
            .filter_map(|(s, p)| {
                let t = truth.get(s)?;
                Some([*s as f64 * 1e-9, (p.translation.vector - t.translation.vector).norm()])
            })
            .collect()
    }
}

fn colour(robot_index: usize) -> String {
    ROBOT_COLOURS[robot_index % ROBOT_COLOURS.len()].to_owned()
}

/// One panel per robot: the online estimate over the truth, x–y in the robot's start frame.
pub fn trajectories(tracks: &[RobotTrack], variant: &str) -> String {
    let panels: Vec<Panel> = tracks
        .iter()
        .enumerate()
        .map(|(i, t)| Panel {
            title: format!("robot {} ({variant})", t.robot),
            x_label: "x [m] (robot's start frame)".to_owned(),
            y_label: "y [m]".to_owned(),
            equal_aspect: true,
            y_from_zero: false,
            series: vec![
                Series {
                    label: "ground truth".to_owned(),
                    colour: "#777".to_owned(),
                    dashed: true,
                    points: t.truth.iter().map(|(_, p)| [p.translation.x, p.translation.y]).collect(),
                },
                Series {
                    label: "online estimate".to_owned(),
                    colour: colour(i),
                    dashed: false,
                    points: t.estimate.iter().map(|(_, p)| [p.translation.x, p.translation.y]).collect(),
                },
            ],
            markers: Vec::new(),
        })
        .collect();
    render(&panels)
}

/// One panel per robot: the error over time of each variant (`(variant, tracks)`, tracks in the
/// same robot order), with `events[i]` (robot i's loop closures, from the team run) marked.
pub fn errors(variants: &[(&str, &[RobotTrack])], events: &[Vec<ClosureEvent>]) -> String {
    let robots = variants.first().map_or(0, |(_, tracks)| tracks.len());
    let panels: Vec<Panel> = (0..robots)
        .map(|i| {
            let robot = variants[0].1[i].robot;
            let series = variants
                .iter()
                .enumerate()
                .filter_map(|(k, (name, tracks))| {
                    let track = tracks.get(i)?;
                    Some(Series {
                        label: (*name).to_owned(),
                        colour: if k == 0 { colour(i) } else { ["#555", "#999", "#bbb"][(k - 1) % 3].to_owned() },
                        dashed: k > 0,
                        points: track.error_over_time(),
                    })
                })
                .collect();
            let markers = events
                .get(i)
                .map(|e| {
                    e.iter()
                        .map(|e| Marker {
                            x: e.stamp_ns as f64 * 1e-9,
                            label: e.kind.name(),
                            colour: kind_colour(e.kind),
                        })
                        .collect()
                })
                .unwrap_or_default();
            Panel {
                title: format!("robot {robot}: 3-D error of the online estimate"),
                x_label: "time [s]".to_owned(),
                y_label: "error [m]".to_owned(),
                equal_aspect: false,
                y_from_zero: true,
                series,
                markers,
            }
        })
        .collect();
    render(&panels)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use nalgebra::Translation3;

    use super::*;

    fn track(robot: u16, offset_m: f64) -> RobotTrack {
        let pose = |k: u64, extra: f64| {
            Isometry3::from_parts(Translation3::new(k as f64 * 0.1 + extra, 0.2 * k as f64, 0.0), Default::default())
        };
        RobotTrack {
            robot,
            estimate: (0..50).map(|k| (k * 100_000_000, pose(k, offset_m * k as f64 / 50.0))).collect(),
            truth: (0..50).map(|k| (k * 100_000_000, pose(k, 0.0))).collect(),
        }
    }

    #[test]
    fn errors_follow_the_trajectories_and_events_are_marked() {
        let t = track(1, 0.5);
        let e = t.error_over_time();
        assert_eq!(e.len(), 50);
        assert!((e[49][0] - 4.9).abs() < 1e-9 && (e[49][1] - 0.49).abs() < 1e-9, "{:?}", e[49]);
        let tracks = [t.clone(), track(2, 0.1)];
        let events = vec![vec![ClosureEvent { stamp_ns: 2_000_000_000, kind: ClosureKind::InterMatch }], Vec::new()];
        let svg = errors(&[("team", &tracks), ("truth", &tracks)], &events);
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<path").count(), 4, "two variants per robot");
        assert!(svg.contains("inter-robot match") && svg.contains("error [m]") && svg.contains("time [s]"));
        // The legend sits below the plot area: every legend text is lower than the area's bottom.
        let bottom = MARGIN[1] + (PANEL_H - MARGIN[1] - MARGIN[3]);
        for line in svg.lines().filter(|l| l.contains(">team<") || l.contains(">truth<")) {
            let y: f64 = line.split("y=\"").nth(1).unwrap().split('"').next().unwrap().parse().unwrap();
            assert!(y > bottom + 30.0, "{line}");
        }
    }

    #[test]
    fn trajectories_keep_a_metre_equal_in_x_and_y() {
        let svg = trajectories(&[track(1, 0.0)], "team");
        assert!(svg.contains("robot 1 (team)") && svg.contains("ground truth"));
        // The path spans 4.9 m in x and 9.8 m in y: with equal scales its drawn height is twice
        // its width.
        let path = svg.lines().find(|l| l.contains("stroke-dasharray") && l.starts_with("<path")).unwrap();
        let coords: Vec<[f64; 2]> = path
            .split('"')
            .nth(1)
            .unwrap()
            .split(['M', 'L'])
            .filter(|s| !s.trim().is_empty())
            .map(|p| {
                let mut it = p.trim().split(',').map(|v| v.parse::<f64>().unwrap());
                [it.next().unwrap(), it.next().unwrap()]
            })
            .collect();
        let width =
            coords.iter().map(|c| c[0]).fold(f64::MIN, f64::max) - coords.iter().map(|c| c[0]).fold(f64::MAX, f64::min);
        let height =
            coords.iter().map(|c| c[1]).fold(f64::MIN, f64::max) - coords.iter().map(|c| c[1]).fold(f64::MAX, f64::min);
        assert!((height / width - 2.0).abs() < 0.01, "{width} × {height}");
    }

    #[test]
    fn empty_panels_say_so_and_ticks_are_round() {
        assert!(
            render(&[Panel {
                title: "t".into(),
                x_label: "x".into(),
                y_label: "y".into(),
                equal_aspect: false,
                y_from_zero: true,
                series: Vec::new(),
                markers: Vec::new(),
            }])
            .contains("no data")
        );
        assert_eq!(tick_step(10.0, 5.0), 2.0);
        assert_eq!(tick_step(0.37, 5.0), 0.05);
        assert_eq!(tick_step(700.0, 6.0), 100.0);
    }
}
