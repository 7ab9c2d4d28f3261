//! Maximum clique of a small undirected graph: exact branch and bound up to a size cap, a greedy
//! heuristic above it. PCM (Mangelson et al. 2018) needs the largest set of mutually consistent
//! loop closures, which is the maximum clique of their consistency graph.
//!
//! Both solvers are deterministic: vertices are visited in the order given (the caller puts the
//! ones it prefers first), and among cliques of equal size the one found first wins.

/// A symmetric adjacency matrix over vertices `0..n` (no self loops needed).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Adjacency {
    n: usize,
    edges: Vec<bool>,
}

impl Adjacency {
    pub fn new(n: usize) -> Self {
        Adjacency { n, edges: vec![false; n * n] }
    }

    pub fn len(&self) -> usize {
        self.n
    }

    pub fn connect(&mut self, a: usize, b: usize) {
        if a < self.n && b < self.n && a != b {
            self.edges[a * self.n + b] = true;
            self.edges[b * self.n + a] = true;
        }
    }

    pub fn adjacent(&self, a: usize, b: usize) -> bool {
        a < self.n && b < self.n && self.edges[a * self.n + b]
    }

    fn degree(&self, a: usize) -> usize {
        (0..self.n).filter(|&b| self.adjacent(a, b)).count()
    }
}

/// The vertices of a maximum clique (exact when `n ≤ exact_max`, else a large clique from the
/// heuristic), in ascending order of their position in `order`. `order` lists the vertices in
/// the order of preference.
pub(crate) fn max_clique(graph: &Adjacency, order: &[usize], exact_max: usize) -> Vec<usize> {
    let mut best = if graph.len() <= exact_max { exact(graph, order) } else { heuristic(graph, order) };
    best.sort_by_key(|v| order.iter().position(|o| o == v));
    best
}

/// Carraghan–Pardalos branch and bound with Tomita's greedy-colouring bound (MCQ): the colour
/// count of the candidates bounds the clique they can still add.
fn exact(graph: &Adjacency, order: &[usize]) -> Vec<usize> {
    let mut best = Vec::new();
    let mut clique = Vec::new();
    // MCQ branches from the end of the candidate list first; reversed, the preferred vertices
    // are tried first and so win ties.
    expand(graph, &mut clique, order.iter().rev().copied().collect(), &mut best);
    best
}

fn expand(graph: &Adjacency, clique: &mut Vec<usize>, candidates: Vec<usize>, best: &mut Vec<usize>) {
    if candidates.is_empty() {
        if clique.len() > best.len() {
            *best = clique.clone();
        }
        return;
    }
    let (sorted, colours) = colour_sort(graph, &candidates);
    let mut remaining = candidates;
    // Highest colour last in `sorted`: branch from there, the bound shrinking as vertices go.
    for i in (0..sorted.len()).rev() {
        if clique.len() + colours[i] <= best.len() {
            return;
        }
        let v = sorted[i];
        clique.push(v);
        let next: Vec<usize> = remaining.iter().copied().filter(|&u| u != v && graph.adjacent(u, v)).collect();
        expand(graph, clique, next, best);
        clique.pop();
        remaining.retain(|&u| u != v);
    }
}

/// Greedy sequential colouring in candidate order; returns the candidates sorted by colour
/// (stable) and each one's colour (1-based).
fn colour_sort(graph: &Adjacency, candidates: &[usize]) -> (Vec<usize>, Vec<usize>) {
    let mut classes: Vec<Vec<usize>> = Vec::new();
    for &v in candidates {
        match classes.iter_mut().find(|class| class.iter().all(|&u| !graph.adjacent(u, v))) {
            Some(class) => class.push(v),
            None => classes.push(vec![v]),
        }
    }
    let mut sorted = Vec::with_capacity(candidates.len());
    let mut colours = Vec::with_capacity(candidates.len());
    for (k, class) in classes.into_iter().enumerate() {
        for v in class {
            sorted.push(v);
            colours.push(k + 1);
        }
    }
    (sorted, colours)
}

/// Pattabiraman et al.'s heuristic (the one Mangelson's PCM uses above its exact range): from
/// every vertex, grow a clique greedily by the highest-degree neighbour compatible with it.
fn heuristic(graph: &Adjacency, order: &[usize]) -> Vec<usize> {
    let degrees: Vec<usize> = (0..graph.len()).map(|v| graph.degree(v)).collect();
    let mut best: Vec<usize> = Vec::new();
    for &v in order {
        if degrees[v] < best.len() {
            continue;
        }
        let mut clique = vec![v];
        let mut candidates: Vec<usize> =
            order.iter().copied().filter(|&u| graph.adjacent(u, v) && degrees[u] >= best.len()).collect();
        while !candidates.is_empty() {
            // Highest degree first; the earlier in `order` on ties (max_by_key keeps the last).
            let Some(&u) = candidates.iter().rev().max_by_key(|&&u| degrees[u]) else {
                break;
            };
            clique.push(u);
            candidates.retain(|&w| w != u && graph.adjacent(w, u));
        }
        if clique.len() > best.len() {
            best = clique;
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn graph(n: usize, edges: &[(usize, usize)]) -> Adjacency {
        let mut g = Adjacency::new(n);
        for &(a, b) in edges {
            g.connect(a, b);
        }
        g
    }

    fn is_clique(g: &Adjacency, c: &[usize]) -> bool {
        c.iter().enumerate().all(|(i, &a)| c[i + 1..].iter().all(|&b| g.adjacent(a, b)))
    }

    #[test]
    fn finds_the_planted_clique() {
        // A 5-clique {1, 3, 5, 7, 9} among a sparse background.
        let mut edges = vec![(0, 2), (2, 4), (4, 6), (0, 8), (8, 1), (6, 3)];
        let planted = [1, 3, 5, 7, 9];
        for (i, &a) in planted.iter().enumerate() {
            for &b in &planted[i + 1..] {
                edges.push((a, b));
            }
        }
        let g = graph(10, &edges);
        let order: Vec<usize> = (0..10).collect();
        assert_eq!(max_clique(&g, &order, 64), planted.to_vec());
        assert_eq!(max_clique(&g, &order, 0), planted.to_vec(), "the heuristic finds it too");
    }

    #[test]
    fn ties_go_to_the_preferred_vertices() {
        // Two disjoint triangles: the one whose vertices come first in `order` wins.
        let g = graph(6, &[(0, 1), (1, 2), (0, 2), (3, 4), (4, 5), (3, 5)]);
        assert_eq!(max_clique(&g, &[0, 1, 2, 3, 4, 5], 64), vec![0, 1, 2]);
        assert_eq!(max_clique(&g, &[3, 4, 5, 0, 1, 2], 64), vec![3, 4, 5]);
    }

    #[test]
    fn exact_matches_brute_force_on_random_graphs() {
        let mut state = 0x9e37_79b9_7f4a_7c15_u64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for _ in 0..40 {
            let n = 11;
            let mut g = Adjacency::new(n);
            for a in 0..n {
                for b in a + 1..n {
                    if next() % 100 < 55 {
                        g.connect(a, b);
                    }
                }
            }
            let brute = (0u32..1 << n)
                .filter(|mask| {
                    let c: Vec<usize> = (0..n).filter(|i| mask & (1 << i) != 0).collect();
                    is_clique(&g, &c)
                })
                .map(|mask| mask.count_ones() as usize)
                .max()
                .unwrap_or(0);
            let order: Vec<usize> = (0..n).collect();
            let found = max_clique(&g, &order, 64);
            assert!(is_clique(&g, &found));
            assert_eq!(found.len(), brute);
            let greedy = max_clique(&g, &order, 0);
            assert!(is_clique(&g, &greedy) && greedy.len() <= brute);
        }
    }

    #[test]
    fn empty_and_edgeless_graphs() {
        assert!(max_clique(&Adjacency::new(0), &[], 64).is_empty());
        assert_eq!(max_clique(&Adjacency::new(3), &[2, 0, 1], 64), vec![2]);
    }
}
