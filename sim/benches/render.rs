//! Rendering speed of a 1024×508 stereo pair against the 100 ms frame period of a 10 Hz camera.
//!
//! `cargo bench -p sim --bench render`: full-size (200 m) Moon and Mars sites, the narrow and the
//! wide camera, several rover and flyer poses; one thread (the renderer never spawns any). Each
//! pose is rendered once untimed (the first frame on a terrain also builds the level-of-detail
//! tables, timed separately), then `RUNS` times.

use std::time::Instant;

use nalgebra::{Isometry3, Vector3};
use sim::camera::{StereoCamera, t_world_cam_looking};
use sim::lighting::{Reflectance, ShadowMap, Sun};
use sim::render::{LodConfig, Renderer, Scene, SensorModel};
use sim::terrain::{Terrain, TerrainConfig};

const RUNS: usize = 9;
const FRAME_BUDGET_MS: f64 = 100.0;

struct Preset {
    name: &'static str,
    config: TerrainConfig,
    sun: Sun,
    reflectance: Reflectance,
    sky_radiance: f32,
}

/// (name, x, y, height above ground, yaw, tilt down), all in metres and radians.
const POSES: [(&str, f64, f64, f64, f64, f64); 7] = [
    ("rover, driving tilt", 0.0, 0.0, 1.4, 0.0, 0.25),
    ("rover, driving tilt", 30.0, -20.0, 1.4, 1.2, 0.25),
    ("rover, horizon", -50.0, 40.0, 1.4, -2.0, 0.0),
    ("rover, horizon", 10.0, 60.0, 1.4, 2.8, 0.0),
    ("rover, slightly down", -70.0, -70.0, 1.4, 0.8, 0.1),
    ("rover, close look", 60.0, 10.0, 1.4, -0.7, 0.6),
    ("flyer, 4 m, 45° down", -20.0, -30.0, 4.0, 0.4, 0.785),
];

fn pose(terrain: &Terrain, x: f64, y: f64, height_m: f64, yaw: f64, tilt: f64) -> Isometry3<f64> {
    let hf = &terrain.heightfield;
    let c = ((x - hf.origin_m[0]) / hf.resolution_m).round() as isize;
    let r = ((y - hf.origin_m[1]) / hf.resolution_m).round() as isize;
    let ground = f64::from(hf.height_at_cell(c, r));
    t_world_cam_looking(&Vector3::new(x, y, ground + height_m), yaw, tilt)
}

fn ms(since: Instant) -> f64 {
    since.elapsed().as_secs_f64() * 1e3
}

/// CPU time this thread has used, in ms (Linux reports it in 10 ms ticks): unlike wall time it
/// does not grow when other processes share the cores.
fn thread_cpu_ms() -> f64 {
    let stat = std::fs::read_to_string("/proc/thread-self/stat").unwrap_or_default();
    // Fields after the command name (which is in parentheses): utime and stime are the 12th and
    // 13th of them.
    let rest = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
    let ticks: f64 = rest.split_whitespace().skip(11).take(2).filter_map(|t| t.parse::<f64>().ok()).sum();
    ticks * 10.0
}

/// Estimated time per pair spent in `Terrain::albedo_filtered` (the terrain's texture, called
/// once per terrain pixel of each image): the call timed on a sample of this frame's own ground
/// points and footprints (`z / f`), scaled to the frame's terrain pixels in both images.
fn albedo_share_ms(terrain: &Terrain, camera: &StereoCamera, t_world_cam: &Isometry3<f64>, depth_m: &[f32]) -> f64 {
    let w = camera.width_px as usize;
    let ground = depth_m.iter().filter(|z| z.is_finite()).count();
    if ground == 0 {
        return 0.0;
    }
    // Whole rows (about 20 000 points), so that neighbouring points come together as in a frame.
    let row_step = (ground / 20_000).max(1);
    let (mut xs, mut ys, mut footprints) = (Vec::new(), Vec::new(), Vec::new());
    for v in (0..depth_m.len() / w).step_by(row_step) {
        for u in 0..w {
            let z = f64::from(depth_m[v * w + u]);
            if !z.is_finite() {
                continue;
            }
            let p = t_world_cam * nalgebra::Point3::from(camera.ray(u as f64, v as f64) * z);
            xs.push(p.x);
            ys.push(p.y);
            footprints.push((z / camera.f_px) as f32);
        }
    }
    // In runs of neighbouring points, as the renderer calls it (a row's ground pixels).
    let mut out = vec![0.0f32; xs.len()];
    let start = Instant::now();
    let mut sum = 0.0;
    for _ in 0..5 {
        terrain.albedo_filtered_many(&xs, &ys, &footprints, &mut out);
        sum += out.iter().sum::<f32>();
    }
    let per_call_ms = ms(start) / (5 * xs.len()) as f64;
    std::hint::black_box(sum);
    per_call_ms * 2.0 * ground as f64
}

fn main() {
    let presets = [
        Preset {
            name: "moon",
            config: TerrainConfig::moon(),
            sun: Sun { azimuth_rad: 150f64.to_radians(), elevation_rad: 20f64.to_radians(), irradiance: 1.0 },
            reflectance: Reflectance::LunarLambert { l: 0.9 },
            sky_radiance: 0.0,
        },
        Preset {
            name: "mars",
            config: TerrainConfig::mars(),
            sun: Sun { azimuth_rad: 210f64.to_radians(), elevation_rad: 42f64.to_radians(), irradiance: 0.6 },
            reflectance: Reflectance::LunarLambert { l: 0.3 },
            sky_radiance: 0.05,
        },
    ];
    // Optional, for quick runs: `RENDER_BENCH=moon,narrow` keeps the matching presets and cameras,
    // `RENDER_BENCH_SIZE_M=60` shrinks the site, `RENDER_BENCH_POSE=3` keeps one pose,
    // `RENDER_BENCH_LOD_PX=0.5` sets `LodConfig::max_error_px`.
    let filter = std::env::var("RENDER_BENCH").unwrap_or_default();
    let keep = |name: &str, all: &[&str]| !all.iter().any(|a| filter.contains(a)) || filter.contains(name);
    let pose_filter: Option<usize> = std::env::var("RENDER_BENCH_POSE").ok().and_then(|s| s.parse().ok());
    let lod_px: Option<f64> = std::env::var("RENDER_BENCH_LOD_PX").ok().and_then(|s| s.parse().ok());
    let size_m: Option<f64> = std::env::var("RENDER_BENCH_SIZE_M").ok().and_then(|s| s.parse().ok());
    let mut sites = Vec::new();
    for preset in presets.iter().filter(|p| keep(p.name, &["moon", "mars"])) {
        let config = size_m.map_or_else(|| preset.config.clone(), |s| preset.config.clone().with_size(s));
        let start = Instant::now();
        let terrain = Terrain::generate(&config, 1);
        let generate_ms = ms(start);
        let start = Instant::now();
        let shadows = ShadowMap::compute(&terrain.heightfield, &preset.sun);
        let shadows_ms = ms(start);
        println!(
            "{}: {} × {} cells; Terrain::generate {generate_ms:.0} ms (albedo base {:.0} MB), ShadowMap::compute \
             {shadows_ms:.0} ms (all cores, not part of a frame)",
            preset.name,
            terrain.heightfield.cols,
            terrain.heightfield.rows,
            terrain.albedo_base.memory_bytes() as f64 / 1e6
        );
        sites.push((preset, terrain, shadows));
    }
    // Every pose of every site and camera, each with the renderer of its site and camera.
    struct Case {
        site: usize,
        camera_name: &'static str,
        camera: StereoCamera,
        renderer: usize,
        pose: usize,
        t_world_cam: Isometry3<f64>,
        first_ms: f64,
        times_ms: Vec<f64>,
        cpu_ms: f64,
    }
    let mut renderers = Vec::new();
    let mut cases = Vec::new();
    for (site, (_, terrain, _)) in sites.iter().enumerate() {
        let cameras = [("narrow", StereoCamera::narrow()), ("wide", StereoCamera::wide())];
        for (camera_name, camera) in cameras.into_iter().filter(|c| keep(c.0, &["narrow", "wide"])) {
            let mut renderer = Renderer::new(camera, SensorModel::default());
            if let Some(max_error_px) = lod_px {
                renderer.set_lod_config(LodConfig { max_error_px, ..LodConfig::default() });
            }
            renderers.push(renderer);
            for (k, &(_, x, y, height, yaw, tilt)) in POSES.iter().enumerate() {
                if pose_filter.is_none_or(|p| p == k) {
                    let t_world_cam = pose(terrain, x, y, height, yaw, tilt);
                    let renderer = renderers.len() - 1;
                    cases.push(Case {
                        site,
                        camera_name,
                        camera,
                        renderer,
                        pose: k,
                        t_world_cam,
                        first_ms: 0.0,
                        times_ms: Vec::new(),
                        cpu_ms: 0.0,
                    });
                }
            }
        }
    }
    let scene = |site: usize| {
        let (preset, terrain, shadows) = &sites[site];
        Scene {
            terrain,
            shadows,
            sun: preset.sun,
            reflectance: preset.reflectance,
            sky_radiance: preset.sky_radiance,
            quads: &[],
        }
    };
    let n = StereoCamera::narrow().pixels().max(StereoCamera::wide().pixels());
    let (mut left, mut right) = (vec![0u8; n], vec![0u8; n]);
    // Rounds over all cases rather than the runs of one case in a row, so that a few seconds of
    // other load on the host spoil one run of many cases, which the medians ignore. In a round a
    // case is rendered twice and the second pair timed: as in a camera's stream of frames, the
    // terrain around the pose is in the caches (not what the previous case left there).
    for round in 0..=RUNS {
        for case in &mut cases {
            let renderer = &mut renderers[case.renderer];
            let pixels = case.camera.pixels();
            let (left, right) = (&mut left[..pixels], &mut right[..pixels]);
            let start = Instant::now();
            renderer.render_stereo(&scene(case.site), &case.t_world_cam, 2 * round as u64, left, right);
            if round == 0 {
                // The first frame of a pose also builds level-of-detail tables.
                case.first_ms = ms(start);
                continue;
            }
            let (start, cpu_start) = (Instant::now(), thread_cpu_ms());
            renderer.render_stereo(&scene(case.site), &case.t_world_cam, 2 * round as u64 + 1, left, right);
            case.times_ms.push(ms(start));
            case.cpu_ms += (thread_cpu_ms() - cpu_start) / RUNS as f64;
        }
    }
    let (mut overall, mut medians, mut cpu_times, mut own_times) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    for case in &mut cases {
        let (preset, terrain, _) = &sites[case.site];
        let renderer = &mut renderers[case.renderer];
        // Once more, for the statistics and the depth of this pose.
        let pixels = case.camera.pixels();
        renderer.render_stereo(&scene(case.site), &case.t_world_cam, 0, &mut left[..pixels], &mut right[..pixels]);
        let times = &mut case.times_ms;
        times.sort_by(f64::total_cmp);
        // The median of a pose's runs: its cost, not a moment when the host was busy.
        let (median, max) = (times[RUNS / 2], times[RUNS - 1]);
        let stats = renderer.stats();
        let sky = renderer.depth_m().iter().filter(|z| z.is_infinite()).count() as f64 / pixels as f64;
        let albedo = albedo_share_ms(terrain, &case.camera, &case.t_world_cam, renderer.depth_m());
        println!(
            "  {:<5} {:<6} pose {} ({:<20}): median {median:5.1} ms ({:.2} of the budget; albedo_filtered \
             ~{albedo:4.1} ms of it), max {max:5.1} ms, cpu mean {:5.1} ms; first frame {:5.1} ms; {} triangles, \
             chunks per level {:?}, sky {sky:.2}",
            preset.name,
            case.camera_name,
            case.pose,
            POSES[case.pose].0,
            median / FRAME_BUDGET_MS,
            case.cpu_ms,
            case.first_ms,
            stats.terrain_triangles,
            stats.chunks_per_level,
        );
        overall.extend_from_slice(times);
        medians.push(median);
        cpu_times.push(case.cpu_ms);
        own_times.push(median - albedo);
    }
    overall.sort_by(f64::total_cmp);
    let sorted = |mut v: Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v
    };
    let (medians, cpu_times, own_times) = (sorted(medians), sorted(cpu_times), sorted(own_times));
    let mid_max = |v: &[f64]| (v[v.len() / 2], v[v.len() - 1]);
    let (median, worst) = mid_max(&medians);
    let (cpu_median, cpu_worst) = mid_max(&cpu_times);
    let (own_median, own_worst) = mid_max(&own_times);
    println!(
        "{} poses × {RUNS} pairs, one thread; per pose the median of its runs: median over poses {median:.1} ms, \
         worst pose {worst:.1} ms = {:.2} / {:.2} of the {FRAME_BUDGET_MS:.0} ms frame budget; slowest single pair \
         {:.1} ms (wall). CPU time per pair (mean of a pose's runs, 10 ms ticks): median {cpu_median:.1} ms, worst \
         pose {cpu_worst:.1} ms",
        medians.len(),
        median / FRAME_BUDGET_MS,
        worst / FRAME_BUDGET_MS,
        overall[overall.len() - 1],
    );
    println!(
        "without Terrain::albedo_filtered (estimated per pose as above): median {own_median:.1} ms, worst pose \
         {own_worst:.1} ms per pair"
    );
}
