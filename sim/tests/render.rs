#![allow(clippy::unwrap_used, clippy::expect_used)]
//! The stereo renderer against exact ray casting, analytic geometry, the FPGA's SGM matcher and
//! the thesis's stereo error model.

use std::sync::OnceLock;

use fpga_model::SgmConfig;
use fpga_model::fast::Matcher;
use fpga_model::image::GrayImage;
use nalgebra::{Isometry3, Point3, Rotation3, Translation3, UnitQuaternion, Vector3};
use sim::camera::{StereoCamera, t_world_cam_looking};
use sim::lighting::{Reflectance, ShadowMap, Sun};
use sim::markers::{TAG_CELLS, TAG36H11_CODES, tag_cells};
use sim::render::{Quad, QuadSurface, Renderer, Scene, SensorModel, raycast_depth_m};
use sim::terrain::{Heightfield, Terrain, TerrainConfig};

/// The Moon preset's light (scenario `moon`): low sun, lunar-Lambert regolith, black sky.
fn moon_sun() -> Sun {
    Sun { azimuth_rad: 150f64.to_radians(), elevation_rad: 20f64.to_radians(), irradiance: 1.0 }
}

struct Site {
    terrain: Terrain,
    shadows: ShadowMap,
}

impl Site {
    fn scene<'a>(&'a self, quads: &'a [Quad], reflectance: Reflectance) -> Scene<'a> {
        Scene { terrain: &self.terrain, shadows: &self.shadows, sun: moon_sun(), reflectance, sky_radiance: 0.0, quads }
    }
}

/// A generated 60 m Moon site, shared by the tests (generation is the slow part).
fn moon_site() -> &'static Site {
    static SITE: OnceLock<Site> = OnceLock::new();
    SITE.get_or_init(|| {
        let terrain = Terrain::generate(&TerrainConfig::moon().with_size(60.0), 7);
        let shadows = ShadowMap::compute(&terrain.heightfield, &moon_sun());
        Site { terrain, shadows }
    })
}

/// A terrain whose heights are `height(x, y)`, textured like the Moon preset.
fn synthetic_site(edge_m: f64, height: impl Fn(f64, f64) -> f64) -> Site {
    let config = TerrainConfig::moon().with_size(edge_m);
    let cells = (edge_m / config.resolution_m).round() as usize + 1;
    let origin_m = [-0.5 * edge_m, -0.5 * edge_m];
    let mut heights_m = Vec::with_capacity(cells * cells);
    for r in 0..cells {
        for c in 0..cells {
            let (x, y) = (origin_m[0] + c as f64 * config.resolution_m, origin_m[1] + r as f64 * config.resolution_m);
            heights_m.push(height(x, y) as f32);
        }
    }
    let heightfield = Heightfield { resolution_m: config.resolution_m, origin_m, cols: cells, rows: cells, heights_m };
    let shadows = ShadowMap::compute(&heightfield, &moon_sun());
    let terrain = Terrain {
        config,
        seed: 11,
        heightfield,
        material: vec![0; cells * cells],
        rocks: Vec::new(),
        craters: Vec::new(),
        ditches: Vec::new(),
        albedo_base: Default::default(),
    };
    Site { terrain, shadows }
}

/// Left camera at `(x, y)`, `height_m` above the mesh vertex there, looking along `yaw`, tilted
/// down by `tilt` (the pan-tilt head's convention).
fn rover_camera(terrain: &Terrain, x: f64, y: f64, height_m: f64, yaw: f64, tilt: f64) -> Isometry3<f64> {
    let hf = &terrain.heightfield;
    let c = ((x - hf.origin_m[0]) / hf.resolution_m).round() as isize;
    let r = ((y - hf.origin_m[1]) / hf.resolution_m).round() as isize;
    let ground = f64::from(hf.height_at_cell(c, r));
    t_world_cam_looking(&Vector3::new(x, y, ground + height_m), yaw, tilt)
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return f64::NAN;
    }
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn sorted(mut v: Vec<f64>) -> Vec<f64> {
    v.sort_by(f64::total_cmp);
    v
}

/// Compares rendered and ray-cast depth on every `step`-th pixel, in depth bins.
struct DepthComparison {
    /// (bin upper edge, relative errors)
    bins: Vec<(f64, Vec<f64>)>,
    mismatched_sky: usize,
    compared: usize,
}

fn compare_depth(
    site: &Site,
    camera: &StereoCamera,
    pose: &Isometry3<f64>,
    step: usize,
    edges: &[f64],
) -> DepthComparison {
    let mut renderer = Renderer::new(*camera, SensorModel::default());
    let scene = site.scene(&[], Reflectance::Lambert);
    let depth = renderer.render_depth(&scene, pose).to_vec();
    let mut bins: Vec<(f64, Vec<f64>)> = edges.iter().map(|&e| (e, Vec::new())).collect();
    let (mut mismatched_sky, mut compared) = (0, 0);
    let w = camera.width_px as usize;
    for v in (0..camera.height_px as usize).step_by(step) {
        for u in (0..w).step_by(step) {
            let rendered = f64::from(depth[v * w + u]);
            let exact = raycast_depth_m(&site.terrain, camera, pose, u as f64, v as f64);
            compared += 1;
            match exact {
                Some(z) if rendered.is_finite() => {
                    let rel = (rendered - z).abs() / z;
                    if let Some(bin) = bins.iter_mut().find(|(edge, _)| z < *edge) {
                        bin.1.push(rel);
                    }
                }
                None if rendered.is_infinite() => {}
                _ => mismatched_sky += 1,
            }
        }
    }
    DepthComparison { bins, mismatched_sky, compared }
}

fn report(name: &str, cmp: &DepthComparison) -> Vec<f64> {
    let mut all = Vec::new();
    let mut lower = 0.0;
    for (edge, errors) in &cmp.bins {
        let s = sorted(errors.clone());
        let within = s.iter().filter(|&&e| e <= 0.01).count() as f64 / s.len().max(1) as f64;
        println!(
            "{name}: z in [{lower:>4.0}, {edge:>4.0}) m: {:>6} px, relative error median {:.2e}, p95 {:.2e}, \
             within 1 % {:.4}",
            s.len(),
            quantile(&s, 0.5),
            quantile(&s, 0.95),
            within
        );
        all.extend_from_slice(errors);
        lower = *edge;
    }
    println!("{name}: {} compared, {} hit/sky mismatches", cmp.compared, cmp.mismatched_sky);
    sorted(all)
}

#[test]
fn rendered_depth_matches_ray_casting_near_and_far() {
    let site = moon_site();
    let camera = StereoCamera::narrow();
    // A rover's head, 1.4 m above the ground, looking down 17°: ground from 2.4 m to ~21 m.
    let pose = rover_camera(&site.terrain, -22.0, -3.0, 1.4, 0.1, 17f64.to_radians());
    let cmp = compare_depth(site, &camera, &pose, 3, &[5.0, 10.0, 20.0, 1e9]);
    let all = report("down 17°", &cmp);
    let within = all.iter().filter(|&&e| e <= 0.01).count() as f64 / all.len() as f64;
    // Within 6 m the mesh is the terrain mesh itself: the only differences are f32 depth
    // storage and vertex snapping to 1/256 px, both far below 1e-4; pixels straddling an
    // occluding edge may see the other surface, a small share.
    let near = sorted(cmp.bins[0].1.clone());
    assert!(near.len() > 5_000, "{} near samples", near.len());
    assert!(quantile(&near, 0.5) < 1e-5, "near median {}", quantile(&near, 0.5));
    assert!(quantile(&near, 0.95) < 1e-4, "near p95 {}", quantile(&near, 0.95));
    assert!(quantile(&all, 0.5) < 1e-4, "median {}", quantile(&all, 0.5));
    assert!(within > 0.99, "within 1 %: {within}");
    assert!(cmp.mismatched_sky as f64 <= 1e-3 * cmp.compared as f64, "{} sky mismatches", cmp.mismatched_sky);

    // Looking at the horizon across the site: beyond 6 m the level of detail coarsens with
    // distance. Its error is bounded by `max_error_px` on screen (1 px), i.e. a relative depth
    // error of about 1 / (f · sin α) at a grazing angle α: 5 % where the ground is seen at 1°.
    let pose = rover_camera(&site.terrain, -28.0, 0.0, 1.4, 0.0, 0.0);
    let cmp = compare_depth(site, &camera, &pose, 4, &[5.0, 10.0, 20.0, 40.0, 1e9]);
    let all = report("horizon", &cmp);
    let within = all.iter().filter(|&&e| e <= 0.01).count() as f64 / all.len() as f64;
    assert!(quantile(&all, 0.5) < 1e-3, "median {}", quantile(&all, 0.5));
    assert!(within > 0.95, "within 1 %: {within}");
}

#[test]
fn a_plane_is_rendered_at_its_analytic_depth() {
    // z = 0.3 + 0.02 x − 0.01 y: every level of detail represents it exactly, so the coarse
    // chunks far away must be as right as the near ones.
    let (a, b, c) = (0.02, -0.01, 0.3);
    let site = synthetic_site(40.0, |x, y| c + a * x + b * y);
    let camera = StereoCamera::narrow();
    let half = 20.0;
    for (name, pose) in [
        ("down 25°", rover_camera(&site.terrain, -15.0, 2.0, 1.5, 0.3, 25f64.to_radians())),
        ("horizon", rover_camera(&site.terrain, -15.0, 2.0, 1.5, 0.3, 0.0)),
    ] {
        let mut renderer = Renderer::new(camera, SensorModel::default());
        let depth = renderer.render_depth(&site.scene(&[], Reflectance::Lambert), &pose).to_vec();
        let o = pose.translation.vector;
        // Analytic 1/z of the plane through pixel (u, v), or 0 where the ray misses the grid.
        let inv_z = |u: f64, v: f64| {
            let dir = pose.rotation * camera.ray(u, v);
            let t = (c + a * o.x + b * o.y - o.z) / (dir.z - a * dir.x - b * dir.y);
            let p = o + dir * t;
            if t > 0.0 && p.x.abs() <= half && p.y.abs() <= half { 1.0 / t } else { 0.0 }
        };
        let w = camera.width_px as usize;
        let (mut checked, mut worst) = (0, 0.0_f64);
        for v in 0..camera.height_px as usize {
            for u in 0..w {
                let (uf, vf) = (u as f64, v as f64);
                let centre = inv_z(uf, vf);
                let around = [inv_z(uf - 1.0, vf), inv_z(uf + 1.0, vf), inv_z(uf, vf - 1.0), inv_z(uf, vf + 1.0)];
                // Pixels next to the grid's edge or the horizon are left out: sub-pixel snapping
                // may move that edge by up to 1/512 px.
                if around.iter().any(|&n| (n == 0.0) != (centre == 0.0)) {
                    continue;
                }
                let rendered = depth[v * w + u];
                // The ray caster, the other tests' ground truth, hits the plane exactly (up to the
                // f32 heights, 1e-7 m).
                if (u * 7 + v * 13) % 97 == 0 {
                    let cast = raycast_depth_m(&site.terrain, &camera, &pose, uf, vf);
                    match cast {
                        Some(z) => assert!((z * centre - 1.0).abs() < 1e-6, "{name}: ray cast {z} vs {}", 1.0 / centre),
                        None => assert_eq!(centre, 0.0, "{name}: ray cast missed at ({u}, {v})"),
                    }
                }
                if centre == 0.0 {
                    assert!(rendered.is_infinite(), "{name}: ({u}, {v}) should be sky, got {rendered}");
                    continue;
                }
                // Vertices are snapped to 1/256 px, which moves the interpolated 1/z by at most
                // √2/512 px times its gradient; plus f32 storage and f32 heights (1e-6).
                let gradient = around.iter().map(|n| (n - centre).abs()).fold(0.0, f64::max);
                let tolerance = 1e-6 * centre + std::f64::consts::SQRT_2 / 512.0 * gradient;
                let err = (1.0 / f64::from(rendered) - centre).abs();
                assert!(
                    err <= tolerance,
                    "{name}: ({u}, {v}) 1/z {} vs {centre} (tolerance {tolerance})",
                    1.0 / rendered
                );
                worst = worst.max(err / centre);
                checked += 1;
            }
        }
        println!(
            "{name}: {checked} pixels checked, worst relative depth error {worst:.2e}, lod {:?}",
            renderer.stats()
        );
        assert!(checked > 200_000, "{name}: only {checked} pixels checked");
    }
}

#[test]
fn the_terrain_mesh_is_watertight() {
    // A hole is a sky pixel with terrain on all four sides: with exact edge functions and skirts
    // between levels of detail there must be none.
    let site = moon_site();
    for camera in [StereoCamera::narrow(), StereoCamera::wide()] {
        let mut renderer = Renderer::new(camera, SensorModel::default());
        for (x, yaw, tilt) in [(-28.0, 0.0, 0.0), (-28.0, 0.4, 0.08), (0.0, 2.0, 0.25)] {
            let pose = rover_camera(&site.terrain, x, 1.0, 1.4, yaw, tilt);
            let depth = renderer.render_depth(&site.scene(&[], Reflectance::Lambert), &pose).to_vec();
            let w = camera.width_px as usize;
            let mut holes = 0;
            for v in 1..camera.height_px as usize - 1 {
                for u in 1..w - 1 {
                    let i = v * w + u;
                    if depth[i].is_infinite() && [i - 1, i + 1, i - w, i + w].iter().all(|&n| depth[n].is_finite()) {
                        holes += 1;
                    }
                }
            }
            assert_eq!(holes, 0, "holes at x {x} yaw {yaw} tilt {tilt}: {:?}", renderer.stats());
        }
    }
}

/// Stereo error model of the thesis (eq. 5.2c): depth error of a point at depth `z`.
fn model_depth_error_m(camera: &StereoCamera, z: f64) -> f64 {
    const PIXEL_ERROR_PX: f64 = 0.5;
    PIXEL_ERROR_PX * z * z / (camera.f_px * camera.baseline_m) * std::f64::consts::SQRT_2
}

#[test]
fn sgm_on_a_rendered_pair_has_the_thesis_stereo_error() {
    let site = moon_site();
    let camera = StereoCamera::narrow();
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let pose = rover_camera(&site.terrain, -22.0, 4.0, 1.4, -0.2, 17f64.to_radians());
    let mut renderer = Renderer::new(camera, SensorModel::default());
    let (mut left, mut right) = (vec![0; w * h], vec![0; w * h]);
    let scene = site.scene(&[], Reflectance::LunarLambert { l: 0.9 });
    renderer.render_stereo(&scene, &pose, 5, &mut left, &mut right);
    let depth = renderer.depth_m().to_vec();
    let mean = left.iter().map(|&v| f64::from(v)).sum::<f64>() / left.len() as f64;
    println!("left mean {mean:.1} DN, gain {:.1}", renderer.stats().exposure_gain);

    let config = SgmConfig::default();
    let mut matcher = Matcher::new(config, w, h, 1).unwrap();
    let disparity =
        matcher.compute(&GrayImage::new(w, h, left).unwrap(), &GrayImage::new(w, h, right).unwrap()).unwrap();

    println!("SGM invalid share over the whole image: {:.4}", disparity.invalid_fraction());
    let fb = camera.f_px * camera.baseline_m;
    let edges = [3.0, 4.0, 6.0, 8.0, 12.0, 20.0];
    let mut bins: Vec<Vec<(f64, f64)>> = vec![Vec::new(); edges.len()];
    let mut disparity_errors = Vec::new();
    let (mut seen, mut valid) = (0, 0);
    // The census window and the disparity range leave a margin without matches.
    for v in 4..h - 4 {
        for u in (config.disparities as usize)..w - 5 {
            let z = f64::from(depth[v * w + u]);
            if !z.is_finite() || z > edges[edges.len() - 1] {
                continue;
            }
            seen += 1;
            let Some(d) = disparity.get_px(u, v) else { continue };
            valid += 1;
            let d = f64::from(d);
            disparity_errors.push(d - fb / z);
            if let Some(bin) = edges.iter().position(|&e| z < e) {
                bins[bin].push((z, if d > 0.0 { (fb / d - z).abs() } else { f64::INFINITY }));
            }
        }
    }
    let abs = sorted(disparity_errors.iter().map(|e| e.abs()).collect());
    let signed = sorted(disparity_errors.clone());
    let over_1px = abs.iter().filter(|&&e| e > 1.0).count() as f64 / abs.len() as f64;
    let valid_share = valid as f64 / seen as f64;
    println!(
        "disparity error: {valid} valid of {seen} ({valid_share:.3}); median {:+.3} px, |e| median {:.3}, p90 {:.3}, \
         p95 {:.3} px; > 1 px: {:.4}",
        quantile(&signed, 0.5),
        quantile(&abs, 0.5),
        quantile(&abs, 0.9),
        quantile(&abs, 0.95),
        over_1px
    );
    let mut lower = 0.0;
    for (bin, &edge) in bins.iter().zip(&edges) {
        let z_med = quantile(&sorted(bin.iter().map(|p| p.0).collect()), 0.5);
        let err = sorted(bin.iter().map(|p| p.1).collect());
        let model = model_depth_error_m(&camera, z_med);
        println!(
            "z in [{lower:>4.1}, {edge:>4.1}) m: {:>6} px, median |Δz| {:.4} m, p90 {:.4} m; model (eq. 5.2c) at \
             {z_med:.2} m: {model:.4} m",
            bin.len(),
            quantile(&err, 0.5),
            quantile(&err, 0.9)
        );
        if bin.len() >= 1_000 {
            assert!(quantile(&err, 0.5) < model, "bin below {edge} m: median {} vs model {model}", quantile(&err, 0.5));
        }
        lower = edge;
    }
    // Textured, lit regolith should match almost everywhere the ground is seen by both cameras.
    assert!(valid_share > 0.8, "only {valid_share} of the ground has a disparity");
    // The model's Δp = 0.5 px per image coordinate is a disparity error of σ = 0.71 px, of which
    // 16 % would exceed 1 px; the rendered pair must not be worse than that.
    assert!(over_1px < 0.16, "{over_1px} of valid pixels off by more than 1 px");
    // No systematic bias (the rendered geometry and the matcher agree on the pair's geometry).
    assert!(quantile(&signed, 0.5).abs() < 0.1, "median disparity error {}", quantile(&signed, 0.5));
}

/// A square tag of edge `edge_m` (white border included) centred at `centre`, facing along
/// `normal`, its top towards `up` (projected onto the tag's plane).
fn tag_quad(code: u64, centre: Point3<f64>, normal: Vector3<f64>, up: Vector3<f64>, edge_m: f64) -> Quad {
    let z = normal.normalize();
    let y = (up - z * up.dot(&z)).normalize();
    let x = y.cross(&z);
    let h = 0.5 * edge_m;
    Quad {
        corners_world_m: [centre + (-x + y) * h, centre + (x + y) * h, centre + (x - y) * h, centre + (-x - y) * h],
        surface: QuadSurface::Tag { code },
    }
}

#[test]
fn a_tag_in_front_of_the_camera_is_readable() {
    let site = synthetic_site(20.0, |_, _| 0.0);
    let camera = StereoCamera::narrow();
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let pose = rover_camera(&site.terrain, -5.0, 0.0, 1.4, 0.0, 5f64.to_radians());
    let eye = pose.translation.vector;
    let mut renderer = Renderer::new(camera, SensorModel::default());
    let (mut left, mut right) = (vec![0; w * h], vec![0; w * h]);
    for (k, (yaw_deg, roll_deg)) in [(0.0_f64, 0.0_f64), (40.0, 20.0), (-55.0, -35.0)].into_iter().enumerate() {
        let code = TAG36H11_CODES[7 + k];
        // 2.5 m ahead, facing back at the camera, turned by `yaw` about the vertical and rolled
        // in its plane: the oblique views check that cells are mapped perspective-correctly.
        let centre = Point3::from(eye + Vector3::new(2.5, 0.0, -0.25));
        let yaw = Rotation3::from_axis_angle(&Vector3::z_axis(), yaw_deg.to_radians());
        let normal = yaw * Vector3::new(-1.0, 0.0, 0.0);
        let up =
            Rotation3::from_axis_angle(&nalgebra::Unit::new_normalize(normal), roll_deg.to_radians()) * Vector3::z();
        let quad = tag_quad(code, centre, normal, up, 0.4);
        let quads = [quad];
        let scene = Scene {
            sun: Sun { azimuth_rad: 3.0, elevation_rad: 0.6, irradiance: 1.0 },
            ..site.scene(&quads, Reflectance::Lambert)
        };
        renderer.render_stereo(&scene, &pose, 100 + k as u64, &mut left, &mut right);
        let c = &quad.corners_world_m;
        let mut samples = [[0u8; TAG_CELLS]; TAG_CELLS];
        for (row, line) in samples.iter_mut().enumerate() {
            for (col, value) in line.iter_mut().enumerate() {
                let (a, b) = ((col as f64 + 0.5) / TAG_CELLS as f64, (row as f64 + 0.5) / TAG_CELLS as f64);
                let p = c[0] + (c[1] - c[0]) * a + (c[3] - c[0]) * b;
                let (u, v) = camera.project(&(pose.inverse() * p).coords).unwrap();
                *value = left[v.round() as usize * w + u.round() as usize];
            }
        }
        let (lo, hi) = samples.iter().flatten().fold((255, 0), |(lo, hi), &s| (lo.min(s), hi.max(s)));
        let threshold = (u16::from(lo) + u16::from(hi)) / 2;
        let read: Vec<Vec<bool>> =
            samples.iter().map(|line| line.iter().map(|&s| u16::from(s) > threshold).collect()).collect();
        let expected: Vec<Vec<bool>> = tag_cells(code).iter().map(|l| l.to_vec()).collect();
        println!("tag {k}: black {lo} DN, white {hi} DN");
        assert!(hi > lo + 60, "tag {k}: contrast {lo}..{hi}");
        assert_eq!(read, expected, "tag {k} (yaw {yaw_deg}°, roll {roll_deg}°)");

        // The tag's depth is the ray–plane distance.
        let (u, v) = camera.project(&(pose.inverse() * centre).coords).unwrap();
        let (u, v) = (u.round(), v.round());
        let dir = pose.rotation * camera.ray(u, v);
        let t = normal.dot(&(centre.coords - eye)) / normal.dot(&dir);
        let rendered = f64::from(renderer.depth_m()[v as usize * w + u as usize]);
        assert!((rendered - t).abs() < 1e-5 * t, "tag depth {rendered} vs {t}");
    }
}

#[test]
fn renders_are_deterministic_and_noise_is_keyed_by_the_seed() {
    let site = moon_site();
    let camera = StereoCamera::narrow().downscaled(2);
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let pose = rover_camera(&site.terrain, -20.0, -8.0, 1.4, 0.3, 0.25);
    let scene = site.scene(&[], Reflectance::LunarLambert { l: 0.9 });
    let render = |renderer: &mut Renderer, seed: u64| {
        let (mut left, mut right) = (vec![0; w * h], vec![0; w * h]);
        renderer.render_stereo(&scene, &pose, seed, &mut left, &mut right);
        (left, right)
    };
    let mut renderer = Renderer::new(camera, SensorModel::default());
    let first = render(&mut renderer, 1);
    assert_eq!(render(&mut renderer, 1), first, "same renderer, same inputs");
    assert_eq!(render(&mut Renderer::new(camera, SensorModel::default()), 1), first, "fresh renderer");
    let other = render(&mut renderer, 2);
    // With σ ≈ 2 DN of noise, two draws round to the same value in roughly one pixel in five.
    let differ = first.0.iter().zip(&other.0).filter(|(a, b)| a != b).count() as f64 / (w * h) as f64;
    println!("different seeds: {differ:.3} of the pixels differ");
    assert!(differ > 0.5, "only {differ} of the pixels differ");
    // The noise is zero-mean: the frames' means agree to a small fraction of a grey value.
    let mean = |img: &[u8]| img.iter().map(|&v| f64::from(v)).sum::<f64>() / img.len() as f64;
    let mut clean = Renderer::new(camera, SensorModel { noise: false, ..SensorModel::default() });
    let noise_free = render(&mut clean, 1);
    assert!((mean(&noise_free.0) - mean(&first.0)).abs() < 0.1, "{} vs {}", mean(&noise_free.0), mean(&first.0));
    assert_eq!(render(&mut clean, 2), noise_free, "the noise seed must not matter without noise");
}

#[test]
fn on_a_fronto_parallel_plane_the_right_image_is_the_left_one_shifted() {
    // Looking straight down at flat ground from the height where the disparity is exactly 20 px:
    // the right camera's pixel u sees what the left one's pixel u + 20 sees.
    let site = synthetic_site(20.0, |_, _| 0.0);
    let camera = StereoCamera::narrow();
    let (w, h) = (camera.width_px as usize, camera.height_px as usize);
    let disparity = 20;
    let height = camera.f_px * camera.baseline_m / f64::from(disparity);
    // Optical axis down, image x east, image y south.
    let rotation = Rotation3::from_matrix_unchecked(nalgebra::Matrix3::new(
        1.0, 0.0, 0.0, //
        0.0, -1.0, 0.0, //
        0.0, 0.0, -1.0,
    ));
    let pose =
        Isometry3::from_parts(Translation3::new(0.3, -0.2, height), UnitQuaternion::from_rotation_matrix(&rotation));
    let sensor = SensorModel { noise: false, ..SensorModel::default() };
    let mut renderer = Renderer::new(camera, sensor);
    let (mut left, mut right) = (vec![0; w * h], vec![0; w * h]);
    renderer.render_stereo(&site.scene(&[], Reflectance::Lambert), &pose, 1, &mut left, &mut right);
    assert!(renderer.depth_m().iter().all(|&z| (f64::from(z) - height).abs() < 1e-5 * height));
    let (mut equal, mut worst, mut total) = (0, 0, 0);
    for v in 0..h {
        for u in 0..w - disparity as usize {
            let (l, r) = (left[v * w + u + disparity as usize], right[v * w + u]);
            equal += usize::from(l == r);
            worst = worst.max(l.abs_diff(r));
            total += 1;
        }
    }
    let spread = left.iter().max().unwrap() - left.iter().min().unwrap();
    println!("shifted left vs right: {equal} of {total} equal, worst {worst} DN (image spread {spread} DN)");
    // The same world point through two rays differs only in the last bits of f64, which can flip a
    // rounding to the next grey value.
    assert!(worst <= 1);
    assert!(equal as f64 > 0.999 * total as f64);
}
