//! Gradient clusters: the boundary points between each pair of touching black and white
//! components.
//!
//! Wherever a black and a white pixel are neighbours (right, down, and both lower diagonals) and
//! both their components have at least [`MIN_COMPONENT_PIXELS`] pixels, the point half-way
//! between them joins the cluster of that (black, white) component pair. Keying clusters by the
//! pair keeps the outline of a tag's black square apart from the edges of its data cells and from
//! whatever else its white border touches.

use super::components::{Components, NO_LABEL};

/// Components smaller than this take part in no cluster (upstream: 25).
pub(crate) const MIN_COMPONENT_PIXELS: u32 = 25;

/// A boundary point in doubled coordinates (`x = 2·column + dx`, so images are limited to
/// [`MAX_SIDE`] px), with the direction towards the white pixel (`gx`, `gy` ∈ {−1, 0, 1}) and,
/// once the quad fit computes it, its angle key.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Pt {
    pub x: u16,
    pub y: u16,
    pub gx: i8,
    pub gy: i8,
    pub slope: f32,
}

/// Largest image side the clusters can address (doubled coordinates in 16 bits; the upstream
/// library has the same limit).
pub(crate) const MAX_SIDE: usize = 32767;

/// Clusters as contiguous slices of one point buffer, kept between frames.
#[derive(Debug, Default)]
pub(crate) struct Clusters {
    /// Open-addressing table from a component pair to its cluster index.
    table_keys: Vec<u64>,
    table_values: Vec<u32>,
    /// Slots of `table_keys` in use (to clear them).
    used_slots: Vec<u32>,
    /// Points in scan order with their cluster index.
    raw: Vec<(u32, Pt)>,
    /// Per column of a row: non-zero where a forward neighbour differs (the pixels to look at).
    changes: Vec<u8>,
    counts: Vec<u32>,
    /// `points[start[c] .. start[c + 1]]` is cluster `c`.
    start: Vec<u32>,
    points: Vec<Pt>,
    label_rows: [Vec<u32>; 2],
}

const EMPTY: u64 = u64::MAX;

impl Clusters {
    /// Collects the clusters of the components of `thresh`.
    pub(crate) fn run(&mut self, thresh: &[u8], components: &Components) {
        self.clear();
        let (w, h) = (components.width(), components.height());
        if w < 3 || h < 3 || w > MAX_SIDE || h > MAX_SIDE {
            self.finish();
            return;
        }
        // Taken out for the scan (moving a Vec allocates nothing) and put back after it.
        let mut rows = std::mem::take(&mut self.label_rows);
        for row in &mut rows {
            row.clear();
            row.resize(w, NO_LABEL);
        }
        components.label_row(1, MIN_COMPONENT_PIXELS, &mut rows[1]);
        let mut changes = std::mem::take(&mut self.changes);
        changes.clear();
        changes.resize(w, 0);
        let mut cached: (u64, u32) = (EMPTY, 0);
        for y in 1..h - 1 {
            rows.swap(0, 1);
            components.label_row(y + 1, MIN_COMPONENT_PIXELS, &mut rows[1]);
            let [cur, next] = &rows;
            let t0 = &thresh[y * w..(y + 1) * w];
            let t1 = &thresh[(y + 1) * w..(y + 2) * w];
            // Where any forward neighbour differs (a branch-free pass the compiler vectorises);
            // boundaries are a small fraction of the pixels.
            for (x, c) in changes[1..w - 1].iter_mut().enumerate() {
                let v = t0[x + 1];
                *c = (v ^ t0[x + 2]) | (v ^ t1[x + 1]) | (v ^ t1[x]) | (v ^ t1[x + 2]);
            }
            let mut x = 1;
            while x < w - 1 {
                // Skip eight unchanged columns at a time.
                if x + 8 < w && changes[x..x + 8].iter().all(|&c| c == 0) {
                    x += 8;
                    continue;
                }
                let here = x;
                x += 1;
                if changes[here] == 0 {
                    continue;
                }
                let x = here;
                let l0 = cur[x];
                if l0 == NO_LABEL {
                    continue;
                }
                let v0 = t0[x];
                // (dx, dy, label, value) of the four forward neighbours.
                let neighbours = [
                    (1i32, 0i32, cur[x + 1], t0[x + 1]),
                    (0, 1, next[x], t1[x]),
                    (-1, 1, next[x - 1], t1[x - 1]),
                    (1, 1, next[x + 1], t1[x + 1]),
                ];
                for (dx, dy, l1, v1) in neighbours {
                    // Labelled pixels are black or white: a different value is the other colour.
                    if l1 == NO_LABEL || v1 == v0 {
                        continue;
                    }
                    let key = if l0 < l1 {
                        (u64::from(l1) << 32) | u64::from(l0)
                    } else {
                        (u64::from(l0) << 32) | u64::from(l1)
                    };
                    let cluster = if cached.0 == key {
                        cached.1
                    } else {
                        let c = self.cluster_of(key);
                        cached = (key, c);
                        c
                    };
                    let towards_white = if v1 > v0 { 1 } else { -1 };
                    let pt = Pt {
                        x: (2 * x as i64 + i64::from(dx)) as u16,
                        y: (2 * y as i64 + i64::from(dy)) as u16,
                        gx: (dx * towards_white) as i8,
                        gy: (dy * towards_white) as i8,
                        slope: 0.0,
                    };
                    self.raw.push((cluster, pt));
                    self.counts[cluster as usize] += 1;
                }
            }
        }
        self.label_rows = rows;
        self.changes = changes;
        self.finish();
    }

    fn clear(&mut self) {
        for &slot in &self.used_slots {
            self.table_keys[slot as usize] = EMPTY;
        }
        self.used_slots.clear();
        self.raw.clear();
        self.counts.clear();
        self.start.clear();
        self.points.clear();
    }

    /// Orders the points by cluster (a counting sort; scan order within a cluster).
    fn finish(&mut self) {
        self.start.clear();
        self.start.push(0);
        let mut total = 0u32;
        for &n in &self.counts {
            total += n;
            self.start.push(total);
        }
        self.points.clear();
        self.points.resize(self.raw.len(), Pt::default());
        // `counts` becomes the next free slot of each cluster.
        for (c, n) in self.counts.iter_mut().enumerate() {
            *n = self.start[c];
        }
        for &(c, pt) in &self.raw {
            let slot = &mut self.counts[c as usize];
            self.points[*slot as usize] = pt;
            *slot += 1;
        }
    }

    fn hash(key: u64, bits: u32) -> usize {
        (key.wrapping_mul(0x9E37_79B9_7F4A_7C15) >> (64 - bits)) as usize
    }

    /// The cluster of a component pair, a new one if the pair is new.
    fn cluster_of(&mut self, key: u64) -> u32 {
        if self.table_keys.is_empty() || (self.used_slots.len() + 1) * 2 > self.table_keys.len() {
            self.grow();
        }
        let bits = self.table_keys.len().trailing_zeros();
        let mask = self.table_keys.len() - 1;
        let mut slot = Self::hash(key, bits);
        loop {
            let k = self.table_keys[slot];
            if k == key {
                return self.table_values[slot];
            }
            if k == EMPTY {
                let c = self.counts.len() as u32;
                self.table_keys[slot] = key;
                self.table_values[slot] = c;
                self.used_slots.push(slot as u32);
                self.counts.push(0);
                return c;
            }
            slot = (slot + 1) & mask;
        }
    }

    /// Doubles the table (at least 1024 slots), re-inserting the pairs in use.
    fn grow(&mut self) {
        let size = (self.table_keys.len() * 2).max(1024);
        let mut keys = vec![EMPTY; size];
        let mut values = vec![0u32; size];
        let bits = size.trailing_zeros();
        for slot in self.used_slots.iter_mut() {
            let (key, value) = (self.table_keys[*slot as usize], self.table_values[*slot as usize]);
            let mut s = Self::hash(key, bits);
            while keys[s] != EMPTY {
                s = (s + 1) & (size - 1);
            }
            keys[s] = key;
            values[s] = value;
            *slot = s as u32;
        }
        self.table_keys = keys;
        self.table_values = values;
    }

    pub(crate) fn len(&self) -> usize {
        self.start.len().saturating_sub(1)
    }

    /// The points of cluster `c` (for the quad fit to sort in place).
    pub(crate) fn cluster_mut(&mut self, c: usize) -> &mut [Pt] {
        let (a, b) = (self.start[c] as usize, self.start[c + 1] as usize);
        &mut self.points[a..b]
    }

    pub(crate) fn cluster_len(&self, c: usize) -> usize {
        (self.start[c + 1] - self.start[c]) as usize
    }

    /// Capacities of the buffers (for the no-allocation check).
    #[cfg(test)]
    pub(crate) fn capacities(&self) -> [usize; 9] {
        [
            self.changes.capacity(),
            self.table_keys.capacity(),
            self.used_slots.capacity(),
            self.raw.capacity(),
            self.counts.capacity(),
            self.start.capacity(),
            self.points.capacity(),
            self.label_rows[0].capacity(),
            self.label_rows[1].capacity(),
        ]
    }
}
