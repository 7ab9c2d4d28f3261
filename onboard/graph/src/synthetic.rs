//! Seeded synthetic pose graphs in the style of Carlone et al.'s `torus3D` (5,000 poses, 9,048
//! edges) and `grid3D` (8,000 poses, 22,236 edges) benchmarks, whose files are not distributed
//! with the other standard datasets. These are not those files: same families and sizes, our
//! own geometry and noise.
//!
//! Both families are built the same way:
//!
//! 1. Ground truth `t_world_pose` for every pose in walk order, re-expressed relative to pose 0,
//!    so vertex 0 is the identity (the anchoring prior of [`crate::dataset::from_g2o`] and of
//!    GTSAM's example sits at vertex 0's initial value).
//! 2. Edges: odometry `k−1 → k`, and loop closures `i → k` (`i < k`) to spatial neighbours, each
//!    candidate kept with probability [`Noise::closure_probability`]. Edges are listed when
//!    their later pose is reached, as an online run would produce them.
//! 3. Each measurement is `t_i_k · Exp(δ)`, `δ ~ N(0, diag(σ_t² I₃, σ_r² I₃))` (default σ_t = 5 cm, σ_r = 10 mrad) in the crate's
//!    `[translation, rotation]` tangent order, and the information matrix written is exactly
//!    `diag(σ_t⁻² I₃, σ_r⁻² I₃)`. Since the between factor's error is `Log(measured⁻¹ ·
//!    t_i_k) = −δ` at the truth, the information is the inverse covariance of the error the
//!    optimizer sees (GTSAM's reading of g2o information; g2o itself would read the rotation
//!    block against the quaternion's vector part, ≈ θ/2).
//! 4. Initial values: the odometry measurements composed from the identity at vertex 0, so the
//!    initial estimate carries the whole accumulated drift and LM has real work to do.
//!
//! Random numbers: SplitMix64 from the seed, Box–Muller normals. Drawn in this order: the
//! keep/drop decision of each loop-closure candidate in candidate order, then six normals per
//! kept edge in edge order. The same seed gives the same graph bit for bit on the same
//! platform; transcendental functions (`sin`, `ln`, the SO(3) exponential) come from the
//! platform's libm, so another libm may change last bits.

use nalgebra::{Isometry3, Matrix6, Point3, Translation3, UnitQuaternion, Vector3, Vector6};

use crate::g2o::{Dimension, G2oEdge, G2oGraph, G2oVertex};
use crate::se3::{self, Pose3};

/// SplitMix64 (Steele, Lea, Flood 2014): tiny, seedable and the same on every platform.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    pub fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1) from the top 53 bits.
    pub fn unit(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller, one draw per pair of uniforms; the sine half is dropped so
    /// that the stream has no hidden state besides the counter).
    pub fn normal(&mut self) -> f64 {
        // 1 − unit() is in (0, 1], so the logarithm is finite.
        let radius = (-2.0 * (1.0 - self.unit()).ln()).sqrt();
        radius * (std::f64::consts::TAU * self.unit()).cos()
    }
}

/// Measurement noise and loop-closure density, shared by both families. The noise is given as
/// information (inverse variance) so that the numbers written to the file are exact; the
/// standard deviations drawn with are derived from it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// Information of each translation component of `δ`, 1/m².
    pub translation_information_per_m2: f64,
    /// Information of each rotation component of `δ`, 1/rad².
    pub rotation_information_per_rad2: f64,
    /// Probability that a loop-closure candidate becomes an edge.
    pub closure_probability: f64,
}

impl Noise {
    /// σ_t = 5 cm and σ_r = 10 mrad per component; the default of both families.
    pub const DEFAULT_INFORMATION: (f64, f64) = (400.0, 10_000.0);

    /// The information matrix of every edge, `[translation, rotation]`.
    pub fn information(&self) -> Matrix6<f64> {
        let (t, r) = (self.translation_information_per_m2, self.rotation_information_per_rad2);
        Matrix6::from_diagonal(&Vector6::new(t, t, t, r, r, r))
    }

    pub fn sigma_translation_m(&self) -> f64 {
        self.translation_information_per_m2.sqrt().recip()
    }

    pub fn sigma_rotation_rad(&self) -> f64 {
        self.rotation_information_per_rad2.sqrt().recip()
    }

    fn with_closure_probability(closure_probability: f64) -> Self {
        let (translation_information_per_m2, rotation_information_per_rad2) = Self::DEFAULT_INFORMATION;
        Self { translation_information_per_m2, rotation_information_per_rad2, closure_probability }
    }
}

/// A torus of `rings` rings around the tube, `poses_per_ring` poses on each; the walk goes
/// around one ring, then steps to the next.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TorusSpec {
    pub rings: usize,
    pub poses_per_ring: usize,
    /// Distance from the torus centre to the tube's centre line, metres.
    pub major_radius_m: f64,
    /// Tube radius, metres.
    pub minor_radius_m: f64,
    pub noise: Noise,
}

impl Default for TorusSpec {
    /// 50 × 100 = 5,000 poses and about 9,000 edges, torus3D's size. Odometry steps are 0.63 m
    /// along a ring; neighbouring rings are 2.5–5 m apart.
    fn default() -> Self {
        Self {
            rings: 50,
            poses_per_ring: 100,
            major_radius_m: 30.0,
            minor_radius_m: 10.0,
            noise: Noise::with_closure_probability(0.8),
        }
    }
}

/// A walk through an `n × n × n` lattice of spacing `spacing_m`: rows back and forth, row order
/// reversed on every other layer, layers stacked (a boustrophedon in 3-D).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GridSpec {
    pub side: usize,
    pub spacing_m: f64,
    pub noise: Noise,
}

impl Default for GridSpec {
    /// 20³ = 8,000 poses and about 22,200 edges, grid3D's size (every lattice neighbour pair
    /// would give 22,800).
    fn default() -> Self {
        Self { side: 20, spacing_m: 1.0, noise: Noise::with_closure_probability(0.96) }
    }
}

/// The torus graph; see the module docs for how it is built.
pub fn torus(spec: &TorusSpec, seed: u64) -> G2oGraph {
    let (rings, per_ring) = (spec.rings, spec.poses_per_ring);
    let mut truth = Vec::with_capacity(rings * per_ring);
    for ring in 0..rings {
        let around_centre_rad = std::f64::consts::TAU * ring as f64 / rings as f64;
        let (sin_c, cos_c) = around_centre_rad.sin_cos();
        for step in 0..per_ring {
            let around_tube_rad = std::f64::consts::TAU * step as f64 / per_ring as f64;
            let (sin_t, cos_t) = around_tube_rad.sin_cos();
            let radial_m = spec.major_radius_m + spec.minor_radius_m * cos_t;
            let p_world = Point3::new(radial_m * cos_c, radial_m * sin_c, spec.minor_radius_m * sin_t);
            // Body x along the ring (the direction of travel), body z the torus' outward normal.
            let forward = Vector3::new(-sin_t * cos_c, -sin_t * sin_c, cos_t);
            let up = Vector3::new(cos_t * cos_c, cos_t * sin_c, sin_t);
            truth.push(pose_from_axes(p_world, forward, up));
        }
    }
    // Each pose's neighbour at the same tube angle on the previous ring; the last ring also
    // closes the torus with the first.
    let mut candidates = Vec::new();
    for ring in 1..rings {
        for step in 0..per_ring {
            let k = ring * per_ring + step;
            candidates.push([k - per_ring, k]);
            if ring == rings - 1 && rings > 2 {
                candidates.push([step, k]);
            }
        }
    }
    build(&truth, &candidates, &spec.noise, seed)
}

/// The lattice graph; see the module docs for how it is built.
pub fn grid(spec: &GridSpec, seed: u64) -> G2oGraph {
    let n = spec.side;
    let cell = |x: usize, y: usize, z: usize| (z * n + y) * n + x;
    let mut walk = Vec::with_capacity(n * n * n);
    let mut index_of_cell = vec![0usize; n * n * n];
    for z in 0..n {
        for yy in 0..n {
            let y = if z.is_multiple_of(2) { yy } else { n - 1 - yy };
            for xx in 0..n {
                let x = if (z * n + yy).is_multiple_of(2) { xx } else { n - 1 - xx };
                index_of_cell[cell(x, y, z)] = walk.len();
                walk.push([x, y, z]);
            }
        }
    }
    let position = |k: usize| Point3::from(walk[k].map(|c| c as f64 * spec.spacing_m));
    // Heading: towards the next cell when that step is horizontal, else kept from the previous
    // pose (a vertical step does not turn the robot).
    let mut truth: Vec<Pose3> = Vec::with_capacity(walk.len());
    for k in 0..walk.len() {
        let next = (k + 1 < walk.len()).then(|| position(k + 1) - position(k));
        let rotation = match next {
            Some(step) if step.z == 0.0 => UnitQuaternion::from_euler_angles(0.0, 0.0, step.y.atan2(step.x)),
            _ => truth.last().map_or(UnitQuaternion::identity(), |previous| previous.rotation),
        };
        truth.push(Isometry3::from_parts(Translation3::from(position(k).coords), rotation));
    }
    // Every lattice neighbour earlier in the walk that is not the odometry predecessor.
    let mut candidates = Vec::new();
    for (k, &[x, y, z]) in walk.iter().enumerate() {
        let mut earlier: Vec<usize> = [
            (x > 0).then(|| cell(x - 1, y, z)),
            (x + 1 < n).then(|| cell(x + 1, y, z)),
            (y > 0).then(|| cell(x, y - 1, z)),
            (y + 1 < n).then(|| cell(x, y + 1, z)),
            (z > 0).then(|| cell(x, y, z - 1)),
        ]
        .into_iter()
        .flatten()
        .map(|c| index_of_cell[c])
        .filter(|&i| i + 1 < k)
        .collect();
        earlier.sort_unstable();
        candidates.extend(earlier.into_iter().map(|i| [i, k]));
    }
    build(&truth, &candidates, &spec.noise, seed)
}

/// The pose at `p_world` whose body x axis is `forward` and body z axis is (the part of `up`
/// orthogonal to) `up`.
fn pose_from_axes(p_world: Point3<f64>, forward: Vector3<f64>, up: Vector3<f64>) -> Pose3 {
    let x = forward.normalize();
    let z = (up - x * x.dot(&up)).normalize();
    let y = z.cross(&x);
    let rotation = nalgebra::Rotation3::from_basis_unchecked(&[x, y, z]);
    Isometry3::from_parts(Translation3::from(p_world.coords), UnitQuaternion::from_rotation_matrix(&rotation))
}

/// Edges (odometry plus the kept candidates, ordered by their later pose), noisy measurements
/// and odometry-composed initial values, for `truth` in walk order.
fn build(truth: &[Pose3], candidates: &[[usize; 2]], noise: &Noise, seed: u64) -> G2oGraph {
    let mut rng = SplitMix64::new(seed);
    let origin_inverse = truth.first().map_or(Isometry3::identity(), Isometry3::inverse);
    let truth: Vec<Pose3> = truth.iter().map(|t| origin_inverse * t).collect();
    let mut pairs: Vec<[usize; 2]> = (1..truth.len()).map(|k| [k - 1, k]).collect();
    pairs.extend(candidates.iter().copied().filter(|_| rng.unit() < noise.closure_probability));
    // Stable: the odometry edge of a pose comes before its loop closures.
    pairs.sort_by_key(|&[_, to]| to);

    let information = noise.information();
    let sigmas = [noise.sigma_translation_m(), noise.sigma_rotation_rad()];
    let mut edges = Vec::with_capacity(pairs.len());
    let mut odometry = vec![Isometry3::identity(); truth.len()];
    for [from, to] in pairs {
        let delta = Vector6::from_fn(|row, _| sigmas[row / 3] * rng.normal());
        let measurement = se3::retract(&(truth[from].inverse() * truth[to]), &delta);
        if from + 1 == to {
            odometry[to] = measurement;
        }
        edges.push(G2oEdge { from: from as u64, to: to as u64, measurement, information });
    }
    let mut vertices = Vec::with_capacity(truth.len());
    let mut t_world_pose = Isometry3::identity();
    for (k, step) in odometry.iter().enumerate() {
        if k > 0 {
            t_world_pose *= step;
            t_world_pose.rotation.renormalize();
        }
        vertices.push(G2oVertex { id: k as u64, pose: t_world_pose });
    }
    G2oGraph { dimension: Dimension::Three, vertices, edges, fixed: Vec::new() }
}
