//! Runtime choice of the instruction set: the same generic kernels compiled three times (baseline,
//! AVX2, AVX-512 with the byte popcount), the best one the CPU supports picked once per matcher.
//! `unsafe` here: calling a `#[target_feature]` function (and, in `super::avx512`, the
//! intrinsics' raw loads and stores).
#![allow(unsafe_code)]

use super::kernels::{self, Aborted, Autovectorised, Job};
use super::lane::Lane;

/// An instruction set the kernels are compiled for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Isa {
    /// The target's baseline (SSE2 on x86-64): whatever LLVM vectorises without extensions.
    Portable,
    /// AVX2 (256-bit), popcount via byte shuffles.
    Avx2,
    /// AVX-512 BW/VL with `vpopcntb` (BITALG): 512-bit lanes, mask registers.
    Avx512,
}

impl Isa {
    /// The best instruction set this CPU runs.
    pub fn detect() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            if std::arch::is_x86_feature_detected!("avx512f")
                && std::arch::is_x86_feature_detected!("avx512bw")
                && std::arch::is_x86_feature_detected!("avx512vl")
                && std::arch::is_x86_feature_detected!("avx512bitalg")
                && std::arch::is_x86_feature_detected!("avx512vpopcntdq")
                && std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("bmi1")
                && std::arch::is_x86_feature_detected!("bmi2")
                && std::arch::is_x86_feature_detected!("popcnt")
                && std::arch::is_x86_feature_detected!("lzcnt")
            {
                return Isa::Avx512;
            }
            if std::arch::is_x86_feature_detected!("avx2")
                && std::arch::is_x86_feature_detected!("bmi1")
                && std::arch::is_x86_feature_detected!("bmi2")
                && std::arch::is_x86_feature_detected!("popcnt")
                && std::arch::is_x86_feature_detected!("lzcnt")
            {
                return Isa::Avx2;
            }
        }
        Isa::Portable
    }

    pub fn name(self) -> &'static str {
        match self {
            Isa::Portable => "portable",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }
}

type Kernel<T> = unsafe fn(Job<'_, '_, '_, T>) -> Result<(), Aborted>;

/// Runs `job` with the kernels of `isa`. `isa` must come from [`Isa::detect`] on this machine
/// (or be [`Isa::Portable`]); the matcher never stores anything else.
pub(crate) fn run<T: Lane, const L: usize>(isa: Isa, job: Job<'_, '_, '_, T>) -> Result<(), Aborted> {
    let kernel: Kernel<T> = match isa {
        Isa::Portable => portable::<T, L>,
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => avx2::<T, L>,
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => avx512::<T, L>,
        #[cfg(not(target_arch = "x86_64"))]
        _ => portable::<T, L>,
    };
    // SAFETY: the AVX2 and AVX-512 kernels are only selected for an `Isa` that `Isa::detect`
    // returned, i.e. after `is_x86_feature_detected!` confirmed every feature their
    // `#[target_feature]` list enables; the portable kernel has no requirement.
    unsafe { kernel(job) }
}

fn portable<T: Lane, const L: usize>(job: Job<'_, '_, '_, T>) -> Result<(), Aborted> {
    kernels::run::<T, L, _>(job, Autovectorised)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,bmi1,bmi2,popcnt,lzcnt")]
fn avx2<T: Lane, const L: usize>(job: Job<'_, '_, '_, T>) -> Result<(), Aborted> {
    kernels::run::<T, L, _>(job, Autovectorised)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx512bw,avx512vl,avx512bitalg,avx512vpopcntdq,avx2,bmi1,bmi2,popcnt,lzcnt")]
fn avx512<T: Lane, const L: usize>(job: Job<'_, '_, '_, T>) -> Result<(), Aborted> {
    // SAFETY: this kernel runs only after `Isa::detect` found AVX-512F/BW (see `run`).
    let intrinsics = unsafe { super::avx512::Avx512::new_unchecked() };
    kernels::run::<T, L, _>(job, intrinsics)
}
