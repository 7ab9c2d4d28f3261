#![allow(clippy::unwrap_used, clippy::expect_used)]
//! Renders both plots for synthetic trajectories and checks the decoded pixels: size, both
//! colours present in plausible amounts, text drawn, and equal axis scales.

use std::fs::File;
use std::io::BufReader;
use std::path::{Path, PathBuf};

use eval::Trajectory;
use eval::plot::{
    ERROR_PLOT_SIZE_PX, ESTIMATE_COLOURS, GT_COLOUR, PlotError, TRAJECTORY_WIDTH_PX, plot_error_over_distance,
    plot_trajectories, register_font_file,
};
use nalgebra::{Isometry3, Translation3, UnitQuaternion};
use plotters::style::RGBColor;

/// A fresh directory per test, so parallel tests never share files.
fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("eval-plot-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A circle of `radius_m` about (cx, cy), starting at angle 0 (its easternmost point).
fn circle(radius_m: f64, cx: f64, cy: f64, n: usize) -> Trajectory {
    let angle = |i: usize| i as f64 / n as f64 * std::f64::consts::TAU * 0.98;
    Trajectory::new(
        (0..n).map(|i| i as f64 * 0.1).collect(),
        (0..n)
            .map(|i| {
                let (x, y) = (cx + radius_m * angle(i).cos(), cy + radius_m * angle(i).sin());
                Isometry3::from_parts(Translation3::new(x, y, 1.0), UnitQuaternion::identity())
            })
            .collect(),
    )
    .unwrap()
}

struct Image {
    width: u32,
    height: u32,
    rgb: Vec<u8>,
}

impl Image {
    fn read(path: &Path) -> Self {
        let mut decoder = png::Decoder::new(BufReader::new(File::open(path).unwrap()));
        decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
        let mut reader = decoder.read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        assert_eq!(info.color_type, png::ColorType::Rgb, "plotters writes RGB");
        buf.truncate(info.buffer_size());
        Self { width: info.width, height: info.height, rgb: buf }
    }

    fn pixel(&self, x: u32, y: u32) -> [u8; 3] {
        let i = 3 * (y * self.width + x) as usize;
        [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
    }

    fn count(&self, colour: RGBColor) -> usize {
        self.rgb.chunks_exact(3).filter(|p| p == &[colour.0, colour.1, colour.2]).count()
    }

    fn count_dark(&self) -> usize {
        self.rgb.chunks_exact(3).filter(|p| p.iter().all(|&c| c < 60)).count()
    }
}

/// The longest run of consecutive indices for which `has` is true.
fn longest_run(n: u32, has: impl Fn(u32) -> bool) -> (u32, u32) {
    let (mut best, mut start) = ((0, 0), None);
    for i in 0..=n {
        match (i < n && has(i), start) {
            (true, None) => start = Some(i),
            (false, Some(s)) => {
                if i - s > best.1 - best.0 {
                    best = (s, i);
                }
                start = None;
            }
            _ => {}
        }
    }
    best
}

#[test]
fn trajectory_plot_shows_both_trajectories_at_equal_scale() {
    let dir = temp_dir("trajectory");
    let out = dir.join("trajectory.png");
    let gt = circle(20.0, 3.0, -5.0, 400);
    let estimate = circle(19.0, 3.5, -5.0, 400);
    let drifting = circle(21.0, 2.0, -4.0, 400);
    plot_trajectories(&out, &gt, &[("estimate", &estimate), ("drifting", &drifting)], "synthetic circles").unwrap();

    let image = Image::read(&out);
    assert_eq!(image.width, TRAJECTORY_WIDTH_PX);
    assert!((700..2000).contains(&image.height), "height {}", image.height);
    let total = (image.width * image.height) as usize;
    for (name, colour) in
        [("ground truth", GT_COLOUR), ("estimate", ESTIMATE_COLOURS[0]), ("drifting", ESTIMATE_COLOURS[1])]
    {
        let n = image.count(colour);
        // A circle ~1000 px across drawn 2–4 px wide is several thousand pixels; a blank or
        // mis-coloured plot has almost none, a flood fill a large share of the image.
        assert!(n > 3000 && n < total / 10, "{name}: {n} of {total} pixels");
    }
    assert!(image.count_dark() > 500, "title, labels and ticks should be drawn in black");

    // Equal scales: the ground-truth circle is as tall as it is wide (within the marker sizes).
    // Its rows form the longest run of rows holding GT pixels; the legend's swatch lies apart.
    let gt_px = |x, y| image.pixel(x, y) == [GT_COLOUR.0, GT_COLOUR.1, GT_COLOUR.2];
    let (r0, r1) = longest_run(image.height, |y| (0..image.width).any(|x| gt_px(x, y)));
    let (c0, c1) = longest_run(image.width, |x| (r0..r1).any(|y| gt_px(x, y)));
    let (w, h) = (f64::from(c1 - c0), f64::from(r1 - r0));
    assert!(w > 600.0, "circle only {w} px wide");
    assert!((w - h).abs() / w < 0.03, "circle is {w} × {h} px");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn error_plot_shows_the_curve_and_its_rmse() {
    let dir = temp_dir("error");
    let out = dir.join("error.png");
    let distance_m: Vec<f64> = (0..500).map(|i| i as f64 * 0.2).collect();
    let error_m: Vec<f64> = distance_m.iter().map(|d| 0.1 + 0.05 * (d / 5.0).sin()).collect();
    plot_error_over_distance(&out, &distance_m, &error_m, "synthetic error").unwrap();

    let image = Image::read(&out);
    assert_eq!((image.width, image.height), ERROR_PLOT_SIZE_PX);
    let total = (image.width * image.height) as usize;
    let curve = image.count(ESTIMATE_COLOURS[0]);
    assert!(curve > 2000 && curve < total / 10, "curve: {curve} pixels");
    // The dashed RMSE line spans the plot about 60 % inked, 2 px wide.
    let rmse = image.count(GT_COLOUR);
    assert!(rmse > 800 && rmse < total / 20, "RMSE line: {rmse} pixels");
    assert!(image.count_dark() > 500);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn plot_errors_are_reported() {
    let dir = temp_dir("errors");
    let empty = Trajectory::default();
    assert!(matches!(plot_trajectories(&dir.join("a.png"), &empty, &[], "t"), Err(PlotError::NoData(_))));
    assert!(matches!(
        plot_error_over_distance(&dir.join("b.png"), &[0.0, 1.0], &[0.1], "t"),
        Err(PlotError::LengthMismatch { distances: 2, errors: 1 })
    ));
    assert!(matches!(
        plot_error_over_distance(&dir.join("c.png"), &[f64::NAN], &[0.1], "t"),
        Err(PlotError::NoData(_))
    ));
    let unwritable = dir.join("missing-dir").join("d.png");
    let err = plot_error_over_distance(&unwritable, &[0.0, 1.0], &[0.1, 0.2], "t").unwrap_err();
    assert!(matches!(err, PlotError::Draw { ref path, .. } if path == &unwritable), "{err}");
    // A missing font is an error that says what to install; nothing registered changes.
    let err = register_font_file(Path::new("/nonexistent/font.ttf")).unwrap_err();
    assert!(err.to_string().contains("fonts-dejavu-core"), "{err}");
    let not_a_font = dir.join("not-a-font.ttf");
    std::fs::write(&not_a_font, b"hello").unwrap();
    assert!(matches!(register_font_file(&not_a_font), Err(PlotError::InvalidFont { .. })));
    std::fs::remove_dir_all(dir).unwrap();
}
