//! The hardware budget of the SGM core: cycles per frame, frame rate, on-chip memory packed into
//! Spartan-6 18 Kb block RAMs, DSP48A1 slices, and, for the two-pass `Eight` mode, the external
//! memory traffic.
//!
//! The model describes a streaming design (`README.md`, "Hardware model"): pixels arrive in
//! raster order, each pixel's `D` disparities are evaluated `disparity_units` at a time, so a
//! pixel takes `ceil(D / units)` clocks; the three row-based paths of a raster pass keep the
//! previous row's path costs in block RAM; everything else the pass needs lives in line
//! buffers, registers or shift-register LUTs. The model counts storage, not logic: LUTs and
//! routing of the datapath are not estimated.

use crate::SgmError;
use crate::config::{PathMode, SgmConfig};
use std::fmt::Write as _;

/// One aspect ratio of a Spartan-6 RAMB16BWER (18 Kb incl. parity; the 9/18/36-bit widths use
/// the parity bits as data).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BramAspect {
    pub depth_words: u64,
    pub width_bits: u32,
}

/// The aspect ratios of a Spartan-6 18 Kb block RAM (UG383), deepest first.
pub const BRAM_ASPECTS: [BramAspect; 6] = [
    BramAspect { depth_words: 16384, width_bits: 1 },
    BramAspect { depth_words: 8192, width_bits: 2 },
    BramAspect { depth_words: 4096, width_bits: 4 },
    BramAspect { depth_words: 2048, width_bits: 9 },
    BramAspect { depth_words: 1024, width_bits: 18 },
    BramAspect { depth_words: 512, width_bits: 36 },
];

/// Bits of one 18 Kb block RAM including parity.
pub const BRAM_BITS: u64 = 18 * 1024;

/// How a `depth × width` memory is tiled with blocks of one aspect ratio.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Packing {
    pub aspect: BramAspect,
    /// Blocks stacked to reach the depth (address decoding selects one).
    pub blocks_deep: u64,
    /// Blocks side by side to reach the width (all read in the same clock).
    pub blocks_wide: u64,
}

impl Packing {
    pub fn blocks(&self) -> u64 {
        self.blocks_deep * self.blocks_wide
    }
}

/// The cheapest tiling of a memory of `depth_words` words of `width_bits` bits, where a whole
/// word is read or written in one clock. Ties go to the deeper aspect (first in
/// [`BRAM_ASPECTS`]). An empty memory takes no block.
pub fn pack(depth_words: u64, width_bits: u32) -> Packing {
    let tile = |aspect: BramAspect| Packing {
        aspect,
        blocks_deep: if width_bits == 0 { 0 } else { depth_words.div_ceil(aspect.depth_words) },
        blocks_wide: u64::from(width_bits.div_ceil(aspect.width_bits)),
    };
    let mut best = tile(BRAM_ASPECTS[0]);
    for aspect in BRAM_ASPECTS.into_iter().skip(1) {
        let candidate = tile(aspect);
        if candidate.blocks() < best.blocks() {
            best = candidate;
        }
    }
    best
}

/// Where a buffer lives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Storage {
    /// Block RAM, tiled as given.
    BlockRam(Packing),
    /// Flip-flops, LUT RAM or SRL shift registers: small buffers, or buffers read at many
    /// addresses in one clock, which a two-port block RAM cannot serve.
    Fabric,
    /// Off-chip DRAM through a Spartan-6 memory controller block (MCB).
    External,
}

/// One memory of the design.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Buffer {
    pub name: String,
    /// Words, one word accessed per clock.
    pub depth_words: u64,
    pub width_bits: u32,
    pub storage: Storage,
}

impl Buffer {
    fn new(name: impl Into<String>, depth_words: u64, width_bits: u32, storage: StorageKind) -> Buffer {
        let storage = match storage {
            StorageKind::BlockRam => Storage::BlockRam(pack(depth_words, width_bits)),
            StorageKind::Fabric => Storage::Fabric,
            StorageKind::External => Storage::External,
        };
        Buffer { name: name.into(), depth_words, width_bits, storage }
    }

    pub fn bits(&self) -> u64 {
        self.depth_words * u64::from(self.width_bits)
    }

    /// 18 Kb blocks this buffer takes (0 unless in block RAM).
    pub fn bram_blocks(&self) -> u64 {
        match self.storage {
            Storage::BlockRam(packing) => packing.blocks(),
            Storage::Fabric | Storage::External => 0,
        }
    }
}

#[derive(Debug, Clone, Copy)]
enum StorageKind {
    BlockRam,
    Fabric,
    External,
}

/// DSP48A1 slices of one function.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct DspUse {
    pub name: &'static str,
    pub count: u32,
}

/// An FPGA's resources as the data sheet gives them (Xilinx DS160, Spartan-6 family overview).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Device {
    pub name: &'static str,
    /// 18 Kb block RAMs.
    pub bram_18kb: u32,
    pub dsp48a1: u32,
    pub flip_flops: u32,
}

pub const SPARTAN6_LX45: Device = Device { name: "XC6SLX45", bram_18kb: 116, dsp48a1: 58, flip_flops: 54_576 };
/// The rover's FPGA: 172 × 18 Kb = 3,096 Kb of block RAM.
pub const SPARTAN6_LX75: Device = Device { name: "XC6SLX75", bram_18kb: 172, dsp48a1: 132, flip_flops: 93_296 };
pub const SPARTAN6_LX100: Device = Device { name: "XC6SLX100", bram_18kb: 268, dsp48a1: 180, flip_flops: 126_576 };
pub const SPARTAN6_LX150: Device = Device { name: "XC6SLX150", bram_18kb: 268, dsp48a1: 180, flip_flops: 184_304 };

/// The Spartan-6 devices the README compares, smallest first.
pub const DEVICES: [Device; 4] = [SPARTAN6_LX45, SPARTAN6_LX75, SPARTAN6_LX100, SPARTAN6_LX150];

/// Parameters of the hardware model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HwConfig {
    pub clock_hz: f64,
    /// Disparities evaluated per clock by each path unit; a pixel takes `ceil(D / units)` clocks.
    pub disparity_units: u32,
    /// Latency from the first pixel in to the last result out beyond the per-pixel clocks, paid
    /// once per frame (frames are not overlapped).
    pub pipeline_depth_cycles: u32,
    /// Idle clocks per image line (line start/end: refill of the census window, row switch).
    pub horizontal_blanking_cycles: u32,
    /// Idle lines per frame (flushing the census window and the median at the bottom).
    pub vertical_blanking_lines: u32,
    pub width: u32,
    pub height: u32,
    pub disparities: u32,
    pub census_width: u32,
    pub census_height: u32,
    /// Largest value of the gradient term of the matching cost (`SgmConfig::gradient_cost_max`);
    /// 0 = census-only cost, no gradient hardware.
    pub gradient_cost_max: u32,
    pub path_cost_bits: u32,
    pub paths: PathMode,
    pub subpixel: bool,
    pub lr_check: bool,
    pub median: bool,
    /// `Eight` only: keep the first pass's sums and the input images in external DRAM (true)
    /// or in block RAM (false, which never fits at useful image sizes).
    pub eight_path_buffers_external: bool,
}

/// The rover's image size (thesis §7.1).
pub const ROVER_WIDTH: u32 = 1024;
pub const ROVER_HEIGHT: u32 = 508;
/// The frame rate the thesis reports for the FPGA core.
pub const ROVER_FRAME_RATE_HZ: f64 = 14.6;

impl HwConfig {
    /// The configuration this crate proposes for the LX75: 1024×508, D = 128, `Four` paths,
    /// b = 7, 9×7 census plus the default gradient term (≤ 32), 16 disparities per clock at
    /// 75 MHz. See `README.md` for its budget.
    pub fn lx75_rover() -> HwConfig {
        HwConfig {
            clock_hz: 75.0e6,
            disparity_units: 16,
            pipeline_depth_cycles: 64,
            horizontal_blanking_cycles: 64,
            vertical_blanking_lines: 4,
            width: ROVER_WIDTH,
            height: ROVER_HEIGHT,
            disparities: 128,
            census_width: 9,
            census_height: 7,
            gradient_cost_max: 32,
            path_cost_bits: 7,
            paths: PathMode::Four,
            subpixel: true,
            lr_check: true,
            median: true,
            eight_path_buffers_external: true,
        }
    }

    /// The hardware of an [`SgmConfig`] on a `width × height` image, with the timing parameters
    /// of [`HwConfig::lx75_rover`].
    pub fn from_sgm(config: &SgmConfig, width: u32, height: u32) -> HwConfig {
        HwConfig {
            width,
            height,
            disparities: u32::from(config.disparities),
            census_width: u32::from(config.census_width),
            census_height: u32::from(config.census_height),
            gradient_cost_max: u32::from(config.gradient_cost_max()),
            path_cost_bits: u32::from(config.path_cost_bits),
            paths: config.paths,
            subpixel: config.subpixel,
            lr_check: config.lr_check,
            median: config.median,
            ..HwConfig::lx75_rover()
        }
    }

    fn validate(&self) -> Result<(), SgmError> {
        let bad = |reason: String| Err(SgmError::InvalidConfig(reason));
        if !(self.clock_hz.is_finite() && self.clock_hz > 0.0) {
            return bad(format!("clock {} Hz must be positive", self.clock_hz));
        }
        if self.width == 0 || self.height == 0 || self.disparities == 0 {
            return bad(format!(
                "image {}x{} with D = {} must be non-empty",
                self.width, self.height, self.disparities
            ));
        }
        if self.disparity_units == 0 || self.disparity_units > self.disparities {
            return bad(format!("disparity units {} must be in 1..=D ({})", self.disparity_units, self.disparities));
        }
        if self.census_width.is_multiple_of(2) || self.census_height.is_multiple_of(2) {
            return bad(format!("census window {}x{} must be odd", self.census_width, self.census_height));
        }
        if self.census_width * self.census_height > 65 {
            return bad(format!("census window {}x{} exceeds 64 bits", self.census_width, self.census_height));
        }
        if self.gradient_cost_max > 255 {
            return bad(format!("gradient cost maximum {} must be <= 255", self.gradient_cost_max));
        }
        if !(1..=16).contains(&self.path_cost_bits) {
            return bad(format!("path cost bits {} must be in 1..=16", self.path_cost_bits));
        }
        Ok(())
    }
}

/// Bits of a horizontal gradient `I(x + 1) − I(x − 1)`: −255 ..= 255.
const GRADIENT_BITS: u32 = 9;

/// Bits to hold the values `0 ..= max`.
fn bits_for(max: u64) -> u32 {
    (u64::BITS - max.leading_zeros()).max(1)
}

/// The budget of one configuration.
#[derive(Debug, Clone, PartialEq)]
pub struct Budget {
    pub config: HwConfig,
    /// `ceil(D / units)`.
    pub cycles_per_pixel: u64,
    /// Width of a matching cost `C` (census bits plus the gradient term): what each disparity
    /// unit adds to its path costs. `C` is computed on the fly and never stored.
    pub cost_bits: u32,
    /// `W · cycles_per_pixel + horizontal blanking`.
    pub cycles_per_line: u64,
    /// Raster passes per frame: 1 for `Four`, 2 for `Eight` (same hardware, run twice).
    pub passes: u64,
    /// `passes · (H + vertical blanking) · cycles_per_line + pipeline depth`.
    pub cycles_per_frame: u64,
    pub frames_per_second: f64,
    pub buffers: Vec<Buffer>,
    pub dsps: Vec<DspUse>,
}

/// Computes the budget of `config`.
pub fn budget(config: &HwConfig) -> Result<Budget, SgmError> {
    config.validate()?;
    let c = config;
    let (w, h, d) = (u64::from(c.width), u64::from(c.height), u64::from(c.disparities));
    let units = c.disparity_units;
    let b = c.path_cost_bits;

    let cycles_per_pixel = d.div_ceil(u64::from(units));
    let cycles_per_line = w * cycles_per_pixel + u64::from(c.horizontal_blanking_cycles);
    let passes = match c.paths {
        PathMode::Four => 1,
        PathMode::Eight => 2,
    };
    let lines = h + u64::from(c.vertical_blanking_lines);
    let cycles_per_frame = passes * lines * cycles_per_line + u64::from(c.pipeline_depth_cycles);
    let frames_per_second = c.clock_hz / cycles_per_frame as f64;

    let census_bits = c.census_width * c.census_height - 1;
    let cost_bits = bits_for(u64::from(census_bits + c.gradient_cost_max));
    // The sum a pass produces: 4 paths of b bits need b + 2 bits.
    let pass_sum_bits = b + 2;
    // The sum the selection sees: the second pass adds the first pass's 4 paths.
    let sum_bits = match c.paths {
        PathMode::Four => b + 2,
        PathMode::Eight => b + 3,
    };
    let disparity_bits = bits_for(d - 1);
    // 1/16 px output up to 16 · (D − 1) + 8, plus one flag bit for INVALID.
    let output_bits = bits_for(16 * (d - 1) + 8) + 1;

    let mut buffers = Vec::new();
    use StorageKind::{BlockRam, External, Fabric};

    // Census: h − 1 previous image rows per image; all rows are read at the same column in one
    // clock, so the rows sit side by side in one wide word. They also give IL of the previous
    // row for the gradient that adapts P2.
    if c.census_height > 1 {
        for image in ["left", "right"] {
            let name = format!("census line buffers, {image} image ({} rows)", c.census_height - 1);
            buffers.push(Buffer::new(name, w, (c.census_height - 1) * 8, BlockRam));
        }
    }
    // The right census words of the last D columns, `units` of them read per clock at offsets
    // that move every clock: registers, not a two-port RAM.
    buffers.push(Buffer::new("right census window (last D words)", cycles_per_pixel, units * census_bits, Fabric));
    if c.gradient_cost_max > 0 {
        // GR(x − d) of the last D right pixels (9 bits signed), beside their census words. GL(x)
        // and GR of the newest pixel come from the census window's centre row (its pixels
        // x − 1 and x + 1 are in the window registers already): no line buffer.
        buffers.push(Buffer::new("right gradients (last D pixels)", cycles_per_pixel, units * GRADIENT_BITS, Fabric));
    }
    // Path (1,0) only needs the previous pixel of the same row.
    buffers.push(Buffer::new("path (1,0): previous pixel's costs", cycles_per_pixel, units * b, Fabric));
    // The three row-based paths read the previous row's costs, `units` values per clock.
    for path in ["(1,1)", "(0,1)", "(-1,1)"] {
        let name = format!("path {path}: previous row's costs");
        buffers.push(Buffer::new(name, w * cycles_per_pixel, units * b, BlockRam));
    }
    // M of the previous row: needed before the first disparity group of a pixel starts.
    for path in ["(1,1)", "(0,1)", "(-1,1)"] {
        buffers.push(Buffer::new(format!("path {path}: previous row's minima"), w, b, BlockRam));
    }
    // P2 for every gradient 0..=255, computed by the host when P1, P2 or s change: no divider.
    buffers.push(Buffer::new("P2 table (by gradient)", 256, 8, Fabric));

    if c.paths == PathMode::Eight {
        let kind = if c.eight_path_buffers_external { External } else { BlockRam };
        // The reverse pass adds the forward pass's sums, so they must outlive the whole frame.
        buffers.push(Buffer::new(
            "forward-pass sums S_fwd (whole frame)",
            w * h * cycles_per_pixel,
            units * pass_sum_bits,
            kind,
        ));
        // The reverse pass re-reads both images (to recompute the census) in reverse order.
        buffers.push(Buffer::new("both input images (whole frame)", w * h, 16, kind));
    }

    if c.lr_check {
        // dR(xr) collects S(xr + d, d) over the next D columns: one running (min, argmin) per
        // column still open, `units` of them updated per clock.
        buffers.push(Buffer::new("LR: right-disparity running minima", d, sum_bits + disparity_bits, Fabric));
        // dR of the last D columns, final; the delayed left pixel looks up dR(x − d1), or with
        // the lenient check dR(x − floor) and dR(x − ceil) of its subpixel disparity: two
        // neighbouring registers, i.e. a second read multiplexer, no more storage.
        buffers.push(Buffer::new("LR: finished right disparities", d, disparity_bits, Fabric));
        // A left result waits D − 1 columns until every dR it may need is final.
        buffers.push(Buffer::new("LR: left disparity delay line (SRL)", d, output_bits + disparity_bits, Fabric));
    }
    if c.median {
        // Two previous output rows, read together. (The median of the valid values sorts all
        // nine with a 25-comparator network and picks index 2, 3 or 4: logic, not storage.)
        buffers.push(Buffer::new("median line buffers (2 rows)", w, 2 * output_bits, BlockRam));
    }

    let mut dsps = vec![
        // 100 · S2 and (100 + U) · S1: two 18×18 multiplies per pixel.
        DspUse { name: "uniqueness test (100·S2, (100+U)·S1)", count: 2 },
    ];
    if c.subpixel {
        // The quotient has 4 bits (|offset| ≤ 8), one restoring step per clock on a DSP48A1
        // post-adder: a pixel's clocks give the steps, faster designs unroll them.
        dsps.push(DspUse {
            name: "subpixel division (4 restoring steps)",
            count: 4u64.div_ceil(cycles_per_pixel) as u32,
        });
    }

    Ok(Budget {
        config: *config,
        cycles_per_pixel,
        cost_bits,
        cycles_per_line,
        passes,
        cycles_per_frame,
        frames_per_second,
        buffers,
        dsps,
    })
}

impl Budget {
    pub fn bram_blocks(&self) -> u64 {
        self.buffers.iter().map(Buffer::bram_blocks).sum()
    }

    /// Bits in block RAM that carry data (the rest of the blocks is packing loss).
    pub fn bram_data_bits(&self) -> u64 {
        self.buffers.iter().filter(|b| matches!(b.storage, Storage::BlockRam(_))).map(Buffer::bits).sum()
    }

    pub fn fabric_bits(&self) -> u64 {
        self.buffers.iter().filter(|b| b.storage == Storage::Fabric).map(Buffer::bits).sum()
    }

    pub fn dsp_count(&self) -> u32 {
        self.dsps.iter().map(|d| d.count).sum()
    }

    /// DRAM bytes moved per frame: every external buffer written once and read once.
    pub fn external_bytes_per_frame(&self) -> u64 {
        self.buffers.iter().filter(|b| b.storage == Storage::External).map(|b| 2 * b.bits().div_ceil(8)).sum()
    }

    /// [`Budget::external_bytes_per_frame`] at the model's frame rate.
    pub fn external_bytes_per_second(&self) -> f64 {
        self.external_bytes_per_frame() as f64 * self.frames_per_second
    }

    /// The clock that gives `frames_per_second` with these cycles per frame.
    pub fn min_clock_hz_for(&self, frames_per_second: f64) -> f64 {
        self.cycles_per_frame as f64 * frames_per_second
    }

    /// Fits if the block RAMs and DSP48A1s are within the device and the fabric buffers'
    /// bits do not exceed its flip-flops (a necessary condition only: the datapath's logic is
    /// not modelled).
    pub fn fits(&self, device: &Device) -> bool {
        self.bram_blocks() <= u64::from(device.bram_18kb)
            && self.dsp_count() <= device.dsp48a1
            && self.fabric_bits() <= u64::from(device.flip_flops)
    }

    /// A Markdown report: timing, one row per buffer, DSPs, and the fit on `devices`.
    pub fn report(&self, devices: &[Device]) -> String {
        let c = &self.config;
        let mut out = String::new();
        let _ = writeln!(
            out,
            "{}x{} px, D = {}, {:?} paths, b = {}, census {}x{}, gradient term ≤ {}, {} disparities/clock at {:.1} \
             MHz",
            c.width,
            c.height,
            c.disparities,
            c.paths,
            c.path_cost_bits,
            c.census_width,
            c.census_height,
            c.gradient_cost_max,
            c.disparity_units,
            c.clock_hz / 1e6
        );
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "- cycles: {} per pixel, {} per line, {} per frame ({} pass{})",
            self.cycles_per_pixel,
            self.cycles_per_line,
            self.cycles_per_frame,
            self.passes,
            if self.passes == 1 { "" } else { "es" }
        );
        let _ = writeln!(
            out,
            "- matching cost: {} bits (0 ..= {}), path costs saturate at {}",
            self.cost_bits,
            c.census_width * c.census_height - 1 + c.gradient_cost_max,
            (1u64 << c.path_cost_bits) - 1
        );
        let _ = writeln!(
            out,
            "- frame rate: {:.2} Hz; {:.1} MHz needed for {} Hz",
            self.frames_per_second,
            self.min_clock_hz_for(ROVER_FRAME_RATE_HZ) / 1e6,
            ROVER_FRAME_RATE_HZ
        );
        let _ = writeln!(out);
        let _ = writeln!(out, "| buffer | storage | words × bits | bits | aspect | 18 Kb blocks |");
        let _ = writeln!(out, "|---|---|---|---:|---|---:|");
        for buffer in &self.buffers {
            let (storage, aspect, blocks) = match buffer.storage {
                Storage::BlockRam(p) => (
                    "BRAM",
                    format!("{}×{} ({}×{})", p.aspect.depth_words, p.aspect.width_bits, p.blocks_deep, p.blocks_wide),
                    p.blocks().to_string(),
                ),
                Storage::Fabric => ("fabric", "-".to_string(), "-".to_string()),
                Storage::External => ("DRAM", "-".to_string(), "-".to_string()),
            };
            let _ = writeln!(
                out,
                "| {} | {} | {} × {} | {} | {} | {} |",
                buffer.name,
                storage,
                buffer.depth_words,
                buffer.width_bits,
                buffer.bits(),
                aspect,
                blocks
            );
        }
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "- block RAM: {} blocks ({} data bits of {} available in them, {:.0}% packing efficiency)",
            self.bram_blocks(),
            self.bram_data_bits(),
            self.bram_blocks() * BRAM_BITS,
            100.0 * self.bram_data_bits() as f64 / (self.bram_blocks() * BRAM_BITS).max(1) as f64
        );
        let _ = writeln!(out, "- fabric storage: {} bits (flip-flops, LUT RAM, SRLs)", self.fabric_bits());
        for dsp in &self.dsps {
            let _ = writeln!(out, "- DSP48A1: {} × {}", dsp.count, dsp.name);
        }
        if self.external_bytes_per_frame() > 0 {
            let _ = writeln!(
                out,
                "- external DRAM traffic: {:.1} MB per frame, {:.2} GB/s at {:.2} Hz, {:.2} GB/s at {} Hz",
                self.external_bytes_per_frame() as f64 / 1e6,
                self.external_bytes_per_second() / 1e9,
                self.frames_per_second,
                self.external_bytes_per_frame() as f64 * ROVER_FRAME_RATE_HZ / 1e9,
                ROVER_FRAME_RATE_HZ
            );
        }
        for device in devices {
            let _ = writeln!(
                out,
                "- {}: {} / {} BRAM, {} / {} DSP48A1, {} / {} flip-flops: {}",
                device.name,
                self.bram_blocks(),
                device.bram_18kb,
                self.dsp_count(),
                device.dsp48a1,
                self.fabric_bits(),
                device.flip_flops,
                if self.fits(device) { "fits" } else { "does not fit" }
            );
        }
        out
    }
}
