//! The SE(3) maps the simulator's ground truth needs: exponential, logarithm and adjoint.
//!
//! Written here from the math, not taken from `posegraph`: the simulator is the reference the
//! pose-graph back-end is checked against, so its noise model must not share code (and so bugs)
//! with the back-end. `tests/se3_cross_check.rs` compares the two implementations.
//!
//! Tangent vectors are `ξ = [ρ, φ]`, translation part first, then rotation (the project's
//! covariance order, and posegraph's). `exp(ξ)` is the true group exponential:
//! `R = Exp_SO3(φ)`, `t = V(φ)·ρ` with the left Jacobian of SO(3)
//! `V = I + (1 − cos θ)/θ² [φ]× + (θ − sin θ)/θ³ [φ]×²`, θ = |φ|. Perturbations act on the right,
//! `T·Exp(δ)`, so `Ad(T)` maps a right perturbation to a left one: `T·Exp(δ)·T⁻¹ = Exp(Ad(T)·δ)`,
//! `Ad(T) = [[R, [t]×·R], [0, R]]` in this ordering.

use nalgebra::{Isometry3, Matrix3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector3, Vector6};

/// Below this angle the coefficients of `V` are summed as their Taylor series: the closed forms
/// subtract nearly equal numbers (1 − cos θ, θ − sin θ) and lose about log10(1/θ²) digits. Eight
/// terms of the series are exact to rounding up to here (the first omitted term is below 1e-20).
const V_SERIES_BELOW_RAD: f64 = 0.5;

/// Below this angle `V⁻¹`'s coefficient uses its series. That series (from the Bernoulli numbers
/// of x·cot x) converges more slowly, so the switch sits lower: with five terms the first omitted
/// one is below 1e-20 here, and the closed form has lost about 3 digits, in a coefficient that is
/// multiplied by θ² anyway.
const V_INV_SERIES_BELOW_RAD: f64 = 0.1;

/// The cross-product matrix: `hat(a)·b = a × b`.
pub fn hat(v: &Vector3<f64>) -> Matrix3<f64> {
    Matrix3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// `(1 − cos θ)/θ²` and `(θ − sin θ)/θ³`, the coefficients of `[φ]×` and `[φ]×²` in `V(φ)`.
fn v_coefficients(theta: f64) -> (f64, f64) {
    if theta < V_SERIES_BELOW_RAD { v_coefficients_series(theta) } else { v_coefficients_closed(theta) }
}

fn v_coefficients_closed(theta: f64) -> (f64, f64) {
    let theta2 = theta * theta;
    ((1.0 - theta.cos()) / theta2, (theta - theta.sin()) / (theta2 * theta))
}

/// (1 − cos θ)/θ² = Σₖ (−θ²)ᵏ/(2k+2)!,  (θ − sin θ)/θ³ = Σₖ (−θ²)ᵏ/(2k+3)!
fn v_coefficients_series(theta: f64) -> (f64, f64) {
    let minus_theta2 = -theta * theta;
    let (mut a, mut b) = (0.0, 0.0);
    let mut power = 1.0;
    let mut factorial = 1.0; // (2k+1)! at the top of each round
    for k in 0..8 {
        let n = f64::from(2 * k + 2);
        factorial *= n;
        a += power / factorial;
        factorial *= n + 1.0;
        b += power / factorial;
        power *= minus_theta2;
    }
    (a, b)
}

/// `c = (1 − (θ/2)·cot(θ/2))/θ²`, the coefficient of `[φ]×²` in `V⁻¹`, from the half angle's
/// cotangent (exact at θ = π, where cot = 0 and sin θ in the textbook form is 0).
fn v_inv_coefficient(theta: f64, cot_half: f64) -> f64 {
    if theta < V_INV_SERIES_BELOW_RAD {
        v_inv_coefficient_series(theta)
    } else {
        v_inv_coefficient_closed(theta, cot_half)
    }
}

fn v_inv_coefficient_closed(theta: f64, cot_half: f64) -> f64 {
    (1.0 - 0.5 * theta * cot_half) / (theta * theta)
}

/// (θ/2)·cot(θ/2) = 1 − θ²/12 − θ⁴/720 − θ⁶/30240 − θ⁸/1209600 − θ¹⁰/47900160 − … (Bernoulli
/// numbers of x·cot x).
fn v_inv_coefficient_series(theta: f64) -> f64 {
    let t2 = theta * theta;
    1.0 / 12.0 + t2 * (1.0 / 720.0 + t2 * (1.0 / 30240.0 + t2 * (1.0 / 1_209_600.0 + t2 / 47_900_160.0)))
}

/// The group exponential of `ξ = [ρ, φ]` (module docs).
pub fn exp(xi: &Vector6<f64>) -> Isometry3<f64> {
    let rho = xi.fixed_rows::<3>(0).into_owned();
    let phi = xi.fixed_rows::<3>(3).into_owned();
    let theta = phi.norm();
    // Unit quaternion of a rotation by θ about φ/θ: (cos θ/2, sin(θ/2)/θ · φ). sin(θ/2)/θ has no
    // cancellation, only the 0/0 at θ = 0, which its series ½(1 − θ²/24) removes.
    let half_sinc = if theta < 1e-4 { 0.5 * (1.0 - theta * theta / 24.0) } else { (0.5 * theta).sin() / theta };
    let v = phi * half_sinc;
    let rotation = UnitQuaternion::new_normalize(Quaternion::new((0.5 * theta).cos(), v.x, v.y, v.z));
    let (a, b) = v_coefficients(theta);
    let phi_x_rho = phi.cross(&rho);
    let t = rho + phi_x_rho * a + phi.cross(&phi_x_rho) * b;
    Isometry3::from_parts(Translation3::from(t), rotation)
}

/// The group logarithm, the inverse of [`exp`] for rotations of at most π (at exactly π the
/// rotation axis's sign is arbitrary).
pub fn log(pose: &Isometry3<f64>) -> Vector6<f64> {
    let q = pose.rotation.quaternion();
    // q and −q are the same rotation; w ≥ 0 picks θ in [0, π].
    let sign = if q.w < 0.0 { -1.0 } else { 1.0 };
    let w = sign * q.w;
    let v = q.imag() * sign;
    let s = v.norm(); // sin(θ/2) for a unit quaternion
    let half_theta = s.atan2(w);
    let theta = 2.0 * half_theta;
    // φ = θ·v/|v|; atan2(s, w)/s → (1/w)(1 − s²/(3w²)) as s → 0 (w → 1 there).
    let phi_per_v = if s < 1e-8 { 2.0 / w * (1.0 - s * s / (3.0 * w * w)) } else { theta / s };
    let phi = v * phi_per_v;
    // V⁻¹ = I − ½[φ]× + c·[φ]×²; cot(θ/2) = w/s.
    let c = if s > 0.0 { v_inv_coefficient(theta, w / s) } else { v_inv_coefficient_series(0.0) };
    let t = pose.translation.vector;
    let phi_x_t = phi.cross(&t);
    let rho = t - phi_x_t * 0.5 + phi.cross(&phi_x_t) * c;
    Vector6::new(rho.x, rho.y, rho.z, phi.x, phi.y, phi.z)
}

/// `Ad(T) = [[R, [t]×·R], [0, R]]`: `T·Exp(δ)·T⁻¹ = Exp(Ad(T)·δ)` (module docs).
pub fn adjoint(pose: &Isometry3<f64>) -> Matrix6<f64> {
    let r = pose.rotation.to_rotation_matrix().into_inner();
    let mut ad = Matrix6::zeros();
    ad.fixed_view_mut::<3, 3>(0, 0).copy_from(&r);
    ad.fixed_view_mut::<3, 3>(0, 3).copy_from(&(hat(&pose.translation.vector) * r));
    ad.fixed_view_mut::<3, 3>(3, 3).copy_from(&r);
    ad
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::{Rng, stream};
    use std::f64::consts::{FRAC_PI_2, PI};

    fn xi(rho: [f64; 3], phi: [f64; 3]) -> Vector6<f64> {
        Vector6::new(rho[0], rho[1], rho[2], phi[0], phi[1], phi[2])
    }

    /// Largest difference of translations and of rotation matrices.
    fn pose_diff(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
        let dt = (a.translation.vector - b.translation.vector).amax();
        let dr = (a.rotation.to_rotation_matrix().into_inner() - b.rotation.to_rotation_matrix().into_inner()).amax();
        dt.max(dr)
    }

    fn rot_z(theta: f64) -> Matrix3<f64> {
        let (s, c) = theta.sin_cos();
        Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0)
    }

    fn random_tangent(rng: &mut Rng, max_angle: f64) -> Vector6<f64> {
        let rho = rng.normal3() * 3.0;
        let axis = rng.normal3().normalize();
        let phi = axis * rng.range(0.0, max_angle);
        xi(rho.into(), phi.into())
    }

    fn random_pose(rng: &mut Rng) -> Isometry3<f64> {
        exp(&random_tangent(rng, PI))
    }

    #[test]
    fn hat_is_the_cross_product() {
        let a = Vector3::new(0.3, -1.2, 2.5);
        let b = Vector3::new(-0.7, 0.4, 1.1);
        assert!((hat(&a) * b - a.cross(&b)).amax() < 1e-15);
        assert_eq!(hat(&a), -hat(&a).transpose());
    }

    #[test]
    fn pure_rotation_about_z_is_the_planar_rotation_matrix() {
        for theta in [0.0, 1e-9, 0.3, FRAC_PI_2, 2.0, PI] {
            let pose = exp(&xi([0.0; 3], [0.0, 0.0, theta]));
            assert_eq!(pose.translation.vector, Vector3::zeros());
            let r = pose.rotation.to_rotation_matrix().into_inner();
            assert!((r - rot_z(theta)).amax() < 1e-15, "θ = {theta}");
        }
    }

    #[test]
    fn pure_rotation_about_a_general_axis_is_rodrigues() {
        let axis = Vector3::new(1.0, -2.0, 0.5).normalize();
        let theta: f64 = 1.3;
        let k = hat(&axis);
        let expected = Matrix3::identity() + k * theta.sin() + k * k * (1.0 - theta.cos());
        let r = exp(&xi([0.0; 3], (axis * theta).into())).rotation.to_rotation_matrix().into_inner();
        assert!((r - expected).amax() < 1e-15);
    }

    #[test]
    fn pure_translation_is_the_tangent_itself() {
        let pose = exp(&xi([1.5, -2.0, 0.25], [0.0; 3]));
        assert_eq!(pose.translation.vector, Vector3::new(1.5, -2.0, 0.25));
        assert_eq!(pose.rotation, UnitQuaternion::identity());
        assert_eq!(log(&pose), xi([1.5, -2.0, 0.25], [0.0; 3]));
    }

    #[test]
    fn screw_motion_about_z_follows_the_circle() {
        // Moving at unit speed along body x while turning at unit rate about z for θ: the
        // body traces a circle of radius v/ω = 1 from the origin, ending at (sin θ, 1 − cos θ);
        // speed along the axis just adds.
        for theta in [1e-6, 0.1, 0.49, 0.51, 1.0, PI, 2.0 * PI] {
            let pose = exp(&xi([theta, 0.0, 0.7], [0.0, 0.0, theta]));
            let expected = Vector3::new(theta.sin(), 1.0 - theta.cos(), 0.7);
            assert!((pose.translation.vector - expected).amax() < 1e-15, "θ = {theta}");
        }
    }

    #[test]
    fn small_angle_limits_match_the_series() {
        // t = ρ + ½ φ×ρ + ⅙ φ×(φ×ρ) + O(θ³|ρ|)
        let rho = Vector3::new(0.8, -0.3, 1.7);
        let dir = Vector3::new(0.2, 0.9, -0.4).normalize();
        for theta in [0.0, 1e-12, 1e-8, 1e-5] {
            let phi = dir * theta;
            let pose = exp(&xi(rho.into(), phi.into()));
            let expected = rho + phi.cross(&rho) * 0.5 + phi.cross(&phi.cross(&rho)) / 6.0;
            assert!((pose.translation.vector - expected).amax() < 1e-15, "θ = {theta}");
            let r = pose.rotation.to_rotation_matrix().into_inner();
            let r_series = Matrix3::identity() + hat(&phi) + hat(&phi) * hat(&phi) * 0.5;
            assert!((r - r_series).amax() < 1e-15, "θ = {theta}");
            let back = log(&pose);
            assert!((back - xi(rho.into(), phi.into())).amax() < 1e-15, "θ = {theta}");
        }
    }

    #[test]
    fn series_and_closed_forms_agree_where_they_hand_over() {
        for theta in [V_SERIES_BELOW_RAD, 0.9 * V_SERIES_BELOW_RAD] {
            let (a_series, b_series) = v_coefficients_series(theta);
            let (a_closed, b_closed) = v_coefficients_closed(theta);
            assert!((a_series / a_closed - 1.0).abs() < 1e-15, "a at {theta}");
            // θ − sin θ loses log10(6/θ²) ≈ 1.4 digits here.
            assert!((b_series / b_closed - 1.0).abs() < 1e-14, "b at {theta}");
        }
        for theta in [V_INV_SERIES_BELOW_RAD, 0.9 * V_INV_SERIES_BELOW_RAD] {
            let cot_half = 1.0 / (0.5 * theta).tan();
            let series = v_inv_coefficient_series(theta);
            // 1 − (θ/2)cot(θ/2) ≈ θ²/12 loses about 3 digits at 0.1 rad.
            assert!((series / v_inv_coefficient_closed(theta, cot_half) - 1.0).abs() < 1e-12, "c at {theta}");
        }
        // Small angles: the leading terms of the Taylor series.
        let (a, b) = v_coefficients(1e-3);
        assert!((a - (0.5 - 1e-6 / 24.0 + 1e-12 / 720.0)).abs() < 1e-16);
        assert!((b - (1.0 / 6.0 - 1e-6 / 120.0 + 1e-12 / 5040.0)).abs() < 1e-16);
        let c = v_inv_coefficient(1e-3, 1.0 / 5e-4f64.tan());
        assert!((c - (1.0 / 12.0 + 1e-6 / 720.0 + 1e-12 / 30240.0)).abs() < 1e-16);
        // Half a turn's c is 1/π² exactly (cot(π/2) = 0).
        let pi_c = v_inv_coefficient(PI, 0.0);
        assert!((pi_c - 1.0 / (PI * PI)).abs() < 1e-17);
    }

    #[test]
    fn exp_is_a_one_parameter_subgroup() {
        // exp(sξ)·exp(uξ) = exp((s+u)ξ), and n steps of ξ/n compose to exp(ξ).
        let mut rng = stream(7, &[1]);
        for _ in 0..200 {
            let xi = random_tangent(&mut rng, 3.0);
            let (s, u) = (rng.range(-1.0, 1.0), rng.range(-1.0, 1.0));
            assert!(pose_diff(&(exp(&(xi * s)) * exp(&(xi * u))), &exp(&(xi * (s + u)))) < 1e-13);
            let step = exp(&(xi / 16.0));
            let composed = (0..16).fold(Isometry3::identity(), |acc, _| acc * step);
            assert!(pose_diff(&composed, &exp(&xi)) < 1e-13);
            assert!(pose_diff(&exp(&(-xi)), &exp(&xi).inverse()) < 1e-14);
        }
    }

    #[test]
    fn translation_then_rotation_composes_to_the_known_pose() {
        let t = exp(&xi([1.0, 2.0, 3.0], [0.0; 3]));
        let r = exp(&xi([0.0; 3], [0.0, 0.0, FRAC_PI_2]));
        let tr = t * r;
        assert!((tr.translation.vector - Vector3::new(1.0, 2.0, 3.0)).amax() < 1e-15);
        assert!((tr.rotation.to_rotation_matrix().into_inner() - rot_z(FRAC_PI_2)).amax() < 1e-15);
        // Rotating first turns the later translation: (1, 2, 3) becomes (−2, 1, 3).
        let rt = r * t;
        assert!((rt.translation.vector - Vector3::new(-2.0, 1.0, 3.0)).amax() < 1e-15);
    }

    #[test]
    fn log_inverts_exp_up_to_a_half_turn() {
        let mut rng = stream(7, &[2]);
        for _ in 0..500 {
            let xi = random_tangent(&mut rng, PI - 1e-6);
            let back = log(&exp(&xi));
            assert!((back - xi).amax() < 1e-9 * (1.0 + xi.amax()), "{xi} vs {back}");
        }
        // A turn beyond π comes back as the shorter turn the other way, same pose.
        let long = xi([0.5, 0.0, 0.0], [0.0, 0.0, 1.5 * PI]);
        let short = log(&exp(&long));
        assert!((short[5] + 0.5 * PI).abs() < 1e-14);
        assert!(pose_diff(&exp(&short), &exp(&long)) < 1e-14);
    }

    #[test]
    fn exp_inverts_log() {
        let mut rng = stream(7, &[3]);
        for _ in 0..500 {
            let pose = random_pose(&mut rng);
            assert!(pose_diff(&exp(&log(&pose)), &pose) < 1e-13);
        }
    }

    #[test]
    fn adjoint_moves_a_right_perturbation_to_the_left() {
        let mut rng = stream(7, &[4]);
        for _ in 0..200 {
            let pose = random_pose(&mut rng);
            let delta = random_tangent(&mut rng, 1.0);
            let right = pose * exp(&delta) * pose.inverse();
            let left = exp(&(adjoint(&pose) * delta));
            assert!(pose_diff(&right, &left) < 1e-12);
        }
    }

    #[test]
    fn adjoint_closed_forms() {
        let mut rng = stream(7, &[5]);
        let (a, b) = (random_pose(&mut rng), random_pose(&mut rng));
        assert!((adjoint(&(a * b)) - adjoint(&a) * adjoint(&b)).amax() < 1e-13);
        assert!((adjoint(&a.inverse()) * adjoint(&a) - Matrix6::identity()).amax() < 1e-13);
        // A pure rotation acts on both halves alike; a pure translation only couples the
        // rotation into the translation, by the lever arm t × δφ.
        let r = exp(&xi([0.0; 3], [0.3, -0.2, 0.9]));
        let rm = r.rotation.to_rotation_matrix().into_inner();
        let ad_r = adjoint(&r);
        assert_eq!(ad_r.fixed_view::<3, 3>(0, 3).into_owned(), Matrix3::zeros());
        assert_eq!(ad_r.fixed_view::<3, 3>(0, 0).into_owned(), rm);
        assert_eq!(ad_r.fixed_view::<3, 3>(3, 3).into_owned(), rm);
        let t = Vector3::new(1.0, -2.0, 0.5);
        let ad_t = adjoint(&exp(&xi(t.into(), [0.0; 3])));
        let delta = xi([0.0; 3], [0.01, 0.02, -0.03]);
        let moved = ad_t * delta;
        let lever = t.cross(&delta.fixed_rows::<3>(3).into_owned());
        assert!((moved - xi(lever.into(), [0.01, 0.02, -0.03])).amax() < 1e-16);
        assert_eq!(adjoint(&Isometry3::identity()), Matrix6::identity());
    }
}
