//! Unit tests of the internal stages on the synthetic terrain (tests/common/terrain.rs).
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::sync::Arc;

use nalgebra::{Isometry3, Point3, Translation3, UnitQuaternion, Vector3};

use super::icp::{Problem, icp};
use super::params::{MatchMode, MatcherParams};
use super::prepared::PreparedCloud;
use crate::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};

#[path = "../../tests/common/terrain.rs"]
mod terrain;

fn errors(est: &Isometry3<f64>, truth: &Isometry3<f64>) -> (f64, f64) {
    let d = truth.inverse() * est;
    (d.translation.vector.norm(), d.rotation.angle().to_degrees())
}

fn rmse_at(t: &Isometry3<f64>, source: &PreparedCloud, target: &PreparedCloud, gate: f32) -> (f64, usize) {
    let tf = t.cast::<f32>();
    let mut sum = 0.0;
    let mut n = 0;
    for p in source.positions() {
        if let Some((_, d2)) = target.index().nearest(&(tf * p))
            && d2 <= gate * gate
        {
            sum += f64::from(d2);
            n += 1;
        }
    }
    ((sum / n.max(1) as f64).sqrt(), n)
}

#[test]
fn lm_icp_converges_from_a_perturbed_start() {
    let pair = terrain::standard_pair(0.01);
    for mode in [MatchMode::FourDof, MatchMode::SixDof] {
        let params = MatcherParams::with_mode(mode);
        let source = PreparedCloud::new(Arc::new(pair.source.clone()), &params);
        let target = PreparedCloud::new(Arc::new(pair.target.clone()), &params);
        let start = pair.t_target_source
            * Isometry3::from_parts(
                Translation3::new(0.15, -0.1, 0.05),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 2f64.to_radians()),
            );
        eprintln!(
            "truth rmse {:?}, start rmse {:?}",
            rmse_at(&pair.t_target_source, &source, &target, 0.15),
            rmse_at(&start, &source, &target, 0.15)
        );
        let problem = Problem {
            source: source.positions(),
            target: target.positions(),
            target_normals: target.normals(),
            metric: params.icp_metric,
        };
        let r = icp(&problem, target.index(), &start, &params).unwrap();
        let (dt, dr) = errors(&r.t_target_source, &pair.t_target_source);
        eprintln!(
            "{mode:?}: error {dt:.4} m {dr:.3}°, rmse {:.4}, {} pairs, {} iterations",
            r.rmse_m,
            r.pairs.len(),
            r.iterations
        );
        assert!(dt < 0.02 && dr < 0.2, "{mode:?}: error {dt:.3} m, {dr:.2}°");
    }
}
