//! Morton order over voxel keys: the shared basis of the exchange octrees and the `.bt` export.
//!
//! Interleaving the key bits (x lowest) makes a depth-first walk of an octree visit leaves in
//! ascending code order, and makes the three bits at a level the child index `x + 2y + 4z`, which
//! is OctoMap's child numbering. So a sorted code list *is* the octree: the children of a node
//! are contiguous runs, found by binary search, and no node objects are ever built.

use std::ops::Range;

/// Interleaves the bits of the three (non-negative, relative) coordinates.
pub(crate) fn morton(rel: [u32; 3]) -> u128 {
    let mut code = 0u128;
    for bit in 0..32 {
        for (axis, &v) in rel.iter().enumerate() {
            code |= u128::from((v >> bit) & 1) << (3 * bit + axis);
        }
    }
    code
}

/// Inverse of [`morton`].
pub(crate) fn demorton(code: u128) -> [u32; 3] {
    let mut rel = [0u32; 3];
    for bit in 0..32 {
        for (axis, v) in rel.iter_mut().enumerate() {
            *v |= (((code >> (3 * bit + axis)) & 1) as u32) << bit;
        }
    }
    rel
}

/// Child index of a code inside its ancestor at `level` (the ancestor spans `2^level` voxels per
/// axis; level 0 is a voxel).
pub(crate) fn child_index(code: u128, level: u32) -> usize {
    ((code >> (3 * (level - 1))) & 7) as usize
}

/// Splits the sorted codes of one node at `level` into its eight children's runs.
pub(crate) fn child_ranges(codes: &[u128], level: u32) -> [Range<usize>; 8] {
    let mut ranges: [Range<usize>; 8] = Default::default();
    let mut start = 0;
    for (child, range) in ranges.iter_mut().enumerate() {
        let end = start + codes[start..].partition_point(|&c| child_index(c, level) <= child);
        *range = start..end;
        start = end;
    }
    ranges
}

/// Smallest depth whose cube (`2^depth` voxels per axis) holds all relative coordinates; at
/// least 1 so that the root is always an inner node.
pub(crate) fn depth_for(max_rel: u32) -> u32 {
    (32 - max_rel.leading_zeros()).max(1)
}

/// A key set as an octree over its bounding cube.
pub(crate) struct SortedKeys {
    /// Lowest key on each axis: the cube's corner.
    pub(crate) min: [i32; 3],
    /// Levels below the root (the cube spans `2^depth` voxels per axis).
    pub(crate) depth: u32,
    /// Morton code of each key relative to `min` and the key's index in the input, ascending.
    pub(crate) codes: Vec<(u128, usize)>,
}

/// Bounding-cube origin and sorted codes of a set of keys; `None` when empty.
pub(crate) fn sorted_codes<'a>(keys: impl Iterator<Item = &'a [i32; 3]> + Clone) -> Option<SortedKeys> {
    let mut min = [i32::MAX; 3];
    let mut max = [i32::MIN; 3];
    let mut any = false;
    for k in keys.clone() {
        any = true;
        for a in 0..3 {
            min[a] = min[a].min(k[a]);
            max[a] = max[a].max(k[a]);
        }
    }
    if !any {
        return None;
    }
    let span = (0..3).map(|a| relative(max[a], min[a])).max().unwrap_or(0);
    let mut codes: Vec<(u128, usize)> = keys
        .enumerate()
        .map(|(i, k)| (morton([relative(k[0], min[0]), relative(k[1], min[1]), relative(k[2], min[2])]), i))
        .collect();
    codes.sort_unstable();
    Some(SortedKeys { min, depth: depth_for(span), codes })
}

/// `k − min` as an unsigned offset (always fits: both are i32 and `k ≥ min`).
pub(crate) fn relative(k: i32, min: i32) -> u32 {
    (i64::from(k) - i64::from(min)) as u32
}

/// `min + rel` back to a key; `None` when it leaves the i32 range (only on corrupt input).
pub(crate) fn absolute(min: i32, rel: u32) -> Option<i32> {
    i32::try_from(i64::from(min) + i64::from(rel)).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_round_trips_and_orders_children_as_octomap() {
        let rel = [0x8000_0001, 0x1234_5678, 0xffff_ffff];
        assert_eq!(demorton(morton(rel)), rel);
        assert_eq!(child_index(morton([1, 0, 0]), 1), 1);
        assert_eq!(child_index(morton([0, 1, 0]), 1), 2);
        assert_eq!(child_index(morton([0, 0, 1]), 1), 4);
        assert_eq!(depth_for(0), 1);
        assert_eq!(depth_for(1), 1);
        assert_eq!(depth_for(2), 2);
        assert_eq!(depth_for(u32::MAX), 32);
    }
}
