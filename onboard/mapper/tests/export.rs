//! Map exports: PLY read back by `eval::map::parse_ply`, `.bt` against a file written by the real
//! OctoMap library (and, with `OCTOMAP_PYTHON` set, read by it), top-down PNG decoded again.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::collections::HashMap;

use eval::map::parse_ply;
use mapper::cloud::{CLOUD_LEAF_M, MapPoint, VoxelCloud};
use mapper::export::png::{OBSTACLE_RGB, UNKNOWN_RGB};
use mapper::export::{BtError, PlyFormat, point_colour, read_bt, write_bt, write_height_png, write_ply};
use mapper::occupancy::{OCTREE_RESOLUTION_M, Occupancy, OccupancyMap, OccupancyParams, VoxelKey};
use nalgebra::{Isometry3, Point3, Vector3};
use proptest::prelude::*;

const REFERENCE_BT: &[u8] = include_bytes!(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data/octomap_reference.bt"));

/// A sloped ground patch with a rock (obstacle points) on it, as a submap cloud would hold.
fn ground_with_rock() -> VoxelCloud {
    let mut cloud = VoxelCloud::new(CLOUD_LEAF_M);
    for i in 0..60 {
        for j in 0..40 {
            let (x, y) = (0.025 + 0.05 * f64::from(i), -1.0 + 0.025 + 0.05 * f64::from(j));
            let rock = (x - 1.5).hypot(y) < 0.2;
            let z = 0.1 * x + if rock { 0.25 } else { 0.0 };
            let intensity = (40 + (i * 3 + j) % 150) as u8;
            cloud.points.push(MapPoint {
                position_m: Point3::new(x as f32, y as f32, z as f32),
                intensity,
                obstacle: rock,
            });
        }
    }
    cloud
}

fn ply_body(bytes: &[u8]) -> &[u8] {
    let end = bytes.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
    &bytes[end..]
}

#[test]
fn ply_binary_and_ascii_are_read_back_by_eval() {
    let cloud = ground_with_rock();
    let t = Isometry3::new(Vector3::new(10.0, -5.0, 1.0), Vector3::new(0.0, 0.0, 0.5));
    for format in [PlyFormat::BinaryLittleEndian, PlyFormat::Ascii] {
        for transform in [None, Some(&t)] {
            let mut bytes = Vec::new();
            write_ply(&cloud, format, transform, &mut bytes).unwrap();
            let points = parse_ply(&bytes).unwrap();
            assert_eq!(points.len(), cloud.len());
            for (read, p) in points.iter().zip(&cloud.points) {
                let expected: Point3<f32> = match transform {
                    Some(t) => (t * Point3::from(p.position_m.coords.cast::<f64>())).cast::<f32>(),
                    None => p.position_m,
                };
                // ASCII prints the shortest text that reads back as the same f32.
                assert_eq!(read.cast::<f32>(), expected, "{format:?}");
                if format == PlyFormat::BinaryLittleEndian {
                    assert_eq!(*read, expected.cast::<f64>());
                }
            }
        }
    }
    // Colours: 15-byte binary records, obstacles red, others grey by intensity.
    let mut bytes = Vec::new();
    write_ply(&cloud, PlyFormat::BinaryLittleEndian, None, &mut bytes).unwrap();
    let body = ply_body(&bytes);
    assert_eq!(body.len(), 15 * cloud.len());
    let obstacles = cloud.obstacle_count();
    assert!(obstacles > 20 && obstacles < cloud.len() / 10);
    for (record, p) in body.chunks_exact(15).zip(&cloud.points) {
        let rgb = [record[12], record[13], record[14]];
        assert_eq!(rgb, point_colour(p));
        assert_eq!(rgb, if p.obstacle { [255, 0, 0] } else { [p.intensity; 3] });
    }
}

/// The content of `tests/data/octomap_reference.bt` (see the README there), built in our map.
fn reference_content() -> OccupancyMap {
    let params = OccupancyParams::default();
    let mut map = OccupancyMap::new(OCTREE_RESOLUTION_M, params);
    for i in 0..10 {
        for j in 0..10 {
            map.add_log_odds([i, j, 0], params.hit_log_odds);
            for k in 1..6 {
                map.add_log_odds([i, j, k], params.miss_log_odds);
            }
        }
    }
    map.add_log_odds([-11, -21, 3], params.hit_log_odds);
    map
}

fn ml_states(map: &OccupancyMap) -> HashMap<VoxelKey, bool> {
    map.iter().map(|(k, _)| (k, map.occupancy(&k) == Occupancy::Occupied)).collect()
}

fn data_part(bytes: &[u8]) -> (&str, &[u8]) {
    let at = bytes.windows(5).position(|w| w == b"data\n").unwrap();
    let header = std::str::from_utf8(&bytes[..at]).unwrap();
    let size_line = header.lines().find(|l| l.starts_with("size ")).unwrap();
    (size_line, &bytes[at + 5..])
}

#[test]
fn real_octomap_file_parses_with_its_content() {
    let tree = read_bt(REFERENCE_BT).unwrap();
    assert_eq!(tree.id, "OcTree");
    assert_eq!(tree.resolution_m, 0.1);
    assert_eq!(tree.node_count, 326);
    // OctoMap's getNumLeafNodes() printed 251 when the file was made.
    assert_eq!(tree.leaves.len(), 251);
    let states = tree.voxel_states(10_000).unwrap();
    assert_eq!(states, ml_states(&reference_content()));
    assert_eq!(states.values().filter(|&&o| o).count(), 101);
    assert_eq!(states.get(&[-11, -21, 3]), Some(&true));
    assert_eq!(states.get(&[4, 7, 3]), Some(&false));
    // Pruning happened: the free box holds 2×2×2 blocks.
    assert!(tree.leaves.iter().any(|l| l.level == 1 && !l.occupied));
}

#[test]
fn our_writer_reproduces_octomaps_bytes() {
    let mut bytes = Vec::new();
    write_bt(&reference_content(), &mut bytes).unwrap();
    assert!(bytes.starts_with(b"# Octomap OcTree binary file\n"));
    assert_eq!(data_part(&bytes), data_part(REFERENCE_BT));
}

#[test]
fn written_bt_reads_back_as_the_map() {
    // Ground-like content: a free layer, occupied floor, scattered values between the clamps.
    let params = OccupancyParams::default();
    let mut map = OccupancyMap::new(OCTREE_RESOLUTION_M, params);
    for x in -40i32..40 {
        for y in -25..35 {
            let ground = (x + y).div_euclid(7);
            map.set_log_odds([x, y, ground], params.max_log_odds);
            for z in ground + 1..ground + 6 {
                let l = if (x * 31 + y * 17 + z) % 11 == 0 { 0.45 } else { params.min_log_odds };
                map.set_log_odds([x, y, z], l);
            }
        }
    }
    let mut bytes = Vec::new();
    write_bt(&map, &mut bytes).unwrap();
    let tree = read_bt(&bytes).unwrap();
    assert_eq!(tree.resolution_m, OCTREE_RESOLUTION_M);
    assert_eq!(tree.voxel_states(1 << 20).unwrap(), ml_states(&map));
    assert!(tree.leaves.len() < map.len(), "pruning should merge the free layers");
    // Keys outside OctoMap's 16-bit range are refused, not wrapped.
    map.set_log_odds([40_000, 0, 0], 1.0);
    assert!(write_bt(&map, &mut Vec::new()).is_err());
}

#[test]
fn bt_reader_rejects_broken_files() {
    assert_eq!(read_bt(b"hello\n"), Err(BtError::BadMagic));
    let (_, data) = data_part(REFERENCE_BT);
    let header_len = REFERENCE_BT.len() - data.len();
    assert_eq!(read_bt(&REFERENCE_BT[..REFERENCE_BT.len() - 1]), Err(BtError::Truncated));
    let text = String::from_utf8_lossy(&REFERENCE_BT[..header_len]).replace("size 326", "size 327");
    let mut wrong_size = text.into_bytes();
    wrong_size.extend_from_slice(data);
    assert_eq!(read_bt(&wrong_size), Err(BtError::SizeMismatch { header: 327, data: 326 }));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    #[test]
    fn bt_reader_is_total(bytes in prop::collection::vec(any::<u8>(), 0..600), mutations in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8)) {
        let _ = read_bt(&bytes);
        let mut prefixed = b"# Octomap OcTree binary file\nid OcTree\nsize 99\nres 0.1\ndata\n".to_vec();
        prefixed.extend_from_slice(&bytes);
        let _ = read_bt(&prefixed);
        let mut mutated = REFERENCE_BT.to_vec();
        for (at, v) in &mutations {
            let i = at.index(mutated.len());
            mutated[i] = *v;
        }
        if let Ok(tree) = read_bt(&mutated) {
            let _ = tree.voxel_states(1 << 16);
        }
    }

    #[test]
    fn bt_round_trip(cells in prop::collection::vec((prop::array::uniform3(-200i32..200), -2.0f32..3.5), 0..300)) {
        let mut map = OccupancyMap::new(OCTREE_RESOLUTION_M, OccupancyParams::default());
        for (k, l) in cells {
            map.set_log_odds(k, l);
        }
        let mut bytes = Vec::new();
        write_bt(&map, &mut bytes).unwrap();
        let tree = read_bt(&bytes).unwrap();
        prop_assert_eq!(tree.voxel_states(1 << 20).unwrap(), ml_states(&map));
    }
}

/// The project venv's python (created by `scripts/test` from scripts/requirements.txt, which
/// pins `octomap-python`, the OctoMap library's binding).
const VENV_PYTHON: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../.venv/bin/python");

/// Reads our `.bt` with the real OctoMap library (through `octomap-python`).
#[test]
fn octomap_library_reads_our_bt() {
    let python = std::env::var("OCTOMAP_PYTHON").unwrap_or_else(|_| VENV_PYTHON.to_owned());
    assert!(std::path::Path::new(&python).exists(), "no Python venv at {python}: run scripts/test first");
    let dir = std::env::temp_dir().join(format!("mapper_bt_check_{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let params = OccupancyParams::default();
    let mut map = OccupancyMap::new(OCTREE_RESOLUTION_M, params);
    for x in -30i32..30 {
        for y in -20..20 {
            let ground = (x - y).div_euclid(9);
            map.set_log_odds([x, y, ground], params.max_log_odds);
            for z in ground + 1..ground + 4 {
                map.set_log_odds([x, y, z], if (x * y + z) % 13 == 0 { 0.85 } else { params.min_log_odds });
            }
        }
    }
    let mut bytes = Vec::new();
    write_bt(&map, &mut bytes).unwrap();
    let expected: String =
        ml_states(&map).iter().map(|(k, o)| format!("{} {} {} {}\n", k[0], k[1], k[2], u8::from(*o))).collect();
    std::fs::write(dir.join("map.bt"), &bytes).unwrap();
    std::fs::write(dir.join("expected.txt"), expected).unwrap();
    let output = std::process::Command::new(python)
        .arg(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/check_bt.py"))
        .arg(dir.join("map.bt"))
        .arg(dir.join("expected.txt"))
        .output()
        .unwrap();
    println!("{}{}", String::from_utf8_lossy(&output.stdout), String::from_utf8_lossy(&output.stderr));
    std::fs::remove_dir_all(&dir).unwrap();
    assert!(output.status.success());
}

#[test]
fn height_png_shows_heights_and_obstacles() {
    let cloud = ground_with_rock();
    let mut bytes = Vec::new();
    write_height_png(&cloud, 0.1, &mut bytes).unwrap();
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut rgb = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut rgb).unwrap();
    // x spans 0.025..2.975 m and y −0.975..0.975 m: 30 × 20 cells of 10 cm.
    assert_eq!((info.width, info.height), (30, 20));
    assert_eq!(info.color_type, png::ColorType::Rgb);
    let pixel = |x: f64, y: f64| {
        let col = ((x - 0.025) / 0.1).floor() as usize;
        let row = 19 - ((y + 0.975) / 0.1).floor() as usize; // north up
        let i = 3 * (row * 30 + col);
        [rgb[i], rgb[i + 1], rgb[i + 2]]
    };
    assert_eq!(pixel(1.5, 0.0), OBSTACLE_RGB);
    // Height rises with x: the ramp's blue fades and red/green grow.
    let (low, high) = (pixel(0.1, 0.5), pixel(2.9, 0.5));
    assert!(low[2] > high[2] && low[0] < high[0], "low {low:?} high {high:?}");
    assert!(rgb.chunks_exact(3).all(|c| c != UNKNOWN_RGB), "the patch is fully observed");
    // A gap shows as unknown.
    let mut sparse = VoxelCloud::new(CLOUD_LEAF_M);
    sparse.points = vec![cloud.points[0], *cloud.points.last().unwrap()];
    let mut bytes = Vec::new();
    write_height_png(&sparse, 0.5, &mut bytes).unwrap();
    let mut reader = png::Decoder::new(std::io::Cursor::new(bytes)).read_info().unwrap();
    let mut rgb = vec![0; reader.output_buffer_size().unwrap()];
    reader.next_frame(&mut rgb).unwrap();
    assert!(rgb.chunks_exact(3).filter(|c| *c == UNKNOWN_RGB).count() > 2);
    assert!(write_height_png(&cloud, 0.0, &mut Vec::new()).is_err());
    assert!(write_height_png(&cloud, 1e-5, &mut Vec::new()).is_err());
}
