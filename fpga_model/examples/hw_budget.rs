//! Prints the hardware budget of the LX75 configuration and of the variants the README
//! discusses: `cargo run -p fpga_model --example hw_budget`.

use fpga_model::PathMode;
use fpga_model::SgmError;
use fpga_model::hw::{DEVICES, HwConfig, budget};

fn main() -> Result<(), SgmError> {
    let lx75 = HwConfig::lx75_rover();
    let variants = [
        ("LX75 configuration: Four paths, b = 7", lx75),
        ("Same with b = 8", HwConfig { path_cost_bits: 8, ..lx75 }),
        ("Same with 8 disparities per clock (worse packing)", HwConfig { disparity_units: 8, ..lx75 }),
        (
            "Eight paths, forward sums in block RAM",
            HwConfig { paths: PathMode::Eight, eight_path_buffers_external: false, ..lx75 },
        ),
        (
            "Eight paths, forward sums and images in external DRAM, 32 disparities per clock",
            HwConfig { paths: PathMode::Eight, disparity_units: 32, ..lx75 },
        ),
    ];
    for (title, config) in variants {
        println!("## {title}\n");
        println!("{}", budget(&config)?.report(&DEVICES));
    }
    println!("## Path-cost width and disparities per clock on the LX75 (Four paths)\n");
    println!("| b | 8/clk | 16/clk | 32/clk | 64/clk |");
    println!("|---|---|---|---|---|");
    for bits in 6..=9 {
        let mut row = format!("| {bits} |");
        for units in [8, 16, 32, 64] {
            let b = budget(&HwConfig { path_cost_bits: bits, disparity_units: units, ..lx75 })?;
            let verdict = if b.fits(&fpga_model::hw::SPARTAN6_LX75) { "fits" } else { "no" };
            row.push_str(&format!(" {} BRAM, {:.1} Hz, {verdict} |", b.bram_blocks(), b.frames_per_second));
        }
        println!("{row}");
    }
    Ok(())
}
