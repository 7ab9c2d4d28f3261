//! The element type of the path-cost vectors.
//!
//! A matching cost is at most 255 (`SgmConfig::cost_max`: 64 census bits plus a gradient term
//! ≤ 191), and a stored path cost `L_r` at most `Lmax`, so for `b ≤ 8` both fit a byte and the
//! aggregation runs on `u8` lanes: twice the disparities per SIMD instruction of `u16` lanes.
//! A padding disparity's cost `T::MAX` may equal a real cost of 255 but never undercuts one, so
//! its path cost is `Lmax` and it still wins no minimum (see [`super::kernels`]). Saturating byte
//! arithmetic gives exactly the wide-integer results of `SPEC.md` there:
//!
//! - `L(d ± 1) + p1` and `M + P2eff` are only ever compared against `L(d) ≤ 255`, so clipping
//!   them at 255 never changes the minimum `best`;
//! - `best − M` is exact (`best ≥ M`), and `C + (best − M)` clipped at 255 is then clipped again
//!   at `Lmax ≤ 255`, which is what the spec stores.
//!
//! For `b ≥ 9` the lanes are `u16`, where nothing saturates below `Lmax ≤ 4095`.

/// A path-cost lane: `u8` for `path_cost_bits ≤ 8`, `u16` above.
pub(crate) trait Lane: Copy + Ord + Default + Send + Sync + std::fmt::Debug + 'static {
    /// The largest value; also the cost of the padding disparities `D ..` of a SIMD block.
    const MAX: Self;
    /// Lanes of one aggregation block: a full 512-bit register of this type.
    const BLOCK: usize;
    /// Converts a value known to fit (callers clamp first).
    fn from_u16(value: u16) -> Self;
    fn from_u8(value: u8) -> Self;
    fn saturating_add(self, other: Self) -> Self;
    /// `self − other` for `self ≥ other`.
    fn minus(self, other: Self) -> Self;
    fn widen(self) -> u16;
    /// The slice as bytes, for the byte-lane intrinsics (`None` for wider lanes).
    fn bytes(values: &[Self]) -> Option<&[u8]>;
    fn bytes_mut(values: &mut [Self]) -> Option<&mut [u8]>;
    /// The value as a byte lane (`None` for wider lanes).
    fn to_byte(self) -> Option<u8>;
}

impl Lane for u8 {
    const MAX: Self = u8::MAX;
    const BLOCK: usize = 64;

    #[inline(always)]
    fn from_u16(value: u16) -> Self {
        value.min(255) as u8
    }

    #[inline(always)]
    fn from_u8(value: u8) -> Self {
        value
    }

    #[inline(always)]
    fn saturating_add(self, other: Self) -> Self {
        u8::saturating_add(self, other)
    }

    #[inline(always)]
    fn minus(self, other: Self) -> Self {
        self.wrapping_sub(other)
    }

    #[inline(always)]
    fn widen(self) -> u16 {
        u16::from(self)
    }

    #[inline(always)]
    fn bytes(values: &[Self]) -> Option<&[u8]> {
        Some(values)
    }

    #[inline(always)]
    fn bytes_mut(values: &mut [Self]) -> Option<&mut [u8]> {
        Some(values)
    }

    #[inline(always)]
    fn to_byte(self) -> Option<u8> {
        Some(self)
    }
}

impl Lane for u16 {
    const MAX: Self = u16::MAX;
    const BLOCK: usize = 32;

    #[inline(always)]
    fn from_u16(value: u16) -> Self {
        value
    }

    #[inline(always)]
    fn from_u8(value: u8) -> Self {
        u16::from(value)
    }

    #[inline(always)]
    fn saturating_add(self, other: Self) -> Self {
        u16::saturating_add(self, other)
    }

    #[inline(always)]
    fn minus(self, other: Self) -> Self {
        self.wrapping_sub(other)
    }

    #[inline(always)]
    fn widen(self) -> u16 {
        self
    }

    #[inline(always)]
    fn bytes(_: &[Self]) -> Option<&[u8]> {
        None
    }

    #[inline(always)]
    fn bytes_mut(_: &mut [Self]) -> Option<&mut [u8]> {
        None
    }

    #[inline(always)]
    fn to_byte(self) -> Option<u8> {
        None
    }
}
