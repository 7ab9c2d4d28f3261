//! The per-pixel aggregation of the four paths of a pass, written with AVX-512BW intrinsics for
//! byte lanes.
//!
//! Why by hand: from the generic `path_step`, LLVM builds each `L(d − 1)` vector out of the
//! `L(d)` load with a broadcast, a lane permute and an align (three shuffles per 32 lanes on the
//! one shuffle port) and splits the 64-lane block into two 256-bit halves; `perf annotate` put
//! half of an 8-path frame there. Here each of `L(d − 1)`, `L(d)`, `L(d + 1)` is one unaligned
//! 512-bit load, the four paths share the cost load, the minima `M` are kept in registers, and
//! the sum `S` widens two paths at a time when their byte sum cannot wrap (`Lmax ≤ 127`, i.e.
//! `b ≤ 7`, the default). The arithmetic is the generic code's lane for lane, so the output is
//! bit-identical (`tests/fast_vs_reference.rs` compares both against the reference).
#![allow(unsafe_code)]

use std::arch::x86_64::{
    __m512i, _MM_HINT_T0, _mm_cvtsi128_si32, _mm_min_epu8, _mm_minpos_epu16, _mm_prefetch, _mm_set1_epi16,
    _mm_srli_epi16, _mm256_castsi256_si128, _mm256_extracti128_si256, _mm256_min_epu8, _mm512_abs_epi16,
    _mm512_add_epi8, _mm512_add_epi16, _mm512_adds_epu8, _mm512_castsi256_si512, _mm512_castsi512_si256,
    _mm512_cvtepi16_epi8, _mm512_cvtepu8_epi16, _mm512_extracti64x4_epi64, _mm512_inserti64x4, _mm512_loadu_si512,
    _mm512_min_epu8, _mm512_min_epu16, _mm512_mullo_epi16, _mm512_popcnt_epi8, _mm512_set1_epi8, _mm512_set1_epi16,
    _mm512_setzero_si512, _mm512_storeu_si512, _mm512_sub_epi8, _mm512_sub_epi16, _mm512_xor_si512,
};

use super::kernels::{Geometry, Params, PixelKernels, aggregate_pixel, cost_pixel};
use super::lane::Lane;

/// Lanes per register: 64 bytes.
const BYTES: usize = 64;

/// Proof that the CPU runs AVX-512F/BW (and what they imply): only [`super::dispatch`] makes
/// one, inside its AVX-512 kernel, which it calls only after `Isa::detect` checked the features.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Avx512 {
    _private: (),
}

impl Avx512 {
    /// # Safety
    /// The CPU must support `avx512f` and `avx512bw` (and `avx2`, `sse4.1`, which they imply).
    pub(crate) unsafe fn new_unchecked() -> Avx512 {
        Avx512 { _private: () }
    }
}

impl PixelKernels for Avx512 {
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
        let [out0, out1, out2, out3] = outs;
        let bytes = (
            T::bytes(cost),
            [T::bytes(prev[0]), T::bytes(prev[1]), T::bytes(prev[2]), T::bytes(prev[3])],
            [T::to_byte(prev_min[0]), T::to_byte(prev_min[1]), T::to_byte(prev_min[2]), T::to_byte(prev_min[3])],
            [T::to_byte(jump[0]), T::to_byte(jump[1]), T::to_byte(jump[2]), T::to_byte(jump[3])],
            T::to_byte(params.p1),
            T::to_byte(params.path_cost_max),
        );
        if let (
            Some(cost),
            [Some(p0), Some(p1), Some(p2), Some(p3)],
            [Some(m0), Some(m1), Some(m2), Some(m3)],
            [Some(j0), Some(j1), Some(j2), Some(j3)],
            Some(penalty),
            Some(lmax),
        ) = bytes
            && g.lanes.is_multiple_of(BYTES)
            && cost.len() >= g.lanes
            && [p0, p1, p2, p3].iter().all(|p| p.len() >= g.lanes + 2)
            && sums_in.len() >= g.lanes
            && sums_out.len() >= g.lanes
            && [out0.len(), out1.len(), out2.len(), out3.len()].iter().all(|&n| n > g.lanes)
            && let (Some(o0), Some(o1), Some(o2), Some(o3)) =
                (T::bytes_mut(out0), T::bytes_mut(out1), T::bytes_mut(out2), T::bytes_mut(out3))
        {
            let pixel = BytePixel {
                lanes: g.lanes,
                penalty,
                lmax,
                cost,
                prev: [p0, p1, p2, p3],
                prev_min: [m0, m1, m2, m3],
                jump: [j0, j1, j2, j3],
            };
            // SAFETY: `self` exists only where the features are present (see `new_unchecked`).
            let minima = unsafe { aggregate_bytes(&pixel, [o0, o1, o2, o3], sums_in, sums_out) };
            return minima.map(T::from_u8);
        }
        aggregate_pixel::<T, L>(g, params, cost, prev, prev_min, jump, [out0, out1, out2, out3], sums_in, sums_out)
    }

    #[inline(always)]
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
        let mirrored = g.width - 1 - x;
        let planes = g.planes;
        let gradient_term = params.gradient_weight > 0 && params.gradient_truncation > 0;
        let in_bounds = g.lanes.is_multiple_of(BYTES)
            && planes <= 8
            && x < g.left_plane_stride
            && census_left.len() >= planes * g.left_plane_stride
            && (planes == 0 || census_right.len() >= (planes - 1) * g.right_plane_stride + mirrored + g.lanes)
            && gradient_right.len() >= mirrored + g.lanes;
        if in_bounds && let Some(out) = T::bytes_mut(&mut cost[..g.lanes]) {
            let mut left = [0u8; 8];
            for (k, l) in left.iter_mut().enumerate().take(planes) {
                *l = census_left[k * g.left_plane_stride + x];
            }
            let words = CostWords {
                planes,
                left,
                right: census_right.as_ptr().wrapping_add(mirrored),
                right_stride: g.right_plane_stride,
                gradient: gradient_term.then_some((gradient, &gradient_right[mirrored..][..g.lanes])),
                weight: params.gradient_weight,
                truncation: params.gradient_truncation,
            };
            // SAFETY: `self` exists only where the features are present (see `new_unchecked`);
            // the bounds of the census reads were checked above.
            unsafe { cost_bytes(&words, out) };
            if x + 1 < g.disparities {
                cost[x + 1..g.disparities].fill(T::from_u8(params.cost_max));
            }
            if g.lanes > g.disparities {
                cost[g.disparities..g.lanes].fill(T::MAX);
            }
            return;
        }
        cost_pixel(cost, bytes, census_left, census_right, gradient_right, gradient, params, g, x);
    }

    #[inline(always)]
    fn prefetch(self, values: &[u16]) {
        for line in values.chunks(32) {
            // SAFETY: a prefetch never faults, and the pointer is in bounds anyway.
            unsafe { _mm_prefetch::<_MM_HINT_T0>(line.as_ptr().cast()) };
        }
    }
}

/// The read-only inputs of one pixel's aggregation on byte lanes.
struct BytePixel<'a> {
    lanes: usize,
    penalty: u8,
    lmax: u8,
    cost: &'a [u8],
    prev: [&'a [u8]; 4],
    prev_min: [u8; 4],
    jump: [u8; 4],
}

/// The four path updates and their sum over `lanes` disparities; returns the new minima `M`.
/// Lengths were checked by the caller: `cost`, `sums_*` ≥ `lanes`, `prev` ≥ `lanes + 2`,
/// `outs` ≥ `lanes + 1` (the new vector is written from index 1, after the guard).
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx2,sse4.1")]
fn aggregate_bytes(pixel: &BytePixel<'_>, outs: [&mut [u8]; 4], sums_in: &[u16], sums_out: &mut [u16]) -> [u8; 4] {
    let penalty = _mm512_set1_epi8(pixel.penalty as i8);
    let lmax = _mm512_set1_epi8(pixel.lmax as i8);
    let prev_min = pixel.prev_min.map(|m| _mm512_set1_epi8(m as i8));
    let jump = pixel.jump.map(|j| _mm512_set1_epi8(j as i8));
    // Two path costs ≤ 127 sum to ≤ 254: add them as bytes, widen once.
    let pairs_fit = pixel.lmax <= 127;
    let mut minima = [_mm512_set1_epi8(-1); 4];
    let [out0, out1, out2, out3] = outs;
    let outs = [out0.as_mut_ptr(), out1.as_mut_ptr(), out2.as_mut_ptr(), out3.as_mut_ptr()];
    for base in (0..pixel.lanes).step_by(BYTES) {
        // SAFETY (all loads and stores below): `base + 64 ≤ lanes`; reads of `prev` reach
        // `base + 2 + 64 ≤ lanes + 2`, writes of `outs` `base + 1 + 64 ≤ lanes + 1`, reads and
        // writes of the sums `base + 64 ≤ lanes`; the lengths are checked by the caller.
        unsafe {
            let cost = _mm512_loadu_si512(pixel.cost.as_ptr().add(base).cast());
            let mut values = [cost; 4];
            for path in 0..4 {
                let prev = pixel.prev[path].as_ptr().add(base);
                let lower = _mm512_loadu_si512(prev.cast());
                let same = _mm512_loadu_si512(prev.add(1).cast());
                let upper = _mm512_loadu_si512(prev.add(2).cast());
                let best = _mm512_min_epu8(
                    _mm512_min_epu8(same, _mm512_adds_epu8(lower, penalty)),
                    _mm512_min_epu8(_mm512_adds_epu8(upper, penalty), jump[path]),
                );
                let value = _mm512_min_epu8(_mm512_adds_epu8(cost, _mm512_sub_epi8(best, prev_min[path])), lmax);
                _mm512_storeu_si512(outs[path].add(base + 1).cast(), value);
                minima[path] = _mm512_min_epu8(minima[path], value);
                values[path] = value;
            }
            let (mut low, mut high) = (
                _mm512_loadu_si512(sums_in.as_ptr().add(base).cast()),
                _mm512_loadu_si512(sums_in.as_ptr().add(base + BYTES / 2).cast()),
            );
            let mut add_widened = |v: __m512i| {
                low = _mm512_add_epi16(low, _mm512_cvtepu8_epi16(_mm512_castsi512_si256(v)));
                high = _mm512_add_epi16(high, _mm512_cvtepu8_epi16(_mm512_extracti64x4_epi64::<1>(v)));
            };
            if pairs_fit {
                add_widened(_mm512_add_epi8(values[0], values[1]));
                add_widened(_mm512_add_epi8(values[2], values[3]));
            } else {
                values.into_iter().for_each(add_widened);
            }
            _mm512_storeu_si512(sums_out.as_mut_ptr().add(base).cast(), low);
            _mm512_storeu_si512(sums_out.as_mut_ptr().add(base + BYTES / 2).cast(), high);
        }
    }
    minima.map(|m| min_byte(m))
}

/// The smallest of 64 bytes.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx2,sse4.1")]
fn min_byte(v: __m512i) -> u8 {
    let half = _mm256_min_epu8(_mm512_castsi512_si256(v), _mm512_extracti64x4_epi64::<1>(v));
    let quarter = _mm_min_epu8(_mm256_castsi256_si128(half), _mm256_extracti128_si256::<1>(half));
    // Each 16-bit word's low byte becomes the smaller of its two bytes; mask the high byte and
    // let `phminposuw` find the smallest word.
    let pairs = _mm_min_epu8(quarter, _mm_srli_epi16::<8>(quarter));
    let words = std::arch::x86_64::_mm_and_si128(pairs, _mm_set1_epi16(0xFF));
    (_mm_cvtsi128_si32(_mm_minpos_epu16(words)) & 0xFF) as u8
}

/// One pixel's census planes and gradient term, as [`cost_bytes`] reads them.
struct CostWords<'a> {
    planes: usize,
    /// The left pixel's byte of each plane.
    left: [u8; 8],
    /// Plane 0 of the mirrored right census at the pixel's first disparity; plane `k` is
    /// `k · right_stride` further, each with `out.len()` readable bytes (checked by the caller).
    right: *const u8,
    right_stride: usize,
    /// `GL(x)` and the mirrored `GR` row from `x − 0` on, when the gradient term is on.
    gradient: Option<(i16, &'a [i16])>,
    weight: u16,
    truncation: u16,
}

/// Hamming distances plus the truncated gradient difference into `out` (a multiple of 64
/// lanes), the byte arithmetic of `cost_pixel` lane for lane.
#[inline]
#[target_feature(enable = "avx512f,avx512bw,avx512bitalg,avx2,sse4.1")]
unsafe fn cost_bytes(words: &CostWords<'_>, out: &mut [u8]) {
    let left = words.left.map(|l| _mm512_set1_epi8(l as i8));
    let weight = _mm512_set1_epi16(words.weight as i16);
    let truncation = _mm512_set1_epi16(words.truncation as i16);
    for base in (0..out.len()).step_by(BYTES) {
        // SAFETY: the caller checked that every plane has `out.len()` bytes from `right`, and
        // `base + 64 ≤ out.len()`; the gradient slice has `out.len()` values.
        unsafe {
            let mut acc = _mm512_setzero_si512();
            for (k, left) in left.iter().enumerate().take(words.planes) {
                let right = _mm512_loadu_si512(words.right.add(k * words.right_stride + base).cast());
                acc = _mm512_add_epi8(acc, _mm512_popcnt_epi8(_mm512_xor_si512(*left, right)));
            }
            if let Some((gradient, right)) = words.gradient {
                let gl = _mm512_set1_epi16(gradient);
                let term = |offset: usize| {
                    let gr = _mm512_loadu_si512(right.as_ptr().add(base + offset).cast());
                    // |GL − GR| ≤ 510 fits i16; the product wraps like the u16 arithmetic of
                    // `cost_pixel` (which never reaches the wrap for a valid configuration).
                    let difference = _mm512_abs_epi16(_mm512_sub_epi16(gl, gr));
                    _mm512_cvtepi16_epi8(_mm512_min_epu16(_mm512_mullo_epi16(difference, weight), truncation))
                };
                let terms = _mm512_inserti64x4::<1>(_mm512_castsi256_si512(term(0)), term(BYTES / 2));
                acc = _mm512_add_epi8(acc, terms);
            }
            _mm512_storeu_si512(out.as_mut_ptr().add(base).cast(), acc);
        }
    }
}
