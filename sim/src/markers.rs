//! AprilTag tag36h11 markers: the codes, their 10 × 10 cell layout, and where each robot carries
//! its three tags.
//!
//! The codes and the bit layout are data from the AprilTag library's `tag36h11.c` (BSD-2-Clause,
//! © 2013-2016 The Regents of the University of Michigan, APRIL Robotics Lab; Olson, ICRA 2011;
//! Wang and Olson, IROS 2016), taken from the repository's `data/apriltag/tag36h11/`. Only the first
//! 96 codes are kept (three per robot for 32 robots); a test checks them against that table.
//!
//! Cell layout (the data folder's verified convention): a 10 × 10 grid, the outer ring white, the
//! inner 8 × 8 square black, and bit `i` (bit 0 = most significant of 36) at column
//! `bit_x[i] + 1`, row `bit_y[i] + 1`, white when set. Row 0 is the tag's top, column 0 its left.
//! The marker's *size* is the edge of the black square (8 cells), as AprilTag detectors expect.

/// Number of data bits of a tag36h11 code.
pub const TAG36H11_BITS: usize = 36;
/// Cells along an edge of a rendered tag, white border included.
pub const TAG_CELLS: usize = 10;
/// Cells along the edge of the black square that defines the tag size.
pub const TAG_BLACK_CELLS: usize = 8;

/// tag36h11 codes for ids `0 ..= 95`.
pub const TAG36H11_CODES: [u64; 96] = [
    0xD7E00984B,
    0xDDA664CA7,
    0xDC4A1C821,
    0xE17B470E9,
    0xEF91D01B1,
    0xF429CDD73,
    0x05DA29225,
    0x1106CBA43,
    0x223BED79D,
    0x21F51213C,
    0x33EB19CA6,
    0x3F76EB0F8,
    0x469A97414,
    0x45DCFE0B0,
    0x4A6465F72,
    0x51801DB96,
    0x5EB946B4E,
    0x68A7CC2EC,
    0x6F0BA2652,
    0x78765559D,
    0x87B83D129,
    0x86CC4A5C5,
    0x8B64DF90F,
    0x9C577B611,
    0xA3810F2F5,
    0xAF4D75B83,
    0xB59A03FEF,
    0xBB1096F85,
    0xD1B92FC76,
    0xD0DD509D2,
    0xE2CFDA160,
    0x2FF497C63,
    0x47240671B,
    0x5047A2E55,
    0x635CA87C7,
    0x691254166,
    0x68F43D94A,
    0x6EF24BDB6,
    0x8CDD8F886,
    0x9DE96B718,
    0xAFF6E5A8A,
    0xBAE46F029,
    0xD225B6D59,
    0xDF8BA8C01,
    0xE3744A22F,
    0xFBB59375D,
    0x18A916828,
    0x22F29C1BA,
    0x286887D58,
    0x41392322E,
    0x75D18ECD1,
    0x87C302743,
    0x8C6317BA9,
    0x9E40F36D7,
    0xC0E5A806A,
    0xCC78CB87C,
    0x12D2F2D01,
    0x379F36A21,
    0x6973F59AC,
    0x7789EA9F4,
    0x8F1C73E84,
    0x8DD287A20,
    0x94A4EEE4C,
    0xA455379B5,
    0xA9E92987D,
    0xBD25CB40B,
    0xBE98D3582,
    0xD3D5972B2,
    0x14C53D7C7,
    0x4F1796936,
    0x4E71FED1A,
    0x66D46FAE0,
    0xA55ABB933,
    0xEBEE1ACCA,
    0x1AD4BA6A4,
    0x305B17571,
    0x553611351,
    0x59CA62775,
    0x7819CB6A1,
    0xEDB7BC9EB,
    0x5B2694212,
    0x72E12D185,
    0xED6152E2C,
    0x5BCDADBF3,
    0x78E0AA0C6,
    0xC60A0B909,
    0xEF9A34B0D,
    0x398A6621A,
    0xA8A27C944,
    0x4B564304E,
    0x52902B4E2,
    0x857280B56,
    0xA91B2C84B,
    0xE91DF939B,
    0x1FA405F28,
    0x23793AB86,
];

const BIT_X: [u8; TAG36H11_BITS] =
    [1, 2, 3, 4, 5, 2, 3, 4, 3, 6, 6, 6, 6, 6, 5, 5, 5, 4, 6, 5, 4, 3, 2, 5, 4, 3, 4, 1, 1, 1, 1, 1, 2, 2, 2, 3];
const BIT_Y: [u8; TAG36H11_BITS] =
    [1, 1, 1, 1, 1, 2, 2, 2, 3, 1, 2, 3, 4, 5, 2, 3, 4, 3, 6, 6, 6, 6, 6, 5, 5, 5, 4, 6, 5, 4, 3, 2, 5, 4, 3, 4];

/// The code of tag `id`, if it is one of the kept codes.
pub fn tag36h11_code(id: u32) -> Option<u64> {
    TAG36H11_CODES.get(id as usize).copied()
}

/// Whether cell `(col, row)` of the 10 × 10 rendering of `code` is white. Out-of-range cells are
/// white (the quiet zone around a printed tag).
pub fn tag_cell_is_white(code: u64, col: usize, row: usize) -> bool {
    if col == 0 || row == 0 || col >= TAG_CELLS - 1 || row >= TAG_CELLS - 1 {
        return true;
    }
    for i in 0..TAG36H11_BITS {
        if usize::from(BIT_X[i]) + 1 == col && usize::from(BIT_Y[i]) + 1 == row {
            return (code >> (TAG36H11_BITS - 1 - i)) & 1 == 1;
        }
    }
    false // the black border ring
}

/// The 10 × 10 cells of `code`, row-major, `true` = white.
pub fn tag_cells(code: u64) -> [[bool; TAG_CELLS]; TAG_CELLS] {
    let mut cells = [[true; TAG_CELLS]; TAG_CELLS];
    for (row, line) in cells.iter_mut().enumerate() {
        for (col, cell) in line.iter_mut().enumerate() {
            *cell = tag_cell_is_white(code, col, row);
        }
    }
    cells
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used, clippy::needless_range_loop)]
    use super::*;

    const SHARED: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../data/apriltag/tag36h11/");

    #[test]
    fn codes_and_layout_match_the_shared_table() {
        let codes = std::fs::read_to_string(format!("{SHARED}tag36h11_codes.txt")).unwrap();
        let table: Vec<u64> = codes
            .lines()
            .filter_map(|l| l.trim().strip_prefix("0x"))
            .map(|h| u64::from_str_radix(h, 16).unwrap())
            .collect();
        assert_eq!(table.len(), 587);
        assert_eq!(&table[..TAG36H11_CODES.len()], &TAG36H11_CODES[..]);
        let layout = std::fs::read_to_string(format!("{SHARED}tag36h11_bit_layout.txt")).unwrap();
        let rows: Vec<Vec<u8>> = layout
            .lines()
            .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
            .map(|l| l.split_whitespace().map(|t| t.parse().unwrap()).collect())
            .collect();
        assert_eq!(rows.len(), TAG36H11_BITS);
        for (i, r) in rows.iter().enumerate() {
            assert_eq!((r[0] as usize, r[1], r[2]), (i, BIT_X[i], BIT_Y[i]));
        }
    }

    #[test]
    fn rendering_matches_the_reference_picture_of_tag_0() {
        // The data folder's PNG: 10 px per cell plus a 40 px white margin.
        let file = std::fs::File::open(format!("{SHARED}tag36h11_id0_rendered_from_table.png")).unwrap();
        let mut reader = png::Decoder::new(std::io::BufReader::new(file)).read_info().unwrap();
        let mut buf = vec![0; reader.output_buffer_size().unwrap()];
        let info = reader.next_frame(&mut buf).unwrap();
        let channels = info.color_type.samples();
        let cells = tag_cells(TAG36H11_CODES[0]);
        for (row, line) in cells.iter().enumerate() {
            for (col, &white) in line.iter().enumerate() {
                let (x, y) = (40 + col * 10 + 5, 40 + row * 10 + 5);
                let value = buf[(y * info.width as usize + x) * channels];
                assert_eq!(value > 127, white, "cell ({col}, {row})");
            }
        }
    }

    #[test]
    fn border_ring_is_black_and_quiet_zone_white() {
        for &code in &TAG36H11_CODES {
            let cells = tag_cells(code);
            for i in 0..TAG_CELLS {
                assert!(cells[0][i] && cells[9][i] && cells[i][0] && cells[i][9]);
            }
            for i in 1..TAG_CELLS - 1 {
                assert!(!cells[1][i] && !cells[8][i] && !cells[i][1] && !cells[i][8]);
            }
        }
    }
}
