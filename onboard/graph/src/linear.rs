//! Block linear algebra of one clique ("front") of the multifrontal Cholesky factorization.
//!
//! A clique eliminates its frontal variables `F` given its separator `S`. Its front is the
//! dense information matrix over `F ∪ S` assembled from the factors assigned to it and the
//! cached factors of its children. Partial Cholesky gives the conditional
//! `L_FFᵀ δ_F = y − X δ_S` (stored as `L_FF`, `X = L_FF⁻¹ A_FS`, `y = L_FF⁻¹ r_F`) and the
//! cached factor (Schur complement) on `S` that the parent receives:
//! `U = A_SS − XᵀX`, `r'_S = r_S − Xᵀy`.

use nalgebra::{DMatrix, DMatrixView, DMatrixViewMut, DVectorViewMut, Matrix6, Vector6};

/// A factor linearized at the current linearization point, in variable indices.
#[derive(Debug, Clone)]
pub(crate) struct LinearFactor {
    pub vars: [usize; 2],
    pub arity: usize,
    /// Whitened (and robust-weighted) Jacobian blocks.
    pub jacobians: [Matrix6<f64>; 2],
    /// Whitened right-hand side: the model is `½‖Σ A_k δ_k − b‖²`.
    pub rhs: Vector6<f64>,
}

impl LinearFactor {
    pub fn vars(&self) -> &[usize] {
        &self.vars[..self.arity]
    }

    /// `bᵀ(Aδ) − ½‖Aδ‖²`: how much the factor's model cost drops for the step `δ`.
    pub fn model_decrease(&self, delta: &[Vector6<f64>]) -> f64 {
        let mut a_delta = Vector6::zeros();
        for k in 0..self.arity {
            a_delta += self.jacobians[k] * delta[self.vars[k]];
        }
        self.rhs.dot(&a_delta) - 0.5 * a_delta.norm_squared()
    }
}

/// The Gaussian conditional `p(δ_F | δ_S)` of a clique in square-root form:
/// `L_FFᵀ δ_F = y − L_SFᵀ δ_S`.
#[derive(Debug, Clone, Default)]
pub(crate) struct Conditional {
    /// The first `nf` columns of the factored `rows × rows` front, column-major: rows `0..nf`
    /// hold the lower-triangular `L_FF`, rows `nf..` hold `L_SF`.
    pub l: Vec<f64>,
    pub rows: usize,
    pub nf: usize,
    /// `L_FF⁻¹ r_F` (nf).
    pub y: Vec<f64>,
}

/// The information a subtree passes to its parent, on the separator (iSAM2's cached factor):
/// a symmetric `dim × dim` matrix, column-major, of which only the lower 6×6 blocks are valid.
#[derive(Debug, Clone, Default)]
pub(crate) struct CachedFactor {
    pub hessian: Vec<f64>,
    pub dim: usize,
    pub rhs: Vec<f64>,
}

/// Levenberg–Marquardt damping added to the frontal diagonal blocks: `λ · D_v`.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Damping<'a> {
    pub lambda: f64,
    /// Per variable, the diagonal of the undamped information (clamped away from zero).
    pub diagonal: &'a [Vector6<f64>],
}

/// Failed to factor a front: the frontal variable whose pivot was not positive.
#[derive(Debug, Clone, Copy)]
pub(crate) struct NotPositiveDefinite {
    pub var: usize,
}

/// Assembles and partially factors one front.
pub(crate) fn factor_front<'c>(
    frontals: &[usize],
    separator: &[usize],
    factors: impl Iterator<Item = &'c LinearFactor>,
    children: impl Iterator<Item = (&'c [usize], &'c CachedFactor)>,
    damping: Option<Damping<'_>>,
    scratch: &mut Scratch,
    (conditional, cached_out): (&mut Conditional, &mut CachedFactor),
) -> Result<(), NotPositiveDefinite> {
    let m = frontals.len();
    let s = separator.len();
    let n = 6 * (m + s);
    let slot = &mut scratch.slot;
    for (i, &v) in frontals.iter().chain(separator).enumerate() {
        slot[v] = i;
    }
    // Only the lower triangle of the front is assembled and read (block-lower for off-diagonal
    // blocks; diagonal 6×6 blocks are kept full). Slots follow elimination order, and children
    // list their separators in the same order, so lower blocks map to lower blocks.
    scratch.front.clear();
    scratch.front.resize(n * n, 0.0);
    scratch.rhs.clear();
    scratch.rhs.resize(n, 0.0);
    let mut rhs = DVectorViewMut::from_slice(&mut scratch.rhs, n);
    {
        let mut front = DMatrixViewMut::from_slice(&mut scratch.front, n, n);
        for f in factors {
            for a in 0..f.arity {
                let sa = 6 * slot[f.vars[a]];
                let at = f.jacobians[a].transpose();
                let mut r = rhs.fixed_rows_mut::<6>(sa);
                r += at * f.rhs;
                for b in 0..f.arity {
                    let sb = 6 * slot[f.vars[b]];
                    if sa >= sb {
                        let mut block = front.fixed_view_mut::<6, 6>(sa, sb);
                        block += at * f.jacobians[b];
                    }
                }
            }
        }
        if let Some(damping) = damping {
            for (i, &v) in frontals.iter().enumerate() {
                for k in 0..6 {
                    front[(6 * i + k, 6 * i + k)] += damping.lambda * damping.diagonal[v][k];
                }
            }
        }
    }
    for (child_separator, cached) in children {
        let cn = cached.dim;
        let child_data = cached.hessian.as_slice();
        for (j, &vj) in child_separator.iter().enumerate() {
            let sj = 6 * slot[vj];
            for (t, v) in scratch.rhs[sj..sj + 6].iter_mut().zip(&cached.rhs[6 * j..6 * j + 6]) {
                *t += v;
            }
            for (i, &vi) in child_separator.iter().enumerate().skip(j) {
                let si = 6 * slot[vi];
                // Block (i, j) of the child is a valid lower block (i ≥ j). A reattached orphan
                // lists its separator in the old elimination order, so it may land above the
                // diagonal here: then add its transpose to the mirrored block.
                if si >= sj {
                    for c in 0..6 {
                        let source = &child_data[(6 * j + c) * cn + 6 * i..(6 * j + c) * cn + 6 * i + 6];
                        let target = &mut scratch.front[(sj + c) * n + si..(sj + c) * n + si + 6];
                        for (t, v) in target.iter_mut().zip(source) {
                            *t += v;
                        }
                    }
                } else {
                    for c in 0..6 {
                        for r in 0..6 {
                            scratch.front[(si + r) * n + sj + c] += child_data[(6 * j + c) * cn + 6 * i + r];
                        }
                    }
                }
            }
        }
    }
    let nf = 6 * m;
    let ns = 6 * s;
    partial_cholesky(&mut scratch.front, n, nf, &mut scratch.panel)
        .map_err(|column| NotPositiveDefinite { var: frontals[column / 6] })?;
    let data = &scratch.front;
    // Forward substitution of the right-hand side: y = L_FF⁻¹ r_F, r'_S = r_S − L_SF y.
    let r = scratch.rhs.as_mut_slice();
    for j in 0..nf {
        let column = &data[j * n..(j + 1) * n];
        r[j] /= column[j];
        let yj = r[j];
        for (ri, lij) in r[j + 1..].iter_mut().zip(&column[j + 1..]) {
            *ri -= lij * yj;
        }
    }
    // Copy out into the caller's buffers, reusing their allocations.
    conditional.rows = n;
    conditional.nf = nf;
    conditional.l.clear();
    conditional.l.extend_from_slice(&data[..n * nf]);
    conditional.y.clear();
    conditional.y.extend_from_slice(&r[..nf]);
    cached_out.dim = ns;
    cached_out.rhs.clear();
    cached_out.rhs.extend_from_slice(&r[nf..]);
    cached_out.hessian.clear();
    for j in nf..n {
        cached_out.hessian.extend_from_slice(&data[j * n + nf..(j + 1) * n]);
    }
    Ok(())
}

/// Reusable buffers of the factorization, so that fronts do not allocate (large fronts would
/// otherwise be fresh `mmap`s, paying page faults every iteration).
#[derive(Debug, Clone, Default)]
pub(crate) struct Scratch {
    /// Per variable: its slot in the current front.
    pub slot: Vec<usize>,
    front: Vec<f64>,
    rhs: Vec<f64>,
    panel: Vec<f64>,
}

impl Scratch {
    pub fn ensure_vars(&mut self, n: usize) {
        if self.slot.len() < n {
            self.slot.resize(n, 0);
        }
    }
}

/// Panel width of the blocked factorization: wide enough for the matrix products to run at
/// full speed, narrow enough that the unblocked panel work stays small.
const PANEL: usize = 48;

/// Right-looking blocked Cholesky of the first `nf` columns of the symmetric `n × n` column-major
/// matrix `data` (lower triangle read and written). Afterwards columns `0..nf` hold
/// `[L_FF; L_SF]` and the trailing block's lower triangle holds the Schur complement
/// `A_SS − L_SF L_SFᵀ` (with full diagonal 6×6 blocks, as `PANEL` is a multiple of 6). Errors
/// with the failing column.
fn partial_cholesky(data: &mut [f64], n: usize, nf: usize, panel: &mut Vec<f64>) -> Result<(), usize> {
    let mut k0 = 0;
    while k0 < nf {
        let kb = PANEL.min(nf - k0);
        // Unblocked left-looking Cholesky of the panel's columns, rows k0..n.
        for j in k0..k0 + kb {
            for k in k0..j {
                let ljk = data[j + k * n];
                if ljk != 0.0 {
                    let (left, right) = data.split_at_mut(j * n);
                    let source = &left[k * n + j..k * n + n];
                    for (t, s) in right[j..n].iter_mut().zip(source) {
                        *t -= s * ljk;
                    }
                }
            }
            let d = data[j + j * n];
            if d.is_nan() || d <= 0.0 {
                return Err(j);
            }
            let pivot = d.sqrt();
            data[j + j * n] = pivot;
            for v in &mut data[j * n + j + 1..j * n + n] {
                *v /= pivot;
            }
        }
        // Trailing update A[t.., t..] −= P Pᵀ with P = L[t.., k0..k0+kb], lower part by column
        // blocks, through nalgebra's gemm (matrixmultiply kernels).
        let t = k0 + kb;
        if t < n {
            let rows = n - t;
            panel.clear();
            for k in k0..t {
                panel.extend_from_slice(&data[k * n + t..(k + 1) * n]);
            }
            let p = DMatrixView::from_slice(panel, rows, kb);
            let mut a = DMatrixViewMut::from_slice(data, n, n);
            let mut c0 = 0;
            while c0 < rows {
                let cb = PANEL.min(rows - c0);
                let lower = p.rows(c0, rows - c0);
                let top = p.rows(c0, cb);
                let mut target = a.view_mut((t + c0, t + c0), (rows - c0, cb));
                target.gemm(-1.0, &lower, &top.transpose(), 1.0);
                c0 += cb;
            }
        }
        k0 += kb;
    }
    Ok(())
}

/// Back-substitution of one clique: `δ_F = L_FF⁻ᵀ (y − L_SFᵀ δ_S)`, written into `out` (nf).
pub(crate) fn solve_frontals(
    conditional: &Conditional,
    separator: &[usize],
    delta: &[Vector6<f64>],
    out: &mut Vec<f64>,
) {
    let nf = conditional.nf;
    let n = conditional.rows;
    let data = &conditional.l;
    out.clear();
    out.extend_from_slice(&conditional.y);
    // Column j of L is row j of Lᵀ: v_j −= L_SF[.., j] · δ_S, then back-substitute L_FFᵀ.
    for j in (0..nf).rev() {
        let column = &data[j * n..(j + 1) * n];
        let mut acc = out[j];
        for (k, &var) in separator.iter().enumerate() {
            let l = &column[nf + 6 * k..nf + 6 * k + 6];
            let d = &delta[var];
            acc -= l[0] * d[0] + l[1] * d[1] + l[2] * d[2] + l[3] * d[3] + l[4] * d[4] + l[5] * d[5];
        }
        for (l, x) in column[j + 1..nf].iter().zip(&out[j + 1..nf]) {
            acc -= l * x;
        }
        out[j] = acc / column[j];
    }
}

/// Covariance of the front variables `F ∪ S` from the separator's covariance (Takahashi /
/// "selected inversion" recursion): `Σ_FS = −L_FF⁻ᵀ L_SFᵀ Σ_SS`,
/// `Σ_FF = L_FF⁻ᵀ (L_FF⁻¹ − L_SFᵀ Σ_SF)`.
pub(crate) fn front_covariance(conditional: &Conditional, sigma_ss: &DMatrix<f64>) -> DMatrix<f64> {
    let nf = conditional.nf;
    let ns = sigma_ss.nrows();
    let l = DMatrixView::from_slice(&conditional.l, conditional.rows, nf);
    let l_ff = l.view((0, 0), (nf, nf)).clone_owned();
    let mut l_inv = DMatrix::<f64>::identity(nf, nf);
    let _ = l_ff.solve_lower_triangular_mut(&mut l_inv);
    let mut out = DMatrix::<f64>::zeros(nf + ns, nf + ns);
    if ns == 0 {
        let _ = l_ff.tr_solve_lower_triangular_mut(&mut l_inv);
        out.copy_from(&l_inv);
        return out;
    }
    let l_sf = l.view((nf, 0), (ns, nf));
    let mut sigma_fs = l_sf.transpose() * sigma_ss;
    let _ = l_ff.tr_solve_lower_triangular_mut(&mut sigma_fs);
    sigma_fs.neg_mut();
    let sigma_sf = sigma_fs.transpose();
    l_inv.gemm(-1.0, &l_sf.transpose(), &sigma_sf, 1.0);
    let _ = l_ff.tr_solve_lower_triangular_mut(&mut l_inv);
    // Symmetrize: round-off makes Σ_FF very slightly asymmetric.
    let sigma_ff = (&l_inv + l_inv.transpose()) * 0.5;
    out.view_mut((0, 0), (nf, nf)).copy_from(&sigma_ff);
    out.view_mut((0, nf), (nf, ns)).copy_from(&sigma_fs);
    out.view_mut((nf, 0), (ns, nf)).copy_from(&sigma_sf);
    out.view_mut((nf, nf), (ns, ns)).copy_from(sigma_ss);
    out
}
