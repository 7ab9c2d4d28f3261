//! Pose-graph problems from g2o files, set up the way GTSAM's `Pose3SLAMExample_g2o` does, so
//! that costs compare with GTSAM's directly.

use crate::error::GraphError;
use crate::factor::{Factor, FactorKind, Key, NoiseModel, RobustKernel};
use crate::g2o::{Dimension, G2oEdge, G2oGraph, G2oVertex};
use crate::incremental::Isam;
use crate::se3::Pose3;
use crate::values::Values;

/// Standard deviations of the prior that holds the first vertex: 1 cm and 1 mrad, GTSAM's
/// example (`Variances(1e-6 ×3 rotation, 1e-4 ×3 translation)`).
pub const ANCHOR_SIGMAS: [f64; 6] = [1e-2, 1e-2, 1e-2, 1e-3, 1e-3, 1e-3];

/// A graph ready to optimize.
#[derive(Debug, Clone)]
pub struct Problem {
    pub values: Values,
    /// The anchoring prior first, then the edges in file order.
    pub factors: Vec<Factor>,
}

/// Which edges get a robust kernel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RobustSelection {
    pub kernel: RobustKernel,
    /// Only edges between non-consecutive ids (loop closures), as the thesis applies the kernel
    /// to detections and matches but not to odometry-like filter factors.
    pub loop_closures_only: bool,
}

/// Whether an edge is odometry (between consecutive ids) rather than a loop closure.
pub fn is_odometry(from: u64, to: u64) -> bool {
    from.abs_diff(to) == 1
}

/// Builds the problem: every vertex a variable (key = vertex id), every edge a between factor,
/// and a prior on the first vertex at its initial value.
pub fn from_g2o(graph: &G2oGraph, robust: Option<RobustSelection>) -> Result<Problem, GraphError> {
    let mut values = Values::new();
    for vertex in &graph.vertices {
        values.insert(Key(vertex.id), vertex.pose)?;
    }
    let mut factors = Vec::with_capacity(graph.edges.len() + 1);
    if let Some(first) = graph.vertices.first() {
        factors.push(Factor::prior(Key(first.id), first.pose, NoiseModel::from_sigmas(ANCHOR_SIGMAS)?));
    }
    for edge in &graph.edges {
        for id in [edge.from, edge.to] {
            if !values.contains(Key(id)) {
                return Err(GraphError::UnknownVariable(Key(id)));
            }
        }
        let mut noise = NoiseModel::from_information(edge.information).map_err(|e| match e {
            GraphError::InvalidNoise(reason) => GraphError::InvalidEdgeNoise { from: edge.from, to: edge.to, reason },
            other => other,
        })?;
        if let Some(selection) = robust
            && (!selection.loop_closures_only || !is_odometry(edge.from, edge.to))
        {
            noise = noise.with_kernel(selection.kernel);
        }
        factors.push(Factor::between(Key(edge.from), Key(edge.to), edge.measurement, noise));
    }
    Ok(Problem { values, factors })
}

/// The problem's between factors with the given poses, as a 3-D g2o graph (priors are not a g2o
/// record; the first vertex is written as `FIX`).
pub fn to_g2o(factors: &[Factor], values: &Values) -> G2oGraph {
    let vertices = values.iter().map(|(key, pose)| G2oVertex { id: key.0, pose: *pose }).collect();
    let edges = factors
        .iter()
        .filter(|f| f.kind() == FactorKind::Between)
        .map(|f| G2oEdge {
            from: f.keys()[0].0,
            to: f.keys()[1].0,
            measurement: *f.measured(),
            information: *f.noise().information(),
        })
        .collect();
    let fixed = values.keys().first().map(|k| vec![k.0]).unwrap_or_default();
    G2oGraph { dimension: Dimension::Three, vertices, edges, fixed }
}

/// One step of feeding a problem to the incremental smoother the way GTSAM's iSAM2 examples
/// do: a new pose with all factors that connect it to earlier poses (its odometry edge plus
/// its loop closures; the anchoring prior comes with the first pose).
#[derive(Debug, Clone)]
pub struct IncrementalStep {
    pub key: Key,
    pub factors: Vec<Factor>,
    /// The odometry edge from the previous pose, if any: the new pose's initial value is the
    /// previous pose's current estimate composed with it.
    pub odometry_from: Option<(Key, Pose3)>,
    /// Initial value when there is no odometry edge (the file's value).
    pub fallback: Pose3,
}

impl IncrementalStep {
    /// The initial value given the smoother's current estimates.
    pub fn initial_value(&self, isam: &Isam) -> Pose3 {
        self.odometry_from
            .and_then(|(previous, measured)| isam.estimate(previous).map(|p| p * measured))
            .unwrap_or(self.fallback)
    }
}

/// Splits a problem into steps in vertex order. Every factor lands in the step of its latest
/// variable (in vertex order); the first step also carries the prior.
pub fn incremental_steps(problem: &Problem) -> Vec<IncrementalStep> {
    let keys = problem.values.keys();
    let mut steps: Vec<IncrementalStep> = problem
        .values
        .iter()
        .map(|(key, pose)| IncrementalStep { key, factors: Vec::new(), odometry_from: None, fallback: *pose })
        .collect();
    for factor in &problem.factors {
        let Some(step) = factor.keys().iter().filter_map(|&k| problem.values.index_of(k)).max() else { continue };
        if factor.kind() == FactorKind::Between && step > 0 {
            let (from, to) = (factor.keys()[0], factor.keys()[1]);
            if to == keys[step] && from == keys[step - 1] && steps[step].odometry_from.is_none() {
                steps[step].odometry_from = Some((from, *factor.measured()));
            } else if from == keys[step] && to == keys[step - 1] && steps[step].odometry_from.is_none() {
                steps[step].odometry_from = Some((to, factor.measured().inverse()));
            }
        }
        steps[step].factors.push(factor.clone());
    }
    steps
}
