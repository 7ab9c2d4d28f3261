//! Image I/O: PNG decoding of every colour type the data uses (and the ones it might), PFM
//! round trips in the Middlebury convention, and a fuzz of the PFM parser (total: no panic).

#![allow(clippy::unwrap_used, reason = "test helpers: a panic is a failed test with its message")]

use std::fs;
use std::path::PathBuf;

use fpga_model::eval::default_data_root;
use fpga_model::io::{self, IoError};
use fpga_model::{DisparityImage, GrayImage, INVALID};
use proptest::prelude::*;

fn temp_dir(test: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("io_tests").join(test);
    fs::create_dir_all(&dir).unwrap();
    dir
}

/// Writes a PNG with the given colour type, depth, optional palette, and raw (packed) rows.
fn write_png(
    path: &PathBuf,
    width: u32,
    height: u32,
    color: png::ColorType,
    depth: png::BitDepth,
    palette: Option<Vec<u8>>,
    data: &[u8],
) {
    let file = fs::File::create(path).unwrap();
    let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), width, height);
    encoder.set_color(color);
    encoder.set_depth(depth);
    if let Some(palette) = palette {
        encoder.set_palette(palette);
    }
    let mut writer = encoder.write_header().unwrap();
    writer.write_image_data(data).unwrap();
    writer.finish().unwrap();
}

#[test]
fn luma_formula() {
    assert_eq!(io::luma_u8(0, 0, 0), 0);
    assert_eq!(io::luma_u8(255, 255, 255), 255);
    for g in 0..=255u8 {
        assert_eq!(io::luma_u8(g, g, g), g, "gray must stay gray");
    }
    assert_eq!(io::luma_u8(255, 0, 0), ((77 * 255 + 128) >> 8) as u8);
    assert_eq!(io::luma_u8(10, 200, 30), ((77 * 10 + 150 * 200 + 29 * 30 + 128) >> 8) as u8);
}

#[test]
fn png_color_types() {
    let dir = temp_dir("png_color_types");
    // 8-bit gray.
    let p = dir.join("gray8.png");
    write_png(&p, 3, 2, png::ColorType::Grayscale, png::BitDepth::Eight, None, &[0, 1, 2, 253, 254, 255]);
    let img = io::read_gray_png(&p).unwrap();
    assert_eq!((img.width, img.height, img.pixels.clone()), (3, 2, vec![0, 1, 2, 253, 254, 255]));
    assert_eq!(io::read_png_values(&p).unwrap().values, vec![0, 1, 2, 253, 254, 255]);

    // 16-bit gray: high byte for the matcher, whole value for read_png_values.
    let p = dir.join("gray16.png");
    write_png(&p, 2, 1, png::ColorType::Grayscale, png::BitDepth::Sixteen, None, &[0x12, 0x34, 0xAB, 0xCD]);
    assert_eq!(io::read_gray_png(&p).unwrap().pixels, vec![0x12, 0xAB]);
    let values = io::read_png_values(&p).unwrap();
    assert_eq!((values.bit_depth, values.values), (16, vec![0x1234, 0xABCD]));

    // RGB and RGBA: integer luma, alpha ignored.
    let p = dir.join("rgb.png");
    write_png(&p, 2, 1, png::ColorType::Rgb, png::BitDepth::Eight, None, &[10, 200, 30, 7, 7, 7]);
    assert_eq!(io::read_gray_png(&p).unwrap().pixels, vec![io::luma_u8(10, 200, 30), 7]);
    assert!(matches!(io::read_png_values(&p), Err(IoError::Png { .. })), "coloured pixels are no value map");
    let p = dir.join("rgba.png");
    write_png(&p, 1, 1, png::ColorType::Rgba, png::BitDepth::Eight, None, &[255, 0, 0, 0]);
    assert_eq!(io::read_gray_png(&p).unwrap().pixels, vec![io::luma_u8(255, 0, 0)]);

    // 16-bit RGB: high bytes, then luma.
    let p = dir.join("rgb16.png");
    write_png(&p, 1, 1, png::ColorType::Rgb, png::BitDepth::Sixteen, None, &[100, 1, 50, 2, 25, 3]);
    assert_eq!(io::read_gray_png(&p).unwrap().pixels, vec![io::luma_u8(100, 50, 25)]);

    // 4-bit palette (like tsukuba's GT): indices 0..3 map through a gray palette.
    let p = dir.join("pal4.png");
    let palette = vec![0, 0, 0, 80, 80, 80, 96, 96, 96, 224, 224, 224];
    // 4 pixels, 4 bits each: indices 0,1 | 2,3.
    write_png(&p, 4, 1, png::ColorType::Indexed, png::BitDepth::Four, Some(palette), &[0x01, 0x23]);
    assert_eq!(io::read_png_values(&p).unwrap().values, vec![0, 80, 96, 224]);
    assert_eq!(io::read_gray_png(&p).unwrap().pixels, vec![0, 80, 96, 224]);

    // 1-bit palette (like the nonocc masks).
    let p = dir.join("pal1.png");
    write_png(
        &p,
        8,
        1,
        png::ColorType::Indexed,
        png::BitDepth::One,
        Some(vec![0, 0, 0, 255, 255, 255]),
        &[0b1010_0001],
    );
    assert_eq!(io::read_png_values(&p).unwrap().values, vec![255, 0, 255, 0, 0, 0, 0, 255]);

    // 2-bit gray: scaled to 0..=255 (0, 85, 170, 255), as libpng and OpenCV do.
    let p = dir.join("gray2.png");
    write_png(&p, 4, 1, png::ColorType::Grayscale, png::BitDepth::Two, None, &[0b00_01_10_11]);
    assert_eq!(io::read_png_values(&p).unwrap().values, vec![0, 85, 170, 255]);
}

#[test]
fn png_errors_name_the_file() {
    let dir = temp_dir("png_errors");
    let missing = dir.join("missing.png");
    let err = io::read_gray_png(&missing).unwrap_err();
    assert!(matches!(err, IoError::File { .. }));
    assert!(err.to_string().contains("missing.png"), "{err}");
    let garbage = dir.join("garbage.png");
    fs::write(&garbage, b"definitely not a png").unwrap();
    let err = io::read_gray_png(&garbage).unwrap_err();
    assert!(matches!(err, IoError::PngDecode { .. }));
    assert!(err.to_string().contains("garbage.png"), "{err}");
}

#[test]
fn gray_png_round_trip() {
    let dir = temp_dir("gray_png_round_trip");
    let p = dir.join("img.png");
    let pixels: Vec<u8> = (0..35u32).map(|i| (i * 37 % 256) as u8).collect();
    let image = GrayImage::new(7, 5, pixels).unwrap();
    io::write_gray_png(&p, &image).unwrap();
    assert_eq!(io::read_gray_png(&p).unwrap(), image);
}

#[test]
fn middlebury_pngs() {
    let root = default_data_root();
    // tsukuba's GT is a 4-bit palette PNG whose palette holds gray levels value*16.
    let gt = io::read_png_values(root.join("middlebury_v2/tsukuba/groundtruth.png")).unwrap();
    assert_eq!((gt.width, gt.height), (384, 288));
    assert!(gt.values.iter().all(|v| v % 16 == 0 && *v <= 15 * 16), "tsukuba GT is value*16");
    assert!(gt.values.contains(&(14 * 16)));
    // Masks are 1-bit palette PNGs: 0 and 255 only.
    let mask = io::read_png_values(root.join("middlebury_v2/teddy/nonocc.png")).unwrap();
    assert!(mask.values.iter().all(|&v| v == 0 || v == 255));
    let share = mask.values.iter().filter(|&&v| v == 255).count() as f64 / mask.values.len() as f64;
    assert!((0.8..0.95).contains(&share), "teddy nonocc share {share}");
    let left = io::read_gray_png(root.join("middlebury_v2/cones/imL.png")).unwrap();
    assert_eq!((left.width, left.height), (450, 375));
}

#[test]
fn pfm_round_trip_middlebury_layout() {
    let dir = temp_dir("pfm_round_trip");
    let p = dir.join("d.pfm");
    let values = vec![0.0, 1.5, f32::INFINITY, 3.25, -2.0, 127.9375];
    io::write_pfm(&p, 3, 2, &values).unwrap();
    let bytes = fs::read(&p).unwrap();
    let header = b"Pf\n3 2\n-1\n";
    assert_eq!(&bytes[..header.len()], header);
    // Bottom row first, little endian.
    assert_eq!(&bytes[header.len()..header.len() + 4], &3.25f32.to_le_bytes());
    assert_eq!(bytes.len(), header.len() + 6 * 4);
    let back = io::read_pfm(&p).unwrap();
    assert_eq!((back.width, back.height), (3, 2));
    assert_eq!(back.values, values);
}

#[test]
fn pfm_big_endian_and_loose_whitespace() {
    // Positive scale = big endian; header tokens separated by arbitrary whitespace.
    let mut bytes = b"Pf  2\t1\r\n 1.0\n".to_vec();
    bytes.extend_from_slice(&7.5f32.to_be_bytes());
    bytes.extend_from_slice(&(-1.0f32).to_be_bytes());
    let image = io::parse_pfm(&bytes).unwrap();
    assert_eq!(image.values, vec![7.5, -1.0]);
}

#[test]
fn pfm_errors() {
    let cases: &[&[u8]] = &[
        b"",
        b"P5\n1 1\n255\n\0",
        b"PF\n1 1\n-1\n\0\0\0\0\0\0\0\0\0\0\0\0",
        b"Pf\n0 1\n-1\n",
        b"Pf\n+1 1\n-1\n\0\0\0\0",
        b"Pf\n1 1\n0\n\0\0\0\0",
        b"Pf\n1 1\nnan\n\0\0\0\0",
        b"Pf\n1 1\n-1\n\0\0\0",
        b"Pf\n1 1\n-1\n\0\0\0\0\0",
        b"Pf\n1 1\n-1",
        b"Pf\n99999999999 99999999999\n-1\n\0\0\0\0",
        b"Pf\n18446744073709551615 2\n-1\n\0\0\0\0",
    ];
    for case in cases {
        assert!(io::parse_pfm(case).is_err(), "{:?} must be rejected", String::from_utf8_lossy(case));
    }
    let err = io::read_pfm(temp_dir("pfm_errors").join("none.pfm")).unwrap_err();
    assert!(err.to_string().contains("none.pfm"), "{err}");
}

#[test]
fn disparity_values_for_pfm() {
    let disparity = DisparityImage { width: 2, height: 2, data: vec![0, 16 * 5 + 8, INVALID, 16 * 127 + 15] };
    assert_eq!(io::disparity_to_pfm_values(&disparity), vec![0.0, 5.5, f32::INFINITY, 127.9375]);
}

#[test]
fn write_rejects_wrong_sizes() {
    let dir = temp_dir("write_sizes");
    assert!(matches!(io::write_pfm(dir.join("a.pfm"), 2, 2, &[0.0; 3]), Err(IoError::Size { .. })));
    assert!(matches!(io::write_pfm(dir.join("b.pfm"), 0, 0, &[]), Err(IoError::Size { .. })));
}

fn valid_pfm() -> impl Strategy<Value = Vec<u8>> {
    (1usize..6, 1usize..6, any::<bool>()).prop_flat_map(|(w, h, little)| {
        prop::collection::vec(any::<f32>(), w * h).prop_map(move |values| {
            let mut bytes = format!("Pf\n{w} {h}\n{}\n", if little { "-1.0" } else { "1.0" }).into_bytes();
            for v in &values {
                bytes.extend_from_slice(&if little { v.to_le_bytes() } else { v.to_be_bytes() });
            }
            bytes
        })
    })
}

/// Header-like text: tokens from a PFM-ish vocabulary joined by random whitespace, then a body.
fn header_soup() -> impl Strategy<Value = Vec<u8>> {
    let token = prop_oneof![
        Just("Pf".to_owned()),
        Just("PF".to_owned()),
        Just("-1".to_owned()),
        Just("1e40".to_owned()),
        Just("-0".to_owned()),
        Just("inf".to_owned()),
        "[0-9]{1,25}",
        "[-+.eE0-9a-z]{0,6}",
    ];
    let sep = prop_oneof![Just(" "), Just("\n"), Just("\t"), Just("\r\n"), Just("")];
    (prop::collection::vec((token, sep), 0..6), prop::collection::vec(any::<u8>(), 0..64)).prop_map(|(parts, body)| {
        let mut bytes = Vec::new();
        for (t, s) in parts {
            bytes.extend_from_slice(t.as_bytes());
            bytes.extend_from_slice(s.as_bytes());
        }
        bytes.extend_from_slice(&body);
        bytes
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 4000, ..ProptestConfig::default() })]

    #[test]
    fn pfm_parser_is_total_on_random_bytes(bytes in prop::collection::vec(any::<u8>(), 0..256)) {
        let _ = io::parse_pfm(&bytes);
    }

    #[test]
    fn pfm_parser_is_total_on_header_soup(bytes in header_soup()) {
        if let Ok(image) = io::parse_pfm(&bytes) {
            prop_assert_eq!(image.values.len(), image.width * image.height);
        }
    }

    #[test]
    fn pfm_parser_is_total_on_mutated_files(
        bytes in valid_pfm(),
        edits in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>(), 0u8..3), 1..6),
    ) {
        let mut bytes = bytes;
        for (index, byte, kind) in edits {
            if bytes.is_empty() {
                break;
            }
            let i = index.index(bytes.len());
            match kind {
                0 => bytes[i] = byte,
                1 => { bytes.remove(i); }
                _ => bytes.insert(i, byte),
            }
        }
        if let Ok(image) = io::parse_pfm(&bytes) {
            prop_assert_eq!(image.values.len(), image.width * image.height);
        }
    }

    #[test]
    fn pfm_round_trip(bytes in valid_pfm()) {
        let image = io::parse_pfm(&bytes).unwrap();
        let encoded = io::encode_pfm(image.width, image.height, &image.values).unwrap();
        let again = io::parse_pfm(&encoded).unwrap();
        prop_assert_eq!(image.width, again.width);
        prop_assert_eq!(image.height, again.height);
        // Bitwise, so NaN payloads count too.
        let bits = |v: &[f32]| v.iter().map(|f| f.to_bits()).collect::<Vec<_>>();
        prop_assert_eq!(bits(&image.values), bits(&again.values));
    }
}
