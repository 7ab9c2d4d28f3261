//! Relative poses between two nodes of one robot from its odometry alone: the frame switches `w`
//! between its submap origins and the filter poses `v` of its robot-pose nodes, with first-order
//! covariance propagation (graph convention: `[translation, rotation]`, right perturbation).
//!
//! The consistency check ([`super::consistency`]) judges inter-robot closures against these
//! paths rather than against the optimizer's estimate: the other robot's nodes are not in the
//! optimizer before a closure connects it (trap 7), the estimate is shaped by the very closures
//! being judged, and a relative marginal would need joint marginals. Odometry covariance bounds
//! the relative uncertainty from above (loop closures only shrink it), so the test errs towards
//! accepting.

use std::collections::BTreeMap;

use nalgebra::{Isometry3, Matrix6};
use posegraph::se3;

use super::covariance;
use super::ids::{NodeId, PoseId, SubmapId};
use super::measurements::{FilterPose, SubmapSwitch};

/// A pose with its covariance (graph convention).
pub(crate) type Uncertain = (Isometry3<f64>, Matrix6<f64>);

/// `a · b` with independent errors: `Σ = Ad(b⁻¹) Σa Ad(b⁻¹)ᵀ + Σb`.
pub(crate) fn compose(a: &Uncertain, b: &Uncertain) -> Uncertain {
    let ad = se3::adjoint(&b.0.inverse());
    (a.0 * b.0, ad * a.1 * ad.transpose() + b.1)
}

/// `a⁻¹`: `(a·Exp(δ))⁻¹ = a⁻¹·Exp(−Ad(a)·δ)`, so `Σ = Ad(a) Σa Ad(a)ᵀ`.
pub(crate) fn invert(a: &Uncertain) -> Uncertain {
    let ad = se3::adjoint(&a.0);
    (a.0.inverse(), ad * a.1 * ad.transpose())
}

/// The odometry of every robot the graph knows.
pub(crate) struct OdometryPaths<'a> {
    /// Frame switches by the submap they start.
    pub switches: &'a BTreeMap<SubmapId, SubmapSwitch>,
    /// The filter pose of every robot-pose node.
    pub poses: &'a BTreeMap<PoseId, FilterPose>,
    /// The graph's floor on filter-derived variances (`TeamGraphConfig::min_filter_variance`).
    pub min_variance: f64,
}

impl OdometryPaths<'_> {
    /// `t_from_to` of two nodes of one robot; `None` for a landmark, nodes of two robots, or a
    /// switch not received yet.
    pub fn relative(&self, from: NodeId, to: NodeId) -> Option<Uncertain> {
        let (robot_from, submap_from, v_from) = self.anchor(from)?;
        let (robot_to, submap_to, v_to) = self.anchor(to)?;
        if robot_from != robot_to {
            return None;
        }
        let chain = if submap_from <= submap_to {
            self.chain(robot_from, submap_from, submap_to)?
        } else {
            invert(&self.chain(robot_from, submap_to, submap_from)?)
        };
        // Two poses of one submap share the filter's error since the switch; taking them as
        // independent overstates the variance of their difference, the safe side here.
        Some(compose(&compose(&invert(&v_from), &chain), &v_to))
    }

    /// A node's submap and its pose in that submap's origin.
    fn anchor(&self, node: NodeId) -> Option<(u16, u32, Uncertain)> {
        match node {
            NodeId::Submap(id) => Some((id.robot, id.index, (Isometry3::identity(), Matrix6::zeros()))),
            NodeId::Pose(id) => {
                let pose = self.poses.get(&id)?;
                let covariance = covariance::clamp_eigenvalues(&pose.covariance, self.min_variance);
                Some((id.robot, pose.submap_index, (pose.t_submap_body, covariance)))
            }
            NodeId::Landmark(_) => None,
        }
    }

    /// Submap `to`'s origin in submap `from`'s, `from ≤ to`, along the switches.
    fn chain(&self, robot: u16, from: u32, to: u32) -> Option<Uncertain> {
        let mut out: Uncertain = (Isometry3::identity(), Matrix6::zeros());
        for index in from + 1..=to {
            let switch = self.switches.get(&SubmapId::new(robot, index))?;
            let covariance = covariance::clamp_eigenvalues(&switch.covariance, self.min_variance);
            out = compose(&out, &(switch.t_old_new, covariance));
        }
        Some(out)
    }
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion, Vector6};

    use super::*;

    fn pose(x: f64, y: f64, yaw: f64) -> Isometry3<f64> {
        Isometry3::from_parts(Translation3::new(x, y, 0.0), UnitQuaternion::from_euler_angles(0.0, 0.0, yaw))
    }

    /// Monte-Carlo check of the propagation: sample both factors' errors, compare covariances.
    #[test]
    fn compose_and_invert_propagate_like_sampling() {
        let a: Uncertain =
            (pose(2.0, 1.0, 0.7), Matrix6::from_diagonal(&Vector6::new(0.01, 0.02, 0.005, 1e-3, 2e-3, 4e-3)));
        let b: Uncertain =
            (pose(-1.0, 3.0, -0.4), Matrix6::from_diagonal(&Vector6::new(0.03, 0.01, 0.002, 2e-3, 1e-3, 3e-3)));
        let (mean, predicted) = compose(&invert(&a), &b);
        let mut state = 12345_u64;
        let mut normal = || {
            // Box–Muller on a xorshift stream: deterministic and dependency-free.
            let mut uniform = || {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                (state >> 11) as f64 / (1u64 << 53) as f64
            };
            let (u1, u2) = (uniform().max(1e-300), uniform());
            (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
        };
        let n = 20_000;
        let mut sampled = Matrix6::zeros();
        for _ in 0..n {
            let da = Vector6::from_fn(|i, _| a.1[(i, i)].sqrt() * normal());
            let db = Vector6::from_fn(|i, _| b.1[(i, i)].sqrt() * normal());
            let noisy = (a.0 * se3::exp(&da)).inverse() * (b.0 * se3::exp(&db));
            let e = se3::local(&mean, &noisy);
            sampled += e * e.transpose() / n as f64;
        }
        for i in 0..6 {
            let ratio = sampled[(i, i)] / predicted[(i, i)];
            assert!(
                (0.9..1.1).contains(&ratio),
                "axis {i}: sampled {} predicted {}",
                sampled[(i, i)],
                predicted[(i, i)]
            );
        }
    }
}
