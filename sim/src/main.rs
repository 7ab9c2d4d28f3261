//! `sim`: record simulated runs as EuRoC/ASL datasets and draw the README's pictures.

fn main() {}
