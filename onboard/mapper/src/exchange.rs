//! Compact exchange encoding of a finished submap (spec §4.1 "SubmapFinished", §4.3).
//!
//! The thesis serialized its submaps as they were (700 KB on average). Here both voxel grids are
//! sent as octree structure bits over the submap's bounding cube, so voxel keys cost about a bit
//! each instead of 12 bytes, followed by the per-voxel payload in separate streams, and the whole
//! body is zlib-compressed when that is smaller (it is on real content: see the README).
//!
//! # What "lossless" means
//!
//! - Cloud: the exact voxel set (keys at the cloud's leaf size), exact intensity and obstacle
//!   bit; each centroid is quantized inside its voxel to [`CENTROID_QUANTA`] steps per axis
//!   (leaf/64 = 0.78 mm at 5 cm), decoded at the step's centre, so it moves by at most leaf/128
//!   (0.39 mm) per axis and stays in its voxel. Points come back in Morton order.
//! - Octree: the exact leaf set and every leaf's log-odds bit for bit (a palette of the distinct
//!   f32 values plus one index per leaf), hence every occupancy state and clamped value.
//!   Blocks of up to 8³ leaves with the same value are sent as one pruned node (OctoMap's
//!   pruning, but only of identical values, so nothing is lost).
//! - Header: robot id, index, stamps, image count, distance, `t_prev_this` and the switch
//!   covariance as raw f64 (bit exact).
//!
//! A cloud with two points in one voxel (not a valid [`VoxelCloud`]) keeps the first.
//!
//! # Layout (little endian)
//!
//! Header: magic `SUBM`, version, flags (bit 0: body is zlib), robot id u16, index u32, start
//! and end stamps u64, images u32, distance f64, translation 3×f64, quaternion (i, j, k, w)
//! 4×f64, covariance 36×f64 (row major). Body: cloud (leaf f64, count u32, then if non-empty:
//! min key 3×i32, depth u8, one child-mask byte per inner node depth first, x, y, z offsets and
//! intensity differences to the previous point, one byte per point each, obstacle bits packed),
//! then octree (resolution f64, params 5×f32, cell count u32, record count u32, then if
//! non-empty: min key, depth, palette count u32 and f32 values, two bytes per inner node with
//! 2 bits per child (0 none, 1 leaf, 2 inner), one palette index per leaf record, u8/u16/u32 by
//! palette size).
//!
//! The decoder is total: every count is checked against the bytes left before anything is
//! reserved, decompression has an output limit, and pruned nodes are bounded in size.

pub(crate) mod octree;
mod wire;

use std::collections::HashMap;

use nalgebra::{Isometry3, Matrix6, Quaternion, Translation3, UnitQuaternion};

use crate::cloud::{MapPoint, VoxelCloud};
use crate::occupancy::{OccupancyMap, OccupancyParams, VoxelKey};
use crate::submap::Submap;
use octree::{absolute, child_ranges, demorton, sorted_codes};
use wire::Reader;

const MAGIC: &[u8; 4] = b"SUBM";
const VERSION: u8 = 1;
const FLAG_ZLIB: u8 = 1;

/// Centroid quantization steps per voxel and axis (6 bits: leaf/64 = 0.78 mm at 5 cm).
pub const CENTROID_QUANTA: u32 = 64;

/// Largest pruned block: a pruned node spans at most `2^MAX_PRUNE_LEVEL` leaves per axis, which
/// bounds how far a few bytes can expand on decoding.
const MAX_PRUNE_LEVEL: u32 = 3;

/// Hard caps for the decoder (far above any submap: 7 m of driving gives ~10⁵ of each).
const MAX_CLOUD_POINTS: usize = 1 << 24;
const MAX_OCTREE_CELLS: usize = 1 << 24;
const MAX_BODY_BYTES: usize = 1 << 26;

/// Body compression choice for [`encode_submap_with`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Compression {
    /// Raw body (the structure streams only).
    None,
    /// zlib (deflate) over the body.
    Zlib,
    /// Whichever of the two is smaller (what [`encode_submap`] uses).
    Smallest,
}

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ExchangeError {
    #[error("not a submap encoding (bad magic)")]
    BadMagic,
    #[error("unsupported submap encoding version {0}")]
    UnsupportedVersion(u8),
    #[error("unknown flags {0:#04x}")]
    UnknownFlags(u8),
    #[error("input ends inside a field")]
    Truncated,
    #[error("non-finite or out-of-range number")]
    NonFinite,
    #[error("zlib body does not decompress within the size limit")]
    Decompression,
    #[error("inconsistent structure: {0}")]
    Corrupt(&'static str),
    #[error("{0} trailing bytes")]
    TrailingBytes(usize),
}

/// Appends the encoding of `submap` to `out`, compressed when that is smaller.
pub fn encode_submap(submap: &Submap, out: &mut Vec<u8>) {
    encode_submap_with(submap, Compression::Smallest, out);
}

/// Appends the encoding of `submap` to `out` with the given body compression.
pub fn encode_submap_with(submap: &Submap, compression: Compression, out: &mut Vec<u8>) {
    let mut body = Vec::new();
    encode_cloud(&submap.cloud, &mut body);
    encode_octree(&submap.occupancy, &mut body);
    let zlib = match compression {
        Compression::None => None,
        Compression::Zlib => Some(miniz_oxide::deflate::compress_to_vec_zlib(&body, 9)),
        Compression::Smallest => {
            Some(miniz_oxide::deflate::compress_to_vec_zlib(&body, 9)).filter(|z| z.len() < body.len())
        }
    };
    out.extend_from_slice(MAGIC);
    out.push(VERSION);
    out.push(if zlib.is_some() { FLAG_ZLIB } else { 0 });
    out.extend_from_slice(&submap.robot_id.to_le_bytes());
    out.extend_from_slice(&submap.index.to_le_bytes());
    out.extend_from_slice(&submap.start_stamp_ns.to_le_bytes());
    out.extend_from_slice(&submap.end_stamp_ns.to_le_bytes());
    out.extend_from_slice(&submap.images.to_le_bytes());
    out.extend_from_slice(&submap.distance_m.to_le_bytes());
    let t = &submap.t_prev_this;
    let q = t.rotation.quaternion().coords;
    for v in t.translation.vector.iter().chain(q.iter()).chain(submap.switch_covariance.transpose().iter()) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(zlib.as_deref().unwrap_or(&body));
}

/// Decodes an encoding made by [`encode_submap`]; never panics, whatever the bytes.
pub fn decode_submap(bytes: &[u8]) -> Result<Submap, ExchangeError> {
    let mut r = Reader::new(bytes);
    if r.bytes(4)? != MAGIC {
        return Err(ExchangeError::BadMagic);
    }
    let version = r.u8()?;
    if version != VERSION {
        return Err(ExchangeError::UnsupportedVersion(version));
    }
    let flags = r.u8()?;
    if flags & !FLAG_ZLIB != 0 {
        return Err(ExchangeError::UnknownFlags(flags));
    }
    let robot_id = r.u16()?;
    let index = r.u32()?;
    let start_stamp_ns = r.u64()?;
    let end_stamp_ns = r.u64()?;
    let images = r.u32()?;
    let distance_m = r.f64()?;
    let translation = Translation3::new(r.f64()?, r.f64()?, r.f64()?);
    // Written as nalgebra stores them, (i, j, k, w); `Quaternion::new` takes (w, i, j, k).
    let (i, j, k, w) = (r.f64()?, r.f64()?, r.f64()?, r.f64()?);
    let q = Quaternion::new(w, i, j, k);
    if (q.norm() - 1.0).abs() > 1e-6 {
        return Err(ExchangeError::Corrupt("rotation is not a unit quaternion"));
    }
    let mut cov = [0.0; 36];
    for v in &mut cov {
        *v = r.f64()?;
    }
    let switch_covariance = Matrix6::from_row_slice(&cov);
    let rest = r.rest();
    let inflated;
    let body = if flags & FLAG_ZLIB != 0 {
        inflated = miniz_oxide::inflate::decompress_to_vec_zlib_with_limit(rest, MAX_BODY_BYTES)
            .map_err(|_| ExchangeError::Decompression)?;
        &inflated[..]
    } else {
        rest
    };
    let mut r = Reader::new(body);
    let cloud = decode_cloud(&mut r)?;
    let occupancy = decode_octree(&mut r)?;
    if r.remaining() != 0 {
        return Err(ExchangeError::TrailingBytes(r.remaining()));
    }
    Ok(Submap {
        robot_id,
        index,
        start_stamp_ns,
        end_stamp_ns,
        t_prev_this: Isometry3::from_parts(translation, UnitQuaternion::new_unchecked(q)),
        switch_covariance,
        cloud,
        occupancy,
        images,
        distance_m,
    })
}

fn put_key(out: &mut Vec<u8>, key: &VoxelKey) {
    key.iter().for_each(|k| out.extend_from_slice(&k.to_le_bytes()));
}

fn read_key_depth(r: &mut Reader<'_>) -> Result<(VoxelKey, u32), ExchangeError> {
    let min = [r.i32()?, r.i32()?, r.i32()?];
    let depth = u32::from(r.u8()?);
    if !(1..=32).contains(&depth) {
        return Err(ExchangeError::Corrupt("octree depth outside 1..=32"));
    }
    Ok((min, depth))
}

fn key_at(min: &VoxelKey, code: u128) -> Result<VoxelKey, ExchangeError> {
    let rel = demorton(code);
    let key = [absolute(min[0], rel[0]), absolute(min[1], rel[1]), absolute(min[2], rel[2])];
    match key {
        [Some(x), Some(y), Some(z)] => Ok([x, y, z]),
        _ => Err(ExchangeError::Corrupt("voxel key outside the i32 range")),
    }
}

// --- cloud --------------------------------------------------------------------------------------

fn encode_cloud(cloud: &VoxelCloud, out: &mut Vec<u8>) {
    out.extend_from_slice(&cloud.leaf_m.to_le_bytes());
    let keys: Vec<VoxelKey> = cloud.points.iter().map(|p| cloud.voxel_of(&p.position_m)).collect();
    let Some(octree::SortedKeys { min, depth, mut codes }) = sorted_codes(keys.iter()) else {
        out.extend_from_slice(&0u32.to_le_bytes());
        return;
    };
    // Ties sort by point index, so the first point of a (non-canonical) duplicated voxel is kept.
    codes.dedup_by_key(|(code, _)| *code);
    out.extend_from_slice(&(codes.len() as u32).to_le_bytes());
    put_key(out, &min);
    out.push(depth as u8);
    let code_list: Vec<u128> = codes.iter().map(|(c, _)| *c).collect();
    write_masks(&code_list, depth, out);
    let leaf = cloud.leaf_m;
    for axis in 0..3 {
        for &(_, i) in &codes {
            let p = &cloud.points[i].position_m;
            let frac = f64::from(p[axis]) / leaf - f64::from(keys[i][axis]);
            out.push((frac * f64::from(CENTROID_QUANTA)).floor().clamp(0.0, f64::from(CENTROID_QUANTA - 1)) as u8);
        }
    }
    // Intensity as the difference to the previous point in Morton order (neighbours look alike).
    let mut previous = 0u8;
    out.extend(codes.iter().map(|&(_, i)| {
        let v = cloud.points[i].intensity;
        let delta = v.wrapping_sub(previous);
        previous = v;
        delta
    }));
    for chunk in codes.chunks(8) {
        let bits = chunk.iter().enumerate().fold(0u8, |b, (j, &(_, i))| b | (u8::from(cloud.points[i].obstacle) << j));
        out.push(bits);
    }
}

/// One child-mask byte per inner node, depth first.
fn write_masks(codes: &[u128], level: u32, out: &mut Vec<u8>) {
    let ranges = child_ranges(codes, level);
    out.push(ranges.iter().enumerate().fold(0u8, |m, (c, r)| if r.is_empty() { m } else { m | (1 << c) }));
    if level > 1 {
        for r in ranges.into_iter().filter(|r| !r.is_empty()) {
            write_masks(&codes[r], level - 1, out);
        }
    }
}

fn read_masks(
    r: &mut Reader<'_>,
    level: u32,
    base: u128,
    max_leaves: usize,
    out: &mut Vec<u128>,
) -> Result<(), ExchangeError> {
    let mask = r.u8()?;
    if mask == 0 {
        return Err(ExchangeError::Corrupt("inner node without children"));
    }
    for child in (0..8u32).filter(|c| mask & (1 << c) != 0) {
        let code = base | (u128::from(child) << (3 * (level - 1)));
        if level == 1 {
            if out.len() == max_leaves {
                return Err(ExchangeError::Corrupt("more cloud voxels than declared"));
            }
            out.push(code);
        } else {
            read_masks(r, level - 1, code, max_leaves, out)?;
        }
    }
    Ok(())
}

fn decode_cloud(r: &mut Reader<'_>) -> Result<VoxelCloud, ExchangeError> {
    let leaf_m = r.f64()?;
    if leaf_m <= 0.0 {
        return Err(ExchangeError::NonFinite);
    }
    let n = r.u32()? as usize;
    let mut cloud = VoxelCloud::new(leaf_m);
    if n == 0 {
        return Ok(cloud);
    }
    // Each point needs at least 4 payload bytes (3 offsets and its intensity).
    if n > MAX_CLOUD_POINTS || n > r.remaining() / 4 {
        return Err(ExchangeError::Truncated);
    }
    let (min, depth) = read_key_depth(r)?;
    let mut codes = Vec::with_capacity(n);
    read_masks(r, depth, 0, n, &mut codes)?;
    if codes.len() != n {
        return Err(ExchangeError::Corrupt("fewer cloud voxels than declared"));
    }
    let offsets = [r.bytes(n)?, r.bytes(n)?, r.bytes(n)?];
    let intensity = r.bytes(n)?;
    let obstacle = r.bytes(n.div_ceil(8))?;
    cloud.points.reserve_exact(n);
    let mut previous = 0u8;
    let q = f64::from(CENTROID_QUANTA);
    for (i, &code) in codes.iter().enumerate() {
        let key = key_at(&min, code)?;
        let mut p = [0f32; 3];
        for a in 0..3 {
            let o = f64::from(offsets[a][i]);
            if o >= q {
                return Err(ExchangeError::Corrupt("centroid offset outside its voxel"));
            }
            p[a] = ((f64::from(key[a]) + (o + 0.5) / q) * leaf_m) as f32;
        }
        cloud.points.push(MapPoint {
            position_m: p.into(),
            intensity: {
                previous = previous.wrapping_add(intensity[i]);
                previous
            },
            obstacle: obstacle[i / 8] & (1 << (i % 8)) != 0,
        });
    }
    Ok(cloud)
}

// --- octree -------------------------------------------------------------------------------------

struct OctreeWriter<'a> {
    codes: &'a [u128],
    values: &'a [u32],
    structure: Vec<u8>,
    /// Palette index per leaf record, depth first.
    records: Vec<u32>,
}

impl OctreeWriter<'_> {
    /// Writes the node at `level` covering `range` of the sorted codes.
    fn node(&mut self, start: usize, end: usize, level: u32) {
        let ranges = child_ranges(&self.codes[start..end], level);
        let mut bits = 0u16;
        let mut inner = Vec::new();
        for (c, r) in ranges.iter().enumerate() {
            let (s, e) = (start + r.start, start + r.end);
            if s == e {
                continue;
            }
            let child_level = level - 1;
            let prunable = child_level <= MAX_PRUNE_LEVEL
                && e - s == 1 << (3 * child_level)
                && self.values[s..e].iter().all(|&v| v == self.values[s]);
            if prunable {
                bits |= 1 << (2 * c);
                self.records.push(self.values[s]);
            } else {
                bits |= 2 << (2 * c);
                inner.push((s, e));
            }
        }
        self.structure.extend_from_slice(&bits.to_le_bytes());
        for (s, e) in inner {
            self.node(s, e, level - 1);
        }
    }
}

fn encode_octree(map: &OccupancyMap, out: &mut Vec<u8>) {
    out.extend_from_slice(&map.resolution_m.to_le_bytes());
    let p = &map.params;
    for v in [p.hit_log_odds, p.miss_log_odds, p.min_log_odds, p.max_log_odds, p.occupied_log_odds] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let cells: Vec<(VoxelKey, f32)> = map.iter().collect();
    let Some(octree::SortedKeys { min, depth, codes }) = sorted_codes(cells.iter().map(|(k, _)| k)) else {
        out.extend_from_slice(&[0; 8]);
        return;
    };
    let mut palette: HashMap<u32, u32> = HashMap::new();
    let mut palette_values = Vec::new();
    let values: Vec<u32> = codes
        .iter()
        .map(|&(_, i)| {
            let bits = cells[i].1.to_bits();
            *palette.entry(bits).or_insert_with(|| {
                palette_values.push(bits);
                (palette_values.len() - 1) as u32
            })
        })
        .collect();
    let code_list: Vec<u128> = codes.iter().map(|(c, _)| *c).collect();
    let mut w = OctreeWriter { codes: &code_list, values: &values, structure: Vec::new(), records: Vec::new() };
    w.node(0, code_list.len(), depth);
    out.extend_from_slice(&(cells.len() as u32).to_le_bytes());
    out.extend_from_slice(&(w.records.len() as u32).to_le_bytes());
    put_key(out, &min);
    out.push(depth as u8);
    out.extend_from_slice(&(palette_values.len() as u32).to_le_bytes());
    palette_values.iter().for_each(|v| out.extend_from_slice(&v.to_le_bytes()));
    out.extend_from_slice(&w.structure);
    let width = index_width(palette_values.len());
    for &v in &w.records {
        out.extend_from_slice(&v.to_le_bytes()[..width]);
    }
}

fn index_width(palette_len: usize) -> usize {
    match palette_len {
        0..=256 => 1,
        257..=65536 => 2,
        _ => 4,
    }
}

/// A decoded leaf record: the code of its first cell and its level (0 = one voxel).
struct Record {
    code: u128,
    level: u32,
}

struct OctreeReader<'a, 'b> {
    r: &'b mut Reader<'a>,
    records: Vec<Record>,
    max_records: usize,
    cells: usize,
}

impl OctreeReader<'_, '_> {
    fn node(&mut self, level: u32, base: u128) -> Result<(), ExchangeError> {
        let bits = self.r.u16()?;
        if bits == 0 {
            return Err(ExchangeError::Corrupt("inner node without children"));
        }
        let mut inner = [false; 8];
        for c in 0..8u32 {
            let code = base | (u128::from(c) << (3 * (level - 1)));
            match (bits >> (2 * c)) & 3 {
                0 => {}
                1 => {
                    let child_level = level - 1;
                    if child_level > MAX_PRUNE_LEVEL {
                        return Err(ExchangeError::Corrupt("pruned node too large"));
                    }
                    if self.records.len() == self.max_records {
                        return Err(ExchangeError::Corrupt("more leaf records than declared"));
                    }
                    self.cells += 1 << (3 * child_level);
                    self.records.push(Record { code, level: child_level });
                }
                2 if level > 1 => inner[c as usize] = true,
                _ => return Err(ExchangeError::Corrupt("bad child code")),
            }
        }
        for c in (0..8u32).filter(|&c| inner[c as usize]) {
            self.node(level - 1, base | (u128::from(c) << (3 * (level - 1))))?;
        }
        Ok(())
    }
}

fn decode_octree(r: &mut Reader<'_>) -> Result<OccupancyMap, ExchangeError> {
    let resolution_m = r.f64()?;
    let mut p = [0f32; 5];
    for v in &mut p {
        *v = r.f32()?;
    }
    if resolution_m <= 0.0 || p.iter().any(|v| !v.is_finite()) || p[2] > p[3] {
        return Err(ExchangeError::NonFinite);
    }
    let params = OccupancyParams {
        hit_log_odds: p[0],
        miss_log_odds: p[1],
        min_log_odds: p[2],
        max_log_odds: p[3],
        occupied_log_odds: p[4],
    };
    let mut map = OccupancyMap::new(resolution_m, params);
    let n_cells = r.u32()? as usize;
    let n_records = r.u32()? as usize;
    if n_cells == 0 && n_records == 0 {
        return Ok(map);
    }
    // A record costs at least a quarter byte of structure and one index byte.
    if n_cells > MAX_OCTREE_CELLS || n_records == 0 || n_records > r.remaining() || n_cells < n_records {
        return Err(ExchangeError::Corrupt("octree counts"));
    }
    let (min, depth) = read_key_depth(r)?;
    let palette_len = r.u32()? as usize;
    if palette_len == 0 || palette_len > n_records || palette_len > r.remaining() / 4 {
        return Err(ExchangeError::Corrupt("palette size"));
    }
    let mut palette = Vec::with_capacity(palette_len);
    for _ in 0..palette_len {
        let v = r.f32()?;
        if !v.is_finite() {
            return Err(ExchangeError::NonFinite);
        }
        palette.push(v);
    }
    let mut reader = OctreeReader { r, records: Vec::with_capacity(n_records), max_records: n_records, cells: 0 };
    reader.node(depth, 0)?;
    if reader.records.len() != n_records || reader.cells != n_cells {
        return Err(ExchangeError::Corrupt("octree counts do not match the structure"));
    }
    let records = reader.records;
    let width = index_width(palette_len);
    let indices = r.bytes(n_records * width)?;
    for (record, index) in records.iter().zip(indices.chunks_exact(width)) {
        let mut le = [0u8; 4];
        le[..width].copy_from_slice(index);
        let value = *palette.get(u32::from_le_bytes(le) as usize).ok_or(ExchangeError::Corrupt("palette index"))?;
        for offset in 0..1u128 << (3 * record.level) {
            map.set_log_odds(key_at(&min, record.code | offset)?, value);
        }
    }
    Ok(map)
}
