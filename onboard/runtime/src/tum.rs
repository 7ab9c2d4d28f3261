//! Trajectories in the TUM format (`stamp tx ty tz qx qy qz qw`, one pose per line, stamp in
//! seconds), the format evo and most SLAM tools read. Stamps are written exactly from their
//! nanoseconds (`1403636593.013555456`), not through a float, so nothing is lost at dataset
//! epochs of 1.4e9 s.

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Isometry3;

/// The TUM text of `(stamp_ns, pose)` rows, `offset_ns` added to every stamp.
pub fn tum_text(rows: &[(u64, Isometry3<f64>)], offset_ns: u64) -> String {
    let mut text = String::with_capacity(rows.len() * 96);
    for (stamp_ns, pose) in rows {
        let stamp_ns = stamp_ns.saturating_add(offset_ns);
        let p = pose.translation.vector;
        let q = pose.rotation.quaternion();
        // Writing into a String cannot fail.
        let _ = writeln!(
            text,
            "{}.{:09} {} {} {} {} {} {} {}",
            stamp_ns / 1_000_000_000,
            stamp_ns % 1_000_000_000,
            p.x,
            p.y,
            p.z,
            q.i,
            q.j,
            q.k,
            q.w
        );
    }
    text
}

/// Writes `rows` as a TUM file (see [`tum_text`]).
pub fn write_tum(path: &Path, rows: &[(u64, Isometry3<f64>)], offset_ns: u64) -> std::io::Result<()> {
    std::fs::write(path, tum_text(rows, offset_ns))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{UnitQuaternion, Vector3};

    #[test]
    fn stamps_are_exact_decimal_seconds() {
        let pose = Isometry3::from_parts(
            Vector3::new(1.0, -2.5, 0.125).into(),
            UnitQuaternion::from_euler_angles(0.1, 0.2, 0.3),
        );
        let text = tum_text(&[(13_555_456, pose), (5, Isometry3::identity())], 1_403_636_593_000_000_000);
        let lines: Vec<&str> = text.lines().collect();
        assert!(lines[0].starts_with("1403636593.013555456 1 -2.5 0.125 "), "{}", lines[0]);
        assert_eq!(lines[1], "1403636593.000000005 0 0 0 0 0 0 1");
        let q = pose.rotation.quaternion();
        let fields: Vec<f64> = lines[0].split(' ').skip(4).map(|f| f.parse().unwrap_or(f64::NAN)).collect();
        assert_eq!(fields, vec![q.i, q.j, q.k, q.w], "rotation written in full precision, x y z w");
    }
}
