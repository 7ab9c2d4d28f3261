//! A real X server for the real-window test and the frame-time benchmark: Xvfb on a free display
//! (Mesa's llvmpipe renders the app's GL), whole-screen grabs with `xwd`, and the few pixel
//! statistics the assertions need. `scripts/lib/setup.sh` installs xvfb, x11-apps and Mesa.
#![allow(clippy::unwrap_used, clippy::expect_used, dead_code)]

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// A running Xvfb, killed on drop.
pub struct Xvfb {
    pub display: String,
    child: Child,
}

impl Xvfb {
    /// Starts Xvfb with one `width`×`height`×24 screen on the first free display from :90.
    pub fn start(width: u32, height: u32) -> Xvfb {
        let base = 90 + (std::process::id() % 200);
        for n in base..base + 50 {
            if Path::new(&format!("/tmp/.X11-unix/X{n}")).exists() || Path::new(&format!("/tmp/.X{n}-lock")).exists() {
                continue;
            }
            let display = format!(":{n}");
            let child = Command::new("Xvfb")
                .args([&display, "-screen", "0", &format!("{width}x{height}x24"), "-nolisten", "tcp"])
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("Xvfb (apt package xvfb, installed by scripts/lib/setup.sh)");
            let mut xvfb = Xvfb { display, child };
            let deadline = Instant::now() + Duration::from_secs(10);
            while Instant::now() < deadline {
                if Path::new(&format!("/tmp/.X11-unix/X{n}")).exists() {
                    return xvfb;
                }
                if let Ok(Some(_)) = xvfb.child.try_wait() {
                    break; // Lost the race for this display: try the next.
                }
                std::thread::sleep(Duration::from_millis(50));
            }
            let _ = xvfb.child.kill();
            let _ = xvfb.child.wait();
        }
        panic!("no free X display for Xvfb");
    }

    /// The whole screen as RGBA rows (via `xwd -root`).
    pub fn grab(&self) -> Image {
        let out = Command::new("xwd")
            .args(["-root", "-silent", "-display", &self.display])
            .output()
            .expect("xwd (apt package x11-apps)");
        assert!(out.status.success(), "xwd failed: {}", String::from_utf8_lossy(&out.stderr));
        parse_xwd(&out.stdout)
    }
}

impl Drop for Xvfb {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// An 8-bit RGBA image.
pub struct Image {
    pub width: usize,
    pub height: usize,
    pub rgba: Vec<u8>,
}

impl Image {
    pub fn pixel(&self, x: usize, y: usize) -> [u8; 4] {
        let i = 4 * (y * self.width + x);
        [self.rgba[i], self.rgba[i + 1], self.rgba[i + 2], self.rgba[i + 3]]
    }

    /// Pixels within `tolerance` (per channel) of `rgb`.
    pub fn count_near(&self, rgb: [u8; 3], tolerance: u8) -> usize {
        self.rgba.chunks_exact(4).filter(|p| (0..3).all(|k| p[k].abs_diff(rgb[k]) <= tolerance)).count()
    }

    /// Distinct colours after quantizing each channel to 16 levels: a blank or single-colour
    /// screen has very few.
    pub fn distinct_colours(&self) -> usize {
        let mut seen = std::collections::HashSet::new();
        for p in self.rgba.chunks_exact(4) {
            seen.insert((p[0] >> 4, p[1] >> 4, p[2] >> 4));
        }
        seen.len()
    }

    pub fn save_png(&self, path: &Path) {
        let bytes = groundstation::app::encode_png_rgba(self.width as u32, self.height as u32, &self.rgba).unwrap();
        std::fs::write(path, bytes).unwrap();
    }
}

fn be32(bytes: &[u8], at: usize) -> u32 {
    u32::from_be_bytes(bytes[at..at + 4].try_into().unwrap())
}

/// The XWD (X Window Dump, version 7) files xwd writes for a TrueColor ZPixmap screen.
pub fn parse_xwd(bytes: &[u8]) -> Image {
    let field = |i: usize| be32(bytes, 4 * i);
    let (header_size, version, format, depth) = (field(0) as usize, field(1), field(2), field(3));
    assert_eq!((version, format), (7, 2), "XWD version 7, ZPixmap");
    assert!(depth == 24 || depth == 32, "depth {depth}");
    let (width, height) = (field(4) as usize, field(5) as usize);
    let byte_order = field(7); // 0 = LSB first
    let bits_per_pixel = field(11);
    let bytes_per_line = field(12) as usize;
    let (red_mask, green_mask, blue_mask) = (field(14), field(15), field(16));
    let ncolors = field(19) as usize;
    // Xvfb packs 24-bit pixels for some screen sizes.
    assert!(bits_per_pixel == 32 || bits_per_pixel == 24, "{bits_per_pixel}-bit pixels");
    let bytes_per_pixel = bits_per_pixel as usize / 8;
    let data = &bytes[header_size + 12 * ncolors..];
    let channel = |pixel: u32, mask: u32| ((pixel & mask) >> mask.trailing_zeros()) as u8;
    let mut rgba = Vec::with_capacity(width * height * 4);
    for y in 0..height {
        let row = &data[y * bytes_per_line..];
        for x in 0..width {
            let p = &row[bytes_per_pixel * x..bytes_per_pixel * (x + 1)];
            let pixel = if byte_order == 0 {
                p.iter().rev().fold(0u32, |acc, &b| (acc << 8) | u32::from(b))
            } else {
                p.iter().fold(0u32, |acc, &b| (acc << 8) | u32::from(b))
            };
            rgba.extend_from_slice(&[
                channel(pixel, red_mask),
                channel(pixel, green_mask),
                channel(pixel, blue_mask),
                255,
            ]);
        }
    }
    Image { width, height, rgba }
}

/// Frame-log lines (`ui_ms prev_frame_cpu_ms interval_ms`) of the last run in `text`.
pub fn frame_log(text: &str) -> Vec<[f64; 3]> {
    let last_run = text.rsplit("# ui_ms").next().unwrap_or("");
    last_run
        .lines()
        .filter_map(|line| {
            let v: Vec<f64> = line.split_whitespace().map(|x| x.parse().unwrap_or(f64::NAN)).collect();
            (v.len() == 3).then(|| [v[0], v[1], v[2]])
        })
        .collect()
}

/// The `q` quantile of the finite values.
pub fn quantile(values: impl Iterator<Item = f64>, q: f64) -> f64 {
    let mut v: Vec<f64> = values.filter(|x| x.is_finite()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}
