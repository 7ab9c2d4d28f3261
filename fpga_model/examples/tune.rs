//! Sweep of the tunable parameters of `SgmConfig` on the four Middlebury scenes: scores every
//! combination of P1, P2, the P2 gradient scale, the uniqueness margin and the gradient term of
//! the matching cost with the fast matcher (bad pixels nonocc > 1 px, invalid = bad, exactly as
//! tests/middlebury.rs scores), and prints the best uniform settings (one setting for all
//! scenes).
//!
//! ```text
//! cargo run --release -p fpga_model --example tune -- \
//!     [--p1 4,6,8] [--p2 60,120] [--scale 0,16] [--uniqueness 0,5] [--paths 4|8] \
//!     [--gradient-weight 0,4] [--gradient-truncation 16,32] \
//!     [--lr-max-diff 1,2] [--lr-lenient 1,0] [--lr-check 1,0] [--census 9x7,7x7] \
//!     [--opencv 3.95,13.92,12.06,15.96] [--top 15]
//! ```
//! The gradient term and the LR options default to `SgmConfig::default`'s values. The census
//! window and the left-right check are fixed by the hardware design; their options are there to
//! show what they cost or gain.
//! `--opencv` gives OpenCV's best rate per scene in percent (tsukuba, teddy, cones, Reindeer, as
//! printed by tests/middlebury_vs_opencv.rs); settings then are ranked by their worst margin to
//! it.

use std::process::ExitCode;

use fpga_model::eval::{DEFAULT_THRESHOLD_PX, Scene, default_data_root};
use fpga_model::{PathMode, SgmConfig, fast, io};

#[derive(Debug)]
struct Grid {
    p1: Vec<u8>,
    p2: Vec<u8>,
    scale: Vec<u8>,
    uniqueness: Vec<u8>,
    gradient_cost_weight: Vec<u8>,
    gradient_cost_truncation: Vec<u8>,
    lr_max_diff: Vec<u8>,
    lr_lenient: Vec<bool>,
    lr_check: Vec<bool>,
    /// Census windows, width × height.
    census: Vec<(u8, u8)>,
    paths: PathMode,
    opencv_percent: Option<Vec<f64>>,
    top: usize,
}

fn list<T: std::str::FromStr>(option: &str, value: std::ffi::OsString) -> Result<Vec<T>, String> {
    let text = value.to_string_lossy().into_owned();
    text.split(',').map(|v| v.trim().parse().map_err(|_| format!("--{option}: bad value '{v}'"))).collect()
}

fn parse_args() -> Result<Grid, String> {
    use lexopt::prelude::*;
    let default = SgmConfig::default();
    let mut grid = Grid {
        p1: vec![24, 32, 40, 48, 56],
        p2: vec![96, 120, 160, 200, 255],
        scale: vec![0, 16, 32, 64, 128],
        uniqueness: vec![0, 2, 5, 10],
        gradient_cost_weight: vec![default.gradient_cost_weight],
        gradient_cost_truncation: vec![default.gradient_cost_truncation],
        lr_max_diff: vec![default.lr_max_diff],
        lr_lenient: vec![default.lr_lenient],
        lr_check: vec![default.lr_check],
        census: vec![(default.census_width, default.census_height)],
        paths: default.paths,
        opencv_percent: None,
        top: 15,
    };
    let mut parser = lexopt::Parser::from_env();
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        let value = |parser: &mut lexopt::Parser| parser.value().map_err(|e| e.to_string());
        match arg {
            Long("p1") => grid.p1 = list("p1", value(&mut parser)?)?,
            Long("p2") => grid.p2 = list("p2", value(&mut parser)?)?,
            Long("scale") => grid.scale = list("scale", value(&mut parser)?)?,
            Long("uniqueness") => grid.uniqueness = list("uniqueness", value(&mut parser)?)?,
            Long("gradient-weight") => grid.gradient_cost_weight = list("gradient-weight", value(&mut parser)?)?,
            Long("gradient-truncation") => {
                grid.gradient_cost_truncation = list("gradient-truncation", value(&mut parser)?)?
            }
            Long("lr-max-diff") => grid.lr_max_diff = list("lr-max-diff", value(&mut parser)?)?,
            Long("lr-lenient") => {
                grid.lr_lenient = list::<u8>("lr-lenient", value(&mut parser)?)?.iter().map(|&v| v != 0).collect()
            }
            Long("lr-check") => {
                grid.lr_check = list::<u8>("lr-check", value(&mut parser)?)?.iter().map(|&v| v != 0).collect()
            }
            Long("census") => {
                let windows: Vec<String> = list("census", value(&mut parser)?)?;
                grid.census = windows
                    .iter()
                    .map(|w| {
                        let (a, b) = w.split_once('x').ok_or_else(|| format!("--census: '{w}' is not WxH"))?;
                        Ok((
                            a.parse().map_err(|_| format!("--census: '{w}'"))?,
                            b.parse().map_err(|_| format!("--census: '{w}'"))?,
                        ))
                    })
                    .collect::<Result<_, String>>()?;
            }
            Long("opencv") => grid.opencv_percent = Some(list("opencv", value(&mut parser)?)?),
            Long("top") => grid.top = list::<usize>("top", value(&mut parser)?)?.first().copied().unwrap_or(15),
            Long("paths") => {
                grid.paths = match list::<u8>("paths", value(&mut parser)?)?.as_slice() {
                    [4] => PathMode::Four,
                    [8] => PathMode::Eight,
                    _ => return Err("--paths must be 4 or 8".to_owned()),
                }
            }
            _ => return Err(arg.unexpected().to_string()),
        }
    }
    Ok(grid)
}

#[derive(Debug)]
struct Scored {
    config: SgmConfig,
    percent: Vec<f64>,
    mean_percent: f64,
    /// Smallest (OpenCV − ours) over the scenes in percentage points; positive = wins everywhere.
    worst_margin_pp: Option<f64>,
}

fn run() -> Result<(), String> {
    let grid = parse_args()?;
    let scenes = Scene::load_all(default_data_root()).map_err(|e| e.to_string())?;
    if let Some(opencv) = &grid.opencv_percent
        && opencv.len() != scenes.len()
    {
        return Err(format!("--opencv needs {} values (one per scene)", scenes.len()));
    }
    let threads = std::thread::available_parallelism().map_or(1, usize::from);
    // One matcher per scene and configuration; the matcher is cheap to build next to a frame.
    let mut configs = Vec::new();
    for &p1 in &grid.p1 {
        for &p2 in grid.p2.iter().filter(|&&p2| p2 >= p1) {
            for &scale in &grid.scale {
                for &uniqueness in &grid.uniqueness {
                    for &lr_check in &grid.lr_check {
                        // Without the check its tolerance and leniency are moot: score that once.
                        let tolerances = if lr_check { &grid.lr_max_diff[..] } else { &grid.lr_max_diff[..1] };
                        let lenient = if lr_check { &grid.lr_lenient[..] } else { &grid.lr_lenient[..1] };
                        for (&lr_max_diff, &lr_lenient) in
                            tolerances.iter().flat_map(|t| lenient.iter().map(move |l| (t, l)))
                        {
                            for &(census_width, census_height) in &grid.census {
                                for &gradient_cost_weight in &grid.gradient_cost_weight {
                                    // Without the term its truncation is moot: score that once.
                                    let truncations = if gradient_cost_weight == 0 {
                                        &grid.gradient_cost_truncation[..1]
                                    } else {
                                        &grid.gradient_cost_truncation[..]
                                    };
                                    for &gradient_cost_truncation in truncations {
                                        configs.push(SgmConfig {
                                            paths: grid.paths,
                                            p1,
                                            p2,
                                            p2_gradient_scale: scale,
                                            uniqueness_percent: uniqueness,
                                            lr_check,
                                            lr_max_diff,
                                            lr_lenient,
                                            census_width,
                                            census_height,
                                            gradient_cost_weight,
                                            gradient_cost_truncation,
                                            ..SgmConfig::default()
                                        });
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
    }
    let mut scored = Vec::with_capacity(configs.len());
    for config in configs {
        let mut percent = Vec::with_capacity(scenes.len());
        for scene in &scenes {
            let config = SgmConfig { disparities: scene.disparities, ..config };
            // One matcher per scene and configuration: building it is cheap next to a frame.
            let mut matcher =
                fast::Matcher::new(config, scene.left.width, scene.left.height, threads).map_err(|e| e.to_string())?;
            let disparity = matcher.compute(&scene.left, &scene.right).map_err(|e| e.to_string())?;
            let values = io::disparity_to_pfm_values(&disparity);
            percent.push(100.0 * scene.bad_pixel_rate(&values, DEFAULT_THRESHOLD_PX).map_err(|e| e.to_string())?);
        }
        let mean_percent = percent.iter().sum::<f64>() / percent.len() as f64;
        let worst_margin_pp = grid.opencv_percent.as_ref().map(|opencv| {
            opencv.iter().zip(&percent).map(|(theirs, ours)| theirs - ours).fold(f64::INFINITY, f64::min)
        });
        scored.push(Scored { config, percent, mean_percent, worst_margin_pp });
    }
    // Rank by the worst margin to OpenCV if given (the goal: win on every scene), else by mean.
    scored.sort_by(|a, b| match (a.worst_margin_pp, b.worst_margin_pp) {
        (Some(ma), Some(mb)) => mb.total_cmp(&ma).then(a.mean_percent.total_cmp(&b.mean_percent)),
        _ => a.mean_percent.total_cmp(&b.mean_percent),
    });
    let names: Vec<&str> = scenes.iter().map(|s| s.name.as_str()).collect();
    println!(
        "{} settings scored, {} paths; bad pixels nonocc > {DEFAULT_THRESHOLD_PX} px in %",
        scored.len(),
        grid.paths.count()
    );
    println!(
        "| p1 | p2 | scale | U | LR | census | gradient w, T | {} | mean | worst margin to OpenCV (pp) |",
        names.join(" | ")
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|{}---:|---:|", "---:|".repeat(names.len()));
    for s in scored.iter().take(grid.top) {
        let rates: Vec<String> = s.percent.iter().map(|p| format!("{p:.2}")).collect();
        println!(
            "| {} | {} | {} | {} | {} | {}x{} | {}, {} | {} | {:.2} | {} |",
            s.config.p1,
            s.config.p2,
            s.config.p2_gradient_scale,
            s.config.uniqueness_percent,
            match (s.config.lr_check, s.config.lr_lenient) {
                (false, _) => "off".to_owned(),
                (true, false) => format!("<={}", s.config.lr_max_diff),
                (true, true) => format!("<={} lenient", s.config.lr_max_diff),
            },
            s.config.census_width,
            s.config.census_height,
            s.config.gradient_cost_weight,
            s.config.gradient_cost_truncation,
            rates.join(" | "),
            s.mean_percent,
            s.worst_margin_pp.map_or("-".to_owned(), |m| format!("{m:+.2}"))
        );
    }
    Ok(())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("tune: {message}");
            ExitCode::from(2)
        }
    }
}
