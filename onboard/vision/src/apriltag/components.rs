//! Connected components of the thresholded image, by union-find over horizontal runs.
//!
//! Connectivity (the upstream detector's): black pixels connect to their 4 neighbours, white
//! pixels to their 8 neighbours (so a white gap between two black regions that touch at a corner
//! keeps them apart, and the white quiet zone around a tag stays one piece); unknown pixels
//! connect to nothing. As upstream, links are made only from pixels of columns `1 ..= w − 2`:
//! the last column connects to nothing, and a pixel of the first column reaches the row above
//! only through its right neighbour (or diagonally, if white).
//!
//! Runs instead of pixels: a row is cut into runs of equal value, a run is linked to the runs of
//! the row above that touch it (overlap, or overlap within one column for white), and the
//! union-find works on runs, typically a tenth of the pixels.

use super::threshold::{UNKNOWN, WHITE};

/// Label of a pixel that belongs to no component big enough to matter.
pub(crate) const NO_LABEL: u32 = u32::MAX;

#[derive(Debug, Clone, Copy)]
struct Run {
    x0: u32,
    /// Inclusive.
    x1: u32,
    value: u8,
}

/// Runs, their union-find forest and component sizes, kept between frames.
#[derive(Debug, Default)]
pub(crate) struct Components {
    width: usize,
    height: usize,
    runs: Vec<Run>,
    /// `row_start[y] .. row_start[y + 1]` are the runs of row `y`.
    row_start: Vec<u32>,
    parent: Vec<u32>,
    /// Pixels in the component, valid at roots.
    size: Vec<u32>,
}

impl Components {
    /// Finds the components of `thresh` (`width × height`, values black / white / unknown).
    pub(crate) fn run(&mut self, thresh: &[u8], width: usize, height: usize) {
        self.width = width;
        self.height = height;
        self.runs.clear();
        self.row_start.clear();
        self.parent.clear();
        self.size.clear();
        if width == 0 || height == 0 {
            self.row_start.push(0);
            return;
        }
        // The last column links to nothing: leave it out of the runs.
        let linked = width - 1;
        let (first, last) = (1u32, width.saturating_sub(2) as u32);
        for y in 0..height {
            let row_begin = self.runs.len();
            self.row_start.push(row_begin as u32);
            let row = &thresh[y * width..y * width + linked];
            let mut x = 0;
            while x < linked {
                let value = row[x];
                let x0 = x;
                x += 1;
                // Eight pixels at a time while they all equal `value`.
                let broadcast = u64::from_ne_bytes([value; 8]);
                while let Some(chunk) = row.get(x..x + 8) {
                    let mut bytes = [0u8; 8];
                    bytes.copy_from_slice(chunk);
                    let differ = u64::from_le_bytes(bytes) ^ broadcast;
                    if differ != 0 {
                        x += (differ.trailing_zeros() / 8) as usize;
                        break;
                    }
                    x += 8;
                }
                while x < linked && row[x] == value {
                    x += 1;
                }
                if value != UNKNOWN {
                    let id = self.runs.len() as u32;
                    self.runs.push(Run { x0: x0 as u32, x1: (x - 1) as u32, value });
                    self.parent.push(id);
                    self.size.push((x - x0) as u32);
                }
            }
            if y == 0 || first > last {
                continue;
            }
            // Link to the runs of the row above.
            let (above_begin, above_end) = (self.row_start[y - 1] as usize, row_begin);
            let mut a = above_begin;
            for b in row_begin..self.runs.len() {
                let run = self.runs[b];
                let (lo, hi) = (run.x0.max(first), run.x1.min(last));
                if lo > hi {
                    continue;
                }
                // Columns of the row above this run reaches.
                let (lo, hi) = if run.value == WHITE { (lo - 1, hi + 1) } else { (lo, hi) };
                while a < above_end && self.runs[a].x1 < lo {
                    a += 1;
                }
                let mut k = a;
                while k < above_end && self.runs[k].x0 <= hi {
                    if self.runs[k].value == run.value {
                        self.union(k as u32, b as u32);
                    }
                    k += 1;
                }
            }
        }
        self.row_start.push(self.runs.len() as u32);
        // Point every run straight at its root.
        for i in 0..self.parent.len() {
            let root = self.find(i as u32);
            self.parent[i] = root;
        }
    }

    fn find(&mut self, mut i: u32) -> u32 {
        while self.parent[i as usize] != i {
            let grand = self.parent[self.parent[i as usize] as usize];
            self.parent[i as usize] = grand;
            i = grand;
        }
        i
    }

    fn union(&mut self, a: u32, b: u32) {
        let (ra, rb) = (self.find(a), self.find(b));
        if ra == rb {
            return;
        }
        let (big, small) = if self.size[ra as usize] >= self.size[rb as usize] { (ra, rb) } else { (rb, ra) };
        self.parent[small as usize] = big;
        self.size[big as usize] += self.size[small as usize];
    }

    /// Writes row `y`'s labels into `out` (`width` entries): the component's root for pixels of
    /// components of at least `min_size` pixels, else [`NO_LABEL`].
    pub(crate) fn label_row(&self, y: usize, min_size: u32, out: &mut [u32]) {
        out.fill(NO_LABEL);
        let (a, b) = (self.row_start[y] as usize, self.row_start[y + 1] as usize);
        for (i, run) in self.runs[a..b].iter().enumerate() {
            let root = self.parent[a + i];
            if self.size[root as usize] >= min_size {
                out[run.x0 as usize..=run.x1 as usize].fill(root);
            }
        }
    }

    /// Size of the component with root `root`.
    #[cfg(test)]
    pub(crate) fn size_of(&self, root: u32) -> u32 {
        self.size[root as usize]
    }

    /// Capacities of the buffers (for the no-allocation check).
    #[cfg(test)]
    pub(crate) fn capacities(&self) -> [usize; 4] {
        [self.runs.capacity(), self.row_start.capacity(), self.parent.capacity(), self.size.capacity()]
    }

    pub(crate) fn height(&self) -> usize {
        self.height
    }

    pub(crate) fn width(&self) -> usize {
        self.width
    }
}

#[cfg(test)]
mod tests {
    use super::super::threshold::BLACK;
    use super::*;

    /// Pixel union-find with the upstream detector's link rules, written out per pixel.
    fn naive_labels(t: &[u8], w: usize, h: usize) -> Vec<usize> {
        let mut parent: Vec<usize> = (0..w * h).collect();
        fn find(p: &mut [usize], mut i: usize) -> usize {
            while p[i] != i {
                i = p[i];
            }
            i
        }
        let mut link = |a: usize, b: usize| {
            let (ra, rb) = (find(&mut parent, a), find(&mut parent, b));
            parent[ra.max(rb)] = ra.min(rb);
        };
        for y in 0..h {
            for x in 1..w.saturating_sub(1) {
                let v = t[y * w + x];
                if v == UNKNOWN {
                    continue;
                }
                let mut try_link = |xx: usize, yy: usize| {
                    if t[yy * w + xx] == v {
                        link(y * w + x, yy * w + xx);
                    }
                };
                try_link(x - 1, y);
                if y > 0 {
                    try_link(x, y - 1);
                    if v == WHITE {
                        try_link(x - 1, y - 1);
                        try_link(x + 1, y - 1);
                    }
                }
            }
        }
        (0..w * h).map(|i| find(&mut parent, i)).collect()
    }

    #[test]
    fn run_components_equal_pixel_components() {
        let mut state = 99u32;
        for (w, h) in [(1, 1), (2, 3), (7, 5), (23, 17), (40, 31)] {
            for density in [2u32, 5, 9] {
                let t: Vec<u8> = (0..w * h)
                    .map(|_| {
                        state = state.wrapping_mul(1664525).wrapping_add(1013904223);
                        match (state >> 24) % 10 {
                            v if v < density / 3 => UNKNOWN,
                            v if v < density => BLACK,
                            _ => WHITE,
                        }
                    })
                    .collect();
                let mut c = Components::default();
                c.run(&t, w, h);
                let truth = naive_labels(&t, w, h);
                let mut labels = vec![vec![0u32; w]; h];
                for (y, row) in labels.iter_mut().enumerate() {
                    c.label_row(y, 1, row);
                }
                // Same partition of the linked pixels (the last column is left out).
                for i in 0..w * h {
                    for j in 0..w * h {
                        let (xi, xj) = (i % w, j % w);
                        if t[i] == UNKNOWN || t[j] == UNKNOWN || xi == w - 1 || xj == w - 1 {
                            continue;
                        }
                        let same = labels[i / w][xi] == labels[j / w][xj];
                        assert_eq!(same, truth[i] == truth[j], "{w}x{h} pixels {i} {j}");
                    }
                }
                // Sizes are pixel counts.
                for y in 0..h {
                    for x in 0..w.saturating_sub(1) {
                        if t[y * w + x] != UNKNOWN {
                            let n = (0..w * h).filter(|&j| j % w != w - 1 && truth[j] == truth[y * w + x]).count();
                            assert_eq!(c.size_of(labels[y][x]) as usize, n);
                        }
                    }
                }
            }
        }
    }
}
