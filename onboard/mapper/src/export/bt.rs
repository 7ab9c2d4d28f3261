//! OctoMap binary `.bt` files: writer and a total reader.
//!
//! The format (OctoMap's `AbstractOccupancyOcTree::writeBinary`): a text header
//! (`# Octomap OcTree binary file`, comment lines, `id OcTree`, `size <nodes>`, `res <m>`,
//! `data`), then the tree depth first from the root. Each node is two bytes, children 0–3 then
//! 4–7, two bits per child at bit `2i` (value `bit(2i+1)·2 + bit(2i)`): 0 unknown, 1 free leaf,
//! 2 occupied leaf, 3 inner node, whose own two bytes follow after its parent's, in child order.
//! The tree is 16 levels deep; a key is `floor(coordinate / res) + 32768`, so our voxel key `k`
//! is OctoMap key `k + 32768`, and the child index is `x + 2y + 4z` of the key bit at that
//! level (the Morton order the exchange encoding uses too). `size` counts all nodes.
//!
//! Like OctoMap's `writeBinary` the file holds maximum-likelihood states only (a reader gives
//! leaves the clamping bounds), and nodes whose eight children are leaves of one state are
//! pruned into one leaf.

use std::collections::HashMap;
use std::io::{self, Write};

use crate::exchange::octree::{child_ranges, demorton, morton};
use crate::occupancy::{Occupancy, OccupancyMap, VoxelKey};

/// First line of every `.bt` file.
pub const BT_MAGIC: &str = "# Octomap OcTree binary file";
const TREE_DEPTH: u32 = 16;
const KEY_OFFSET: i32 = 1 << 15;
const FREE: u16 = 1;
const OCCUPIED: u16 = 2;
const INNER: u16 = 3;

/// Writes the map's maximum-likelihood octree. Voxel keys must lie in [−32768, 32767] (±3.2 km
/// at 10 cm); anything else is `InvalidInput`.
pub fn write_bt(map: &OccupancyMap, out: &mut impl Write) -> io::Result<()> {
    let mut cells = Vec::with_capacity(map.len());
    for (key, _) in map.iter() {
        let mut rel = [0u32; 3];
        for a in 0..3 {
            rel[a] = u32::try_from(i64::from(key[a]) + i64::from(KEY_OFFSET))
                .ok()
                .filter(|&r| r < 1 << TREE_DEPTH)
                .ok_or_else(|| io::Error::new(io::ErrorKind::InvalidInput, "voxel key outside OctoMap's range"))?;
        }
        let state = if map.occupancy(&key) == Occupancy::Occupied { OCCUPIED } else { FREE };
        cells.push((morton(rel), state));
    }
    cells.sort_unstable();
    let codes: Vec<u128> = cells.iter().map(|c| c.0).collect();
    let states: Vec<u16> = cells.iter().map(|c| c.1).collect();
    let mut data = Vec::new();
    let mut nodes = 0usize;
    if !codes.is_empty() {
        nodes = 1 + write_node(&codes, &states, TREE_DEPTH, &mut data);
    }
    write!(
        out,
        "{BT_MAGIC}\n# written by the mapper crate (maximum likelihood, pruned)\n#\nid OcTree\nsize {nodes}\nres {}\ndata\n",
        map.resolution_m
    )?;
    out.write_all(&data)
}

/// Writes one inner node and its inner descendants; returns the number of child nodes below it.
fn write_node(codes: &[u128], states: &[u16], level: u32, out: &mut Vec<u8>) -> usize {
    let ranges = child_ranges(codes, level);
    let mut bits = 0u16;
    let mut count = 0;
    let child_level = level - 1;
    for (c, r) in ranges.iter().enumerate() {
        if r.is_empty() {
            continue;
        }
        count += 1;
        let s = &states[r.clone()];
        let full = r.len() as u64 == 1u64 << (3 * child_level);
        let code = if full && s.iter().all(|&v| v == s[0]) { s[0] } else { INNER };
        bits |= code << (2 * c);
    }
    out.extend_from_slice(&bits.to_le_bytes());
    for (c, r) in ranges.iter().enumerate() {
        if (bits >> (2 * c)) & 3 == INNER {
            count += write_node(&codes[r.clone()], &states[r.clone()], child_level, out);
        }
    }
    count
}

/// A leaf of a `.bt` tree: the cube of `2^level` voxels per axis whose lowest voxel is `key`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BtLeaf {
    pub key: VoxelKey,
    pub level: u8,
    pub occupied: bool,
}

/// A parsed `.bt` file.
#[derive(Debug, Clone, PartialEq)]
pub struct BtTree {
    pub id: String,
    pub resolution_m: f64,
    /// Nodes in the tree (the header's `size`, checked against the data).
    pub node_count: usize,
    /// Leaves depth first (pruned ones have `level > 0`).
    pub leaves: Vec<BtLeaf>,
}

impl BtTree {
    /// Per-voxel states with pruned leaves expanded; `None` when there would be more than
    /// `max_voxels` (a pruned leaf near the root covers up to 2^48 voxels).
    pub fn voxel_states(&self, max_voxels: usize) -> Option<HashMap<VoxelKey, bool>> {
        let total =
            self.leaves.iter().try_fold(0usize, |n, l| n.checked_add(1usize.checked_shl(3 * u32::from(l.level))?))?;
        if total > max_voxels {
            return None;
        }
        let mut states = HashMap::with_capacity(total);
        for leaf in &self.leaves {
            let side = 1i32 << leaf.level;
            for dz in 0..side {
                for dy in 0..side {
                    for dx in 0..side {
                        states.insert([leaf.key[0] + dx, leaf.key[1] + dy, leaf.key[2] + dz], leaf.occupied);
                    }
                }
            }
        }
        Some(states)
    }

    pub fn occupied_leaves(&self) -> usize {
        self.leaves.iter().filter(|l| l.occupied).count()
    }
}

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BtError {
    #[error("first line is not `{BT_MAGIC}`")]
    BadMagic,
    #[error("header: {0}")]
    Header(&'static str),
    #[error("binary data ends inside the tree")]
    Truncated,
    #[error("a voxel at the finest level is marked as an inner node")]
    InnerVoxel,
    #[error("header says {header} nodes, the data holds {data}")]
    SizeMismatch { header: usize, data: usize },
}

/// Parses a `.bt` file (OctoMap's current header format); total on any bytes.
pub fn read_bt(bytes: &[u8]) -> Result<BtTree, BtError> {
    let mut pos = 0;
    let mut line = || -> Option<&[u8]> {
        let rest = bytes.get(pos..)?;
        let end = rest.iter().position(|&b| b == b'\n')?;
        pos += end + 1;
        Some(&rest[..end])
    };
    if !line().is_some_and(|l| l.starts_with(BT_MAGIC.as_bytes())) {
        return Err(BtError::BadMagic);
    }
    let (mut id, mut size, mut res) = (None, None, None);
    loop {
        let text = line().ok_or(BtError::Header("no `data` line"))?;
        let text = std::str::from_utf8(text).map_err(|_| BtError::Header("not UTF-8"))?;
        let mut tokens = text.split_whitespace();
        match tokens.next() {
            Some("data") => break,
            Some(t) if t.starts_with('#') => {}
            Some("id") => id = tokens.next().map(str::to_owned),
            Some("size") => size = tokens.next().and_then(|t| t.parse::<usize>().ok()),
            Some("res") => res = tokens.next().and_then(|t| t.parse::<f64>().ok()),
            _ => {} // OctoMap skips unknown keywords too.
        }
    }
    let id = id.ok_or(BtError::Header("missing id"))?;
    let node_count = size.ok_or(BtError::Header("missing or bad size"))?;
    let resolution_m = res.filter(|r| r.is_finite() && *r > 0.0).ok_or(BtError::Header("missing or bad res"))?;
    let mut tree = BtTree { id, resolution_m, node_count, leaves: Vec::new() };
    if node_count == 0 {
        return Ok(tree);
    }
    let data = &bytes[pos..];
    let mut cursor = 0;
    let nodes = 1 + read_node(data, &mut cursor, TREE_DEPTH, 0, &mut tree.leaves)?;
    if nodes != node_count {
        return Err(BtError::SizeMismatch { header: node_count, data: nodes });
    }
    Ok(tree)
}

fn read_node(
    data: &[u8],
    cursor: &mut usize,
    level: u32,
    base: u128,
    leaves: &mut Vec<BtLeaf>,
) -> Result<usize, BtError> {
    let two = data.get(*cursor..*cursor + 2).ok_or(BtError::Truncated)?;
    *cursor += 2;
    let bits = u16::from_le_bytes([two[0], two[1]]);
    let mut count = 0;
    for c in 0..8u32 {
        let code = base | (u128::from(c) << (3 * (level - 1)));
        let child_level = level - 1;
        match (bits >> (2 * c)) & 3 {
            0 => continue,
            INNER if child_level == 0 => return Err(BtError::InnerVoxel),
            INNER => count += read_node(data, cursor, child_level, code, leaves)?,
            kind => {
                let rel = demorton(code);
                let key = rel.map(|r| r as i32 - KEY_OFFSET);
                leaves.push(BtLeaf { key, level: child_level as u8, occupied: kind != FREE });
            }
        }
        count += 1;
    }
    Ok(count)
}
