//! The fast implementation of the core: streaming, SIMD, optional threads, bit-identical to
//! [`crate::reference`].
//!
//! # Design
//!
//! - **Streaming rows.** Census words, matching costs and path costs are produced row by row;
//!   no cost volume exists. A pass keeps the previous row's path costs of the three paths from
//!   above (`O(W · D)`) and the left path's vector of the previous pixel. `Four` selects winners,
//!   the subpixel position and the right view's running minima as soon as a pixel's sum is
//!   complete, so it needs no volume at all. `Eight` keeps one `W · H · Dp` volume of `u16` sums:
//!   each pass stores the sum of its four paths for one half of the image and, in the other half,
//!   adds the stored sum of the other pass and selects.
//! - **Disparity-contiguous lanes.** Every per-pixel vector is contiguous in `d`, padded to a
//!   multiple of the SIMD block, so the inner loops are straight `min`/saturating `add` on
//!   `u8` lanes (`b ≤ 8`, see [`lane`]) or `u16` lanes; census words are bit-planes of bytes
//!   so the Hamming cost is a byte popcount (see [`kernels`]).
//! - **Dispatch.** The kernels are generic `#[inline(always)]` code compiled for the baseline,
//!   AVX2 and AVX-512 (BW + BITALG); [`Isa::detect`] picks one per matcher.
//! - **Threads.** `Four` runs the raster pass as a wavefront: row `j` belongs to thread
//!   `j mod n` and follows row `j − 1` two 64-pixel blocks behind, handing blocks over through
//!   per-block mutexes and a progress counter. `Eight` runs its two passes concurrently, meeting
//!   in the middle of the image (each pass first stores its half, then completes the other).
//!   Integer sums do not depend on the order of the passes, so every thread count gives the
//!   same bits.

#[cfg(target_arch = "x86_64")]
mod avx512;
mod dispatch;
mod kernels;
mod lane;

use std::sync::Mutex;
use std::sync::mpsc;

pub use dispatch::Isa;
use kernels::{Direction, FinishJob, Frame, Geometry, Job, Params, PassRows, RowJob, Scratch, Sums};
use lane::Lane;

use crate::SgmError;
use crate::config::{PathMode, SgmConfig};
use crate::image::{DisparityImage, GrayImage, GrayView, INVALID, check_pair};
use crate::stages::aggregate::effective_p2;

/// Threads beyond this many give no further speed-up (and the machines have two cores).
const MAX_THREADS: usize = 16;

/// A matcher for one image size and configuration. Owns every buffer it needs, so matching a
/// frame allocates no buffer; with more than one thread, spawning the scoped threads (and, for
/// `Eight`, the two hand-over channels) are the only allocations.
pub struct Matcher {
    config: SgmConfig,
    width: usize,
    height: usize,
    threads: usize,
    isa: Isa,
    force_portable: bool,
    padded_left: Vec<u8>,
    padded_right: Vec<u8>,
    /// The image after stage 6, before the median.
    pre_median: Vec<u16>,
    engine: EngineKind,
}

impl std::fmt::Debug for Matcher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Matcher")
            .field("config", &self.config)
            .field("width", &self.width)
            .field("height", &self.height)
            .field("threads", &self.threads)
            .field("isa", &self.isa())
            .field("working_memory_bytes", &self.working_memory_bytes())
            .finish_non_exhaustive()
    }
}

/// The aggregation state for the lane type the configuration needs.
enum EngineKind {
    Byte(Engine<u8>),
    Word(Engine<u16>),
}

struct Engine<T> {
    geometry: Geometry,
    params: Params<T>,
    /// One pass (`Four`) or the forward and backward passes (`Eight`).
    passes: Vec<PassRows<T>>,
    scratches: Vec<Scratch<T>>,
    /// `Eight` only: the four-path sums, `[y][x][Dp]`.
    volume: Vec<u16>,
}

impl<T: Lane> Engine<T> {
    fn new(config: &SgmConfig, width: usize, height: usize, threads: usize, lane_block: usize) -> Engine<T> {
        let geometry = Geometry::new(
            width,
            height,
            usize::from(config.disparities),
            lane_block,
            usize::from(config.census_width),
            usize::from(config.census_height),
        );
        let mut p2_effective = [0u8; 256];
        for (step, p2) in p2_effective.iter_mut().enumerate() {
            // P2eff ≤ p2 ≤ 255.
            *p2 = effective_p2(config.p1, config.p2, config.p2_gradient_scale, step as u8).clamp(0, 255) as u8;
        }
        let params = Params {
            p1: T::from_u16(u16::from(config.p1)),
            path_cost_max: T::from_u16(config.path_cost_max()),
            gradient_weight: u16::from(config.gradient_cost_weight),
            gradient_truncation: u16::from(config.gradient_cost_truncation),
            // ≤ 64 + 191 = 255 for a validated configuration.
            cost_max: config.cost_max().min(255) as u8,
            p2_effective,
            uniqueness_percent: u32::from(config.uniqueness_percent),
            lr_check: config.lr_check,
            lr_max_diff: u16::from(config.lr_max_diff),
            lr_lenient: config.lr_lenient,
            subpixel: config.subpixel,
        };
        let (passes, volume) = match config.paths {
            PathMode::Four => (vec![PassRows::new(&geometry, threads)], Vec::new()),
            PathMode::Eight => (
                vec![PassRows::new(&geometry, 1), PassRows::new(&geometry, 1)],
                vec![0u16; width * height * geometry.lanes],
            ),
        };
        let scratches = (0..threads).map(|_| Scratch::new(&geometry)).collect();
        Engine { geometry, params, passes, scratches, volume }
    }

    fn memory_bytes(&self) -> usize {
        self.geometry.neighbours.capacity() * size_of::<(isize, isize)>()
            + self.passes.iter().map(PassRows::memory_bytes).sum::<usize>()
            + self.scratches.iter().map(Scratch::memory_bytes).sum::<usize>()
            + self.volume.capacity() * size_of::<u16>()
    }
}

/// Flags the pass as aborted if the thread owning it unwinds, so its partners stop waiting.
struct AbortOnPanic<'a, T>(&'a PassRows<T>);

impl<T> Drop for AbortOnPanic<'_, T> {
    fn drop(&mut self) {
        if std::thread::panicking() {
            self.0.abort.store(true, std::sync::atomic::Ordering::Relaxed);
        }
    }
}

impl Matcher {
    /// A matcher for `width × height` pairs. `threads ≥ 1`; `Four` uses up to `threads` (at most
    /// one per row, at most 16), `Eight` up to two (one per pass).
    pub fn new(config: SgmConfig, width: usize, height: usize, threads: usize) -> Result<Self, SgmError> {
        config.validate()?;
        if width == 0 || height == 0 {
            return Err(SgmError::BadImage { width, height, len: 0 });
        }
        if threads == 0 {
            return Err(SgmError::InvalidConfig("threads must be at least 1".into()));
        }
        let threads = match config.paths {
            PathMode::Four => threads.min(height).min(MAX_THREADS),
            PathMode::Eight => threads.min(2),
        };
        let engine = if config.path_cost_bits <= 8 {
            EngineKind::Byte(Engine::new(&config, width, height, threads, <u8 as Lane>::BLOCK))
        } else {
            EngineKind::Word(Engine::new(&config, width, height, threads, <u16 as Lane>::BLOCK))
        };
        let pad_stride = match &engine {
            EngineKind::Byte(e) => e.geometry.pad_stride,
            EngineKind::Word(e) => e.geometry.pad_stride,
        };
        Ok(Matcher {
            config,
            width,
            height,
            threads,
            isa: Isa::detect(),
            force_portable: false,
            padded_left: vec![0; pad_stride * height],
            padded_right: vec![0; pad_stride * height],
            pre_median: vec![INVALID; width * height],
            engine,
        })
    }

    pub fn config(&self) -> &SgmConfig {
        &self.config
    }

    /// Threads a frame actually uses.
    pub fn threads(&self) -> usize {
        self.threads
    }

    /// The instruction set the kernels run with.
    pub fn isa(&self) -> Isa {
        if self.force_portable { Isa::Portable } else { self.isa }
    }

    /// Runs the baseline kernels instead of the detected SIMD ones (for tests and benchmarks:
    /// both must give the same bits).
    pub fn set_force_portable(&mut self, force: bool) {
        self.force_portable = force;
    }

    /// Bytes of every buffer the matcher holds.
    pub fn working_memory_bytes(&self) -> usize {
        let engine = match &self.engine {
            EngineKind::Byte(e) => e.memory_bytes(),
            EngineKind::Word(e) => e.memory_bytes(),
        };
        engine
            + self.padded_left.capacity()
            + self.padded_right.capacity()
            + self.pre_median.capacity() * size_of::<u16>()
            + size_of::<Matcher>()
    }

    /// Matches a pair into `out` (resized to the frame if needed, else reused).
    pub fn compute_into(
        &mut self,
        left: &GrayImage,
        right: &GrayImage,
        out: &mut DisparityImage,
    ) -> Result<(), SgmError> {
        self.compute_views_into(left.view(), right.view(), out)
    }

    /// Matches a borrowed pair into `out` (resized to the frame if needed, else reused): the
    /// entry point for pixels that live elsewhere (shared memory), which are read in place.
    pub fn compute_views_into(
        &mut self,
        left: GrayView<'_>,
        right: GrayView<'_>,
        out: &mut DisparityImage,
    ) -> Result<(), SgmError> {
        left.check()?;
        right.check()?;
        if (left.width, left.height) != (right.width, right.height) {
            return Err(SgmError::SizeMismatch { left: (left.width, left.height), right: (right.width, right.height) });
        }
        if (left.width, left.height) != (self.width, self.height) {
            return Err(SgmError::InvalidConfig(format!(
                "matcher is for {}x{} images, got {}x{}",
                self.width, self.height, left.width, left.height
            )));
        }
        let isa = self.isa();
        let Matcher { padded_left, padded_right, pre_median, engine, config, .. } = self;
        match engine {
            EngineKind::Byte(e) => {
                pad_images(&e.geometry, left.pixels, right.pixels, padded_left, padded_right);
                run_frame::<u8, 64>(e, isa, config.paths, left.pixels, padded_left, padded_right, pre_median);
            }
            EngineKind::Word(e) => {
                pad_images(&e.geometry, left.pixels, right.pixels, padded_left, padded_right);
                run_frame::<u16, 32>(e, isa, config.paths, left.pixels, padded_left, padded_right, pre_median);
            }
        }
        out.width = self.width;
        out.height = self.height;
        out.data.resize(self.width * self.height, INVALID);
        let finish = FinishJob {
            width: self.width,
            height: self.height,
            median: self.config.median,
            pre: &self.pre_median,
            out: &mut out.data,
        };
        // The finishing job never waits on other threads, so it cannot abort.
        let _ = dispatch::run::<u8, 64>(isa, Job::Finish(finish));
        Ok(())
    }

    /// Matches a pair into a new image.
    pub fn compute(&mut self, left: &GrayImage, right: &GrayImage) -> Result<DisparityImage, SgmError> {
        let mut out =
            DisparityImage { width: self.width, height: self.height, data: vec![INVALID; self.width * self.height] };
        self.compute_into(left, right, &mut out)?;
        Ok(out)
    }
}

/// One-shot matching on one thread (builds a [`Matcher`] for the pair's size).
pub fn compute(left: &GrayImage, right: &GrayImage, config: &SgmConfig) -> Result<DisparityImage, SgmError> {
    check_pair(left, right)?;
    Matcher::new(*config, left.width, left.height, 1)?.compute(left, right)
}

/// Copies the images into rows with replicated borders (the census clamps coordinates); the
/// right image is mirrored left-right (see [`kernels`]).
fn pad_images(g: &Geometry, left: &[u8], right: &[u8], padded_left: &mut [u8], padded_right: &mut [u8]) {
    let w = g.width;
    for ((src_left, src_right), (dst_left, dst_right)) in left
        .chunks_exact(w)
        .zip(right.chunks_exact(w))
        .zip(padded_left.chunks_exact_mut(g.pad_stride).zip(padded_right.chunks_exact_mut(g.pad_stride)))
    {
        let (first_left, last_left) = (src_left[0], src_left[w - 1]);
        dst_left[..g.pad_left].fill(first_left);
        dst_left[g.pad_left..g.pad_left + w].copy_from_slice(src_left);
        dst_left[g.pad_left + w..].fill(last_left);
        // Mirrored: the right image's last column comes first.
        let (first_right, last_right) = (src_right[w - 1], src_right[0]);
        dst_right[..g.pad_left].fill(first_right);
        for (dst, &src) in dst_right[g.pad_left..g.pad_left + w].iter_mut().zip(src_right.iter().rev()) {
            *dst = src;
        }
        dst_right[g.pad_left + w..].fill(last_right);
    }
}

/// What every row job of a frame shares.
struct RowContext<'a, 'o, T> {
    frame: Frame<'a>,
    params: &'a Params<T>,
    out: &'a Mutex<&'o mut [u16]>,
    isa: Isa,
}

impl<T: Lane> RowContext<'_, '_, T> {
    /// Runs one row; false if another thread panicked.
    fn row<const L: usize>(
        &self,
        pass: &PassRows<T>,
        thread: usize,
        direction: Direction,
        row: usize,
        scratch: &mut Scratch<T>,
        sums: Sums<'_>,
    ) -> bool {
        let job = RowJob {
            frame: self.frame,
            params: self.params,
            pass,
            thread,
            direction,
            row,
            scratch,
            sums,
            out: self.out,
        };
        dispatch::run::<T, L>(self.isa, Job::Row(job)).is_ok()
    }
}

/// Stages 1–6 of a frame into `pre_median`.
#[allow(clippy::too_many_arguments)]
fn run_frame<T: Lane, const L: usize>(
    engine: &mut Engine<T>,
    isa: Isa,
    paths: PathMode,
    left: &[u8],
    padded_left: &[u8],
    padded_right: &[u8],
    pre_median: &mut [u16],
) {
    let Engine { geometry, params, passes, scratches, volume } = engine;
    let frame = Frame { geometry, left, padded_left, padded_right };
    let params = &*params;
    for pass in passes.iter() {
        pass.reset();
    }
    let out = Mutex::new(pre_median);
    let ctx = RowContext { frame, params, out: &out, isa };
    let ctx = &ctx;
    let (w, h, lanes) = (geometry.width, geometry.height, geometry.lanes);

    match paths {
        PathMode::Four => {
            let pass = &passes[0];
            let threads = pass.threads();
            let worker = |thread: usize, scratch: &mut Scratch<T>| {
                let _guard = AbortOnPanic(pass);
                for row in (0..h).filter(|&row| kernels::wavefront_thread(row, threads) == thread) {
                    if !ctx.row::<L>(pass, thread, Direction::Forward, row, scratch, Sums::Select) {
                        return;
                    }
                }
            };
            let (first, others) = scratches.split_at_mut(1);
            std::thread::scope(|s| {
                for (thread, scratch) in others.iter_mut().enumerate() {
                    s.spawn(move || worker(thread + 1, scratch));
                }
                if let Some(scratch) = first.first_mut() {
                    worker(0, scratch);
                }
            });
        }
        PathMode::Eight => {
            // Forward pass (A) covers physical rows 0 .. mid first, the backward pass (B) rows
            // H − 1 down to mid; then each completes the half the other stored.
            let mid = h / 2;
            let row_len = w * lanes;
            let (top, bottom) = volume.split_at_mut(mid * row_len);
            let (pass_a, pass_b) = (&passes[0], &passes[1]);
            let forward = |scratch: &mut Scratch<T>, rows: std::ops::Range<usize>, half: &mut [u16], store: bool| {
                for (row, volume_row) in rows.zip(half.chunks_exact_mut(row_len)) {
                    let sums = if store { Sums::Store(volume_row) } else { Sums::AddSelect(volume_row) };
                    if !ctx.row::<L>(pass_a, 0, Direction::Forward, row, scratch, sums) {
                        return false;
                    }
                }
                true
            };
            let backward = |scratch: &mut Scratch<T>, rows: std::ops::Range<usize>, half: &mut [u16], store: bool| {
                // Iteration row j is physical row H − 1 − j: walk the half's rows from the end.
                for (row, volume_row) in rows.zip(half.chunks_exact_mut(row_len).rev()) {
                    let sums = if store { Sums::Store(volume_row) } else { Sums::AddSelect(volume_row) };
                    if !ctx.row::<L>(pass_b, 0, Direction::Backward, row, scratch, sums) {
                        return false;
                    }
                }
                true
            };
            match scratches.as_mut_slice() {
                [scratch] => {
                    let _ = forward(scratch, 0..mid, top, true)
                        && backward(scratch, 0..h - mid, bottom, true)
                        && forward(scratch, mid..h, bottom, false)
                        && backward(scratch, h - mid..h, top, false);
                }
                [scratch_a, scratch_b, ..] => {
                    let (to_b, from_a) = mpsc::channel::<&mut [u16]>();
                    let (to_a, from_b) = mpsc::channel::<&mut [u16]>();
                    std::thread::scope(|s| {
                        s.spawn(move || {
                            let _guard = AbortOnPanic(pass_b);
                            if backward(scratch_b, 0..h - mid, bottom, true)
                                && to_a.send(bottom).is_ok()
                                && let Ok(top) = from_a.recv()
                            {
                                backward(scratch_b, h - mid..h, top, false);
                            }
                        });
                        let _guard = AbortOnPanic(pass_a);
                        if forward(scratch_a, 0..mid, top, true)
                            && to_b.send(top).is_ok()
                            && let Ok(bottom) = from_b.recv()
                        {
                            forward(scratch_a, mid..h, bottom, false);
                        }
                    });
                }
                [] => {}
            }
        }
    }
}
