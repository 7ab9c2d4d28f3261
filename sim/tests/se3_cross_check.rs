//! The simulator's SE(3) maps against posegraph's: two implementations written independently must
//! agree, or the ground truth and the back-end it checks disagree about what a tangent means.

use nalgebra::{Isometry3, Vector6};
use sim::rng::stream;

fn pose_diff(a: &Isometry3<f64>, b: &Isometry3<f64>) -> f64 {
    let dt = (a.translation.vector - b.translation.vector).amax();
    let dr = (a.rotation.to_rotation_matrix().into_inner() - b.rotation.to_rotation_matrix().into_inner()).amax();
    dt.max(dr)
}

#[test]
fn exp_log_and_adjoint_agree_with_posegraph() {
    let mut rng = stream(42, &[]);
    // Angles across every regime: zero, below and above both implementations' series switches,
    // and up to a half turn (log's range).
    let angles = [
        0.0,
        1e-12,
        1e-7,
        1e-4,
        3e-3,
        9e-3,
        1.1e-2,
        0.05,
        0.099,
        0.101,
        0.3,
        0.499,
        0.501,
        1.0,
        2.0,
        3.0,
        std::f64::consts::PI - 1e-3,
    ];
    let mut worst = [0.0f64; 3];
    for round in 0..300 {
        let angle = if round < angles.len() { angles[round] } else { rng.range(0.0, std::f64::consts::PI - 1e-3) };
        let axis = rng.normal3().normalize() * angle;
        let rho = rng.normal3() * rng.range(0.0, 10.0);
        let xi = Vector6::new(rho.x, rho.y, rho.z, axis.x, axis.y, axis.z);

        let ours = sim::se3::exp(&xi);
        let theirs = posegraph::se3::exp(&xi);
        let scale = 1.0 + rho.norm();
        let exp_diff = pose_diff(&ours, &theirs) / scale;
        assert!(exp_diff < 1e-14, "exp({xi}): {ours} vs {theirs}");

        let log_ours = sim::se3::log(&ours);
        let log_theirs = posegraph::se3::log(&ours);
        let log_diff = (log_ours - log_theirs).amax() / scale;
        assert!(log_diff < 1e-14, "log: {log_ours} vs {log_theirs}");

        let ad_ours = sim::se3::adjoint(&ours);
        let ad_theirs = posegraph::se3::adjoint(&ours);
        let ad_diff = (ad_ours - ad_theirs).amax() / scale;
        assert!(ad_diff < 1e-14, "adjoint of {ours}");
        for (w, d) in worst.iter_mut().zip([exp_diff, log_diff, ad_diff]) {
            *w = w.max(d);
        }
    }
    // Relative to 1 + |ρ|.
    println!("largest difference to posegraph: exp {:.1e}, log {:.1e}, adjoint {:.1e}", worst[0], worst[1], worst[2]);
}
