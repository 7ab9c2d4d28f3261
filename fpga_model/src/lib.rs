//! A bit-exact software model of the FPGA semi-global matching (SGM) stereo core that runs on
//! the rovers (thesis §7.1: 1024×508 px at up to 14.6 Hz on a Spartan-6 LX75), and the stereo
//! matcher the rover software uses.
//!
//! `SPEC.md` defines the fixed-point data path; `PARITY.md` explains its choices. Two
//! implementations of the same core: [`reference`] (stage by stage, readable, each stage a
//! function of [`stages`]) and [`fast`] (streaming, SIMD-friendly, optional threads), bit-identical.
//! [`hw`] is the hardware budget: cycles, BRAM, frame rate.

pub mod config;
pub mod eval;
pub mod fast;
pub mod hw;
pub mod image;
pub mod io;
pub mod reference;
pub mod stages;

pub use config::{PathMode, SgmConfig};
pub use image::{DISPARITY_FRAC_BITS, DisparityImage, GrayImage, GrayView, INVALID};

#[derive(Debug, thiserror::Error)]
pub enum SgmError {
    #[error("invalid configuration: {0}")]
    InvalidConfig(String),
    #[error("image of {width}x{height} has {len} pixels")]
    BadImage { width: usize, height: usize, len: usize },
    #[error("left image is {left:?} but right image is {right:?}")]
    SizeMismatch { left: (usize, usize), right: (usize, usize) },
}
