//! PNG plots: top-down trajectories against ground truth, and error over distance travelled.
//!
//! Text is drawn with plotters' `ab_glyph` backend, which loads no system fonts: the first plot
//! registers [`DEFAULT_FONT_PATH`] (DejaVu Sans from the Debian package `fonts-dejavu-core`,
//! installed by `scripts/lib/setup.sh`) unless [`register_font_file`] was called before. The
//! repository ships no font file.

use std::fmt::Display;
use std::path::{Path, PathBuf};
use std::sync::Mutex;

use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::FontStyle;

use crate::Trajectory;

/// DejaVu Sans as installed by `fonts-dejavu-core`.
pub const DEFAULT_FONT_PATH: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
/// The bold face used for titles when present; titles fall back to the regular face otherwise.
pub const DEFAULT_BOLD_FONT_PATH: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans-Bold.ttf";

/// Ground truth: a neutral grey, drawn under the estimates so they stay readable where they agree.
pub const GT_COLOUR: RGBColor = RGBColor(110, 110, 110);
/// Estimate colours in order (Okabe–Ito: distinguishable with the common colour-vision deficiencies).
pub const ESTIMATE_COLOURS: [RGBColor; 5] = [
    RGBColor(0, 114, 178),
    RGBColor(213, 94, 0),
    RGBColor(0, 158, 115),
    RGBColor(204, 121, 167),
    RGBColor(230, 159, 0),
];

/// Size of the trajectory plot's drawing area; the image height follows the data's aspect.
pub const TRAJECTORY_WIDTH_PX: u32 = 1200;
/// Size of the error-over-distance plot.
pub const ERROR_PLOT_SIZE_PX: (u32, u32) = (1200, 600);

const FONT: &str = "sans-serif";
const TITLE_AREA_PX: u32 = 64;
const MARGIN_PX: u32 = 24;
const X_LABEL_AREA_PX: u32 = 70;
const Y_LABEL_AREA_PX: u32 = 100;
const GRID_COLOUR: RGBColor = RGBColor(225, 225, 225);

/// Why a plot could not be drawn.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    #[error(
        "cannot read the font {path} (install the Debian package fonts-dejavu-core, or call plot::register_font_file): {source}"
    )]
    FontRead { path: PathBuf, source: std::io::Error },
    #[error("{path} is not a TrueType or OpenType font")]
    InvalidFont { path: PathBuf },
    #[error("nothing to plot: {0}")]
    NoData(&'static str),
    #[error("{distances} distances but {errors} errors")]
    LengthMismatch { distances: usize, errors: usize },
    #[error("drawing {path}: {message}")]
    Draw { path: PathBuf, message: String },
}

/// Whether a regular face is registered: plots register the default one on first use.
static FONT_REGISTERED: Mutex<bool> = Mutex::new(false);

/// Registers a TTF/OTF file as the regular face of all plot text; a later call replaces it.
///
/// plotters keeps fonts for the life of the process and wants `'static` bytes, so the file's
/// contents are leaked: call this once, not per plot.
pub fn register_font_file(path: &Path) -> Result<(), PlotError> {
    let mut registered = FONT_REGISTERED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    register_face(path, FontStyle::Normal)?;
    *registered = true;
    Ok(())
}

fn register_face(path: &Path, style: FontStyle) -> Result<(), PlotError> {
    let bytes = std::fs::read(path).map_err(|source| PlotError::FontRead { path: path.to_owned(), source })?;
    let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
    plotters::style::register_font(FONT, style, bytes).map_err(|_| PlotError::InvalidFont { path: path.to_owned() })
}

fn ensure_font() -> Result<(), PlotError> {
    let mut registered = FONT_REGISTERED.lock().unwrap_or_else(|poisoned| poisoned.into_inner());
    if !*registered {
        register_face(Path::new(DEFAULT_FONT_PATH), FontStyle::Normal)?;
        // Bold titles are a nicety: without the bold file they fall back to the regular face.
        let _ = register_face(Path::new(DEFAULT_BOLD_FONT_PATH), FontStyle::Bold);
        *registered = true;
    }
    Ok(())
}

fn draw_err<E: Display>(out: &Path) -> impl Fn(E) -> PlotError + '_ {
    move |e| PlotError::Draw { path: out.to_owned(), message: e.to_string() }
}

/// Draws `title` centred in a band at the top and returns the area below it.
fn with_title<'a>(
    root: &DrawingArea<BitMapBackend<'a>, Shift>,
    title: &str,
    out: &Path,
) -> Result<DrawingArea<BitMapBackend<'a>, Shift>, PlotError> {
    let (band, body) = root.split_vertically(TITLE_AREA_PX);
    let (w, h) = band.dim_in_pixel();
    // `FontDesc::style` keeps the face already looked up: the bold face must be asked for here.
    let style = TextStyle::from(FontDesc::new(FONT.into(), 30.0, FontStyle::Bold)).color(&BLACK).pos(
        plotters::style::text_anchor::Pos::new(
            plotters::style::text_anchor::HPos::Center,
            plotters::style::text_anchor::VPos::Center,
        ),
    );
    band.draw_text(title, &style, ((w / 2) as i32, (h / 2 + 6) as i32)).map_err(draw_err(out))?;
    Ok(body)
}

/// Top-down (x–y) plot of ground truth and estimates with equal axis scales.
///
/// The trajectories are drawn as given: associate and align them first (the plot shows what the
/// metrics measure). Each trajectory gets a circle at its start and a triangle at its end.
pub fn plot_trajectories(
    out: &Path,
    gt: &Trajectory,
    estimates: &[(&str, &Trajectory)],
    title: &str,
) -> Result<(), PlotError> {
    ensure_font()?;
    let xy = |t: &Trajectory| -> Vec<(f64, f64)> {
        t.poses
            .iter()
            .map(|p| (p.translation.x, p.translation.y))
            .filter(|(x, y)| x.is_finite() && y.is_finite())
            .collect()
    };
    let gt_xy = xy(gt);
    let estimates_xy: Vec<(&str, Vec<(f64, f64)>)> = estimates.iter().map(|(name, t)| (*name, xy(t))).collect();
    let all = || gt_xy.iter().chain(estimates_xy.iter().flat_map(|(_, pts)| pts));
    let Some(bounds) = Bounds::of(all()) else {
        return Err(PlotError::NoData("no finite positions in any trajectory"));
    };

    // The legend gets a strip of its own above or below the data (whichever side has the emptier
    // corner), so it never hides a path however the trajectory winds.
    let position = emptiest_corner(all().copied(), &(bounds.x_min..bounds.x_max), &(bounds.y_min..bounds.y_max));
    let legend_on_top = matches!(position, SeriesLabelPosition::UpperLeft | SeriesLabelPosition::UpperRight);
    let strip_px = legend_height_px(estimates.len() + 3);
    // The image takes the data's aspect (within limits), so equal scales leave little empty space.
    let aspect = (bounds.height() / bounds.width()).clamp(0.55, 1.25);
    let plot_w = f64::from(TRAJECTORY_WIDTH_PX - Y_LABEL_AREA_PX - 2 * MARGIN_PX);
    let height_px = (plot_w * aspect) as u32 + strip_px + TITLE_AREA_PX + X_LABEL_AREA_PX + 2 * MARGIN_PX;
    let root = BitMapBackend::new(out, (TRAJECTORY_WIDTH_PX, height_px)).into_drawing_area();
    root.fill(&WHITE).map_err(draw_err(out))?;
    let body = with_title(&root, title, out)?;

    let build = |x: std::ops::Range<f64>, y: std::ops::Range<f64>| {
        ChartBuilder::on(&body)
            .margin(MARGIN_PX)
            .x_label_area_size(X_LABEL_AREA_PX)
            .y_label_area_size(Y_LABEL_AREA_PX)
            .build_cartesian_2d(x, y)
    };
    // Building a chart draws nothing, so a probe gives the exact plotting-area size in pixels;
    // the ranges are then widened until a metre is the same number of pixels on both axes.
    let (plot_w_px, plot_h_px) = build(0.0..1.0, 0.0..1.0).map_err(draw_err(out))?.plotting_area().dim_in_pixel();
    let (x_range, y_range) =
        bounds.padded(0.03).equal_scale(f64::from(plot_w_px), f64::from(plot_h_px), f64::from(strip_px), legend_on_top);
    let mut chart = build(x_range.clone(), y_range.clone()).map_err(draw_err(out))?;
    // Tick counts in proportion to the axes' pixel lengths give both axes the same round step,
    // so the grid is made of squares, which shows the equal scale at a glance.
    let ticks_x = 10;
    let ticks_y = ((ticks_x * plot_h_px as usize) as f64 / f64::from(plot_w_px.max(1))).round().max(2.0) as usize;
    configure_mesh(&mut chart, "x [m]", "y [m]", TickCounts { x: ticks_x, y: ticks_y }, out)?;

    chart
        .draw_series(LineSeries::new(gt_xy.iter().copied(), GT_COLOUR.stroke_width(4)))
        .map_err(draw_err(out))?
        .label("ground truth")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 28, y)], GT_COLOUR.stroke_width(4)));
    for (i, (name, pts)) in estimates_xy.iter().enumerate() {
        let colour = ESTIMATE_COLOURS[i % ESTIMATE_COLOURS.len()];
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), colour.stroke_width(2)))
            .map_err(draw_err(out))?
            .label(*name)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 28, y)], colour.stroke_width(3)));
    }
    // Markers go on top of every line so that no trajectory hides another's start or end.
    let ends: Vec<(RGBColor, &Vec<(f64, f64)>)> = std::iter::once((GT_COLOUR, &gt_xy))
        .chain(estimates_xy.iter().enumerate().map(|(i, (_, pts))| (ESTIMATE_COLOURS[i % ESTIMATE_COLOURS.len()], pts)))
        .collect();
    let marker_outline = BLACK.stroke_width(2);
    chart
        .draw_series(ends.iter().filter_map(|(c, pts)| pts.first().map(|p| Circle::new(*p, 9, c.filled()))))
        .map_err(draw_err(out))?
        .label("start")
        .legend(|(x, y)| Circle::new((x + 14, y), 8, BLACK.filled()));
    chart
        .draw_series(ends.iter().filter_map(|(_, pts)| pts.first().map(|p| Circle::new(*p, 9, marker_outline))))
        .map_err(draw_err(out))?;
    chart
        .draw_series(ends.iter().filter_map(|(c, pts)| pts.last().map(|p| TriangleMarker::new(*p, 12, c.filled()))))
        .map_err(draw_err(out))?
        .label("end")
        .legend(|(x, y)| TriangleMarker::new((x + 14, y), 10, BLACK.filled()));

    draw_legend(&mut chart, position, out)?;
    root.present().map_err(draw_err(out))?;
    Ok(())
}

/// Translation error per pose (m) against distance travelled along the ground truth (m), with the
/// RMSE as a dashed reference line.
pub fn plot_error_over_distance(out: &Path, distance_m: &[f64], error_m: &[f64], title: &str) -> Result<(), PlotError> {
    ensure_font()?;
    if distance_m.len() != error_m.len() {
        return Err(PlotError::LengthMismatch { distances: distance_m.len(), errors: error_m.len() });
    }
    let pts: Vec<(f64, f64)> = distance_m
        .iter()
        .copied()
        .zip(error_m.iter().copied())
        .filter(|(d, e)| d.is_finite() && e.is_finite())
        .collect();
    let Some(bounds) = Bounds::of(pts.iter()) else {
        return Err(PlotError::NoData("no finite (distance, error) pairs"));
    };
    let rmse_m = (pts.iter().map(|(_, e)| e * e).sum::<f64>() / pts.len() as f64).sqrt();
    let x_range = bounds.x_min..bounds.x_max.max(bounds.x_min + 1e-3);

    let root = BitMapBackend::new(out, ERROR_PLOT_SIZE_PX).into_drawing_area();
    root.fill(&WHITE).map_err(draw_err(out))?;
    let body = with_title(&root, title, out)?;
    let build = |y: std::ops::Range<f64>| {
        ChartBuilder::on(&body)
            .margin(MARGIN_PX)
            .x_label_area_size(X_LABEL_AREA_PX)
            .y_label_area_size(Y_LABEL_AREA_PX)
            .build_cartesian_2d(x_range.clone(), y)
    };
    // Errors are magnitudes: the axis starts at zero so heights compare honestly. Headroom above
    // the largest error keeps the legend (top right) clear of the curve.
    let (_, plot_h_px) = build(0.0..1.0).map_err(draw_err(out))?.plotting_area().dim_in_pixel();
    let free_fraction = 1.0 - f64::from(legend_height_px(2) + 8) / f64::from(plot_h_px.max(1));
    let y_min = bounds.y_min.min(0.0);
    let y_max = y_min + (bounds.y_max.max(rmse_m) - y_min).max(1e-3) / free_fraction.max(0.3);
    let mut chart = build(y_min..y_max).map_err(draw_err(out))?;
    configure_mesh(
        &mut chart,
        "distance travelled along ground truth [m]",
        "translation error [m]",
        TickCounts { x: 10, y: 8 },
        out,
    )?;

    let colour = ESTIMATE_COLOURS[0];
    chart
        .draw_series(LineSeries::new(pts.iter().copied(), colour.stroke_width(2)))
        .map_err(draw_err(out))?
        .label("error per pose")
        .legend(move |(x, y)| PathElement::new([(x, y), (x + 28, y)], colour.stroke_width(3)));
    chart
        .draw_series(DashedLineSeries::new(
            [(x_range.start, rmse_m), (x_range.end, rmse_m)],
            12,
            8,
            GT_COLOUR.stroke_width(2),
        ))
        .map_err(draw_err(out))?
        .label(format!("RMSE {rmse_m:.3} m"))
        .legend(|(x, y)| PathElement::new([(x, y), (x + 28, y)], GT_COLOUR.stroke_width(2)));

    draw_legend(&mut chart, SeriesLabelPosition::UpperRight, out)?;
    root.present().map_err(draw_err(out))?;
    Ok(())
}

type Chart<'a, 'b> = ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

/// Upper bounds on the number of tick labels; plotters picks round steps within them.
#[derive(Debug, Clone, Copy)]
struct TickCounts {
    x: usize,
    y: usize,
}

fn configure_mesh(
    chart: &mut Chart<'_, '_>,
    x_desc: &str,
    y_desc: &str,
    ticks: TickCounts,
    out: &Path,
) -> Result<(), PlotError> {
    // Tick labels with as many decimals as the tick spacing needs, the same on every tick
    // ("0.05, 0.10, 0.15" rather than plotters' "0.05, 0.1, 0.15").
    let (x, y) = (chart.x_range(), chart.y_range());
    let (x_decimals, y_decimals) = (tick_decimals(x.end - x.start, ticks.x), tick_decimals(y.end - y.start, ticks.y));
    let x_fmt = move |v: &f64| format_tick(*v, x_decimals);
    let y_fmt = move |v: &f64| format_tick(*v, y_decimals);
    chart
        .configure_mesh()
        .x_label_formatter(&x_fmt)
        .y_label_formatter(&y_fmt)
        .x_desc(x_desc)
        .y_desc(y_desc)
        .axis_desc_style((FONT, 24))
        .label_style((FONT, 20))
        .bold_line_style(GRID_COLOUR)
        .light_line_style(TRANSPARENT)
        .axis_style(BLACK.stroke_width(1))
        .x_labels(ticks.x)
        .y_labels(ticks.y)
        .draw()
        .map_err(draw_err(out))
}

/// Legend layout: entries are drawn `LEGEND_ROW_PX` apart inside a box `LEGEND_MARGIN_PX` from the
/// plot's edge; [`legend_height_px`] reserves room for that box.
const LEGEND_FONT_PX: u32 = 22;
const LEGEND_MARGIN_PX: u32 = 14;

/// Pixel height of a legend with `entries` rows, margin included.
fn legend_height_px(entries: usize) -> u32 {
    // Measured from plotters' layout: one row per font height plus a few pixels, and padding.
    entries as u32 * (LEGEND_FONT_PX + 8) + 2 * LEGEND_MARGIN_PX + 10
}

fn draw_legend<'a, 'b: 'a>(
    chart: &mut Chart<'a, 'b>,
    position: SeriesLabelPosition,
    out: &Path,
) -> Result<(), PlotError> {
    chart
        .configure_series_labels()
        .position(position)
        .margin(LEGEND_MARGIN_PX)
        .legend_area_size(40)
        .label_font((FONT, LEGEND_FONT_PX))
        .background_style(WHITE.mix(0.9))
        .border_style(RGBColor(160, 160, 160))
        .draw()
        .map_err(draw_err(out))
}

/// Decimals that resolve a tick spacing of about `span / labels`.
fn tick_decimals(span: f64, labels: usize) -> usize {
    let step = span / labels.max(1) as f64;
    if step.is_finite() && step > 0.0 { (-step.log10()).ceil().clamp(0.0, 6.0) as usize } else { 2 }
}

fn format_tick(v: f64, decimals: usize) -> String {
    let text = format!("{v:.decimals$}");
    // "-0.00" from a tick a rounding error below zero reads as a different number than "0.00".
    if text.trim_start_matches('-').chars().all(|c| c == '0' || c == '.') {
        text.trim_start_matches('-').to_owned()
    } else {
        text
    }
}

/// The chart corner whose quarter holds the fewest data points: where the legend hides least.
fn emptiest_corner(
    points: impl Iterator<Item = (f64, f64)>,
    x: &std::ops::Range<f64>,
    y: &std::ops::Range<f64>,
) -> SeriesLabelPosition {
    // The legend box is roughly a third of the plot wide and tall; count points under that box.
    let (x_split_lo, x_split_hi) = (x.start + (x.end - x.start) / 3.0, x.end - (x.end - x.start) / 3.0);
    let (y_split_lo, y_split_hi) = (y.start + (y.end - y.start) / 3.0, y.end - (y.end - y.start) / 3.0);
    let mut counts = [0usize; 4]; // upper left, upper right, lower left, lower right
    for (px, py) in points {
        let (left, right) = (px <= x_split_lo, px >= x_split_hi);
        let (lower, upper) = (py <= y_split_lo, py >= y_split_hi);
        counts[0] += usize::from(upper && left);
        counts[1] += usize::from(upper && right);
        counts[2] += usize::from(lower && left);
        counts[3] += usize::from(lower && right);
    }
    // Ties go to the upper right, where readers look for a legend first.
    let order = [1, 0, 3, 2];
    let best = order.into_iter().min_by_key(|&i| counts[i]).unwrap_or(1);
    match best {
        0 => SeriesLabelPosition::UpperLeft,
        2 => SeriesLabelPosition::LowerLeft,
        3 => SeriesLabelPosition::LowerRight,
        _ => SeriesLabelPosition::UpperRight,
    }
}

/// Axis-aligned bounds of finite data.
#[derive(Debug, Clone, Copy)]
struct Bounds {
    x_min: f64,
    x_max: f64,
    y_min: f64,
    y_max: f64,
}

impl Bounds {
    fn of<'a>(points: impl Iterator<Item = &'a (f64, f64)>) -> Option<Self> {
        points.fold(None, |acc: Option<Self>, &(x, y)| {
            Some(match acc {
                None => Self { x_min: x, x_max: x, y_min: y, y_max: y },
                Some(b) => {
                    Self { x_min: b.x_min.min(x), x_max: b.x_max.max(x), y_min: b.y_min.min(y), y_max: b.y_max.max(y) }
                }
            })
        })
    }

    fn width(&self) -> f64 {
        (self.x_max - self.x_min).max(1e-9)
    }

    fn height(&self) -> f64 {
        (self.y_max - self.y_min).max(1e-9)
    }

    /// Grows each side by `fraction` of the larger extent; a degenerate extent gets ±0.5 m.
    fn padded(&self, fraction: f64) -> Self {
        let extent = self.width().max(self.height());
        let pad = if extent > 1e-6 { extent * fraction } else { 0.5 };
        Self { x_min: self.x_min - pad, x_max: self.x_max + pad, y_min: self.y_min - pad, y_max: self.y_max + pad }
    }

    /// Ranges with equal metres per pixel on a `w_px` × `h_px` plot, the data centred in what is
    /// left after an empty strip of `strip_px` at the top (or bottom) for the legend.
    fn equal_scale(
        &self,
        w_px: f64,
        h_px: f64,
        strip_px: f64,
        strip_on_top: bool,
    ) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
        let data_h_px = (h_px - strip_px).max(1.0);
        let m_per_px = (self.width() / w_px.max(1.0)).max(self.height() / data_h_px);
        let (cx, cy) = ((self.x_min + self.x_max) / 2.0, (self.y_min + self.y_max) / 2.0);
        let half_w = m_per_px * w_px / 2.0;
        let (data_half_h, strip) = (m_per_px * data_h_px / 2.0, m_per_px * strip_px);
        let y = if strip_on_top {
            cy - data_half_h..cy + data_half_h + strip
        } else {
            cy - data_half_h - strip..cy + data_half_h
        };
        (cx - half_w..cx + half_w, y)
    }
}
