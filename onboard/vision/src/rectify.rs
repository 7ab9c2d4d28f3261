//! Rectification of raw stereo pairs (pinhole + radial-tangential) into the canonical pair.
//!
//! # Geometry
//!
//! The relative rotation of the raw pair is split in half (Bouguet): each camera turns by half of
//! it towards the other, so both become parallel while each image moves as little as possible.
//! The common frame is then turned so its x axis lies on the baseline (y ⟂ to the baseline and the
//! mid optical axis, z completing the frame). The right camera then sits at exactly
//! `+baseline_m` along x of the rectified left frame and corresponding points share a row.
//!
//! # Output camera
//!
//! Both outputs share one square-pixel pinhole of the input image size. Its focal length and
//! principal point are chosen so that the output frame is the largest axis-aligned rectangle
//! (in the rectified normalized plane) lying inside the undistorted borders of *both* raw images:
//! every output pixel shows real image content (no black wedges that the feature detector or SGM
//! would have to learn to ignore), at the price of a slightly smaller focal length than the raw
//! one when the distortion is strongly barrel-shaped (EuRoC MH_01, 752×480: raw f ≈ 458 px,
//! rectified f = 431.5 px, principal point (364.3, 254.2), no invalid pixel). The free axis (the one with slack, usually x) is
//! centred on the common field of view. A final check walks the output border through the exact
//! mapping and zooms in by small steps until no border pixel falls outside a raw image.
//!
//! # Resampling
//!
//! `new` precomputes, for every output pixel, the raw source position through the inverse chain
//! (output pixel → rectified ray → raw camera ray → distortion → raw pixel) and stores the
//! top-left source index with 1/128-px fixed-point bilinear weights. `rectify` then does four loads
//! and integer arithmetic per pixel, no trigonometry and no allocation after the first frame.
//! Output pixels whose source lies outside the raw image are 0.

use hal::sensor::{CameraCalibration, Distortion, Pinhole, StereoCalibration, StereoFrame};
use nalgebra::{Isometry3, Matrix3, Rotation3, UnitQuaternion, Vector3};

use crate::image::StereoView;

/// Larger images are rejected rather than allocating gigabytes of maps (64 Mpx).
const MAX_PIXELS: u64 = 1 << 26;
/// A pose's quaternion must be this close to unit norm.
const UNIT_QUATERNION_TOLERANCE: f64 = 1e-6;
/// Shorter baselines are treated as zero.
const MIN_BASELINE_M: f64 = 1e-9;
/// The baseline must lie within 45° of the left camera's x axis (a horizontal pair, right camera
/// on the right); vertical or swapped pairs are not supported.
const MIN_BASELINE_X_COSINE: f64 = std::f64::consts::FRAC_1_SQRT_2;
/// Each camera may be turned by at most this much (45°) to rectify it: beyond, the two views barely
/// overlap and the output camera would be meaningless.
const MAX_RECTIFYING_ANGLE_RAD: f64 = std::f64::consts::FRAC_PI_4;
/// Newton iterations of the undistortion; it converges quadratically, 5–6 steps suffice in practice.
const UNDISTORT_MAX_ITERATIONS: usize = 40;
/// Residual in the normalized plane at which the undistortion stops (≈ 1e-10 px at f = 500 px).
const UNDISTORT_TOLERANCE: f64 = 1e-13;
/// Samples along each edge of a raw image when fitting the output camera.
const BORDER_SAMPLES: usize = 96;
/// Zoom step and step budget of the final border check (at most ≈ 10 % zoom).
const ZOOM_STEP: f64 = 1.0025;
const MAX_ZOOM_STEPS: usize = 40;
/// Rays beyond this multiple of the largest undistorted radius of a raw image's border cannot be
/// in that image; the polynomial may fold them back in, so they are rejected outright.
const RADIUS_MARGIN: f64 = 1.1;
/// Fixed-point scale of the bilinear weights: 1/128 px steps (at most 0.004 px off) in a byte.
const WEIGHT_ONE: u32 = 128;
const INVALID_TAP: u32 = u32::MAX;

/// Why a rectifier could not be built or applied.
#[derive(Debug, thiserror::Error)]
pub enum RectifyError {
    #[error("rectification: {0}")]
    Calibration(String),
    #[error("rectification: frame is {got_w}x{got_h}, calibration is {want_w}x{want_h}")]
    FrameSize { got_w: u32, got_h: u32, want_w: u32, want_h: u32 },
    /// The frame's header size is right but an image buffer has the wrong length.
    #[error("rectification: image buffer holds {got} bytes, {want} expected")]
    BufferLength { got: usize, want: usize },
}

fn calibration_error(reason: impl Into<String>) -> RectifyError {
    RectifyError::Calibration(reason.into())
}

/// Which camera of the pair.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StereoSide {
    Left,
    Right,
}

/// Applies the radial-tangential model to a point of the ideal normalized image plane
/// (`[x/z, y/z]`), giving the distorted normalized point.
pub fn distort_normalized(distortion: &Distortion, [x, y]: [f64; 2]) -> [f64; 2] {
    match *distortion {
        Distortion::None => [x, y],
        Distortion::RadTan([k1, k2, p1, p2]) => {
            let r2 = x * x + y * y;
            let radial = 1.0 + r2 * (k1 + k2 * r2);
            [
                x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x),
                y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y,
            ]
        }
    }
}

/// The distorted point and the Jacobian `[[∂xd/∂x, ∂xd/∂y], [∂yd/∂x, ∂yd/∂y]]`.
fn distort_with_jacobian(k: [f64; 4], [x, y]: [f64; 2]) -> ([f64; 2], [[f64; 2]; 2]) {
    let [k1, k2, p1, p2] = k;
    let r2 = x * x + y * y;
    let radial = 1.0 + r2 * (k1 + k2 * r2);
    // d(radial)/d(r2)
    let slope = k1 + 2.0 * k2 * r2;
    let cross = 2.0 * x * y * slope + 2.0 * p1 * x + 2.0 * p2 * y;
    let jacobian = [
        [radial + 2.0 * x * x * slope + 2.0 * p1 * y + 6.0 * p2 * x, cross],
        [cross, radial + 2.0 * y * y * slope + 6.0 * p1 * y + 2.0 * p2 * x],
    ];
    (distort_normalized(&Distortion::RadTan(k), [x, y]), jacobian)
}

/// Inverts [`distort_normalized`] by Newton's method. `None` when it does not converge or lands
/// where the model folds over (negative Jacobian determinant: not the physical solution).
pub fn undistort_normalized(distortion: &Distortion, distorted: [f64; 2]) -> Option<[f64; 2]> {
    let k = match *distortion {
        Distortion::None => return Some(distorted),
        Distortion::RadTan(k) => k,
    };
    let mut p = distorted;
    for _ in 0..UNDISTORT_MAX_ITERATIONS {
        let (d, j) = distort_with_jacobian(k, p);
        let (ex, ey) = (distorted[0] - d[0], distorted[1] - d[1]);
        let determinant = j[0][0] * j[1][1] - j[0][1] * j[1][0];
        if determinant.is_nan() || determinant <= 0.0 {
            return None;
        }
        if ex.abs().max(ey.abs()) < UNDISTORT_TOLERANCE {
            return Some(p);
        }
        p[0] += (j[1][1] * ex - j[0][1] * ey) / determinant;
        p[1] += (j[0][0] * ey - j[1][0] * ex) / determinant;
    }
    None
}

/// Pixel of a raw camera for a point in that camera's optical frame (`None` behind the camera).
pub fn project_raw(camera: &CameraCalibration, point_cam: &Vector3<f64>) -> Option<[f64; 2]> {
    if point_cam.z.is_nan() || point_cam.z <= 0.0 {
        return None;
    }
    let [xd, yd] = distort_normalized(&camera.distortion, [point_cam.x / point_cam.z, point_cam.y / point_cam.z]);
    let k = &camera.intrinsics;
    Some([k.fx_px * xd + k.cx_px, k.fy_px * yd + k.cy_px])
}

/// One raw camera seen from its rectified frame.
#[derive(Debug, Clone, Copy)]
struct RawView {
    camera: CameraCalibration,
    /// Maps rectified-frame directions into the raw camera frame.
    r_raw_rect: Rotation3<f64>,
    /// Squared normalized radius beyond which a ray cannot hit the raw image.
    max_radius2: f64,
}

impl RawView {
    /// Normalized ray `[x, y, 1]` in the raw frame of a raw pixel.
    fn raw_ray(&self, [u, v]: [f64; 2]) -> Option<Vector3<f64>> {
        let k = &self.camera.intrinsics;
        let distorted = [(u - k.cx_px) / k.fx_px, (v - k.cy_px) / k.fy_px];
        let [x, y] = undistort_normalized(&self.camera.distortion, distorted)?;
        Some(Vector3::new(x, y, 1.0))
    }

    /// Raw pixel → point `[x/z, y/z]` of the rectified normalized plane.
    fn raw_to_rectified_normalized(&self, raw_px: [f64; 2]) -> Option<[f64; 2]> {
        let ray = self.r_raw_rect.inverse_transform_vector(&self.raw_ray(raw_px)?);
        (ray.z > 0.0).then(|| [ray.x / ray.z, ray.y / ray.z])
    }

    /// Rectified normalized point → raw pixel, `None` when the ray cannot reach the raw image.
    fn rectified_normalized_to_raw(&self, [x, y]: [f64; 2]) -> Option<[f64; 2]> {
        let ray = self.r_raw_rect * Vector3::new(x, y, 1.0);
        if ray.z.is_nan() || ray.z <= 0.0 {
            return None;
        }
        let (xn, yn) = (ray.x / ray.z, ray.y / ray.z);
        let radius2 = xn * xn + yn * yn;
        if radius2.is_nan() || radius2 > self.max_radius2 {
            return None;
        }
        let [xd, yd] = distort_normalized(&self.camera.distortion, [xn, yn]);
        let k = &self.camera.intrinsics;
        Some([k.fx_px * xd + k.cx_px, k.fy_px * yd + k.cy_px])
    }

    /// Whether a raw pixel position lies on the raw image (pixel centres at integers).
    fn contains(&self, [u, v]: [f64; 2]) -> bool {
        let (w, h) = (f64::from(self.camera.width_px), f64::from(self.camera.height_px));
        (-0.5..=w - 0.5).contains(&u) && (-0.5..=h - 0.5).contains(&v)
    }
}

/// Points along the border of the rectangle `[lo, hi]`: `(edge, [u, v])` with edge 0 = left,
/// 1 = right, 2 = top, 3 = bottom; corners belong to two edges.
fn border_samples(lo: [f64; 2], hi: [f64; 2]) -> impl Iterator<Item = (usize, [f64; 2])> {
    (0..=BORDER_SAMPLES).flat_map(move |i| {
        let s = i as f64 / BORDER_SAMPLES as f64;
        let (u, v) = (lo[0] + s * (hi[0] - lo[0]), lo[1] + s * (hi[1] - lo[1]));
        [(0, [lo[0], v]), (1, [hi[0], v]), (2, [u, lo[1]]), (3, [u, hi[1]])]
    })
}

/// The border of a `w × h` image's pixel area (pixel centres at integers).
fn image_border(w: f64, h: f64) -> impl Iterator<Item = (usize, [f64; 2])> {
    border_samples([-0.5, -0.5], [w - 0.5, h - 0.5])
}

/// The precomputed source taps of one output image: per output pixel the top-left source index
/// (or [`INVALID_TAP`]) and the fixed-point fractions `[x, y]`. Two flat arrays rather than one of
/// structs: 5 bytes per pixel instead of 8, and the maps of a pair (3.6 MB at 752×480) are read
/// once per frame, so their size is the cost.
struct RemapTable {
    width: usize,
    index: Vec<u32>,
    fraction: Vec<[u8; 2]>,
    invalid: usize,
}

impl std::fmt::Debug for RemapTable {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemapTable").field("taps", &self.index.len()).field("invalid", &self.invalid).finish()
    }
}

impl RemapTable {
    fn build(view: &RawView, output: &Pinhole, width: usize, height: usize) -> Self {
        let (w_max, h_max) = ((width - 1) as f64, (height - 1) as f64);
        let mut index = Vec::with_capacity(width * height);
        let mut fraction = Vec::with_capacity(width * height);
        let mut invalid = 0;
        for v in 0..height {
            let y = (v as f64 - output.cy_px) / output.fy_px;
            for u in 0..width {
                let x = (u as f64 - output.cx_px) / output.fx_px;
                match view.rectified_normalized_to_raw([x, y]) {
                    Some(raw) if view.contains(raw) => {
                        // Within half a pixel of the border the edge pixel itself is the sample.
                        let (su, sv) = (raw[0].clamp(0.0, w_max), raw[1].clamp(0.0, h_max));
                        let (ix, iy) = ((su as usize).min(width - 2), (sv as usize).min(height - 2));
                        let weight = |f: f64| (f * f64::from(WEIGHT_ONE)).round() as u8;
                        index.push((iy * width + ix) as u32);
                        fraction.push([weight(su - ix as f64), weight(sv - iy as f64)]);
                    }
                    _ => {
                        invalid += 1;
                        index.push(INVALID_TAP);
                        fraction.push([0, 0]);
                    }
                }
            }
        }
        RemapTable { width, index, fraction, invalid }
    }

    fn apply(&self, src: &[u8], dst: &mut [u8]) {
        let w = self.width;
        for ((out, &index), &[fx, fy]) in dst.iter_mut().zip(&self.index).zip(&self.fraction) {
            *out = if index == INVALID_TAP {
                0
            } else {
                let i = index as usize;
                let (top, bottom) = (&src[i..i + 2], &src[i + w..i + w + 2]);
                let (wx, wy) = (u32::from(fx), u32::from(fy));
                let top = u32::from(top[0]) * (WEIGHT_ONE - wx) + u32::from(top[1]) * wx;
                let bottom = u32::from(bottom[0]) * (WEIGHT_ONE - wx) + u32::from(bottom[1]) * wx;
                ((top * (WEIGHT_ONE - wy) + bottom * wy + WEIGHT_ONE * WEIGHT_ONE / 2) / (WEIGHT_ONE * WEIGHT_ONE))
                    as u8
            };
        }
    }
}

#[derive(Debug)]
enum Mapping {
    Identity,
    Remap { views: Box<[RawView; 2]>, tables: [RemapTable; 2] },
}

/// Precomputed remapping of a raw pair into a rectified pair.
#[derive(Debug)]
pub struct Rectifier {
    rectified: StereoCalibration,
    mapping: Mapping,
}

fn check_camera(name: &str, camera: &CameraCalibration) -> Result<(), RectifyError> {
    let (w, h) = (camera.width_px, camera.height_px);
    if w < 2 || h < 2 || u64::from(w) * u64::from(h) > MAX_PIXELS {
        return Err(calibration_error(format!("{name} camera: image size {w}x{h} is not supported")));
    }
    let k = &camera.intrinsics;
    let finite = [k.fx_px, k.fy_px, k.cx_px, k.cy_px].iter().all(|v| v.is_finite());
    if !finite || k.fx_px <= 0.0 || k.fy_px <= 0.0 {
        return Err(calibration_error(format!("{name} camera: intrinsics {k:?} are not finite and positive")));
    }
    if let Distortion::RadTan(c) = camera.distortion
        && !c.iter().all(|v| v.is_finite())
    {
        return Err(calibration_error(format!("{name} camera: distortion {c:?} is not finite")));
    }
    let pose = &camera.t_body_cam;
    let q = pose.rotation.quaternion();
    let finite = pose.translation.vector.iter().chain(q.coords.iter()).all(|v| v.is_finite());
    // `finite` rules out NaN before the norm test.
    if !finite || (q.norm() - 1.0).abs() > UNIT_QUATERNION_TOLERANCE {
        return Err(calibration_error(format!("{name} camera: t_body_cam is not a finite rigid transform")));
    }
    Ok(())
}

fn check_pair(raw: &StereoCalibration) -> Result<(), RectifyError> {
    check_camera("left", &raw.left)?;
    check_camera("right", &raw.right)?;
    let (l, r) = (&raw.left, &raw.right);
    if (l.width_px, l.height_px) != (r.width_px, r.height_px) {
        return Err(calibration_error(format!(
            "image sizes differ: left {}x{}, right {}x{}",
            l.width_px, l.height_px, r.width_px, r.height_px
        )));
    }
    if !raw.baseline_m.is_finite() || raw.baseline_m <= MIN_BASELINE_M {
        return Err(calibration_error(format!("baseline {} m is not finite and positive", raw.baseline_m)));
    }
    Ok(())
}

/// Rotations `r_left_rect`, `r_right_rect` (rectified → raw camera frame) and the baseline length.
fn rectifying_rotations(t_left_right: &Isometry3<f64>) -> Result<(Rotation3<f64>, Rotation3<f64>, f64), RectifyError> {
    let r_left_right = t_left_right.rotation;
    let r_left_mid = UnitQuaternion::from_scaled_axis(r_left_right.scaled_axis() * 0.5);
    let r_right_mid = r_left_right.inverse() * r_left_mid;
    let baseline_mid = r_left_mid.inverse_transform_vector(&t_left_right.translation.vector);
    let baseline_m = baseline_mid.norm();
    if !baseline_m.is_finite() || baseline_m <= MIN_BASELINE_M {
        return Err(calibration_error(format!("the cameras' poses give a baseline of {baseline_m} m")));
    }
    let e1 = baseline_mid / baseline_m;
    // e1 is finite: the baseline was checked.
    if e1.x < MIN_BASELINE_X_COSINE {
        return Err(calibration_error(format!(
            "the right camera is not to the right of the left one (baseline direction {:?})",
            e1.as_slice()
        )));
    }
    // e1 is within 45° of x, so it is never parallel to z and the cross product is well defined.
    let e2 = Vector3::z().cross(&e1).normalize();
    let e3 = e1.cross(&e2);
    let r_mid_rect =
        UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(Matrix3::from_columns(&[e1, e2, e3])));
    let (r_left_rect, r_right_rect) = (r_left_mid * r_mid_rect, r_right_mid * r_mid_rect);
    for (name, r) in [("left", r_left_rect), ("right", r_right_rect)] {
        if r.angle().is_nan() || r.angle() > MAX_RECTIFYING_ANGLE_RAD {
            return Err(calibration_error(format!(
                "the {name} camera would have to turn by {:.1}° to rectify the pair",
                r.angle().to_degrees()
            )));
        }
    }
    Ok((r_left_rect.to_rotation_matrix(), r_right_rect.to_rotation_matrix(), baseline_m))
}

/// The view of a raw camera from its rectified frame, with the radius its image spans.
fn raw_view(name: &str, camera: &CameraCalibration, r_raw_rect: Rotation3<f64>) -> Result<RawView, RectifyError> {
    let mut view = RawView { camera: *camera, r_raw_rect, max_radius2: f64::INFINITY };
    let (w, h) = (f64::from(camera.width_px), f64::from(camera.height_px));
    let mut max_radius2: f64 = 0.0;
    for (_, px) in image_border(w, h) {
        let ray = view.raw_ray(px).ok_or_else(|| {
            calibration_error(format!("{name} camera: the distortion cannot be inverted at raw pixel {px:?}"))
        })?;
        max_radius2 = max_radius2.max(ray.x * ray.x + ray.y * ray.y);
    }
    view.max_radius2 = max_radius2 * RADIUS_MARGIN * RADIUS_MARGIN;
    Ok(view)
}

/// The largest rectangle of the rectified normalized plane inside both raw images' borders, as a
/// square-pixel pinhole of the given size (see the module documentation).
fn fit_output_pinhole(views: &[RawView; 2], width: u32, height: u32) -> Result<Pinhole, RectifyError> {
    let (w, h) = (f64::from(width), f64::from(height));
    // Inner bounds: left, right, top, bottom.
    let mut bounds = [f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY];
    for view in views {
        let (raw_w, raw_h) = (f64::from(view.camera.width_px), f64::from(view.camera.height_px));
        for (edge, px) in image_border(raw_w, raw_h) {
            let [x, y] = view.raw_to_rectified_normalized(px).ok_or_else(|| {
                calibration_error(format!("raw border pixel {px:?} does not look into the rectified half-space"))
            })?;
            match edge {
                0 => bounds[0] = bounds[0].max(x),
                1 => bounds[1] = bounds[1].min(x),
                2 => bounds[2] = bounds[2].max(y),
                _ => bounds[3] = bounds[3].min(y),
            }
        }
    }
    let [left, right, top, bottom] = bounds;
    let overlap = right > left && bottom > top;
    if !overlap {
        return Err(calibration_error("the two cameras' fields of view do not overlap"));
    }
    // Output pixel areas span [-0.5, w - 0.5]; the tighter axis sets the focal length.
    let focal = (w / (right - left)).max(h / (bottom - top));
    let centred = |f: f64| Pinhole {
        fx_px: f,
        fy_px: f,
        cx_px: 0.5 * (w - 1.0) - f * 0.5 * (left + right),
        cy_px: 0.5 * (h - 1.0) - f * 0.5 * (top + bottom),
    };
    // The rectangle test above is exact only for borders that are straight or bulge outwards;
    // zoom in until the real mapping of the output border stays on both raw images.
    let mut pinhole = centred(focal);
    for _ in 0..MAX_ZOOM_STEPS {
        if border_outside(views, &pinhole, width, height) == 0 {
            break;
        }
        pinhole = centred(pinhole.fx_px * ZOOM_STEP);
    }
    if ![pinhole.fx_px, pinhole.cx_px, pinhole.cy_px].iter().all(|v| v.is_finite()) {
        return Err(calibration_error("the rectified camera is degenerate"));
    }
    Ok(pinhole)
}

/// How many output border pixels map outside a raw image.
fn border_outside(views: &[RawView; 2], pinhole: &Pinhole, width: u32, height: u32) -> usize {
    let (w, h) = (f64::from(width), f64::from(height));
    let mut outside = 0;
    // The outermost output pixel centres.
    for (_, [u, v]) in border_samples([0.0, 0.0], [w - 1.0, h - 1.0]) {
        let normalized = [(u - pinhole.cx_px) / pinhole.fx_px, (v - pinhole.cy_px) / pinhole.fy_px];
        for view in views {
            if !view.rectified_normalized_to_raw(normalized).is_some_and(|raw| view.contains(raw)) {
                outside += 1;
            }
        }
    }
    outside
}

impl Rectifier {
    /// A rectifier for a raw calibration (an already rectified one gives the identity mapping).
    pub fn new(raw: &StereoCalibration) -> Result<Self, RectifyError> {
        check_pair(raw)?;
        if raw.rectified {
            return Ok(Rectifier { rectified: *raw, mapping: Mapping::Identity });
        }
        let t_left_right = raw.left.t_body_cam.inverse() * raw.right.t_body_cam;
        let (r_left_rect, r_right_rect, baseline_m) = rectifying_rotations(&t_left_right)?;
        let views = [raw_view("left", &raw.left, r_left_rect)?, raw_view("right", &raw.right, r_right_rect)?];
        let (width, height) = (raw.left.width_px, raw.left.height_px);
        let pinhole = fit_output_pinhole(&views, width, height)?;
        let rectified_camera = |camera: &CameraCalibration, r_cam_rect: Rotation3<f64>| CameraCalibration {
            width_px: width,
            height_px: height,
            intrinsics: pinhole,
            distortion: Distortion::None,
            t_body_cam: camera.t_body_cam * UnitQuaternion::from_rotation_matrix(&r_cam_rect),
        };
        let rectified = StereoCalibration {
            left: rectified_camera(&raw.left, r_left_rect),
            right: rectified_camera(&raw.right, r_right_rect),
            rectified: true,
            baseline_m,
            // The head carries the pair; the rectifying rotation (a degree or so) is not modelled.
            head: raw.head,
        };
        let (w, h) = (width as usize, height as usize);
        let tables = [RemapTable::build(&views[0], &pinhole, w, h), RemapTable::build(&views[1], &pinhole, w, h)];
        Ok(Rectifier { rectified, mapping: Mapping::Remap { views: Box::new(views), tables } })
    }

    /// The calibration of the output pair: `rectified == true`, shared pinhole, no distortion,
    /// right camera at `+baseline_m` along x, `left.t_body_cam` the rectified left camera (the raw
    /// pose turned by the rectifying rotation; the optical centres do not move). A pan-tilt head is
    /// copied unchanged: its kinematics then ignore the rectifying rotation (about a degree).
    pub fn rectified_calibration(&self) -> StereoCalibration {
        self.rectified
    }

    /// True when the input was already rectified and frames are only copied.
    pub fn is_identity(&self) -> bool {
        matches!(self.mapping, Mapping::Identity)
    }

    /// Output pixels of the left and right image without a raw source (always 0).
    pub fn invalid_pixels(&self) -> [usize; 2] {
        match &self.mapping {
            Mapping::Identity => [0, 0],
            Mapping::Remap { tables, .. } => [tables[0].invalid, tables[1].invalid],
        }
    }

    /// The raw pixel an output pixel is sampled from (the exact mapping behind the maps); `None`
    /// when it has no source. Identity for an already rectified pair.
    pub fn rectified_to_raw_px(&self, side: StereoSide, rectified_px: [f64; 2]) -> Option<[f64; 2]> {
        let Mapping::Remap { views, .. } = &self.mapping else {
            return Some(rectified_px);
        };
        let k = &self.rectified.left.intrinsics;
        let view = &views[side as usize];
        let normalized = [(rectified_px[0] - k.cx_px) / k.fx_px, (rectified_px[1] - k.cy_px) / k.fy_px];
        view.rectified_normalized_to_raw(normalized).filter(|raw| view.contains(*raw))
    }

    /// Where a raw pixel lands in the rectified image (it may fall outside the output frame);
    /// `None` when the distortion cannot be inverted there. Identity for an already rectified pair.
    pub fn raw_to_rectified_px(&self, side: StereoSide, raw_px: [f64; 2]) -> Option<[f64; 2]> {
        let Mapping::Remap { views, .. } = &self.mapping else {
            return Some(raw_px);
        };
        let k = &self.rectified.left.intrinsics;
        let [x, y] = views[side as usize].raw_to_rectified_normalized(raw_px)?;
        Some([k.fx_px * x + k.cx_px, k.fy_px * y + k.cy_px])
    }

    /// Rectifies `raw` into `out` (resized; allocation reused). Stamps and head angles are copied.
    pub fn rectify(&self, raw: &StereoFrame, out: &mut StereoFrame) -> Result<(), RectifyError> {
        self.rectify_view(StereoView::of(raw), out)
    }

    /// As [`Rectifier::rectify`], reading the raw pair where it lies (e.g. in shared memory).
    pub fn rectify_view(&self, raw: StereoView<'_>, out: &mut StereoFrame) -> Result<(), RectifyError> {
        let (want_w, want_h) = (self.rectified.left.width_px, self.rectified.left.height_px);
        if (raw.width_px, raw.height_px) != (want_w, want_h) {
            return Err(RectifyError::FrameSize { got_w: raw.width_px, got_h: raw.height_px, want_w, want_h });
        }
        let want = want_w as usize * want_h as usize;
        for got in [raw.left.len(), raw.right.len()] {
            if got != want {
                return Err(RectifyError::BufferLength { got, want });
            }
        }
        out.resize(want_w, want_h);
        out.stamp_ns = raw.stamp_ns;
        out.sequence = raw.sequence;
        out.pan_rad = raw.pan_rad;
        out.tilt_rad = raw.tilt_rad;
        match &self.mapping {
            Mapping::Identity => {
                out.left.copy_from_slice(raw.left);
                out.right.copy_from_slice(raw.right);
            }
            Mapping::Remap { tables, .. } => {
                tables[0].apply(raw.left, &mut out.left);
                tables[1].apply(raw.right, &mut out.right);
            }
        }
        Ok(())
    }
}
