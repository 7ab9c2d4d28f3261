//! `sil campaign --out DIR [--scenarios A,B|all] [--variants team,solo,truth] [--downscale K]
//! [--duration S] [--threads N]`: the named experiments in every variant; `DIR/report.md`.
//! Exit codes: 0 success, 1 runtime error, 2 usage error.

use std::ffi::OsString;
use std::io::IsTerminal;
use std::process::ExitCode;

use sim::scenario::experiments;

use crate::campaign::{self, Campaign, CampaignOptions, Variant};

const USAGE: &str = "usage: sil campaign --out DIR [--scenarios A,B|all] [--variants team,solo,truth]
                    [--downscale K] [--duration S] [--threads N]

  --out DIR          output folder: DIR/NAME/VARIANT/ per mission (its outputs and report),
                     DIR/report.md for the whole campaign (rewritten after every mission)
  --scenarios LIST   comma-separated experiments (`sil mission --scenario list`; default all)
  --variants LIST    comma-separated: team (the robots' own loop closures; the thesis's
                     back-end variants replay its graph inputs), truth (closures from the
                     simulator's truth: the upper bound), solo (a second run with no radio
                     between the robots, to check the single-robot replay); default team,truth
  --downscale K      camera resolution 1024x508 / K, K in 1, 2, 4 (default 1)
  --duration S       run only the first S seconds of each experiment (default: all of it)
  --threads N        threads stepping the robots of a mission (default: the machine's cores)";

fn list<T>(text: &str, name: &str, parse: impl Fn(&str) -> Option<T>, known: &str) -> Result<Vec<T>, String> {
    let items: Result<Vec<T>, String> = text
        .split(',')
        .map(|item| parse(item.trim()).ok_or_else(|| format!("{name}: unknown {:?} (known: {known})", item.trim())))
        .collect();
    match items {
        Ok(items) if items.is_empty() => Err(format!("{name}: empty list")),
        other => other,
    }
}

fn parse_args(args: Vec<OsString>) -> Result<Option<CampaignOptions>, String> {
    use super::text;
    use lexopt::prelude::*;
    let mut parser = lexopt::Parser::from_args(args);
    let mut options = CampaignOptions::default();
    let mut out = None;
    while let Some(arg) = parser.next().map_err(|e| e.to_string())? {
        match arg {
            Long("out") => out = Some(parser.value().map_err(|e| e.to_string())?.into()),
            Long("scenarios") => {
                let v = text(&mut parser, "--scenarios")?;
                if v != "all" {
                    let known = experiments::names().join(", ");
                    options.experiments = list(&v, "--scenarios", experiments::find, &known)?;
                }
            }
            Long("variants") => {
                let v = text(&mut parser, "--variants")?;
                options.variants = list(&v, "--variants", Variant::parse, "team, solo, truth")?;
            }
            Long("downscale") => {
                options.downscale = super::downscale(&text(&mut parser, "--downscale")?)?;
            }
            Long("duration") => {
                options.duration_s = Some(super::duration_s(&text(&mut parser, "--duration")?)?);
            }
            Long("threads") => {
                options.step_threads = super::step_threads(&text(&mut parser, "--threads")?)?;
            }
            Long("help") | Short('h') => return Ok(None),
            other => return Err(other.unexpected().to_string()),
        }
    }
    options.out = out.ok_or("--out is required")?;
    options.progress = std::io::stderr().is_terminal();
    Ok(Some(options))
}

pub fn main(args: Vec<OsString>) -> ExitCode {
    let run =
        |options: &CampaignOptions| -> Result<Campaign, String> { campaign::run(options).map_err(|e| e.to_string()) };
    let (options, campaign) = match onboard::cli::parse_and_run("sil", "campaign", USAGE, args, parse_args, run) {
        Ok(done) => done,
        Err(code) => return code,
    };
    println!(
        "{} missions in {:.0} s; report in {}",
        campaign.runs.len(),
        campaign.wall_s,
        options.out.join("report.md").display()
    );
    ExitCode::SUCCESS
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]

    use super::*;

    fn parse(args: &[&str]) -> Result<Option<CampaignOptions>, String> {
        parse_args(args.iter().map(OsString::from).collect())
    }

    #[test]
    fn lists_of_scenarios_and_variants_are_checked() {
        let o = parse(&["--out", "x", "--scenarios", "loops, lab-rocks", "--variants", "team,solo"]).unwrap().unwrap();
        assert_eq!(o.experiments.iter().map(|e| e.name).collect::<Vec<_>>(), ["loops", "lab-rocks"]);
        assert_eq!(o.variants, [Variant::Team, Variant::Solo]);
        let all = parse(&["--out", "x"]).unwrap().unwrap();
        assert_eq!(all.experiments.len(), experiments::EXPERIMENTS.len());
        assert_eq!(all.variants, Variant::DEFAULT);
        for (args, needle) in [
            (&["--scenarios", "loops"][..], "--out"),
            (&["--out", "x", "--scenarios", "loops,venus"][..], "venus"),
            (&["--out", "x", "--variants", "team,filter"][..], "filter"),
            (&["--out", "x", "--variants", ""][..], "--variants"),
            (&["--out", "x", "--duration", "1"][..], "--duration"),
        ] {
            let error = parse(args).err().unwrap();
            assert!(error.contains(needle), "{args:?}: {error}");
        }
    }
}
