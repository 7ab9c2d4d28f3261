//! SGM depth of the EuRoC MH_01 hand-held pairs (raw, rectified here) integrated along the
//! ground-truth poses into submaps, composed, written as PLY plus a top-down and a perspective
//! picture, and the consistency of overlapping observations on the pallet top and the floor.
//!
//! `cargo run --release -p mapper --example map_euroc -- --out onboard/mapper/docs`

mod common;

use common::{BoxError, HeightConsistency, StereoDepth};
use hal::asl::AslDataset;
use hal::sensor::{SensorSource, StereoFrame};
use mapper::integrate::IntegratorConfig;
use nalgebra::{Point3, Vector2, Vector3};
use vision::rectify::Rectifier;

const MH01: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/euroc/mh_01_handheld");

fn main() -> Result<(), BoxError> {
    let out = common::out_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/docs"));
    std::fs::create_dir_all(&out)?;
    let mut dataset = AslDataset::open(MH01)?;
    let raw = dataset.stereo_calibration().ok_or("no camera calibration")?;
    let rectifier = Rectifier::new(&raw)?;
    let calibration = rectifier.rectified_calibration();
    let geometry = common::geometry_of(&calibration);
    // Ground truth: body (IMU) pose in the Leica world frame (z up); camera via t_body_cam.
    let gt_text = std::fs::read_to_string(format!("{MH01}/groundtruth_openvins_MH_01_easy_tum_crop.txt"))?;
    let gt = eval::io::parse_tum(&gt_text)?;
    let t_body_cam = calibration.left.t_body_cam;

    let (w, h) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
    let mut stereo = StereoDepth::new(128, w, h, geometry)?;
    let config = IntegratorConfig::default();
    // Hand-held over 4 s covers ~2 m: 1 m submaps exercise the composition.
    let mut run = common::SubmapRun::new(geometry, config, 1.0);
    let cutoff_m = run.integrator.cutoff_m();
    let (mut raw_frame, mut frame) = (StereoFrame::default(), StereoFrame::default());
    let mut frame_points: Vec<Vec<Point3<f64>>> = Vec::new();
    let mut sgm_s = 0.0;
    let mut path = Vec::new();
    for i in 0..dataset.pairs().len() {
        dataset.load_pair(i, &mut raw_frame)?;
        let Some(t_world_body) = gt.interpolate(raw_frame.stamp_ns as f64 * 1e-9, 0.02) else { continue };
        rectifier.rectify(&raw_frame, &mut frame)?;
        let started = std::time::Instant::now();
        let depth = stereo.compute(&frame)?;
        sgm_s += started.elapsed().as_secs_f64();
        let t_world_cam = t_world_body * t_body_cam;
        path.push(t_world_cam.translation.vector);
        run.add(frame.stamp_ns, depth, &frame.left, &t_world_cam);
        let mut points = Vec::new();
        common::for_each_point(depth, &geometry, &t_world_cam, (config.min_depth_m, cutoff_m), 1, |p| points.push(p));
        frame_points.push(points);
    }
    let frames = frame_points.len();
    // Horizontal surfaces in the gravity-aligned GT frame (RANSAC, normal within 10° of +z, 3 cm
    // inliers) on every 50th observation: the one with most support is the pallet the camera is
    // swung over; the floor is the best such plane among the points 40 cm or more below it.
    let sample: Vec<Point3<f64>> = frame_points.iter().flatten().step_by(50).copied().collect();
    let (top, top_inliers) = common::fit_horizontal_plane(&sample, 10.0, 0.03, 400, 1).ok_or("no horizontal plane")?;
    let below: Vec<Point3<f64>> = sample.iter().filter(|p| top.distance(p) < -0.4).copied().collect();
    let floor = common::fit_horizontal_plane(&below, 10.0, 0.03, 400, 2);
    let centre = path.iter().sum::<Vector3<f64>>() / path.len().max(1) as f64;
    let camera_z = centre.z;
    println!(
        "  dominant horizontal plane (pallet top): z = {:.3} m at the path centre, tilt {:.1}°, {top_inliers} of {} \
         sampled points; camera {:.2} m above it",
        top.z_at(centre.x, centre.y),
        top.tilt_deg(),
        sample.len(),
        camera_z - top.z_at(centre.x, centre.y)
    );
    let surfaces: Vec<(&str, common::Plane)> =
        std::iter::once(("pallet top", top)).chain(floor.map(|(plane, _)| ("floor", plane))).collect();
    if let Some((plane, n)) = floor {
        println!(
            "  floor (best horizontal plane ≥ 40 cm below): z = {:.3} m, tilt {:.1}°, {n} of {} sampled points \
             ({:.1} %); camera {:.2} m above it",
            plane.z_at(centre.x, centre.y),
            plane.tilt_deg(),
            sample.len(),
            100.0 * n as f64 / sample.len().max(1) as f64,
            camera_z - plane.z_at(centre.x, centre.y)
        );
    }
    // Per-cell spread of the per-frame mean height, points within 15 cm of each surface.
    for (name, plane) in &surfaces {
        let mut consistency = HeightConsistency::new(0.1);
        for points in &frame_points {
            for p in points.iter().filter(|p| plane.distance(p).abs() < 0.15) {
                consistency.add_point(p);
            }
            consistency.end_frame(3);
        }
        let (cells, median, p95) = consistency.spread();
        // How far the cells are from the camera path (horizontal, nearest frame).
        let mut distances: Vec<f64> = consistency
            .cell_centres()
            .iter()
            .map(|(x, y)| path.iter().map(|c| (c.xy() - Vector2::new(*x, *y)).norm()).fold(f64::INFINITY, f64::min))
            .collect();
        distances.sort_by(f64::total_cmp);
        let q = |f: f64| distances.get(((distances.len().max(1) - 1) as f64 * f).round() as usize).copied();
        println!(
            "  {name}: height spread over frames (10 cm cells, {cells} seen ≥ 2×): median {median:.3} m, p95 \
             {p95:.3} m; cells {:.2}–{:.2} m (5th–95th pct.) from the camera path horizontally",
            q(0.05).unwrap_or(f64::NAN),
            q(0.95).unwrap_or(f64::NAN)
        );
    }

    let composition = run.compose();
    let points = &composition.cloud.points;
    let ply = common::write_ply(points, &out.join("euroc_mh01.ply"))?;
    let top = common::render_top_down(points, 800).write_png(&out.join("euroc_top.png"))?;
    let size = (960, 540);
    let (eye, target) = common::frame_view(points, -60.0, 40.0, 60.0, size);
    let persp = common::render_perspective(points, eye, target, 60.0, size).write_png(&out.join("euroc_persp.png"))?;
    println!("EuRoC MH_01: {frames} frames, {} submaps (1 m), depth cutoff {cutoff_m:.1} m", run.global.len() + 1);
    println!(
        "  SGM {:.0} ms/frame, integration {:.1} ms/frame, compose {:.1} ms",
        1e3 * sgm_s / frames.max(1) as f64,
        1e3 * run.integrate_s / frames.max(1) as f64,
        composition.stats.elapsed.as_secs_f64() * 1e3
    );
    println!(
        "  composed cloud {} points, octree {} leaves ({} occupied)",
        points.len(),
        composition.occupancy.len(),
        composition.occupancy.occupied_count()
    );
    println!(
        "  wrote euroc_mh01.ply ({ply} B), euroc_top.png ({top} B), euroc_persp.png ({persp} B) to {}",
        out.display()
    );
    Ok(())
}
