//! A tag family as data, and the lookup table that decodes a sampled code word.

/// A family of square tags: a black square of `width_at_border` cells inside a one-cell white
/// ring (`total_width` cells in all), data bits in the cells inside the black border.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TagFamily {
    pub name: &'static str,
    /// Data bits per code (a multiple of 4, so that a quarter turn is a cyclic shift).
    pub nbits: u32,
    /// Smallest Hamming distance between any two codes, over all four rotations.
    pub min_hamming: u32,
    /// Cells along an edge of the black square (the tag's size).
    pub width_at_border: u32,
    /// Cells along an edge including the white ring.
    pub total_width: u32,
    /// White square in a black ring instead (not supported by the detector).
    pub reversed_border: bool,
    /// Cell of bit `i` inside the black square: column `bit_x[i]`, row `bit_y[i]` (rows down);
    /// bit 0 is the most significant bit of a code.
    pub bit_x: &'static [u8],
    pub bit_y: &'static [u8],
    /// The codes; the tag id is the index.
    pub codes: &'static [u64],
}

impl TagFamily {
    /// Mask of the `nbits` data bits.
    pub fn mask(&self) -> u64 {
        if self.nbits >= 64 { u64::MAX } else { (1u64 << self.nbits) - 1 }
    }

    /// The code word read from a tag turned by a quarter: the bit layout is made of four
    /// quarter-turn copies of one quadrant (bit `i + nbits/4` sits where bit `i` lands after
    /// the turn), so a quarter turn moves every bit `nbits/4` places towards the most
    /// significant end, cyclically.
    pub fn rotate90(&self, code: u64) -> u64 {
        let n = self.nbits;
        let q = n / 4;
        ((code << q) | (code >> (n - q))) & self.mask()
    }

    /// Whether the detector can use this family: a layout for every bit, `nbits` a multiple of 4
    /// within a `u64`, cells inside the black square, codes within `nbits`.
    pub(crate) fn is_supported(&self) -> bool {
        let n = self.nbits as usize;
        self.nbits > 0
            && self.nbits <= 64
            && self.nbits.is_multiple_of(4)
            && !self.reversed_border
            && self.width_at_border >= 3
            && self.total_width == self.width_at_border + 2
            && self.total_width as usize <= super::decode::MAX_TOTAL_WIDTH
            && self.bit_x.len() == n
            && self.bit_y.len() == n
            && self.bit_x.iter().chain(self.bit_y).all(|&c| u32::from(c) < self.width_at_border)
            && self.codes.len() < usize::from(u16::MAX)
            && self.codes.iter().all(|&c| c & !self.mask() == 0)
    }
}

/// A decoded code word: which tag, how many bits were wrong, and how many quarter turns of the
/// sampled word ([`TagFamily::rotate90`]) matched it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Decoded {
    pub id: u32,
    pub hamming: u32,
    pub rotation: u32,
}

/// Number of pieces a code word is cut into for the lookup: a word within `CHUNKS - 1` bit
/// errors of a code agrees with it exactly on at least one piece (pigeonhole), so looking up the
/// codes that share each piece finds every candidate.
const CHUNKS: u32 = 4;
/// Most bit errors the table can correct (`CHUNKS - 1`).
pub const MAX_CORRECTABLE: u32 = CHUNKS - 1;

/// Precomputed lookup table from code-word pieces to the codes that contain them ("multi-index
/// hashing"): `CHUNKS` tables of `2^(nbits/CHUNKS)` buckets, each bucket listing the ids whose
/// code has that value in that piece. A query looks at `CHUNKS` buckets per rotation (for
/// tag36h11 about one id each) and counts the differing bits of each candidate. For tag36h11 that
/// is 2 k entries, where a table of every code with up to two flipped bits (the upstream library's
/// design) holds 391 k.
#[derive(Debug, Clone)]
pub struct CodeIndex {
    family: TagFamily,
    max_hamming: u32,
    chunk_bits: u32,
    /// `starts[c * buckets + v] .. starts[c * buckets + v + 1]` index `ids` for piece `c` = `v`.
    starts: Vec<u32>,
    ids: Vec<u16>,
}

impl CodeIndex {
    /// The table for `family` (which must be supported) correcting up to `max_hamming` bits
    /// (at most [`MAX_CORRECTABLE`]).
    pub fn new(family: TagFamily, max_hamming: u32) -> Self {
        let chunk_bits = family.nbits / CHUNKS;
        let buckets = 1usize << chunk_bits;
        let chunk_mask = (1u64 << chunk_bits) - 1;
        let mut counts = vec![0u32; CHUNKS as usize * buckets + 1];
        for &code in family.codes {
            for c in 0..CHUNKS {
                let v = ((code >> (c * chunk_bits)) & chunk_mask) as usize;
                counts[c as usize * buckets + v + 1] += 1;
            }
        }
        for i in 1..counts.len() {
            counts[i] += counts[i - 1];
        }
        let starts = counts;
        let mut fill = starts.clone();
        let mut ids = vec![0u16; family.codes.len() * CHUNKS as usize];
        for (id, &code) in family.codes.iter().enumerate() {
            for c in 0..CHUNKS {
                let v = ((code >> (c * chunk_bits)) & chunk_mask) as usize;
                let slot = &mut fill[c as usize * buckets + v];
                ids[*slot as usize] = id as u16;
                *slot += 1;
            }
        }
        CodeIndex { family, max_hamming: max_hamming.min(MAX_CORRECTABLE), chunk_bits, starts, ids }
    }

    pub fn max_hamming(&self) -> u32 {
        self.max_hamming
    }

    /// The code within `max_hamming` bits of `word` in one of its four rotations, trying the
    /// rotations in order (the family's minimum distance makes the answer unique).
    pub fn decode(&self, word: u64) -> Option<Decoded> {
        let buckets = 1usize << self.chunk_bits;
        let chunk_mask = (1u64 << self.chunk_bits) - 1;
        let mut word = word & self.family.mask();
        for rotation in 0..4 {
            let mut best: Option<(u32, u32)> = None;
            for c in 0..CHUNKS {
                let v = ((word >> (c * self.chunk_bits)) & chunk_mask) as usize;
                let bucket = c as usize * buckets + v;
                let (a, b) = (self.starts[bucket] as usize, self.starts[bucket + 1] as usize);
                for &id in &self.ids[a..b] {
                    let distance = (self.family.codes[usize::from(id)] ^ word).count_ones();
                    if distance <= self.max_hamming && best.is_none_or(|(_, d)| distance < d) {
                        best = Some((u32::from(id), distance));
                    }
                }
            }
            if let Some((id, hamming)) = best {
                return Some(Decoded { id, hamming, rotation });
            }
            word = self.family.rotate90(word);
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::super::tag36h11::TAG36H11;
    use super::*;

    #[test]
    fn tag36h11_is_supported_and_its_layout_is_four_quarter_turns() {
        let f = TAG36H11;
        assert!(f.is_supported());
        // Bit i + 9 sits where bit i lands after a quarter turn (x, y) -> (w - 1 - y, x).
        let w = f.width_at_border as u8;
        for i in 0..27 {
            let (x, y) = (f.bit_x[i], f.bit_y[i]);
            assert_eq!((f.bit_x[i + 9], f.bit_y[i + 9]), (w - 1 - y, x), "bit {i}");
        }
        // Four quarter turns are the identity.
        for &code in f.codes.iter().take(20) {
            let mut w = code;
            for _ in 0..4 {
                w = f.rotate90(w);
            }
            assert_eq!(w, code);
        }
    }

    #[test]
    fn every_code_decodes_in_every_rotation_with_up_to_three_errors() {
        let f = TAG36H11;
        let index = CodeIndex::new(f, 3);
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for (id, &code) in f.codes.iter().enumerate() {
            let mut turned = code;
            for turns in 0..4u32 {
                for errors in 0..=3u32 {
                    let mut word = turned;
                    let mut flipped = 0u64;
                    while flipped.count_ones() < errors {
                        flipped |= 1 << (next() % 36);
                    }
                    word ^= flipped;
                    let d = index.decode(word).expect("decodes");
                    assert_eq!((d.id, d.hamming), (id as u32, errors), "id {id} turns {turns}");
                    assert_eq!(d.rotation, turns, "id {id} turns {turns}");
                }
                // A word that one more quarter turn brings back to the previous one.
                turned = f.rotate90(f.rotate90(f.rotate90(turned)));
            }
        }
    }

    #[test]
    fn words_far_from_every_code_are_rejected() {
        let f = TAG36H11;
        let index = CodeIndex::new(f, 2);
        // Brute force over a sample of words: the table answers exactly when some rotation of
        // some code is within two bits.
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for _ in 0..20_000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let word = (state >> 20) & f.mask();
            let mut truth = None;
            let mut w = word;
            for rotation in 0..4 {
                if truth.is_none()
                    && let Some((id, &c)) = f.codes.iter().enumerate().find(|(_, c)| (**c ^ w).count_ones() <= 2)
                {
                    truth = Some(Decoded { id: id as u32, hamming: (c ^ w).count_ones(), rotation });
                }
                w = f.rotate90(w);
            }
            assert_eq!(index.decode(word), truth);
        }
        assert_eq!(index.decode(0), None);
    }
}
