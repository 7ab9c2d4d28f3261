//! No false or wrong detections on simulated terrain: full-resolution (1024×508) frames of Moon
//! worlds (four seeds, three rovers each carrying three 16 cm tag36h11 markers, ids 3j..3j+2)
//! from cameras placed 2.5–12 m from a rover and looking at its mast, and frames looking over
//! open terrain. Every detection must be a marker that is in view (its whole tag inside the
//! image, facing the camera) and lie on it (centre within 2 px of the projected marker centre).
//!
//! The table printed (`--nocapture`) compares settings: the flight defaults must make no wrong
//! detection; the others are the evidence the defaults were chosen on (vision README).

#![allow(clippy::unwrap_used, reason = "test helpers: a panic is a failed test with its message")]

mod apriltag_common;

use apriltag_common::{SimFrame, sim_frames};
use vision::apriltag::{TagDetector, TagDetectorConfig};

const SEEDS: [u64; 4] = [1, 2, 3, 4];
const VIEWS_PER_SEED: usize = 9;
const TERRAIN_VIEWS_PER_SEED: usize = 3;
/// Distance bands for the recall table: the mapper uses detections up to 7 m (the uncertainty
/// table's range).
const BANDS: [(f64, f64); 3] = [(0.0, 4.0), (4.0, 7.0), (7.0, f64::INFINITY)];
const FRONTAL_RAD: f64 = 60.0 * std::f64::consts::PI / 180.0;

fn band(distance_m: f64) -> usize {
    BANDS.iter().position(|&(lo, hi)| distance_m >= lo && distance_m < hi).unwrap_or(BANDS.len() - 1)
}

#[derive(Debug, Default)]
struct Tally {
    markers_in_view: usize,
    found: usize,
    /// Per band of [`BANDS`]: (in view, found), for markers seen at most 60° off their normal.
    by_distance: [(usize, usize); 3],
    wrong: Vec<String>,
    corner_errors_px: Vec<f64>,
}

fn evaluate(config: TagDetectorConfig, frames: &[SimFrame]) -> Tally {
    let mut detector = TagDetector::new(config).unwrap();
    let mut tally = Tally::default();
    for frame in frames {
        tally.markers_in_view += frame.markers.len();
        for m in frame.markers.iter().filter(|m| m.view_angle_rad <= FRONTAL_RAD) {
            tally.by_distance[band(m.distance_m)].0 += 1;
        }
        for t in detector.detect(frame.image.view()) {
            let marker = frame.markers.iter().find(|m| {
                m.id == t.id && (m.center_px[0] - t.center_px[0]).hypot(m.center_px[1] - t.center_px[1]) < 2.0
            });
            match marker {
                Some(m) => {
                    tally.found += 1;
                    if m.view_angle_rad <= FRONTAL_RAD {
                        tally.by_distance[band(m.distance_m)].1 += 1;
                    }
                    for (a, b) in t.corners_px.iter().zip(&m.corners_px) {
                        tally.corner_errors_px.push((a[0] - b[0]).hypot(a[1] - b[1]));
                    }
                }
                None => tally.wrong.push(format!(
                    "{}: id {} (hamming {}, margin {:.1}) at ({:.1}, {:.1}); in view: {:?}",
                    frame.label,
                    t.id,
                    t.hamming,
                    t.decision_margin,
                    t.center_px[0],
                    t.center_px[1],
                    frame.markers.iter().map(|m| m.id).collect::<Vec<_>>()
                )),
            }
        }
    }
    tally
}

#[test]
fn no_wrong_detections_on_simulated_terrain() {
    let start = std::time::Instant::now();
    let frames: Vec<SimFrame> =
        SEEDS.iter().flat_map(|&seed| sim_frames(seed, VIEWS_PER_SEED, TERRAIN_VIEWS_PER_SEED)).collect();
    let with_rover = frames.iter().filter(|f| !f.markers.is_empty()).count();
    println!(
        "{} frames ({} with markers in view, {} markers), rendered in {:.1} s",
        frames.len(),
        with_rover,
        frames.iter().map(|f| f.markers.len()).sum::<usize>(),
        start.elapsed().as_secs_f64()
    );
    assert!(with_rover >= SEEDS.len() * VIEWS_PER_SEED / 2, "too few frames show a rover's markers");

    let defaults = TagDetectorConfig::default();
    println!(
        "| decimate | max_hamming | min_margin | markers found / in view | ≤ 60° off normal, found / in view at < 4 m, 4–7 m, ≥ 7 m | wrong | corner error median / max px |"
    );
    println!("|---|---|---|---|---|---|---|");
    let mut default_tally = None;
    for decimate in [1u32, 2] {
        for max_hamming in [0u32, 1, 2, 3] {
            let config = TagDetectorConfig { quad_decimate: decimate, max_hamming, ..defaults };
            let mut tally = evaluate(config, &frames);
            tally.corner_errors_px.sort_by(f64::total_cmp);
            let median = tally.corner_errors_px.get(tally.corner_errors_px.len() / 2).copied().unwrap_or(f64::NAN);
            let max = tally.corner_errors_px.last().copied().unwrap_or(f64::NAN);
            let bands: Vec<String> = tally.by_distance.iter().map(|(n, f)| format!("{f} / {n}")).collect();
            println!(
                "| {decimate} | {max_hamming} | {} | {} / {} | {} | {} | {median:.3} / {max:.3} |",
                config.min_decision_margin,
                tally.found,
                tally.markers_in_view,
                bands.join(", "),
                tally.wrong.len()
            );
            for w in &tally.wrong {
                println!("  wrong: {w}");
            }
            if config == defaults {
                default_tally = Some(tally);
            }
        }
    }
    let tally = default_tally.unwrap();
    assert!(tally.wrong.is_empty(), "wrong detections with the flight defaults: {:#?}", tally.wrong);
    // Within the mapper's 7 m, seen less than 60° off their normal (measured 23 of 26): the
    // markers farther out or more oblique are the detector's range, reported above, not asserted.
    let (near_in_view, near_found) =
        (tally.by_distance[0].0 + tally.by_distance[1].0, tally.by_distance[0].1 + tally.by_distance[1].1);
    assert!(near_in_view >= 20, "too few near markers in view: {near_in_view}");
    assert!(
        near_found * 10 >= near_in_view * 8,
        "found {near_found} of {near_in_view} markers within 7 m and 60° of their normal"
    );
    println!("total {:.1} s", start.elapsed().as_secs_f64());
}
