//! g2o import and export, so the back-end can be checked on the standard public pose-graph
//! benchmarks (sphere2500, parking-garage, intel, MIT, CSAIL, manhattan, …) and its results
//! compared with g2o, GTSAM and SE-Sync.
//!
//! # Records
//!
//! | record | fields |
//! |---|---|
//! | `VERTEX_SE3:QUAT` | `id x y z qx qy qz qw` |
//! | `EDGE_SE3:QUAT` | `i j x y z qx qy qz qw` + 21 information entries |
//! | `VERTEX_SE2` | `id x y θ` |
//! | `EDGE_SE2` | `i j dx dy dθ I11 I12 I13 I22 I23 I33` |
//! | `VERTEX3` (legacy) | `id x y z roll pitch yaw` |
//! | `EDGE3` (legacy) | `i j x y z roll pitch yaw` + 21 information entries |
//! | `FIX` | `id…` |
//!
//! Information entries are the row-major upper triangle of the 6×6 matrix in the project's
//! `[translation, rotation]` order, which is also g2o's; the lower triangle is mirrored. Legacy
//! Euler angles mean `Rz(yaw)·Ry(pitch)·Rx(roll)`, as GTSAM's `Rot3::Ypr` (the files come from
//! GTSAM's examples). Blank lines and lines starting with `#` are skipped; any other record type
//! is an error rather than silently ignored, because a dropped edge changes the optimum without
//! any visible symptom.
//!
//! # Information units
//!
//! Information matrices are passed through unscaled, as GTSAM's reader does. Note that g2o's
//! `EDGE_SE3:QUAT` error uses the quaternion's vector part (≈ θ/2), so its rotation information
//! is about 4× that of an angle-axis error such as the project's `Log`: sphere2500.g2o's rotation
//! block is (400, 400, 99) where the legacy `EDGE3` records of sphere2500_groundtruth.g2o have
//! (100, 100, 25) over the same translation block (10, 10, 10). That pair is also why `EDGE3`
//! information is read `[translation, rotation]`: GTSAM's reader takes it in its own `[rotation,
//! translation]` order, which would give those edges a translation information of (100, 100, 25)
//! against (10, 10, 10) in the quaternion file.
//!
//! # 2D files
//!
//! The back-end only knows SE(3), so SE(2) records are lifted: a pose `(x, y, θ)` becomes the
//! translation `(x, y, 0)` with rotation θ about z, and the 3×3 information over `(x, y, θ)` lands
//! at indices `[0, 1, 5]` (x, y, yaw) of the 6×6. The lifted measurements say nothing about z,
//! roll and pitch, so with zero information there the lifted problem would be singular. Those
//! axes get z ← `max(I11, I22)` and roll, pitch ← `I33`: the same stiffness as the observed axes,
//! so the lifted normal equations are conditioned like the 2D ones, and since every lifted
//! measurement and vertex has z = roll = pitch = 0, the optimum stays in the plane with the same
//! x, y, yaw as the 2D optimum.
//!
//! # Information that is not positive definite
//!
//! [`parse`] takes information matrices as written; the noise model later refuses those that
//! are not positive definite, without knowing the line. [`parse_with`] tests each edge's matrix
//! as it is read, with the noise model's own test (its Cholesky factorization), and then either
//! rejects the file with an error naming the line and the edge ([`InformationPolicy::Reject`],
//! the default) or replaces the matrix by the nearest one whose eigenvalues are all above a
//! floor ([`InformationPolicy::Repair`]; the [`crate::information`] module explains the
//! projection and the floor) and lists the edge in [`CheckedGraph::repaired_edges`]. Published
//! datasets need this: SE-Sync's cubicle has edges with indefinite information. Matrices that
//! pass the test are kept bit for bit. An `EDGE_SE2` matrix is tested and repaired as the
//! file's 3×3 before lifting, so the lifted z, roll and pitch follow the repaired values.
//!
//! # Exact round trips
//!
//! [`write()`] prints every `f64` with Rust's shortest round-trip formatting, so
//! `parse(write(g))` reproduces every bit of a parsed graph. Two read-side rules make that hold
//! for rotations too: a quaternion is only renormalized when its norm differs from 1 by more than
//! rounding (re-dividing an already normalized quaternion by its computed norm would move its
//! last bits on every round trip), and the sign is fixed to `qw ≥ 0` (q and −q are the same
//! rotation, and a canonical sign makes the stored numbers, not just the rotation, reproducible).

use core::fmt;
use std::collections::{BTreeMap, BTreeSet, HashSet, VecDeque};
use std::str::FromStr;

use nalgebra::{Isometry3, Matrix3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector3};

use crate::factor::NoiseModel;
use crate::information::{self, EigenFloor, RepairError};

/// Whether the file described planar (SE(2)) or spatial (SE(3)) poses. Either way the poses in a
/// [`G2oGraph`] are 3D; this only records what the source was.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Dimension {
    /// `VERTEX_SE2` / `EDGE_SE2` records, lifted to 3D.
    Two,
    /// `VERTEX_SE3:QUAT` / `EDGE_SE3:QUAT` or legacy `VERTEX3` / `EDGE3` records. Also the
    /// dimension of a file without pose records.
    #[default]
    Three,
}

/// A pose variable with its initial estimate `t_world_vertex`.
#[derive(Debug, Clone, PartialEq)]
pub struct G2oVertex {
    pub id: u64,
    pub pose: Isometry3<f64>,
}

/// A relative-pose measurement `t_from_to` with its information matrix, ordered
/// `[translation, rotation]`.
#[derive(Debug, Clone, PartialEq)]
pub struct G2oEdge {
    pub from: u64,
    pub to: u64,
    pub measurement: Isometry3<f64>,
    pub information: Matrix6<f64>,
}

/// The contents of a g2o file, in file order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct G2oGraph {
    pub dimension: Dimension,
    pub vertices: Vec<G2oVertex>,
    pub edges: Vec<G2oEdge>,
    /// Ids named by `FIX` records, without duplicates, in order of first mention. They need not
    /// have a vertex record: files without vertices can still fix the first pose.
    pub fixed: Vec<u64>,
}

/// What [`parse_with`] does with an edge whose information matrix is not positive definite.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum InformationPolicy {
    /// Fail with [`G2oErrorKind::NotPositiveDefinite`] at the first such edge.
    #[default]
    Reject,
    /// Project the matrix onto the nearest one with every eigenvalue above the floor.
    Repair(EigenFloor),
}

impl InformationPolicy {
    /// Repair with the default floor ([`crate::information::DEFAULT_RELATIVE_EIGEN_FLOOR`]).
    pub fn repair() -> Self {
        Self::Repair(EigenFloor::default())
    }
}

/// An edge whose information [`parse_with`] repaired. Eigenvalues and the change are those of the
/// matrix as the file states it: 6×6, or 3×3 for `EDGE_SE2`.
#[derive(Debug, Clone, PartialEq)]
pub struct RepairedEdge {
    /// 1-based line of the edge record.
    pub line: usize,
    pub from: u64,
    pub to: u64,
    /// ≤ 0 for the indefinite or semidefinite matrices a repair is for.
    pub smallest_eigenvalue_before: f64,
    /// Every eigenvalue of the repaired matrix is at least this.
    pub eigen_floor: f64,
    /// `‖repaired − file‖_F`, in the file's information units.
    pub frobenius_change: f64,
}

/// A parsed graph, its information matrices all positive definite, and the edges repaired to get
/// there, in file order.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct CheckedGraph {
    pub graph: G2oGraph,
    pub repaired_edges: Vec<RepairedEdge>,
}

/// A parse failure and the 1-based line it happened on.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("line {line}: {kind}")]
pub struct G2oError {
    pub line: usize,
    pub kind: G2oErrorKind,
}

/// What was wrong with a line. Tokens quoted in the variants are cut to a few dozen characters,
/// since a corrupt file can hold arbitrarily long ones.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum G2oErrorKind {
    #[error("unknown record type `{0}`")]
    UnknownRecord(String),
    #[error("{record} record ends before field `{field}`: {found} of {expected} fields present")]
    MissingField { record: &'static str, field: &'static str, expected: usize, found: usize },
    #[error("{record} record has {found} fields, expected {expected}")]
    TrailingFields { record: &'static str, expected: usize, found: usize },
    #[error("field `{field}`: `{token}` is not a number")]
    BadNumber { field: &'static str, token: String },
    #[error("field `{field}`: `{token}` is not finite")]
    NonFinite { field: &'static str, token: String },
    #[error("field `{field}`: `{token}` is not a vertex id (an integer from 0 to 2^64-1)")]
    BadId { field: &'static str, token: String },
    #[error("quaternion norm is zero or too small to define a rotation")]
    ZeroQuaternion,
    #[error("vertex {0} is defined twice")]
    DuplicateVertex(u64),
    #[error("edge from vertex {0} to itself")]
    SelfLoop(u64),
    #[error("the file mixes 2D (SE2) and 3D (SE3) records")]
    MixedDimensions,
    #[error(
        "edge {from} → {to}: information matrix is not positive definite (smallest eigenvalue {smallest_eigenvalue:e})"
    )]
    NotPositiveDefinite { from: u64, to: u64, smallest_eigenvalue: f64 },
    #[error("edge {from} → {to}: information matrix cannot be repaired: {reason}")]
    Unrepairable { from: u64, to: u64, reason: RepairError },
}

/// Failure to derive initial poses from edges.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum InitialPoseError {
    /// The graph falls apart into pieces; the solver would have an unconstrained gauge per piece.
    #[error("vertex {vertex} is not connected by edges to any vertex the initial poses start from")]
    Unreachable { vertex: u64 },
}

/// Quaternions whose norm is below this are rejected: files print about six decimals, so such a
/// quaternion's direction is rounding noise, and real writers never produce one.
const MIN_QUATERNION_NORM: f64 = 1e-6;

/// A quaternion whose squared norm is this close to 1 is kept as is. Normalizing any finite
/// quaternion leaves its squared norm within 3 ε of 1 (measured over 2·10⁷ random quaternions
/// of magnitudes 10⁻³⁰⁰…10³⁰⁰), so normalization is idempotent with this bound.
const UNIT_NORM_SQUARED_TOLERANCE: f64 = 8.0 * f64::EPSILON;

/// Longest token quoted back in an error.
const MAX_QUOTED_CHARS: usize = 40;

const FIELDS_VERTEX_SE3: [&str; 8] = ["id", "x", "y", "z", "qx", "qy", "qz", "qw"];
const FIELDS_VERTEX_SE2: [&str; 4] = ["id", "x", "y", "theta"];
const FIELDS_VERTEX3: [&str; 7] = ["id", "x", "y", "z", "roll", "pitch", "yaw"];
const FIELDS_EDGE_SE3: [&str; 30] = [
    "from", "to", "x", "y", "z", "qx", "qy", "qz", "qw", "I11", "I12", "I13", "I14", "I15", "I16", "I22", "I23", "I24",
    "I25", "I26", "I33", "I34", "I35", "I36", "I44", "I45", "I46", "I55", "I56", "I66",
];
const FIELDS_EDGE3: [&str; 29] = [
    "from", "to", "x", "y", "z", "roll", "pitch", "yaw", "I11", "I12", "I13", "I14", "I15", "I16", "I22", "I23", "I24",
    "I25", "I26", "I33", "I34", "I35", "I36", "I44", "I45", "I46", "I55", "I56", "I66",
];
const FIELDS_EDGE_SE2: [&str; 11] = ["from", "to", "dx", "dy", "dtheta", "I11", "I12", "I13", "I22", "I23", "I33"];

/// Most fields any record has after its tag.
const MAX_FIELDS: usize = 30;

/// Parses a g2o file, information matrices as written (see [`parse_with`] to check them). Total:
/// any input gives a graph or an error, never a panic.
pub fn parse(text: &str) -> Result<G2oGraph, G2oError> {
    read(text, None).map(|checked| checked.graph)
}

/// Parses a g2o file and applies `policy` to every information matrix that is not positive
/// definite (module documentation). Total, as [`parse`].
pub fn parse_with(text: &str, policy: InformationPolicy) -> Result<CheckedGraph, G2oError> {
    read(text, Some(policy))
}

fn read(text: &str, policy: Option<InformationPolicy>) -> Result<CheckedGraph, G2oError> {
    let mut builder = Builder { policy, ..Builder::default() };
    for (index, raw) in text.lines().enumerate() {
        let trimmed = raw.trim_start();
        if trimmed.is_empty() || trimmed.starts_with('#') {
            continue;
        }
        let line = index + 1;
        let mut tokens = trimmed.split_whitespace();
        let tag = tokens.next().unwrap_or_default();
        let added = match tag {
            "VERTEX_SE3:QUAT" => parse_vertex_se3(tokens).and_then(|v| builder.add_vertex(v, Dimension::Three)),
            "EDGE_SE3:QUAT" => parse_edge_se3(tokens).and_then(|e| builder.add_edge(e, None, line)),
            "VERTEX_SE2" => parse_vertex_se2(tokens).and_then(|v| builder.add_vertex(v, Dimension::Two)),
            "EDGE_SE2" => parse_edge_se2(tokens).and_then(|(e, planar)| builder.add_edge(e, Some(planar), line)),
            "VERTEX3" => parse_vertex3(tokens).and_then(|v| builder.add_vertex(v, Dimension::Three)),
            "EDGE3" => parse_edge3(tokens).and_then(|e| builder.add_edge(e, None, line)),
            "FIX" => parse_fix(tokens).map(|ids| builder.add_fixed(ids)),
            other => Err(G2oErrorKind::UnknownRecord(quote(other))),
        };
        added.map_err(|kind| G2oError { line, kind })?;
    }
    Ok(builder.finish())
}

impl FromStr for G2oGraph {
    type Err = G2oError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        parse(text)
    }
}

/// Writes `graph` as `VERTEX_SE3:QUAT`, `FIX` and `EDGE_SE3:QUAT` records, whatever its
/// [`Dimension`]: 2D graphs come out lifted, and re-read as 3D. Only the upper triangle of each
/// information matrix is written, as the format has no room for an asymmetric one.
pub fn write(graph: &G2oGraph, out: &mut impl fmt::Write) -> fmt::Result {
    for vertex in &graph.vertices {
        write!(out, "VERTEX_SE3:QUAT {}", vertex.id)?;
        write_pose(&vertex.pose, out)?;
        writeln!(out)?;
    }
    for id in &graph.fixed {
        writeln!(out, "FIX {id}")?;
    }
    for edge in &graph.edges {
        write!(out, "EDGE_SE3:QUAT {} {}", edge.from, edge.to)?;
        write_pose(&edge.measurement, out)?;
        for row in 0..6 {
            for col in row..6 {
                out.write_char(' ')?;
                write_f64(edge.information[(row, col)], out)?;
            }
        }
        writeln!(out)?;
    }
    Ok(())
}

impl G2oGraph {
    /// The pose of vertex `id`, if the file defined one. A linear scan: for many lookups build a
    /// map once, as [`G2oGraph::initial_from_edges`] does.
    pub fn vertex_pose(&self, id: u64) -> Option<&Isometry3<f64>> {
        self.vertices.iter().find(|vertex| vertex.id == id).map(|vertex| &vertex.pose)
    }

    /// Initial poses for every vertex id in the graph (vertex records and edge endpoints), for
    /// files such as CSAIL or manhattan that carry none. The smallest id is the root, at its
    /// vertex pose if it has one and at the identity otherwise; every other pose composes edge
    /// measurements along a spanning tree that uses as few non-odometry edges (ids not
    /// consecutive) as possible, i.e. follows the odometry chain `i → i+1` where there is one.
    /// Loop closures are only taken where the chain is broken, since they are typically the
    /// least reliable edges (and in benchmark files with injected outliers, the wrong ones).
    pub fn initial_from_edges(&self) -> Result<BTreeMap<u64, Isometry3<f64>>, InitialPoseError> {
        let Some(root) = self.all_ids().first().copied() else { return Ok(BTreeMap::new()) };
        let root_pose = self.vertex_pose(root).copied().unwrap_or_else(Isometry3::identity);
        self.spanning_tree_poses(&[(root, root_pose)])
    }

    /// Adds a vertex for every edge endpoint that has none, so a vertex-less file can be solved
    /// directly. Missing poses are composed along edges, as in [`G2oGraph::initial_from_edges`],
    /// starting from all vertices that have poses (they keep them), so each new pose hangs off
    /// its nearest known neighbour. New vertices are appended in id order. Returns how many were
    /// added.
    pub fn fill_missing_vertices(&mut self) -> Result<usize, InitialPoseError> {
        let sources: Vec<(u64, Isometry3<f64>)> = if self.vertices.is_empty() {
            self.all_ids().first().map(|&root| (root, Isometry3::identity())).into_iter().collect()
        } else {
            self.vertices.iter().map(|vertex| (vertex.id, vertex.pose)).collect()
        };
        let poses = self.spanning_tree_poses(&sources)?;
        let known: HashSet<u64> = self.vertices.iter().map(|vertex| vertex.id).collect();
        let before = self.vertices.len();
        for (id, pose) in poses {
            if !known.contains(&id) {
                self.vertices.push(G2oVertex { id, pose });
            }
        }
        Ok(self.vertices.len() - before)
    }

    /// All ids mentioned by vertex records or edges, sorted.
    fn all_ids(&self) -> Vec<u64> {
        let ids: BTreeSet<u64> = self
            .vertices
            .iter()
            .map(|vertex| vertex.id)
            .chain(self.edges.iter().flat_map(|edge| [edge.from, edge.to]))
            .collect();
        ids.into_iter().collect()
    }

    /// 0-1 breadth-first search (odometry edges cost 0, others 1) from `sources`, composing
    /// measurements along the resulting tree.
    fn spanning_tree_poses(
        &self,
        sources: &[(u64, Isometry3<f64>)],
    ) -> Result<BTreeMap<u64, Isometry3<f64>>, InitialPoseError> {
        let ids = self.all_ids();
        let index_of = |id: u64| ids.binary_search(&id).ok();
        // Per vertex: (edge index, neighbour index, whether the edge points away from the vertex).
        let mut adjacency: Vec<Vec<(usize, usize, bool)>> = vec![Vec::new(); ids.len()];
        for (e, edge) in self.edges.iter().enumerate() {
            if let (Some(a), Some(b)) = (index_of(edge.from), index_of(edge.to)) {
                adjacency[a].push((e, b, true));
                adjacency[b].push((e, a, false));
            }
        }
        let mut cost = vec![usize::MAX; ids.len()];
        let mut pose: Vec<Option<Isometry3<f64>>> = vec![None; ids.len()];
        // How each vertex was reached: (parent index, edge index, forward).
        let mut parent: Vec<Option<(usize, usize, bool)>> = vec![None; ids.len()];
        let mut done = vec![false; ids.len()];
        let mut queue = VecDeque::new();
        for &(id, source_pose) in sources {
            if let Some(i) = index_of(id) {
                cost[i] = 0;
                pose[i] = Some(source_pose);
                queue.push_back(i);
            }
        }
        let mut order = Vec::with_capacity(ids.len());
        while let Some(u) = queue.pop_front() {
            if done[u] {
                continue;
            }
            done[u] = true;
            order.push(u);
            for &(e, v, forward) in &adjacency[u] {
                let edge = &self.edges[e];
                let weight = usize::from(edge.from.abs_diff(edge.to) != 1);
                let candidate = cost[u].saturating_add(weight);
                if candidate < cost[v] {
                    cost[v] = candidate;
                    parent[v] = Some((u, e, forward));
                    if weight == 0 {
                        queue.push_front(v);
                    } else {
                        queue.push_back(v);
                    }
                }
            }
        }
        // A vertex is finalized only after its parent, so one pass in that order suffices.
        for &v in &order {
            if let (None, Some((u, e, forward))) = (pose[v], parent[v])
                && let Some(base) = pose[u]
            {
                let measurement = &self.edges[e].measurement;
                let step = if forward { *measurement } else { measurement.inverse() };
                pose[v] = Some(renormalized(base * step));
            }
        }
        ids.iter()
            .zip(pose)
            .map(|(&vertex, pose)| pose.map(|p| (vertex, p)).ok_or(InitialPoseError::Unreachable { vertex }))
            .collect()
    }
}

/// The graph so far, and what is needed to reject records that conflict with earlier ones.
#[derive(Default)]
struct Builder {
    graph: G2oGraph,
    dimension: Option<Dimension>,
    vertex_ids: HashSet<u64>,
    fixed_ids: HashSet<u64>,
    /// `None`: information is not checked.
    policy: Option<InformationPolicy>,
    repaired_edges: Vec<RepairedEdge>,
}

impl Builder {
    fn add_vertex(&mut self, vertex: G2oVertex, dimension: Dimension) -> Result<(), G2oErrorKind> {
        self.check_dimension(dimension)?;
        if !self.vertex_ids.insert(vertex.id) {
            return Err(G2oErrorKind::DuplicateVertex(vertex.id));
        }
        self.graph.vertices.push(vertex);
        Ok(())
    }

    /// `planar` is the file's 3×3 information of an `EDGE_SE2`, which `edge` carries lifted.
    fn add_edge(&mut self, mut edge: G2oEdge, planar: Option<Matrix3<f64>>, line: usize) -> Result<(), G2oErrorKind> {
        self.check_dimension(if planar.is_some() { Dimension::Two } else { Dimension::Three })?;
        if edge.from == edge.to {
            return Err(G2oErrorKind::SelfLoop(edge.from));
        }
        if let Some(policy) = self.policy
            && !accepted_by_noise_model(&edge.information)
        {
            let (from, to) = (edge.from, edge.to);
            let unrepairable = |reason| G2oErrorKind::Unrepairable { from, to, reason };
            let floor = match policy {
                InformationPolicy::Reject => {
                    let smallest = match planar {
                        Some(planar) => information::smallest_eigenvalue3(&planar),
                        None => information::smallest_eigenvalue6(&edge.information),
                    };
                    let smallest_eigenvalue = smallest.ok_or(unrepairable(RepairError::NoConvergence))?;
                    return Err(G2oErrorKind::NotPositiveDefinite { from, to, smallest_eigenvalue });
                }
                InformationPolicy::Repair(floor) => floor,
            };
            let repaired = match planar {
                Some(planar) => information::repair3(&planar, floor).map(|r| r.map(|m| lift_information(&m))),
                None => information::repair6(&edge.information, floor),
            }
            .map_err(unrepairable)?;
            if !accepted_by_noise_model(&repaired.matrix) {
                return Err(unrepairable(RepairError::Overflow));
            }
            edge.information = repaired.matrix;
            self.repaired_edges.push(RepairedEdge {
                line,
                from,
                to,
                smallest_eigenvalue_before: repaired.smallest_eigenvalue_before,
                eigen_floor: repaired.eigen_floor,
                frobenius_change: repaired.frobenius_change,
            });
        }
        self.graph.edges.push(edge);
        Ok(())
    }

    fn add_fixed(&mut self, ids: Vec<u64>) {
        for id in ids {
            if self.fixed_ids.insert(id) {
                self.graph.fixed.push(id);
            }
        }
    }

    fn check_dimension(&mut self, dimension: Dimension) -> Result<(), G2oErrorKind> {
        match self.dimension {
            None => self.dimension = Some(dimension),
            Some(seen) if seen != dimension => return Err(G2oErrorKind::MixedDimensions),
            Some(_) => {}
        }
        Ok(())
    }

    fn finish(self) -> CheckedGraph {
        CheckedGraph {
            graph: G2oGraph { dimension: self.dimension.unwrap_or_default(), ..self.graph },
            repaired_edges: self.repaired_edges,
        }
    }
}

/// The fields after a record's tag, checked for count before any is interpreted.
struct Fields<'a> {
    tokens: [&'a str; MAX_FIELDS],
    names: &'static [&'static str],
    next: usize,
}

impl<'a> Fields<'a> {
    fn new(
        record: &'static str,
        names: &'static [&'static str],
        tokens: impl Iterator<Item = &'a str>,
    ) -> Result<Self, G2oErrorKind> {
        let expected = names.len();
        let mut stored = [""; MAX_FIELDS];
        let mut found = 0usize;
        for token in tokens {
            if let Some(slot) = stored.get_mut(found)
                && found < expected
            {
                *slot = token;
            }
            found += 1;
        }
        if found < expected {
            let field = names.get(found).copied().unwrap_or("?");
            return Err(G2oErrorKind::MissingField { record, field, expected, found });
        }
        if found > expected {
            return Err(G2oErrorKind::TrailingFields { record, expected, found });
        }
        Ok(Self { tokens: stored, names, next: 0 })
    }

    fn take(&mut self) -> (&'static str, &'a str) {
        let field = self.names.get(self.next).copied().unwrap_or("?");
        let token = self.tokens.get(self.next).copied().unwrap_or("");
        self.next += 1;
        (field, token)
    }

    fn id(&mut self) -> Result<u64, G2oErrorKind> {
        let (field, token) = self.take();
        token.parse().map_err(|_| G2oErrorKind::BadId { field, token: quote(token) })
    }

    fn number(&mut self) -> Result<f64, G2oErrorKind> {
        let (field, token) = self.take();
        let value: f64 = token.parse().map_err(|_| G2oErrorKind::BadNumber { field, token: quote(token) })?;
        if value.is_finite() { Ok(value) } else { Err(G2oErrorKind::NonFinite { field, token: quote(token) }) }
    }

    fn vector3(&mut self) -> Result<Vector3<f64>, G2oErrorKind> {
        Ok(Vector3::new(self.number()?, self.number()?, self.number()?))
    }

    fn quaternion(&mut self) -> Result<UnitQuaternion<f64>, G2oErrorKind> {
        let (x, y, z, w) = (self.number()?, self.number()?, self.number()?, self.number()?);
        unit_quaternion(Quaternion::new(w, x, y, z)).ok_or(G2oErrorKind::ZeroQuaternion)
    }

    fn euler(&mut self) -> Result<UnitQuaternion<f64>, G2oErrorKind> {
        let (roll, pitch, yaw) = (self.number()?, self.number()?, self.number()?);
        let q = UnitQuaternion::from_euler_angles(roll, pitch, yaw).into_inner();
        unit_quaternion(q).ok_or(G2oErrorKind::ZeroQuaternion)
    }

    /// 21 entries of the row-major upper triangle.
    fn information6(&mut self) -> Result<Matrix6<f64>, G2oErrorKind> {
        let mut information = Matrix6::zeros();
        for row in 0..6 {
            for col in row..6 {
                let value = self.number()?;
                information[(row, col)] = value;
                information[(col, row)] = value;
            }
        }
        Ok(information)
    }
}

fn parse_vertex_se3<'a>(tokens: impl Iterator<Item = &'a str>) -> Result<G2oVertex, G2oErrorKind> {
    let mut fields = Fields::new("VERTEX_SE3:QUAT", &FIELDS_VERTEX_SE3, tokens)?;
    let id = fields.id()?;
    let translation = fields.vector3()?;
    let rotation = fields.quaternion()?;
    Ok(G2oVertex { id, pose: Isometry3::from_parts(Translation3::from(translation), rotation) })
}

fn parse_edge_se3<'a>(tokens: impl Iterator<Item = &'a str>) -> Result<G2oEdge, G2oErrorKind> {
    let mut fields = Fields::new("EDGE_SE3:QUAT", &FIELDS_EDGE_SE3, tokens)?;
    let (from, to) = (fields.id()?, fields.id()?);
    let translation = fields.vector3()?;
    let rotation = fields.quaternion()?;
    let information = fields.information6()?;
    let measurement = Isometry3::from_parts(Translation3::from(translation), rotation);
    Ok(G2oEdge { from, to, measurement, information })
}

fn parse_vertex3<'a>(tokens: impl Iterator<Item = &'a str>) -> Result<G2oVertex, G2oErrorKind> {
    let mut fields = Fields::new("VERTEX3", &FIELDS_VERTEX3, tokens)?;
    let id = fields.id()?;
    let translation = fields.vector3()?;
    let rotation = fields.euler()?;
    Ok(G2oVertex { id, pose: Isometry3::from_parts(Translation3::from(translation), rotation) })
}

fn parse_edge3<'a>(tokens: impl Iterator<Item = &'a str>) -> Result<G2oEdge, G2oErrorKind> {
    let mut fields = Fields::new("EDGE3", &FIELDS_EDGE3, tokens)?;
    let (from, to) = (fields.id()?, fields.id()?);
    let translation = fields.vector3()?;
    let rotation = fields.euler()?;
    let information = fields.information6()?;
    let measurement = Isometry3::from_parts(Translation3::from(translation), rotation);
    Ok(G2oEdge { from, to, measurement, information })
}

fn parse_vertex_se2<'a>(tokens: impl Iterator<Item = &'a str>) -> Result<G2oVertex, G2oErrorKind> {
    let mut fields = Fields::new("VERTEX_SE2", &FIELDS_VERTEX_SE2, tokens)?;
    let id = fields.id()?;
    let (x, y, theta) = (fields.number()?, fields.number()?, fields.number()?);
    Ok(G2oVertex { id, pose: planar_pose(x, y, theta)? })
}

/// The edge with its information lifted to 6×6, and the file's 3×3 information.
fn parse_edge_se2<'a>(tokens: impl Iterator<Item = &'a str>) -> Result<(G2oEdge, Matrix3<f64>), G2oErrorKind> {
    let mut fields = Fields::new("EDGE_SE2", &FIELDS_EDGE_SE2, tokens)?;
    let (from, to) = (fields.id()?, fields.id()?);
    let (x, y, theta) = (fields.number()?, fields.number()?, fields.number()?);
    let mut planar = Matrix3::zeros();
    for row in 0..3 {
        for col in row..3 {
            let value = fields.number()?;
            planar[(row, col)] = value;
            planar[(col, row)] = value;
        }
    }
    let edge = G2oEdge { from, to, measurement: planar_pose(x, y, theta)?, information: lift_information(&planar) };
    Ok((edge, planar))
}

fn parse_fix<'a>(tokens: impl Iterator<Item = &'a str>) -> Result<Vec<u64>, G2oErrorKind> {
    let ids = tokens
        .map(|token| token.parse().map_err(|_| G2oErrorKind::BadId { field: "id", token: quote(token) }))
        .collect::<Result<Vec<u64>, _>>()?;
    if ids.is_empty() {
        return Err(G2oErrorKind::MissingField { record: "FIX", field: "id", expected: 1, found: 0 });
    }
    Ok(ids)
}

/// Whether the noise model will take `information`: the reader's test must be the noise model's
/// own, or a matrix could pass here and still fail, unlabelled, when the problem is built.
fn accepted_by_noise_model(information: &Matrix6<f64>) -> bool {
    NoiseModel::from_information(*information).is_ok()
}

/// Axes of the lifted 6×6 information (`[x, y, z, roll, pitch, yaw]`) that the planar
/// `(x, y, θ)` occupy.
const PLANAR_AXES: [usize; 3] = [0, 1, 5];

/// Embeds a planar information matrix; the module documentation explains the unobserved axes.
fn lift_information(planar: &Matrix3<f64>) -> Matrix6<f64> {
    let mut information = Matrix6::zeros();
    for (row, &lifted_row) in PLANAR_AXES.iter().enumerate() {
        for (col, &lifted_col) in PLANAR_AXES.iter().enumerate() {
            information[(lifted_row, lifted_col)] = planar[(row, col)];
        }
    }
    information[(2, 2)] = planar[(0, 0)].max(planar[(1, 1)]);
    information[(3, 3)] = planar[(2, 2)];
    information[(4, 4)] = planar[(2, 2)];
    information
}

fn planar_pose(x: f64, y: f64, theta: f64) -> Result<Isometry3<f64>, G2oErrorKind> {
    let (sin, cos) = (0.5 * theta).sin_cos();
    let rotation = unit_quaternion(Quaternion::new(cos, 0.0, 0.0, sin)).ok_or(G2oErrorKind::ZeroQuaternion)?;
    Ok(Isometry3::from_parts(Translation3::new(x, y, 0.0), rotation))
}

/// Normalizes (unless already unit to rounding) and fixes the sign so that `w` has a clear sign
/// bit. `None` for non-finite or near-zero quaternions.
fn unit_quaternion(q: Quaternion<f64>) -> Option<UnitQuaternion<f64>> {
    let scale = q.coords.amax();
    if !scale.is_finite() || scale == 0.0 {
        return None;
    }
    let scaled = q.coords / scale;
    let scaled_norm = scaled.norm();
    if scale * scaled_norm < MIN_QUATERNION_NORM {
        return None;
    }
    let coords = if (q.coords.norm_squared() - 1.0).abs() <= UNIT_NORM_SQUARED_TOLERANCE {
        q.coords
    } else {
        scaled / scaled_norm
    };
    // `coords` is (i, j, k, w).
    let coords = if coords[3].is_sign_negative() { -coords } else { coords };
    Some(UnitQuaternion::new_unchecked(Quaternion::from(coords)))
}

/// Keeps composed rotations unit and canonical, so poses from [`G2oGraph::fill_missing_vertices`]
/// survive a write/parse round trip bit for bit.
fn renormalized(pose: Isometry3<f64>) -> Isometry3<f64> {
    match unit_quaternion(pose.rotation.into_inner()) {
        Some(rotation) => Isometry3::from_parts(pose.translation, rotation),
        None => pose,
    }
}

fn write_pose(pose: &Isometry3<f64>, out: &mut impl fmt::Write) -> fmt::Result {
    let q = pose.rotation.coords;
    let q = if q[3].is_sign_negative() { -q } else { q };
    for value in pose.translation.vector.iter().chain(q.iter()) {
        out.write_char(' ')?;
        write_f64(*value, out)?;
    }
    Ok(())
}

/// Shortest text that parses back to the same bits: plain digits for ordinary magnitudes, an
/// exponent where plain digits would run to hundreds of zeros.
fn write_f64(value: f64, out: &mut impl fmt::Write) -> fmt::Result {
    let magnitude = value.abs();
    if value == 0.0 || (1e-5..1e16).contains(&magnitude) { write!(out, "{value}") } else { write!(out, "{value:e}") }
}

fn quote(token: &str) -> String {
    match token.char_indices().nth(MAX_QUOTED_CHARS) {
        Some((cut, _)) => format!("{}…", &token[..cut]),
        None => token.to_owned(),
    }
}
