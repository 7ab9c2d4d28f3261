//! The world's ground truth next to the robots' datasets: terrain heights around the paths,
//! rocks, craters, negative obstacles, the robots' markers and the scenario itself.

use std::fmt::Write as _;
use std::path::Path;

use serde_json::json;

use super::{AslError, write_text};
use crate::camera::StereoCamera;
use crate::lighting::Reflectance;
use crate::robot::RobotKind;
use crate::terrain::NegativeObstacleKind;
use crate::world::World;

/// How much of the terrain `world/terrain.heightgrid` holds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WorldExport {
    /// Margin around the robots' paths.
    pub margin_m: f64,
    /// Every `height_step`-th cell of the terrain's grid (2 at 5 cm = 10 cm cells).
    pub height_step: usize,
}

impl Default for WorldExport {
    fn default() -> Self {
        WorldExport { margin_m: 10.0, height_step: 2 }
    }
}

/// What [`write_world`] wrote.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct WorldFiles {
    pub bytes: u64,
    /// World (x, y) bounds the height grid was cropped to.
    pub height_grid_min_m: [f64; 2],
    pub height_grid_max_m: [f64; 2],
    pub rocks: usize,
    pub markers: usize,
}

/// Spacing of the trajectory samples that bound the paths (a rover moves centimetres in it).
const PATH_SAMPLE_NS: u64 = 100_000_000;

/// World (x, y) bounding box of every robot's waypoints and trajectory; `None` without robots.
pub fn path_bounds(world: &World) -> Option<([f64; 2], [f64; 2])> {
    let mut bounds: Option<([f64; 2], [f64; 2])> = None;
    let mut add = |x: f64, y: f64| {
        if !(x.is_finite() && y.is_finite()) {
            return;
        }
        let (min, max) = bounds.get_or_insert(([x, y], [x, y]));
        *min = [min[0].min(x), min[1].min(y)];
        *max = [max[0].max(x), max[1].max(y)];
    };
    for robot in &world.robots {
        for waypoint in &robot.setup.waypoints_m {
            add(waypoint[0], waypoint[1]);
        }
        let trajectory = &robot.trajectory;
        let (start, end) = (trajectory.start_ns(), trajectory.end_ns());
        let mut stamp = start;
        while stamp <= end {
            if let Some(state) = trajectory.state_at(stamp) {
                let p = state.t_world_body.translation.vector;
                add(p.x, p.y);
            }
            if stamp == end {
                break;
            }
            stamp = stamp.saturating_add(PATH_SAMPLE_NS).min(end);
        }
    }
    bounds
}

/// Writes `dir/` with the defaults of [`WorldExport`].
pub fn write_world(world: &World, dir: &Path) -> Result<WorldFiles, AslError> {
    write_world_with(world, dir, &WorldExport::default())
}

/// Writes `terrain.heightgrid`, `rocks.csv`, `craters.csv`, `negative_obstacles.csv`,
/// `markers.csv` and `scenario.json` into `dir`.
pub fn write_world_with(world: &World, dir: &Path, export: &WorldExport) -> Result<WorldFiles, AslError> {
    std::fs::create_dir_all(dir).map_err(super::io_error(dir))?;
    let hf = &world.terrain.heightfield;
    let res = hf.resolution_m;
    let site_min = hf.origin_m;
    let site_max = [
        hf.origin_m[0] + hf.cols.saturating_sub(1) as f64 * res,
        hf.origin_m[1] + hf.rows.saturating_sub(1) as f64 * res,
    ];
    let (min_m, max_m) = match path_bounds(world) {
        Some((lo, hi)) => (
            [(lo[0] - export.margin_m).max(site_min[0]), (lo[1] - export.margin_m).max(site_min[1])],
            [(hi[0] + export.margin_m).min(site_max[0]), (hi[1] + export.margin_m).min(site_max[1])],
        ),
        None => (site_min, site_max),
    };
    let mut files = WorldFiles { height_grid_min_m: min_m, height_grid_max_m: max_m, ..WorldFiles::default() };
    let step = export.height_step.max(1);
    files.bytes += write_text(&dir.join("terrain.heightgrid"), &hf.to_height_grid_text(min_m, max_m, step))?;

    let mut rocks = String::from("#id,x [m],y [m],z [m],radius [m],height [m]\n");
    for rock in &world.terrain.rocks {
        let p = rock.base_m;
        let _ = writeln!(rocks, "{},{:?},{:?},{:?},{:?},{:?}", rock.id, p.x, p.y, p.z, rock.radius_m, rock.height_m);
    }
    files.rocks = world.terrain.rocks.len();
    files.bytes += write_text(&dir.join("rocks.csv"), &rocks)?;

    let mut craters = String::from("#id,x [m],y [m],radius [m],depth [m],rim_height [m]\n");
    for (id, crater) in world.terrain.craters.iter().enumerate() {
        let [x, y] = crater.centre_m;
        let _ =
            writeln!(craters, "{id},{x:?},{y:?},{:?},{:?},{:?}", crater.radius_m, crater.depth_m, crater.rim_height_m);
    }
    files.bytes += write_text(&dir.join("craters.csv"), &craters)?;

    let mut obstacles = String::from("#obstacle,kind,drop [m],vertex,x [m],y [m]\n");
    for (id, obstacle) in world.terrain.negative_obstacles().iter().enumerate() {
        let kind = match obstacle.kind {
            NegativeObstacleKind::CraterEdge => "crater_edge",
            NegativeObstacleKind::Ditch => "ditch",
        };
        for (vertex, [x, y]) in obstacle.edge_m.iter().enumerate() {
            let _ = writeln!(obstacles, "{id},{kind},{:?},{vertex},{x:?},{y:?}", obstacle.drop_m);
        }
    }
    files.bytes += write_text(&dir.join("negative_obstacles.csv"), &obstacles)?;

    let mut markers = String::from("#robot,tag_id,size [m],x [m],y [m],z [m],qx,qy,qz,qw\n");
    for robot in &world.robots {
        for marker in &robot.setup.model.markers {
            let p = marker.t_body_marker.translation.vector;
            let q = marker.t_body_marker.rotation.quaternion();
            let _ = writeln!(
                markers,
                "{},{},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
                robot.setup.id, marker.tag_id, marker.size_m, p.x, p.y, p.z, q.i, q.j, q.k, q.w
            );
            files.markers += 1;
        }
    }
    files.bytes += write_text(&dir.join("markers.csv"), &markers)?;

    let scenario = scenario_json(world, &files, step);
    let text = serde_json::to_string_pretty(&scenario).map_err(|e| AslError::Invalid(e.to_string()))? + "\n";
    files.bytes += write_text(&dir.join("scenario.json"), &text)?;
    Ok(files)
}

fn camera_json(camera: &StereoCamera) -> serde_json::Value {
    json!({
        "width_px": camera.width_px,
        "height_px": camera.height_px,
        "f_px": camera.f_px,
        "cx_px": camera.cx_px,
        "cy_px": camera.cy_px,
        "baseline_m": camera.baseline_m,
        "hfov_deg": camera.hfov_rad().to_degrees(),
    })
}

fn scenario_json(world: &World, files: &WorldFiles, step: usize) -> serde_json::Value {
    let s = &world.scenario;
    let robots: Vec<serde_json::Value> = world
        .robots
        .iter()
        .map(|robot| {
            let setup = &robot.setup;
            json!({
                "id": setup.id,
                "name": setup.name,
                "dataset": format!("robot{}", setup.id),
                "kind": match setup.model.kind { RobotKind::Rover => "rover", RobotKind::Flyer => "flyer" },
                "waypoints_m": setup.waypoints_m,
                "tilt_rad": setup.tilt_rad,
                "pan_sweep_rad": setup.pan_sweep_rad,
                "drive": {
                    "speed_mps": setup.drive.speed_mps,
                    "pause_s": setup.drive.pause_s,
                    "knot_interval_s": setup.drive.knot_interval_s,
                },
                "camera": camera_json(&setup.model.camera),
                "markers": setup.model.markers.iter().map(|m| m.tag_id).collect::<Vec<_>>(),
                "trajectory_ns": [robot.trajectory.start_ns(), robot.trajectory.end_ns()],
            })
        })
        .collect();
    let reflectance = match s.reflectance {
        Reflectance::Lambert => json!({ "model": "lambert" }),
        Reflectance::LunarLambert { l } => json!({ "model": "lunar_lambert", "l": l }),
    };
    let t = &s.terrain;
    let n = &s.imu_noise;
    json!({
        "name": s.name,
        "seed": s.seed,
        "body": s.body.name(),
        "gravity_mps2": s.body.gravity_mps2(),
        "duration_s": s.duration_s,
        "rates_hz": { "camera": s.camera_rate_hz, "imu": s.imu_rate_hz, "wheel": s.wheel.rate_hz },
        "camera": world.robots.first().map(|r| camera_json(&r.setup.model.camera)),
        "sun": {
            "azimuth_rad": s.sun.azimuth_rad,
            "elevation_rad": s.sun.elevation_rad,
            "irradiance": s.sun.irradiance,
        },
        "sky_radiance": s.sky_radiance,
        "reflectance": reflectance,
        "terrain": {
            "size_m": t.size_m,
            "resolution_m": t.resolution_m,
            "relief_amplitude_m": t.relief_amplitude_m,
            "craters_per_km2": t.craters_per_km2,
            "rocks_per_100m2": t.rocks_per_100m2,
            "ditches": t.ditches,
            "albedo_mean": t.albedo_mean,
            "albedo_contrast": t.albedo_contrast,
        },
        "imu_noise": {
            "gyroscope_noise_density": n.gyro_noise_density_radps_rthz,
            "gyroscope_random_walk": n.gyro_bias_rw_radps2_rthz,
            "accelerometer_noise_density": n.accel_noise_density_mps2_rthz,
            "accelerometer_random_walk": n.accel_bias_rw_mps3_rthz,
            "gyroscope_bias_init_sigma": n.gyro_bias_init_radps,
            "accelerometer_bias_init_sigma": n.accel_bias_init_mps2,
        },
        "height_grid": {
            "file": "terrain.heightgrid",
            "min_m": files.height_grid_min_m,
            "max_m": files.height_grid_max_m,
            "step": step,
            "resolution_m": t.resolution_m * step as f64,
        },
        "robots": robots,
    })
}
