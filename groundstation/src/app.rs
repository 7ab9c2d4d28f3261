//! The eframe application: each frame takes the model's latest [`TeamView`], draws the panels
//! and hands the operator's actions back. Nothing here waits on I/O: the engine's networking
//! runs on its own thread, and `view()`/`act()` only swap an `Arc` or push into a bounded
//! channel.
//!
//! Also the command line ([`Cli`]), the frame-time ring, the frame log for the Xvfb
//! measurement, and the screenshot-then-exit used by the real-window test.

use std::collections::VecDeque;
use std::ffi::OsString;
use std::fs::File;
use std::io::{BufWriter, Write as _};
use std::path::PathBuf;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use egui::{ColorImage, Ui, ViewportCommand};

use crate::ui::{self, UiState};
use crate::view::{TeamView, UiAction};

/// Where the snapshots come from and where the actions go: the engine in the binary, a fixed
/// view in tests.
pub trait TeamSource {
    fn view(&self) -> Arc<TeamView>;
    /// Hands an action to the model; an error is shown to the operator, never blocks.
    fn act(&mut self, action: UiAction) -> Result<(), String>;
}

impl TeamSource for crate::engine::Engine {
    fn view(&self) -> Arc<TeamView> {
        crate::engine::Engine::view(self)
    }
    fn act(&mut self, action: UiAction) -> Result<(), String> {
        crate::engine::Engine::act(self, action).map_err(|e| e.to_string())
    }
}

/// The environment variable naming the per-frame time log.
pub const FRAME_LOG_ENV: &str = "GROUNDSTATION_FRAME_LOG";
/// When set (to anything), the app redraws continuously instead of at 10 Hz, so the frame log's
/// intervals are the whole frame time (UI, tessellation, GL rendering and buffer swap).
pub const CONTINUOUS_ENV: &str = "GROUNDSTATION_CONTINUOUS";

/// The last frames' UI CPU times.
#[derive(Debug, Clone)]
pub struct FrameTimes {
    ms: VecDeque<f32>,
    capacity: usize,
}

impl FrameTimes {
    pub fn new(capacity: usize) -> Self {
        Self { ms: VecDeque::with_capacity(capacity), capacity: capacity.max(1) }
    }

    pub fn push(&mut self, ms: f32) {
        if self.ms.len() == self.capacity {
            self.ms.pop_front();
        }
        self.ms.push_back(ms);
    }

    /// Nearest-rank quantile `q` in [0, 1] of the kept frames.
    pub fn quantile(&self, q: f64) -> Option<f32> {
        let mut v: Vec<f32> = self.ms.iter().copied().collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f32::total_cmp);
        let rank = ((q.clamp(0.0, 1.0) * v.len() as f64).ceil() as usize).clamp(1, v.len());
        Some(v[rank - 1])
    }

    pub fn summary(&self) -> String {
        match (self.quantile(0.5), self.quantile(0.95), self.quantile(1.0)) {
            (Some(p50), Some(p95), Some(max)) => format!("UI {p50:.1} ms p50, {p95:.1} p95, {max:.1} max"),
            _ => String::new(),
        }
    }
}

/// Take one screenshot `after` the start, write it to `path`, then close the window.
#[derive(Debug, Clone)]
pub struct ScreenshotPlan {
    pub path: PathBuf,
    pub after: Duration,
}

/// The outcome of the screenshot, read by `main` after the window closed.
pub type ScreenshotResult = Arc<Mutex<Option<Result<(), String>>>>;

/// The operator's window.
pub struct GroundStationApp {
    source: Box<dyn TeamSource>,
    pub ui_state: UiState,
    frame_times: FrameTimes,
    frame_log: Option<BufWriter<File>>,
    last_frame_start: Option<Instant>,
    started: Instant,
    screenshot: Option<ScreenshotPlan>,
    screenshot_requested: bool,
    pub screenshot_result: ScreenshotResult,
    exit_after: Option<Duration>,
    last_act_error: Option<String>,
    continuous: bool,
}

impl std::fmt::Debug for GroundStationApp {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GroundStationApp")
            .field("ui_state", &self.ui_state)
            .field("frame_times", &self.frame_times)
            .field("screenshot", &self.screenshot)
            .field("exit_after", &self.exit_after)
            .finish_non_exhaustive()
    }
}

impl GroundStationApp {
    /// Opens the frame log named by [`FRAME_LOG_ENV`] if set (a failure is reported once on
    /// stderr and the app runs without the log); redraws continuously if [`CONTINUOUS_ENV`] is set.
    pub fn new(source: Box<dyn TeamSource>) -> Self {
        let frame_log = std::env::var_os(FRAME_LOG_ENV).and_then(|path| {
            let opened = File::options().create(true).append(true).open(&path).map(BufWriter::new);
            match opened {
                Ok(mut w) => {
                    // A header per run, so that appended runs stay distinguishable.
                    let _ = writeln!(w, "# ui_ms prev_frame_cpu_ms interval_ms");
                    Some(w)
                }
                Err(e) => {
                    eprintln!("groundstation: cannot open {FRAME_LOG_ENV}={}: {e}", PathBuf::from(path).display());
                    None
                }
            }
        });
        Self {
            source,
            ui_state: UiState::default(),
            frame_times: FrameTimes::new(240),
            frame_log,
            last_frame_start: None,
            started: Instant::now(),
            screenshot: None,
            screenshot_requested: false,
            screenshot_result: Arc::new(Mutex::new(None)),
            exit_after: None,
            last_act_error: None,
            continuous: std::env::var_os(CONTINUOUS_ENV).is_some(),
        }
    }

    pub fn with_screenshot(mut self, plan: Option<ScreenshotPlan>) -> Self {
        self.screenshot = plan;
        self
    }

    pub fn with_exit_after(mut self, after: Option<Duration>) -> Self {
        self.exit_after = after;
        self
    }

    pub fn frame_times(&self) -> &FrameTimes {
        &self.frame_times
    }

    /// One frame of UI: snapshot, panels, actions. Returns the UI CPU time, ms.
    pub fn draw(&mut self, ui: &mut Ui) -> f32 {
        let start = Instant::now();
        let view = self.source.view();
        let mut status = self.frame_times.summary();
        if let Some(e) = &self.last_act_error {
            status = format!("action failed: {e}   {status}");
        }
        self.ui_state.status_text = status;
        let actions = ui::show(ui, &view, &mut self.ui_state);
        for action in actions {
            match self.source.act(action) {
                Ok(()) => self.last_act_error = None,
                Err(e) => self.last_act_error = Some(e),
            }
        }
        let ms = start.elapsed().as_secs_f32() * 1e3;
        self.frame_times.push(ms);
        ms
    }

    fn log_frame(&mut self, ui_ms: f32, prev_cpu_s: Option<f32>, start: Instant) {
        let interval_ms = self.last_frame_start.map(|t| (start - t).as_secs_f32() * 1e3);
        self.last_frame_start = Some(start);
        if let Some(w) = &mut self.frame_log {
            let fmt = |v: Option<f32>| v.map_or_else(|| "nan".to_owned(), |v| format!("{v:.3}"));
            let line = writeln!(w, "{ui_ms:.3} {} {}", fmt(prev_cpu_s.map(|s| s * 1e3)), fmt(interval_ms));
            if let Err(e) = line.and_then(|()| w.flush()) {
                eprintln!("groundstation: frame log write failed, stopping it: {e}");
                self.frame_log = None;
            }
        }
    }

    fn handle_timers(&mut self, ctx: &egui::Context) {
        let elapsed = self.started.elapsed();
        if let Some(plan) = &self.screenshot
            && !self.screenshot_requested
            && elapsed >= plan.after
        {
            self.screenshot_requested = true;
            let path = plan.path.clone();
            let result = Arc::clone(&self.screenshot_result);
            let ctx2 = ctx.clone();
            ctx.request_screenshot(move |image| {
                let outcome = save_png(&path, &image);
                if let Err(e) = &outcome {
                    eprintln!("groundstation: screenshot failed: {e}");
                }
                if let Ok(mut slot) = result.lock() {
                    *slot = Some(outcome);
                }
                ctx2.send_viewport_cmd(ViewportCommand::Close);
                ctx2.request_repaint();
            });
        }
        if self.exit_after.is_some_and(|after| elapsed >= after) {
            ctx.send_viewport_cmd(ViewportCommand::Close);
        }
    }
}

impl eframe::App for GroundStationApp {
    fn ui(&mut self, ui: &mut Ui, frame: &mut eframe::Frame) {
        let start = Instant::now();
        let ui_ms = self.draw(ui);
        self.log_frame(ui_ms, frame.info().cpu_usage, start);
        let ctx = ui.ctx().clone();
        self.handle_timers(&ctx);
        if self.continuous {
            ctx.request_repaint();
        } else {
            // The model changes at the link's pace (1 Hz telemetry, 10 Hz poses at most).
            ctx.request_repaint_after(Duration::from_millis(100));
        }
    }
}

/// Writes an RGBA image as a PNG.
pub fn save_png(path: &std::path::Path, image: &ColorImage) -> Result<(), String> {
    let rgba: Vec<u8> = image.pixels.iter().flat_map(|c| c.to_srgba_unmultiplied()).collect();
    let bytes = encode_png_rgba(image.size[0] as u32, image.size[1] as u32, &rgba)?;
    std::fs::write(path, bytes).map_err(|e| format!("cannot write {}: {e}", path.display()))
}

/// PNG bytes of an 8-bit RGBA image (`rgba.len() == 4·w·h`).
pub fn encode_png_rgba(width: u32, height: u32, rgba: &[u8]) -> Result<Vec<u8>, String> {
    if rgba.len() != 4 * width as usize * height as usize || width == 0 || height == 0 {
        return Err(format!("image {width}×{height} does not match {} bytes", rgba.len()));
    }
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgba);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(|e| format!("PNG header: {e}"))?;
    writer.write_image_data(rgba).map_err(|e| format!("PNG data: {e}"))?;
    writer.finish().map_err(|e| format!("PNG end: {e}"))?;
    Ok(bytes)
}

/// The command line.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Cli {
    /// `udp://HOST:PORT` or `serial:///dev/ttyX?baud=N`.
    pub connect: Option<String>,
    pub replay: Option<PathBuf>,
    pub key: Option<PathBuf>,
    pub reference: Option<u8>,
    pub screenshot: Option<PathBuf>,
    pub screenshot_after: Option<Duration>,
    pub exit_after: Option<Duration>,
}

pub const USAGE: &str =
    "usage: groundstation (--connect udp://HOST:PORT | --connect serial:///dev/ttyX?baud=N | --replay DIR)
                     [--key FILE] [--reference ROBOT]
                     [--screenshot PATH.png [--screenshot-after SECONDS]] [--exit-after SECONDS]

  --connect URL            receive the mission's feed and send commands over this link
  --replay DIR             play back a recorded mission directory (commands disabled)
  --key FILE               command authentication key (hex); without it commands are disabled
  --reference ROBOT        draw the team in this robot's frame (default: the first one heard)
  --screenshot PATH.png    save a screenshot of the window, then exit
  --screenshot-after SECS  when to take it (default 5)
  --exit-after SECS        close the window after this long";

/// A command line the ground station cannot run with.
#[derive(Debug, thiserror::Error)]
pub enum CliError {
    #[error("{0}")]
    Parse(#[from] lexopt::Error),
    #[error("give exactly one of --connect URL or --replay DIR")]
    NoSource,
    #[error("--connect and --replay exclude each other")]
    TwoSources,
    #[error("{flag} wants a number of seconds >= 0, got {value:?}")]
    BadSeconds { flag: &'static str, value: String },
    #[error("--reference wants a robot id 0-255, got {0:?}")]
    BadRobot(String),
    #[error("--screenshot-after without --screenshot")]
    AfterWithoutScreenshot,
    #[error("--screenshot {0} must end in .png")]
    NotPng(PathBuf),
    #[error("help requested")]
    Help,
}

fn seconds(flag: &'static str, value: OsString) -> Result<Duration, CliError> {
    let text = value.to_string_lossy().into_owned();
    match text.parse::<f64>() {
        Ok(s) if s.is_finite() && s >= 0.0 => Ok(Duration::from_secs_f64(s)),
        _ => Err(CliError::BadSeconds { flag, value: text }),
    }
}

impl Cli {
    /// Parses the arguments after the program name.
    pub fn parse(args: impl IntoIterator<Item = impl Into<OsString>>) -> Result<Self, CliError> {
        use lexopt::prelude::*;
        let mut cli = Cli::default();
        let mut parser = lexopt::Parser::from_args(args);
        while let Some(arg) = parser.next()? {
            match arg {
                Long("connect") => cli.connect = Some(parser.value()?.string()?),
                Long("replay") => cli.replay = Some(parser.value()?.into()),
                Long("key") => cli.key = Some(parser.value()?.into()),
                Long("reference") => {
                    let v = parser.value()?.to_string_lossy().into_owned();
                    cli.reference = Some(v.parse().map_err(|_| CliError::BadRobot(v))?);
                }
                Long("screenshot") => cli.screenshot = Some(parser.value()?.into()),
                Long("screenshot-after") => {
                    cli.screenshot_after = Some(seconds("--screenshot-after", parser.value()?)?)
                }
                Long("exit-after") => cli.exit_after = Some(seconds("--exit-after", parser.value()?)?),
                Short('h') | Long("help") => return Err(CliError::Help),
                _ => return Err(arg.unexpected().into()),
            }
        }
        match (&cli.connect, &cli.replay) {
            (None, None) => return Err(CliError::NoSource),
            (Some(_), Some(_)) => return Err(CliError::TwoSources),
            _ => {}
        }
        if cli.screenshot_after.is_some() && cli.screenshot.is_none() {
            return Err(CliError::AfterWithoutScreenshot);
        }
        if let Some(p) = &cli.screenshot
            && p.extension().is_none_or(|e| !e.eq_ignore_ascii_case("png"))
        {
            return Err(CliError::NotPng(p.clone()));
        }
        Ok(cli)
    }

    pub fn screenshot_plan(&self) -> Option<ScreenshotPlan> {
        self.screenshot.as_ref().map(|path| ScreenshotPlan {
            path: path.clone(),
            after: self.screenshot_after.unwrap_or(Duration::from_secs(5)),
        })
    }
}

/// Window size and the glow renderer (Mesa's llvmpipe under Xvfb runs it; wgpu is not built).
pub fn native_options() -> eframe::NativeOptions {
    eframe::NativeOptions {
        renderer: eframe::Renderer::Glow,
        viewport: egui::ViewportBuilder::default().with_inner_size([1400.0, 900.0]).with_title("Ground station"),
        ..Default::default()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]

    use super::*;

    #[test]
    fn frame_time_quantiles_over_the_ring() {
        let mut f = FrameTimes::new(4);
        assert_eq!(f.quantile(0.5), None);
        for ms in [100.0, 1.0, 2.0, 3.0, 4.0] {
            f.push(ms);
        }
        // 100 fell out of the ring.
        assert_eq!(f.quantile(1.0), Some(4.0));
        assert_eq!(f.quantile(0.5), Some(2.0));
        assert_eq!(f.quantile(0.95), Some(4.0));
    }

    #[test]
    fn png_pixels_round_trip() {
        let (w, h) = (200u32, 100u32);
        let rgba: Vec<u8> = (0..w * h * 4).map(|i| (i * 7 % 251) as u8).collect();
        let bytes = encode_png_rgba(w, h, &rgba).unwrap();
        let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap();
        let mut decoded = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut decoded).unwrap();
        assert_eq!((info.width, info.height, info.color_type), (w, h, png::ColorType::Rgba));
        assert_eq!(&decoded[..info.buffer_size()], &rgba[..]);
        assert!(encode_png_rgba(2, 2, &[0; 15]).is_err());
    }

    #[test]
    fn cli_accepts_the_documented_forms() {
        let cli = Cli::parse(["--connect", "udp://127.0.0.1:47800", "--key", "k.hex", "--reference", "2"]).unwrap();
        assert_eq!(cli.connect.as_deref(), Some("udp://127.0.0.1:47800"));
        assert_eq!(cli.key, Some(PathBuf::from("k.hex")));
        assert_eq!(cli.reference, Some(2));
        let cli = Cli::parse(["--replay", "runs/demo", "--screenshot", "s.png", "--screenshot-after", "2.5"]).unwrap();
        let plan = cli.screenshot_plan().unwrap();
        assert_eq!((plan.path, plan.after), (PathBuf::from("s.png"), Duration::from_millis(2500)));
    }

    #[test]
    fn cli_rejects_bad_arguments_clearly() {
        let err = |args: &[&str]| Cli::parse(args.iter().copied()).unwrap_err().to_string();
        assert!(err(&[]).contains("exactly one of"));
        assert!(err(&["--connect", "udp://a:1", "--replay", "d"]).contains("exclude"));
        assert!(err(&["--replay", "d", "--exit-after", "soon"]).contains("--exit-after"));
        assert!(err(&["--replay", "d", "--reference", "300"]).contains("0-255"));
        assert!(err(&["--replay", "d", "--screenshot-after", "3"]).contains("without --screenshot"));
        assert!(err(&["--replay", "d", "--screenshot", "x.jpg"]).contains(".png"));
        assert!(err(&["--replay", "d", "--frobnicate"]).contains("frobnicate"));
        assert!(err(&["--connect"]).contains("connect"));
    }
}
