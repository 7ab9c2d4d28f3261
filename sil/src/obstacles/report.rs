//! The lines of the evaluation's text report (the `sim_obstacles` example prints them): one row
//! per [`Tally`], the recall by rock height and by range, the approach runs, the false clusters
//! and the SGM disparity error.

use super::{APPROACH_STEP_M, Aim, DISPARITY_BIN_PX, DISPARITY_SPAN_PX, FalseCluster, RANGE_BIN_M, RunOutcome, Tally};
use super::{approach_distances, ratio};

/// Selects the runs of one summary line.
type RunFilter = fn(&RunOutcome) -> bool;

/// A ratio as a percentage with one decimal, `n/a` without one.
pub fn pct(v: Option<f64>) -> String {
    v.map_or_else(|| "n/a".to_owned(), |v| format!("{:.1} %", 100.0 * v))
}

/// One table row: frames, rock, edge-disc and step-cell recall, clusters and their precision.
pub fn tally_row(name: &str, t: &Tally) -> String {
    format!(
        "{name:>6} {:5} | rocks {:4}/{:<4} {:>7} | edge discs {:5}/{:<5} {:>7} | step cells {:>7} | clusters {:4}: rocks {:3}, +edges {:3} ({:>7}), +steps {:3} ({:>7})",
        t.frames,
        t.rocks_found,
        t.rocks,
        pct(t.rock_recall()),
        t.edges_found,
        t.edges,
        pct(t.edge_recall()),
        pct(t.step_recall()),
        t.clusters,
        t.clusters_rocks,
        t.clusters_listed,
        pct(t.precision_listed()),
        t.clusters_any,
        pct(t.precision()),
    )
}

/// Rock recall by height above `h_max` ([`Tally::rock_bins`]), a line per bin.
pub fn rock_height_lines(t: &Tally) -> Vec<String> {
    let names = ["h_max..+0.1 m", "+0.1..+0.3 m", ">= +0.3 m"];
    names
        .iter()
        .zip(&t.rock_bins)
        .map(|(name, (seen, found))| {
            format!("  rocks {name:>14}: {found}/{seen} found ({})", pct(ratio(*found, *seen)))
        })
        .collect()
}

/// Rock and edge-disc recall by camera distance ([`Tally::rock_ranges`], [`Tally::edge_ranges`]).
pub fn range_lines(t: &Tally) -> Vec<String> {
    [("rocks", &t.rock_ranges), ("edge discs", &t.edge_ranges)]
        .into_iter()
        .map(|(name, bins)| {
            let cells: Vec<String> = bins
                .iter()
                .enumerate()
                .map(|(k, (seen, found))| {
                    let lo = k as f64 * RANGE_BIN_M;
                    format!("{lo:.0}-{:.0} m {found}/{seen} {}", lo + RANGE_BIN_M, pct(ratio(*found, *seen)))
                })
                .collect();
            format!("  {name} by camera distance: {}", cells.join(", "))
        })
        .collect()
}

/// The approach runs from `far_m` to `near_m` with head tilt `tilt_rad` (`None`: as mounted): a
/// header, then for rocks by height above `h_max` and for edge sections how many runs mapped and
/// found their target, and how many found it by each frame distance.
pub fn approach_lines(outcomes: &[RunOutcome], (far_m, near_m): (f64, f64), tilt_rad: Option<f64>) -> Vec<String> {
    let mut lines = vec![format!(
        "approach runs (camera from {far_m:.1} to {near_m:.1} m, a frame every {APPROACH_STEP_M} m, head tilt {}; found = in at least one frame):",
        tilt_rad.map_or_else(|| "as mounted".to_owned(), |t| format!("{t:.2} rad"))
    )];
    let groups: [(&str, RunFilter); 5] = [
        ("rocks", |o: &RunOutcome| o.aim == Aim::Rock),
        ("rocks h_max..+0.1 m", |o: &RunOutcome| o.aim == Aim::Rock && o.excess_height_m < 0.1),
        ("rocks +0.1..+0.3 m", |o: &RunOutcome| o.aim == Aim::Rock && (0.1..0.3).contains(&o.excess_height_m)),
        ("rocks >= +0.3 m", |o: &RunOutcome| o.aim == Aim::Rock && o.excess_height_m >= 0.3),
        ("edge sections", |o: &RunOutcome| o.aim == Aim::Edge),
    ];
    for (name, keep) in &groups {
        let runs: Vec<&RunOutcome> = outcomes.iter().filter(|o| keep(o)).collect();
        let seen: Vec<&&RunOutcome> = runs.iter().filter(|o| o.seen).collect();
        let mut at: Vec<f64> = seen.iter().filter_map(|o| o.found_at_m).collect();
        at.sort_by(f64::total_cmp);
        let by_distance: Vec<String> = approach_distances((far_m, near_m))
            .map(|d| format!("{d:.1} m {}", at.iter().filter(|&&a| a >= d - 1e-9).count()))
            .collect();
        lines.push(format!(
            "  {name:>20}: {} runs, {} mapped, {} found ({}); found by this distance: {}",
            runs.len(),
            seen.len(),
            at.len(),
            pct(ratio(at.len(), seen.len())),
            by_distance.join(", ")
        ));
    }
    lines
}

/// How many clusters lie off the listed obstacles, and how many of them on a true step taller
/// than `max_step_m`.
pub fn false_cluster_summary(clusters: &[(u64, FalseCluster)], max_step_m: f64) -> String {
    let real = clusters.iter().filter(|(_, c)| c.true_step_m > max_step_m as f32).count();
    format!(
        "clusters off the listed obstacles: {} ({} on a true step > h_max, the rest stereo artefacts)",
        clusters.len(),
        real
    )
}

/// One false cluster of world `seed`: where, how big, and its measured and true steps.
pub fn false_cluster_line(seed: u64, c: &FalseCluster) -> String {
    format!(
        "  seed {seed} at ({:7.2}, {:7.2}) {:3} cells, {:.2} m from camera: h_diff {:.3} > {:.3}, true step {:.3}{}",
        c.centre_m.x,
        c.centre_m.y,
        c.cells,
        c.camera_distance_m,
        c.h_diff_m,
        c.threshold_m,
        c.true_step_m,
        if c.negative_edge { ", negative edge" } else { "" }
    )
}

/// The SGM disparity error against the rendered truth: invalid and blunder shares, then the
/// median, quantiles and the MAD-based spread of the errors within ±[`DISPARITY_SPAN_PX`].
pub fn disparity_summary(t: &Tally) -> String {
    let inliers: u64 = t.disparity_error_bins.iter().sum();
    let total = inliers + t.disparity_blunders + t.disparity_invalid;
    let q = |q: f64| t.disparity_error_quantile_px(q).unwrap_or(f64::NAN);
    let (p16, p50, p84) = (q(0.1587), q(0.5), q(0.8413));
    let mad = {
        let mut dev: Vec<(f64, u64)> = t
            .disparity_error_bins
            .iter()
            .enumerate()
            .map(|(k, &n)| (((k as f64 + 0.5) * DISPARITY_BIN_PX - DISPARITY_SPAN_PX - p50).abs(), n))
            .collect();
        dev.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut seen = 0;
        dev.iter()
            .find(|(_, n)| {
                seen += n;
                2 * seen >= inliers
            })
            .map_or(f64::NAN, |(d, _)| *d)
    };
    format!(
        "SGM disparity error vs rendered truth (true depth <= range cutoff, {total} px): {:.2} % invalid, {:.2} % off by > {DISPARITY_SPAN_PX} px; within: median {p50:+.2} px, 15.9/84.1 % quantiles {p16:+.2}/{p84:+.2} px (half-width {:.2} px), 1.4826·MAD {:.2} px, 2.3/97.7 % {:+.2}/{:+.2} px, 0.1/99.9 % {:+.2}/{:+.2} px",
        100.0 * t.disparity_invalid as f64 / total.max(1) as f64,
        100.0 * t.disparity_blunders as f64 / total.max(1) as f64,
        0.5 * (p84 - p16),
        1.4826 * mad,
        q(0.0228),
        q(0.9772),
        q(0.001),
        q(0.999),
    )
}

/// The median classification time of `t`'s frames, `None` without frames.
pub fn classify_line(t: &Tally) -> Option<String> {
    let mut ms = t.classify_ms.clone();
    ms.sort_by(f64::total_cmp);
    ms.get(ms.len() / 2).map(|median| {
        format!("classify: median {median:.1} ms per 1024x508 depth image (this process, not the benchmark)")
    })
}
