//! The Bayes tree: cliques of the multifrontal Cholesky factor, with the cached factor each
//! subtree sends to its parent. Batch solves eliminate every variable; incremental updates
//! detach the top of the tree (the cliques on the paths from changed variables to the root),
//! re-eliminate only those variables together with the cached factors of the orphaned subtrees,
//! and reattach the orphans (Kaess et al. 2012, iSAM2, Alg. 4–5).

use nalgebra::{DMatrix, Matrix6, Vector6};

use crate::linear::{self, CachedFactor, Conditional, Damping, LinearFactor, NotPositiveDefinite, Scratch};

pub(crate) const NONE: usize = usize::MAX;

#[derive(Debug, Clone)]
pub(crate) struct Clique {
    /// Frontal variables in elimination order.
    pub frontals: Vec<usize>,
    /// Separator variables, in elimination order (all eliminated after the frontals).
    pub separator: Vec<usize>,
    pub parent: usize,
    pub children: Vec<usize>,
    /// Factors whose first-eliminated variable is one of the frontals.
    pub factors: Vec<usize>,
    pub conditional: Conditional,
    pub cached: CachedFactor,
}

/// A clique produced by symbolic elimination, before numeric factorization.
#[derive(Debug, Clone, Default)]
pub(crate) struct SymbolicClique {
    pub frontals: Vec<usize>,
    pub separator: Vec<usize>,
    pub factors: Vec<usize>,
    /// Children among the new cliques (indices into the same list).
    pub new_children: Vec<usize>,
    /// Children that are existing (orphaned) cliques of the tree.
    pub orphan_children: Vec<usize>,
    /// Parent among the new cliques, or `NONE` for a root.
    pub parent: usize,
}

/// Symbolic elimination of `order` (variables, in elimination order) over hyperedges made of
/// factors (`factor_vars[f]` for `f` in `factors`) and orphan cliques (their separators).
///
/// `position` gives every variable's elimination position; the positions of `order` must be
/// increasing and larger than those of all orphan frontals. Cliques come out in a postorder
/// (children before parents). Fundamental supernodes are merged: a variable joins its only
/// child clique when that child's separator is exactly the variable plus its own separator.
pub(crate) fn eliminate_symbolic(
    order: &[usize],
    position: &[u64],
    factors: &[usize],
    factor_vars: &[LinearFactor],
    orphans: &[(usize, &[usize])],
    local: &mut [usize],
    mark: &mut [usize],
) -> Vec<SymbolicClique> {
    for (i, &v) in order.iter().enumerate() {
        local[v] = i;
    }
    let earliest = |vars: &[usize]| vars.iter().copied().min_by_key(|&v| position[v]).unwrap_or(NONE);
    let mut var_factors: Vec<Vec<usize>> = vec![Vec::new(); order.len()];
    for &f in factors {
        let v = earliest(factor_vars[f].vars());
        debug_assert!(factor_vars[f].vars().iter().all(|&u| order.get(local[u]) == Some(&u)));
        var_factors[local[v]].push(f);
    }
    let mut var_orphans: Vec<Vec<usize>> = vec![Vec::new(); order.len()];
    for (o, (_, sep)) in orphans.iter().enumerate() {
        // An orphan's separator is listed in the old elimination order; it hangs below the
        // first of those variables in the new order.
        let first = earliest(sep);
        if first != NONE {
            var_orphans[local[first]].push(o);
        }
    }
    let mut pending: Vec<Vec<usize>> = vec![Vec::new(); order.len()];
    let mut cliques: Vec<SymbolicClique> = Vec::new();
    let mut structure: Vec<usize> = Vec::new();
    for (i, &v) in order.iter().enumerate() {
        // Mark with the step number so no clearing is needed between steps.
        let stamp = i;
        mark[v] = stamp;
        structure.clear();
        let mut add = |u: usize, structure: &mut Vec<usize>| {
            if mark[u] != stamp {
                mark[u] = stamp;
                structure.push(u);
            }
        };
        for &f in &var_factors[i] {
            for &u in factor_vars[f].vars() {
                add(u, &mut structure);
            }
        }
        for &o in &var_orphans[i] {
            for &u in orphans[o].1 {
                add(u, &mut structure);
            }
        }
        for &c in &pending[i] {
            for &u in &cliques[c].separator {
                add(u, &mut structure);
            }
        }
        structure.sort_unstable_by_key(|&u| position[u]);

        let merge_into = match (pending[i].as_slice(), var_orphans[i].is_empty()) {
            ([only], true) if cliques[*only].separator.len() == structure.len() + 1 => Some(*only),
            _ => None,
        };
        let id = match merge_into {
            Some(c) => {
                let clique = &mut cliques[c];
                clique.frontals.push(v);
                clique.separator.clone_from(&structure);
                clique.factors.extend_from_slice(&var_factors[i]);
                c
            }
            None => {
                cliques.push(SymbolicClique {
                    frontals: vec![v],
                    separator: structure.clone(),
                    factors: std::mem::take(&mut var_factors[i]),
                    new_children: std::mem::take(&mut pending[i]),
                    orphan_children: var_orphans[i].iter().map(|&o| orphans[o].0).collect(),
                    parent: NONE,
                });
                let id = cliques.len() - 1;
                for k in 0..cliques[id].new_children.len() {
                    let child = cliques[id].new_children[k];
                    cliques[child].parent = id;
                }
                id
            }
        };
        if let Some(&first) = structure.first() {
            pending[local[first]].push(id);
        }
    }
    // Cliques are pushed when their first frontal is eliminated and parents only after all
    // children, except that a merge extends an existing clique in place; re-sort into postorder.
    postorder(cliques)
}

fn postorder(cliques: Vec<SymbolicClique>) -> Vec<SymbolicClique> {
    let n = cliques.len();
    let mut order = Vec::with_capacity(n);
    let mut stack: Vec<(usize, bool)> =
        (0..n).rev().filter(|&c| cliques[c].parent == NONE).map(|c| (c, false)).collect();
    while let Some((c, expanded)) = stack.pop() {
        if expanded {
            order.push(c);
        } else {
            stack.push((c, true));
            for &child in cliques[c].new_children.iter().rev() {
                stack.push((child, false));
            }
        }
    }
    let mut new_index = vec![NONE; n];
    for (k, &c) in order.iter().enumerate() {
        new_index[c] = k;
    }
    let mut slots: Vec<Option<SymbolicClique>> = cliques.into_iter().map(Some).collect();
    order
        .iter()
        .filter_map(|&c| slots[c].take())
        .map(|mut clique| {
            clique.parent = if clique.parent == NONE { NONE } else { new_index[clique.parent] };
            for child in &mut clique.new_children {
                *child = new_index[*child];
            }
            clique
        })
        .collect()
}

/// How a postorder-numbered tree (clique id = postorder position) is factored on two threads:
/// a worker takes the whole subtrees in the id range `worker`, all children of one clique;
/// meanwhile the calling thread factors every clique that is neither in that range nor an
/// ancestor of it (`caller`, in postorder), and after the join the ancestors (`ancestors`).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ParallelSplit {
    pub worker: std::ops::Range<usize>,
    pub caller: Vec<usize>,
    pub ancestors: Vec<usize>,
    /// Estimated flops taken off the calling thread's critical path.
    pub saved_flops: f64,
}

/// Rough flop count of assembling and partially factoring a front with `m` frontal and `s`
/// separator variables: the panel Cholesky, the triangular solve and the Schur update, plus
/// the zeroing and copying of the front.
pub(crate) fn front_flops(m: usize, s: usize) -> f64 {
    let nf = 6.0 * m as f64;
    let ns = 6.0 * s as f64;
    let n = nf + ns;
    nf * nf * nf / 3.0 + nf * nf * ns + nf * ns * ns + 2.0 * n * n
}

/// The clique array seen by one thread: ids below `low.len()` and ids from `high_start` on.
struct CliqueView<'a> {
    low: &'a mut [Option<Clique>],
    high: &'a mut [Option<Clique>],
    high_start: usize,
}

impl CliqueView<'_> {
    fn slot(&mut self, id: usize) -> &mut Option<Clique> {
        if id < self.low.len() { &mut self.low[id] } else { &mut self.high[id - self.high_start] }
    }

    fn get(&self, id: usize) -> Option<&Clique> {
        if id < self.low.len() { self.low[id].as_ref() } else { self.high[id - self.high_start].as_ref() }
    }
}

/// Re-factors the cliques `ids` (children before parents); the view must hold their children.
/// A failure carries the id of the failing clique.
fn refactor_view(
    cliques: &mut CliqueView<'_>,
    ids: impl Iterator<Item = usize>,
    lin: &[LinearFactor],
    damping: Option<Damping<'_>>,
    scratch: &mut Scratch,
) -> Result<(), (usize, NotPositiveDefinite)> {
    for id in ids {
        let Some(mut clique) = cliques.slot(id).take() else { continue };
        let children =
            clique.children.iter().filter_map(|&c| cliques.get(c)).map(|c| (c.separator.as_slice(), &c.cached));
        let result = linear::factor_front(
            &clique.frontals,
            &clique.separator,
            clique.factors.iter().map(|&f| &lin[f]),
            children,
            damping,
            scratch,
            (&mut clique.conditional, &mut clique.cached),
        );
        *cliques.slot(id) = Some(clique);
        result.map_err(|e| (id, e))?;
    }
    Ok(())
}

/// The tree of cliques over all variables.
#[derive(Debug, Clone, Default)]
pub(crate) struct BayesTree {
    pub cliques: Vec<Option<Clique>>,
    free: Vec<usize>,
    pub roots: Vec<usize>,
    /// Clique holding each variable as a frontal (`NONE` before its first elimination).
    pub var_clique: Vec<usize>,
    /// Elimination position of each variable; later eliminations get larger numbers.
    pub position: Vec<u64>,
    next_position: u64,
    /// Scratch arrays over variables (the fronts' slots live in `scratch`). Every operation
    /// leaves `mark` all `NONE` and `var_flag` all false, so that no update pays for a pass
    /// over all variables.
    mark: Vec<usize>,
    var_flag: Vec<bool>,
    /// Scratch over clique ids, all false between operations.
    clique_flag: Vec<bool>,
    scratch: Scratch,
    /// The second thread's buffers, kept so that threaded refactoring does not allocate.
    worker_scratch: Scratch,
}

impl BayesTree {
    pub fn ensure_vars(&mut self, n: usize) {
        if self.var_clique.len() < n {
            self.var_clique.resize(n, NONE);
            self.position.resize(n, 0);
            self.mark.resize(n, NONE);
            self.var_flag.resize(n, false);
            self.scratch.ensure_vars(n);
        }
    }

    pub fn clique(&self, id: usize) -> &Clique {
        // Ids handed out by this tree always refer to live cliques.
        self.cliques[id].as_ref().unwrap_or_else(|| unreachable!("dead clique {id}"))
    }

    /// Assigns fresh positions, later than every existing one, to `order`.
    pub fn assign_positions(&mut self, order: &[usize]) {
        for &v in order {
            self.position[v] = self.next_position;
            self.next_position += 1;
        }
    }

    /// Symbolic elimination of `order` with the given factors and orphan cliques.
    pub fn symbolic(
        &mut self,
        order: &[usize],
        factors: &[usize],
        lin: &[LinearFactor],
        orphans: &[usize],
    ) -> Vec<SymbolicClique> {
        let orphan_seps: Vec<(usize, Vec<usize>)> =
            orphans.iter().map(|&o| (o, self.clique(o).separator.clone())).collect();
        let orphan_refs: Vec<(usize, &[usize])> = orphan_seps.iter().map(|(o, s)| (*o, s.as_slice())).collect();
        let cliques = eliminate_symbolic(
            order,
            &self.position,
            factors,
            lin,
            &orphan_refs,
            &mut self.scratch.slot,
            &mut self.mark,
        );
        // Elimination marks only variables of `order`: factors and orphan separators lie inside it.
        for &v in order {
            self.mark[v] = NONE;
        }
        debug_assert!(self.mark.iter().all(|&m| m == NONE));
        cliques
    }

    /// Numeric factorization of new symbolic cliques (postorder), reading orphans' cached factors.
    pub fn numeric(
        &mut self,
        symbolic: &[SymbolicClique],
        lin: &[LinearFactor],
        damping: Option<Damping<'_>>,
    ) -> Result<Vec<(Conditional, CachedFactor)>, NotPositiveDefinite> {
        let mut out: Vec<(Conditional, CachedFactor)> = Vec::with_capacity(symbolic.len());
        for sc in symbolic {
            let children_new = sc.new_children.iter().map(|&c| (symbolic[c].separator.as_slice(), &out[c].1));
            let children_old = sc.orphan_children.iter().map(|&o| {
                let clique = self.cliques[o].as_ref().unwrap_or_else(|| unreachable!("dead orphan {o}"));
                (clique.separator.as_slice(), &clique.cached)
            });
            let mut conditional = Conditional::default();
            let mut cached = CachedFactor::default();
            linear::factor_front(
                &sc.frontals,
                &sc.separator,
                sc.factors.iter().map(|&f| &lin[f]),
                children_new.chain(children_old),
                damping,
                &mut self.scratch,
                (&mut conditional, &mut cached),
            )?;
            out.push((conditional, cached));
        }
        Ok(out)
    }

    /// Re-factors existing cliques in place (same structure, new numbers), reusing their
    /// buffers. `postorder` must list children before parents.
    pub fn refactor(
        &mut self,
        postorder: &[usize],
        lin: &[LinearFactor],
        damping: Option<Damping<'_>>,
    ) -> Result<(), NotPositiveDefinite> {
        let mut view = CliqueView { low: &mut self.cliques, high: &mut [], high_start: usize::MAX };
        refactor_view(&mut view, postorder.iter().copied(), lin, damping, &mut self.scratch).map_err(|(_, e)| e)
    }

    /// The best [`ParallelSplit`] of a tree whose clique ids are a postorder (`id == position`,
    /// as after a batch commit into an empty tree); `None` for other trees.
    pub fn plan_split(&self) -> Option<ParallelSplit> {
        let n = self.cliques.len();
        // Work of the ids below each id: a subtree is a contiguous id range, so its work is a
        // difference of two entries.
        let mut work_before = Vec::with_capacity(n + 1);
        let mut size = vec![0usize; n];
        let mut parent = vec![NONE; n];
        work_before.push(0.0);
        for id in 0..n {
            let clique = self.cliques[id].as_ref()?;
            let mut count = 1;
            for &c in &clique.children {
                if c >= id || parent[c] != NONE {
                    return None;
                }
                parent[c] = id;
                count += size[c];
            }
            size[id] = count;
            let total = work_before[id] + front_flops(clique.frontals.len(), clique.separator.len());
            work_before.push(total);
        }
        let total = work_before[n];
        // Work of each clique and its ancestors; parents come after their children.
        let mut path_work = vec![0.0; n];
        for id in (0..n).rev() {
            let own = work_before[id + 1] - work_before[id];
            path_work[id] = own + if parent[id] == NONE { 0.0 } else { path_work[parent[id]] };
        }
        let mut best: Option<(std::ops::Range<usize>, usize, f64)> = None;
        let mut consider = |children: &[usize], owner: usize| {
            let ancestors = if owner == NONE { 0.0 } else { path_work[owner] };
            // Windows of consecutive children (their subtrees lie side by side); only single
            // children where there are many.
            let width = if children.len() <= 32 { children.len() } else { 1 };
            for (i, &first) in children.iter().enumerate() {
                let start = first + 1 - size[first];
                for &last in children[i..].iter().take(width) {
                    let end = last + 1;
                    let worker = work_before[end] - work_before[start];
                    let saved = worker.min(total - worker - ancestors);
                    if best.as_ref().is_none_or(|b| saved > b.2) {
                        best = Some((start..end, owner, saved));
                    }
                }
            }
        };
        for (id, clique) in self.cliques.iter().enumerate() {
            if let Some(clique) = clique {
                consider(&clique.children, id);
            }
        }
        consider(&self.roots, NONE);
        let (worker, owner, saved_flops) = best?;
        // A window is only valid if its subtrees are exactly the ids in the range.
        let covered: usize = (worker.start..worker.end).filter(|&c| parent[c] == owner).map(|c| size[c]).sum();
        if covered != worker.len() {
            return None;
        }
        // Reuse `size` as the mark of the ancestors.
        let mut ancestors = Vec::new();
        let mut c = owner;
        while c != NONE {
            ancestors.push(c);
            size[c] = 0;
            c = parent[c];
        }
        let caller = (0..n).filter(|&c| !worker.contains(&c) && size[c] != 0).collect();
        Some(ParallelSplit { worker, caller, ancestors, saved_flops })
    }

    /// [`Self::refactor`] of a tree numbered as [`Self::plan_split`] requires, on two threads.
    /// Each clique's arithmetic is that of the sequential run, so the results are bit-identical,
    /// and so is the failure reported: the first in postorder.
    pub fn refactor_split(
        &mut self,
        split: &ParallelSplit,
        lin: &[LinearFactor],
        damping: Option<Damping<'_>>,
    ) -> Result<(), NotPositiveDefinite> {
        let ParallelSplit { worker, caller, ancestors, .. } = split;
        let mut worker_scratch = std::mem::take(&mut self.worker_scratch);
        worker_scratch.ensure_vars(self.var_clique.len());
        let (low_and_worker, high) = self.cliques.split_at_mut(worker.end);
        let (low, worker_cliques) = low_and_worker.split_at_mut(worker.start);
        let mut worker_view = CliqueView { low: &mut [], high: worker_cliques, high_start: worker.start };
        let mut caller_view = CliqueView { low, high, high_start: worker.end };
        let scratch = &mut self.scratch;
        let (result_caller, result_worker) = std::thread::scope(|scope| {
            let handle =
                scope.spawn(|| refactor_view(&mut worker_view, worker.clone(), lin, damping, &mut worker_scratch));
            let result_caller = refactor_view(&mut caller_view, caller.iter().copied(), lin, damping, scratch);
            let result_worker = handle.join().unwrap_or_else(|panic| std::panic::resume_unwind(panic));
            (result_caller, result_worker)
        });
        self.worker_scratch = worker_scratch;
        match (result_caller, result_worker) {
            (Err(a), Err(b)) => return Err(if a.0 < b.0 { a.1 } else { b.1 }),
            (Err((_, e)), Ok(())) | (Ok(()), Err((_, e))) => return Err(e),
            (Ok(()), Ok(())) => {}
        }
        let mut view = CliqueView { low: &mut self.cliques, high: &mut [], high_start: usize::MAX };
        refactor_view(&mut view, ancestors.iter().copied(), lin, damping, &mut self.scratch).map_err(|(_, e)| e)
    }

    /// Replaces the cliques `removed` by the new ones; orphans are re-parented. Returns the ids
    /// of the inserted cliques (same order as `symbolic`).
    pub fn commit(
        &mut self,
        removed: &[usize],
        symbolic: Vec<SymbolicClique>,
        numeric: Vec<(Conditional, CachedFactor)>,
    ) -> Vec<usize> {
        for &c in removed {
            self.cliques[c] = None;
            self.free.push(c);
        }
        self.roots.retain(|r| self.cliques[*r].is_some());
        let ids: Vec<usize> = symbolic
            .iter()
            .map(|_| match self.free.pop() {
                Some(id) => id,
                None => {
                    self.cliques.push(None);
                    self.cliques.len() - 1
                }
            })
            .collect();
        for ((k, sc), (conditional, cached)) in symbolic.into_iter().enumerate().zip(numeric) {
            let id = ids[k];
            for &v in &sc.frontals {
                self.var_clique[v] = id;
            }
            let parent = if sc.parent == NONE { NONE } else { ids[sc.parent] };
            if parent == NONE {
                self.roots.push(id);
            }
            let mut children: Vec<usize> = sc.new_children.iter().map(|&c| ids[c]).collect();
            for &o in &sc.orphan_children {
                if let Some(orphan) = self.cliques[o].as_mut() {
                    orphan.parent = id;
                }
                children.push(o);
            }
            self.cliques[id] = Some(Clique {
                frontals: sc.frontals,
                separator: sc.separator,
                parent,
                children,
                factors: sc.factors,
                conditional,
                cached,
            });
        }
        ids
    }

    fn take_clique_flags(&mut self) -> Vec<bool> {
        let mut flags = std::mem::take(&mut self.clique_flag);
        flags.resize(self.cliques.len(), false);
        flags
    }

    /// The top of the tree for the `marked` cliques: the cliques on their paths to the roots
    /// (deduplicated, each path from its marked clique upwards), and the orphans, the children
    /// of top cliques that are not in the top themselves.
    pub fn top_and_orphans(&mut self, marked: &[usize]) -> (Vec<usize>, Vec<usize>) {
        let mut in_top = self.take_clique_flags();
        let mut top = Vec::new();
        for &(mut c) in marked {
            while c != NONE && !in_top[c] {
                in_top[c] = true;
                top.push(c);
                c = self.clique(c).parent;
            }
        }
        let mut orphans = Vec::new();
        for &c in &top {
            orphans.extend(self.clique(c).children.iter().copied().filter(|&child| !in_top[child]));
        }
        for &c in &top {
            in_top[c] = false;
        }
        self.clique_flag = in_top;
        (top, orphans)
    }

    /// Variables whose step exceeds `threshold` in some component, found by descending from the
    /// roots: a clique's children are visited only if one of its frontal or separator variables
    /// exceeds it (GTSAM's partial relinearization check). A large step below a clique whose own
    /// variables stayed under the threshold is not seen. Appended to `out` in visiting order.
    pub fn steps_above_partial(&self, delta: &[Vector6<f64>], threshold: f64, out: &mut Vec<usize>) {
        let mut stack: Vec<usize> = self.roots.clone();
        while let Some(c) = stack.pop() {
            let clique = self.clique(c);
            let mut descend = false;
            for &v in &clique.frontals {
                if delta[v].amax() > threshold {
                    out.push(v);
                    descend = true;
                }
            }
            // Separator variables are frontals of ancestors, already collected on the way down;
            // they only widen the descent, as in GTSAM.
            descend = descend || clique.separator.iter().any(|&v| delta[v].amax() > threshold);
            if descend {
                stack.extend_from_slice(&clique.children);
            }
        }
    }

    /// Solves every clique top-down (batch).
    pub fn solve_all(&self, delta: &mut [Vector6<f64>]) {
        let mut stack: Vec<usize> = self.roots.clone();
        let mut delta_f = Vec::new();
        while let Some(c) = stack.pop() {
            let clique = self.clique(c);
            linear::solve_frontals(&clique.conditional, &clique.separator, delta, &mut delta_f);
            for (i, &v) in clique.frontals.iter().enumerate() {
                delta[v] = Vector6::from_column_slice(&delta_f[6 * i..6 * i + 6]);
            }
            stack.extend_from_slice(&clique.children);
        }
    }

    /// Partial back-substitution from the cliques `start` (re-eliminated: always solved) down
    /// into subtrees only while some separator variable moved by more than `threshold`
    /// (iSAM2's wildfire). Returns the number of cliques solved.
    pub fn solve_wildfire(&mut self, start: &[usize], delta: &mut [Vector6<f64>], threshold: f64) -> usize {
        let mut changed = std::mem::take(&mut self.var_flag);
        changed.resize(delta.len(), false);
        let mut changed_vars: Vec<usize> = Vec::new();
        let mut forced = self.take_clique_flags();
        for &c in start {
            forced[c] = true;
        }
        // Start at the roots that were re-eliminated; new cliques include every root touched.
        let mut stack: Vec<usize> = self.roots.iter().copied().filter(|&r| forced[r]).collect();
        let mut solved = 0;
        let mut delta_f = Vec::new();
        while let Some(c) = stack.pop() {
            let clique = self.clique(c);
            if !forced[c] && !clique.separator.iter().any(|&v| changed[v]) {
                continue;
            }
            solved += 1;
            linear::solve_frontals(&clique.conditional, &clique.separator, delta, &mut delta_f);
            for (i, &v) in clique.frontals.iter().enumerate() {
                let new = Vector6::from_column_slice(&delta_f[6 * i..6 * i + 6]);
                if (new - delta[v]).amax() > threshold && !changed[v] {
                    changed[v] = true;
                    changed_vars.push(v);
                }
                delta[v] = new;
            }
            stack.extend_from_slice(&clique.children);
        }
        for v in changed_vars {
            changed[v] = false;
        }
        for &c in start {
            forced[c] = false;
        }
        self.var_flag = changed;
        self.clique_flag = forced;
        solved
    }

    /// Marginal covariances of `vars` (6×6 each, tangent order `[ρ, φ]`).
    pub fn marginals(&mut self, vars: &[usize]) -> Vec<Matrix6<f64>> {
        // Cliques needed: the paths from each variable's clique to its root.
        let mut needed = vec![false; self.cliques.len()];
        let mut list = Vec::new();
        for &v in vars {
            let mut c = self.var_clique[v];
            while c != NONE && !needed[c] {
                needed[c] = true;
                list.push(c);
                c = self.clique(c).parent;
            }
        }
        // Parents before children: a parent's last frontal is eliminated after the child's.
        list.sort_unstable_by_key(|&c| {
            std::cmp::Reverse(self.clique(c).frontals.last().map_or(0, |&v| self.position[v]))
        });
        let mut sigma: Vec<Option<DMatrix<f64>>> = vec![None; self.cliques.len()];
        let mut slot = std::mem::take(&mut self.scratch.slot);
        for &c in &list {
            let clique = self.clique(c);
            let s = clique.separator.len();
            let mut sigma_ss = DMatrix::<f64>::zeros(6 * s, 6 * s);
            if clique.parent != NONE {
                let parent = self.clique(clique.parent);
                for (i, &v) in parent.frontals.iter().chain(&parent.separator).enumerate() {
                    slot[v] = i;
                }
                if let Some(parent_sigma) = sigma[clique.parent].as_ref() {
                    for (i, &a) in clique.separator.iter().enumerate() {
                        for (j, &b) in clique.separator.iter().enumerate() {
                            let block = parent_sigma.fixed_view::<6, 6>(6 * slot[a], 6 * slot[b]);
                            sigma_ss.fixed_view_mut::<6, 6>(6 * i, 6 * j).copy_from(&block);
                        }
                    }
                }
            }
            sigma[c] = Some(linear::front_covariance(&clique.conditional, &sigma_ss));
        }
        self.scratch.slot = slot;
        vars.iter()
            .map(|&v| {
                let c = self.var_clique[v];
                let clique = self.clique(c);
                let i = clique.frontals.iter().position(|&u| u == v).unwrap_or(0);
                sigma[c].as_ref().map_or_else(Matrix6::zeros, |s| s.fixed_view::<6, 6>(6 * i, 6 * i).into_owned())
            })
            .collect()
    }
}
