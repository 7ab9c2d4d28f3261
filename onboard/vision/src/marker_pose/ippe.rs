//! Pose of a square tag from its four image corners: IPPE (Collins & Bartoli 2014,
//! "Infinitesimal Plane-based Pose Estimation"), both planar solutions, each optionally refined by
//! Levenberg-Marquardt on the reprojection error.
//!
//! IPPE, as in OpenCV's `SOLVEPNP_IPPE_SQUARE` (and checked against it in
//! `tests/marker_pose.rs`): the homography `H` from the tag plane (metres) to normalised image
//! coordinates is exact for four corners (Heckbert's square-to-quad mapping, no linear solve); its
//! Jacobian `J` at the tag centre and the centre's image `v` give the two rotations in closed form
//! (the 2 × 2 block `A = B⁻¹J / γ` of the rotation seen through `Rv`, completed to a rotation in
//! the two ways the plane allows), and each rotation's translation is the linear least-squares
//! solution of the projection equations. With exact corners both steps are exact and the best
//! solution is the true pose; with noisy corners IPPE is close to, but not at, the reprojection
//! minimum, which the optional refinement reaches (4 corners = 8 residuals, 6 unknowns).
//!
//! Reprojection RMS is OpenCV's: `sqrt(Σ‖û − u‖² / (2·4))`, i.e. per image coordinate.
//!
//! Corner order (the AprilTag library's): in the tag frame (x right, y up, z out of the face, `s`
//! the edge of the black square) corner `k` is `(−s/2, −s/2)`, `(s/2, −s/2)`, `(s/2, s/2)`,
//! `(−s/2, s/2)`. A tag is only ever seen from the front, so its corners always wind
//! counter-clockwise as seen on the screen (negative signed area with y down); the mirrored order,
//! a degenerate (collinear) quad, non-finite input or a pose behind the camera is an error.

use hal::sensor::Pinhole;
use nalgebra::{
    Isometry3, Matrix2, Matrix3, Matrix6, Point3, Rotation3, Translation3, UnitQuaternion, Vector3, Vector6,
};

/// Corners closer to the camera plane than this (metres) make a pose invalid.
const MIN_DEPTH_M: f64 = 1e-6;

/// Why a square-tag pose could not be computed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum PnpError {
    #[error("a corner, an intrinsic parameter or the tag size is not finite")]
    NonFinite,
    #[error("focal lengths and the tag size must be positive")]
    InvalidParameters,
    #[error("the corners do not form a strictly convex quadrilateral (collinear or crossing corners)")]
    Degenerate,
    #[error("the corners wind clockwise on screen: the back of the tag, or corners in the wrong order")]
    BackFacing,
    #[error("no pose puts all four corners in front of the camera")]
    BehindCamera,
}

/// Options of [`solve_square`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpOptions {
    /// Levenberg-Marquardt iterations on each IPPE solution (0: plain IPPE, as OpenCV's).
    pub refine_iterations: u32,
}

impl Default for PnpOptions {
    /// Plain IPPE: refinement changes the pose by a small fraction of its error (measured in
    /// `tests/marker_pose.rs`) at about three times the cost, so the online sampling and the
    /// table use IPPE's own solutions.
    fn default() -> Self {
        PnpOptions { refine_iterations: 0 }
    }
}

/// One pose hypothesis with its reprojection RMS (pixels, per coordinate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PnpSolution {
    pub t_cam_marker: Isometry3<f64>,
    pub rms_px: f64,
}

/// Both planar solutions, best (lowest reprojection RMS) first.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SquarePnp {
    pub best: PnpSolution,
    /// The other IPPE solution; `None` if it puts a corner behind the camera.
    pub second: Option<PnpSolution>,
    /// `second.rms_px / best.rms_px` (≥ 1): near 1 the two are indistinguishable (the planar
    /// ambiguity); `INFINITY` without a second solution or when only the best one is exact.
    pub ratio: f64,
}

/// The tag's corners in its own frame (see the module docs).
pub fn tag_corners_marker(tag_size_m: f64) -> [Vector3<f64>; 4] {
    let h = 0.5 * tag_size_m;
    [Vector3::new(-h, -h, 0.0), Vector3::new(h, -h, 0.0), Vector3::new(h, h, 0.0), Vector3::new(-h, h, 0.0)]
}

/// Pixel of a point in the camera frame; `None` at or behind the camera plane.
#[inline]
pub fn project(intrinsics: &Pinhole, p_cam: &Vector3<f64>) -> Option<[f64; 2]> {
    (p_cam.z > MIN_DEPTH_M).then(|| {
        [
            intrinsics.fx_px * p_cam.x / p_cam.z + intrinsics.cx_px,
            intrinsics.fy_px * p_cam.y / p_cam.z + intrinsics.cy_px,
        ]
    })
}

/// The four corners of a tag of edge `tag_size_m` at `t_cam_marker`, in pixels.
pub fn project_corners(intrinsics: &Pinhole, tag_size_m: f64, t_cam_marker: &Isometry3<f64>) -> Option<[[f64; 2]; 4]> {
    let c = tag_corners_marker(tag_size_m);
    let mut out = [[0.0; 2]; 4];
    for (o, p) in out.iter_mut().zip(&c) {
        *o = project(intrinsics, &(t_cam_marker * Point3::from(*p)).coords)?;
    }
    Some(out)
}

/// Reprojection RMS (pixels, per coordinate) of a pose; `None` if a corner is behind the camera.
pub fn reprojection_rms_px(
    corners_px: &[[f64; 2]; 4],
    intrinsics: &Pinhole,
    tag_size_m: f64,
    t_cam_marker: &Isometry3<f64>,
) -> Option<f64> {
    let predicted = project_corners(intrinsics, tag_size_m, t_cam_marker)?;
    let sum: f64 = predicted.iter().zip(corners_px).map(|(p, q)| (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sum();
    Some((sum / 8.0).sqrt())
}

/// Both IPPE solutions for a square tag (see the module docs), refined if `options` ask for it.
pub fn solve_square(
    corners_px: &[[f64; 2]; 4],
    intrinsics: &Pinhole,
    tag_size_m: f64,
    options: &PnpOptions,
) -> Result<SquarePnp, PnpError> {
    let Pinhole { fx_px, fy_px, cx_px, cy_px } = *intrinsics;
    let finite = [fx_px, fy_px, cx_px, cy_px, tag_size_m].iter().all(|v| v.is_finite())
        && corners_px.iter().flatten().all(|v| v.is_finite());
    if !finite {
        return Err(PnpError::NonFinite);
    }
    if fx_px <= 0.0 || fy_px <= 0.0 || tag_size_m <= 0.0 {
        return Err(PnpError::InvalidParameters);
    }
    check_winding(corners_px)?;
    let normalised = corners_px.map(|[u, v]| [(u - cx_px) / fx_px, (v - cy_px) / fy_px]);
    let h = homography_from_square(&normalised, tag_size_m).ok_or(PnpError::Degenerate)?;
    let (r1, r2) = ippe_rotations(&h).ok_or(PnpError::Degenerate)?;
    let model = tag_corners_marker(tag_size_m);
    let mut solutions: [Option<PnpSolution>; 2] = [None, None];
    for (slot, r) in solutions.iter_mut().zip([r1, r2]) {
        let Some(t) = translation_for(&r, &model, &normalised) else { continue };
        let mut pose = Isometry3::from_parts(
            Translation3::from(t),
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r)),
        );
        if options.refine_iterations > 0 {
            pose = refine(corners_px, intrinsics, &model, &pose, options.refine_iterations);
        }
        if let Some(rms_px) = reprojection_rms_px(corners_px, intrinsics, tag_size_m, &pose) {
            *slot = Some(PnpSolution { t_cam_marker: pose, rms_px });
        }
    }
    let (best, second) = match solutions {
        [Some(a), Some(b)] => {
            if b.rms_px < a.rms_px {
                (b, Some(a))
            } else {
                (a, Some(b))
            }
        }
        [Some(a), None] | [None, Some(a)] => (a, None),
        [None, None] => return Err(PnpError::BehindCamera),
    };
    let ratio = match second {
        Some(s) if best.rms_px > 0.0 => s.rms_px / best.rms_px,
        Some(s) if s.rms_px == 0.0 => 1.0,
        _ => f64::INFINITY,
    };
    Ok(SquarePnp { best, second, ratio })
}

/// The corners must form a strictly convex quadrilateral winding counter-clockwise on screen
/// (every turn's cross product negative in pixel coordinates with y down).
fn check_winding(c: &[[f64; 2]; 4]) -> Result<(), PnpError> {
    let scale = c.iter().flat_map(|p| p.iter()).fold(1.0f64, |m, v| m.max(v.abs()));
    let mut negative = 0;
    let mut positive = 0;
    for k in 0..4 {
        let (a, b, d) = (c[k], c[(k + 1) % 4], c[(k + 2) % 4]);
        let cross = (b[0] - a[0]) * (d[1] - b[1]) - (b[1] - a[1]) * (d[0] - b[0]);
        // Relative to the coordinates' magnitude: rounding cannot make a straight line turn.
        if cross < -1e-12 * scale * scale {
            negative += 1;
        } else if cross > 1e-12 * scale * scale {
            positive += 1;
        }
    }
    match (negative, positive) {
        (4, 0) => Ok(()),
        (0, 4) => Err(PnpError::BackFacing),
        _ => Err(PnpError::Degenerate),
    }
}

/// Homography from the tag plane (metres, corners as [`tag_corners_marker`]) to the given
/// points, normalised so that `H[(2, 2)] = 1` (the image of the tag centre is then
/// `(H[(0, 2)], H[(1, 2)])`). Heckbert's closed form for the unit square, composed with the
/// plane's scaling. `None` when three corners are collinear.
pub fn homography_from_square(p: &[[f64; 2]; 4], tag_size_m: f64) -> Option<Matrix3<f64>> {
    let [[x0, y0], [x1, y1], [x2, y2], [x3, y3]] = *p;
    let (sx, sy) = (x0 - x1 + x2 - x3, y0 - y1 + y2 - y3);
    let (dx1, dx2, dy1, dy2) = (x1 - x2, x3 - x2, y1 - y2, y3 - y2);
    let den = dx1 * dy2 - dx2 * dy1;
    if den.abs() < 1e-300 || !den.is_finite() {
        return None;
    }
    let g = (sx * dy2 - dx2 * sy) / den;
    let h = (dx1 * sy - sx * dy1) / den;
    // Unit square (0,0) (1,0) (1,1) (0,1) to the corners.
    let unit = Matrix3::new(x1 - x0 + g * x1, x3 - x0 + h * x3, x0, y1 - y0 + g * y1, y3 - y0 + h * y3, y0, g, h, 1.0);
    // Tag plane to unit square: u = x/s + 1/2, v = y/s + 1/2.
    let inv_s = 1.0 / tag_size_m;
    let scale = Matrix3::new(inv_s, 0.0, 0.5, 0.0, inv_s, 0.5, 0.0, 0.0, 1.0);
    let hm = unit * scale;
    let w = hm[(2, 2)];
    (w.abs() > 1e-300 && hm.iter().all(|v| v.is_finite())).then(|| hm / w)
}

/// IPPE's two rotations from a plane-to-normalised-image homography with `H[(2, 2)] = 1`
/// (Collins & Bartoli 2014, Algorithm 1). `None` if the homography is degenerate.
fn ippe_rotations(h: &Matrix3<f64>) -> Option<(Matrix3<f64>, Matrix3<f64>)> {
    let (v0, v1) = (h[(0, 2)], h[(1, 2)]);
    // Jacobian of the plane-to-image map at the plane's origin.
    let j = Matrix2::new(
        h[(0, 0)] - h[(2, 0)] * v0,
        h[(0, 1)] - h[(2, 1)] * v0,
        h[(1, 0)] - h[(2, 0)] * v1,
        h[(1, 1)] - h[(2, 1)] * v1,
    );
    // Rv: the rotation taking the optical axis onto the ray through the origin's image.
    let rv = rotation_z_to(&Vector3::new(v0, v1, 1.0));
    // B = [I₂ | −v] · Rv[:, 0..2].
    let mut b = Matrix2::zeros();
    for r in 0..2 {
        let vr = if r == 0 { v0 } else { v1 };
        for c in 0..2 {
            b[(r, c)] = rv[(r, c)] - vr * rv[(2, c)];
        }
    }
    let a = b.try_inverse()? * j;
    // Largest singular value of A.
    let ata00 = a[(0, 0)] * a[(0, 0)] + a[(1, 0)] * a[(1, 0)];
    let ata01 = a[(0, 0)] * a[(0, 1)] + a[(1, 0)] * a[(1, 1)];
    let ata11 = a[(0, 1)] * a[(0, 1)] + a[(1, 1)] * a[(1, 1)];
    let gamma2 = 0.5 * (ata00 + ata11 + ((ata00 - ata11).powi(2) + 4.0 * ata01 * ata01).sqrt());
    if gamma2.is_nan() || gamma2 <= 1e-300 || !gamma2.is_finite() {
        return None;
    }
    let r22 = a / gamma2.sqrt();
    // Complete the first two columns (r22's columns over (c0, c1)) to orthonormal vectors.
    let b0 = (1.0 - r22[(0, 0)].powi(2) - r22[(1, 0)].powi(2)).max(0.0);
    let b1 = -(r22[(0, 0)] * r22[(0, 1)] + r22[(1, 0)] * r22[(1, 1)]);
    let b2 = (1.0 - r22[(0, 1)].powi(2) - r22[(1, 1)].powi(2)).max(0.0);
    let (c0, c1) = (b0.sqrt(), if b1 >= 0.0 { b2.sqrt() } else { -b2.sqrt() });
    let complete = |sign: f64| {
        let x = Vector3::new(r22[(0, 0)], r22[(1, 0)], sign * c0);
        let y = Vector3::new(r22[(0, 1)], r22[(1, 1)], sign * c1);
        let z = x.cross(&y);
        rv * Matrix3::from_columns(&[x, y, z])
    };
    Some((complete(1.0), complete(-1.0)))
}

/// The rotation about the axis `z × d` taking `z` onto `d / |d|` (identity if `d` is along `z`).
fn rotation_z_to(d: &Vector3<f64>) -> Matrix3<f64> {
    let n = d.norm();
    let axis = Vector3::new(-d.y, d.x, 0.0);
    let s = axis.norm() / n;
    let c = d.z / n;
    if axis.norm() < 1e-300 {
        return Matrix3::identity();
    }
    let k = axis / axis.norm();
    let kx = k.cross_matrix();
    Matrix3::identity() + kx * s + kx * kx * (1.0 - c)
}

/// Least-squares translation of rotation `r` for normalised image points: each corner gives
/// `(Rp + t)_x − x·(Rp + t)_z = 0` and the same for y, linear in `t`.
fn translation_for(r: &Matrix3<f64>, model: &[Vector3<f64>; 4], normalised: &[[f64; 2]; 4]) -> Option<Vector3<f64>> {
    let mut ata = Matrix3::zeros();
    let mut atb = Vector3::zeros();
    for (p, &[x, y]) in model.iter().zip(normalised) {
        let rp = r * p;
        for (row, rhs) in [(Vector3::new(1.0, 0.0, -x), x * rp.z - rp.x), (Vector3::new(0.0, 1.0, -y), y * rp.z - rp.y)]
        {
            ata += row * row.transpose();
            atb += row * rhs;
        }
    }
    let t = ata.try_inverse()? * atb;
    t.iter().all(|v| v.is_finite()).then_some(t)
}

/// Levenberg-Marquardt on the 8 reprojection residuals. Perturbation: `t ← t + δt`,
/// `R ← Exp(δθ)·R` (both in the camera frame; the rotation acts about the tag centre).
fn refine(
    corners_px: &[[f64; 2]; 4],
    intrinsics: &Pinhole,
    model: &[Vector3<f64>; 4],
    start: &Isometry3<f64>,
    iterations: u32,
) -> Isometry3<f64> {
    let cost_and_normal = |pose: &Isometry3<f64>| -> Option<(f64, Matrix6<f64>, Vector6<f64>)> {
        let r = pose.rotation.to_rotation_matrix().into_inner();
        let t = pose.translation.vector;
        let (mut cost, mut h, mut g) = (0.0, Matrix6::zeros(), Vector6::zeros());
        for (p, q) in model.iter().zip(corners_px) {
            let rp = r * p;
            let pc = rp + t;
            if pc.z <= MIN_DEPTH_M {
                return None;
            }
            let inv_z = 1.0 / pc.z;
            let (fx, fy) = (intrinsics.fx_px, intrinsics.fy_px);
            let res = [fx * pc.x * inv_z + intrinsics.cx_px - q[0], fy * pc.y * inv_z + intrinsics.cy_px - q[1]];
            let dproj = [
                Vector3::new(fx * inv_z, 0.0, -fx * pc.x * inv_z * inv_z),
                Vector3::new(0.0, fy * inv_z, -fy * pc.y * inv_z * inv_z),
            ];
            // ∂pc/∂δt = I, ∂pc/∂δθ = −[Rp]×.
            let rpx = rp.cross_matrix();
            for (row, &e) in dproj.iter().zip(&res) {
                let jr = -(row.transpose() * rpx);
                let jac = Vector6::new(row.x, row.y, row.z, jr[0], jr[1], jr[2]);
                h += jac * jac.transpose();
                g += jac * e;
                cost += e * e;
            }
        }
        Some((cost, h, g))
    };
    let mut pose = *start;
    let Some((mut cost, mut h, mut g)) = cost_and_normal(&pose) else { return pose };
    let mut lambda = 1e-6;
    for _ in 0..iterations {
        if cost < 1e-24 {
            break;
        }
        let mut damped = h;
        for i in 0..6 {
            damped[(i, i)] += lambda * h[(i, i)].max(1e-12);
        }
        let Some(delta) = damped.cholesky().map(|c| c.solve(&(-g))) else { break };
        let rotation = Rotation3::new(Vector3::new(delta[3], delta[4], delta[5]));
        let candidate = Isometry3::from_parts(
            Translation3::from(pose.translation.vector + Vector3::new(delta[0], delta[1], delta[2])),
            UnitQuaternion::from_rotation_matrix(&rotation) * pose.rotation,
        );
        match cost_and_normal(&candidate) {
            Some((c, hc, gc)) if c < cost => {
                let converged = cost - c < 1e-12 * cost;
                (pose, cost, h, g) = (candidate, c, hc, gc);
                lambda = (lambda * 0.1).max(1e-12);
                if converged {
                    break;
                }
            }
            _ => lambda *= 10.0,
        }
    }
    pose
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    fn cam() -> Pinhole {
        Pinhole { fx_px: 1083.0, fy_px: 1079.0, cx_px: 511.5, cy_px: 253.5 }
    }

    #[test]
    fn exact_corners_give_the_true_pose() {
        let truth = Isometry3::new(Vector3::new(0.3, -0.2, 2.5), Vector3::new(0.2, 3.0, 0.1));
        let corners = project_corners(&cam(), 0.16, &truth).unwrap();
        let sol = solve_square(&corners, &cam(), 0.16, &PnpOptions::default()).unwrap();
        let dt = (sol.best.t_cam_marker.translation.vector - truth.translation.vector).norm();
        let dr = (sol.best.t_cam_marker.rotation * truth.rotation.inverse()).angle();
        assert!(dt < 1e-9 && dr < 1e-9, "{dt} {dr}");
        assert!(sol.best.rms_px < 1e-9);
        assert!(sol.ratio > 1e3);
    }

    #[test]
    fn mirrored_and_collinear_corners_are_errors() {
        let truth = Isometry3::new(Vector3::new(0.0, 0.0, 2.0), Vector3::new(0.0, std::f64::consts::PI, 0.0));
        let c = project_corners(&cam(), 0.16, &truth).unwrap();
        assert_eq!(
            solve_square(&[c[3], c[2], c[1], c[0]], &cam(), 0.16, &PnpOptions::default()),
            Err(PnpError::BackFacing)
        );
        let line = [[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [3.0, 3.0]];
        assert_eq!(solve_square(&line, &cam(), 0.16, &PnpOptions::default()), Err(PnpError::Degenerate));
        let nan = [[f64::NAN, 0.0], c[1], c[2], c[3]];
        assert_eq!(solve_square(&nan, &cam(), 0.16, &PnpOptions::default()), Err(PnpError::NonFinite));
    }
}
