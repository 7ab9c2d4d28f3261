//! Shared by the AprilTag tests and benchmark: the real photo sets, the upstream C reference
//! (`scripts/apriltag_reference.py` in the project venv), matching of detections, and simulated
//! frames with the markers in view.
#![allow(dead_code, clippy::unwrap_used, clippy::expect_used, reason = "test helpers: a panic is a failed test")]

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Vector3};
use sim::render::Renderer;
use sim::scenario::{ScenarioOptions, preset};
use sim::world::World;
use vision::apriltag::TagDetection;
use vision::image_file::{self, GreyImage};

pub const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/apriltag/");

/// One set of real photographs and the tag ids it is known to contain.
pub struct PhotoSet {
    pub name: &'static str,
    pub images: Vec<(String, GreyImage)>,
    pub known_ids: BTreeSet<u32>,
}

/// Ids in column `tag_id` of a derived detections CSV.
fn csv_ids(path: &str) -> BTreeSet<u32> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    let column = header.iter().position(|h| *h == "tag_id").unwrap();
    lines.filter(|l| !l.trim().is_empty()).map(|l| l.split(',').nth(column).unwrap().parse().unwrap()).collect()
}

fn read(dir: &str, names: &[&str]) -> Vec<(String, GreyImage)> {
    names
        .iter()
        .map(|n| {
            let path = format!("{DATA}{dir}/{n}");
            (format!("{dir}/{n}"), image_file::read_grey(&path).unwrap_or_else(|e| panic!("{e}")))
        })
        .collect()
}

/// The 20 photographs of `data/apriltag/` in three sets (see each SOURCE.md). Known ids:
/// every tag of the NASA Swarmathon cubes is id 0; the others' ids are those of the derived
/// reference CSVs (AprilTag 3 on the same images; for swatbotics checked for consistency across
/// the sequence upstream) and fat_tags.png's 20–23.
pub fn photo_sets() -> Vec<PhotoSet> {
    let duckietown = read(
        "duckietown",
        &[
            "test_image.png",
            "test_image_multiple_01.png",
            "test_image_multiple_02.png",
            "test_image_multiple_03.png",
            "test_image_multiple_04.png",
            "test_image_multiple_05.png",
        ],
    );
    let mut duck_ids = csv_ids(&format!("{DATA}duckietown/detections_sample.csv"));
    duck_ids.extend(csv_ids(&format!("{DATA}duckietown/detections_multiple.csv")));
    let nasa = read(
        "nasa_swarmathon",
        &["33369213973_9d9bb4cc96_c.jpg", "34085369442_304b6bafd9_c.jpg", "34139872896_defdb2f8d9_c.jpg"],
    );
    let mut swat = read(
        "swatbotics",
        &[
            "hallway/IMG_0612.jpg",
            "hallway/IMG_0613.jpg",
            "hallway/IMG_0614.jpg",
            "hallway/IMG_0615.jpg",
            "hallway/IMG_0617.jpg",
            "clipboard/clipboard00.png",
            "clipboard/clipboard01.png",
            "clipboard/clipboard02.png",
            "clipboard/clipboard03.png",
            "clipboard/clipboard04.png",
        ],
    );
    swat.extend(read("swatbotics", &["fat_tags.png"]));
    let mut swat_ids = csv_ids(&format!("{DATA}swatbotics/detections_hallway_clipboard.csv"));
    swat_ids.extend(20..=23);
    vec![
        PhotoSet { name: "duckietown", images: duckietown, known_ids: duck_ids },
        PhotoSet { name: "nasa_swarmathon", images: nasa, known_ids: [0].into() },
        PhotoSet { name: "swatbotics", images: swat, known_ids: swat_ids },
    ]
}

/// The project venv's python (created by `scripts/test` from `scripts/requirements.txt`, which
/// pins the upstream C AprilTag 3.4.5 wheel).
pub fn venv_python() -> PathBuf {
    let python = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../.venv/bin/python");
    assert!(
        python.exists(),
        "{} is missing: run scripts/test (it creates the venv with the upstream AprilTag wheel) before this test",
        python.display()
    );
    python
}

/// A detection of the C library, in our pixel convention.
#[derive(Debug, Clone)]
pub struct RefDetection {
    pub id: u32,
    pub hamming: u32,
    pub decision_margin: f64,
    pub center: [f64; 2],
    pub corners: [[f64; 2]; 4],
}

/// The C library's result for one image.
#[derive(Debug, Clone)]
pub struct RefRecord {
    pub time_ms: f64,
    pub cpu_ms: f64,
    pub detections: Vec<RefDetection>,
}

fn pair(v: &serde_json::Value) -> [f64; 2] {
    [v[0].as_f64().unwrap(), v[1].as_f64().unwrap()]
}

/// Writes `images` as grey PNGs into `dir` (so that both detectors see the same pixels).
pub fn grey_copies(images: &[(String, GreyImage)], dir: &Path) -> Vec<PathBuf> {
    std::fs::create_dir_all(dir).unwrap();
    images
        .iter()
        .enumerate()
        .map(|(k, (_, image))| {
            let path = dir.join(format!("{k:03}.png"));
            image_file::write_grey_png(&path, image).unwrap();
            path
        })
        .collect()
}

/// Runs the upstream C detector (tag36h11, one thread, refine_edges, sharpening 0.25) on PNG
/// files, `runs` timed runs each.
pub fn run_reference(files: &[PathBuf], decimate: u32, max_hamming: u32, runs: usize) -> Vec<RefRecord> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/apriltag_reference.py");
    let output = Command::new(venv_python())
        .arg(&script)
        .args(["--decimate", &decimate.to_string(), "--max-hamming", &max_hamming.to_string()])
        .args(["--runs", &runs.to_string()])
        .args(files)
        .output()
        .unwrap();
    assert!(
        output.status.success(),
        "apriltag_reference.py failed ({}); if the apriltag module is missing run scripts/test:\n{}",
        output.status,
        String::from_utf8_lossy(&output.stderr)
    );
    let text = String::from_utf8(output.stdout).unwrap();
    let records: Vec<RefRecord> = text
        .lines()
        .map(|line| {
            let v: serde_json::Value = serde_json::from_str(line).unwrap();
            let detections = v["detections"]
                .as_array()
                .unwrap()
                .iter()
                .map(|d| RefDetection {
                    id: d["id"].as_u64().unwrap() as u32,
                    hamming: d["hamming"].as_u64().unwrap() as u32,
                    decision_margin: d["decision_margin"].as_f64().unwrap(),
                    center: pair(&d["center"]),
                    corners: [
                        pair(&d["corners"][0]),
                        pair(&d["corners"][1]),
                        pair(&d["corners"][2]),
                        pair(&d["corners"][3]),
                    ],
                })
                .collect();
            RefRecord { time_ms: v["time_ms"].as_f64().unwrap(), cpu_ms: v["cpu_ms"].as_f64().unwrap(), detections }
        })
        .collect();
    assert_eq!(records.len(), files.len());
    records
}

/// How our detections of one image compare with the C library's.
#[derive(Debug, Default, Clone)]
pub struct Comparison {
    /// C detections with one of ours within 2 px (centre), and those with another id.
    pub matched: usize,
    pub wrong_ids: Vec<(u32, u32)>,
    /// C detections we do not have (id, centre).
    pub missed: Vec<(u32, [f64; 2])>,
    /// Our detections C does not have (id, centre).
    pub extra: Vec<(u32, [f64; 2])>,
    /// Corner distances of matched detections with the same id.
    pub corner_diffs_px: Vec<f64>,
}

pub fn compare(ours: &[TagDetection], reference: &[RefDetection]) -> Comparison {
    let dist = |a: [f64; 2], b: [f64; 2]| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt();
    let mut c = Comparison::default();
    let mut used = vec![false; ours.len()];
    for r in reference {
        let nearest = ours
            .iter()
            .enumerate()
            .filter(|(k, _)| !used[*k])
            .map(|(k, t)| (k, dist(t.center_px, r.center)))
            .min_by(|a, b| a.1.total_cmp(&b.1));
        match nearest {
            Some((k, d)) if d < 2.0 => {
                used[k] = true;
                c.matched += 1;
                if ours[k].id == r.id {
                    c.corner_diffs_px.extend(ours[k].corners_px.iter().zip(&r.corners).map(|(a, b)| dist(*a, *b)));
                } else {
                    c.wrong_ids.push((ours[k].id, r.id));
                }
            }
            _ => c.missed.push((r.id, r.center)),
        }
    }
    c.extra = ours.iter().zip(&used).filter(|(_, u)| !**u).map(|(t, _)| (t.id, t.center_px)).collect();
    c
}

/// `q`-quantile of `values` (sorted in place), NaN when empty.
pub fn quantile(values: &mut [f64], q: f64) -> f64 {
    if values.is_empty() {
        return f64::NAN;
    }
    values.sort_by(f64::total_cmp);
    values[((values.len() - 1) as f64 * q).round() as usize]
}

/// A marker whose whole tag is inside the image and faces the camera.
#[derive(Debug, Clone, Copy)]
pub struct MarkerInView {
    pub id: u32,
    pub center_px: [f64; 2],
    /// Bottom-left, bottom-right, top-right, top-left of the black square.
    pub corners_px: [[f64; 2]; 4],
    /// Camera to marker centre.
    pub distance_m: f64,
    /// Angle between the marker's normal and the line to the camera.
    pub view_angle_rad: f64,
}

/// A rendered left image and the markers in it.
pub struct SimFrame {
    pub label: String,
    pub image: GreyImage,
    pub markers: Vec<MarkerInView>,
}

/// Renders simulated frames of a Moon world (seed `seed`, three rovers): `views` frames from
/// cameras placed around the rovers at 2.5–12 m, looking at their masts (markers in view), and
/// `terrain_views` frames looking away over the terrain (no rover in view: textured ground only).
pub fn sim_frames(seed: u64, views: usize, terrain_views: usize) -> Vec<SimFrame> {
    let options = ScenarioOptions {
        robots: 3,
        duration_s: 20.0,
        seed,
        downscale: 1,
        world_size_m: Some(60.0),
        flyer: false,
        rocks_per_100m2: None,
        rocks_in_hub: false,
    };
    let scenario = preset("moon", &options).unwrap();
    let world: Arc<World> = World::build(&scenario).unwrap();
    let camera = world.robots[0].model().camera;
    let mut renderer = Renderer::new(camera, scenario.sensor);
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let (mut left, mut right) = (vec![0u8; w * h], vec![0u8; w * h]);
    let mut quads = Vec::new();
    let mut state = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut rnd = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    };
    let mut frames = Vec::new();
    for k in 0..views + terrain_views {
        let stamp_ns = (rnd() * 19.0 * 1e9) as u64;
        let target = k % world.robots.len();
        let state = world.robot_state(target, stamp_ns).unwrap();
        let mast = state.t_world_body * Point3::new(0.2, 0.0, 0.8);
        let (distance, azimuth) = (2.5 + 9.5 * rnd(), std::f64::consts::TAU * rnd());
        let base = state.t_world_body.translation.z;
        let ground = |x: f64, y: f64| world.terrain.heightfield.height_at(x, y).unwrap_or(base);
        let (t_world_cam, label) = if k < views {
            let (x, y) = (mast.x + distance * azimuth.cos(), mast.y + distance * azimuth.sin());
            let eye = Vector3::new(x, y, ground(x, y) + 1.1);
            let to = mast.coords - eye;
            let yaw = to.y.atan2(to.x) + 0.15 * (rnd() - 0.5);
            let tilt = (-to.z).atan2((to.x * to.x + to.y * to.y).sqrt()) + 0.1 * (rnd() - 0.5);
            (
                sim::camera::t_world_cam_looking(&eye, yaw, tilt),
                format!("seed {seed} view {k}: rover {target} at {distance:.1} m"),
            )
        } else {
            // Over open terrain, away from every rover.
            let (x, y) = (mast.x + 3.0 * azimuth.cos(), mast.y + 3.0 * azimuth.sin());
            let eye = Vector3::new(x, y, ground(x, y) + 1.1);
            (sim::camera::t_world_cam_looking(&eye, azimuth, 0.25 + 0.2 * rnd()), format!("seed {seed} terrain {k}"))
        };
        quads.clear();
        world.quads_at(stamp_ns, None, &mut quads);
        let scene = world.scene(&quads);
        renderer.render_stereo(&scene, &t_world_cam, seed ^ (k as u64) << 20, &mut left, &mut right);
        let markers = markers_in_view(&world, stamp_ns, &t_world_cam, &camera);
        frames.push(SimFrame { label, image: GreyImage { width: w, height: h, data: left.clone() }, markers });
    }
    frames
}

/// Markers of every robot whose four corners project inside the image, in front of a camera
/// they face.
pub fn markers_in_view(
    world: &World,
    stamp_ns: u64,
    t_world_cam: &Isometry3<f64>,
    camera: &sim::camera::StereoCamera,
) -> Vec<MarkerInView> {
    let mut out = Vec::new();
    let t_cam_world = t_world_cam.inverse();
    for robot in 0..world.robots.len() {
        for (id, t_world_marker) in world.marker_poses_world(robot, stamp_ns) {
            let half = 0.5 * sim::robot::MARKER_SIZE_M;
            let to_cam = t_world_cam.translation.vector - t_world_marker.translation.vector;
            if to_cam.dot(&(t_world_marker.rotation * Vector3::z())) <= 0.0 {
                continue;
            }
            let project = |x: f64, y: f64| {
                let p = t_cam_world * (t_world_marker * Point3::new(x, y, 0.0));
                camera.project(&p.coords).map(|(u, v)| [u, v])
            };
            let corners = [project(-half, -half), project(half, -half), project(half, half), project(-half, half)];
            let inside = |c: &Option<[f64; 2]>| {
                c.is_some_and(|[u, v]| {
                    u >= 0.0
                        && v >= 0.0
                        && u <= f64::from(camera.width_px) - 1.0
                        && v <= f64::from(camera.height_px) - 1.0
                })
            };
            if corners.iter().all(inside)
                && let (Some(c), [Some(a), Some(b), Some(cc), Some(d)]) = (project(0.0, 0.0), corners)
            {
                let distance_m = to_cam.norm();
                let cos_view = to_cam.dot(&(t_world_marker.rotation * Vector3::z())) / distance_m;
                out.push(MarkerInView {
                    id,
                    center_px: c,
                    corners_px: [a, b, cc, d],
                    distance_m,
                    view_angle_rad: cos_view.clamp(-1.0, 1.0).acos(),
                });
            }
        }
    }
    out
}
