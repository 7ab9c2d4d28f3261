//! SGM depth of the KITTI straight drive (60 m road) integrated along the ground-truth poses
//! into 7 m submaps, composed, written as PLY plus a top-down and a perspective picture, and the
//! consistency of overlapping road observations.
//!
//! `cargo run --release -p mapper --example map_kitti -- --out onboard/mapper/docs`

mod common;

use common::{BoxError, HeightConsistency, StereoDepth};
use hal::kitti::KittiDataset;
use hal::sensor::StereoFrame;
use mapper::integrate::IntegratorConfig;
use nalgebra::{Isometry3, Translation3, Vector3};

const KITTI: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/stereo_sequences/kitti_straight");
/// KITTI's camera height above the road.
const CAMERA_HEIGHT_M: f64 = 1.65;

fn main() -> Result<(), BoxError> {
    let out = common::out_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/docs"));
    std::fs::create_dir_all(&out)?;
    let mut dataset = KittiDataset::open(KITTI)?;
    let calibration = *dataset.calibration();
    let geometry = common::geometry_of(&calibration);
    let poses = common::read_kitti_poses(&std::fs::read_to_string(format!("{KITTI}/poses.txt"))?)?;
    // World: the first camera's frame turned to x forward, y left, z up (the camera is level).
    let t_world_first = Isometry3::from_parts(Translation3::identity(), calibration.left.t_body_cam.rotation);
    let t_world_cam: Vec<Isometry3<f64>> = poses.iter().map(|p| t_world_first * p).collect();

    let (w, h) = (calibration.left.width_px as usize, calibration.left.height_px as usize);
    // 128 disparities: at f·b ≈ 388 px·m the road is matched from 3 m on.
    let mut stereo = StereoDepth::new(128, w, h, geometry)?;
    let config = IntegratorConfig::default();
    let mut run = common::SubmapRun::new(geometry, config, 7.0);
    let cutoff_m = run.integrator.cutoff_m();
    let mut consistency = HeightConsistency::new(0.1);
    let mut frame = StereoFrame::default();
    let mut sgm_s = 0.0;
    let frames = dataset.frames().len().min(t_world_cam.len());
    for i in 0..frames {
        dataset.load_frame(i, &mut frame)?;
        let started = std::time::Instant::now();
        let depth = stereo.compute(&frame)?;
        sgm_s += started.elapsed().as_secs_f64();
        let t = t_world_cam[i];
        run.add(frame.stamp_ns, depth, &frame.left, &t);
        // Road surface: within 3 m of the driven line and 30 cm of the expected road height.
        common::for_each_point(depth, &geometry, &t, (config.min_depth_m, cutoff_m), 1, |p| {
            let near = t_world_cam.iter().min_by(|a, b| {
                let da = (a.translation.vector.xy() - p.coords.xy()).norm();
                let db = (b.translation.vector.xy() - p.coords.xy()).norm();
                da.total_cmp(&db)
            });
            if let Some(n) = near {
                let lateral = (n.rotation * Vector3::x()).xy().normalize();
                let d = p.coords.xy() - n.translation.vector.xy();
                let off = (d - lateral * d.dot(&lateral)).norm();
                let road_z = n.translation.vector.z - CAMERA_HEIGHT_M;
                if off < 3.0 && (p.z - road_z).abs() < 0.3 {
                    consistency.add_point(&p);
                }
            }
        });
        consistency.end_frame(3);
    }
    let composition = run.compose();
    let points = &composition.cloud.points;
    let ply = common::write_ply(points, &out.join("kitti_straight.ply"))?;
    let top = common::render_top_down(points, 900).write_png(&out.join("kitti_top.png"))?;
    // From behind the drive and well to its left, 35° above the horizon, fitted to the cloud.
    let size = (960, 540);
    let (eye, target) = common::frame_view(points, 55.0, 35.0, 60.0, size);
    let persp = common::render_perspective(points, eye, target, 60.0, size).write_png(&out.join("kitti_persp.png"))?;
    let (cells, median, p95) = consistency.spread();
    println!("KITTI straight: {frames} frames, {} submaps (7 m), depth cutoff {cutoff_m:.1} m", run.global.len() + 1);
    println!(
        "  SGM {:.0} ms/frame, integration {:.1} ms/frame, compose {:.1} ms",
        1e3 * sgm_s / frames as f64,
        1e3 * run.integrate_s / frames as f64,
        composition.stats.elapsed.as_secs_f64() * 1e3
    );
    println!(
        "  composed cloud {} points, octree {} leaves ({} occupied)",
        points.len(),
        composition.occupancy.len(),
        composition.occupancy.occupied_count()
    );
    println!("  road height spread over frames (10 cm cells, {cells} seen ≥ 2×): median {median:.3} m, p95 {p95:.3} m");
    println!(
        "  wrote kitti_straight.ply ({ply} B), kitti_top.png ({top} B), kitti_persp.png ({persp} B) to {}",
        out.display()
    );
    Ok(())
}
