//! `mapper::cloud_file`: the PLY, PCD and XYZ readers on hand-made files, the project's own PLY
//! export read back with its obstacle flags, the real test clouds of `data/pointcloud/`, and
//! totality (no panic on any bytes).

use mapper::cloud_file::{CloudFormat, CloudParseError, parse_cloud, read_cloud};
use mapper::export::{PlyFormat, write_ply};
use mapper::{MapPoint, VoxelCloud};
use nalgebra::Point3;
use proptest::prelude::*;

const DATA: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../data/pointcloud/");

fn point(x: f32, y: f32, z: f32, intensity: u8, obstacle: bool) -> MapPoint {
    MapPoint { position_m: Point3::new(x, y, z), intensity, obstacle }
}

#[test]
fn project_ply_export_reads_back_with_obstacle_flags_in_both_encodings() {
    let cloud = VoxelCloud {
        leaf_m: 0.05,
        points: vec![
            point(1.0, -2.5, 0.25, 17, false),
            point(0.5, 0.0, -1.0, 0, true),
            point(3.0, 4.0, 5.0, 255, false),
        ],
    };
    for format in [PlyFormat::Ascii, PlyFormat::BinaryLittleEndian] {
        let mut bytes = Vec::new();
        write_ply(&cloud, format, None, &mut bytes).unwrap();
        let read = parse_cloud(&bytes).unwrap();
        assert_eq!(read.format, Some(CloudFormat::ProjectPly));
        assert_eq!(read.points, cloud.points, "{format:?}");
    }
}

#[test]
fn generic_ply_with_doubles_intensity_a_leading_element_and_faces() {
    let mut bytes =
        b"ply\nformat binary_big_endian 1.0\ncomment not ours\nelement camera 1\nproperty list uchar int ids\n\
        property double height\nelement vertex 2\nproperty double x\nproperty double y\nproperty double z\n\
        property float intensity\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
            .to_vec();
    bytes.push(2);
    bytes.extend_from_slice(&[0; 8]);
    bytes.extend_from_slice(&1.0f64.to_be_bytes());
    for (xyz, intensity) in [([1.0f64, 2.0, 3.0], 12.4f32), ([-1.0, f64::NAN, 0.0], 0.0), ([4.0, 5.0, 6.0], 900.0)] {
        xyz.iter().for_each(|v| bytes.extend_from_slice(&v.to_be_bytes()));
        bytes.extend_from_slice(&intensity.to_be_bytes());
    }
    // The header says 2 vertices: the third record is where faces would be, and is not read.
    let read = parse_cloud(&bytes).unwrap();
    assert_eq!(read.format, Some(CloudFormat::Ply));
    assert_eq!(read.points, vec![point(1.0, 2.0, 3.0, 12, true)]);
    assert_eq!(read.dropped_non_finite, 1);

    let ascii = b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
        property list uchar int extra\nend_header\n1 2 3 2 7 7\n4 5 6 0\n";
    let read = parse_cloud(ascii).unwrap();
    assert_eq!(read.points, vec![point(1.0, 2.0, 3.0, 0, true), point(4.0, 5.0, 6.0, 0, true)]);
}

#[test]
fn pcd_ascii_with_extra_fields_and_binary_with_intensity() {
    let ascii = b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z normal curvature\nSIZE 4 4 4 4 4\nTYPE F F F F F\n\
        COUNT 1 1 1 3 1\nWIDTH 2\nHEIGHT 1\nPOINTS 2\nDATA ascii\n1 2 3 0 0 1 0.5\nnan nan nan 0 0 1 0\n";
    let read = parse_cloud(ascii).unwrap();
    assert_eq!(read.format, Some(CloudFormat::Pcd));
    assert_eq!(read.points, vec![point(1.0, 2.0, 3.0, 0, true)]);
    assert_eq!(read.dropped_non_finite, 1);

    let mut binary =
        b"VERSION .7\nFIELDS x y z intensity\nSIZE 4 4 4 1\nTYPE F F F U\nWIDTH 1\nHEIGHT 1\nDATA binary\n".to_vec();
    [0.5f32, -0.5, 2.0].iter().for_each(|v| binary.extend_from_slice(&v.to_le_bytes()));
    binary.push(200);
    assert_eq!(parse_cloud(&binary).unwrap().points, vec![point(0.5, -0.5, 2.0, 200, true)]);

    let compressed = b"VERSION .7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA binary_compressed\n";
    assert!(matches!(parse_cloud(compressed), Err(CloudParseError::Header { .. })));
}

#[test]
fn xyz_text_with_comments_commas_and_extra_columns() {
    let read = parse_cloud(b"# scan 3\n1 2 3\n\n4,5,6, 0.1 0.2 0.3\n// end\n").unwrap();
    assert_eq!(read.format, Some(CloudFormat::Xyz));
    assert_eq!(read.points, vec![point(1.0, 2.0, 3.0, 0, true), point(4.0, 5.0, 6.0, 0, true)]);
    let error = parse_cloud(b"1 2 3\n1 2\n").unwrap_err().to_string();
    assert!(error.contains("line 2"), "{error}");
}

#[test]
fn errors_name_the_file_and_the_problem() {
    let missing = read_cloud(format!("{DATA}no_such_cloud.ply")).unwrap_err().to_string();
    assert!(missing.contains("no_such_cloud.ply"), "{missing}");
    let truncated = b"ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\nproperty float y\n\
        property float z\nend_header\n\0\0\0\0";
    let message = parse_cloud(truncated).unwrap_err().to_string();
    assert!(message.contains("vertex 0") && message.contains("ends early"), "{message}");
    assert!(matches!(parse_cloud(b""), Err(CloudParseError::Empty { .. })));
}

/// The real clouds the matcher's tests and benchmark use: sizes from their SOURCE.md.
#[test]
fn real_test_clouds_read_completely() {
    let bun0 = read_cloud(format!("{DATA}bunny/pcl_test_bun0.pcd")).unwrap();
    let bun4 = read_cloud(format!("{DATA}bunny/pcl_test_bun4.pcd")).unwrap();
    assert_eq!((bun0.points.len(), bun4.points.len()), (397, 361));
    let source = read_cloud(format!("{DATA}lidar_pair/source.ply")).unwrap();
    let target = read_cloud(format!("{DATA}lidar_pair/target.ply")).unwrap();
    assert_eq!(source.format, Some(CloudFormat::Ply));
    assert_eq!(source.points.len() + source.dropped_non_finite, 69_792);
    assert!(target.points.len() > 60_000);
    assert!(source.points.iter().all(|p| p.obstacle));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(20_000))]

    /// Any bytes: points or an error, never a panic.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..512)) {
        let _ = parse_cloud(&bytes);
    }

    /// Valid headers followed by arbitrary bytes reach the data parsers.
    #[test]
    fn arbitrary_data_after_valid_headers_never_panics(
        header in prop::sample::select(vec![
            "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\nproperty float z\nproperty list uchar int l\nend_header\n",
            "ply\nformat ascii 1.0\nelement a 3\nproperty list int uchar l\nelement vertex 3\nproperty uchar x\nproperty short y\nproperty double z\nend_header\n",
            "ply\nformat binary_big_endian 1.0\ncomment voxel cloud\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n",
            "VERSION .7\nFIELDS x y z\nSIZE 8 2 4\nTYPE F I F\nCOUNT 1 1 1\nPOINTS 18446744073709551615\nDATA binary\n",
            "VERSION .7\nFIELDS x y z intensity\nSIZE 4 4 4 4\nTYPE F F F F\nWIDTH 3\nHEIGHT 1\nDATA ascii\n",
        ]),
        data in proptest::collection::vec(any::<u8>(), 0..256),
    ) {
        let mut bytes = header.as_bytes().to_vec();
        bytes.extend_from_slice(&data);
        let _ = parse_cloud(&bytes);
    }
}
