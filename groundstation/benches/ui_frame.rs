//! CPU time of one UI frame, headless: `Context::run_ui` + `tessellate` for a 4-robot team on a
//! 200 m × 200 m map (2000 × 2000 cells, 4 × 50k-pose trajectories, 200k 3D points, 10 min of
//! link samples). No GPU upload or rasterisation: the real-window glow frame under Xvfb is
//! measured separately (README).
//!
//! `cargo bench -p groundstation --bench ui_frame` (without `--bench`: a small smoke run).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::{BTreeMap, VecDeque};
use std::sync::Arc;
use std::time::Instant;

use egui::{Pos2, RawInput, Rect, Vec2};
use groundstation::ui::{self, CentralTab, UiState};
use groundstation::view::{
    CommandState, CommandView, EdgeKind, EdgeView, HeightGrid, LinkSample, LinkView, MapPoints, RobotView, Staleness,
    SubmapOutline, TeamView,
};
use nalgebra::{Isometry3, Matrix2, Vector3};
use protocol::message::{FilterHealth, FilterStatus, Mode, ResourceUsage};

struct Size {
    cells: usize,
    poses: usize,
    points: usize,
    frames: usize,
}

fn view(size: &Size) -> TeamView {
    let cell_m = 200.0 / size.cells as f64;
    let n = size.cells * size.cells;
    let height_m: Vec<f32> = (0..n)
        .map(|i| {
            let (r, c) = ((i / size.cells) as f32, (i % size.cells) as f32);
            if ((r * 0.37 + c * 0.11) as usize).is_multiple_of(23) {
                f32::NAN
            } else {
                (r * 0.01).sin() + (c * 0.013).cos()
            }
        })
        .collect();
    let obstacle: Vec<bool> = (0..n).map(|i| i.is_multiple_of(211)).collect();
    let mut robots = BTreeMap::new();
    for id in 1..=4u8 {
        let k = f64::from(id);
        let trajectory_ref_m: Vec<[f64; 3]> = (0..size.poses)
            .map(|i| {
                let s = i as f64 / size.poses as f64 * std::f64::consts::TAU * 3.0;
                [80.0 * (s + k).cos() * (0.3 + 0.2 * k), 80.0 * (s * 1.3 + k).sin() * (0.3 + 0.15 * k), 0.0]
            })
            .collect();
        let last = *trajectory_ref_m.last().unwrap();
        let submaps = (0..40)
            .map(|j| SubmapOutline {
                index: j,
                t_ref_submap: Isometry3::new(
                    Vector3::new(
                        trajectory_ref_m[j as usize * size.poses / 40][0],
                        trajectory_ref_m[j as usize * size.poses / 40][1],
                        0.0,
                    ),
                    Vector3::new(0.0, 0.0, f64::from(j) * 0.3),
                ),
                bounds_submap_m: Some([-8.0, -6.0, 12.0, 6.0]),
            })
            .collect();
        robots.insert(
            id,
            RobotView {
                robot: id,
                connected: true,
                mode: Some(Mode::Autonomous),
                sensors: None,
                filter: Some(FilterHealth {
                    status: FilterStatus::Nominal,
                    position_std_m: 0.2,
                    yaw_std_rad: 0.01,
                    vo_age_ms: 30,
                }),
                tasks: vec![],
                queues: vec![],
                links: vec![],
                resources: Some(ResourceUsage { cpu_permille: 400, mem_used_kib: 1 << 20, mem_total_kib: 4 << 20 }),
                auth_rejections: 0,
                last_message_ns: Some(599_000_000_000),
                staleness: if id == 4 { Staleness::Stale } else { Staleness::Fresh },
                trajectory_ref_m,
                t_ref_body: Some(Isometry3::new(Vector3::new(last[0], last[1], 0.0), Vector3::new(0.0, 0.0, k))),
                position_cov_xy_m2: Some(Matrix2::new(0.5, 0.1, 0.1, 0.3)),
                submaps,
                hazards: None,
            },
        );
    }
    let samples: VecDeque<LinkSample> = (0..600)
        .map(|i| LinkSample {
            t_s: f64::from(i),
            rx_bytes_per_s_by_class: ["Telemetry", "PoseEstimate", "SubmapChunk", "Heartbeat", "CommandAck"]
                .iter()
                .enumerate()
                .map(|(j, c)| ((*c).to_owned(), 100.0 * j as f64 + f64::from(i % 17)))
                .collect(),
            tx_bytes_per_s_by_class: [("Telemetry".to_owned(), 300.0)].into_iter().collect(),
            rtt_ms: Some(4000.0 + f64::from(i % 50)),
            loss_permille: Some(f64::from(i % 9)),
            robot_queue_depth: i % 20,
            ground_queue_depth: i % 3,
            outage: i % 97 < 4,
        })
        .collect();
    TeamView {
        now_ns: 600_000_000_000,
        reference_robot: Some(1),
        robots,
        edges: (0..60u16)
            .map(|i| EdgeView {
                kind: if i % 2 == 0 { EdgeKind::SubmapMatch } else { EdgeKind::RobotDetection },
                from_ref_m: [f64::from(i) - 30.0, -20.0, 0.0],
                to_ref_m: [f64::from(i) - 25.0, 20.0, 0.0],
            })
            .collect(),
        map: Some(Arc::new(HeightGrid {
            origin_xy_m: [-100.0, -100.0],
            cell_m,
            width: size.cells,
            height: size.cells,
            height_m,
            obstacle,
            revision: 1,
        })),
        points: Arc::new(MapPoints {
            points_ref_m: (0..size.points)
                .map(|i| {
                    let (x, y) = ((i % 447) as f32 * 0.45 - 100.0, (i / 447) as f32 * 0.45 - 100.0);
                    [x, y, (x * 0.05).sin() + (y * 0.07).cos()]
                })
                .collect(),
            obstacle: (0..size.points).map(|i| i.is_multiple_of(37)).collect(),
            revision: 1,
        }),
        link: LinkView { samples, outages: 7, packets_received: 1_000_000, packets_rejected: 12 },
        commands: (0..40)
            .map(|i| CommandView {
                id: i,
                target: (i % 4) as u8 + 1,
                summary: format!("waypoint ({i}.0, 2.0) m"),
                state: CommandState::Sent { first_sent_ns: 590_000_000_000, attempts: 2 },
                queued_ns: 589_000_000_000,
            })
            .collect(),
        can_command: true,
        replay: None,
        notices: vec![],
        source: "udp://0.0.0.0:47800".into(),
    }
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    let rank = ((q * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// Runs `frames` frames; returns per-frame ms (UI pass, tessellation) and the vertex count.
fn run(ctx: &egui::Context, view: &TeamView, state: &mut UiState, frames: usize) -> (Vec<f64>, Vec<f64>, usize) {
    let (mut ui_ms, mut tess_ms, mut vertices) = (Vec::new(), Vec::new(), 0);
    for frame in 0..frames {
        let input = RawInput {
            screen_rect: Some(Rect::from_min_size(Pos2::ZERO, Vec2::new(1600.0, 1000.0))),
            time: Some(frame as f64 / 30.0),
            ..Default::default()
        };
        let t0 = Instant::now();
        let output = ctx.run_ui(input, |ui| {
            let _ = ui::show(ui, view, state);
        });
        let t1 = Instant::now();
        let egui::FullOutput { shapes, pixels_per_point, mut textures_delta, .. } = output;
        // No GPU here: the texture uploads are the painter's job, out of scope.
        textures_delta.clear();
        let prims = ctx.tessellate(shapes, pixels_per_point);
        let t2 = Instant::now();
        vertices = prims
            .iter()
            .map(|p| match &p.primitive {
                egui::epaint::Primitive::Mesh(m) => m.vertices.len(),
                egui::epaint::Primitive::Callback(_) => 0,
            })
            .sum();
        ui_ms.push((t1 - t0).as_secs_f64() * 1e3);
        tess_ms.push((t2 - t1).as_secs_f64() * 1e3);
    }
    (ui_ms, tess_ms, vertices)
}

fn report(name: &str, ui_ms: &[f64], tess_ms: &[f64], vertices: usize) {
    let total: Vec<f64> = ui_ms.iter().zip(tess_ms).map(|(a, b)| a + b).collect();
    let sorted = |v: &[f64]| {
        let mut v = v.to_vec();
        v.sort_by(f64::total_cmp);
        v
    };
    let (t, u, s) = (sorted(&total), sorted(ui_ms), sorted(tess_ms));
    println!(
        "{name:<28} frames {:>4}  total p50 {:>6.2} ms p95 {:>6.2} ms max {:>6.2} ms | ui p50 {:>6.2} | tessellate p50 {:>6.2} | {vertices} vertices",
        t.len(),
        percentile(&t, 0.5),
        percentile(&t, 0.95),
        percentile(&t, 1.0),
        percentile(&u, 0.5),
        percentile(&s, 0.5),
    );
}

fn main() {
    let heavy = std::env::args().any(|a| a == "--bench");
    let size = if heavy {
        Size { cells: 2000, poses: 50_000, points: 200_000, frames: 200 }
    } else {
        Size { cells: 200, poses: 1000, points: 2000, frames: 5 }
    };
    let view = view(&size);
    let ctx = egui::Context::default();
    let mut state = UiState::default();

    // First frame: fit, grid texture built from the 4M cells, fonts.
    let (first_ui, first_tess, _) = run(&ctx, &view, &mut state, 1);
    println!(
        "first frame (texture build):  {:.1} ms (ui {:.1}, tessellate {:.1})",
        first_ui[0] + first_tess[0],
        first_ui[0],
        first_tess[0]
    );
    // Steady state: egui's Grid/ScrollArea sizing passes settle in the first few frames.
    run(&ctx, &view, &mut state, 3);
    let (u, t, v) = run(&ctx, &view, &mut state, size.frames);
    report("map tab, fit all", &u, &t, v);

    // Zoomed in on a robot: long trajectories cross the screen.
    state.map.set_view([0.0, 0.0], 40.0);
    let (u, t, v) = run(&ctx, &view, &mut state, size.frames);
    report("map tab, 40 px/m", &u, &t, v);

    // A new map revision: the texture is rebuilt on the UI thread in that frame.
    let mut rebuilds = Vec::new();
    let mut view = view;
    for revision in 2..if heavy { 7 } else { 3 } {
        let mut grid = (**view.map.as_ref().unwrap()).clone();
        grid.revision = revision;
        view.map = Some(Arc::new(grid));
        let (u, t, _) = run(&ctx, &view, &mut state, 1);
        rebuilds.push(u[0] + t[0]);
    }
    rebuilds.sort_by(f64::total_cmp);
    println!(
        "frame with a new map revision: median {:.1} ms over {} rebuilds",
        percentile(&rebuilds, 0.5),
        rebuilds.len()
    );
    let uploads = state.map.texture_uploads;

    state.tab = CentralTab::Points3d;
    run(&ctx, &view, &mut state, 2);
    let (u, t, v) = run(&ctx, &view, &mut state, size.frames / 4);
    report("3D tab", &u, &t, v);
    assert_eq!(state.map.texture_uploads, uploads, "the grid texture is built once per revision");
}
