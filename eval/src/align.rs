//! Spatial alignment of an estimate to ground truth before computing errors.
//!
//! An estimate lives in its own world frame (where the robot started, with whatever heading), so
//! absolute errors only mean something after the estimate is mapped into the ground truth's frame.
//! What may be fitted decides what the error hides:
//!
//! | method | fitted | use |
//! |---|---|---|
//! | [`Alignment::Se3`] | rotation, translation | evo's `--align`: best case over the whole run |
//! | [`Alignment::Sim3`] | + scale | evo's `--align --correct_scale`: monocular estimates |
//! | [`Alignment::Scale`] | scale only | evo's `--correct_scale` without `--align` |
//! | [`Alignment::FourDof`] | x, y, z, yaw | visual-inertial estimates: gravity fixes roll and pitch, so fitting them would hide tilt errors |
//! | [`Alignment::Se2`] | x, y, yaw | planar ground truth; errors are then taken in the plane |
//! | [`Alignment::FirstMetres`] | SE(3) or 4-DoF on the first N metres | thesis §7.4: fit on the start of the run, so later drift stays visible |
//!
//! The SE(3) / Sim(3) fit is evo's `umeyama_alignment` (evo 1.38.1, `evo/core/geometry.py`)
//! step for step: the same covariance, the same rank test, the same sign correction of the
//! smallest singular direction, so aligned errors agree with evo to rounding.

use core::fmt;
use core::str::FromStr;

use nalgebra::{DMatrix, Isometry3, Matrix3, Rotation3, Translation3, UnitQuaternion, Vector3};

/// A similarity transform taking estimate poses into the ground truth's frame:
/// `aligned = t_gt_est · (scale · translation, rotation)` of the estimate pose, i.e. the estimate's
/// positions are scaled about its world origin, then rotated and translated (evo's
/// `scale(s)` followed by `transform(se3(r, t))`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Sim3 {
    pub scale: f64,
    pub t_gt_est: Isometry3<f64>,
}

impl Default for Sim3 {
    fn default() -> Self {
        Self::identity()
    }
}

impl Sim3 {
    pub fn identity() -> Self {
        Self { scale: 1.0, t_gt_est: Isometry3::identity() }
    }

    /// Maps an estimate pose `t_est_body` to `t_gt_body`.
    pub fn apply(&self, t_est_body: &Isometry3<f64>) -> Isometry3<f64> {
        let scaled =
            Isometry3::from_parts(Translation3::from(t_est_body.translation.vector * self.scale), t_est_body.rotation);
        self.t_gt_est * scaled
    }

    pub fn apply_all(&self, poses: &[Isometry3<f64>]) -> Vec<Isometry3<f64>> {
        poses.iter().map(|p| self.apply(p)).collect()
    }
}

/// The model fitted on the first metres of the path.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FirstMetresModel {
    Se3,
    FourDof,
}

/// How to align the estimate to the ground truth.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum Alignment {
    #[default]
    None,
    Se3,
    Sim3,
    Scale,
    FourDof,
    Se2,
    /// Fit `model` on the pairs whose ground-truth path distance from the first pair is at most
    /// `distance_m`, and apply it to the whole trajectory.
    FirstMetres {
        distance_m: f64,
        model: FirstMetresModel,
    },
}

impl fmt::Display for Alignment {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::None => f.write_str("none"),
            Self::Se3 => f.write_str("se3"),
            Self::Sim3 => f.write_str("sim3"),
            Self::Scale => f.write_str("scale"),
            Self::FourDof => f.write_str("4dof"),
            Self::Se2 => f.write_str("se2"),
            Self::FirstMetres { distance_m, model: FirstMetresModel::Se3 } => write!(f, "first:{distance_m}m"),
            Self::FirstMetres { distance_m, model: FirstMetresModel::FourDof } => write!(f, "first:{distance_m}m:4dof"),
        }
    }
}

/// An alignment name that is none of those [`Alignment::from_str`] knows.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown alignment `{0}` (expected none, se3, sim3, scale, 4dof, se2, first:<N>m or first:<N>m:4dof)")]
pub struct UnknownAlignment(pub String);

impl FromStr for Alignment {
    type Err = UnknownAlignment;

    /// Parses `none`, `se3`, `sim3`, `scale`, `4dof`, `se2`, `first:4m` (SE(3) on the first 4 m)
    /// or `first:4m:4dof`.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let unknown = || UnknownAlignment(text.chars().take(40).collect());
        match text {
            "none" => return Ok(Self::None),
            "se3" => return Ok(Self::Se3),
            "sim3" => return Ok(Self::Sim3),
            "scale" => return Ok(Self::Scale),
            "4dof" => return Ok(Self::FourDof),
            "se2" => return Ok(Self::Se2),
            _ => {}
        }
        let rest = text.strip_prefix("first:").ok_or_else(unknown)?;
        let (distance, model) = match rest.split_once(':') {
            None => (rest, FirstMetresModel::Se3),
            Some((distance, "4dof")) => (distance, FirstMetresModel::FourDof),
            Some((distance, "se3")) => (distance, FirstMetresModel::Se3),
            Some(_) => return Err(unknown()),
        };
        let distance_m: f64 = distance.strip_suffix('m').unwrap_or(distance).parse().map_err(|_| unknown())?;
        if !(distance_m.is_finite() && distance_m > 0.0) {
            return Err(unknown());
        }
        Ok(Self::FirstMetres { distance_m, model })
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    #[error("{found} pose pairs, at least {needed} needed to fit the alignment")]
    TooFewPairs { found: usize, needed: usize },
    #[error("estimate and ground truth have different numbers of poses ({est} vs {gt})")]
    LengthMismatch { est: usize, gt: usize },
    #[error("degenerate point configuration (collinear or coincident positions): the alignment is not determined")]
    Degenerate,
    #[error("positions are not finite or too large to fit an alignment")]
    NonFinite,
}

/// evo's `umeyama_alignment(x = est, y = gt, with_scale)`: the similarity minimizing
/// Σ |gt_i − (c R est_i + t)|² (c = 1 without scale).
pub fn umeyama(est: &[Vector3<f64>], gt: &[Vector3<f64>], with_scale: bool) -> Result<Sim3, AlignError> {
    if est.len() != gt.len() {
        return Err(AlignError::LengthMismatch { est: est.len(), gt: gt.len() });
    }
    if est.is_empty() {
        return Err(AlignError::TooFewPairs { found: 0, needed: 3 });
    }
    let n = est.len() as f64;
    let mean_x = est.iter().sum::<Vector3<f64>>() / n;
    let mean_y = gt.iter().sum::<Vector3<f64>>() / n;
    let sigma_x = est.iter().map(|x| (x - mean_x).norm_squared()).sum::<f64>() / n;
    let mut outer_sum = Matrix3::zeros();
    for (x, y) in est.iter().zip(gt) {
        outer_sum += (y - mean_y) * (x - mean_x).transpose();
    }
    let cov_xy = outer_sum / n;
    if !(cov_xy.iter().all(|v| v.is_finite()) && sigma_x.is_finite() && mean_y.iter().all(|v| v.is_finite())) {
        return Err(AlignError::NonFinite);
    }
    // The general (Golub–Kahan) SVD: nalgebra's 3×3 special case goes through the eigenvectors of
    // CᵀC, which squares the condition number.
    let svd =
        nalgebra::SVD::try_new(DMatrix::from_column_slice(3, 3, cov_xy.as_slice()), true, true, f64::EPSILON, 1000)
            .ok_or(AlignError::NonFinite)?;
    let (Some(u), Some(v_t)) = (&svd.u, &svd.v_t) else {
        return Err(AlignError::NonFinite);
    };
    let u = Matrix3::from_column_slice(u.as_slice());
    let v_t = Matrix3::from_column_slice(v_t.as_slice());
    let d = Vector3::from_column_slice(svd.singular_values.as_slice());
    // evo: `np.count_nonzero(d > eps) < m - 1` → degenerate.
    if d.iter().filter(|&&s| s > f64::EPSILON).count() < 2 {
        return Err(AlignError::Degenerate);
    }
    // Sign correction (Umeyama eq. 43): flip the direction of the smallest singular value, the
    // last one as both numpy and nalgebra's `SVD::try_new` sort them in descending order.
    let mut s = Vector3::new(1.0, 1.0, 1.0);
    if u.determinant() * v_t.determinant() < 0.0 {
        s[2] = -1.0;
    }
    let r = u * Matrix3::from_diagonal(&s) * v_t;
    let c = if with_scale { d.dot(&s) / sigma_x } else { 1.0 };
    if !(c.is_finite() && c > 0.0) {
        return Err(AlignError::Degenerate);
    }
    let t = mean_y - c * (r * mean_x);
    let rotation = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(r));
    Ok(Sim3 { scale: c, t_gt_est: Isometry3::from_parts(Translation3::from(t), rotation) })
}

/// The yaw θ (about world z) and the centroids minimizing Σ |Rz(θ)·a_i − b_i|² over the xy
/// components of centred points: θ = atan2(Σ a×b, Σ a·b), the closed form of the 2-D
/// cross-covariance.
fn fit_yaw(est: &[Vector3<f64>], gt: &[Vector3<f64>]) -> Result<(f64, Vector3<f64>, Vector3<f64>), AlignError> {
    if est.len() != gt.len() {
        return Err(AlignError::LengthMismatch { est: est.len(), gt: gt.len() });
    }
    if est.len() < 2 {
        return Err(AlignError::TooFewPairs { found: est.len(), needed: 2 });
    }
    let n = est.len() as f64;
    let mean_est = est.iter().sum::<Vector3<f64>>() / n;
    let mean_gt = gt.iter().sum::<Vector3<f64>>() / n;
    let (mut cross, mut dot, mut spread) = (0.0, 0.0, 0.0);
    for (a, b) in est.iter().zip(gt) {
        let (a, b) = (a - mean_est, b - mean_gt);
        cross += a.x * b.y - a.y * b.x;
        dot += a.x * b.x + a.y * b.y;
        spread += a.x.hypot(a.y) * b.x.hypot(b.y);
    }
    if !(cross.is_finite() && dot.is_finite() && spread.is_finite()) {
        return Err(AlignError::NonFinite);
    }
    // With all estimate (or ground-truth) positions on one vertical line, every heading fits.
    if cross.hypot(dot) <= 1e-12 * spread || spread == 0.0 {
        return Err(AlignError::Degenerate);
    }
    Ok((cross.atan2(dot), mean_est, mean_gt))
}

/// 4-DoF alignment (x, y, z, yaw): rotation about gravity (world z) only, so the estimate's
/// roll and pitch relative to gravity are kept. Yaw from the 2-D cross-covariance of the centred
/// xy positions; translation from the means.
pub fn align_4dof(est: &[Vector3<f64>], gt: &[Vector3<f64>]) -> Result<Sim3, AlignError> {
    let (yaw, mean_est, mean_gt) = fit_yaw(est, gt)?;
    let rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
    let t = mean_gt - rotation * mean_est;
    Ok(Sim3 { scale: 1.0, t_gt_est: Isometry3::from_parts(Translation3::from(t), rotation) })
}

/// SE(2) alignment (x, y, yaw) for planar ground truth: as [`align_4dof`] with z ignored (no z
/// translation). Errors after it belong in the plane: see [`project_to_plane`].
pub fn align_se2(est: &[Vector3<f64>], gt: &[Vector3<f64>]) -> Result<Sim3, AlignError> {
    let (yaw, mean_est, mean_gt) = fit_yaw(est, gt)?;
    let rotation = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
    let mut t = mean_gt - rotation * mean_est;
    t.z = 0.0;
    Ok(Sim3 { scale: 1.0, t_gt_est: Isometry3::from_parts(Translation3::from(t), rotation) })
}

/// Cumulative path length (m) along `poses`, starting at 0.
pub fn path_distances_m(poses: &[Isometry3<f64>]) -> Vec<f64> {
    let mut total_m = 0.0;
    let mut out = Vec::with_capacity(poses.len());
    for (i, pose) in poses.iter().enumerate() {
        if i > 0 {
            total_m += (pose.translation.vector - poses[i - 1].translation.vector).norm();
        }
        out.push(total_m);
    }
    out
}

/// Thesis §7.4 alignment: fit `model` on the pairs whose ground-truth path distance from the
/// first pair is at most `distance_m`, to be applied to the whole trajectory. The path distance
/// is measured along the associated ground-truth poses (the estimate's sampling), which is what
/// the pairs cover.
pub fn align_first_metres(
    est: &[Isometry3<f64>],
    gt: &[Isometry3<f64>],
    distance_m: f64,
    model: FirstMetresModel,
) -> Result<Sim3, AlignError> {
    if est.len() != gt.len() {
        return Err(AlignError::LengthMismatch { est: est.len(), gt: gt.len() });
    }
    let count = path_distances_m(gt).iter().take_while(|&&d| d <= distance_m).count();
    let est_points = positions(&est[..count]);
    let gt_points = positions(&gt[..count]);
    match model {
        FirstMetresModel::Se3 => {
            if count < 3 {
                return Err(AlignError::TooFewPairs { found: count, needed: 3 });
            }
            umeyama(&est_points, &gt_points, false)
        }
        FirstMetresModel::FourDof => align_4dof(&est_points, &gt_points),
    }
}

fn positions(poses: &[Isometry3<f64>]) -> Vec<Vector3<f64>> {
    poses.iter().map(|p| p.translation.vector).collect()
}

/// Fits `alignment` of the estimate poses onto the paired ground-truth poses.
pub fn fit(alignment: &Alignment, est: &[Isometry3<f64>], gt: &[Isometry3<f64>]) -> Result<Sim3, AlignError> {
    if est.len() != gt.len() {
        return Err(AlignError::LengthMismatch { est: est.len(), gt: gt.len() });
    }
    let (est_points, gt_points) = (positions(est), positions(gt));
    match *alignment {
        Alignment::None => Ok(Sim3::identity()),
        Alignment::Se3 => umeyama(&est_points, &gt_points, false),
        Alignment::Sim3 => umeyama(&est_points, &gt_points, true),
        // evo's `correct_only_scale`: Umeyama's scale, but neither its rotation nor translation.
        Alignment::Scale => umeyama(&est_points, &gt_points, true).map(|s| Sim3 { scale: s.scale, ..Sim3::identity() }),
        Alignment::FourDof => align_4dof(&est_points, &gt_points),
        Alignment::Se2 => align_se2(&est_points, &gt_points),
        Alignment::FirstMetres { distance_m, model } => align_first_metres(est, gt, distance_m, model),
    }
}

/// Yaw (rad) of a rotation: the z angle of its `Rz·Ry·Rx` decomposition, atan2(R₁₀, R₀₀).
pub fn yaw_rad(rotation: &UnitQuaternion<f64>) -> f64 {
    let r = rotation.to_rotation_matrix();
    r[(1, 0)].atan2(r[(0, 0)])
}

/// Projects poses into the xy plane as evo's `project(Plane.XY)`: z = 0 and the rotation reduced
/// to its yaw.
pub fn project_to_plane(poses: &[Isometry3<f64>]) -> Vec<Isometry3<f64>> {
    poses
        .iter()
        .map(|p| {
            let t = p.translation.vector;
            Isometry3::from_parts(
                Translation3::new(t.x, t.y, 0.0),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad(&p.rotation)),
            )
        })
        .collect()
}
