//! Stereo error model (thesis eqs. 5.2–5.4, after Hirschmüller 2003): how far a triangulated
//! point, and the distance between two of them, may be off for a given pixel error.
//!
//! Frames: the left rectified camera's optical frame, right camera at `+b` along x. The error is
//! a first-order propagation of independent noise `Δp` on `u_l, v_l, u_r, v_r` through
//! `x = b·u_l/δ`, `y = b·v/δ`, `z = f·b/δ` with `δ = u_l − u_r` and `v = (v_l + v_r)/2`.

/// The camera-dependent constants of the error model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StereoErrorModel {
    /// Pixel error `Δp`; the thesis uses 0.5 px because its calibration RMSE reached 0.46 px.
    pub pixel_error_px: f64,
    pub f_px: f64,
    pub baseline_m: f64,
}

impl StereoErrorModel {
    /// Per-axis error of a point `p_cam` (eqs. 5.2a–c).
    pub fn point_error_m(&self, p_cam: &[f64; 3]) -> [f64; 3] {
        let [x, y, z] = *p_cam;
        let b = self.baseline_m;
        let k = self.pixel_error_px * z / (self.f_px * b);
        [k * ((b - x).powi(2) + x * x).sqrt(), k * (2.0 * y * y + 0.5 * b * b).sqrt(), k * z * std::f64::consts::SQRT_2]
    }

    /// Depth error at depth `z_m` (eq. 5.2c): the range cutoff test needs only this.
    pub fn depth_error_m(&self, z_m: f64) -> f64 {
        self.pixel_error_px * z_m * z_m / (self.f_px * self.baseline_m) * std::f64::consts::SQRT_2
    }

    /// The depth at which [`Self::depth_error_m`] reaches `max_error_m`: the maximum view
    /// distance (spec trap 13: the thesis's "[2.5 m, 5 m]" are such distances).
    pub fn max_depth_m(&self, max_error_m: f64) -> f64 {
        (max_error_m * self.f_px * self.baseline_m / (self.pixel_error_px * std::f64::consts::SQRT_2)).sqrt()
    }

    /// Error `Δd` of the distance between two camera-frame points (eqs. 5.3, 5.4a–f with the
    /// corrected 5.4b of spec §2.5.3: `(b − q_x)` and a minus before `(q_z − p_z)·q_z`).
    /// Zero for coincident points, where the distance's direction is undefined.
    pub fn distance_error_m(&self, p_cam: &[f64; 3], q_cam: &[f64; 3]) -> f64 {
        let [px, py, pz] = *p_cam;
        let [qx, qy, qz] = *q_cam;
        let b = self.baseline_m;
        let (dx, dy, dz) = (qx - px, qy - py, qz - pz);
        let d = (dx * dx + dy * dy + dz * dz).sqrt();
        if d <= f64::EPSILON {
            return 0.0;
        }
        let a = (dx * (b - qx) - dy * qy - dz * qz).powi(2);
        let bb = (dx * qx + dy * qy + dz * qz).powi(2);
        let c = 0.5 * (b * dy).powi(2);
        let dd = (dx * (b - px) - dy * py - dz * pz).powi(2);
        let e = (dx * px + dy * py + dz * pz).powi(2);
        self.pixel_error_px / (d * self.f_px * b) * (qz * qz * (a + bb + c) + pz * pz * (c + dd + e)).sqrt()
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    const MODEL: StereoErrorModel = StereoErrorModel { pixel_error_px: 0.5, f_px: 1080.0, baseline_m: 0.09 };

    /// The point of pixel coordinates `[u_l, v_l, u_r, v_r]` (relative to the principal point).
    fn triangulate(m: &StereoErrorModel, px: [f64; 4]) -> [f64; 3] {
        let disparity = px[0] - px[2];
        let v = 0.5 * (px[1] + px[3]);
        let b = m.baseline_m;
        [b * px[0] / disparity, b * v / disparity, m.f_px * b / disparity]
    }

    fn project(m: &StereoErrorModel, p: &[f64; 3]) -> [f64; 4] {
        let [x, y, z] = *p;
        let f = m.f_px;
        [f * x / z, f * y / z, f * (x - m.baseline_m) / z, f * y / z]
    }

    /// First-order propagation by central differences: the reference the closed forms must meet.
    fn numeric_distance_error(m: &StereoErrorModel, p: &[f64; 3], q: &[f64; 3]) -> f64 {
        let pixels = [project(m, p), project(m, q)];
        let distance = |px: &[[f64; 4]; 2]| {
            let (a, b) = (triangulate(m, px[0]), triangulate(m, px[1]));
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        };
        let h = 1e-4;
        let mut sum = 0.0;
        for point in 0..2 {
            for coord in 0..4 {
                let (mut plus, mut minus) = (pixels, pixels);
                plus[point][coord] += h;
                minus[point][coord] -= h;
                let derivative = (distance(&plus) - distance(&minus)) / (2.0 * h);
                sum += (derivative * m.pixel_error_px).powi(2);
            }
        }
        sum.sqrt()
    }

    #[test]
    fn corrected_eq_5_4_reproduces_the_spec_check() {
        let (p, q) = ([0.3, -0.4, 2.5], [-0.2, -0.35, 3.4]);
        let closed = MODEL.distance_error_m(&p, &q);
        assert!((closed - 0.084525).abs() < 5e-7, "Δd = {closed}");
        let numeric = numeric_distance_error(&MODEL, &p, &q);
        assert!((closed - numeric).abs() < 1e-8, "closed {closed} vs numeric {numeric}");
        // The misprinted sign gives the spec's 0.081824 m: the correction is not a no-op here.
        assert!((closed - 0.081824).abs() > 2e-3);
    }

    #[test]
    fn distance_error_matches_propagation_across_geometries() {
        let cases = [
            ([0.0, 0.8, 2.0], [0.1, 0.9, 2.3]),
            ([-1.0, 0.5, 4.0], [-0.9, 0.4, 4.1]),
            ([0.5, 1.2, 1.5], [0.5, 1.0, 1.5]),
            ([2.0, -0.3, 6.0], [-2.0, 0.3, 3.0]),
        ];
        for (p, q) in cases {
            let closed = MODEL.distance_error_m(&p, &q);
            let numeric = numeric_distance_error(&MODEL, &p, &q);
            assert!((closed - numeric).abs() < 1e-8 * closed.max(1.0), "{p:?} {q:?}: {closed} vs {numeric}");
        }
    }

    #[test]
    fn point_error_matches_propagation() {
        let p = [0.4, 0.7, 3.0];
        let pixels = project(&MODEL, &p);
        let h = 1e-4;
        let mut var = [0.0; 3];
        for coord in 0..4 {
            let (mut plus, mut minus) = (pixels, pixels);
            plus[coord] += h;
            minus[coord] -= h;
            let (a, b) = (triangulate(&MODEL, plus), triangulate(&MODEL, minus));
            for axis in 0..3 {
                var[axis] += ((a[axis] - b[axis]) / (2.0 * h) * MODEL.pixel_error_px).powi(2);
            }
        }
        let closed = MODEL.point_error_m(&p);
        for axis in 0..3 {
            assert!((closed[axis] - var[axis].sqrt()).abs() < 1e-9, "axis {axis}: {closed:?} vs {var:?}");
        }
        assert!((MODEL.depth_error_m(3.0) - closed[2]).abs() < 1e-12);
    }

    #[test]
    fn view_distance_for_0_15_m_matches_the_thesis_narrow_camera() {
        // Spec §2.5.2: Δp_z = 0.15 m at z ≈ 4.5 m for f = 1080 px; 0.116 m at 4 m.
        let z = MODEL.max_depth_m(0.15);
        assert!((z - 4.54).abs() < 0.01, "{z}");
        assert!((MODEL.depth_error_m(4.0) - 0.116).abs() < 5e-4);
    }
}
