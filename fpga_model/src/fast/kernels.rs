//! The hot loops, written once as `#[inline(always)]` generic code in shapes LLVM vectorises
//! (element-wise work on fixed-size chunks, reductions as folds over runtime-length slices,
//! selects as mask arithmetic; each choice is commented where it is made);
//! [`super::dispatch`] compiles them again for AVX2 and AVX-512.
//!
//! Layouts (all chosen so the innermost loop runs over contiguous disparities or columns):
//!
//! - census: bit-planes of bytes. Plane `k` of a row holds, for each column, the comparison bits
//!   of neighbours `8k .. 8k + 8` of the window. The Hamming cost only counts differing bits, so
//!   the bit order is free as long as left and right agree; bytes let the census be built with
//!   one compare per 64 columns and the cost be summed with a byte popcount (`vpopcntb`).
//! - the right census is stored mirrored (column `W − 1 − x`), so the right pixels `x − d` of a
//!   left pixel are contiguous and ascending in `d`.
//! - path costs: per pixel and path a vector of `Dp + 2` lanes: a guard, `D` disparities, padding
//!   up to `Dp` (a multiple of the SIMD block), a guard. Guards keep `L(d ± 1)` loads in range
//!   and never win a minimum; padding disparities carry the cost `T::MAX`, which makes their
//!   path costs `Lmax` — never below a real one, so they change neither `M` nor a neighbour.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Mutex, MutexGuard, PoisonError};

use super::lane::Lane;
use crate::image::INVALID;
use crate::stages::lr::candidates;

/// Columns per census block: one 512-bit register of bytes.
pub(crate) const CENSUS_BLOCK: usize = 64;
/// Lanes of the selection loops (winner, right view): 256 bits of `u16`. `D` is a multiple of 16,
/// so these loops never need a remainder.
const SELECT_BLOCK: usize = 16;
/// Paths whose predecessor lies in the previous row: top-left, top, top-right.
pub(crate) const PATHS_FROM_ABOVE: usize = 3;
/// Pixels between a volume prefetch and the use of what it fetched.
const PREFETCH_PX: usize = 4;
/// `winner` entry of a pixel that failed the uniqueness test.
pub(crate) const NO_WINNER: u16 = u16::MAX;

/// The frame geometry and buffer strides, fixed when the matcher is built.
#[derive(Debug, Clone)]
pub(crate) struct Geometry {
    pub width: usize,
    pub height: usize,
    /// `D`.
    pub disparities: usize,
    /// `Dp`: `D` rounded up to the aggregation block.
    pub lanes: usize,
    /// Elements of one path-cost vector: `Dp` plus a guard on each side.
    pub slot: usize,
    /// Columns of a census row rounded up to [`CENSUS_BLOCK`].
    pub width_padded: usize,
    /// Replicated columns left of the image in a padded row (`census_width / 2`).
    pub pad_left: usize,
    /// Bytes per padded image row.
    pub pad_stride: usize,
    /// Window neighbours `(dx, dy)` in raster order without the centre.
    pub neighbours: Vec<(isize, isize)>,
    /// Census bit-planes (`ceil(bits / 8)`).
    pub planes: usize,
    /// Bytes per left census plane row.
    pub left_plane_stride: usize,
    /// Bytes per mirrored right census plane row (room for `W − 1 + Dp` reads).
    pub right_plane_stride: usize,
    pub blocks: usize,
    /// `0, 1, …, Dp − 1`: the disparity of each lane, loaded as a vector by the selection loops.
    pub ramp: Vec<u16>,
}

/// Pixels per row-buffer block (the unit of hand-over between wavefront threads): small enough that a follower thread is only two blocks behind,
/// large enough that the four lock operations per block are noise.
const BLOCK_PX: usize = 64;

impl Geometry {
    pub(crate) fn new(
        width: usize,
        height: usize,
        disparities: usize,
        lane_block: usize,
        census_width: usize,
        census_height: usize,
    ) -> Geometry {
        let lanes = disparities.div_ceil(lane_block) * lane_block;
        let width_padded = width.div_ceil(CENSUS_BLOCK) * CENSUS_BLOCK;
        let (half_w, half_h) = ((census_width / 2) as isize, (census_height / 2) as isize);
        let mut neighbours = Vec::with_capacity(census_width * census_height);
        for dy in -half_h..=half_h {
            for dx in -half_w..=half_w {
                if (dx, dy) != (0, 0) {
                    neighbours.push((dx, dy));
                }
            }
        }
        let planes = neighbours.len().div_ceil(8);
        Geometry {
            width,
            height,
            disparities,
            lanes,
            slot: lanes + 2,
            width_padded,
            pad_left: census_width / 2,
            pad_stride: width_padded + census_width - 1,
            neighbours,
            planes,
            left_plane_stride: width_padded,
            right_plane_stride: width_padded + lanes,
            blocks: width.div_ceil(BLOCK_PX),
            ramp: (0..lanes as u16).collect(),
        }
    }
}

/// The configuration in the form the kernels use it.
#[derive(Debug, Clone)]
pub(crate) struct Params<T> {
    pub p1: T,
    pub path_cost_max: T,
    /// `w` and `T` of the gradient term of the cost; 0 in either disables it.
    pub gradient_weight: u16,
    pub gradient_truncation: u16,
    /// The cost of `x − d < 0`: `SgmConfig::cost_max` (≤ 255).
    pub cost_max: u8,
    /// `P2eff` for each intensity step `g = 0 ..= 255`.
    pub p2_effective: [u8; 256],
    pub uniqueness_percent: u32,
    pub lr_check: bool,
    pub lr_max_diff: u16,
    pub lr_lenient: bool,
    pub subpixel: bool,
}

/// Iteration order of a pass. A backward pass is the forward pass of the image turned by 180°:
/// iteration coordinates `(i, j)` map to physical `(W − 1 − i, H − 1 − j)`, and the reverse
/// directions of `SPEC.md` become the forward ones, so one kernel serves both passes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Direction {
    Forward,
    Backward,
}

impl Direction {
    #[inline(always)]
    pub(crate) fn physical(self, index: usize, extent: usize) -> usize {
        match self {
            Direction::Forward => index,
            Direction::Backward => extent - 1 - index,
        }
    }
}

/// Path costs of the three from-above paths for [`BLOCK_PX`] pixels of one row.
#[derive(Debug)]
pub(crate) struct Block<T> {
    /// `[pixel][path][slot]`.
    pub lanes: Vec<T>,
    /// `M` of each vector, `[pixel][path]`.
    pub minima: Vec<T>,
}

/// The row buffers of one pass, shared by the threads running it as a wavefront.
#[derive(Debug)]
pub(crate) struct PassRows<T> {
    /// `threads + 1` rows; iteration row `j` lives in `rows[j % rows.len()]`.
    pub rows: Vec<Vec<Mutex<Block<T>>>>,
    /// Per thread: `j · blocks + k + 1` after finishing block `k` of its row `j` (monotonic).
    pub done: Vec<AtomicUsize>,
    /// Set when a thread panicked, so waiting threads give up instead of spinning forever.
    pub abort: AtomicBool,
}

impl<T: Lane> PassRows<T> {
    pub(crate) fn new(geometry: &Geometry, threads: usize) -> PassRows<T> {
        let block_len = BLOCK_PX * PATHS_FROM_ABOVE * geometry.slot;
        let rows = (0..=threads)
            .map(|_| {
                (0..geometry.blocks)
                    .map(|_| {
                        // Every value starts as a guard; the data lanes are written by the first
                        // row before anything reads them, the guards are never written.
                        Mutex::new(Block {
                            lanes: vec![T::MAX; block_len],
                            minima: vec![T::MAX; BLOCK_PX * PATHS_FROM_ABOVE],
                        })
                    })
                    .collect()
            })
            .collect();
        PassRows { rows, done: (0..threads).map(|_| AtomicUsize::new(0)).collect(), abort: AtomicBool::new(false) }
    }

    pub(crate) fn threads(&self) -> usize {
        self.done.len()
    }

    pub(crate) fn reset(&self) {
        for done in &self.done {
            done.store(0, Ordering::Relaxed);
        }
        self.abort.store(false, Ordering::Relaxed);
    }

    pub(crate) fn memory_bytes(&self) -> usize {
        let per_block = |b: &Mutex<Block<T>>| {
            let block = lock(b);
            (block.lanes.capacity() + block.minima.capacity()) * size_of::<T>() + size_of::<Mutex<Block<T>>>()
        };
        self.rows.iter().flat_map(|row| row.iter()).map(per_block).sum::<usize>()
            + self.done.capacity() * size_of::<AtomicUsize>()
    }
}

/// Per-thread working rows.
#[derive(Debug)]
pub(crate) struct Scratch<T> {
    census_left: Vec<u8>,
    census_right: Vec<u8>,
    cost: Vec<T>,
    cost_bytes: Vec<u8>,
    /// Horizontal gradients `GL` of the left image's current row.
    gradient_left: Vec<i16>,
    /// `GR` of the right image's current row, mirrored like the census (`GR(x − d)` at
    /// `W − 1 − x + d`), with `Dp` values of slack for the lanes of `x − d < 0`, whose costs are
    /// overwritten.
    gradient_right: Vec<i16>,
    /// The virtual predecessor of a path's first pixel: all zero with `M = 0` and `P2eff = 0`
    /// gives `best = 0`, hence `L = min(C, Lmax)` as the spec asks, without a branch.
    zero: Vec<T>,
    zero_sums: Vec<u16>,
    /// Left-path vectors of the previous and the current pixel.
    horizontal: Vec<T>,
    horizontal_min: [T; 2],
    sums: Vec<u16>,
    /// Running minimum of `S((xr + d), d)` over the row, indexed by `W − 1 − xr`.
    right_cost: Vec<u16>,
    right_disparity: Vec<u16>,
    winner: Vec<u16>,
    refined: Vec<u16>,
    row_out: Vec<u16>,
}

impl<T: Lane> Scratch<T> {
    pub(crate) fn new(geometry: &Geometry) -> Scratch<T> {
        let g = geometry;
        Scratch {
            census_left: vec![0; g.planes * g.left_plane_stride],
            census_right: vec![0; g.planes * g.right_plane_stride],
            cost: vec![T::MAX; g.lanes],
            cost_bytes: vec![0; g.lanes],
            gradient_left: vec![0; g.width],
            gradient_right: vec![0; g.width + g.lanes],
            zero: vec![T::default(); g.slot],
            zero_sums: vec![0; g.lanes],
            horizontal: vec![T::MAX; 2 * g.slot],
            horizontal_min: [T::MAX; 2],
            sums: vec![0; g.lanes],
            right_cost: vec![u16::MAX; g.width + g.lanes],
            right_disparity: vec![0; g.width + g.lanes],
            winner: vec![NO_WINNER; g.width],
            refined: vec![0; g.width],
            row_out: vec![INVALID; g.width],
        }
    }

    pub(crate) fn memory_bytes(&self) -> usize {
        self.census_left.capacity()
            + self.census_right.capacity()
            + self.cost_bytes.capacity()
            + (self.gradient_left.capacity() + self.gradient_right.capacity()) * size_of::<i16>()
            + (self.cost.capacity() + self.zero.capacity() + self.horizontal.capacity()) * size_of::<T>()
            + (self.right_disparity.capacity()
                + self.zero_sums.capacity()
                + self.sums.capacity()
                + self.right_cost.capacity()
                + self.winner.capacity()
                + self.refined.capacity()
                + self.row_out.capacity())
                * size_of::<u16>()
    }
}

/// The read-only inputs of a frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Frame<'a> {
    pub geometry: &'a Geometry,
    pub left: &'a [u8],
    /// Left image with replicated borders, `pad_stride` bytes per row.
    pub padded_left: &'a [u8],
    /// Right image mirrored left-right, with replicated borders.
    pub padded_right: &'a [u8],
}

/// Where the path-cost sum `S` of a row goes.
#[derive(Debug)]
pub(crate) enum Sums<'a> {
    /// Four paths: `S` is complete; select the winners.
    Select,
    /// First half of Eight: store the four-path sum of the row (`W × Dp`).
    Store(&'a mut [u16]),
    /// Second half of Eight: add the stored sum of the other pass, then select.
    AddSelect(&'a [u16]),
}

/// One row of one pass.
#[derive(Debug)]
pub(crate) struct RowJob<'a, 'b, 'o, T> {
    pub frame: Frame<'a>,
    pub params: &'a Params<T>,
    pub pass: &'a PassRows<T>,
    /// Index of this thread in the pass's wavefront.
    pub thread: usize,
    pub direction: Direction,
    /// Iteration row `j`.
    pub row: usize,
    pub scratch: &'b mut Scratch<T>,
    pub sums: Sums<'b>,
    /// The image before the median, `W × H`.
    pub out: &'a Mutex<&'o mut [u16]>,
}

/// Stage 7 and 8 over the whole image.
#[derive(Debug)]
pub(crate) struct FinishJob<'a> {
    pub width: usize,
    pub height: usize,
    pub median: bool,
    pub pre: &'a [u16],
    pub out: &'a mut [u16],
}

/// Work handed to a dispatched kernel.
#[derive(Debug)]
pub(crate) enum Job<'a, 'b, 'o, T> {
    Row(RowJob<'a, 'b, 'o, T>),
    Finish(FinishJob<'a>),
}

/// Another thread of the frame panicked; the scope re-raises its panic.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Aborted;

/// The one entry point of the kernels (compiled once per instruction set).
#[inline(always)]
pub(crate) fn run<T: Lane, const L: usize, A: PixelKernels>(
    job: Job<'_, '_, '_, T>,
    kernels: A,
) -> Result<(), Aborted> {
    match job {
        Job::Row(row) => process_row::<T, L, A>(row, kernels),
        Job::Finish(finish) => {
            finish_image(finish);
            Ok(())
        }
    }
}

pub(crate) fn lock<B>(mutex: &Mutex<B>) -> MutexGuard<'_, B> {
    // A poisoned lock only follows a panic elsewhere, which the thread scope re-raises anyway.
    mutex.lock().unwrap_or_else(PoisonError::into_inner)
}

/// The thread of a pass that runs iteration row `row`: rows go round-robin. (Bands of 2 or 4
/// consecutive rows per thread, which keep more path costs in one core's cache, measured slower:
/// the follower then idles while the leader finishes its band.)
pub(crate) fn wavefront_thread(row: usize, threads: usize) -> usize {
    row % threads
}

/// Waits until thread `thread` of `pass` has reported `target` units of progress.
fn wait_for<T>(pass: &PassRows<T>, thread: usize, target: usize) -> Result<(), Aborted> {
    let mut spins = 0u32;
    while pass.done[thread].load(Ordering::Acquire) < target {
        if pass.abort.load(Ordering::Relaxed) {
            return Err(Aborted);
        }
        // The leader is normally a fraction of a block ahead: spin briefly, then give the core
        // away in case there are more threads than cores.
        if spins < 2_000 {
            std::hint::spin_loop();
            spins += 1;
        } else {
            std::thread::yield_now();
        }
    }
    Ok(())
}

/// Census bit-planes of one row of a padded image (see the module comment).
#[inline(always)]
fn census_row(planes: &mut [u8], plane_stride: usize, padded: &[u8], geometry: &Geometry, y: usize, mirror: bool) {
    let g = geometry;
    let centre_row = &padded[y * g.pad_stride..][..g.pad_stride];
    for (k, plane_neighbours) in g.neighbours.chunks(8).enumerate() {
        let plane = &mut planes[k * plane_stride..][..g.width_padded];
        for (c, out) in plane.chunks_exact_mut(CENSUS_BLOCK).enumerate() {
            let column = g.pad_left + c * CENSUS_BLOCK;
            let centre = &centre_row[column..column + CENSUS_BLOCK];
            let mut acc = [0u8; CENSUS_BLOCK];
            for &(dx, dy) in plane_neighbours {
                let yy = (y as isize + dy).clamp(0, g.height as isize - 1) as usize;
                // The mirrored image sees the neighbour at −dx where the original sees +dx; the
                // same window position then lands in the same bit of both images.
                let dx = if mirror { -dx } else { dx };
                let start = yy * g.pad_stride + (column as isize + dx) as usize;
                let neighbour = &padded[start..start + CENSUS_BLOCK];
                for l in 0..CENSUS_BLOCK {
                    acc[l] = (acc[l] << 1) | u8::from(neighbour[l] < centre[l]);
                }
            }
            out.copy_from_slice(&acc);
        }
    }
}

/// `C(x, y, d)` for `d < Dp` into `cost`: Hamming distance plus the gradient term for
/// `x − d ≥ 0`, `cost_max` for `x − d < 0`, `T::MAX` for the padding disparities. `bytes` is a
/// `Dp`-byte scratch row; `gradient` is `GL(x)`, `gradient_right` the mirrored `GR` row.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn cost_pixel<T: Lane>(
    cost: &mut [T],
    bytes: &mut [u8],
    census_left: &[u8],
    census_right: &[u8],
    gradient_right: &[i16],
    gradient: i16,
    params: &Params<T>,
    g: &Geometry,
    x: usize,
) {
    // The plane count as a constant: the plane loop unrolls and its strides fold away.
    match g.planes {
        0 => cost_planes::<0>(bytes, census_left, census_right, g, x),
        1 => cost_planes::<1>(bytes, census_left, census_right, g, x),
        2 => cost_planes::<2>(bytes, census_left, census_right, g, x),
        3 => cost_planes::<3>(bytes, census_left, census_right, g, x),
        4 => cost_planes::<4>(bytes, census_left, census_right, g, x),
        5 => cost_planes::<5>(bytes, census_left, census_right, g, x),
        6 => cost_planes::<6>(bytes, census_left, census_right, g, x),
        7 => cost_planes::<7>(bytes, census_left, census_right, g, x),
        _ => cost_planes::<8>(bytes, census_left, census_right, g, x),
    }
    if params.gradient_weight > 0 && params.gradient_truncation > 0 {
        let right = &gradient_right[g.width - 1 - x..][..g.lanes];
        let (weight, truncation) = (params.gradient_weight, params.gradient_truncation);
        for (c, &r) in bytes[..g.lanes].iter_mut().zip(right) {
            // In u16: 510 · 15 does not overflow; after the min the term is ≤ 191, and a
            // Hamming cost ≤ 64 plus it stays within the byte.
            let term = (gradient.abs_diff(r) * weight).min(truncation);
            *c = c.wrapping_add(term as u8);
        }
    }
    // One widening loop of runtime length (a byte-to-word store inside the chunked loop above
    // makes LLVM scatter the words one by one).
    for (out, &c) in cost[..g.lanes].iter_mut().zip(&bytes[..g.lanes]) {
        *out = T::from_u8(c);
    }
    if x + 1 < g.disparities {
        cost[x + 1..g.disparities].fill(T::from_u8(params.cost_max));
    }
    if g.lanes > g.disparities {
        cost[g.disparities..g.lanes].fill(T::MAX);
    }
}

/// `G(x) = I(clamp(x + 1)) − I(clamp(x − 1))` of one image row into `out`. A `mirrored` row
/// holds `I(W − 1 − j)` at `j`, so there `G` of the original column is `row[j − 1] − row[j + 1]`.
#[inline(always)]
fn gradient_row(row: &[u8], out: &mut [i16], mirrored: bool) {
    let w = row.len();
    let sign = if mirrored { -1 } else { 1 };
    let difference = |next: u8, previous: u8| sign * (i16::from(next) - i16::from(previous));
    if w == 1 {
        out[0] = 0;
        return;
    }
    // Interior as a zip of shifted slices (vectorises); the two clamped borders apart.
    for ((o, &next), &previous) in out[1..w - 1].iter_mut().zip(&row[2..]).zip(&row[..w - 2]) {
        *o = difference(next, previous);
    }
    out[0] = difference(row[1], row[0]);
    out[w - 1] = difference(row[w - 1], row[w - 2]);
}

/// Hamming distances of `P` census bit-planes into `bytes[..Dp]`, in chunks of one 512-bit
/// register and a 256-bit tail (`Dp` is a multiple of 32).
#[inline(always)]
fn cost_planes<const P: usize>(bytes: &mut [u8], census_left: &[u8], census_right: &[u8], g: &Geometry, x: usize) {
    let mirrored = g.width - 1 - x;
    let mut left = [0u8; P];
    let mut right: [&[u8]; P] = [&[]; P];
    for k in 0..P {
        left[k] = census_left[k * g.left_plane_stride + x];
        right[k] = &census_right[k * g.right_plane_stride + mirrored..][..g.lanes];
    }
    let (chunks, tail) = bytes[..g.lanes].as_chunks_mut::<CENSUS_BLOCK>();
    for (c, out) in chunks.iter_mut().enumerate() {
        *out = hamming_chunk::<P, CENSUS_BLOCK>(&left, &right, c * CENSUS_BLOCK);
    }
    if let Ok(tail) = <&mut [u8; CENSUS_BLOCK / 2]>::try_from(tail) {
        *tail = hamming_chunk::<P, { CENSUS_BLOCK / 2 }>(&left, &right, g.lanes - CENSUS_BLOCK / 2);
    }
}

#[inline(always)]
fn hamming_chunk<const P: usize, const L: usize>(left: &[u8; P], right: &[&[u8]; P], start: usize) -> [u8; L] {
    let mut acc = [0u8; L];
    for k in 0..P {
        let right: &[u8; L] = match right[k][start..].first_chunk() {
            Some(chunk) => chunk,
            None => return acc,
        };
        for l in 0..L {
            // At most 8 planes of 8 bits: the byte never overflows.
            acc[l] = acc[l].wrapping_add((left[k] ^ right[l]).count_ones() as u8);
        }
    }
    acc
}

/// One path's update of one aggregation block (see `SPEC.md` stage 3 and [`super::lane`]).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn path_step<T: Lane, const L: usize>(
    prev: &[T],
    cost: &[T],
    p1: T,
    path_cost_max: T,
    prev_min: T,
    jump: T,
    out: &mut [T],
    sums: &mut [u16; L],
) {
    let (prev, cost, out) = (&prev[..L + 2], &cost[..L], &mut out[..L]);
    for l in 0..L {
        let best = prev[l + 1].min(prev[l].saturating_add(p1)).min(prev[l + 2].saturating_add(p1)).min(jump);
        let value = cost[l].saturating_add(best.minus(prev_min)).min(path_cost_max);
        out[l] = value;
        // At most 8 · 4095 in total: never wraps.
        sums[l] = sums[l].wrapping_add(value.widen());
    }
}

/// The four paths of a pass at one pixel, and their sum. Returns the new minima `M`.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(crate) fn aggregate_pixel<T: Lane, const L: usize>(
    g: &Geometry,
    params: &Params<T>,
    cost: &[T],
    prev: [&[T]; 4],
    prev_min: [T; 4],
    jump: [T; 4],
    outs: [&mut [T]; 4],
    sums_in: &[u16],
    sums_out: &mut [u16],
) -> [T; 4] {
    let [out0, out1, out2, out3] = outs;
    let (p1, lmax) = (params.p1, params.path_cost_max);
    for c in 0..g.lanes / L {
        let base = c * L;
        let cost = &cost[base..base + L];
        let mut sums = [0u16; L];
        sums.copy_from_slice(&sums_in[base..base + L]);
        path_step::<T, L>(&prev[0][base..], cost, p1, lmax, prev_min[0], jump[0], &mut out0[base + 1..], &mut sums);
        path_step::<T, L>(&prev[1][base..], cost, p1, lmax, prev_min[1], jump[1], &mut out1[base + 1..], &mut sums);
        path_step::<T, L>(&prev[2][base..], cost, p1, lmax, prev_min[2], jump[2], &mut out2[base + 1..], &mut sums);
        path_step::<T, L>(&prev[3][base..], cost, p1, lmax, prev_min[3], jump[3], &mut out3[base + 1..], &mut sums);
        sums_out[base..base + L].copy_from_slice(&sums);
    }
    // M of each new vector, read back from L1: reducing the vectors while they are computed
    // makes LLVM spill them and reassemble the lanes through the stack.
    let lanes = 1..g.lanes + 1;
    [min_of(&out0[lanes.clone()]), min_of(&out1[lanes.clone()]), min_of(&out2[lanes.clone()]), min_of(&out3[lanes])]
}

/// The per-pixel work of a row as an instruction set implements it: [`Autovectorised`] is the
/// generic code as LLVM compiles it for the kernel's target features; `super::avx512::Avx512`
/// writes the matching cost and the four path updates with intrinsics. Both give the same bits.
pub(crate) trait PixelKernels: Copy {
    /// Writes the four new vectors from index 1 of `outs` (after the guard), `sums_out =
    /// sums_in + Σ L_r`, and returns the new minima `M`.
    #[allow(clippy::too_many_arguments)]
    fn aggregate<T: Lane, const L: usize>(
        self,
        g: &Geometry,
        params: &Params<T>,
        cost: &[T],
        prev: [&[T]; 4],
        prev_min: [T; 4],
        jump: [T; 4],
        outs: [&mut [T]; 4],
        sums_in: &[u16],
        sums_out: &mut [u16],
    ) -> [T; 4];

    /// `C(x, y, ·)`; see [`cost_pixel`].
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn cost<T: Lane>(
        self,
        cost: &mut [T],
        bytes: &mut [u8],
        census_left: &[u8],
        census_right: &[u8],
        gradient_right: &[i16],
        gradient: i16,
        params: &Params<T>,
        g: &Geometry,
        x: usize,
    ) {
        cost_pixel(cost, bytes, census_left, census_right, gradient_right, gradient, params, g, x);
    }

    /// Asks for the cache lines of `values` (a later pixel's sums in the `Eight` volume) ahead
    /// of their use; a hint only.
    #[inline(always)]
    fn prefetch(self, values: &[u16]) {
        let _ = values;
    }
}

/// The generic kernels, vectorised by LLVM.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Autovectorised;

impl PixelKernels for Autovectorised {
    #[inline(always)]
    fn aggregate<T: Lane, const L: usize>(
        self,
        g: &Geometry,
        params: &Params<T>,
        cost: &[T],
        prev: [&[T]; 4],
        prev_min: [T; 4],
        jump: [T; 4],
        outs: [&mut [T]; 4],
        sums_in: &[u16],
        sums_out: &mut [u16],
    ) -> [T; 4] {
        aggregate_pixel::<T, L>(g, params, cost, prev, prev_min, jump, outs, sums_in, sums_out)
    }
}

/// `M`: the smallest lane of a path-cost vector (see [`min_u16`] for the shape).
#[inline(always)]
fn min_of<T: Lane>(values: &[T]) -> T {
    values.iter().fold(T::MAX, |m, &v| m.min(v))
}

/// `M + P2eff` for a predecessor with minimum `prev_min` and intensity step `step`.
#[inline(always)]
fn jump_cost<T: Lane>(params: &Params<T>, prev_min: T, step: u8) -> T {
    T::from_u16(prev_min.widen() + u16::from(params.p2_effective[usize::from(step)]))
}

/// Smallest value of a runtime-length slice. Reductions are written as plain folds over slices
/// of runtime length on purpose: the loop vectoriser then builds the vector accumulator and ends
/// with one `vphminposuw`-style reduction. Over fixed-size arrays LLVM unrolls first and its SLP
/// vectoriser often falls back to a scalar chain (or spills the lanes through the stack).
#[inline(always)]
fn min_u16(values: &[u16]) -> u16 {
    values.iter().fold(u16::MAX, |m, &v| m.min(v))
}

/// `if pick { a } else { b }` as mask arithmetic: LLVM's SLP vectoriser keeps `if`-selects of
/// loaded values scalar, but vectorises this.
#[inline(always)]
fn blend(pick: bool, a: u16, b: u16) -> u16 {
    let mask = 0u16.wrapping_sub(u16::from(pick));
    (a & mask) | (b & !mask)
}

/// Stages 4 and 5 at one pixel: `(d1, 16 · d1 + offset)`, or `(NO_WINNER, _)` if not unique.
/// `sums` holds `Dp` lanes, the padding ones `u16::MAX`; `ramp` is [`Geometry::ramp`].
#[inline(always)]
fn select_pixel(sums: &[u16], ramp: &[u16], disparities: usize, params_uniqueness: u32, subpixel: bool) -> (u16, u16) {
    let s1 = min_u16(sums);
    let (chunks, _) = sums.as_chunks::<SELECT_BLOCK>();
    let (ramp, _) = ramp[..sums.len()].as_chunks::<SELECT_BLOCK>();
    // Per-lane accumulators over fixed chunks (which the SLP vectoriser handles), then one
    // runtime-length fold (which the loop vectoriser reduces); see `min_u16`. `sums.len() ≥ 16`.
    let lanes = SELECT_BLOCK.min(sums.len());
    // The first index holding S1, as a minimum over indices (branch-free, so it vectorises).
    let mut first = [u16::MAX; SELECT_BLOCK];
    for (chunk, ramp) in chunks.iter().zip(ramp) {
        for l in 0..SELECT_BLOCK {
            first[l] = first[l].min(blend(chunk[l] == s1, ramp[l], u16::MAX));
        }
    }
    let d1 = usize::from(min_u16(&first[..lanes])).min(disparities - 1);
    // S2: the minimum at least two disparities away from d1. `d − (d1 − 1) ≤ 2` (wrapping) is
    // exactly `d ∈ {d1 − 1, d1, d1 + 1}`.
    let below = (d1 as u16).wrapping_sub(1);
    let mut second = [u16::MAX; SELECT_BLOCK];
    for (chunk, ramp) in chunks.iter().zip(ramp) {
        for l in 0..SELECT_BLOCK {
            second[l] = second[l].min(blend(ramp[l].wrapping_sub(below) <= 2, u16::MAX, chunk[l]));
        }
    }
    let s2 = min_u16(&second[..lanes]);
    let unique = 100 * u32::from(s2) >= (100 + params_uniqueness) * u32::from(s1);
    let refined = if subpixel && d1 > 0 && d1 + 1 < disparities {
        // Once per pixel, scalar: the reference's own definition keeps the two bit-identical.
        let offset = crate::stages::select::subpixel_offset(sums[d1 - 1], sums[d1], sums[d1 + 1]);
        (16 * d1 as i32 + offset) as u16
    } else {
        16 * d1 as u16
    };
    (if unique { d1 as u16 } else { NO_WINNER }, refined)
}

/// Folds `S(x, ·)` into the right view's running minima. `LATER_IS_SMALLER`: pixels come in
/// decreasing `x` (backward pass), so for a fixed right pixel `d` decreases and an equal cost
/// must win (the spec's smallest `d`); in a forward pass only a smaller cost wins.
#[inline(always)]
fn right_update<const LATER_IS_SMALLER: bool>(
    right_cost: &mut [u16],
    right_disparity: &mut [u16],
    sums: &[u16],
    ramp: &[u16],
    mirrored_x: usize,
    disparities: usize,
) {
    let (costs, _) = right_cost[mirrored_x..mirrored_x + disparities].as_chunks_mut::<SELECT_BLOCK>();
    let (best, _) = right_disparity[mirrored_x..mirrored_x + disparities].as_chunks_mut::<SELECT_BLOCK>();
    let (sums, _) = sums[..disparities].as_chunks::<SELECT_BLOCK>();
    let (ramp, _) = ramp[..disparities].as_chunks::<SELECT_BLOCK>();
    for (((costs, best), sums), ramp) in costs.iter_mut().zip(best.iter_mut()).zip(sums).zip(ramp) {
        // Work on register copies: with the stores interleaved, LLVM cannot rule out that they
        // alias the next loads and keeps the loop scalar.
        let (s, old_cost, old_best) = (*sums, *costs, *best);
        let mut new_cost = [0u16; SELECT_BLOCK];
        let mut new_best = [0u16; SELECT_BLOCK];
        for l in 0..SELECT_BLOCK {
            let better = if LATER_IS_SMALLER { s[l] <= old_cost[l] } else { s[l] < old_cost[l] };
            new_best[l] = blend(better, ramp[l], old_best[l]);
            new_cost[l] = s[l].min(old_cost[l]);
        }
        *costs = new_cost;
        *best = new_best;
    }
}

/// The previous row's blocks around the current block.
struct Above<'g, T> {
    blocks: [Option<MutexGuard<'g, Block<T>>>; 3],
    first_block: isize,
    slot: usize,
}

impl<T: Lane> Above<'_, T> {
    /// The vector and `M` of `path` at iteration column `i` of the previous row.
    #[inline(always)]
    fn get(&self, i: usize, path: usize) -> Option<(&[T], T)> {
        // A constant divisor: shifts, not a division per lookup.
        let b = (i / BLOCK_PX) as isize - self.first_block;
        let block = self.blocks.get(usize::try_from(b).ok()?)?.as_ref()?;
        let o = (i % BLOCK_PX) * PATHS_FROM_ABOVE + path;
        Some((&block.lanes[o * self.slot..][..self.slot], block.minima[o]))
    }
}

/// A predecessor in the previous row: its vector, `M` and `M + P2eff`; the zero predecessor on
/// the first row.
#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn from_above<'a, T: Lane>(
    above: &'a Above<'_, T>,
    previous_left_row: Option<&[u8]>,
    zero: &'a [T],
    params: &Params<T>,
    direction: Direction,
    intensity: u8,
    column: usize,
    path: usize,
) -> (&'a [T], T, T) {
    match (previous_left_row, above.get(column, path)) {
        (Some(previous_left_row), Some((lanes, m))) => {
            let step = intensity.abs_diff(previous_left_row[direction.physical(column, previous_left_row.len())]);
            (lanes, m, jump_cost(params, m, step))
        }
        _ => (zero, T::default(), T::default()),
    }
}

/// Census, cost, aggregation of the four paths of a pass and, when the sum is complete, winner
/// selection and the left-right check, for one row.
#[inline(always)]
fn process_row<T: Lane, const L: usize, A: PixelKernels>(
    job: RowJob<'_, '_, '_, T>,
    kernels: A,
) -> Result<(), Aborted> {
    let RowJob { frame, params, pass, thread, direction, row: j, scratch, mut sums, out } = job;
    let g = frame.geometry;
    let (w, h) = (g.width, g.height);
    let y = direction.physical(j, h);
    let Scratch {
        census_left,
        census_right,
        cost,
        cost_bytes,
        gradient_left,
        gradient_right,
        zero,
        zero_sums,
        horizontal,
        horizontal_min,
        sums: sum_buf,
        right_cost,
        right_disparity,
        winner,
        refined,
        row_out,
    } = scratch;
    census_row(census_left, g.left_plane_stride, frame.padded_left, g, y, false);
    census_row(census_right, g.right_plane_stride, frame.padded_right, g, y, true);
    if params.gradient_weight > 0 && params.gradient_truncation > 0 {
        gradient_row(&frame.left[y * w..][..w], gradient_left, false);
        gradient_row(&frame.padded_right[y * g.pad_stride + g.pad_left..][..w], &mut gradient_right[..w], true);
    }

    let selecting = !matches!(sums, Sums::Store(_));
    let track_right = selecting && params.lr_check;
    if track_right {
        right_cost.fill(u16::MAX);
        right_disparity.fill(0);
    }
    let threads = pass.threads();
    let buffers = pass.rows.len();
    let current_row = &pass.rows[j % buffers];
    let previous_row = &pass.rows[(j + buffers - 1) % buffers];
    let left_row = &frame.left[y * w..][..w];
    let previous_left_row = (j > 0).then(|| &frame.left[direction.physical(j - 1, h) * w..][..w]);
    let zero = &zero[..];
    let zero_sums = &zero_sums[..];

    for k in 0..g.blocks {
        if j > 0 && wavefront_thread(j - 1, threads) != thread {
            // Row j − 1 must be done up to the pixel right of this block's last one.
            wait_for(pass, wavefront_thread(j - 1, threads), (j - 1) * g.blocks + (k + 2).min(g.blocks))?;
        }
        let mut current = lock(&current_row[k]);
        let above = Above {
            blocks: if j > 0 {
                [
                    k.checked_sub(1).map(|b| lock(&previous_row[b])),
                    Some(lock(&previous_row[k])),
                    previous_row.get(k + 1).map(lock),
                ]
            } else {
                [None, None, None]
            },
            first_block: k as isize - 1,
            slot: g.slot,
        };
        let Block { lanes: current_lanes, minima: current_minima } = &mut *current;
        for i in k * BLOCK_PX..((k + 1) * BLOCK_PX).min(w) {
            let x = direction.physical(i, w);
            kernels.cost(cost, cost_bytes, census_left, census_right, gradient_right, gradient_left[x], params, g, x);
            let intensity = left_row[x];

            // Predecessors: from the left (same row), then top-left, top, top-right.
            let (h_prev, h_cur) = horizontal.split_at_mut(g.slot);
            let (h_prev, h_cur, h_prev_index) = if i % 2 == 0 { (&*h_cur, h_prev, 1) } else { (&*h_prev, h_cur, 0) };
            let from_left = if i > 0 {
                let step = intensity.abs_diff(left_row[direction.physical(i - 1, w)]);
                let m = horizontal_min[h_prev_index];
                (h_prev, m, jump_cost(params, m, step))
            } else {
                (zero, T::default(), T::default())
            };
            let above_at = |column: usize, path: usize| {
                from_above(&above, previous_left_row, zero, params, direction, intensity, column, path)
            };
            let top_left = if i > 0 { above_at(i - 1, 0) } else { (zero, T::default(), T::default()) };
            let top = above_at(i, 1);
            let top_right = if i + 1 < w { above_at(i + 1, 2) } else { (zero, T::default(), T::default()) };

            let o = i % BLOCK_PX;
            let outputs = &mut current_lanes[o * PATHS_FROM_ABOVE * g.slot..][..PATHS_FROM_ABOVE * g.slot];
            let (out1, rest) = outputs.split_at_mut(g.slot);
            let (out2, out3) = rest.split_at_mut(g.slot);
            // The volume was written half a frame ago and is out of the caches: ask for the sums
            // of a pixel a few steps ahead (what the next pixels need arrives meanwhile).
            let volume_row: Option<&[u16]> = match &sums {
                Sums::Select => None,
                Sums::Store(row) => Some(row),
                Sums::AddSelect(row) => Some(row),
            };
            if let Some(volume_row) = volume_row
                && i + PREFETCH_PX < w
            {
                let ahead = direction.physical(i + PREFETCH_PX, w);
                kernels.prefetch(&volume_row[ahead * g.lanes..][..g.lanes]);
            }
            let (sums_in, sums_out): (&[u16], &mut [u16]) = match &mut sums {
                Sums::Select => (zero_sums, &mut sum_buf[..]),
                Sums::Store(volume_row) => (zero_sums, &mut volume_row[x * g.lanes..][..g.lanes]),
                Sums::AddSelect(volume_row) => (&volume_row[x * g.lanes..][..g.lanes], &mut sum_buf[..]),
            };
            let minima = kernels.aggregate::<T, L>(
                g,
                params,
                cost,
                [from_left.0, top_left.0, top.0, top_right.0],
                [from_left.1, top_left.1, top.1, top_right.1],
                [from_left.2, top_left.2, top.2, top_right.2],
                [h_cur, out1, out2, out3],
                sums_in,
                sums_out,
            );
            horizontal_min[1 - h_prev_index] = minima[0];
            current_minima[o * PATHS_FROM_ABOVE..][..PATHS_FROM_ABOVE].copy_from_slice(&minima[1..]);

            if selecting {
                if track_right {
                    match direction {
                        Direction::Forward => right_update::<false>(
                            right_cost,
                            right_disparity,
                            sum_buf,
                            &g.ramp,
                            w - 1 - x,
                            g.disparities,
                        ),
                        Direction::Backward => right_update::<true>(
                            right_cost,
                            right_disparity,
                            sum_buf,
                            &g.ramp,
                            w - 1 - x,
                            g.disparities,
                        ),
                    }
                }
                if g.lanes > g.disparities {
                    sum_buf[g.disparities..].fill(u16::MAX);
                }
                let (d1, d16) =
                    select_pixel(sum_buf, &g.ramp, g.disparities, params.uniqueness_percent, params.subpixel);
                winner[x] = d1;
                refined[x] = d16;
            }
        }
        drop(above);
        drop(current);
        pass.done[thread].store(j * g.blocks + k + 1, Ordering::Release);
    }

    if selecting {
        for x in 0..w {
            let d1 = winner[x];
            row_out[x] = if d1 == NO_WINNER {
                INVALID
            } else if !params.lr_check {
                refined[x]
            } else {
                let consistent = candidates(d1, refined[x], params.lr_lenient).iter().any(|&d| {
                    let d = usize::from(d);
                    x >= d && right_disparity[w - 1 - (x - d)].abs_diff(d as u16) <= params.lr_max_diff
                });
                if consistent { refined[x] } else { INVALID }
            };
        }
        lock(out)[y * w..][..w].copy_from_slice(row_out);
    }
    Ok(())
}

/// Defines `SORT9`, a sorting network for nine values (25 compare-exchanges in 7 layers,
/// Floyd's network; checked against sorting in the unit tests below by the 0-1 principle), and
/// `sort9_lanes`, which applies it to nine vectors lane by lane. The macro writes the 25 steps
/// out with constant indices: as a loop over the table LLVM keeps the nine vectors on the stack
/// and reloads them at every step.
macro_rules! sort9_network {
    ($(($i:literal, $j:literal)),* $(,)?) => {
        #[cfg(test)]
        const SORT9: [(usize, usize); 25] = [$(($i, $j)),*];

        #[inline(always)]
        fn sort9_lanes(v: &mut [[u16; MEDIAN_BLOCK]; 9]) {
            $(compare_exchange(v, $i, $j);)*
        }
    };
}

sort9_network![
    (0, 3),
    (1, 7),
    (2, 5),
    (4, 8),
    (0, 7),
    (2, 4),
    (3, 8),
    (5, 6),
    (0, 2),
    (1, 3),
    (4, 5),
    (7, 8),
    (1, 4),
    (3, 6),
    (5, 7),
    (0, 1),
    (2, 4),
    (3, 5),
    (6, 8),
    (2, 3),
    (4, 5),
    (6, 7),
    (1, 2),
    (3, 4),
    (5, 6),
];

/// `v[i], v[j] = min, max` lane by lane.
#[inline(always)]
fn compare_exchange(v: &mut [[u16; MEDIAN_BLOCK]; 9], i: usize, j: usize) {
    let (a, b) = (v[i], v[j]);
    for l in 0..MEDIAN_BLOCK {
        v[i][l] = a[l].min(b[l]);
        v[j][l] = a[l].max(b[l]);
    }
}

/// Output pixels per median block: one 512-bit register of `u16` per window position.
const MEDIAN_BLOCK: usize = 32;

/// Stage 7 for `MEDIAN_BLOCK` consecutive pixels starting at column `x0` of a row, from the
/// three input rows around it.
///
/// The nine window values of every pixel are sorted by the `SORT9` network lane-wise
/// (INVALID = 0xFFFF last), then the lower median of the `n` valid ones, index `(n − 1) / 2`, is
/// picked without counting: `n ≥ 5` iff `sorted[4]` is valid, `n ≥ 7` iff `sorted[6]` is,
/// `n = 9` iff `sorted[8]` is.
#[inline(always)]
fn median_block(rows: [&[u16]; 3], x0: usize, out: &mut [u16; MEDIAN_BLOCK]) {
    let mut v = [[0u16; MEDIAN_BLOCK]; 9];
    for (k, values) in v.iter_mut().enumerate() {
        let (row, dx) = (rows[k / 3], k % 3);
        values.copy_from_slice(&row[x0 + dx - 1..][..MEDIAN_BLOCK]);
    }
    sort9_lanes(&mut v);
    for l in 0..MEDIAN_BLOCK {
        let upper = blend(v[8][l] != INVALID, v[4][l], v[3][l]);
        let middle = blend(v[6][l] != INVALID, upper, v[2][l]);
        out[l] = blend(v[4][l] != INVALID, middle, INVALID);
    }
}

/// Stage 7 (3×3 median of the valid values, borders kept) and stage 8 (invalid marking).
#[inline(always)]
fn finish_image(job: FinishJob<'_>) {
    let FinishJob { width: w, height: h, median, pre, out } = job;
    out.copy_from_slice(pre);
    if median && w >= 3 && h >= 3 {
        for y in 1..h - 1 {
            let rows = [&pre[(y - 1) * w..][..w], &pre[y * w..][..w], &pre[(y + 1) * w..][..w]];
            let row = &mut out[y * w..][..w];
            if w - 2 < MEDIAN_BLOCK {
                // Narrower than a block: the reference's window function, pixel by pixel.
                for x in 1..w - 1 {
                    let mut window = [0u16; 9];
                    for (k, value) in window.iter_mut().enumerate() {
                        *value = rows[k / 3][x + k % 3 - 1];
                    }
                    row[x] = crate::stages::median::median_of_window(window);
                }
                continue;
            }
            // Blocks from x = 1; the last one is moved left to end at W − 2 (it recomputes a few
            // pixels, which reads `pre` only and so gives the same values).
            let mut x0 = 1;
            loop {
                let x0_clamped = x0.min(w - 1 - MEDIAN_BLOCK);
                let mut block = [0u16; MEDIAN_BLOCK];
                median_block(rows, x0_clamped, &mut block);
                row[x0_clamped..][..MEDIAN_BLOCK].copy_from_slice(&block);
                if x0_clamped + MEDIAN_BLOCK >= w - 1 {
                    break;
                }
                x0 += MEDIAN_BLOCK;
            }
        }
    }
    for row in out.chunks_exact_mut(w) {
        for (x, value) in row.iter_mut().enumerate() {
            // INVALID (0xFFFF) is never below 16 · x for an image narrower than 4096 px, and
            // stays INVALID anyway.
            if 16 * x < usize::from(*value) {
                *value = INVALID;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// By the 0-1 principle a comparator network sorts every input iff it sorts every 0/1 input:
    /// all 2^9 of them.
    #[test]
    fn sort9_sorts_every_zero_one_input() {
        for bits in 0u32..1 << 9 {
            let mut v: [u16; 9] = std::array::from_fn(|k| ((bits >> k) & 1) as u16);
            for &(i, j) in &SORT9 {
                let (a, b) = (v[i], v[j]);
                v[i] = a.min(b);
                v[j] = a.max(b);
            }
            assert!(v.is_sorted(), "input {bits:09b} gives {v:?}");
        }
    }

    /// The block median against the reference's window function, on windows with every count of
    /// invalid values, including the block's last lane.
    #[test]
    fn median_block_equals_the_window_function() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        let width = MEDIAN_BLOCK + 2;
        for _ in 0..200 {
            let invalid_per_mille = next() % 1000;
            let rows: Vec<Vec<u16>> = (0..3)
                .map(|_| {
                    (0..width)
                        .map(|_| if next() % 1000 < invalid_per_mille { INVALID } else { (next() % 40) as u16 })
                        .collect()
                })
                .collect();
            let mut block = [0u16; MEDIAN_BLOCK];
            median_block([&rows[0], &rows[1], &rows[2]], 1, &mut block);
            for (l, &got) in block.iter().enumerate() {
                let window: [u16; 9] = std::array::from_fn(|k| rows[k / 3][l + k % 3]);
                assert_eq!(got, crate::stages::median::median_of_window(window), "{window:?}");
            }
        }
    }
}
