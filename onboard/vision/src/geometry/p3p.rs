//! Minimal 3-point absolute pose (P3P) after Grunert: the three camera-to-point distances from
//! the law of cosines, reduced to a quartic in one distance ratio, then the rigid motion from
//! the three point pairs.
//!
//! The quartic is assembled by polynomial arithmetic from the elimination below instead of
//! hard-coded coefficients, so each step can be checked against the equations it comes from.

use nalgebra::{Isometry3, Matrix3, Matrix4, Rotation3, Translation3, UnitQuaternion, Vector3};

/// Up to four poses `t_camera_world` (world point into the camera frame) that map the three
/// `points_world` onto the unit `bearings` (camera frame). Returns how many were written.
pub fn solve(points_world: &[Vector3<f64>; 3], bearings: &[Vector3<f64>; 3], out: &mut [Isometry3<f64>; 4]) -> usize {
    let [p1, p2, p3] = points_world;
    let [j1, j2, j3] = bearings;
    // Side lengths opposite the camera-ray angles: a = |P2P3|, b = |P1P3|, c = |P1P2|.
    let a2 = (p2 - p3).norm_squared();
    let b2 = (p1 - p3).norm_squared();
    let c2 = (p1 - p2).norm_squared();
    if a2 < 1e-18 || b2 < 1e-18 || c2 < 1e-18 {
        return 0;
    }
    let cos_alpha = j2.dot(j3);
    let cos_beta = j1.dot(j3);
    let cos_gamma = j1.dot(j2);
    // With distances s2 = u·s1, s3 = v·s1 the cosine laws give
    //   (i)  u² + v² − 2uv·cosα = (a²/b²)(1 + v² − 2v·cosβ)
    //   (ii) 1 + u² − 2u·cosγ   = (c²/b²)(1 + v² − 2v·cosβ).
    // (i) − (ii) is linear in u:  u = N(v) / D(v) with
    //   N(v) = (K − 1)v² − 2K·cosβ·v + (1 + K),  D(v) = 2(cosγ − v·cosα),  K = (a² − c²)/b².
    let k = (a2 - c2) / b2;
    let n_poly = [1.0 + k, -2.0 * k * cos_beta, k - 1.0];
    let d_poly = [2.0 * cos_gamma, -2.0 * cos_alpha];
    let m_poly = [1.0, -2.0 * cos_beta, 1.0]; // 1 + v² − 2v·cosβ
    // Substituting u into (ii) times D²:  D² + N² − 2cosγ·N·D − (c²/b²)·M·D² = 0, a quartic in v.
    let dd = mul_2_2(&mul_1_1(&d_poly, &d_poly), &[1.0, 0.0, 0.0]);
    let nn = mul_2_2(&n_poly, &n_poly);
    let nd = mul_2_2(&n_poly, &[d_poly[0], d_poly[1], 0.0]);
    let mdd = mul_2_2(&m_poly, &mul_1_1(&d_poly, &d_poly));
    let mut quartic = [0.0; 5];
    for i in 0..5 {
        quartic[i] = dd[i] + nn[i] - 2.0 * cos_gamma * nd[i] - (c2 / b2) * mdd[i];
    }
    let mut roots = [0.0; 4];
    let root_count = real_roots_quartic(&quartic, &mut roots);
    let mut count = 0;
    for &v in &roots[..root_count] {
        let d = d_poly[0] + d_poly[1] * v;
        if d.abs() < 1e-12 || v <= 0.0 {
            continue;
        }
        let u = (n_poly[0] + n_poly[1] * v + n_poly[2] * v * v) / d;
        if u <= 0.0 {
            continue;
        }
        let m = m_poly[0] + m_poly[1] * v + m_poly[2] * v * v;
        if m <= 1e-15 {
            continue;
        }
        let s1 = (b2 / m).sqrt();
        let depths = polish_depths(Vector3::new(s1, u * s1, v * s1), [a2, b2, c2], [cos_alpha, cos_beta, cos_gamma]);
        let camera_points = [j1 * depths.x, j2 * depths.y, j3 * depths.z];
        if let Some(pose) = rigid_from_triads(points_world, &camera_points) {
            out[count] = pose;
            count += 1;
        }
    }
    count
}

/// Newton steps on the three cosine laws in the depths `s`: the quartic's root and the division
/// for `u` lose digits on thin triangles, the original equations are well conditioned there.
fn polish_depths(mut s: Vector3<f64>, sides2: [f64; 3], cosines: [f64; 3]) -> Vector3<f64> {
    let [a2, b2, c2] = sides2;
    let [ca, cb, cg] = cosines;
    let residual = |s: &Vector3<f64>| {
        Vector3::new(
            s.y * s.y + s.z * s.z - 2.0 * s.y * s.z * ca - a2,
            s.x * s.x + s.z * s.z - 2.0 * s.x * s.z * cb - b2,
            s.x * s.x + s.y * s.y - 2.0 * s.x * s.y * cg - c2,
        )
    };
    let mut f = residual(&s);
    for _ in 0..3 {
        let jacobian = Matrix3::new(
            0.0,
            2.0 * (s.y - s.z * ca),
            2.0 * (s.z - s.y * ca),
            2.0 * (s.x - s.z * cb),
            0.0,
            2.0 * (s.z - s.x * cb),
            2.0 * (s.x - s.y * cg),
            2.0 * (s.y - s.x * cg),
            0.0,
        );
        let Some(step) = jacobian.lu().solve(&f) else {
            break;
        };
        let candidate = s - step;
        let f_candidate = residual(&candidate);
        // Also stops on NaN.
        if f_candidate.norm().partial_cmp(&f.norm()) != Some(std::cmp::Ordering::Less) {
            break;
        }
        s = candidate;
        f = f_candidate;
    }
    s
}

/// Product of two polynomials of degree ≤ 1 (coefficients lowest first), degree ≤ 2.
fn mul_1_1(a: &[f64; 2], b: &[f64; 2]) -> [f64; 3] {
    [a[0] * b[0], a[0] * b[1] + a[1] * b[0], a[1] * b[1]]
}

/// Product of two polynomials of degree ≤ 2, degree ≤ 4.
fn mul_2_2(a: &[f64; 3], b: &[f64; 3]) -> [f64; 5] {
    let mut out = [0.0; 5];
    for (i, ai) in a.iter().enumerate() {
        for (j, bj) in b.iter().enumerate() {
            out[i + j] += ai * bj;
        }
    }
    out
}

/// Real roots of `c[0] + c[1]·x + … + c[4]·x⁴` (companion-matrix eigenvalues, Newton-polished).
/// A (near-)vanishing leading coefficient falls back to the cubic's companion matrix.
fn real_roots_quartic(c: &[f64; 5], roots: &mut [f64; 4]) -> usize {
    let scale = c.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if scale == 0.0 || !scale.is_finite() {
        return 0;
    }
    let mut count = 0;
    if c[4].abs() > 1e-12 * scale {
        let mut companion = Matrix4::<f64>::zeros();
        for i in 0..3 {
            companion[(i + 1, i)] = 1.0;
        }
        for i in 0..4 {
            companion[(i, 3)] = -c[i] / c[4];
        }
        for z in companion.complex_eigenvalues().iter() {
            if z.im.abs() <= 1e-6 * (1.0 + z.re.abs()) {
                roots[count] = z.re;
                count += 1;
            }
        }
    } else if c[3].abs() > 1e-12 * scale {
        let mut companion = Matrix3::<f64>::zeros();
        companion[(1, 0)] = 1.0;
        companion[(2, 1)] = 1.0;
        for i in 0..3 {
            companion[(i, 2)] = -c[i] / c[3];
        }
        for z in companion.complex_eigenvalues().iter() {
            if z.im.abs() <= 1e-6 * (1.0 + z.re.abs()) {
                roots[count] = z.re;
                count += 1;
            }
        }
    }
    for root in &mut roots[..count] {
        for _ in 0..3 {
            let x = *root;
            let value = (((c[4] * x + c[3]) * x + c[2]) * x + c[1]) * x + c[0];
            let slope = ((4.0 * c[4] * x + 3.0 * c[3]) * x + 2.0 * c[2]) * x + c[1];
            if slope.abs() < 1e-300 {
                break;
            }
            let step = value / slope;
            if !step.is_finite() {
                break;
            }
            *root = x - step;
        }
    }
    count
}

/// The rigid motion `t_b_a` with `b_i = t_b_a · a_i` for three exact, non-collinear point pairs,
/// from the orthonormal frames the triangles span in each set.
pub fn rigid_from_triads(a: &[Vector3<f64>; 3], b: &[Vector3<f64>; 3]) -> Option<Isometry3<f64>> {
    let frame = |p: &[Vector3<f64>; 3]| -> Option<Matrix3<f64>> {
        let e1 = (p[1] - p[0]).try_normalize(1e-12)?;
        let e3 = (p[1] - p[0]).cross(&(p[2] - p[0])).try_normalize(1e-12)?;
        let e2 = e3.cross(&e1);
        Some(Matrix3::from_columns(&[e1, e2, e3]))
    };
    let frame_a = frame(a)?;
    let frame_b = frame(b)?;
    let rotation = Rotation3::from_matrix_unchecked(frame_b * frame_a.transpose());
    let centroid_a = (a[0] + a[1] + a[2]) / 3.0;
    let centroid_b = (b[0] + b[1] + b[2]) / 3.0;
    let translation = centroid_b - rotation * centroid_a;
    Some(Isometry3::from_parts(Translation3::from(translation), UnitQuaternion::from_rotation_matrix(&rotation)))
}
