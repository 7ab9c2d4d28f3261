//! Which variables a factor path ties to a prior: without such a path a variable's gauge is
//! free and the information matrix singular.

/// Union-find over `n` variables plus one node standing for "anchored by a prior".
#[derive(Debug)]
pub(crate) struct Anchoring {
    parent: Vec<usize>,
}

impl Anchoring {
    pub fn new(n: usize) -> Self {
        Self { parent: (0..=n).collect() }
    }

    /// The node a prior connects its variable to.
    pub fn anchor(&self) -> usize {
        self.parent.len() - 1
    }

    fn find(&mut self, mut x: usize) -> usize {
        while self.parent[x] != x {
            self.parent[x] = self.parent[self.parent[x]];
            x = self.parent[x];
        }
        x
    }

    /// Records a factor between `a` and `b` (a prior: `b` = [`Self::anchor`]).
    pub fn join(&mut self, a: usize, b: usize) {
        let (ra, rb) = (self.find(a), self.find(b));
        self.parent[ra] = rb;
    }

    pub fn is_anchored(&mut self, v: usize) -> bool {
        let anchor = self.anchor();
        self.find(v) == self.find(anchor)
    }
}
