//! `groundstation`: the operator's window. See `groundstation --help` and README.md.

use std::process::ExitCode;
use std::str::FromStr as _;

use groundstation::app::{Cli, CliError, GroundStationApp, USAGE, native_options};
use groundstation::engine::Engine;
use groundstation::model::ModelConfig;
use groundstation::net::LinkSpec;
use groundstation::view::UiAction;

fn main() -> ExitCode {
    let cli = match Cli::parse(std::env::args_os().skip(1)) {
        Ok(cli) => cli,
        Err(CliError::Help) => {
            println!("{USAGE}");
            return ExitCode::SUCCESS;
        }
        Err(e) => {
            eprintln!("groundstation: {e}\n\n{USAGE}");
            return ExitCode::from(2);
        }
    };
    match run(&cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("groundstation: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(cli: &Cli) -> Result<ExitCode, String> {
    let auth_key = match &cli.key {
        Some(path) => Some(hal::keyfile::load_auth_key(path).map_err(|e| e.to_string())?),
        None => None,
    };
    let engine = if let Some(url) = &cli.connect {
        let spec = LinkSpec::from_str(url).map_err(|e| format!("--connect {url}: {e}"))?;
        Engine::live(spec, ModelConfig { auth_key, source: url.clone() }).map_err(|e| format!("{url}: {e}"))?
    } else if let Some(dir) = &cli.replay {
        let source = format!("replay {}", dir.display());
        Engine::replay(dir, ModelConfig { auth_key, source }).map_err(|e| format!("--replay {}: {e}", dir.display()))?
    } else {
        return Err("no source".to_owned());
    };
    if let Some(robot) = cli.reference {
        engine.act(UiAction::SetReference(robot)).map_err(|e| format!("--reference {robot}: {e}"))?;
    }

    let app =
        GroundStationApp::new(Box::new(engine)).with_screenshot(cli.screenshot_plan()).with_exit_after(cli.exit_after);
    let screenshot_result = std::sync::Arc::clone(&app.screenshot_result);
    eframe::run_native("groundstation", native_options(), Box::new(move |_cc| Ok(Box::new(app))))
        .map_err(|e| format!("window: {e}"))?;

    if let Some(plan) = cli.screenshot_plan() {
        let outcome = screenshot_result.lock().ok().and_then(|mut slot| slot.take());
        return match outcome {
            Some(Ok(())) => {
                println!("screenshot saved to {}", plan.path.display());
                Ok(ExitCode::SUCCESS)
            }
            Some(Err(e)) => Err(format!("screenshot: {e}")),
            None => Err("the window closed before the screenshot was taken".to_owned()),
        };
    }
    Ok(ExitCode::SUCCESS)
}
