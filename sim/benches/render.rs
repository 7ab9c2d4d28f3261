//! Rendering speed of a 1024×508 stereo pair against the 100 ms frame period of a 10 Hz camera.

fn main() {}
