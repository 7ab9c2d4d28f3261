//! The offline look-up table of the marker uncertainty model (thesis §6.2.3, offline step).
//!
//! **Grid.** Row `i` is distance `d_i = d_min + i·(d_max − d_min)/(n_d − 1)`, column `j` signed
//! tilt `Φ_j = Φ_min + j·(Φ_max − Φ_min)/(n_Φ − 1)` (both equidistant, ends included). Cell
//! `(i, j)`'s true pose ([`cell_truth`]): the tag centred on the optical axis at distance `d_i`,
//! upright, facing the camera, turned by `Φ_j` about the camera's y axis:
//! `t_cam_marker = (Ry(Φ_j)·diag(1, −1, −1), (0, 0, d_i))`, whose signed tilt
//! ([`super::signed_tilt`]) is `Φ_j`.
//!
//! **A cell.** Render the tag ([`super::render`]), detect its corners, run PnP (the best IPPE
//! solution) on the detected corners and on the 256 perturbed sets of Eq. 6.9, take each pose's
//! error against the truth ([`super::pose_error`]: `t̂ − t`, `Log(R̂ Rᵀ)`, camera frame) and
//! write the per-DOF maximum of |error| over the 257 poses. Ambiguity compensation (the thesis's
//! `Φ̂ → −Φ̂`): if the chosen solution's rotation error exceeds
//! [`LutParams::flip_threshold_rad`] and the other IPPE solution's is smaller, the other one
//! counts. No detection (or PnP failure on the detected corners): NaN.
//!
//! **Post-processing**, in the thesis's order, per DOF: (1) [`median_filter`] (`k × k`, default
//! 3 × 3, over the valid cells of the window; NaN cells stay NaN so the detection boundary does not
//! move; the upper median for an even count, the conservative one); (2) [`fill_rows`]: in each
//! row (distance) the cells before the first valid cell take its value, those after the last
//! valid cell take that one's, and a hole between valid cells takes the larger of its two valid
//! neighbours; (3) [`fill_columns`]: in each column (tilt) the maximum of the final 10 % (at
//! least one) of its valid values, in order of distance, fills every remaining NaN cell.
//!
//! **Lookup**: bilinear in `(d, Φ)`, clamped to the grid (beyond 7 m the table's last row; the
//! thesis notes the model then underestimates the translation error).
//!
//! **File format** (all little-endian), version [`LUT_FORMAT_VERSION`]:
//!
//! | bytes | field |
//! |---|---|
//! | 8 | magic `b"MRKRLUT\0"` |
//! | 4 | format version (u32) |
//! | 4 | header length `H` in bytes (u32), the fields below up to the detector string |
//! | 4 + 4 | image width, height (u32) |
//! | 4 × 8 | fx, fy, cx, cy (f64, pixels) |
//! | 8 + 4 | tag size (f64, m), tag id rendered (u32) |
//! | 8 | Δp (f64, px) |
//! | 4 × 4 | white, black, plate, background level (f32, grey values) |
//! | 4 × 8 | plate half edge / tag size, blur σ (px), read noise (DN), full well (e⁻) (f64) |
//! | 4 + 8 | supersampling (u32), noise seed (u64) |
//! | 4 + 2 × 8 | distance rows `n_d` (u32), `d_min`, `d_max` (f64, m) |
//! | 4 + 2 × 8 | tilt columns `n_Φ` (u32), `Φ_min`, `Φ_max` (f64, degrees) |
//! | 4 + 8 + 4 | median kernel (u32), flip threshold (f64, degrees), PnP refinement iterations (u32) |
//! | 4 + n | detector description: length (u32), UTF-8 |
//! | `n_d·n_Φ·6·4` | raw table (f32), cell `(i, j)` at `(i·n_Φ + j)·6`, DOFs x, y, z (m), rx, ry, rz (rad); NaN = not detected |
//! | `n_d·n_Φ·6·4` | final table (f32), same layout, all finite |
//! | 4 | CRC-32/ISO-HDLC (`protocol::crc`) of every byte before it |
//!
//! The decoder is total: any byte string gives a table or a [`LutDecodeError`].

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::mpsc;

use nalgebra::{Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

use super::ippe::{PnpOptions, solve_square};
use super::render::{CameraModel, RenderConfig, TagCells, render_tag};
use super::sampling::{SAMPLE_SETS, perturbed_corners};
use super::{DOFS, pose_error};
use crate::apriltag::{TagDetector, TagDetectorConfig};
use crate::image::ImageView;

/// File magic and the format version this code writes and reads.
pub const LUT_MAGIC: [u8; 8] = *b"MRKRLUT\0";
pub const LUT_FORMAT_VERSION: u32 = 1;

/// The (distance, tilt) grid.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LutGrid {
    pub distances: u32,
    pub d_min_m: f64,
    pub d_max_m: f64,
    pub tilts: u32,
    pub phi_min_deg: f64,
    pub phi_max_deg: f64,
}

impl LutGrid {
    /// The thesis's grid (§6.2.3): 200 × 200 over d ∈ [0.2, 7.0] m, Φ ∈ [−89°, 89°].
    pub fn thesis(size: u32) -> Self {
        LutGrid { distances: size, d_min_m: 0.2, d_max_m: 7.0, tilts: size, phi_min_deg: -89.0, phi_max_deg: 89.0 }
    }

    pub fn cells(&self) -> usize {
        self.distances as usize * self.tilts as usize
    }

    pub fn distance_m(&self, i: usize) -> f64 {
        self.d_min_m + (self.d_max_m - self.d_min_m) * i as f64 / (f64::from(self.distances) - 1.0)
    }

    pub fn tilt_rad(&self, j: usize) -> f64 {
        (self.phi_min_deg + (self.phi_max_deg - self.phi_min_deg) * j as f64 / (f64::from(self.tilts) - 1.0))
            .to_radians()
    }

    fn is_valid(&self) -> bool {
        self.distances >= 2
            && self.tilts >= 2
            && self.d_min_m.is_finite()
            && self.d_max_m.is_finite()
            && self.d_min_m > 0.0
            && self.d_max_m > self.d_min_m
            && self.phi_min_deg.is_finite()
            && self.phi_max_deg.is_finite()
            && self.phi_min_deg > -90.0
            && self.phi_max_deg < 90.0
            && self.phi_max_deg > self.phi_min_deg
            && self.cells() <= MAX_CELLS
    }
}

/// Largest table a file may declare (16 M cells, 384 MiB per table): bounds what a decoder
/// allocates.
const MAX_CELLS: usize = 1 << 24;
/// Longest detector description.
const MAX_DETECTOR_BYTES: usize = 4096;

/// Everything a table depends on (T23, T24): camera, tag, Δp, renderer, grid, post-processing,
/// PnP and detector.
#[derive(Debug, Clone, PartialEq)]
pub struct LutParams {
    pub camera: CameraModel,
    pub tag_size_m: f64,
    /// The tag36h11 id rendered (its cells are the generator's `cells` argument).
    pub tag_id: u32,
    pub delta_px: f64,
    pub render: RenderConfig,
    /// Seed of the image noise; cell `(i, j)` uses [`cell_seed`].
    pub noise_seed: u64,
    pub grid: LutGrid,
    /// Edge of the median filter's square window (odd, ≥ 1; 1 = no filter).
    pub median_kernel: u32,
    /// Rotation error above which the other IPPE solution counts if it is closer to the truth.
    pub flip_threshold_deg: f64,
    pub pnp_refine_iterations: u32,
    /// What detected the corners (name and configuration), free text.
    pub detector: String,
}

impl LutParams {
    fn pnp_options(&self) -> PnpOptions {
        PnpOptions { refine_iterations: self.pnp_refine_iterations }
    }
}

impl LutParams {
    /// The defaults of the `marker-lut` command for a camera, tag size and grid size: tag36h11 id
    /// 0, Δp = 0.5 px, [`RenderConfig::default`], noise seed 1, the thesis's grid ranges, a 3 × 3
    /// median filter, a 5° flip threshold, plain IPPE.
    pub fn command_defaults(camera: CameraModel, tag_size_m: f64, grid_size: u32, detector: String) -> Self {
        LutParams {
            camera,
            tag_size_m,
            tag_id: 0,
            delta_px: 0.5,
            render: RenderConfig::default(),
            noise_seed: 1,
            grid: LutGrid::thesis(grid_size),
            median_kernel: 3,
            flip_threshold_deg: 5.0,
            pnp_refine_iterations: 0,
            detector,
        }
    }
}

/// The simulator's rover camera at full resolution (`sim::camera::StereoCamera::narrow()`, the
/// camera of every scenario preset at `downscale = 1`): 1024 × 508, horizontal field of view
/// 50.6°, so `f = 512 / tan(25.3°) ≈ 1083.1` px, principal point at the image centre
/// (`(w − 1)/2`, `(h − 1)/2`).
pub fn sim_rover_camera() -> CameraModel {
    let f = 0.5 * 1024.0 / (0.5 * 50.6f64.to_radians()).tan();
    CameraModel {
        width_px: 1024,
        height_px: 508,
        intrinsics: hal::sensor::Pinhole { fx_px: f, fy_px: f, cx_px: 511.5, cy_px: 253.5 },
    }
}

/// [`sim_rover_camera`] as the simulator renders it at `downscale` (`sim::camera::StereoCamera::
/// downscaled`): sizes and focal length divided, the principal point kept on the same scene point
/// (`(c + 0.5) / k − 0.5`).
pub fn sim_rover_camera_downscaled(downscale: u32) -> CameraModel {
    let full = sim_rover_camera();
    let k = f64::from(downscale.max(1));
    let i = &full.intrinsics;
    CameraModel {
        width_px: (full.width_px / downscale.max(1)).max(1),
        height_px: (full.height_px / downscale.max(1)).max(1),
        intrinsics: hal::sensor::Pinhole {
            fx_px: i.fx_px / k,
            fy_px: i.fy_px / k,
            cx_px: (i.cx_px + 0.5) / k - 0.5,
            cy_px: (i.cy_px + 0.5) / k - 0.5,
        },
    }
}

/// Why a table could not be built.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LutError {
    #[error("invalid table parameters: {0}")]
    InvalidParams(&'static str),
    #[error("raw table has {got} values, the grid needs {expected}")]
    RawSize { expected: usize, got: usize },
    #[error("no cell of the table was detected: nothing to fill it from")]
    NothingDetected,
    #[error("a generator thread failed")]
    Worker,
}

/// Why bytes are not a table.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum LutDecodeError {
    #[error("{0} bytes are too few for a marker table")]
    TooShort(usize),
    #[error("not a marker table (bad magic)")]
    BadMagic,
    #[error("table format version {0} is not supported (this build reads {LUT_FORMAT_VERSION})")]
    UnsupportedVersion(u32),
    #[error("CRC mismatch: stored {stored:#010x}, computed {computed:#010x} (corrupted file)")]
    Crc { stored: u32, computed: u32 },
    #[error("header: {0}")]
    InvalidHeader(&'static str),
    #[error("the file holds {got} data bytes, its header announces {expected}")]
    DataSize { expected: usize, got: usize },
    #[error("final table value {index} is not a finite non-negative number")]
    InvalidValue { index: usize },
}

/// A table: its parameters, the raw per-cell maxima and the post-processed table.
#[derive(Debug, Clone, PartialEq)]
pub struct MarkerLut {
    params: LutParams,
    raw: Vec<f32>,
    table: Vec<f32>,
}

/// Pose of the tag in cell `(i, j)` (see the module docs).
pub fn cell_truth(grid: &LutGrid, i: usize, j: usize) -> Isometry3<f64> {
    let facing = Matrix3::from_diagonal(&Vector3::new(1.0, -1.0, -1.0));
    let r = Rotation3::from_axis_angle(&Vector3::y_axis(), grid.tilt_rad(j)).into_inner() * facing;
    Isometry3::from_parts(
        Translation3::new(0.0, 0.0, grid.distance_m(i)),
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
    )
}

/// Noise seed of cell `(i, j)`.
pub fn cell_seed(noise_seed: u64, i: usize, j: usize) -> u64 {
    let mut z = noise_seed ^ ((i as u64) << 32 | j as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Per-DOF maximum |error| against `truth` of the PnP poses of `corners_px` and its 256 perturbed
/// sets, with the ambiguity compensation (module docs). `None` if PnP fails on the corners.
pub fn cell_errors(params: &LutParams, truth: &Isometry3<f64>, corners_px: &[[f64; 2]; 4]) -> Option<[f32; DOFS]> {
    let options = params.pnp_options();
    let k = &params.camera.intrinsics;
    let flip = params.flip_threshold_deg.to_radians();
    let mut max = [0.0f64; DOFS];
    let mut accumulate = |corners: &[[f64; 2]; 4]| -> bool {
        let Ok(sol) = solve_square(corners, k, params.tag_size_m, &options) else { return false };
        let mut e = pose_error(&sol.best.t_cam_marker, truth);
        if rotation_norm(&e) > flip
            && let Some(second) = sol.second
        {
            let e2 = pose_error(&second.t_cam_marker, truth);
            if rotation_norm(&e2) < rotation_norm(&e) {
                e = e2;
            }
        }
        for (m, v) in max.iter_mut().zip(e) {
            *m = m.max(v.abs());
        }
        true
    };
    if !accumulate(corners_px) {
        return None;
    }
    for s in 0..SAMPLE_SETS {
        accumulate(&perturbed_corners(corners_px, params.delta_px, s));
    }
    Some(max.map(|v| v as f32))
}

fn rotation_norm(e: &[f64; DOFS]) -> f64 {
    (e[3] * e[3] + e[4] * e[4] + e[5] * e[5]).sqrt()
}

/// Renders cell `(i, j)` into `image` (the camera's size) and returns its raw errors (NaN if the
/// detector finds nothing). The building block of [`generate_lut`], public so that tests can
/// regenerate single cells.
pub fn generate_cell<D>(
    params: &LutParams,
    cells: &TagCells,
    i: usize,
    j: usize,
    detector: &mut D,
    image: &mut [u8],
) -> Result<[f32; DOFS], LutError>
where
    D: FnMut(ImageView<'_>) -> Option<[[f64; 2]; 4]>,
{
    let truth = cell_truth(&params.grid, i, j);
    let seed = cell_seed(params.noise_seed, i, j);
    render_tag(&params.camera, params.tag_size_m, cells, &truth, &params.render, seed, image)
        .map_err(|_| LutError::InvalidParams("renderer rejected the camera or tag"))?;
    let view = ImageView::new(params.camera.width_px as usize, params.camera.height_px as usize, image)
        .ok_or(LutError::InvalidParams("image size"))?;
    Ok(detector(view).and_then(|corners| cell_errors(params, &truth, &corners)).unwrap_or([f32::NAN; DOFS]))
}

/// Generates a table: renders and detects every cell (rows shared among `threads` std threads,
/// each with its own detector from `make_detector`), then post-processes. `progress(done, total)`
/// is called on the calling thread after each finished row.
pub fn generate_lut<F, D>(
    params: &LutParams,
    cells: &TagCells,
    make_detector: F,
    threads: usize,
    progress: impl FnMut(usize, usize),
) -> Result<MarkerLut, LutError>
where
    F: Fn() -> D + Sync,
    D: FnMut(ImageView<'_>) -> Option<[[f64; 2]; 4]>,
{
    check_params(params)?;
    let pixels = params.camera.pixels();
    generate_rows(
        params,
        || {
            let mut detector = make_detector();
            let mut image = vec![0u8; pixels];
            move |i: usize, j: usize| generate_cell(params, cells, i, j, &mut detector, &mut image)
        },
        threads,
        progress,
    )
}

/// [`generate_lut`] without rendering: `make_source()` gives each thread a function from
/// `(i, j, truth)` to the detected corners (exact projections in tests).
pub fn generate_lut_from_corners<F, S>(
    params: &LutParams,
    make_source: F,
    threads: usize,
    progress: impl FnMut(usize, usize),
) -> Result<MarkerLut, LutError>
where
    F: Fn() -> S + Sync,
    S: FnMut(usize, usize, &Isometry3<f64>) -> Option<[[f64; 2]; 4]>,
{
    check_params(params)?;
    generate_rows(
        params,
        || {
            let mut source = make_source();
            move |i: usize, j: usize| {
                let truth = cell_truth(&params.grid, i, j);
                Ok(source(i, j, &truth).and_then(|c| cell_errors(params, &truth, &c)).unwrap_or([f32::NAN; DOFS]))
            }
        },
        threads,
        progress,
    )
}

fn check_params(params: &LutParams) -> Result<(), LutError> {
    if !params.grid.is_valid() {
        return Err(LutError::InvalidParams("grid"));
    }
    if !(params.tag_size_m.is_finite() && params.tag_size_m > 0.0) {
        return Err(LutError::InvalidParams("tag size"));
    }
    if !(params.delta_px.is_finite() && params.delta_px >= 0.0) {
        return Err(LutError::InvalidParams("delta_px"));
    }
    if params.median_kernel == 0 || params.median_kernel.is_multiple_of(2) || params.median_kernel > 15 {
        return Err(LutError::InvalidParams("median kernel must be odd, 1..=15"));
    }
    if !params.flip_threshold_deg.is_finite() || params.detector.len() > MAX_DETECTOR_BYTES {
        return Err(LutError::InvalidParams("flip threshold or detector description"));
    }
    Ok(())
}

fn generate_rows<F, C>(
    params: &LutParams,
    make_cell: F,
    threads: usize,
    mut progress: impl FnMut(usize, usize),
) -> Result<MarkerLut, LutError>
where
    F: Fn() -> C + Sync,
    C: FnMut(usize, usize) -> Result<[f32; DOFS], LutError>,
{
    let (rows, cols) = (params.grid.distances as usize, params.grid.tilts as usize);
    let mut raw = vec![f32::NAN; rows * cols * DOFS];
    let next = AtomicUsize::new(0);
    let (tx, rx) = mpsc::channel::<(usize, Result<Vec<f32>, LutError>)>();
    let mut failure = None;
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            let tx = tx.clone();
            let (next, make_cell) = (&next, &make_cell);
            scope.spawn(move || {
                let mut cell = make_cell();
                loop {
                    let i = next.fetch_add(1, Ordering::Relaxed);
                    if i >= rows {
                        break;
                    }
                    let mut row = Vec::with_capacity(cols * DOFS);
                    let mut result = Ok(());
                    for j in 0..cols {
                        match cell(i, j) {
                            Ok(v) => row.extend_from_slice(&v),
                            Err(e) => {
                                result = Err(e);
                                break;
                            }
                        }
                    }
                    let failed = result.is_err();
                    if tx.send((i, result.map(|()| row))).is_err() || failed {
                        // Stop the other workers too.
                        next.store(rows, Ordering::Relaxed);
                        break;
                    }
                }
            });
        }
        drop(tx);
        let mut done = 0;
        for (i, row) in rx {
            match row {
                Ok(values) => raw[i * cols * DOFS..(i + 1) * cols * DOFS].copy_from_slice(&values),
                Err(e) => failure = Some(e),
            }
            done += 1;
            progress(done, rows);
        }
    });
    if let Some(e) = failure {
        return Err(e);
    }
    MarkerLut::from_raw(params.clone(), raw)
}

/// Median filter of one DOF plane (`rows × cols`, NaN = invalid): each valid cell becomes the
/// upper median of the valid cells in its `kernel × kernel` window; invalid cells stay NaN.
pub fn median_filter(plane: &[f32], rows: usize, cols: usize, kernel: usize) -> Vec<f32> {
    let r = kernel / 2;
    let mut out = plane.to_vec();
    let mut window = Vec::with_capacity(kernel * kernel);
    for i in 0..rows {
        for j in 0..cols {
            if plane[i * cols + j].is_nan() {
                continue;
            }
            window.clear();
            for ii in i.saturating_sub(r)..(i + r + 1).min(rows) {
                for jj in j.saturating_sub(r)..(j + r + 1).min(cols) {
                    let v = plane[ii * cols + jj];
                    if !v.is_nan() {
                        window.push(v);
                    }
                }
            }
            window.sort_by(f32::total_cmp);
            out[i * cols + j] = window[window.len() / 2];
        }
    }
    out
}

/// Fill step 1 (rows): see the module docs.
pub fn fill_rows(plane: &mut [f32], rows: usize, cols: usize) {
    for i in 0..rows {
        let row = &mut plane[i * cols..(i + 1) * cols];
        let valid: Vec<usize> = (0..cols).filter(|&j| !row[j].is_nan()).collect();
        let (Some(&first), Some(&last)) = (valid.first(), valid.last()) else { continue };
        let (head, tail) = (row[first], row[last]);
        row[..first].fill(head);
        row[last + 1..].fill(tail);
        for pair in valid.windows(2) {
            let (a, b) = (pair[0], pair[1]);
            let hole = row[a].max(row[b]);
            row[a + 1..b].fill(hole);
        }
    }
}

/// Fill step 2 (columns): see the module docs.
pub fn fill_columns(plane: &mut [f32], rows: usize, cols: usize) {
    for j in 0..cols {
        let valid: Vec<f32> = (0..rows).map(|i| plane[i * cols + j]).filter(|v| !v.is_nan()).collect();
        if valid.is_empty() {
            continue;
        }
        let last = valid.len().div_ceil(10).max(1);
        let fill = valid[valid.len() - last..].iter().copied().fold(f32::NEG_INFINITY, f32::max);
        for i in 0..rows {
            let v = &mut plane[i * cols + j];
            if v.is_nan() {
                *v = fill;
            }
        }
    }
}

/// Median filter, then both fill steps, DOF by DOF (cell-major input and output).
pub fn post_process(raw: &[f32], rows: usize, cols: usize, kernel: usize) -> Vec<f32> {
    let mut out = vec![f32::NAN; raw.len()];
    for k in 0..DOFS {
        let plane: Vec<f32> = (0..rows * cols).map(|c| raw[c * DOFS + k]).collect();
        let mut plane = median_filter(&plane, rows, cols, kernel);
        fill_rows(&mut plane, rows, cols);
        fill_columns(&mut plane, rows, cols);
        for (c, v) in plane.into_iter().enumerate() {
            out[c * DOFS + k] = v;
        }
    }
    out
}

impl MarkerLut {
    /// A table from its raw cells (post-processed here).
    pub fn from_raw(params: LutParams, raw: Vec<f32>) -> Result<Self, LutError> {
        check_params(&params)?;
        let (rows, cols) = (params.grid.distances as usize, params.grid.tilts as usize);
        if raw.len() != rows * cols * DOFS {
            return Err(LutError::RawSize { expected: rows * cols * DOFS, got: raw.len() });
        }
        if raw.iter().all(|v| v.is_nan()) {
            return Err(LutError::NothingDetected);
        }
        let table = post_process(&raw, rows, cols, params.median_kernel as usize);
        Ok(MarkerLut { params, raw, table })
    }

    pub fn params(&self) -> &LutParams {
        &self.params
    }

    /// Raw per-cell maxima, cell-major (`(i·n_Φ + j)·6 + dof`), NaN where nothing was detected.
    pub fn raw(&self) -> &[f32] {
        &self.raw
    }

    /// The post-processed table, same layout, all finite.
    pub fn table(&self) -> &[f32] {
        &self.table
    }

    pub fn cell(&self, i: usize, j: usize) -> Option<[f32; DOFS]> {
        let at = (i * self.params.grid.tilts as usize + j) * DOFS;
        self.table.get(at..at + DOFS).and_then(|s| s.try_into().ok())
    }

    pub fn raw_cell(&self, i: usize, j: usize) -> Option<[f32; DOFS]> {
        let at = (i * self.params.grid.tilts as usize + j) * DOFS;
        self.raw.get(at..at + DOFS).and_then(|s| s.try_into().ok())
    }

    /// Share of cells with a detection.
    pub fn detected_share(&self) -> f64 {
        let n = self.raw.len() / DOFS;
        (0..n).filter(|c| !self.raw[c * DOFS].is_nan()).count() as f64 / n.max(1) as f64
    }

    /// The six base errors at `(distance_m, tilt_rad)`, bilinear, clamped to the grid.
    pub fn lookup(&self, distance_m: f64, tilt_rad: f64) -> [f64; DOFS] {
        let g = &self.params.grid;
        let (rows, cols) = (g.distances as usize, g.tilts as usize);
        let frac = |v: f64, lo: f64, hi: f64, n: usize| {
            let f = (v - lo) / (hi - lo) * (n as f64 - 1.0);
            if f.is_nan() { 0.0 } else { f.clamp(0.0, n as f64 - 1.0) }
        };
        let fi = frac(distance_m, g.d_min_m, g.d_max_m, rows);
        let fj = frac(tilt_rad.to_degrees(), g.phi_min_deg, g.phi_max_deg, cols);
        let (i0, j0) = ((fi as usize).min(rows - 2), (fj as usize).min(cols - 2));
        let (a, b) = (fi - i0 as f64, fj - j0 as f64);
        let at = |i: usize, j: usize, k: usize| f64::from(self.table[(i * cols + j) * DOFS + k]);
        std::array::from_fn(|k| {
            (1.0 - a) * ((1.0 - b) * at(i0, j0, k) + b * at(i0, j0 + 1, k))
                + a * ((1.0 - b) * at(i0 + 1, j0, k) + b * at(i0 + 1, j0 + 1, k))
        })
    }

    /// The file bytes (see the module docs).
    pub fn encode(&self) -> Vec<u8> {
        let p = &self.params;
        let mut header = Vec::new();
        let c = &p.camera;
        put_u32(&mut header, c.width_px);
        put_u32(&mut header, c.height_px);
        for v in [c.intrinsics.fx_px, c.intrinsics.fy_px, c.intrinsics.cx_px, c.intrinsics.cy_px, p.tag_size_m] {
            put_f64(&mut header, v);
        }
        put_u32(&mut header, p.tag_id);
        put_f64(&mut header, p.delta_px);
        let r = &p.render;
        for v in [r.white_dn, r.black_dn, r.plate_dn, r.background_dn] {
            header.extend_from_slice(&v.to_le_bytes());
        }
        for v in [r.plate_half_per_tag_size, r.blur_sigma_px, r.read_noise_dn, r.full_well_e] {
            put_f64(&mut header, v);
        }
        put_u32(&mut header, r.supersampling);
        header.extend_from_slice(&p.noise_seed.to_le_bytes());
        let g = &p.grid;
        put_u32(&mut header, g.distances);
        put_f64(&mut header, g.d_min_m);
        put_f64(&mut header, g.d_max_m);
        put_u32(&mut header, g.tilts);
        put_f64(&mut header, g.phi_min_deg);
        put_f64(&mut header, g.phi_max_deg);
        put_u32(&mut header, p.median_kernel);
        put_f64(&mut header, p.flip_threshold_deg);
        put_u32(&mut header, p.pnp_refine_iterations);
        put_u32(&mut header, p.detector.len() as u32);
        header.extend_from_slice(p.detector.as_bytes());

        let mut out = Vec::with_capacity(16 + header.len() + 8 * self.raw.len() + 4);
        out.extend_from_slice(&LUT_MAGIC);
        put_u32(&mut out, LUT_FORMAT_VERSION);
        put_u32(&mut out, header.len() as u32);
        out.extend_from_slice(&header);
        for v in self.raw.iter().chain(&self.table) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        let crc = protocol::crc::crc32(&out);
        put_u32(&mut out, crc);
        out
    }

    /// Parses a file (total: see the module docs).
    pub fn decode(bytes: &[u8]) -> Result<Self, LutDecodeError> {
        if bytes.len() < 16 + 4 {
            return Err(LutDecodeError::TooShort(bytes.len()));
        }
        if bytes[..8] != LUT_MAGIC {
            return Err(LutDecodeError::BadMagic);
        }
        let mut head = Reader { bytes: &bytes[8..16], at: 0 };
        let version = head.u32()?;
        if version != LUT_FORMAT_VERSION {
            return Err(LutDecodeError::UnsupportedVersion(version));
        }
        let header_len = head.u32()? as usize;
        let (body, crc_bytes) = bytes.split_at(bytes.len() - 4);
        let stored = u32::from_le_bytes([crc_bytes[0], crc_bytes[1], crc_bytes[2], crc_bytes[3]]);
        let computed = protocol::crc::crc32(body);
        if stored != computed {
            return Err(LutDecodeError::Crc { stored, computed });
        }
        let rest = &body[16..];
        if header_len > rest.len() {
            return Err(LutDecodeError::InvalidHeader("header length beyond the file"));
        }
        let (header, data) = rest.split_at(header_len);
        let mut r = Reader { bytes: header, at: 0 };
        let width_px = r.u32()?;
        let height_px = r.u32()?;
        let (fx_px, fy_px, cx_px, cy_px) = (r.f64()?, r.f64()?, r.f64()?, r.f64()?);
        let tag_size_m = r.f64()?;
        let tag_id = r.u32()?;
        let delta_px = r.f64()?;
        let (white_dn, black_dn, plate_dn, background_dn) = (r.f32()?, r.f32()?, r.f32()?, r.f32()?);
        let (plate_half_per_tag_size, blur_sigma_px, read_noise_dn, full_well_e) =
            (r.f64()?, r.f64()?, r.f64()?, r.f64()?);
        let supersampling = r.u32()?;
        let noise_seed = r.u64()?;
        let grid = LutGrid {
            distances: r.u32()?,
            d_min_m: r.f64()?,
            d_max_m: r.f64()?,
            tilts: r.u32()?,
            phi_min_deg: r.f64()?,
            phi_max_deg: r.f64()?,
        };
        let median_kernel = r.u32()?;
        let flip_threshold_deg = r.f64()?;
        let pnp_refine_iterations = r.u32()?;
        let detector_len = r.u32()? as usize;
        if detector_len > MAX_DETECTOR_BYTES {
            return Err(LutDecodeError::InvalidHeader("detector description too long"));
        }
        let detector = std::str::from_utf8(r.take(detector_len)?)
            .map_err(|_| LutDecodeError::InvalidHeader("detector description is not UTF-8"))?
            .to_owned();
        if r.at != header.len() {
            return Err(LutDecodeError::InvalidHeader("header length does not match its fields"));
        }
        if !grid.is_valid() {
            return Err(LutDecodeError::InvalidHeader("grid"));
        }
        let camera_ok = width_px > 0
            && height_px > 0
            && [fx_px, fy_px].iter().all(|v| v.is_finite() && *v > 0.0)
            && [cx_px, cy_px].iter().all(|v| v.is_finite());
        if !camera_ok {
            return Err(LutDecodeError::InvalidHeader("camera"));
        }
        let params = LutParams {
            camera: CameraModel {
                width_px,
                height_px,
                intrinsics: hal::sensor::Pinhole { fx_px, fy_px, cx_px, cy_px },
            },
            tag_size_m,
            tag_id,
            delta_px,
            render: RenderConfig {
                white_dn,
                black_dn,
                plate_dn,
                background_dn,
                plate_half_per_tag_size,
                blur_sigma_px,
                read_noise_dn,
                full_well_e,
                supersampling,
            },
            noise_seed,
            grid,
            median_kernel,
            flip_threshold_deg,
            pnp_refine_iterations,
            detector,
        };
        check_params(&params).map_err(|e| match e {
            LutError::InvalidParams(what) => LutDecodeError::InvalidHeader(what),
            _ => LutDecodeError::InvalidHeader("parameters"),
        })?;
        let n = grid.cells() * DOFS;
        if data.len() != 2 * n * 4 {
            return Err(LutDecodeError::DataSize { expected: 2 * n * 4, got: data.len() });
        }
        let floats: Vec<f32> = data.chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        let (raw, table) = floats.split_at(n);
        if let Some(index) = table.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err(LutDecodeError::InvalidValue { index });
        }
        Ok(MarkerLut { params, raw: raw.to_vec(), table: table.to_vec() })
    }
}

fn put_u32(out: &mut Vec<u8>, v: u32) {
    out.extend_from_slice(&v.to_le_bytes());
}

fn put_f64(out: &mut Vec<u8>, v: f64) {
    out.extend_from_slice(&v.to_le_bytes());
}

struct Reader<'a> {
    bytes: &'a [u8],
    at: usize,
}

impl<'a> Reader<'a> {
    fn take(&mut self, n: usize) -> Result<&'a [u8], LutDecodeError> {
        let end = self.at.checked_add(n).filter(|&e| e <= self.bytes.len());
        let end = end.ok_or(LutDecodeError::InvalidHeader("header ends inside a field"))?;
        let s = &self.bytes[self.at..end];
        self.at = end;
        Ok(s)
    }
    fn array<const N: usize>(&mut self) -> Result<[u8; N], LutDecodeError> {
        self.take(N)?.try_into().map_err(|_| LutDecodeError::InvalidHeader("header ends inside a field"))
    }
    fn u32(&mut self) -> Result<u32, LutDecodeError> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    fn u64(&mut self) -> Result<u64, LutDecodeError> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    fn f32(&mut self) -> Result<f32, LutDecodeError> {
        Ok(f32::from_le_bytes(self.array()?))
    }
    fn f64(&mut self) -> Result<f64, LutDecodeError> {
        Ok(f64::from_le_bytes(self.array()?))
    }
}

/// How a table header names the AprilTag detector: its type, family and configuration.
pub fn apriltag_description(config: &TagDetectorConfig) -> String {
    format!("vision::apriltag::TagDetector tag36h11 {config:?}")
}

/// The corners of the first detection of `tag_id` in `image` (AprilTag corner order): the corner
/// detector of the `marker-lut` command.
pub fn apriltag_corners(detector: &mut TagDetector, image: ImageView<'_>, tag_id: u32) -> Option<[[f64; 2]; 4]> {
    detector.detect(image).iter().find(|d| d.id == tag_id).map(|d| d.corners_px)
}

/// The `marker-lut` command's defaults: [`LutParams::command_defaults`] for the simulator's rover
/// camera at full resolution ([`sim_rover_camera`]), a 16 cm tag, the 200 × 200 grid and the
/// detector's default configuration.
pub fn default_command_params() -> LutParams {
    LutParams::command_defaults(sim_rover_camera(), 0.16, 200, apriltag_description(&TagDetectorConfig::default()))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    const N: f32 = f32::NAN;

    fn same(a: &[f32], b: &[f32]) -> bool {
        a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits() || (x.is_nan() && y.is_nan()))
    }

    #[test]
    fn median_filter_uses_valid_cells_only_and_keeps_holes() {
        #[rustfmt::skip]
        let plane = [
            1.0, 2.0, 3.0, N,
            4.0, 100.0, 6.0, N,
            7.0, 8.0, N, N,
        ];
        let out = median_filter(&plane, 3, 4, 3);
        #[rustfmt::skip]
        let expected = [
            // (0,0): {1,2,4,100} → upper median 4; (0,1): {1,2,3,4,100,6} → 4;
            // (0,2): {2,3,100,6} → 6; (1,0): {1,2,4,100,7,8} → 7; (1,1): all 8 valid → 6;
            // (1,2): {2,3,100,6,8} → 6; (2,0): {4,100,7,8} → 8; (2,1): {4,100,6,7,8} → 7.
            4.0, 4.0, 6.0, N,
            7.0, 6.0, 6.0, N,
            8.0, 7.0, N, N,
        ];
        assert!(same(&out, &expected), "{out:?}");
    }

    #[test]
    fn rows_fill_from_their_borders_and_holes_take_the_larger_neighbour() {
        #[rustfmt::skip]
        let mut plane = [
            N, 2.0, N, N, 5.0, N,
            N, N, N, N, N, N,
            1.0, N, 3.0, N, N, N,
        ];
        fill_rows(&mut plane, 3, 6);
        #[rustfmt::skip]
        let expected = [
            2.0, 2.0, 5.0, 5.0, 5.0, 5.0,
            N, N, N, N, N, N,
            1.0, 3.0, 3.0, 3.0, 3.0, 3.0,
        ];
        assert!(same(&plane, &expected), "{plane:?}");
    }

    #[test]
    fn columns_fill_with_the_max_of_their_last_ten_percent() {
        // One column of 25 rows: 21 valid values 1..=21 in rows 2..=22, NaN elsewhere. The final
        // 10 % of 21 values is 3 values (rounded up): 19, 20, 21 → 21 fills rows 0, 1, 23, 24.
        let mut plane = vec![N; 25];
        for (k, v) in plane[2..23].iter_mut().enumerate() {
            *v = (k + 1) as f32;
        }
        plane[10] = 50.0; // a large value early in the column does not count
        fill_columns(&mut plane, 25, 1);
        assert_eq!([plane[0], plane[1], plane[23], plane[24]], [21.0; 4]);
        assert_eq!(plane[10], 50.0);
        // Fewer than ten valid values: the last one alone.
        let mut short = [N, 4.0, 3.0, N];
        fill_columns(&mut short, 4, 1);
        assert_eq!(short, [3.0, 4.0, 3.0, 3.0]);
    }
}
